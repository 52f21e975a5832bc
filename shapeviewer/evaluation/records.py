"""The files of a results folder (written by ``shapeviewer evaluate``): names, view records, grasp rows.

Folder layout (relative paths)::

    <root>/views/<stem>.json            one record per finished view (see :func:`view_record`)
    <root>/meshes/<stem>__truth.ply     ground-truth mesh, camera optical frame, metres
    <root>/meshes/<stem>__points.ply    the partial view (points), camera optical frame, metres
    <root>/meshes/<stem>__<method>.ply  each method's completion, camera optical frame, metres
    <root>/meshes/<stem>__samples.npz   the CNN's sample completions (:func:`samples_file`)
    <root>/grasps/<stem>__<method>[__<hand>].json  grasps planned on a completion (:mod:`grasp.serialize`);
                                        ranked by robustness too, its ``meta["robustness"]`` (:func:`grasp_rows`)

with ``stem`` from :func:`view_stem`. A view file is either the current format, a dict (see
:func:`view_record`), or the first format, a bare list of completion rows whose meshes sit at the
paths above and whose seed was not recorded. :func:`parse_view_file` reads both.

A completion row (:class:`CompletionRow`) has the keys :data:`ROW_FIELDS` (metrics NaN when the
method failed); a grasp row (:func:`grasp_rows`) the keys :data:`GRASP_ROW_FIELDS`. Method names
are :mod:`.methods`' :data:`~.methods.Method` strings, in file names as in rows.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal, cast, get_args

from ..errors import ShapeviewerError
from ..fileio import atomic_write
from ..sim import catalogue
from .methods import ENVELOPE as ENVELOPE
from .methods import GRASP_TABLE_METHODS as GRASP_TABLE_METHODS
from .methods import METHODS as METHODS
from .methods import Method, is_method

Metric = Literal["jaccard", "j80", "hausdorff_mean_mm", "hausdorff_max_mm", "hausdorff_rms_mm", "geodesic"]
METRICS: tuple[str, ...] = get_args(Metric)  # the Metric names, as row keys and columns
# Which way each metric is better, and its title.
HIGHER_IS_BETTER: dict[Metric, bool] = {
    "jaccard": True,
    "j80": True,
    "hausdorff_mean_mm": False,
    "hausdorff_max_mm": False,
    "hausdorff_rms_mm": False,
    "geodesic": False,
}
METRIC_TITLES: dict[Metric, str] = {
    "jaccard": "Jaccard",
    "j80": "J80 (sampled solids)",
    "hausdorff_mean_mm": "Hausdorff mean (mm)",
    "hausdorff_max_mm": "Hausdorff max (mm)",
    "hausdorff_rms_mm": "Hausdorff RMS (mm)",
    "geodesic": "Geodesic divergence",
}
# ``prior``: the shape prior the pipeline applied to our completions ("box", "revolution" or "").
ROW_FIELDS = ("object", "view", "view_set", "kind", "sensor", "method", *METRICS, "seconds", "error", "prior")
# What a view can show: the ground truth, the partial view, then each method (paper Fig. 1 order).
KINDS: tuple[str, ...] = ("truth", "points", *METHODS)
# Per view and method, means over its grasps (the keys of a view's "grasps" entries).
GRASP_MEANS = (
    "joint_error_deg",
    "pose_error_mm",
    "epsilon_planned",
    "volume_planned",
    "epsilon_executed",
    "volume_executed",
    "force_closure_planned",
    "force_closure_executed",
    "start_clear",
    "lift_success",
)
# The entry fields a results index keeps and shows (a subset of an entry's keys).
GRASP_FIELDS = (
    "n",
    "joint_error_deg",
    "pose_error_mm",
    "epsilon_planned",
    "epsilon_executed",
    "force_closure_planned",
    "lift_success",
    "seconds_plan",
)
GRASP_ROW_FIELDS = (
    "object",
    "view",
    "view_set",
    "method",
    "hand",
    "rank",
    "epsilon_planned",
    "volume_planned",
    "energy_planned",
    "lift_planned",
    "epsilon_executed",
    "volume_executed",
    "joint_error_deg",
    "pose_error_mm",
    "start_clear",
    "approach_contact",
    "lift_success",
    "lift_rise_mm",
    "lift_slip_mm",
    "robust_rank",
    "robust_fraction",
    "robust_epsilon_low",
    "robust_lifted",
    "wider",
)


def _float(v) -> float:
    """A value read from a view file as float; None, "", or anything unreadable is NaN."""
    try:
        return math.nan if v is None or v == "" else float(v)
    except (TypeError, ValueError):
        return math.nan


@dataclass(frozen=True)
class CompletionRow:
    """One method's completion of one view (a completion row, :data:`ROW_FIELDS`), as saved in a
    view record's ``rows`` and in ``rows.csv``.

    Attributes:
        object, view: which view (``view`` numbers the 726-view orientation grid; tabletop views
            from ``viewsets.TABLETOP_VIEW_OFFSET``).
        view_set: the view set (:data:`viewsets.ViewSet`).
        method: the completion method.
        kind: the object's shape kind (:func:`catalogue.shape_kind`; "" in rows written before it was).
        sensor: ``kinect`` or ``realsense`` ("" when not recorded).
        jaccard, j80, hausdorff_mean_mm, hausdorff_max_mm, hausdorff_rms_mm, geodesic: the metrics
            against the ground truth (:func:`metrics.completion_metrics`; distances in mm), NaN when
            the method failed.
        seconds: completion time (s), NaN when it failed.
        error: why the method failed ("" when it did not).
        prior: the shape prior the pipeline applied to our completions (``box``, ``revolution`` or "").
    """

    object: str
    view: int
    view_set: str
    method: Method
    kind: str = ""
    sensor: str = ""
    jaccard: float = math.nan
    j80: float = math.nan
    hausdorff_mean_mm: float = math.nan
    hausdorff_max_mm: float = math.nan
    hausdorff_rms_mm: float = math.nan
    geodesic: float = math.nan
    seconds: float = math.nan
    error: str = ""
    prior: str = ""

    @property
    def ok(self) -> bool:
        return not self.error

    def metric(self, name: Metric) -> float:
        return float(getattr(self, name))

    def to_json(self) -> dict:
        """The row as saved: a plain dict with the keys :data:`ROW_FIELDS`, in that order."""
        return {k: getattr(self, k) for k in ROW_FIELDS}

    @classmethod
    def from_json(cls, d: dict) -> CompletionRow:
        """A row as saved (either view-file format; keys a format did not write take their
        defaults, unreadable numbers are NaN). Raises ValueError for a row without an object,
        view or known method."""
        try:
            name, view, method = str(d["object"]), int(d["view"]), str(d["method"])
        except (KeyError, TypeError, ValueError):
            raise ValueError("a completion row needs an object, a view and a method") from None
        if not is_method(method):
            raise ValueError(f"unknown method {method!r}")
        return cls(
            object=name,
            view=view,
            view_set=str(d.get("view_set") or ""),
            method=cast(Method, method),
            kind=str(d.get("kind") or ""),
            sensor=str(d.get("sensor") or ""),
            jaccard=_float(d.get("jaccard")),
            j80=_float(d.get("j80")),
            hausdorff_mean_mm=_float(d.get("hausdorff_mean_mm")),
            hausdorff_max_mm=_float(d.get("hausdorff_max_mm")),
            hausdorff_rms_mm=_float(d.get("hausdorff_rms_mm")),
            geodesic=_float(d.get("geodesic")),
            seconds=_float(d.get("seconds")),
            error=str(d.get("error") or ""),
            prior=str(d.get("prior") or ""),
        )


def completion_rows(record: dict) -> list[CompletionRow]:
    """A view record's completion rows (:func:`parse_view_file` has checked them); a row without a
    view set takes the record's."""
    rows = [CompletionRow.from_json(r) for r in record["rows"]]
    return [r if r.view_set else replace(r, view_set=record["view_set"]) for r in rows]


