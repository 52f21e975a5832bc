"""Grasps that survive the completion's uncertainty: each planned grasp re-closed, and
the most robust lifted, on sample completions, with the palm where a robot might really put it.

A completion is one guess at the side the camera never saw; the CNN's sample completions
(:meth:`~shapeviewer.completion.model.Completer.predict_samples`, meshed one by one with
:func:`~shapeviewer.completion.reconstruct.fast_mesh`) are other plausible guesses. A robot's hand also never
lands exactly where it was sent: camera calibration and arm errors of a few millimetres and degrees
are common. So :func:`robustness` re-closes every planned grasp on every sample with its palm moved
by that sample's pose error (:func:`palm_perturbations`: none on sample 0, ``POSE_NOISE`` and
``ROTATION_NOISE`` standard deviations on the others), then lifts the ``LIFT_TOP`` most robust
grasps, so far, from their closed state on every sample in the dynamic lift test
(:func:`~shapeviewer.grasp.lift.lift_test`). The ``RECHECK_TOP`` most robust after that are lifted
on every sample once more, with new palm errors (``seed + 1``), and rank first, by their lift
share over both rounds: most views have several grasps that lift all 8 samples once, and one
round of 8 lifts cannot reliably tell a grasp that lifts 7 in 8 from one that lifts them all.
:func:`rank_robust` orders the grasps by how well they survive: after the planner's lift check,
those lifted in two rounds, then the share of samples the grasp lifts, then the share on which it
still has force closure, then a lower quantile of its epsilon over the samples.

:func:`envelope_mesh` is the mesh to plan on for this ranking: the samples' mean taken at a lower
level than a completion's surface, so that grasps wrap what the object may be where the network
hedges (a vessel's unseen wall, an occluded end), and the samples then choose among them.

When even the most robust grasp lifts fewer than ``WIDEN_BELOW`` (all) of its sample tests
(:func:`is_weak`), no grasp planned on the completion holds on everything the object may be (a
plate's rim, a banana's hidden end, a pitcher's far wall, a jar a few millimetres wider): the pick
(:func:`~shapeviewer.grasp.pick.rank_grasps`, which every caller goes through) then plans as many
grasps again on the grasp envelope, scores them over the same samples against the envelope, and
ranks both sets together. Views with a grasp that lifts every sample test (two in five on the
tabletop views) cost nothing more.

Why lift: the planner's ranking already puts the grasps that lift the completion first; the grasps
that then still fail on the true object mostly close without force closure on it. Whether a grasp
lifts the perturbed samples tells those apart from the good ones far better than whether it closes
on them (docs/studies/robust-ranking.md has the figures).

Frames and units: the grasps and every mesh are in one world frame, the planner's
(:mod:`~shapeviewer.grasp.plan`: the table top is z = 0, +z up, when there is a table); metres and
radians. Sample meshes come out of the CNN in the camera frame: move them with the same
``T_world_cam`` as the mesh the grasps were planned on.

A grasp on one sample follows the planner's own protocol (:func:`~shapeviewer.grasp.plan.approach_and_close`):
the hand at the grasp's palm pose (perturbed) with its preshape (the spread; the fingers open),
backed off ``BACK_OFF`` along its approach, moved up to ``BACK_OFF + APPROACH_SLACK`` until contact,
and closed until every finger stops. Its epsilon on the sample is that of its contacts with the
sample, about the sample's own centre of mass and radius (:func:`~shapeviewer.grasp.plan.object_contacts`);
the grasp holds on the sample when that epsilon is positive. The lift starts from that closed state.

Collision shapes: pybullet queries a static triangle mesh 10-100x slower than convex parts, and
V-HACD takes 0.1-3 s per mesh, more than the whole budget of 8 samples. But a sample differs from
the completion only where the network guesses, so each sample is cut along the planner's own V-HACD
parts of the mesh it planned on (cached by :func:`~shapeviewer.grasp.plan.plan`): every vertex of
the sample joins the part it lies nearest to, and the convex hull of each group is a part of the
sample, in about 10 ms. A sample identical to the planned-on mesh collides with that decomposition
itself, exactly as in the planner. (V-HACD's parts stand about a millimetre proud of the mesh; the
hulls of a sample's own vertices do not.) The lift test moves the sample as one body of those parts.

Cost: about 10 ms per grasp and sample to re-close the hand and as much for its epsilon, and 50 ms
per lift, so 20 grasps on 8 samples, the 3 best lifted and 2 of them again, take about 5 s of CPU
time (``benchmarks/robust.py``), shared by ``processes``. Deterministic: the pose errors come from
``seed`` (and ``seed + 1`` for the second round); ``processes`` only shares out the samples. In one
process the work can report its progress and be cancelled between samples (the viewer's "Rank by
robustness" job); forked workers cannot call back.
"""

