"""The benchmark's grasp execution protocol with the project's free-floating Panda hand, in dynamics.

Frames: the benchmark's world (:mod:`.scene`) and the hand's palm frame (:mod:`shapeviewer.grasp.hands`:
origin at the centre of the palm face, +z the approach, the fingers closing along y). The benchmark
states grasps by the hand's *TCP*, TCP_OFFSET in front of the palm between the finger pads.
Units: metres, radians, seconds.

:func:`execute_grasp` follows VGN / GIGA's ``execute_grasp``: the hand appears PREGRASP_DISTANCE
back along its approach, opened to the grasp's width, held by a fixed constraint (the arm, at most
HOLD_FORCE) whose target moves in 2 mm steps at 10 cm/s; if it touches anything there the attempt
fails (``pregrasp_contact``). It then moves to the grasp (stopping early at a contact, which is
allowed), closes both fingers with their URDF effort for half a second, and moves RETREAT_DISTANCE
straight up when the approach is more than SIDE_GRASP_ANGLE from straight down, else back along the
approach. The grasp succeeds when the hand touches an object with the fingers open more than
SUCCESS_WIDTH of the maximum; that object is removed. After every attempt the hand is removed and
the objects settle, those leaving the workspace being removed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ..geometry import pose_to_pq
from ..grasp.hands import HandBody, load_hand, palm_pose, set_joints
from ..grasp.lift import hold_base
from ..runtime.bullet import pybullet as p
from .scene import MAX_OPENING, TIME_STEP, ClutterWorld

TCP_OFFSET = 0.022  # m: the TCP in front of the palm face, along the approach
PREGRASP_DISTANCE = 0.05  # m back along the approach
RETREAT_DISTANCE = 0.1  # m
SIDE_GRASP_ANGLE = math.pi / 3  # rad from straight down beyond which the hand lifts straight up
SUCCESS_WIDTH = 0.1  # of MAX_OPENING: fingers closed further hold nothing
HOLD_FORCE = 300.0  # N: the constraint standing in for the arm
GEAR_FORCE = 50.0  # N: the coupling that keeps the fingers centred
MOVE_STEP = 0.002  # m per target update
MOVE_SPEED = 0.1  # m/s
CLOSE_SECONDS = 0.5
# The Panda's finger pads: soft contacts (pybullet's contact stiffness N/m and damping), as in the benchmark's hand.
PAD_STIFFNESS, PAD_DAMPING = 30000.0, 1000.0

OutcomeKind = Literal["success", "pregrasp_contact", "closed_on_nothing", "slipped"]
FailureKind = Literal["no_grasp", "pregrasp_contact", "closed_on_nothing", "slipped"]
FAILURE_KINDS: tuple[FailureKind, ...] = ("no_grasp", "pregrasp_contact", "slipped", "closed_on_nothing")


@dataclass(frozen=True, eq=False)
class GraspPose:
    """A grasp to execute: the palm's pose ``T_world_palm`` (4x4, world frame; +z the approach, the
    fingers closing along y), the opening ``width`` (m) the hand approaches with, and the method's
    ``score`` (higher is better; for the record only)."""

    T_world_palm: np.ndarray
    width: float = MAX_OPENING
    score: float = 0.0

    @property
    def T_world_tcp(self) -> np.ndarray:
        return palm_to_tcp(self.T_world_palm)

    def to_dict(self) -> dict:
        return {"T_world_palm": np.asarray(self.T_world_palm).tolist(), "width": self.width, "score": self.score}


@dataclass(frozen=True)
class Outcome:
    """How an attempt went: ``kind`` (``success`` or the failure), the removed object's name (on
    success), the finger opening ``width`` (m) at the end, and whether the approach stopped at a contact."""

    kind: OutcomeKind
    object: str | None = None
    width: float = 0.0
    approach_contact: bool = False

    @property
    def success(self) -> bool:
        return self.kind == "success"


def _translate(T: np.ndarray, offset: np.ndarray) -> np.ndarray:
    out = np.array(T, dtype=np.float64)
    out[:3, 3] += offset
    return out


def tcp_to_palm(T_world_tcp: np.ndarray) -> np.ndarray:
    """``T_world_palm`` of a hand whose TCP is at ``T_world_tcp`` (same orientation, TCP_OFFSET behind)."""
    T = np.asarray(T_world_tcp, dtype=np.float64)
    return _translate(T, -TCP_OFFSET * T[:3, 2])


def palm_to_tcp(T_world_palm: np.ndarray) -> np.ndarray:
    """``T_world_tcp`` of a hand whose palm is at ``T_world_palm``."""
    T = np.asarray(T_world_palm, dtype=np.float64)
    return _translate(T, TCP_OFFSET * T[:3, 2])


class _Hand:
    """The Panda loaded into a clutter world, held by a fixed constraint whose target it moves."""

    def __init__(self, world: ClutterWorld, T_world_palm: np.ndarray, width: float) -> None:
        self.world = world
        c = world.client
        self.hb: HandBody = load_hand(c, "panda", T_world_palm)
        half = float(np.clip(width, 0.0, MAX_OPENING)) / 2
        set_joints(self.hb, [half, half])
        self.fingers = [self.hb.link_index["left_finger"], self.hb.link_index["right_finger"]]
        for link in self.fingers:
            p.changeDynamics(
                self.hb.body, link, contactStiffness=PAD_STIFFNESS, contactDamping=PAD_DAMPING, physicsClientId=c
            )
        pos, quat = pose_to_pq(T_world_palm)  # the palm frame is the base's inertial frame
        self.orientation = quat
        self.cid = hold_base(c, self.hb.body, pos, quat, HOLD_FORCE)
        gear = p.createConstraint(
            self.hb.body,
            self.fingers[0],
            self.hb.body,
            self.fingers[1],
            p.JOINT_GEAR,
            [1, 0, 0],
            [0, 0, 0],
            [0, 0, 0],
            physicsClientId=c,
        )
        p.changeConstraint(gear, gearRatio=-1, erp=0.1, maxForce=GEAR_FORCE, physicsClientId=c)
        self.drive(half)

    def drive(self, half_width: float) -> None:
        """Drive both fingers towards ``half_width`` (m each) with their URDF efforts."""
        c = self.world.client
        for j in self.hb.joint_index:
            effort = p.getJointInfo(self.hb.body, j, physicsClientId=c)[10]
            p.setJointMotorControl2(
                self.hb.body, j, p.POSITION_CONTROL, targetPosition=half_width, force=effort, physicsClientId=c
            )

    @property
    def width(self) -> float:
        """The finger opening (m): the sum of both fingers' joint values."""
        c = self.world.client
        return float(sum(p.getJointState(self.hb.body, j, physicsClientId=c)[0] for j in self.hb.joint_index))

    def contact_bodies(self, links: list[int] | None = None) -> list[int]:
        """Bodies the hand (or its ``links``) touches after the last step, in pybullet's order."""
        rows = p.getContactPoints(bodyA=self.hb.body, physicsClientId=self.world.client)
        return [r[2] for r in rows if links is None or r[3] in links]

    def move_to(self, target: np.ndarray, *, abort_on_contact: bool) -> bool:
        """Move the palm's target in a straight line to ``target``'s position (world frame, m) in
        MOVE_STEP steps at MOVE_SPEED; returns whether it stopped at a contact."""
        start = palm_pose(self.hb)[:3, 3]
        diff = np.asarray(target)[:3, 3] - start
        n = int(np.linalg.norm(diff) / MOVE_STEP)
        if n == 0:
            return False
        step = diff / n
        substeps = max(1, int(np.linalg.norm(step) / MOVE_SPEED / TIME_STEP))
        pos = start.copy()
        for _ in range(n):
            pos += step
            p.changeConstraint(
                self.cid, pos.tolist(), self.orientation, maxForce=HOLD_FORCE, physicsClientId=self.world.client
            )
            self.world.step(substeps)
            if abort_on_contact and self.contact_bodies():
                return True
        return False


