"""Boxes on a table: a cuboid fitted to the points of a segment that is one.

A box rests on a table on one of its faces, so its edges are the table's normal and two directions
on the table, and a camera above the table sees its whole top face: the observed points span its
true extents (within 5 mm on the tabletop views), while the network's completion of a box is larger
along every axis (3-29 mm, median about 10 mm; docs/studies/grasp-misses.md). Here the cuboid is fitted
to the points and, when they look like one (:attr:`Cuboid.accepted`), its occupancy replaces the
network's answers (:func:`shapeviewer.completion.pipeline.complete_points`).

All coordinates are metres; frames are named where they are used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from ..perception.camera import transform_points
from ..perception.segment import points_on_table
from .voxel import GridFrame

EXTENT_PERCENTILE = 0.5  # the box spans the points' 0.5th to 99.5th percentile along each edge,
HEIGHT_PERCENTILE = 98.0  # and from the table up to this percentile of their height,
# widened on the table by the rim of each face a depth camera loses at the silhouette (flying and
# missing pixels there): the points of YCB boxes on the tabletop views stop 2-3 mm short of each edge.
SILHOUETTE_MARGIN = 0.0025  # metres
FIT_POINTS = 2000  # the normals are fitted on a seeded subsample of this many points,
YAW_POINTS = 500  # and the yaw coarsely on this many of them
# A box's footprint is the rectangle its points fill; a can's or a bowl's disc fills pi / 4 of
# its bounding square, a banana's arc or a drill far less.
MIN_FILL = 0.9
# A box's points lie on its faces within depth noise; a can lying on its side, whose footprint is a
# rectangle too, has its curved side up to 0.29 of its radius off the faces.
MAX_RESIDUAL = 0.004  # metres, the 90th percentile of the points' distance to the box's surface
MIN_EXTENT = 0.01  # metres: thinner than this is a sheet, not a box
NORMAL_NEIGHBOURS = 30  # points a surface normal is fitted to
ALIGNED_DEG = 15.0  # a normal this close to one of the box's edges is on one of its faces
# A box's points have their normals along its edges but at its rounded edges and where depth noise
# tilts them (0.84-0.92 of them on the tabletop views' boxes); a bottle's, jar's or plate's at most 0.8.
MIN_ALIGNED = 0.8


@dataclass(frozen=True)
class Cuboid:
    """A box resting on the table.

    Attributes:
        T_table_cam: 4x4 transform, camera frame -> table frame (metres; the table at z = 0, z up:
            :func:`~shapeviewer.perception.segment.table_frame`).
        centre: (2,) the footprint's centre, x, y in the table frame, metres.
        yaw: the angle of the box's first edge from the table frame's x axis, radians.
        extents: (3,) the edge lengths, metres: along ``yaw``, across it, and the height above the table.
        residual: the 90th percentile of the observed points' distance to the surface of the box they
            span (before :data:`SILHOUETTE_MARGIN` widens it), metres.
        fill: the share of the footprint rectangle the points' convex hull on the table covers.
        aligned: the share of the points whose surface normal lies within :data:`ALIGNED_DEG` of one
            of the box's edges (on one of its faces).
    """

    T_table_cam: np.ndarray
    centre: np.ndarray
    yaw: float
    extents: np.ndarray
    residual: float
    fill: float
    aligned: float

    @property
    def accepted(self) -> bool:
        """Whether the points look like a box: they fill its footprint, lie on its faces and face along
        its edges."""
        return (
            self.fill >= MIN_FILL
            and self.residual <= MAX_RESIDUAL
            and self.aligned >= MIN_ALIGNED
            and bool(np.all(self.extents >= MIN_EXTENT))
        )

    def to_box(self, points_cam: np.ndarray) -> np.ndarray:
        """(N, 3) camera-frame points (metres) in the box's own frame: origin at its centre, axes along
        its edges (metres)."""
        table = transform_points(self.T_table_cam, np.asarray(points_cam).reshape(-1, 3))
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        rel = table[:, :2] - self.centre
        return np.column_stack([rel @ [c, s], rel @ [-s, c], table[:, 2] - self.extents[2] / 2])

    def signed_distance(self, points_cam: np.ndarray) -> np.ndarray:
        """(N,) signed distance of camera-frame points (metres) to the box's surface, negative inside, metres."""
        q = np.abs(self.to_box(points_cam)) - np.asarray(self.extents) / 2
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
        return outside + np.minimum(q.max(axis=1), 0.0)


