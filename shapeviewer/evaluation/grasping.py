"""The evaluation's grasp stage (the paper's Tables IV and V): grasps planned on each view's
completions, executed on its true mesh, and ranked by robustness over the CNN's sample completions.

For every view and each of the options' methods (:class:`GraspOptions`), up to ``n_grasps`` grasps
are planned on the completion (:func:`grasp.plan.plan`) and every one is executed on the
ground-truth mesh (:func:`grasp.execute.execute_grasps`, the paper's protocol, then the dynamic
lift test). Planning costs about the same on every mesh, so both of our meshes are evaluated; the
paper's one "Ours" is compared with Ours-detailed (:mod:`.tables`). With the options' ``robust``,
the grasps of our meshes are also ranked by the app's pick (:func:`grasp.pick.rank_grasps`: their
robustness over the CNN's sample completions of the view, which the completion stage saves, and
the wider search on the grasp envelope): the same grasps, executed once, so Table V's best grasp
compares the two rankings on the same completions. ``Ours-envelope`` is a mesh grasped but not
scored as a completion: the grasp envelope of those sample completions
(:func:`grasp.robust.envelope_mesh`), written beside the view's meshes when grasped.

Frames: floating views run without a table in the *evaluation world frame* :data:`T_WORLD_CAM`
(the body frame of a level camera at the origin, so that the lift test's gravity, -z, points down
the image); tabletop views in the table frame of the plane the segmentation found (z up, the table
at z = 0). Metres throughout; the saved meshes are in the camera frame.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
import traceback
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..fileio import atomic_write
from .records import (
    ENVELOPE,
    GRASP_MEANS,
    GRASP_TABLE_METHODS,
    envelope_file,
    grasp_file,
    grasp_rows,
    samples_file,
    view_stem,
)

if TYPE_CHECKING:  # imported lazily at run time: pybullet is heavy
    from ..grasp.pick import Pick
    from ..grasp.plan import PlanSettings

log = logging.getLogger(__name__)

# The evaluation world frame (see the module docstring): a level camera's body frame, camera at
# the origin. Rows map camera axes: world x = camera z (forward), y = -camera x, z = -camera y (up).
T_WORLD_CAM = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
GRASP_FRAME = (
    "evaluation world: level camera body frame, camera at the origin, x forward (camera z), "
    "y left (-camera x), z up (-camera y); no table"
)
TABLE_GRASP_FRAME = "table frame of the segmentation's support plane (z up, table at z = 0)"
# Every completion, the baselines and both of our meshes (see the docstring), and the grasp
# envelope of the CNN's sample completions (records.ENVELOPE).
GRASP_METHODS = GRASP_TABLE_METHODS
ROBUST_METHODS = ("Ours-fast", "Ours-detailed", ENVELOPE)  # the CNN's: they have sample completions


@dataclass(frozen=True)
class GraspOptions:
    """The grasp stage of :func:`.run.evaluate`: the ``methods`` grasped (completions, and ``Ours-envelope``,
    the grasp envelope of the CNN's sample completions), the ``hand``, grasps
    planned per view and method, the planner's wall-clock ``budget_seconds`` (None: its full
    deterministic search), its search sizes (``settings``; None: the planner's defaults), whether
    the grasps of :data:`ROBUST_METHODS` are also ranked by robustness (``robust``), and below
    which lift share of the most robust grasp on the samples as many grasps again are planned on
    the grasp envelope and ranked with them (``widen_below``; None: :data:`grasp.robust.WIDEN_BELOW`,
    0: never; not for the envelope's own grasps)."""

    methods: tuple[str, ...] = GRASP_METHODS
    hand: str = "barrett"
    n_grasps: int = 20
    budget_seconds: float | None = None
    settings: PlanSettings | None = None
    robust: bool = False
    widen_below: float | None = None

    def __post_init__(self) -> None:
        unknown = [m for m in self.methods if m not in GRASP_METHODS]
        if unknown or not self.methods:
            raise ValueError(f"grasp methods must be some of {', '.join(GRASP_METHODS)}; got {list(self.methods)}")
        if self.hand not in ("barrett", "panda"):
            raise ValueError(f"unknown hand {self.hand!r} (barrett or panda)")
        if self.n_grasps < 1:
            raise ValueError(f"n_grasps must be at least 1, got {self.n_grasps}")


def plan_seed(seed: int, name: str, view: int) -> int:
    """The planner's seed for a view: the same for every method, so that the methods differ only
    in the mesh they plan on."""
    return int(np.random.SeedSequence([seed, zlib.crc32(name.encode()), int(view), 13]).generate_state(1)[0])


def _world_mesh(path: Path, T_world_cam: np.ndarray):
    """A saved camera-frame mesh moved into a world frame (metres)."""
    import trimesh

    mesh = trimesh.load(path, force="mesh")
    mesh.apply_transform(T_world_cam)
    return mesh


def grasp_meshes(out_dir, record: dict, method: str):
    """``(completion, truth, T_world_cam, table)``: a view's ``method`` completion and its true mesh,
    read from ``out_dir`` and moved into the grasp world of :func:`grasp_world` (metres). On a
    table the true object is raised to stand on it: the estimated table may sit a few millimetres
    high, and the object must not start inside it."""
    out = Path(out_dir)
    T_world_cam, table = grasp_world(record)
    completion = _world_mesh(out / record["files"][method], T_world_cam)
    truth = _world_mesh(out / record["files"]["truth"], T_world_cam)
    if table:
        truth.apply_translation([0.0, 0.0, max(0.0, -float(truth.bounds[0, 2]))])
    return completion, truth, T_world_cam, table


def grasp_world(record: dict) -> tuple[np.ndarray, bool]:
    """``(T_world_cam, table)`` of a view's grasp stage: the table frame of the support plane the
    segmentation found (z up, the table at z = 0) with the table in the world, or, for a floating
    object, the evaluation world frame ``T_WORLD_CAM`` without a table."""
    if record.get("support_plane") is None:
        return T_WORLD_CAM, False
    from ..perception.segment import table_frame

    return table_frame(np.asarray(record["support_plane"], dtype=np.float64)), True


def grasp_means(rows: list[dict]) -> dict:
    """Means over one view's grasp rows (``GRASP_MEANS``; NaN without grasps) and
    ``lift_success_best``: whether the planner's best grasp (rank 0, the one a robot would
    execute) lifted the object; 0 when no grasp was found (a robot would have had nothing to try)."""
    derived = {
        "force_closure_planned": [float(r["epsilon_planned"] > 0) for r in rows],
        "force_closure_executed": [float(r["epsilon_executed"] > 0) for r in rows],
    }
    means = {
        k: (float(np.mean(derived[k] if k in derived else [r[k] for r in rows])) if rows else math.nan)
        for k in GRASP_MEANS
    }
    means["lift_success_best"] = float(rows[0]["lift_success"]) if rows else 0.0
    return means


def grasp_view(out_dir, record: dict, method: str, options: GraspOptions = GraspOptions()) -> dict:
    """Plan grasps on one view's ``method`` completion and execute each on its true mesh.

    Both meshes are read from ``out_dir`` (camera frame) and moved to the grasp world of
    :func:`grasp_world`. The grasps, planned and executed, go to ``grasp_file(...)`` with the frame
    in their ``meta`` (and, ranked by robustness, ``meta["robustness"]``: :func:`robust_entries`).
    The robust ranking is the app's pick (:func:`~shapeviewer.grasp.pick.rank_grasps`) on these
    grasps: when even the most robust grasp is weak (:func:`~shapeviewer.grasp.robust.is_weak`),
    as many grasps again are planned on the grasp envelope, scored over the same samples, ranked
    with the first and executed: they follow them in the file, ``meta["wider"]`` says from which
    index, and only the robust ranking sees them (the planner's best and the means over grasps are
    the completion's own).
    Returns the view's entry: ``{"method", "hand", "file", "n", "n_wider", <GRASP_MEANS means>,
    "lift_success_best", "robust", "lift_success_best_robust", "n_requested", "plan_seed",
    "seconds_plan", "seconds_execute", "seconds_robust", "frame", "error"}``: ``robust`` says whether
    the grasps were ranked by robustness (the options ask for it and ``method`` is one of
    :data:`ROBUST_METHODS`), ``lift_success_best_robust`` whether the grasp ranked first by it lifted
    the object (0 without grasps, NaN without the ranking). A failure (no mesh, planner error)
    records ``error`` and NaN means.
    """
    from ..grasp.execute import execute_grasps
    from ..grasp.pick import rank_grasps
    from ..grasp.plan import PlanSettings, plan
    from ..grasp.robust import WIDEN_BELOW
    from ..grasp.serialize import grasps_to_json

    out = Path(out_dir)
    name, view = record["object"], int(record["view"])
    seed = plan_seed(record["seed"], name, view)
    entry = {
        "method": method,
        "hand": options.hand,
        "file": "",
        "n": 0,
        "n_wider": 0,
        **grasp_means([]),
        "lift_success_best": math.nan,
        "robust": options.robust and method in ROBUST_METHODS,
        "lift_success_best_robust": math.nan,
        "n_requested": int(options.n_grasps),
        "plan_seed": seed,
        "seconds_plan": math.nan,
        "seconds_execute": math.nan,
        "seconds_robust": math.nan,
        "frame": "evaluation_world",
        "error": "",
    }
    # The envelope is made from the view's sample completions below, not read like a completion.
    missing = [k for k in ("truth",) + (() if method == ENVELOPE else (method,)) if k not in record["files"]]
    if missing:
        entry["error"] = f"no {' or '.join(missing)} mesh"
        return entry
    below = WIDEN_BELOW if options.widen_below is None else options.widen_below
    envelope_rel = envelope_file(view_stem(name, view))
    try:
        if method == ENVELOPE:
            record = {**record, "files": {**record["files"], ENVELOPE: write_envelope(out, record)}}
        completion, truth, T_world_cam, table = grasp_meshes(out, record, method)
        settings = options.settings or PlanSettings()
        t0 = time.perf_counter()
        result = plan(
            completion,
            hand=options.hand,
            n_grasps=options.n_grasps,
            seed=seed,
            table=table,
            budget_seconds=options.budget_seconds,
            settings=settings,
        )
        t1 = time.perf_counter()
        executions = execute_grasps(result.grasps, truth, table=table, lift=True)
        t2 = time.perf_counter()
        pick: Pick | None = None
        if entry["robust"]:
            samples = sample_completions(out / samples_file(view_stem(name, view)), T_world_cam)
            pick = rank_grasps(
                completion,
                samples,
                hand=options.hand,
                n_grasps=options.n_grasps,
                seed=seed,
                table=table,
                planned=result.grasps,
                widen=method != ENVELOPE,
                widen_below=below,
                envelope=lambda: _world_mesh(out / write_envelope(out, record), T_world_cam),
                settings=settings,
                budget_seconds=options.budget_seconds,
            )
            if pick.wider_from is not None:
                try:
                    executions = executions + execute_grasps(
                        pick.grasps[pick.wider_from :], truth, table=table, lift=True
                    )
                except Exception as e:  # the completion's own grasps stand
                    log.info("%s view %d: executing the wider search failed:\n%s", name, view, traceback.format_exc())
                    pick = pick.without_wider(f"{type(e).__name__}: {e}")
        t3 = time.perf_counter()
    except Exception as e:  # one mesh the planner cannot handle must not stop the run
        entry["error"] = f"{type(e).__name__}: {e}"
        log.info("%s view %d %s grasps failed:\n%s", name, view, method, traceback.format_exc())
        return entry
    grasps = list(result.grasps) if pick is None else list(pick.grasps)
    rel = grasp_file(view_stem(name, view), method, options.hand)
    meta = {
        "object": name,
        "view": view,
        "view_set": record["view_set"],
        "method": method,
        "frame": TABLE_GRASP_FRAME if table else GRASP_FRAME,
        "T_world_cam": T_world_cam.tolist(),
        "planned_on": record["files"][method],
        "executed_on": record["files"]["truth"],
        "table": table,
        "plan_seed": seed,
        "plan_stats": {
            "evaluations": result.stats.evaluations,
            "simulated": result.stats.simulated,
            "seconds": result.stats.seconds,
            "cancelled": result.stats.cancelled,
        },
    }
    robust = None if pick is None else robust_entries(pick)
    if robust is not None:
        meta["robustness"] = robust
    if pick is not None and pick.wider_from is not None:
        assert pick.wider_stats is not None  # the evaluation's wider search always plans
        meta["wider"] = {
            "planned_on": envelope_rel,
            "first": pick.wider_from,
            "below": below,
            "plan_stats": {"evaluations": pick.wider_stats.evaluations, "seconds": pick.wider_stats.seconds},
        }
    atomic_write(out / rel, grasps_to_json(grasps, executions, meta))
    base = {"object": name, "view": view, "view_set": record["view_set"], "method": method, "hand": options.hand}
    rows = grasp_rows(base, grasps, executions, robust, first_round=len(result.grasps))
    entry.update(
        file=rel,
        n=len(result.grasps),
        n_wider=len(grasps) - len(result.grasps),
        **grasp_means(rows[: len(result.grasps)]),
        seconds_plan=t1 - t0,
        seconds_execute=t2 - t1,
    )
    if robust is not None:
        # As for the planner's best grasp, a view without grasps counts as a failed lift.
        entry["lift_success_best_robust"] = next((r["lift_success"] for r in rows if r["robust_rank"] == 0), 0.0)
        entry["seconds_robust"] = t3 - t2
    return entry


def load_samples(path: Path):
    """A view's saved sample completions (:func:`records.samples_file`): ``(samples, frame, level)``,
    the (n, 40, 40, 40) probabilities, their :class:`~shapeviewer.completion.voxel.GridFrame` and the level the
    network's meshes are taken at (files written before it was saved: ``MESH_LEVEL``)."""
    from ..completion.reconstruct import MESH_LEVEL
    from ..completion.voxel import GridFrame

    with np.load(path) as saved:
        frame = GridFrame(saved["center"], float(saved["voxel_size"]))
        level = float(saved["mesh_level"]) if "mesh_level" in saved else MESH_LEVEL
        return saved["samples"], frame, level


def write_envelope(out_dir, record: dict) -> str:
    """Write a view's grasp envelope (:func:`grasp.robust.envelope_mesh` of its saved sample
    completions, camera frame) to ``out_dir`` and return its path there (:func:`records.envelope_file`).

    Raises:
        FileNotFoundError: the view has no saved sample completions.
        EmptyCompletionError: nothing in their mean answer is above the envelope's level.
    """
    from ..grasp.robust import envelope_mesh

    stem = view_stem(record["object"], int(record["view"]))
    samples, frame, _ = load_samples(Path(out_dir) / samples_file(stem))
    rel = envelope_file(stem)
    envelope_mesh(samples, frame, np.eye(4)).export(Path(out_dir) / rel)
    return rel


def sample_completions(samples: Path, T_world_cam: np.ndarray, *, hedge: float | None = None) -> list:
    """A view's sample completions (the file ``samples``, see :func:`records.samples_file`) meshed
    as the robust ranking meshes them (:func:`~shapeviewer.grasp.robust.sample_meshes`; ``hedge``
    None: its default) and moved to the grasp world by ``T_world_cam`` (metres)."""
    from ..grasp.robust import HEDGE, sample_meshes

    grids, frame, level = load_samples(samples)
    return sample_meshes(grids, frame, T_world_cam, level=level, hedge=HEDGE if hedge is None else hedge)


def robust_entries(pick: Pick) -> list[dict]:
    """Each grasp's robustness (:attr:`~shapeviewer.grasp.pick.Pick.robustness`) and its rank in the
    pick (0 first), as a grasp file's ``meta["robustness"]`` (:func:`records.grasp_rows`)."""
    rank = {i: k for k, i in enumerate(pick.order)}
    return [{"rank": rank[i], **dataclasses.asdict(s)} for i, s in enumerate(pick.robustness)]


def pending_grasps(record: dict, options: GraspOptions) -> list[str]:
    """Methods of ``options`` still to grasp on this view: no entry for (method, hand), one with an
    error (retried: it may have been a crash), or, when the options rank by robustness, one of
    :data:`ROBUST_METHODS` grasped without that ranking."""
    done = {
        (g["method"], g["hand"])
        for g in record.get("grasps", [])
        if not g["error"] and (g.get("robust", False) or not (options.robust and g["method"] in ROBUST_METHODS))
    }
    return [m for m in options.methods if (m, options.hand) not in done]