def execute_grasp(world: ClutterWorld, grasp: GraspPose, *, remove: bool = True) -> Outcome:
    """Execute ``grasp`` in ``world`` with the benchmark's protocol (see the module docstring).

    With ``remove``, a grasped object is removed from the world, and the objects then settle
    (those that left the workspace removed): the next capture sees the table as the robot left it.
    """
    T_grasp = np.asarray(grasp.T_world_palm, dtype=np.float64)
    approach = T_grasp[:3, 2]
    T_pregrasp = _translate(T_grasp, -PREGRASP_DISTANCE * approach)
    if math.acos(float(np.clip(-approach[2], -1.0, 1.0))) > SIDE_GRASP_ANGLE:
        T_retreat = _translate(T_grasp, np.array([0.0, 0.0, RETREAT_DISTANCE]))
    else:
        T_retreat = _translate(T_grasp, -RETREAT_DISTANCE * approach)
    hand = _Hand(world, T_pregrasp, grasp.width)
    try:
        if world.touching(hand.hb.body):
            return Outcome("pregrasp_contact", width=hand.width)
        contact = hand.move_to(T_grasp, abort_on_contact=True)
        hand.drive(0.0)
        world.step(int(CLOSE_SECONDS / TIME_STEP))
        objects = set(world.objects)
        held = [b for b in hand.contact_bodies(hand.fingers) if b in objects]
        closed_on = bool(held) and hand.width > SUCCESS_WIDTH * MAX_OPENING
        hand.move_to(T_retreat, abort_on_contact=False)
        touching = [b for b in hand.contact_bodies() if b in objects]
        width = hand.width
        if not (touching and width > SUCCESS_WIDTH * MAX_OPENING):
            return Outcome("slipped" if closed_on else "closed_on_nothing", width=width, approach_contact=contact)
        fingers = [b for b in hand.contact_bodies(hand.fingers) if b in objects]
        body = (fingers or touching)[0]
        name = world.objects[body].name
        if remove:
            world.remove_body(body)
        return Outcome("success", object=name, width=width, approach_contact=contact)
    finally:
        world.remove_body(hand.hb.body)
        if remove:
            world.settle()
