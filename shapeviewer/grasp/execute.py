"""Executing planned grasps on the true object (the paper's Table IV protocol), then lifting it.

Frames: world (table top z = 0, +z up) and palm (see :mod:`shapeviewer.grasp.hands`). Units: metres
and radians, except the reported errors: joint error in degrees (millimetres for prismatic
fingers) and pose error in millimetres, as in the paper's Table IV.

:func:`execute_grasps` follows the paper's protocol in the kinematic world: the true mesh replaces
the one planned on; the hand is put at the planned pose with its planned preshape, opened, backed
off 200 mm along the approach, moved back up to 200 mm until contact, closed towards the planned
dofs stopping at contact, then closed until contact or the joint limits. The planned and executed
states are compared, and with ``lift`` each executed state is lifted in a dynamic simulation
(:func:`~shapeviewer.grasp.lift.lift_test`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import trimesh

from shapeviewer.geometry import centre_of_mass
from shapeviewer.grasp.hands import Hand, get_hand
from shapeviewer.grasp.lift import lift_test
from shapeviewer.grasp.plan import BACK_OFF, approach_and_close, hand_state
from shapeviewer.grasp.quality import max_radius
from shapeviewer.grasp.search import CancelFn, ProgressFn
from shapeviewer.grasp.state import Grasp, HandState, LiftResult
from shapeviewer.grasp.world import GraspWorld, convex_decomposition

# s: the true object's V-HACD bound. Execution and every lift test collide with its decomposition,
# and V-HACD takes over a minute on some true meshes that lie flat along the world's axes
# (a plate on the table), beyond the planner's VHACD_TIMEOUT, which suits completions a user waits for.
TRUTH_VHACD_TIMEOUT = 300.0


@dataclass(eq=False)
class ExecutionResult(HandState):
    """A grasp executed on the true object: its executed state (see :class:`HandState`; qualities
    with the true object's centre of mass and radius) and how it went.

    ``joint_error``: mean absolute difference of planned and executed finger joints (every joint a
    closing dof moves; degrees, or millimetres for prismatic fingers). ``pose_error``: distance
    between planned and executed palm positions (mm). ``start_clear``: the backed-off start was
    free of collisions; ``approach_contact``: the approach stopped at contact (rather than at its
    full 200 mm). ``lift``: the lift test, if run.
    """

    joint_error: float
    pose_error: float
    start_clear: bool
    approach_contact: bool
    lift: LiftResult | None = None
    frame: str = "world"


def joint_error(hand: Hand, planned: dict[str, float], executed: dict[str, float]) -> float:
    """Mean absolute difference of the finger joints: degrees for revolute, mm for prismatic."""
    by_name = {j.name: j for j in hand.model.joints}
    diffs = []
    for name, finger in zip(hand.joint_names, hand.closing_joints):
        if not finger:
            continue
        scale = 1000.0 if by_name[name].kind == "prismatic" else 180.0 / math.pi
        diffs.append(scale * abs(planned[name] - executed[name]))
    return float(np.mean(diffs))


def execute_grasps(
    grasps: Sequence[Grasp],
    true_mesh_world: trimesh.Trimesh,
    *,
    table: bool = True,
    lift: bool = False,
    shake: bool = False,
    progress: ProgressFn | None = None,
    cancel: CancelFn | None = None,
) -> list[ExecutionResult]:
    """Execute every grasp on ``true_mesh_world`` (world frame) with the protocol of the authors'
    GraspIt evaluation (:func:`~.plan.approach_and_close`), in one kinematic world per hand; with
    ``lift``, also run :func:`lift_test` on each executed state. ``progress(fraction)`` reports 0..1
    (the lift tests are most of the work); ``cancel()`` is asked before each lift test, and those not
    run keep ``lift`` None."""
    by_index: dict[int, ExecutionResult] = {}
    com = centre_of_mass(true_mesh_world)
    radius = max_radius(true_mesh_world.vertices, com)
    parts = convex_decomposition(true_mesh_world, timeout=TRUTH_VHACD_TIMEOUT) if grasps else None
    for hand_name in dict.fromkeys(g.hand for g in grasps):
        hand = get_hand(hand_name)
        with GraspWorld(hand, table=table) as world:
            body = world.add_object(true_mesh_world, parts=parts)
            for i, g in enumerate(grasps):
                if g.hand != hand_name:
                    continue
                planned = [g.dofs[n] for n in hand.dof_names]
                clear, approach, closed = approach_and_close(
                    world, g.T_world_palm, planned, back_off=BACK_OFF, max_approach=BACK_OFF, targets=(planned, None)
                )
                assert closed is not None  # two closing targets
                state = hand_state(world, closed, body, com, radius)
                by_index[i] = ExecutionResult(
                    **vars(state),
                    joint_error=joint_error(hand, g.joints, state.joints),
                    pose_error=1000.0 * float(np.linalg.norm(state.T_world_palm[:3, 3] - g.T_world_palm[:3, 3])),
                    start_clear=clear,
                    approach_contact=approach.contact,
                )
    results = [by_index[i] for i in range(len(grasps))]  # every grasp's hand had its world
    share = 0.1 if lift and results else 1.0  # of the work, executing them
    if progress is not None:
        progress(share)
    if lift:
        for j, r in enumerate(results):
            if cancel is not None and cancel():
                break
            r.lift = lift_test(r, true_mesh_world, table=table, shake=shake, parts=parts)
            if progress is not None:
                progress(share + (1 - share) * (j + 1) / len(results))
    return results
