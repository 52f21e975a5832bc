"""GraspIt-style grasp planning on one object mesh (as the authors' GraspIt plugin planned).

Frames: the world frame has the table top as z = 0 (+z up); the palm frame is the hand's (origin at
the centre of the palm face, +z the approach). ``T_world_palm`` maps palm to world coordinates.
Units: metres and radians.

:func:`plan` works in two stages.

1. A cheap search without physics. A candidate is a palm orientation ``R`` (its approach
   ``R[:, 2]`` never points up, so the hand never comes from below the table), an aim point the
   approach line passes through, and a preshape (the Barrett's spread). Its palm position is where
   the open hand, moved along the approach from far away, first touches the object (rays cast from
   the front of the hand at the object's surface inflated by a few millimetres, so that the hand
   does not skim past it); every finger then closes until it touches the object or the table (a
   signed-distance grid of the object looked up at finger surface samples precomputed over the
   closing range). Its energy is GraspIt's contact energy of the hand's virtual contacts in that
   closed state: the mean over contacts of the distance to the object plus 50 mm per unit of
   (1 - cos) misalignment of the contact normal. Random candidates are refined by simulated
   annealing (parallel chains, one vectorised evaluation per step).
2. The best distinct candidates run the execution protocol in the pybullet world
   (:func:`approach_and_close`: back off, approach until contact, close), which gives each grasp's
   planned palm pose, joints and contacts; epsilon and volume come from those contacts. Grasps
   that start in collision, touch the table, or leave a finger without object contact are dropped.
3. The lift check: the best distinct grasps are lifted in a dynamic simulation on the same mesh
   (:func:`~shapeviewer.grasp.lift.lift_test`, gravity on, the fingers squeezing), and those that
   pick the object up come first. Epsilon ignores gravity, the table and how the fingers squeeze,
   so even on a perfect mesh its best grasp can drop the object (``benchmarks/studies/grasp_ceiling.py``
   measures how often).

Stage 1 is :func:`~shapeviewer.grasp.search.search`, on the hand's precomputed samples
(:mod:`~shapeviewer.grasp.samples`) and the object's field (:mod:`~shapeviewer.grasp.object_field`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import trimesh

from shapeviewer.grasp.hands import Hand, get_hand
from shapeviewer.grasp.lift import lift_test
from shapeviewer.grasp.object_field import ObjectField
from shapeviewer.grasp.quality import GraspQuality, grasp_quality
from shapeviewer.grasp.samples import hand_samples
from shapeviewer.grasp.search import CancelFn, PlanSettings, ProgressFn, distinct, search
from shapeviewer.grasp.state import Grasp, GraspContact, HandState, lift_order
from shapeviewer.grasp.world import ApproachResult, CloseResult, Decomposition, GraspWorld

from ..runtime.bullet import pybullet as p

BACK_OFF = 0.2  # m: the protocol backs the open hand off this far along the approach (the authors' GraspIt evaluation)
APPROACH_SLACK = 0.03  # m: planning approaches this much beyond the back-off, for cheap-stage errors
LIFT_CANDIDATES = 2  # the lift check tries up to this many times the requested number of grasps


# ---------------------------------------------------------------------------------------------
# The pybullet stage.


def approach_and_close(
    world: GraspWorld,
    T_world_palm: np.ndarray,
    preshape: Sequence[float],
    *,
    back_off: float = BACK_OFF,
    max_approach: float = BACK_OFF,
    targets: Sequence[Sequence[float] | None] = (None,),
) -> tuple[bool, ApproachResult, CloseResult | None]:
    """The execution protocol of the authors' GraspIt evaluation on the hand of ``world``.

    Set the palm at ``T_world_palm`` (world frame) with the dofs ``preshape`` and open the hand;
    back off ``back_off`` (m) along the approach (poses are set directly, so nothing collides on
    the way: the protocol's "collisions off"); approach up to ``max_approach`` (m) until contact;
    then close towards each of ``targets`` in turn (dof vectors; None: fully closed), each
    stopping fingers at contact. Returns whether the backed-off start was clear of every obstacle,
    the approach, and the last closing (None without targets).
    """
    world.set_dofs(preshape)
    world.open_hand()
    world.set_palm_pose(T_world_palm)
    world.move_along_approach(-back_off)
    clear = not world.in_collision(world.contact_tol)
    approach = world.approach(max_approach)
    closed = None
    for target in targets:
        closed = world.close_fingers(target)
    return clear, approach, closed


def object_contacts(
    closed: CloseResult, body: int, com: np.ndarray, radius: float
) -> tuple[tuple[GraspContact, ...], GraspQuality]:
    """The closed hand's contacts with object ``body`` and their qualities, for the object's
    centre of mass ``com`` (world frame) and max radius (m); no contacts: (0, 0)."""
    contacts = tuple(GraspContact.from_world(c) for c in closed.contacts if c.body == body)
    return contacts, grasp_quality([c.position for c in contacts], [c.normal for c in contacts], com, radius)


def hand_state(world: GraspWorld, closed: CloseResult, body: int, com: np.ndarray, radius: float) -> HandState:
    """The hand's current state in ``world`` after ``closed`` as a :class:`HandState` on object
    ``body``: its palm pose and joints, and its contacts and their qualities for the object's
    centre of mass ``com`` (world frame) and max radius (m), see :func:`object_contacts`."""
    hand = world.hand.hand
    contacts, q = object_contacts(closed, body, com, radius)
    return HandState(
        hand.name,
        world.palm_pose(),
        dict(zip(hand.dof_names, map(float, closed.dofs))),
        dict(zip(hand.joint_names, map(float, closed.joints))),
        contacts,
        q.epsilon,
        q.volume,
    )


def _grasp_from_world(world: GraspWorld, body: int, obj: ObjectField, closed: CloseResult) -> Grasp:
    """The hand's current state in ``world`` as a :class:`Grasp` on object ``body`` (qualities
    from its contacts, energy from ``obj``, the same object's field)."""
    state = hand_state(world, closed, body, obj.com, obj.max_radius)
    T = state.T_world_palm
    vc_p, vc_n = world.hand.hand.virtual_contacts_palm(closed.joints)
    energy = float(obj.contact_energy(vc_p @ T[:3, :3].T + T[:3, 3], vc_n @ T[:3, :3].T))
    return Grasp(**vars(state), energy=energy)


def _table_gap(world: GraspWorld, radius: float) -> float:
    """Smallest hand-table distance (m), or ``radius`` when farther (no table: inf)."""
    if world.table is None:
        return math.inf
    rows = p.getClosestPoints(world.hand.body, world.table, radius, physicsClientId=world.client)
    return min((r[8] for r in rows), default=radius)


def _fingers_touch(hand: Hand, contacts: Sequence[GraspContact]) -> bool:
    links = {c.link for c in contacts}
    return all(links & set(f.links) for f in hand.fingers)


# ---------------------------------------------------------------------------------------------
# Planning.


@dataclass(frozen=True)
class PlanStats:
    """What planning did: cheap evaluations and their rate (per second of search), candidates
    executed in pybullet, seconds per stage, and whether it was cancelled."""

    evaluations: int
    evaluations_per_second: float
    simulated: int
    seconds: dict[str, float]
    cancelled: bool


@dataclass(frozen=True)
class PlanResult:
    """The grasps :func:`plan` found (best first) and what it did."""

    grasps: list[Grasp]
    stats: PlanStats


def plan(
    mesh_world: trimesh.Trimesh,
    *,
    hand: str = "barrett",
    n_grasps: int = 20,
    seed: int = 0,
    table: bool = True,
    budget_seconds: float | None = None,
    progress: ProgressFn | None = None,
    cancel: CancelFn | None = None,
    settings: PlanSettings = PlanSettings(),
    lift_check: bool = True,
) -> PlanResult:
    """Up to ``n_grasps`` distinct grasps of ``mesh_world`` (world frame, metres, standing on the
    table z = 0 when ``table``), best first: force-closure grasps by epsilon, then the rest; with
    ``lift_check``, those that lift the mesh in simulation before those not checked and those that
    drop it (each grasp's ``lift``; up to ``LIFT_CANDIDATES * n_grasps`` grasps are tried).

    Deterministic for a seed unless ``budget_seconds`` (wall-clock limit: the search gets up to
    45% of it, the simulation up to 80% with the lift check, 95% without, the lift check the rest)
    or ``cancel`` (polled often; planning then returns the grasps simulated so far) cut it short.
    ``progress(fraction)`` reports 0..1.

    Raises:
        DecompositionError: the object's convex decomposition failed or was not ready within the
            budget (or :data:`~shapeviewer.grasp.world.VHACD_TIMEOUT` without one).
    """
    t0 = time.perf_counter()
    report = progress or (lambda _f: None)
    stopped = cancel or (lambda: False)

    def over(share: float) -> bool:
        return budget_seconds is not None and time.perf_counter() > t0 + share * budget_seconds

    rng = np.random.default_rng(seed)
    hand_ = get_hand(hand)
    seconds: dict[str, float] = {}
    # V-HACD runs in a child process: let it overlap the cheap stage. A cancelled plan does not
    # wait for it (it still completes the cache for the next one, within its own time bound); a
    # failed or interrupted one kills it.
    decomposition = Decomposition(mesh_world)
    try:
        hs = hand_samples(hand)
        obj = ObjectField(mesh_world, seed)
        seconds["setup"] = time.perf_counter() - t0
        t1 = time.perf_counter()
        found, evaluations, cancelled = search(obj, hs, rng, table, settings, report, stopped, lambda: over(0.45))
        seconds["search"] = time.perf_counter() - t1
        if not cancelled:
            # Within the budget when there is one (a grasp needs the decomposition: none without it).
            left = None if budget_seconds is None else max(1.0, t0 + budget_seconds - time.perf_counter())
            decomposition.wait(left)
    except BaseException:
        decomposition.cancel()
        raise

    t2 = time.perf_counter()
    grasps: list[Grasp] = []
    simulated = 0
    simulate_end, simulate_share = (0.8, 0.35) if lift_check else (0.95, 0.5)
    if not cancelled:
        order = np.argsort(found.energy, kind="stable")
        order = order[np.isfinite(found.energy[order])]
        n_sim = max(settings.simulate, 3 * n_grasps)
        picks = distinct(found.palm, found.R, order, 3 * n_sim)
        with GraspWorld(hand_, table=table) as world:
            body = world.add_object(mesh_world, decompose=True)
            for j, i in enumerate(picks):
                if (j >= n_sim and len(_best_distinct(grasps, n_grasps, force_closure=True)) >= n_grasps) or over(
                    simulate_end
                ):
                    break
                if stopped():
                    cancelled = True
                    break
                T = np.eye(4)
                T[:3, :3] = found.R[i]
                T[:3, 3] = found.palm[i]
                clear, _, closed = approach_and_close(
                    world, T, hs.preshapes[found.shape[i]], max_approach=BACK_OFF + APPROACH_SLACK
                )
                simulated += 1
                report(0.5 + simulate_share * min(1.0, (j + 1) / n_sim))
                # Reject a start in collision and any touch of the table (by the approach or a finger).
                if not clear or _table_gap(world, 2 * world.contact_tol) <= world.contact_tol:
                    continue
                assert closed is not None  # the default targets close once
                g = _grasp_from_world(world, body, obj, closed)
                if _fingers_touch(hand_, g.contacts):
                    grasps.append(g)
    seconds["simulate"] = time.perf_counter() - t2
    if lift_check and not cancelled:
        t3 = time.perf_counter()
        kept, cancelled = _lift_checked(
            _best_distinct(grasps, LIFT_CANDIDATES * n_grasps),
            mesh_world,
            table,
            n_grasps,
            lambda f: report(0.85 + 0.15 * f),
            lambda: stopped() or over(1.0),
        )
        cancelled = cancelled and stopped()  # out of time is not cancelled
        seconds["lift"] = time.perf_counter() - t3
    else:
        kept = _best_distinct(grasps, n_grasps)
    seconds["total"] = time.perf_counter() - t0
    report(1.0)
    rate = evaluations / max(seconds["search"], 1e-9)
    return PlanResult(kept, PlanStats(evaluations, rate, simulated, seconds, cancelled))


def _lift_checked(
    ranked: list[Grasp], mesh_world: trimesh.Trimesh, table: bool, n: int, report: ProgressFn, stop: CancelFn
) -> tuple[list[Grasp], bool]:
    """The first ``n`` of ``ranked`` (best first) after lifting them on ``mesh_world`` in order
    until ``n`` lift it or ``stop()``: those that lift first, then those not tried, then those
    that drop it, each group in the given order. Sets each tried grasp's ``lift``; returns the
    grasps and whether ``stop()`` ended the check."""
    lifted = 0
    stopped = False
    for k, g in enumerate(ranked):
        if lifted >= n:
            break
        if stop():
            stopped = True
            break
        g.lift = lift_test(g, mesh_world, table=table)
        lifted += g.lift.success
        report(min(1.0, (k + 1) / max(1, min(n, len(ranked)))))
    order = sorted(ranked, key=lambda g: lift_order(g.lift))
    return order[:n], stopped


def _best_distinct(grasps: list[Grasp], n: int, force_closure: bool = False) -> list[Grasp]:
    """Up to ``n`` distinct grasps, best first: force closure, then epsilon, volume, energy."""
    ranked = sorted(
        (g for g in grasps if g.force_closure or not force_closure),
        key=lambda g: (-g.force_closure, -g.epsilon, -g.volume, g.energy),
    )
    keep = distinct(
        np.array([g.position for g in ranked]).reshape(-1, 3),
        np.array([g.T_world_palm[:3, :3] for g in ranked]).reshape(-1, 3, 3),
        range(len(ranked)),
        n,
    )
    return [ranked[i] for i in keep]
