"""The pick: the grasp a robot would execute, chosen by how well it survives the completion's
uncertainty. Every caller (the public API :func:`robust_grasps`, the evaluation's robust ranking,
the viewer's "Rank by robustness", the benchmarks) picks through :func:`rank_grasps`.

The steps, all in the planner's world frame (:mod:`~shapeviewer.grasp.plan`: the table top is
z = 0, +z up, when there is a table; metres and radians):

1. plan grasps on the completion (:func:`~shapeviewer.grasp.plan.plan`), or take those already planned;
2. score each over the CNN's sample completions (:func:`~shapeviewer.grasp.robust.robustness`:
   re-closed with palm errors, the most robust lifted) and rank them
   (:func:`~shapeviewer.grasp.robust.rank_robust`);
3. the wider search: when even the most robust grasp lifted fewer than ``widen_below`` of its
   sample tests (:func:`~shapeviewer.grasp.robust.is_weak`), no grasp planned on the completion
   holds on everything the object may be (a plate's rim, a banana's hidden end, a pitcher's far
   wall, a jar a few millimetres wider). As many grasps again are then planned on the grasp
   envelope (:func:`~shapeviewer.grasp.robust.envelope_mesh`), scored over the same samples against
   the envelope, and both sets are ranked together. Views with a grasp that lifts every sample
   test (two in five on the tabletop views) cost nothing more.

Deterministic: the same grasps, samples and seeds give the same :class:`Pick`. ``seed`` is the
planner's (both plans use it); the palm errors on the samples come from ``noise_seed``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
import trimesh

from shapeviewer.errors import Cancelled
from shapeviewer.grasp.plan import PlanResult, PlanStats, plan
from shapeviewer.grasp.robust import (
    LIFT_TOP,
    RECHECK_TOP,
    WIDEN_BELOW,
    Robustness,
    is_weak,
    rank_robust,
    robustness,
)
from shapeviewer.grasp.search import CancelFn, PlanSettings, ProgressFn
from shapeviewer.grasp.state import Grasp

log = logging.getLogger(__name__)

HandName = Literal["barrett", "panda"]
CompletionMode = Literal["fast", "detailed"]
# How rank_grasps calls its heavy stages: ``runner(fn, *args, progress=..., cancel=..., **kwargs)``
# returns ``fn(*args, progress=..., cancel=..., **kwargs)``, computed wherever the caller likes.
Runner = Callable[..., Any]
# The grasp envelope (world frame), or a function that makes it when the wider search needs it.
EnvelopeSource = trimesh.Trimesh | Callable[[], trimesh.Trimesh]


@dataclass(frozen=True, eq=False)
class Pick:
    """Grasps ranked by robustness over the sample completions: what :func:`rank_grasps` and
    :func:`robust_grasps` return.

    Attributes:
        grasps: every grasp (world frame), in the planner's order: those of the completion first,
            then those of the wider search on the grasp envelope.
        order: indices into ``grasps``, most robust first (:func:`~shapeviewer.grasp.robust.rank_robust`
            after each grasp's lift check on the mesh it was planned on).
        robustness: each grasp's :class:`~shapeviewer.grasp.robust.Robustness`, aligned with ``grasps``.
        wider_from: the index in ``grasps`` where the wider search's grasps start (``len(grasps)``
            when it found none); None when it did not run.
        seconds: wall-clock seconds per stage: ``"plan"`` (0 when the grasps were given),
            ``"rank"`` (scoring them) and ``"wider"`` (planning and scoring on the envelope; 0
            when it did not run).
        plan_stats: what planning on the completion did (None when the grasps were given).
        wider_stats: what planning on the envelope did (None when it did not plan).
        wider_error: why the wider search failed, when it did (the completion's grasps are then
            ranked alone).
        T_world_cam: 4x4, camera optical frame -> world frame (metres), when the pick knows the
            camera (:func:`robust_grasps`).
        mesh_world: the completion the first grasps were planned on (world frame, metres), when
            the pick made it (:func:`robust_grasps`).
    """

    grasps: tuple[Grasp, ...]
    order: tuple[int, ...]
    robustness: tuple[Robustness, ...]
    wider_from: int | None = None
    seconds: Mapping[str, float] = field(default_factory=lambda: {"plan": 0.0, "rank": 0.0, "wider": 0.0})
    plan_stats: PlanStats | None = None
    wider_stats: PlanStats | None = None
    wider_error: str | None = None
    T_world_cam: np.ndarray | None = None
    mesh_world: trimesh.Trimesh | None = None

    @property
    def best(self) -> Grasp | None:
        """The most robust grasp (world frame), the one a robot would execute; None without grasps."""
        return self.grasps[self.order[0]] if self.order else None

    @property
    def ranked(self) -> list[Grasp]:
        """The grasps most robust first."""
        return [self.grasps[i] for i in self.order]

    @property
    def first(self) -> int:
        """How many grasps were planned on the completion (those before the wider search's)."""
        return len(self.grasps) if self.wider_from is None else self.wider_from

    def without_wider(self, reason: str) -> Pick:
        """This pick with the completion's grasps only, ranked alone: the wider search's grasps
        dropped because of ``reason`` (kept as :attr:`wider_error`)."""
        n = self.first
        grasps, scores = self.grasps[:n], self.robustness[:n]
        order = tuple(rank_robust(scores, [g.lift for g in grasps]))
        return replace(
            self, grasps=grasps, order=order, robustness=scores, wider_from=None, wider_stats=None, wider_error=reason
        )


def _direct(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """The default :data:`Runner`: ``fn`` called here."""
    return fn(*args, **kwargs)


def rank_grasps(
    mesh_world: trimesh.Trimesh,
    samples_world: Sequence[trimesh.Trimesh],
    *,
    hand: str,
    n_grasps: int = 20,
    seed: int = 0,
    table: bool = True,
    planned: Sequence[Grasp] | None = None,
    wider: Sequence[Grasp] | None = None,
    widen: bool = True,
    widen_below: float = WIDEN_BELOW,
    envelope: EnvelopeSource | None = None,
    settings: PlanSettings | None = None,
    budget_seconds: float | None = None,
    lift_top: int = LIFT_TOP,
    recheck_top: int = RECHECK_TOP,
    noise_seed: int = 0,
    processes: int = 1,
    runner: Runner | None = None,
    progress: ProgressFn | None = None,
    cancel: CancelFn | None = None,
) -> Pick:
    """Plan grasps on ``mesh_world``, rank them by robustness over ``samples_world`` and, when even
    the most robust is weak, widen the search to the grasp envelope (see the module docstring).

    Args:
        mesh_world: the completion (world frame, metres; standing on the table z = 0 when ``table``).
        samples_world: the meshes of its sample completions, in the same frame
            (:func:`~shapeviewer.grasp.robust.sample_meshes`).
        hand: the hand's name (:data:`~shapeviewer.grasp.hands.HAND_NAMES`).
        n_grasps: grasps planned on ``mesh_world`` and, in the wider search, on the envelope.
        seed: the planner's seed (both plans).
        table: whether the world has the table plane z = 0 (planning and scoring).
        planned: grasps of ``hand`` already planned on ``mesh_world`` (world frame): they are
            ranked instead of planning.
        wider: grasps already planned on ``envelope`` by an earlier wider search: scored again
            instead of planning when the search widens.
        widen: whether the search may widen at all (False for grasps planned on the envelope itself).
        widen_below: the lift share of its sample tests below which the most robust grasp is weak
            (:func:`~shapeviewer.grasp.robust.is_weak`; 0: never widen).
        envelope: the grasp envelope (world frame, metres), or a function that makes it, called
            only when the search widens. Needed when ``widen`` and ``widen_below`` > 0.
        settings: the planner's search sizes (None: its defaults).
        budget_seconds: each plan's wall-clock limit (None: the full, deterministic search).
        lift_top, recheck_top: grasps lifted on every sample, and of those lifted again
            (:func:`~shapeviewer.grasp.robust.robustness`).
        noise_seed: the seed of the palm errors on the samples (``robustness``'s ``seed``).
        processes: forked workers that share the samples (``robustness``); 1 works here.
        runner: how the heavy stages (planning, scoring) are called, ``runner(fn, *args,
            progress=..., cancel=..., **kwargs)``; None calls them here. The viewer's computes
            them in its worker processes.
        progress: told the share of the work done, 0..1.
        cancel: asked between and during the stages; True stops with :class:`~shapeviewer.errors.Cancelled`.

    Raises:
        Cancelled: ``cancel`` returned True.
        ValueError: the search may widen but there is no ``envelope``; ``planned`` grasps of
            another hand.
        DecompositionError: planning on (or scoring against) ``mesh_world`` failed. A failing
            wider search does not raise: the completion's grasps are ranked alone and
            :attr:`Pick.wider_error` says why.
    """
    if widen and widen_below > 0 and envelope is None:
        raise ValueError("the wider search needs the grasp envelope: give envelope, or widen=False")
    if planned is not None and any(g.hand != hand for g in planned):
        raise ValueError(f"the planned grasps are not all {hand} grasps")
    run = runner or _direct
    stopped = cancel or (lambda: False)
    # Shares of the work for progress, the wider search counted as if it ran (planning and scoring
    # a set cost about the same): each stage's [start, end) of the whole.
    may_widen = widen and widen_below > 0
    weights = {"plan": planned is None, "rank": True, "wider plan": may_widen and wider is None, "wider": may_widen}
    ends = dict(zip(weights, np.cumsum(list(weights.values())) / sum(weights.values())))
    starts = dict(zip(weights, [0.0, *list(ends.values())[:-1]]))

    def stage(name: str) -> ProgressFn | None:
        if progress is None:
            return None
        return lambda share: progress(float(starts[name] + share * (ends[name] - starts[name])))

    def check() -> None:
        if stopped():
            raise Cancelled

    def plan_on(mesh: trimesh.Trimesh, step: str) -> PlanResult:
        result = run(
            plan,
            mesh,
            hand=hand,
            n_grasps=n_grasps,
            seed=seed,
            table=table,
            budget_seconds=budget_seconds,
            settings=settings or PlanSettings(),
            progress=stage(step),
            cancel=cancel,
        )
        if result.stats.cancelled:
            raise Cancelled
        check()
        return result

    def score(grasps: Sequence[Grasp], mesh: trimesh.Trimesh, step: str) -> list[Robustness]:
        if not grasps:
            return []
        try:
            return run(
                robustness,
                list(grasps),
                list(samples_world),
                mesh,
                table=table,
                lift_top=lift_top,
                recheck_top=recheck_top,
                seed=noise_seed,
                processes=processes,
                progress=stage(step),
                cancel=cancel,
            )
        except Cancelled:
            raise

    seconds = {"plan": 0.0, "rank": 0.0, "wider": 0.0}
    check()
    t0 = time.perf_counter()
    plan_stats: PlanStats | None = None
    if planned is None:
        result = plan_on(mesh_world, "plan")
        first, plan_stats = list(result.grasps), result.stats
    else:
        first = list(planned)
    t1 = time.perf_counter()
    scores = score(first, mesh_world, "rank")
    check()
    t2 = time.perf_counter()
    seconds.update(plan=t1 - t0, rank=t2 - t1)
    grasps = first
    wider_from: int | None = None
    wider_stats: PlanStats | None = None
    wider_error: str | None = None
    if widen and is_weak(scores, [g.lift for g in first], below=widen_below):
        try:
            assert envelope is not None  # checked above
            envelope_world = envelope() if callable(envelope) else envelope
            if wider is None:
                result = plan_on(envelope_world, "wider plan")
                more, wider_stats = list(result.grasps), result.stats
            else:
                more = list(wider)
            more_scores = score(more, envelope_world, "wider")
        except Cancelled:  # a cancelled pick stops; only a failed wider search lets the first grasps stand
            raise
        except Exception as e:  # the completion's own grasps stand
            log.info("the wider search failed; the completion's grasps are ranked alone", exc_info=True)
            wider_error = f"{type(e).__name__}: {e}"
            wider_stats = None
        else:
            grasps, scores, wider_from = first + more, scores + more_scores, len(first)
        seconds["wider"] = time.perf_counter() - t2
    order = rank_robust(scores, [g.lift for g in grasps])
    if progress is not None:
        progress(1.0)
    return Pick(
        tuple(grasps),
        tuple(order),
        tuple(scores),
        wider_from,
        seconds,
        plan_stats=plan_stats,
        wider_stats=wider_stats,
        wider_error=wider_error,
    )


def robust_grasps(
    points_cam: np.ndarray,
    *,
    support_plane: np.ndarray,
    hand: HandName = "barrett",
    n_grasps: int = 20,
    mode: CompletionMode = "detailed",
    seed: int = 0,
    completer: Any = None,
    widen: bool = True,
    progress: ProgressFn | None = None,
    cancel: CancelFn | None = None,
) -> Pick:
    """Grasps for one object seen on a table, most robust first: the app's pick end to end.

    The object's points are completed as :func:`shapeviewer.complete` completes them (cut as the
    app's segmentation would, then the CNN and its 8 sample completions, then the ``mode`` mesh);
    the completion and its samples are moved to the table frame of ``support_plane`` and picked
    from by :func:`rank_grasps` (planning ``n_grasps`` grasps on the completion, ranking them over
    the samples, and with ``widen`` the wider search on the grasp envelope).

    Args:
        points_cam: (N, 3) the object's observed points, camera optical frame (x right, y down,
            z forward), metres; non-finite rows are ignored.
        support_plane: ``(a, b, c, d)`` of the table in the camera frame, ``a x + b y + c z + d = 0``
            (metres), e.g. a segmentation's ``plane_cam``.
        hand: ``"barrett"`` (BH8-280) or ``"panda"`` (Franka).
        n_grasps: grasps planned on the completion (and as many on the envelope when widening).
        mode: the completion mesh planned on: ``"fast"`` (marching cubes of the CNN output) or
            ``"detailed"`` (Algorithm 1).
        seed: the planner's seed; the same points and seed give the same pick.
        completer: the network (default: the shipped model, loaded once and kept).
        widen: allow the wider search on the grasp envelope when no grasp holds up on the samples.
        progress: told the share of the grasp work done, 0..1.
        cancel: asked often; True stops with :class:`~shapeviewer.errors.Cancelled`.

    Returns:
        A :class:`Pick` in the world frame: the table top is z = 0 and +z up (metres), its x axis
        along the camera's x (:func:`~shapeviewer.perception.segment.table_frame`). ``pick.best``
        is the grasp to execute (its ``T_world_palm``, 4x4); ``pick.T_world_cam`` (4x4) maps
        camera-frame points to the world frame and ``pick.mesh_world`` is the completion planned on.

    Raises:
        SegmentTooSmallError: too few points or too small an object to place a grid on.
        EmptyCompletionError: the network completed nothing.
        Cancelled: ``cancel`` returned True.
        ValueError: an unknown ``hand`` or ``mode``, or a malformed ``support_plane``.
    """
    from shapeviewer.completion.pipeline import complete_with_samples
    from shapeviewer.completion.voxel import unit_plane
    from shapeviewer.grasp.hands import HAND_NAMES
    from shapeviewer.grasp.robust import envelope_mesh, sample_meshes
    from shapeviewer.perception.segment import table_frame

    if hand not in HAND_NAMES:
        raise ValueError(f"unknown hand {hand!r}; choose one of {HAND_NAMES}")
    if mode not in ("fast", "detailed"):
        raise ValueError(f"mode must be 'fast' or 'detailed', got {mode!r}")
    normal, d = unit_plane(support_plane)
    plane = np.append(normal, d)
    c, mesh_cam = complete_with_samples(points_cam, support_plane=plane, mode=mode, completer=completer)
    T_world_cam = table_frame(plane)
    mesh_world = mesh_cam.copy().apply_transform(T_world_cam)
    samples_world = sample_meshes(c.samples, c.frame, T_world_cam, level=c.mesh_level)
    pick = rank_grasps(
        mesh_world,
        samples_world,
        hand=hand,
        n_grasps=n_grasps,
        seed=seed,
        table=True,
        widen=widen,
        envelope=lambda: envelope_mesh(c.samples, c.frame, T_world_cam),
        progress=progress,
        cancel=cancel,
    )
    return replace(pick, T_world_cam=T_world_cam, mesh_world=mesh_world)
