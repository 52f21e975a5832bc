"""A dynamic lift test: does a hand, closed on an object on the table, pick it up?

Frames: world (table top z = 0, +z up) and palm (see :mod:`shapeviewer.grasp.hands`). Units: metres,
radians, seconds, kilograms.

:func:`lift_test` simulates dynamics: gravity on, the object movable (its convex decomposition),
the hand held by a fixed constraint whose pivot is moved up (and optionally shaken), the fingers
squeezing under position control limited to their URDF efforts, their contacts soft (torsional
friction, SOFT_CONTACT_SPIN). The grasp succeeds when the object comes up with the hand. The
planner runs it on the mesh it planned on (:func:`~shapeviewer.grasp.plan.plan`), the evaluation on
the true object (:func:`~shapeviewer.grasp.execute.execute_grasps`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import trimesh

from shapeviewer.grasp.hands import get_hand, set_joint_positions
from shapeviewer.grasp.state import HandState, LiftResult
from shapeviewer.grasp.world import GraspWorld

from ..runtime.bullet import pybullet as p

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


def hold_base(client: int, body: int, position, orientation, max_force: float) -> int:
    """The arm of a free-floating hand: a fixed constraint from the world to ``body``'s base (its
    inertial frame) at ``position`` (m, world) and ``orientation`` (quaternion xyzw), pulling with at
    most ``max_force`` (N). Move the hand with ``p.changeConstraint`` on the returned id."""
    cid = p.createConstraint(
        body,
        -1,
        -1,
        -1,
        p.JOINT_FIXED,
        [0, 0, 0],
        [0, 0, 0],
        position,
        childFrameOrientation=orientation,
        physicsClientId=client,
    )
    p.changeConstraint(cid, position, orientation, maxForce=max_force, physicsClientId=client)
    return cid


def lift_test(
    state: HandState,
    true_mesh_world: trimesh.Trimesh,
    *,
    table: bool = True,
    lift_height: float = LIFT_HEIGHT,
    shake: bool = False,
    mass: float = 0.2,
    friction: float = 1.0,
    parts: str | Path | None = None,
) -> LiftResult:
    """Whether the hand, at ``state``'s palm pose (world frame) and joints, lifts the object.

    The object (``mass`` kg, ``friction`` on it and on every hand link) starts where
    ``true_mesh_world`` puts it, resting on the table. The fingers squeeze towards closed under
    torque-limited position control for SETTLE_SECONDS, then the hand rises ``lift_height`` (m)
    over LIFT_SECONDS, holds, and with ``shake`` moves sideways back and forth. ``parts``: an OBJ
    of convex parts of the mesh (world frame) to collide with instead of its cached V-HACD
    decomposition (see :meth:`~shapeviewer.grasp.world.GraspWorld.add_object`).
    """
    hand = get_hand(state.hand)
    with GraspWorld(hand, table=table) as world:
        c = world.client
        body = world.add_object(true_mesh_world, movable=True, parts=parts, mass=mass, friction=friction)
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
        cid = hold_base(c, hb.body, start_pos, orn, HOLD_FORCE)

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