def view_stem(name: str, view: int) -> str:
    """The file-name stem of one view: ``ycb/025_mug``, 7 -> ``ycb__025_mug__007``."""
    return f"{name.replace('/', '__')}__{int(view):03d}"


def view_file(root: str | Path, name: str, view: int) -> Path:
    """The record file of a view: ``<root>/views/<stem>.json``."""
    return Path(root) / "views" / f"{view_stem(name, view)}.json"


def grasp_file(stem: str, method: str, hand: str = "barrett") -> str:
    """Path (relative to the results folder) of a view's grasps for one method and hand."""
    return f"grasps/{stem}__{method}{'' if hand == 'barrett' else '__' + hand}.json"


def envelope_file(stem: str) -> str:
    """Path (relative to the results folder) of a view's grasp envelope (camera frame, metres), made
    from its sample completions when grasps are planned on it."""
    return f"meshes/{stem}__{ENVELOPE}.ply"


def samples_file(stem: str) -> str:
    """Path (relative to the results folder) of a view's sample completions: an ``.npz`` of
    ``samples`` ((8, 40, 40, 40) float32 occupancy probabilities, :meth:`Completer.predict_samples`;
    their mean is the CNN output that Ours-fast and Ours-detailed mesh) and their grid frame, ``center`` (camera frame,
    metres) and ``voxel_size`` (metres)."""
    return f"meshes/{stem}__samples.npz"