from __future__ import annotations

import multiprocessing as mp
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError, cKDTree
from scipy.spatial.transform import Rotation

from shapeviewer.completion.reconstruct import MESH_LEVEL, fast_mesh
from shapeviewer.completion.voxel import GridFrame
from shapeviewer.errors import Cancelled
from shapeviewer.geometry import centre_of_mass
from shapeviewer.grasp.hands import get_hand
from shapeviewer.grasp.lift import lift_test
from shapeviewer.grasp.plan import APPROACH_SLACK, BACK_OFF, approach_and_close, hand_state
from shapeviewer.grasp.quality import max_radius
from shapeviewer.grasp.search import CancelFn, ProgressFn
from shapeviewer.grasp.state import Grasp, HandState, LiftResult, lift_order
from shapeviewer.grasp.world import GraspWorld, convex_decomposition, mesh_hash

ROBUST_QUANTILE = 0.25  # the robust score's pessimistic epsilon: the lower quartile over samples
POSE_NOISE = 0.005  # m: std of each axis of the palm's position error on a sample
ROTATION_NOISE = 3.0  # degrees: std of each axis of the palm's rotation error (a rotation vector)
LIFT_TOP = 3  # grasps lifted on every sample: the most robust by closure
RECHECK_TOP = 2  # of those, the most robust are lifted in a second round with new palm errors
LIFT_COST = 2.5  # a lift test takes about as long as this many closures
# The grasp envelope's level: the mean sample answer above this is what the network thinks may be
# there. A vessel's hedged cavity (0.3-0.5) reaches out to its unseen outer wall, an occluded end of
# an object is kept; the surface level (0.5) makes a blob inside the vessel instead.
ENVELOPE_LEVEL = 0.3
# Every other sample completion is meshed this far below the completion's level. A completion's
# errors are systematic, not random: the network rounds the corners it cannot see and stops short of
# an unseen end, so samples meshed at its level all share them. Meshed lower, a sample reaches out
# where the network hedges, as the true object often does; a grasp that lifts both kinds of sample
# holds on more true objects (docs/studies/robust-ranking.md
# has the figures).
HEDGE = 0.2
# A most robust grasp that lifted fewer than this share of its lift tests on the samples is not
# trusted, so as many grasps again are planned on the grasp envelope (:func:`envelope_mesh`) and the
# most robust of both is kept (:func:`is_weak`). All of them: on the tabletop views, a pick that
# lifted every sample test lifted the true object every time, one that lifted 80-95 % of them about
# nine times in ten (docs/studies/wider-search.md has the figures).
WIDEN_BELOW = 1.0


# :func:`robustness` stopped because its ``cancel`` returned True (the package's one cancellation error).


@dataclass(frozen=True)
class Robustness:
    """How one grasp fares over the sample completions.

    ``epsilons``: its epsilon re-closed on each sample, in sample order (dimensionless, see
    :mod:`~shapeviewer.grasp.quality`; <= 0: no force closure). ``fraction``: the share of samples
    on which it holds (epsilon > 0). ``epsilon_low``: a lower quantile of ``epsilons`` (linear
    interpolation), what the grasp is worth on the worse samples. ``lifted``: the share of its lift
    tests that lifted the sample, or None when it was not lifted (not among the ``LIFT_TOP``).
    ``lift_rounds``: how many times it was lifted on every sample (0, 1, or 2 for the
    ``RECHECK_TOP``), so ``len(epsilons) * lift_rounds`` lift tests.
    """

    fraction: float
    epsilon_low: float
    epsilons: tuple[float, ...]
    lifted: float | None = None
    lift_rounds: int = 0

    @property
    def lift_tests(self) -> int:
        """How many lift tests :attr:`lifted` is the share of: one per sample and round."""
        return len(self.epsilons) * self.lift_rounds

    @classmethod
    def of(
        cls,
        epsilons: Sequence[float],
        quantile: float = ROBUST_QUANTILE,
        lifted: float | None = None,
        lift_rounds: int | None = None,
    ) -> Robustness:
        """The robustness of a grasp with these ``epsilons`` over the samples, ``epsilon_low`` at
        ``quantile``, that ``lifted`` this share of its lift tests (None: not lifted) in
        ``lift_rounds`` rounds (None: one if lifted, else none)."""
        e = np.asarray(epsilons, dtype=np.float64)
        rounds = int(lifted is not None) if lift_rounds is None else lift_rounds
        return cls(float(np.mean(e > 0.0)), float(np.quantile(e, quantile)), tuple(map(float, e)), lifted, rounds)


