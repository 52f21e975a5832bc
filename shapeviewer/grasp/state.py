"""What a grasp is: the hand's state on an object.

:class:`HandState` is what a planned :class:`Grasp` and an executed one
(:class:`~shapeviewer.grasp.execute.ExecutionResult`) have in common: the palm pose, the dofs and
joints, the contacts and their qualities.

Frames: the world frame has the table top as z = 0 (+z up); the palm frame is the hand's (see
:mod:`shapeviewer.grasp.hands`). ``T_world_palm`` maps palm to world coordinates. Units: metres
and radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shapeviewer.geometry import pose_to_pq
from shapeviewer.grasp.hands import get_hand
from shapeviewer.grasp.world import Contact


@dataclass(frozen=True, eq=False)
class GraspContact:
    """A hand link touching the object: ``position`` on the object's surface and the object's
    outward unit ``normal`` there (both world frame, metres)."""

    link: str
    position: np.ndarray
    normal: np.ndarray

    @staticmethod
    def from_world(c: Contact) -> GraspContact:
        return GraspContact(c.link, np.asarray(c.position, float), np.asarray(c.normal, float))


@dataclass(frozen=True)
class LiftResult:
    """Outcome of a lift test (:func:`~shapeviewer.grasp.lift.lift_test`): ``rise`` (m) of the
    object's centre of mass, ``slip`` (m) of the object relative to the palm over the test, and
    ``success`` (the object rose at least half the lift)."""

    success: bool
    rise: float
    slip: float


def lift_order(lift: LiftResult | None) -> int:
    """Where the planner's lift check puts a grasp: 0 it lifted the mesh, 1 not checked, 2 it
    dropped the mesh (a sort key: those that lift first)."""
    return 1 if lift is None else 0 if lift.success else 2


@dataclass(eq=False)
class HandState:
    """A hand on an object.

    ``T_world_palm``: 4x4 palm pose (world frame, metres). ``dofs``: the hand's actuated values by
    ``hand.dof_names`` (radians; metres for the Panda's fingers); ``joints``: every movable URDF
    joint by ``hand.joint_names``, the full state (after a Barrett breakaway the distal joints are
    ahead of their coupled values). ``contacts``: where the closed hand touches the object.
    ``epsilon``/``volume``: GraspIt's qualities of those contacts (see :mod:`quality`).
    """

    hand: str
    T_world_palm: np.ndarray
    dofs: dict[str, float]
    joints: dict[str, float]
    contacts: tuple[GraspContact, ...]
    epsilon: float
    volume: float

    @property
    def position(self) -> np.ndarray:
        """Palm position (world frame, m)."""
        return self.T_world_palm[:3, 3].copy()

    @property
    def quaternion_xyzw(self) -> np.ndarray:
        """Palm orientation as a unit quaternion (x, y, z, w), world frame."""
        return np.asarray(pose_to_pq(self.T_world_palm)[1])

    @property
    def approach(self) -> np.ndarray:
        """Approach direction (unit, world frame)."""
        return self.T_world_palm[:3, :3] @ np.asarray(get_hand(self.hand).approach, float)

    @property
    def force_closure(self) -> bool:
        return self.epsilon > 0.0


@dataclass(eq=False)
class Grasp(HandState):
    """A planned grasp (see :class:`HandState`). ``energy``: GraspIt's contact energy (m) of the
    virtual contacts in this state (lower is better). ``lift``: the planner's lift test of this
    state on the mesh it was planned on (None: not run)."""

    energy: float
    frame: str = "world"
    lift: LiftResult | None = None

    @property
    def lifted(self) -> bool:
        """The planner's lift check ran and the grasp picked the mesh up."""
        return self.lift is not None and self.lift.success