def mesh_files(root: str | Path, stem: str) -> dict[str, str]:
    """Paths relative to ``root`` of the view's meshes that exist: ``truth``, ``points`` and each
    method's completion (all camera frame, metres)."""
    found: dict[str, str] = {}
    for key in KINDS:
        rel = f"meshes/{stem}__{key}.ply"
        if (Path(root) / rel).is_file():
            found[key] = rel
    return found


def view_record(root, name: str, view: int, view_set: str, seed: int, rows: list[dict]) -> dict:
    """A view's record, as saved in ``views/<stem>.json``::

        {"object", "view", "view_set", "seed", "support_plane": [a, b, c, d] (camera frame) or None,
         "files": {"truth": "meshes/..", "points": "meshes/..", "<method>": "meshes/.."},
         "rows": [completion rows, ROW_FIELDS],
         "grasps": [one entry per (method, hand), see run.grasp_view]}

    ``rows`` may carry the view's ``support_plane`` (as :func:`run.evaluate_view` returns them);
    it is taken off the rows into the record. The rows are saved as :meth:`CompletionRow.to_json`
    writes them (every key of :data:`ROW_FIELDS`). ``files`` lists only meshes that exist (a failed
    method has none); paths are relative to ``root``.
    """
    planes = [r.pop("support_plane", None) for r in rows]
    return {
        "object": name,
        "view": int(view),
        "view_set": view_set,
        "seed": int(seed),
        "support_plane": next((p for p in planes if p is not None), None),
        "files": mesh_files(root, view_stem(name, view)),
        "rows": [CompletionRow.from_json(r).to_json() for r in rows],
        "grasps": [],
    }


class ViewFileError(ShapeviewerError, ValueError):
    """A view file that cannot be read (half written, corrupt, or not a view file)."""


def parse_view_file(text: str, root: str | Path) -> dict:
    """A view file's content (either format) as a record (:func:`view_record`'s keys and any other
    keys the file has); ``seed`` is None for the first format, which did not record it.

    ``files`` maps kind (truth, points, method) to a path relative to ``root`` and only holds files
    that exist. Raises :class:`ViewFileError` saying what is wrong.
    """
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as e:
        raise ViewFileError(f"not JSON ({e.msg} at line {e.lineno})") from None
    rows: object
    grasps: list = []
    if isinstance(doc, list):  # the first format: completion rows only, meshes at fixed paths
        rows, files = doc, None
        if not rows:
            raise ViewFileError("no rows")
        head, doc = rows[0], {}
    elif isinstance(doc, dict):
        rows, files, head = doc.get("rows"), doc.get("files"), doc
        grasps = doc.get("grasps") or []
        if not isinstance(rows, list):
            raise ViewFileError("no 'rows' list")
        if not isinstance(grasps, list) or not all(isinstance(g, dict) for g in grasps):
            raise ViewFileError("'grasps' is not a list of objects")
    else:
        raise ViewFileError(f"a JSON {type(doc).__name__}, not a view")
    if not isinstance(head, dict):
        raise ViewFileError("rows are not objects")
    try:
        name, view = str(head["object"]), int(head["view"])
    except (KeyError, TypeError, ValueError):
        raise ViewFileError("no object name and view number") from None
    for r in rows:
        if (
            not isinstance(r, dict)
            or r.get("object", name) != name
            or int(r.get("view", view)) != view
            or "method" not in r
        ):
            raise ViewFileError("rows of different views, or without a method")
        try:
            CompletionRow.from_json({"object": name, "view": view, **r})
        except ValueError as e:
            raise ViewFileError(f"a row that cannot be read: {e}") from None
    view_set = head.get("view_set") or (rows[0].get("view_set") if rows else "")
    view_set = str(view_set or catalogue.view_split(name, view))
    stem = view_stem(name, view)
    if not isinstance(files, dict):
        files = {k: f"meshes/{stem}__{k}.ply" for k in KINDS}
    files = {str(k): str(v) for k, v in files.items() if isinstance(v, str) and (Path(root) / v).is_file()}
    seed = doc.get("seed")
    return {
        **doc,
        "object": name,
        "view": view,
        "view_set": view_set,
        "seed": None if seed is None else int(seed),
        "support_plane": doc.get("support_plane"),
        "files": files,
        "rows": rows,
        "grasps": grasps,
    }


def load_view(root, name: str, view: int, seed: int | None = None) -> dict | None:
    """The record of a view (:func:`view_record`), or None when it has not been computed.

    A first-format file gets ``seed`` (the caller's run seed; -1 when None) as its seed. Raises
    :class:`ViewFileError` for a file that cannot be read.
    """
    path = view_file(root, name, view)
    if not path.exists():
        return None
    record = parse_view_file(path.read_text(), root)
    if record["seed"] is None:
        record["seed"] = -1 if seed is None else int(seed)
    return record


