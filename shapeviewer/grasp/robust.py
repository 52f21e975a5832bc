"""Grasps that survive the completion's uncertainty (issue 14): each planned grasp re-closed on
sample completions.

A completion is one guess at the side the camera never saw; the CNN's sample completions
(:meth:`~shapeviewer.model.Completer.predict_samples`, meshed one by one with
:func:`~shapeviewer.reconstruct.fast_mesh`) are other plausible guesses. :func:`robustness` re-closes
every planned grasp on every sample, and :func:`rank_robust` orders the grasps by how well they
survive: first the share of samples on which the grasp still has force closure, then a lower
quantile of its epsilon over the samples (after the planner's lift check, when it ran).

Frames and units: the grasps and every mesh are in one world frame, the planner's
(:mod:`~shapeviewer.grasp.plan`: the table top is z = 0, +z up, when there is a table); metres and
radians. Sample meshes come out of the CNN in the camera frame: move them with the same
``T_world_cam`` as the mesh the grasps were planned on.

A grasp on one sample follows the planner's own protocol (:func:`~shapeviewer.grasp.plan.approach_and_close`):
the hand at the grasp's palm pose with its preshape (the spread; the fingers open), backed off
``BACK_OFF`` along its approach, moved up to ``BACK_OFF + APPROACH_SLACK`` until contact, and closed
until every finger stops. Its epsilon on the sample is that of its contacts with the sample, about
the sample's own centre of mass and radius (:func:`~shapeviewer.grasp.plan.object_contacts`); the
grasp holds on the sample when that epsilon is positive.

Collision shapes: pybullet queries a static triangle mesh 10-100x slower than convex parts, and
V-HACD takes 0.1-3 s per mesh, more than the whole budget of 8 samples. But a sample differs from
the completion only where the network guesses, so each sample is cut along the planner's own V-HACD
parts of the mesh it planned on (cached by :func:`~shapeviewer.grasp.plan.plan`): every vertex of
the sample joins the part it lies nearest to, and the convex hull of each group is a part of the
sample, in about 10 ms. A sample identical to the planned-on mesh collides with that decomposition
itself, exactly as in the planner. (V-HACD's parts stand about a millimetre proud of the mesh; the
hulls of a sample's own vertices do not.)

Cost: about 10 ms per grasp and sample to re-close the hand and as much for its epsilon, so 20
grasps on 8 samples take about 3 s of CPU time (``benchmarks/robust.py``), shared by ``processes``.
Deterministic: nothing here is random (no seed to give); ``processes`` only shares out the samples.
In one process the work can report its progress and be cancelled between samples (the viewer's
"Rank by robustness" job); forked workers cannot call back.
"""

from __future__ import annotations

import multiprocessing as mp
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError, cKDTree

from shapeviewer.geometry import centre_of_mass
from shapeviewer.grasp.hands import get_hand
from shapeviewer.grasp.plan import APPROACH_SLACK, BACK_OFF, approach_and_close, object_contacts
from shapeviewer.grasp.quality import max_radius
from shapeviewer.grasp.search import CancelFn, ProgressFn
from shapeviewer.grasp.state import Grasp, LiftResult, lift_order
from shapeviewer.grasp.world import GraspWorld, convex_decomposition, mesh_hash
from shapeviewer.reconstruct import MESH_LEVEL, fast_mesh
from shapeviewer.voxel import GridFrame

ROBUST_QUANTILE = 0.25  # the robust score's pessimistic epsilon: the lower quartile over samples


class RobustnessCancelled(Exception):
    """:func:`robustness` stopped because its ``cancel`` returned True."""


@dataclass(frozen=True)
class Robustness:
    """How one grasp fares over the sample completions.

    ``epsilons``: its epsilon re-closed on each sample, in sample order (dimensionless, see
    :mod:`~shapeviewer.grasp.quality`; <= 0: no force closure). ``fraction``: the share of samples
    on which it holds (epsilon > 0). ``epsilon_low``: a lower quantile of ``epsilons`` (linear
    interpolation), what the grasp is worth on the worse samples.
    """

    fraction: float
    epsilon_low: float
    epsilons: tuple[float, ...]

    @classmethod
    def of(cls, epsilons: Sequence[float], quantile: float = ROBUST_QUANTILE) -> Robustness:
        """The robustness of a grasp with these ``epsilons`` over the samples, ``epsilon_low`` at
        ``quantile``."""
        e = np.asarray(epsilons, dtype=np.float64)
        return cls(float(np.mean(e > 0.0)), float(np.quantile(e, quantile)), tuple(map(float, e)))


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


