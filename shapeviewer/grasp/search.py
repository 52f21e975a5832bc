"""The cheap stage of grasp planning: a search without physics (stage 1 of :mod:`shapeviewer.grasp.plan`).

A candidate is a palm orientation ``R`` (world frame; its approach ``R[:, 2]`` never points up when
there is a table), an aim point (world frame, metres) its approach line passes through, and a
preshape (an index into :attr:`HandSamples.preshapes`). :func:`search` scores random candidates,
then refines the best distinct ones by simulated annealing (parallel chains, one vectorised
evaluation per step); the score is GraspIt's contact energy (m) of the hand's virtual contacts
after the approach and the closing, both computed from precomputed samples
(:mod:`~shapeviewer.grasp.samples`) against the object's field (:mod:`~shapeviewer.grasp.object_field`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from shapeviewer.grasp.object_field import APPROACH_MARGIN, ObjectField
from shapeviewer.grasp.samples import HandSamples
from shapeviewer.runtime.progress import CancelCheck, Progress

DISTINCT_POSITION = 0.01  # m: grasps closer than this in palm position ...
DISTINCT_ANGLE = math.radians(15.0)  # ... and in palm orientation are the same grasp
TABLE_CLEARANCE = 0.003  # m: the open hand must stay this far above the table
BATCH = 256  # candidates per vectorised evaluation

ProgressFn = Progress  # the package's progress callback (fraction done, 0..1)
CancelFn = CancelCheck


@dataclass
class Candidates:
    """A batch of cheap-stage states and their evaluation (world frame).

    ``R`` (N x 3 x 3) palm orientations, ``aim`` (N x 3) points on the approach lines, ``shape``
    (N,) preshape indices, ``palm`` (N x 3) palm positions at first contact and ``energy`` (N,)
    (inf: the hand misses the object, meets the table, or approaches from below it).
    """

    R: np.ndarray
    aim: np.ndarray
    shape: np.ndarray
    palm: np.ndarray
    energy: np.ndarray

    def take(self, idx) -> Candidates:
        return Candidates(self.R[idx], self.aim[idx], self.shape[idx], self.palm[idx], self.energy[idx])

    @staticmethod
    def concat(parts: Sequence[Candidates]) -> Candidates:
        return Candidates(
            *(np.concatenate([getattr(part, k) for part in parts]) for k in ("R", "aim", "shape", "palm", "energy"))
        )


def _evaluate(
    obj: ObjectField,
    hs: HandSamples,
    R: np.ndarray,
    aim: np.ndarray,
    shape: np.ndarray,
    table: bool,
    start_distance: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Palm positions (N x 3) and energies (N,) of candidates (see :mod:`shapeviewer.grasp.plan`)."""
    n = len(R)
    d = R[:, :, 2]
    start = aim - start_distance * d
    Rt = np.transpose(R, (0, 2, 1))
    Rt32 = Rt.astype(np.float32)
    front = hs.approach_pts[shape] @ Rt32 + start[:, None, :].astype(np.float32)
    travel = obj.offset_ray_hits(front, d[:, None, :]).min(axis=1)
    ok = np.isfinite(travel)
    # From the offset surface the hand has at least the margin left to go; stop a contact
    # tolerance short of that, as the pybullet approach stops short of contact.
    palm = start + np.where(ok, travel + APPROACH_MARGIN - 1e-3, 0.0)[:, None] * d
    if table:
        body_z = np.einsum("nj,npj->np", R[:, 2, :].astype(np.float32), hs.body_pts[shape]) + palm[:, 2:3]
        ok &= body_z.min(axis=1) >= TABLE_CLEARANCE
    # Close every finger until its samples first reach into the object or below the table.
    pts = hs.close_pts[shape]  # N x F x U x Q x 3
    nf, nu, nq = pts.shape[1:4]
    world = (pts.reshape(n, -1, 3) @ Rt32 + palm[:, None, :].astype(np.float32)).reshape(n, nf, nu, nq, 3)
    clearance = obj.nearest_signed_distance(world).min(axis=-1)
    if table:
        clearance = np.minimum(clearance, world[..., 2].min(axis=-1))
    hit = clearance < 0.0
    first = np.where(hit.any(axis=-1), hit.argmax(axis=-1), nu)  # N x F
    # Interpolate the closing fraction where the clearance crosses zero.
    k0 = np.clip(first - 1, 0, nu - 1)
    k1 = np.clip(first, 0, nu - 1)
    c0 = np.take_along_axis(clearance, k0[..., None], -1)[..., 0]
    c1 = np.take_along_axis(clearance, k1[..., None], -1)[..., 0]
    frac = np.where(first > 0, np.clip(c0 / np.maximum(c0 - c1, 1e-9), 0.0, 1.0), 0.0)
    step = np.where((first > 0) & (first < nu), k0 + frac, np.where(first == 0, 0.0, nu - 1.0))  # N x F
    # Virtual contacts at each finger's stop (the palm's do not move).
    vc_step = np.where(hs.vc_finger[None, :] >= 0, step[:, np.maximum(hs.vc_finger, 0)], 0.0)  # N x V
    lo = np.clip(np.floor(vc_step).astype(int), 0, nu - 2)
    t = (vc_step - lo)[..., None]
    v = np.arange(len(hs.vc_finger))[None, :]
    s = shape[:, None]
    vc_p = (1 - t) * hs.vc_pos[s, lo, v] + t * hs.vc_pos[s, lo + 1, v]
    vc_n = (1 - t) * hs.vc_nrm[s, lo, v] + t * hs.vc_nrm[s, lo + 1, v]
    vc_p = vc_p @ Rt + palm[:, None, :]
    vc_n = vc_n @ Rt
    energy = obj.contact_energy(vc_p, vc_n / np.linalg.norm(vc_n, axis=-1, keepdims=True))
    return palm, np.where(ok, energy, np.inf)