def save_view(root, record: dict) -> Path:
    """Write a record to ``views/<stem>.json`` atomically (a concurrent :meth:`ResultsStore.sync`
    never reads it half written); returns the path."""
    # NaN is written as NaN, which json reads back.
    return atomic_write(view_file(root, record["object"], record["view"]), json.dumps(record, indent=1))


def set_grasp_entry(record: dict, entry: dict) -> None:
    """Put a grasp entry into ``record["grasps"]`` in place of any earlier one of its (method, hand)."""
    key = (entry["method"], entry["hand"])
    record["grasps"] = [g for g in record["grasps"] if (g["method"], g["hand"]) != key] + [entry]


def upgrade_old_views(root, views, seed: int) -> None:
    """Rewrite the first-format files of ``views`` (``(object, view, ...)`` tuples) as records, so
    that every file in ``views/`` has the current format."""
    for name, view, *_ in views:
        path = view_file(root, name, view)
        text = path.read_text() if path.exists() else "{}"
        if isinstance(json.loads(text), list):
            save_view(root, {**parse_view_file(text, root), "seed": int(seed)})


def grasp_rows(
    base: dict, grasps, executions, robustness: list[dict] | None = None, first_round: int | None = None
) -> list[dict]:
    """One row (:data:`GRASP_ROW_FIELDS`) per planned grasp and its execution on the true object.

    ``base``: object, view, view_set, method, hand. ``robustness``: per grasp, a grasp file's
    ``meta["robustness"]`` entry (``{"rank"`` by robustness, 0 first, ``"fraction"`` of sample
    completions it holds on, ``"epsilon_low"``, ``"epsilons"``, ``"lifted"``: the share of them it
    lifted, None when not lifted``}``, :mod:`grasp.robust`), or None when
    the grasps were not ranked by robustness (the robust columns are then NaN). ``first_round``:
    how many of the grasps were planned on the completion; those after it come from the wider
    search on the grasp envelope (a grasp file's ``meta["wider"]["first"]``; None: there are none),
    and their rows have ``wider`` 1 and no planner's ``rank`` (NaN). ``lift_planned``:
    the planner's lift check on the completion (NaN: not run). Units: joint error
    in degrees (mm for the Panda's prismatic fingers), pose error, lift rise and slip in mm;
    booleans as 0/1.
    """
    rows = []
    first = len(grasps) if first_round is None else first_round
    for rank, (g, e) in enumerate(zip(grasps, executions)):
        lift = e.lift
        robust = robustness[rank] if robustness is not None else {}
        rows.append(
            {
                **base,
                "rank": rank if rank < first else math.nan,
                "epsilon_planned": float(g.epsilon),
                "volume_planned": float(g.volume),
                "energy_planned": float(g.energy),
                "lift_planned": math.nan if g.lift is None else float(g.lift.success),
                "epsilon_executed": float(e.epsilon),
                "volume_executed": float(e.volume),
                "joint_error_deg": float(e.joint_error),
                "pose_error_mm": float(e.pose_error),
                "start_clear": float(e.start_clear),
                "approach_contact": float(e.approach_contact),
                "lift_success": math.nan if lift is None else float(lift.success),
                "lift_rise_mm": math.nan if lift is None else 1000.0 * lift.rise,
                "lift_slip_mm": math.nan if lift is None else 1000.0 * lift.slip,
                "robust_rank": float(robust.get("rank", math.nan)),
                "robust_fraction": float(robust.get("fraction", math.nan)),
                "robust_epsilon_low": float(robust.get("epsilon_low", math.nan)),
                "robust_lifted": math.nan if robust.get("lifted") is None else float(robust["lifted"]),
                "wider": float(rank >= first),
            }
        )
    return rows


def load_grasp_rows(root, records: list[dict]) -> list[dict]:
    """Every executed grasp of the records' grasp entries, read back from their grasp files
    (entries with an error or without a file have none)."""
    from ..grasp.serialize import grasps_from_json

    rows = []
    for rec in records:
        for g in rec.get("grasps", []):
            if g["error"] or not g["file"]:
                continue
            gs = grasps_from_json((Path(root) / g["file"]).read_text())
            base = {
                "object": rec["object"],
                "view": int(rec["view"]),
                "view_set": rec["view_set"],
                "method": g["method"],
                "hand": g["hand"],
            }
            wider = gs.meta.get("wider")
            first = None if wider is None else int(wider["first"])
            rows += grasp_rows(base, gs.grasps, gs.executions, gs.meta.get("robustness"), first)
    return rows