def _sample_epsilons(
    grasps: Sequence[Grasp],
    samples: Sequence[tuple[int, trimesh.Trimesh]],
    parts: _Parts,
    table: bool,
    folder: str,
    progress: ProgressFn | None = None,
    cancel: CancelFn | None = None,
) -> dict[int, list[float]]:
    """Each grasp's epsilon on each of ``samples`` (index, mesh), in one world whose object is
    swapped per sample, cut into ``parts``; ``folder``: where the samples' parts are written.
    ``progress`` is told the share of samples done; ``cancel`` is asked before each sample."""
    hand = get_hand(grasps[0].hand)
    out: dict[int, list[float]] = {}
    with GraspWorld(hand, table=table) as world:
        for k, mesh in samples:
            if cancel is not None and cancel():
                raise RobustnessCancelled
            body = world.add_object(mesh, parts=parts.obj(mesh, Path(folder) / f"sample{k}.obj"))
            com = centre_of_mass(mesh)
            radius = max_radius(mesh.vertices, com)
            epsilons = []
            for g in grasps:
                _, _, closed = approach_and_close(
                    world, g.T_world_palm, [g.dofs[n] for n in hand.dof_names], max_approach=BACK_OFF + APPROACH_SLACK
                )
                assert closed is not None  # the default targets close once
                epsilons.append(object_contacts(closed, body, com, radius)[1].epsilon)
            world.remove_object(body)
            out[k] = epsilons
            if progress is not None:
                progress(len(out) / len(samples))
    return out


def robustness(
    grasps: Sequence[Grasp],
    samples_world: Sequence[trimesh.Trimesh],
    planned_on_world: trimesh.Trimesh,
    *,
    table: bool = True,
    quantile: float = ROBUST_QUANTILE,
    processes: int = 1,
    progress: ProgressFn | None = None,
    cancel: CancelFn | None = None,
) -> list[Robustness]:
    """Each grasp's :class:`Robustness` over the sample completions ``samples_world``.

    ``grasps``: planned grasps of one hand on ``planned_on_world``; every mesh and grasp in the
    planner's world frame (metres), standing on the table z = 0 when ``table``. ``quantile``: of
    epsilon over the samples, for :attr:`Robustness.epsilon_low`. ``processes``: forked workers
    that share the samples (each re-closes every grasp on its samples); 1 works in this process,
    which is right wherever other workers already fill the cores (the evaluation's).
    ``progress``: told the share of samples done (0..1); ``cancel``: asked before each sample.
    Both need ``processes`` = 1.

    Raises:
        DecompositionError: V-HACD of ``planned_on_world`` failed (it is cached by the planner,
            which needed it too, so it is normally not computed again here).
        RobustnessCancelled: ``cancel`` returned True.
    """
    if not samples_world or processes < 1:
        raise ValueError(f"robustness needs samples and processes; got {len(samples_world)} and {processes}")
    if processes > 1 and (progress is not None or cancel is not None):
        raise ValueError("progress and cancel need processes=1: forked workers cannot call back")
    if not grasps:
        return []
    if len({g.hand for g in grasps}) > 1:
        raise ValueError("robustness scores the grasps of one hand at a time")
    parts = _Parts(planned_on_world)
    indexed = list(enumerate(samples_world))
    with tempfile.TemporaryDirectory(prefix="shapeviewer-robust-") as folder:
        jobs = [(grasps, indexed[i::processes], parts, table, folder) for i in range(min(processes, len(indexed)))]
        if len(jobs) > 1:
            # Fork: the workers inherit the loaded modules (a spawned one would spend a second
            # importing them) and only pickle their epsilons back.
            with mp.get_context("fork").Pool(len(jobs)) as pool:
                results = pool.starmap(_sample_epsilons, jobs)
        else:
            results = [_sample_epsilons(*job, progress, cancel) for job in jobs]
    by_sample = {k: eps for result in results for k, eps in result.items()}
    epsilons = np.array([by_sample[k] for k in range(len(indexed))]).T  # grasps x samples
    return [Robustness.of(e, quantile) for e in epsilons]


def rank_robust(scores: Sequence[Robustness], lifts: Sequence[LiftResult | None] | None = None) -> list[int]:
    """Indices of the grasps ``scores`` belong to, most robust first: by the share of samples
    on which a grasp holds, then its low epsilon; ties keep the given (the planner's) order.

    ``lifts``: the planner's lift check of each grasp (:attr:`Grasp.lift`; None: not run). Given,
    the grasps that lifted the mesh come first, then those not checked, then those that dropped it,
    each group by robustness: a grasp that drops the completion in simulation is no one's best,
    however many samples it closes on."""
    order = [lift_order(None if lifts is None else lifts[i]) for i in range(len(scores))]
    return sorted(range(len(scores)), key=lambda i: (order[i], -scores[i].fraction, -scores[i].epsilon_low))


def sample_meshes(
    samples: np.ndarray, frame: GridFrame, T_world_cam: np.ndarray, *, level: float = MESH_LEVEL
) -> list[trimesh.Trimesh]:
    """The mesh of each sample completion ((n, 40, 40, 40) occupancy probabilities in the grid
    ``frame``; :meth:`~shapeviewer.model.Completer.predict_samples`) as the fast mesh is made
    (:func:`~shapeviewer.reconstruct.fast_mesh`), moved from the camera frame to the world frame
    by ``T_world_cam`` (metres).

    Raises:
        EmptyCompletionError: a sample has no occupied voxel.
    """
    return [fast_mesh(s, frame, level=level).apply_transform(T_world_cam) for s in samples]
