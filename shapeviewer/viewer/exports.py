"""The Pipeline tab's downloads of a segment: its points, its CNN grids and its meshes.

No viser: the app sends the ``(file name, content)`` pairs made here to the browser.
"""

from __future__ import annotations

from collections.abc import Mapping

from .. import export
from .results import SegmentResult
from .state import MESH_KINDS, MESH_TITLES, LoadedScene


def segment_export(
    scene: LoadedScene | None,
    results: Mapping[int, SegmentResult],
    sid: int | None,
    kind: str,
    mesh_format: str = "ply",
    frame: str = "world",
    mesh: str = "fast",
) -> tuple[str, bytes]:
    """``(file name, content)`` of an export of segment ``sid`` of ``scene``.

    Args:
        results: segment id -> its completion and the meshes made of it (camera frame).
        kind: ``points`` (PLY of the segment's points), ``grids`` (NPZ of the CNN input grid,
            output probabilities and grid frame) or ``mesh``.
        mesh_format: ``ply``, ``obj``, ``stl`` or ``glb`` (meshes only).
        frame: ``world`` or ``camera`` coordinates, metres (points and meshes; grids carry both).
        mesh: which mesh, one of :data:`~.state.MESH_KINDS`.

    Raises:
        ValueError: with a message for the user (nothing selected, not completed yet, ...).
    """
    if scene is None or sid is None or sid not in scene.segments:
        raise ValueError("Select a segment first (click it, or pick it in the Completion folder).")
    T, stem = scene.T_world_cam, f"{scene.name}_seg{sid}"
    if kind == "points":
        seg = scene.segments[sid]
        colors = scene.capture.flat_colors()
        data = export.points_ply_bytes(seg.points_cam, None if colors is None else colors[seg.indices], frame, T)
        return f"{stem}_points_{frame}.ply", data
    result = results.get(sid)
    if result is None:
        raise ValueError(f"Segment {sid} has no completion yet: complete it first.")
    c = result.completion
    if kind == "grids":
        return f"{stem}_grids.npz", export.grids_npz_bytes(c.grid_in, c.probabilities, c.frame, T, grid_out=c.grid_out)
    if kind == "mesh":
        if mesh not in MESH_KINDS:
            raise ValueError(f"unknown mesh {mesh!r}; choose one of {MESH_KINDS}")
        m = result.mesh(mesh)
        if m is None and mesh == "fast":
            raise ValueError(f"Segment {sid} has no fast mesh: {c.error}")
        if m is None:
            raise ValueError(
                f"Segment {sid} has no {MESH_TITLES[mesh].lower()} yet: compute it in the Completion folder first."
            )
        return f"{stem}_{mesh}_{frame}.{mesh_format}", export.mesh_bytes(m, mesh_format, frame, T)
    raise ValueError(f"unknown export {kind!r}")