def _frames(d: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """Rotations (N x 3 x 3) whose z axis is the unit ``d`` and x axis turned by ``roll`` about it."""
    helper = np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(d, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(d, e1)
    x = np.cos(roll)[:, None] * e1 + np.sin(roll)[:, None] * e2
    return np.stack([x, np.cross(d, x), d], axis=2)


def _allowed(R: np.ndarray, table: bool) -> np.ndarray:
    """With a table, approaches may be horizontal or downwards, never upwards from below it."""
    return R[:, 2, 2] <= 1e-9 if table else np.ones(len(R), bool)


def distinct(positions: np.ndarray, rotations: np.ndarray, order: Sequence[int], limit: int) -> list[int]:
    """Indices from ``order`` (best first), skipping any within DISTINCT_POSITION and
    DISTINCT_ANGLE of one already kept, at most ``limit``."""
    kept: list[int] = []
    for i in order:
        if kept:
            dp = np.linalg.norm(positions[kept] - positions[i], axis=1)
            cos = (np.einsum("kij,ij->k", rotations[kept], rotations[i]) - 1.0) / 2.0
            if np.any((dp <= DISTINCT_POSITION) & (cos >= math.cos(DISTINCT_ANGLE))):
                continue
        kept.append(int(i))
        if len(kept) >= limit:
            break
    return kept


@dataclass(frozen=True)
class PlanSettings:
    """Search sizes. ``samples``: random candidates; ``chains`` x ``steps``: annealing;
    ``simulate``: candidates executed in pybullet (at least 3 per requested grasp; more when
    fewer than the requested number reach force closure); ``t_start``/``t_end``: annealing
    temperatures (m of energy)."""

    samples: int = 1024
    chains: int = 64
    steps: int = 150
    simulate: int = 60
    t_start: float = 0.01
    t_end: float = 0.0005


def search(
    obj: ObjectField,
    hs: HandSamples,
    rng: np.random.Generator,
    table: bool,
    settings: PlanSettings,
    report: ProgressFn,
    stopped: CancelFn,
    out_of_time: Callable[[], bool],
) -> tuple[Candidates, int, bool]:
    """The cheap stage: random candidates, then simulated annealing from the best distinct ones.
    Returns every state evaluated, the number of evaluations, and whether it was cancelled."""
    extent = np.asarray(obj.mesh.extents, float)
    centre = np.asarray(obj.mesh.bounds.mean(axis=0), float)
    # Far enough that the open hand starts clear of the object wherever the aim point is.
    start_distance = 2.0 * float(np.linalg.norm(extent)) + 0.3
    evaluations = 0

    def evaluate(R: np.ndarray, aim: np.ndarray, shape: np.ndarray) -> Candidates:
        nonlocal evaluations
        palm, energy = np.zeros((len(R), 3)), np.full(len(R), np.inf)
        allowed = np.flatnonzero(_allowed(R, table))
        for i in range(0, len(allowed), BATCH):
            sl = allowed[i : i + BATCH]
            palm[sl], energy[sl] = _evaluate(obj, hs, R[sl], aim[sl], shape[sl], table, start_distance)
        evaluations += len(allowed)
        return Candidates(R, aim, shape, palm, energy)

    # Random candidates: approach directions over the sphere (folded to point down onto the
    # table), aim points around the object's centre, random roll and preshape.
    n0 = settings.samples
    d = rng.normal(size=(n0, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    if table:
        d[:, 2] = -np.abs(d[:, 2])
    first = evaluate(
        _frames(d, rng.uniform(0, 2 * np.pi, n0)),
        centre + rng.normal(size=(n0, 3)) * 0.35 * extent,
        rng.integers(0, hs.n_init, n0),
    )
    found = [first]
    report(0.05)
    order = np.argsort(first.energy, kind="stable")
    order = order[np.isfinite(first.energy[order])]
    starts = distinct(first.palm, first.R, order, settings.chains)
    if not starts:
        return first, evaluations, stopped()
    chains = first.take(np.array(starts))
    n_c = len(chains.R)
    for k in range(settings.steps):
        if stopped():
            return Candidates.concat(found), evaluations, True
        if out_of_time():
            break
        temp = settings.t_start * (settings.t_end / settings.t_start) ** (k / max(settings.steps - 1, 1))
        # Steps shrink with the temperature, down to a floor that keeps the chains moving.
        scale = max(math.sqrt(temp / settings.t_start), 0.15)
        R = Rotation.from_rotvec(rng.normal(size=(n_c, 3)) * 0.25 * scale).as_matrix() @ chains.R
        aim = chains.aim + rng.normal(size=(n_c, 3)) * 0.15 * extent * scale
        shape = np.clip(chains.shape + np.rint(rng.normal(size=n_c) * 3 * scale).astype(int), 0, len(hs.preshapes) - 1)
        proposal = evaluate(R, aim, shape)
        found.append(proposal)
        delta = proposal.energy - chains.energy
        accept = np.isfinite(proposal.energy) & (
            (delta <= 0) | (rng.random(n_c) < np.exp(-np.clip(delta, 0, None) / temp))
        )
        for name in ("R", "aim", "shape", "palm", "energy"):
            getattr(chains, name)[accept] = getattr(proposal, name)[accept]
        report(0.05 + 0.45 * (k + 1) / settings.steps)
    return Candidates.concat(found), evaluations, False
