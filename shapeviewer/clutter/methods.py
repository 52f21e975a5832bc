"""Grasping methods for the clutter-removal benchmark, and the interface every method implements.

A method is a function ``method(capture, segmentation, info) -> list[GraspPose]``: from the side
view's :class:`~shapeviewer.perception.capture.Capture` (organized, camera optical frame, metres,
with its intrinsics and true ``T_world_cam``), its :func:`~shapeviewer.segment_scene` segmentation
and the :class:`WorldInfo` of the benchmark's world, it returns grasps ranked best first, each the
Panda's palm pose in the world frame and an opening width (:class:`~.execute.GraspPose`). The
benchmark executes the first; an empty list means the method found no grasp (the round ends).

A method that takes long should ask ``info.cancel()`` now and then and stop when it says True (its
time is up): the pick's :func:`~shapeviewer.grasp.pick.rank_grasps` takes it as its ``cancel``.
The planner's world has the table at z = 0, this one at ``info.table_z``: :meth:`WorldInfo.T_world_table`
moves grasps planned in the table frame (e.g. of ``robust_grasps``) into it.

Methods here: ``Highest``, a top-down grasp at the highest point of the highest segment.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache

import numpy as np

from ..perception.camera import transform_points
from ..perception.capture import Capture
from ..perception.segment import Segment, Segmentation
from .execute import TCP_OFFSET, GraspPose, tcp_to_palm
from .scene import FINGER_DEPTH, MAX_OPENING, TABLE_Z, WORKSPACE

# The volume grasps are looked for in (the benchmark's): 2 cm in from the workspace's sides, from
# just above the table to the workspace's top (world frame, m).
GRASP_MARGIN = 0.02
TABLE_CLEARANCE = 0.005
# Highest: the top of a segment is this percentile of its points' heights (a few noisy points
# above the surface do not count), the grasp point the middle of its points within TOP_BAND of
# the top, the fingers close across the narrower side of its points within SPAN_BAND of the top,
# and the TCP goes GRASP_DEPTH below the top, the fingertips staying TIP_CLEARANCE above the table.
TOP_PERCENTILE = 99.0
TOP_BAND = 0.01  # m
SPAN_BAND = 0.03  # m
GRASP_DEPTH = 0.01  # m
TIP_CLEARANCE = 0.005  # m
MIN_SEGMENT_POINTS = 30


def _never() -> bool:
    return False


@dataclass(frozen=True, eq=False)
class WorldInfo:
    """What a method knows of the benchmark's world besides the capture.

    Attributes:
        T_world_cam: the camera's true pose (4x4, world frame).
        table_z: height of the table top (m, world frame).
        lower, upper: corners of the volume grasps are looked for in (m, world frame).
        hand: the hand's name (:data:`shapeviewer.grasp.hands.HAND_NAMES`).
        max_opening, finger_depth: the hand's widest opening and finger depth (m).
        seed: a seed for the method's own random choices, fixed per attempt.
        cancel: True once the method's time is up.
    """

    T_world_cam: np.ndarray
    table_z: float = TABLE_Z
    lower: np.ndarray = field(default_factory=lambda: np.array([GRASP_MARGIN, GRASP_MARGIN, TABLE_Z + TABLE_CLEARANCE]))
    upper: np.ndarray = field(
        default_factory=lambda: np.array([WORKSPACE - GRASP_MARGIN, WORKSPACE - GRASP_MARGIN, WORKSPACE])
    )
    hand: str = "panda"
    max_opening: float = MAX_OPENING
    finger_depth: float = FINGER_DEPTH
    seed: int = 0
    cancel: Callable[[], bool] = _never

    @property
    def T_world_table(self) -> np.ndarray:
        """The table frame (the planner's world: table top z = 0, +z up) in this world."""
        T = np.eye(4)
        T[2, 3] = self.table_z
        return T

    def table_plane_cam(self) -> np.ndarray:
        """The true table plane ``(a, b, c, d)`` in the camera frame, unit normal towards the camera
        (as :attr:`Segmentation.plane_cam`): ``d`` is the camera's height above the table (m)."""
        T_cam_world = np.linalg.inv(self.T_world_cam)
        n = T_cam_world[:3, :3] @ np.array([0.0, 0.0, 1.0])
        point = T_cam_world[:3, :3] @ np.array([0.0, 0.0, self.table_z]) + T_cam_world[:3, 3]
        return np.r_[n, -float(n @ point)]


Method = Callable[[Capture, Segmentation, WorldInfo], list[GraspPose]]


def depth_scale(segmentation: Segmentation, info: WorldInfo) -> float:
    """The factor the capture's depths are off by, from the table's measured distance against its
    known one (the benchmark's noise scales a whole image by one Gamma draw, about 3 %: 2 cm at the
    table); 1 without a plane. Dividing camera-frame points by it undoes that part of the noise."""
    if segmentation.plane_cam is None:
        return 1.0
    measured = float(segmentation.plane_cam[3])
    true = float(info.table_plane_cam()[3])
    return measured / true if measured > 0 and true > 0 else 1.0


def segment_world(segment: Segment, info: WorldInfo, scale: float = 1.0) -> np.ndarray:
    """A segment's points in the world frame (m), their depths divided by ``scale``
    (:func:`depth_scale`), and only those within the grasp volume."""
    pts = transform_points(info.T_world_cam, np.asarray(segment.points_cam, dtype=np.float64) / scale)
    inside = np.all((pts >= info.lower) & (pts <= info.upper), axis=1)
    return pts[inside]


@cache
def finger_reach() -> float:
    """How far (m) the Panda's fingertips reach in front of its palm face, open."""
    from ..grasp.hands import get_hand

    hand = get_hand("panda")
    poses = hand.link_poses(hand.joints_from_dofs(hand.dof_open))
    reach = 0.0
    for finger in hand.fingers:
        for link in finger.links:
            for g in hand.model.collisions[link]:
                pts = g.sample_points() @ poses[link][:3, :3].T + poses[link][:3, 3]
                reach = max(reach, float(pts[:, 2].max()))
    return reach


def top_down_grasp(points_world: np.ndarray, info: WorldInfo) -> GraspPose:
    """A top-down grasp of the highest point of ``points_world`` (N, 3; world frame, m): the fingers
    closing across the narrower horizontal side of the points near the top, the TCP GRASP_DEPTH
    below the top but the fingertips no lower than TIP_CLEARANCE above the table; score: the top's height."""
    z = points_world[:, 2]
    top = float(np.percentile(z, TOP_PERCENTILE))
    xy = np.median(points_world[z >= top - TOP_BAND, :2], axis=0)
    near = points_world[z >= top - SPAN_BAND, :2]
    closing = np.array([1.0, 0.0])
    if len(near) >= 3:
        cov = np.cov((near - near.mean(axis=0)).T)
        if np.all(np.isfinite(cov)):
            closing = np.linalg.eigh(cov)[1][:, 0]  # the direction of least spread
    y = np.r_[closing, 0.0]
    zaxis = np.array([0.0, 0.0, -1.0])
    T_tcp = np.eye(4)
    T_tcp[:3, :3] = np.column_stack([np.cross(y, zaxis), y, zaxis])
    tip_below_tcp = finger_reach() - TCP_OFFSET
    T_tcp[:3, 3] = [xy[0], xy[1], max(top - GRASP_DEPTH, info.table_z + TIP_CLEARANCE + tip_below_tcp)]
    return GraspPose(tcp_to_palm(T_tcp), info.max_opening, top)


def highest(capture: Capture, segmentation: Segmentation, info: WorldInfo) -> list[GraspPose]:
    """``Highest``: a top-down grasp at the highest point of each segment, the highest segment first.

    The segments' points are moved to the world frame with the camera's true pose as measured (no
    correction of the depth noise's scale: the heuristic faces the benchmark's noise as every
    method does) and cut to the grasp volume; segments with fewer than MIN_SEGMENT_POINTS points
    left are skipped."""
    grasps = []
    for segment in segmentation.segments:
        pts = segment_world(segment, info)
        if len(pts) >= MIN_SEGMENT_POINTS:
            grasps.append(top_down_grasp(pts, info))
    return sorted(grasps, key=lambda g: -g.score)


METHODS: dict[str, Method] = {"Highest": highest}


def get_method(name: str) -> Method:
    """The method called ``name`` (a key of :data:`METHODS`)."""
    if name not in METHODS:
        raise ValueError(f"unknown clutter method {name!r}; known: {', '.join(METHODS)}")
    return METHODS[name]