def _footprint(uv: np.ndarray) -> tuple[float, float]:
    """``(yaw, area)``: the direction and area of the smallest rectangle holding the points' central
    percentiles, ``uv`` (N, 2) table-frame metres, in no order; yaw searched every degree on the
    first :data:`YAW_POINTS` of them, then every 0.1 degree on all."""
    lo, hi = EXTENT_PERCENTILE, 100 - EXTENT_PERCENTILE

    def areas(uv: np.ndarray, yaws: np.ndarray) -> np.ndarray:
        c, s = np.cos(yaws), np.sin(yaws)
        a = uv @ np.stack([c, s])  # (N, Y) along each yaw
        b = uv @ np.stack([-s, c])
        span = lambda v: np.diff(np.percentile(v, [lo, hi], axis=0), axis=0)[0]  # noqa: E731
        return span(a) * span(b)

    coarse = np.deg2rad(np.arange(0.0, 90.0, 1.0))
    best = coarse[int(np.argmin(areas(uv[:YAW_POINTS], coarse)))]
    fine = best + np.deg2rad(np.arange(-1.0, 1.0001, 0.1))
    a = areas(uv, fine)
    k = int(np.argmin(a))
    return float(fine[k] % (np.pi / 2)), float(a[k])


def fit_cuboid(points_cam: np.ndarray, support_plane: np.ndarray, *, seed: int = 0) -> Cuboid:
    """The box on the table that the observed points span.

    Args:
        points_cam: (N, 3) the segment's observed points, camera frame, metres.
        support_plane: ``(a, b, c, d)`` of the table in the camera frame (normal towards the camera).
        seed: picks the subsamples the normals (:data:`FIT_POINTS`) and the yaw (:data:`YAW_POINTS`)
            are fitted on.

    The yaw is that of the smallest rectangle on the table holding the points' 0.5th-99.5th
    percentiles along its edges; the box spans those percentiles and reaches from the table up to the
    points' 98th percentile of height; on the table it is widened by :data:`SILHOUETTE_MARGIN` each side.
    """
    T, pts, table = points_on_table(points_cam, support_plane, fitting="a box")
    sub = table[np.random.default_rng(seed).permutation(len(table))[:FIT_POINTS]]  # in no order
    yaw, _ = _footprint(sub[:, :2])
    c, s = np.cos(yaw), np.sin(yaw)
    a, b = table[:, :2] @ [c, s], table[:, :2] @ [-s, c]
    lo, hi = EXTENT_PERCENTILE, 100 - EXTENT_PERCENTILE
    (a0, a1), (b0, b1) = np.percentile(a, [lo, hi]), np.percentile(b, [lo, hi])
    height = float(np.percentile(table[:, 2], HEIGHT_PERCENTILE))
    centre = np.array([c * (a0 + a1) / 2 - s * (b0 + b1) / 2, s * (a0 + a1) / 2 + c * (b0 + b1) / 2])
    inside = (a >= a0) & (a <= a1) & (b >= b0) & (b <= b1)
    try:
        hull_area = ConvexHull(np.column_stack([a[inside], b[inside]])).volume if inside.sum() >= 3 else 0.0
    except QhullError:  # the points are collinear on the table
        hull_area = 0.0
    fill = float(hull_area / max((a1 - a0) * (b1 - b0), 1e-12))
    spanned = np.array([a1 - a0, b1 - b0, max(height, 0.0)])
    residual = float(np.percentile(np.abs(Cuboid(T, centre, yaw, spanned, 0.0, fill, 0.0).signed_distance(pts)), 90))
    extents = spanned + [2 * SILHOUETTE_MARGIN, 2 * SILHOUETTE_MARGIN, 0.0]
    edges = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # the box's edges in the table frame
    cosines = np.abs(_normals(sub) @ edges.T).max(axis=1)
    aligned = float((cosines >= np.cos(np.deg2rad(ALIGNED_DEG))).mean())
    return Cuboid(T, centre, yaw, extents, residual, fill, aligned)


def _normals(points: np.ndarray) -> np.ndarray:
    """(N, 3) unit surface normals (unsigned) of (N, 3) points, each fitted to its
    :data:`NORMAL_NEIGHBOURS` nearest points."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(NORMAL_NEIGHBOURS))
    return np.asarray(cloud.normals)


def occupancy(cuboid: Cuboid, frame: GridFrame) -> np.ndarray:
    """(D, D, D) float32 [x, y, z] the box's occupancy of ``frame``'s voxels: 1 inside, 0 outside,
    falling linearly over one voxel across the surface, so that the 0.5 level lies on it."""
    index = np.indices((frame.dim,) * 3).reshape(3, -1).T
    sdf = cuboid.signed_distance(frame.voxel_centers(index))
    p = np.clip(0.5 - sdf / frame.voxel_size, 0.0, 1.0)
    return p.reshape((frame.dim,) * 3).astype(np.float32)