def _read_parts(path: Path) -> list[np.ndarray]:
    """The vertex sets (K x 3 each) of the convex parts in an OBJ written by V-HACD (one ``o`` per part)."""
    parts: list[list[list[float]]] = []
    for line in path.read_text().splitlines():
        if line.startswith("o "):
            parts.append([])
        elif line.startswith("v ") and parts:
            parts[-1].append([float(v) for v in line.split()[1:4]])
    return [np.array(v) for v in parts if len(v) >= 4]


class _Parts:
    """The V-HACD parts of the mesh grasps were planned on (world frame), and samples cut like it.

    Each vertex of the planned-on mesh belongs to the part it lies nearest to (the smallest of a
    part's largest signed facet-plane distances: negative inside, about the distance outside); a
    sample's vertex joins the part of the planned-on vertex nearest to it. Measuring every vertex
    against every part's facets takes up to 0.1 s a mesh, so it is done once, for the planned-on
    mesh; a sample's lookup in a k-d tree takes a few milliseconds.
    """

    def __init__(self, planned_on: trimesh.Trimesh):
        self.hash = mesh_hash(planned_on)
        self.decomposition = convex_decomposition(planned_on)
        equations = [ConvexHull(v).equations for v in _read_parts(self.decomposition)]
        planes = np.vstack(equations)
        starts = np.cumsum([0] + [len(e) for e in equations[:-1]])
        reference = np.asarray(planned_on.vertices, float)
        # In chunks: all of a mesh's vertices against all facets at once would take hundreds of MB.
        self.labels = np.concatenate(
            [
                np.argmin(np.maximum.reduceat(chunk @ planes[:, :3].T + planes[:, 3], starts, axis=1), axis=1)
                for chunk in np.array_split(reference, max(1, len(reference) // 4096))
            ]
        )
        self.tree = cKDTree(reference)
        self.count = len(equations)

    def obj(self, mesh: trimesh.Trimesh, path: Path) -> Path:
        """An OBJ of convex parts of ``mesh`` (a sample, world frame): the planned-on mesh's own
        decomposition when ``mesh`` is that mesh, else each part's group of vertices' convex hull,
        written to ``path``."""
        if mesh_hash(mesh) == self.hash:
            return self.decomposition
        vertices = np.asarray(mesh.vertices, float)
        label = self.labels[self.tree.query(vertices)[1]]
        lines: list[str] = []
        offset = 1
        for k in range(self.count):
            points = vertices[label == k]
            try:
                hull = ConvexHull(points)
            except (QhullError, ValueError):  # fewer than 4 vertices, or flat: nothing a finger could stop on
                continue
            index = np.full(len(points), -1)
            index[hull.vertices] = np.arange(len(hull.vertices))
            lines.append(f"o part{k}")
            lines += [f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in points[hull.vertices]]
            lines += [f"f {a} {b} {c}" for a, b, c in index[hull.simplices] + offset]
            offset += len(hull.vertices)
        path.write_text("\n".join(lines) + "\n")
        return path


def palm_perturbations(
    n: int, *, translation: float = POSE_NOISE, rotation: float = ROTATION_NOISE, seed: int = 0
) -> np.ndarray:
    """``n`` palm pose errors (n x 4 x 4, see :func:`perturb_palm`): the first none, the others a
    rotation vector and an offset with ``rotation`` (degrees) and ``translation`` (m) standard
    deviations per axis, drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    out = np.tile(np.eye(4), (n, 1, 1))
    for k in range(1, n):
        out[k, :3, :3] = Rotation.from_rotvec(rng.normal(0.0, np.radians(rotation), 3)).as_matrix()
        out[k, :3, 3] = rng.normal(0.0, translation, 3)
    return out


def perturb_palm(T_world_palm: np.ndarray, error: np.ndarray) -> np.ndarray:
    """The palm pose ``T_world_palm`` (world frame) off by ``error``: turned by its rotation about
    the palm's origin, then moved by its offset (world axes, m)."""
    T = np.array(T_world_palm, dtype=np.float64)
    T[:3, :3] = error[:3, :3] @ T[:3, :3]
    T[:3, 3] += error[:3, 3]
    return T


@dataclass(frozen=True)
class _Sample:
    """One sample completion (world frame) as a worker sees it: its index, mesh and pose error."""

    index: int
    mesh: trimesh.Trimesh
    error: np.ndarray


@dataclass(frozen=True)
class _Closed:
    """The grasps re-closed on one sample: each grasp's epsilon and closed state there, and the
    OBJ of the sample's convex parts they collided with (the lifts reuse it)."""

    epsilons: list[float]
    states: list[HandState]
    parts: Path


def _close_on_samples(
    grasps: Sequence[Grasp],
    samples: Sequence[_Sample],
    parts: _Parts,
    table: bool,
    folder: str,
    progress: ProgressFn | None = None,
    cancel: CancelFn | None = None,
) -> dict[int, _Closed]:
    """Each grasp re-closed on each of ``samples`` with its pose error, in one world whose object
    is swapped per sample, cut into ``parts`` (written to ``folder``), by sample index.
    ``progress`` is told the share of samples done; ``cancel`` is asked before each sample."""
    hand = get_hand(grasps[0].hand)
    out: dict[int, _Closed] = {}
    with GraspWorld(hand, table=table) as world:
        for s in samples:
            if cancel is not None and cancel():
                raise Cancelled
            path = parts.obj(s.mesh, Path(folder) / f"sample{s.index}.obj")
            body = world.add_object(s.mesh, parts=path)
            com = centre_of_mass(s.mesh)
            radius = max_radius(s.mesh.vertices, com)
            states = []
            for g in grasps:
                _, _, closed = approach_and_close(
                    world,
                    perturb_palm(g.T_world_palm, s.error),
                    [g.dofs[n] for n in hand.dof_names],
                    max_approach=BACK_OFF + APPROACH_SLACK,
                )
                assert closed is not None  # the default targets close once
                states.append(hand_state(world, closed, body, com, radius))
            world.remove_object(body)
            out[s.index] = _Closed([h.epsilon for h in states], states, path)
            if progress is not None:
                progress(len(out) / len(samples))
    return out


def _lift_on_samples(
    work: dict[int, tuple[trimesh.Trimesh, Path, list[HandState]]],
    table: bool,
    progress: ProgressFn | None = None,
    cancel: CancelFn | None = None,
) -> dict[int, list[bool]]:
    """The lift test of closed states on their sample: ``work`` maps a sample index to its mesh,
    the OBJ of its convex parts (it moves as one body of them) and the states."""
    out: dict[int, list[bool]] = {}
    for k, (mesh, parts, states) in work.items():
        if cancel is not None and cancel():
            raise Cancelled
        out[k] = [lift_test(h, mesh, table=table, parts=parts).success for h in states]
        if progress is not None:
            progress(len(out) / len(work))
    return out


def _shared(function, jobs: list[tuple], progress: ProgressFn | None, cancel: CancelFn | None) -> dict:
    """``function`` run on each of ``jobs`` (argument tuples), in forked workers when there are
    several, with ``progress`` and ``cancel`` in this process otherwise; their dicts merged."""
    if len(jobs) > 1:
        # Fork: the workers inherit the loaded modules (a spawned one would spend a second
        # importing them) and only pickle their results back.
        with mp.get_context("fork").Pool(len(jobs)) as pool:
            results = pool.starmap(function, jobs)
    else:
        results = [function(*job, progress, cancel) for job in jobs]
    return {k: v for result in results for k, v in result.items()}


def robustness(
    grasps: Sequence[Grasp],
    samples_world: Sequence[trimesh.Trimesh],
    planned_on_world: trimesh.Trimesh,
    *,
    table: bool = True,
    quantile: float = ROBUST_QUANTILE,
    pose_noise: float = POSE_NOISE,
    rotation_noise: float = ROTATION_NOISE,
    lift_top: int = LIFT_TOP,
    recheck_top: int = RECHECK_TOP,
    seed: int = 0,
    processes: int = 1,
    progress: ProgressFn | None = None,
    cancel: CancelFn | None = None,
) -> list[Robustness]:
    """Each grasp's :class:`Robustness` over the sample completions ``samples_world``.

    ``grasps``: planned grasps of one hand on ``planned_on_world``; every mesh and grasp in the
    planner's world frame (metres), standing on the table z = 0 when ``table``. ``quantile``: of
    epsilon over the samples, for :attr:`Robustness.epsilon_low`. ``pose_noise`` (m) and
    ``rotation_noise`` (degrees): standard deviations of the palm's error on every sample but the
    first (:func:`palm_perturbations`, from ``seed``; 0 and 0: the planned pose). ``lift_top``:
    how many grasps, the most robust by closure (:func:`rank_robust`), are then lifted on every
    sample (0: none). ``recheck_top``: how many of those, the most robust after the lifts, are
    re-closed and lifted on every sample once more with new palm errors (from ``seed + 1``).
    ``processes``: forked workers that share the samples; 1 works in this process, which is right
    wherever other workers already fill the cores (the evaluation's). ``progress``: told the share
    of the work done (0..1); ``cancel``: asked before each sample. Both need ``processes`` = 1.

    Raises:
        DecompositionError: V-HACD of ``planned_on_world`` failed (it is cached by the planner,
            which needed it too, so it is normally not computed again here).
        Cancelled: ``cancel`` returned True.
    """
    if not samples_world or processes < 1 or lift_top < 0 or recheck_top < 0:
        raise ValueError(
            "robustness needs samples, processes and lift_top, recheck_top >= 0; got "
            f"{len(samples_world)}, {processes}, {lift_top}, {recheck_top}"
        )
    if processes > 1 and (progress is not None or cancel is not None):
        raise ValueError("progress and cancel need processes=1: forked workers cannot call back")
    if not grasps:
        return []
    if len({g.hand for g in grasps}) > 1:
        raise ValueError("robustness scores the grasps of one hand at a time")
    parts = _Parts(planned_on_world)
    n = len(samples_world)
    planned = [g.lift for g in grasps]
    lifted = min(lift_top, len(grasps))
    rechecked = min(recheck_top, lifted)
    # Shares of the work for progress: a lift test costs about LIFT_COST closures.
    work = np.cumsum([0.0, len(grasps), LIFT_COST * lifted, rechecked, LIFT_COST * rechecked])

    def stage(k: int) -> ProgressFn | None:
        if progress is None:
            return None
        return lambda share: progress((work[k] + share * (work[k + 1] - work[k])) / work[-1])

    def round_of(offset: int, round_seed: int) -> list[list[_Sample]]:
        """Every sample with a palm error from ``round_seed``, numbered from ``offset``, shared out."""
        errors = palm_perturbations(n, translation=pose_noise, rotation=rotation_noise, seed=round_seed)
        samples = [_Sample(offset + k, m, e) for k, (m, e) in enumerate(zip(samples_world, errors))]
        return [samples[i::processes] for i in range(min(processes, n))]

    def lift_closed(
        closed: dict[int, _Closed], shares: list[list[_Sample]], which: list[int], k: int
    ) -> list[list[bool]]:
        """The lift tests of closed states ``which`` (indices into each sample's states) on every
        sample: per listed state, one per sample."""
        jobs = [
            (
                {s.index: (s.mesh, closed[s.index].parts, [closed[s.index].states[i] for i in which]) for s in share},
                table,
            )
            for share in shares
        ]
        lifts = _shared(_lift_on_samples, jobs, stage(k), cancel)
        return [[lifts[s][j] for s in sorted(lifts)] for j in range(len(which))]

    with tempfile.TemporaryDirectory(prefix="shapeviewer-robust-") as folder:
        shares = round_of(0, seed)
        closed = _shared(
            _close_on_samples, [(grasps, share, parts, table, folder) for share in shares], stage(0), cancel
        )
        epsilons = np.array([closed[k].epsilons for k in range(n)]).T  # grasps x samples
        closure = [Robustness.of(e, quantile) for e in epsilons]
        if not lifted:
            return closure

        def with_lifts(tests: dict[int, list[bool]]) -> list[Robustness]:
            return [
                s if i not in tests else replace(s, lifted=float(np.mean(tests[i])), lift_rounds=len(tests[i]) // n)
                for i, s in enumerate(closure)
            ]

        top = rank_robust(closure, planned)[:lifted]
        tests = dict(zip(top, lift_closed(closed, shares, top, 1)))
        again = rank_robust(with_lifts(tests), planned)[:rechecked]
        if again:
            shares = round_of(n, seed + 1)
            closed = _shared(
                _close_on_samples,
                [([grasps[i] for i in again], share, parts, table, folder) for share in shares],
                stage(2),
                cancel,
            )
            for i, more in zip(again, lift_closed(closed, shares, list(range(len(again))), 3)):
                tests[i] = tests[i] + more
    return with_lifts(tests)


def rank_robust(scores: Sequence[Robustness], lifts: Sequence[LiftResult | None] | None = None) -> list[int]:
    """Indices of the grasps ``scores`` belong to, most robust first: those lifted in more rounds
    first (:attr:`Robustness.lift_rounds`), then by the share of lift tests that lifted the sample
    (those not lifted last), then the share of samples on which it holds, then its low epsilon;
    ties keep the given (the planner's) order.

    ``lifts``: the planner's lift check of each grasp (:attr:`Grasp.lift`; None: not run). Given,
    the grasps that lifted the mesh come first, then those not checked, then those that dropped it,
    each group by robustness: a grasp that drops the completion in simulation is no one's best,
    however many samples it closes on."""
    order = [lift_order(None if lifts is None else lifts[i]) for i in range(len(scores))]

    def key(i: int) -> tuple:
        s = scores[i]
        return (order[i], -s.lift_rounds, 1.0 if s.lifted is None else -s.lifted, -s.fraction, -s.epsilon_low)

    return sorted(range(len(scores)), key=key)


def is_weak(
    scores: Sequence[Robustness], lifts: Sequence[LiftResult | None] | None = None, *, below: float = WIDEN_BELOW
) -> bool:
    """Whether the most robust of the grasps ``scores`` belong to (:func:`rank_robust`, after the
    planner's ``lifts``) lifted fewer than ``below`` of its lift tests on the sample completions,
    was never lifted on them, or there is no grasp at all: then a wider search is worth its cost.
    ``below`` <= 0: never (the wider search is off)."""
    if below <= 0:
        return False
    if not scores:
        return True
    best = scores[rank_robust(scores, lifts)[0]]
    return best.lifted is None or best.lifted < below


def envelope_mesh(
    samples: np.ndarray, frame: GridFrame, T_world_cam: np.ndarray, *, level: float = ENVELOPE_LEVEL
) -> trimesh.Trimesh:
    """The grasp envelope of sample completions ((n, 40, 40, 40) occupancy probabilities in the grid
    ``frame``): the fast mesh of their mean at p = ``level``, moved from the camera frame to the
    world frame by ``T_world_cam`` (metres). Planned on, it gives grasps that wrap what the object
    may be, which the ranking over the samples (:func:`robustness`) then checks; on the tabletop
    views that beat grasps planned on the completion itself (docs/studies/wider-search.md).

    Raises:
        EmptyCompletionError: nothing in the mean answer is above ``level``.
    """
    return fast_mesh(np.mean(samples, axis=0), frame, level=level).apply_transform(T_world_cam)


def sample_meshes(
    samples: np.ndarray,
    frame: GridFrame,
    T_world_cam: np.ndarray,
    *,
    level: float = MESH_LEVEL,
    hedge: float = HEDGE,
) -> list[trimesh.Trimesh]:
    """The mesh of each sample completion ((n, 40, 40, 40) occupancy probabilities in the grid
    ``frame``; :meth:`~shapeviewer.completion.model.Completer.predict_samples`) as the fast mesh is made
    (:func:`~shapeviewer.completion.reconstruct.fast_mesh`), moved from the camera frame to the world frame
    by ``T_world_cam`` (metres). Samples 0, 2, 4... are meshed at ``level``, samples 1, 3, 5... at
    ``level - hedge`` (:data:`HEDGE`: where the network is unsure, they reach further out).

    Raises:
        EmptyCompletionError: a sample has no occupied voxel.
    """
    levels = (level, level - hedge)
    return [fast_mesh(s, frame, level=levels[k % 2]).apply_transform(T_world_cam) for k, s in enumerate(samples)]
