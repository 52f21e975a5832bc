"""Executing planned grasps on the true object (SPEC section 8), and a dynamic lift test.

Frames: world (table top z = 0, +z up) and palm (see :mod:`shapeviewer.grasp.hands`). Units: metres
and radians, except the reported errors: joint error in degrees (millimetres for prismatic
fingers) and pose error in millimetres, as in the paper's Table IV.

:func:`execute_grasps` follows the paper's protocol in the kinematic world: the true mesh replaces
the one planned on; the hand is put at the planned pose with its planned preshape, opened, backed
off 200 mm along the approach, moved back up to 200 mm until contact, closed towards the planned
dofs stopping at contact, then closed until contact or the joint limits. The planned and executed
states are compared.

:func:`lift_test` simulates dynamics: gravity on, the object movable (its convex decomposition),
the hand held by a fixed constraint whose pivot is moved up (and optionally shaken), the fingers
squeezing under position control limited to their URDF efforts, their contacts soft (torsional
friction, SOFT_CONTACT_SPIN). The grasp succeeds when the object comes up with the hand.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pybullet as p
import trimesh

from shapeviewer.geometry import centre_of_mass
from shapeviewer.grasp.hands import Hand, get_hand, set_joint_positions
from shapeviewer.grasp.plan import BACK_OFF, approach_and_close, object_contacts
from shapeviewer.grasp.quality import max_radius
from shapeviewer.grasp.search import CancelFn, ProgressFn
from shapeviewer.grasp.state import Grasp, HandState
from shapeviewer.grasp.world import GraspWorld

# Lift test timing (s) at pybullet's default 240 Hz step.
SETTLE_SECONDS = 0.1  # the fingers squeeze before the hand moves
LIFT_SECONDS = 0.35
HOLD_SECONDS = 0.15
SHAKE_SECONDS = 0.3
SHAKE_AMPLITUDE = 0.02  # m, horizontal, two full cycles
LIFT_HEIGHT = 0.12  # m
HOLD_FORCE = 500.0  # N: the constraint standing in for the arm
SPREAD_FORCE = 5.0  # N m: the spread is a preshape the hand's worm gear holds, not a squeezing motor
SUCCESS_FRACTION = 0.5  # the object must rise at least this share of the lift
# m: torsional ("spinning") friction per unit normal force at every hand-object contact. The
# Barrett's rubber pads touch over a patch, not a point, and resist twisting about the contact
# normal by about 2/3 x friction x patch radius (3 mm here). Point contacts let a held object
# pivot about the fingertips and tip out of a grasp that has force closure (the master chef can
# of the default scene: 4 of 10 grasps planned on its true mesh lifted it, 7 of 10 with this).
SOFT_CONTACT_SPIN = 0.002


@dataclass(frozen=True)
class LiftResult:
    """Outcome of :func:`lift_test`: ``rise`` (m) of the object's centre of mass, ``slip`` (m) of
    the object relative to the palm over the test, and ``success`` (the object rose at least half
    the lift)."""

    success: bool
    rise: float
    slip: float


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
    """Execute every grasp on ``true_mesh_world`` (world frame) with the protocol of SPEC
    section 8, in one kinematic world per hand; with ``lift``, also run :func:`lift_test` on each
    executed state. ``progress(fraction)`` reports 0..1 (the lift tests are most of the work);
    ``cancel()`` is asked before each lift test, and those not run keep ``lift`` None."""
    by_index: dict[int, ExecutionResult] = {}
    com = centre_of_mass(true_mesh_world)
    radius = max_radius(true_mesh_world.vertices, com)
    for hand_name in dict.fromkeys(g.hand for g in grasps):
        hand = get_hand(hand_name)
        with GraspWorld(hand, table=table) as world:
            body = world.add_object(true_mesh_world, decompose=True)
            for i, g in enumerate(grasps):
                if g.hand != hand_name:
                    continue
                planned = [g.dofs[n] for n in hand.dof_names]
                clear, approach, closed = approach_and_close(
                    world, g.T_world_palm, planned, back_off=BACK_OFF, max_approach=BACK_OFF, targets=(planned, None)
                )
                assert closed is not None  # two closing targets
                contacts, q = object_contacts(closed, body, com, radius)
                T = world.palm_pose()
                joints = dict(zip(hand.joint_names, map(float, closed.joints)))
                by_index[i] = ExecutionResult(
                    hand=hand_name,
                    T_world_palm=T,
                    dofs=dict(zip(hand.dof_names, map(float, closed.dofs))),
                    joints=joints,
                    contacts=contacts,
                    epsilon=q.epsilon,
                    volume=q.volume,
                    joint_error=joint_error(hand, g.joints, joints),
                    pose_error=1000.0 * float(np.linalg.norm(T[:3, 3] - g.T_world_palm[:3, 3])),
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
            r.lift = lift_test(r, true_mesh_world, table=table, shake=shake)
            if progress is not None:
                progress(share + (1 - share) * (j + 1) / len(results))
    return results


def lift_test(
    state: HandState,
    true_mesh_world: trimesh.Trimesh,
    *,
    table: bool = True,
    lift_height: float = LIFT_HEIGHT,
    shake: bool = False,
    mass: float = 0.2,
    friction: float = 1.0,
) -> LiftResult:
    """Whether the hand, at ``state``'s palm pose (world frame) and joints, lifts the object.

    The object (``mass`` kg, ``friction`` on it and on every hand link) starts where
    ``true_mesh_world`` puts it, resting on the table. The fingers squeeze towards closed under
    torque-limited position control for SETTLE_SECONDS, then the hand rises ``lift_height`` (m)
    over LIFT_SECONDS, holds, and with ``shake`` moves sideways back and forth.
    """
    hand = get_hand(state.hand)
    with GraspWorld(hand, table=table) as world:
        c = world.client
        body = world.add_object(true_mesh_world, movable=True, mass=mass, friction=friction)
        p.changeDynamics(body, -1, spinningFriction=SOFT_CONTACT_SPIN, physicsClientId=c)
        hb = world.hand
        set_joint_positions(hb, [state.joints[n] for n in hand.joint_names])
        world.set_palm_pose(state.T_world_palm)
        for link in hb.link_index.values():
            p.changeDynamics(
                hb.body, link, lateralFriction=friction, spinningFriction=SOFT_CONTACT_SPIN, physicsClientId=c
            )
        p.setGravity(0.0, 0.0, -9.81, physicsClientId=c)
        dt = p.getPhysicsEngineParameters(physicsClientId=c)["fixedTimeStep"]

        # The arm: a fixed constraint from the world to the palm's inertial frame, moved by its pivot.
        start_pos, orn = p.getBasePositionAndOrientation(hb.body, physicsClientId=c)
        cid = p.createConstraint(
            hb.body,
            -1,
            -1,
            -1,
            p.JOINT_FIXED,
            [0, 0, 0],
            [0, 0, 0],
            start_pos,
            childFrameOrientation=orn,
            physicsClientId=c,
        )
        p.changeConstraint(cid, start_pos, orn, maxForce=HOLD_FORCE, physicsClientId=c)

        # Fingers squeeze towards fully closed with their URDF efforts; preshape joints hold.
        fingers = hand.closing_joints
        closed = hand.joints_from_dofs(hand.dof_closed)
        target = [float(closed[k]) if fingers[k] else state.joints[n] for k, n in enumerate(hand.joint_names)]
        forces = [
            p.getJointInfo(hb.body, j, physicsClientId=c)[10] if fingers[k] else SPREAD_FORCE
            for k, j in enumerate(hb.joint_index)
        ]
        p.setJointMotorControlArray(
            hb.body, list(hb.joint_index), p.POSITION_CONTROL, targetPositions=target, forces=forces, physicsClientId=c
        )

        def com_in_palm() -> np.ndarray:
            T = world.palm_pose()
            pos = np.asarray(p.getBasePositionAndOrientation(body, physicsClientId=c)[0])
            return T[:3, :3].T @ (pos - T[:3, 3])

        z0 = p.getBasePositionAndOrientation(body, physicsClientId=c)[0][2]
        trajectory = [np.zeros(3)] * int(round(SETTLE_SECONDS / dt))
        n_lift = int(round(LIFT_SECONDS / dt))
        trajectory += [np.array([0.0, 0.0, lift_height * (k + 1) / n_lift]) for k in range(n_lift)]
        trajectory += [trajectory[-1]] * int(round(HOLD_SECONDS / dt))
        if shake:
            n_shake = int(round(SHAKE_SECONDS / dt))
            trajectory += [
                trajectory[-1] + [SHAKE_AMPLITUDE * math.sin(4 * math.pi * (k + 1) / n_shake), 0.0, 0.0]
                for k in range(n_shake)
            ]
        grasped = None
        for k, offset in enumerate(trajectory):
            if k == int(round(SETTLE_SECONDS / dt)):
                grasped = com_in_palm()  # after the squeeze, before the lift
            p.changeConstraint(
                cid, list(map(float, np.add(start_pos, offset))), orn, maxForce=HOLD_FORCE, physicsClientId=c
            )
            p.stepSimulation(physicsClientId=c)
        rise = p.getBasePositionAndOrientation(body, physicsClientId=c)[0][2] - z0
        slip = float(np.linalg.norm(com_in_palm() - grasped))
        return LiftResult(bool(rise >= SUCCESS_FRACTION * lift_height), float(rise), slip)
