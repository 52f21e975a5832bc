"""The Dataset tab's downloads: a view's files at full resolution, its metrics, the index and the tables.

No viser: the tab sends the ``(file name, content)`` pairs made here to the browser.
"""

from __future__ import annotations

import numpy as np

from ... import export
from ...evaluation.records import KINDS
from ...evaluation.results import ResultsStore
from ...evaluation.summaries import GraspSummary, ObjectSummary, ViewInfo
from .summary import TITLES


def export_bytes(
    store: ResultsStore | None,
    objects: list[ObjectSummary],
    info: ViewInfo | None,
    grasps: list[GraspSummary],
    what: str,
    kind: str | None = None,
    mesh_format: str = "ply",
    frame: str = "camera",
) -> tuple[str, bytes]:
    """``(file name, content)`` of an export of ``store``.

    Args:
        objects: the objects of the current index (``index_csv`` and ``rows_csv``).
        info, grasps: the view on screen and its grasp results (None / [] when none is shown).
        what: ``mesh`` (``kind``: truth, points or a method), ``grasps`` (the grasps JSON of
            method ``kind``), ``view_csv`` (per-method metrics of the view), ``index_csv`` (the
            objects of the current index), ``rows_csv`` (every row of those objects' views) or
            ``tables`` (Tables I-IV, markdown).
        mesh_format: ``ply``, ``obj``, ``stl`` or ``glb`` (meshes; points are always PLY).
        frame: ``camera`` (the view's camera optical frame, as stored) or ``object`` (the
            object's frame: catalogue axes, bounding-box centre at the origin); metres.

    Raises:
        ValueError: with a message for the user.
    """
    if store is None:
        raise ValueError("No results store is open.")
    if what == "index_csv":
        return "results_index.csv", store.objects_csv(objects).encode()
    if what == "rows_csv":
        names = [o.name for o in objects if o.views]
        return "results_rows.csv", store.rows_csv(names).encode()
    if what == "tables":
        return "results_tables.md", store.tables_markdown().encode()
    if info is None:
        raise ValueError("Choose a view first.")
    stem = info.stem
    if what == "view_csv":
        return f"{stem}_metrics.csv", store.view_csv(info.object, info.view).encode()
    if what == "grasps":
        file = next((g.file for g in grasps if g.method == kind and g.file), None)
        if file is None:
            raise ValueError(f"No grasps planned on {kind} for this view.")
        return f"{stem}__{kind}_grasps.json", store.path(file).read_bytes()
    if what != "mesh":
        raise ValueError(f"unknown export {what!r}")
    if kind not in KINDS:
        raise ValueError(f"unknown mesh {kind!r}; choose one of {KINDS}")
    if frame not in ("camera", "object"):
        raise ValueError(f"unknown frame {frame!r} (camera or object)")
    T = np.linalg.inv(store.T_cam_obj(info.object, info.view))  # object <- camera
    out_frame = "world" if frame == "object" else "camera"
    try:
        if kind == "points":
            return f"{stem}__points_{frame}.ply", export.points_ply_bytes(
                store.load_points(info.object, info.view), None, out_frame, T
            )
        mesh = store.load_mesh(info.object, info.view, kind)
    except KeyError:
        raise ValueError(f"This view has no {TITLES.get(kind, kind).lower()} file.") from None
    return f"{stem}__{kind}_{frame}.{mesh_format}", export.mesh_bytes(mesh, mesh_format, out_frame, T)
