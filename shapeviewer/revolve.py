"""Surfaces of revolution on a table: the far side of a bowl, a cup or a can read off its near side.

Bowls, plates, cups, cans, jars and bottles rest on a table as surfaces of revolution about its
normal, upright or upside down. The network completes the side the camera sees and hedges on the far
side; an upside-down bowl's completion is the near half of the dome (model card, "Session 32"). Here
the vertical axis is fitted to the observed points and the network's answer is revolved about it: at
every voxel, the answer's 75th percentile over the angles about the axis at the voxel's radius and
height, where it is larger than the answer itself.

Not yet part of :func:`shapeviewer.complete`: it helps bowls, cups and jars and hurts what only
looks revolved from one side, and :attr:`RevolutionAxis.accepted` is still being measured
(``python benchmarks/revolve.py <results folder>``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .segment import table_frame
from .voxel import GridFrame, unit_plane

BIN_HEIGHT = 0.005  # metres: the observed points' radius is compared within height bins this tall
N_ANGLES = 72  # angles about the axis the answer is read at
PROFILE_PERCENTILE = 75.0  # of the answer over those angles (50 leaves domes open, 90 thickens walls)
MIN_ANGLES_INSIDE = 3  # a voxel whose circle has fewer angles inside the grid keeps its answer
# A surface of revolution is seen from at least one side all round its axis, and its points lie at
# one radius per height; a banana's top is a circular arc about a vertical axis (40-150 deg of it
# seen) and a box's corners are far from any one radius (0.11-0.23 of it): both are left alone.
MIN_COVERAGE_DEG = 180.0
MAX_RELATIVE_RESIDUAL = 0.08
FIT_POINTS = 3000  # the axis is fitted on a seeded subsample of this many points


@dataclass(frozen=True)
class RevolutionAxis:
    """A vertical axis (the table's normal) through an object resting on the table.

    Attributes:
        T_table_cam: 4x4 transform, camera frame -> table frame (metres; the table at z = 0, z up:
            :func:`~shapeviewer.segment.table_frame`).
        centre: (2,) the axis's x, y in the table frame, metres.
        residual: median distance of the observed points' radius from their height bin's mean, metres.
        radius: mean distance of the observed points from the axis, metres.
        coverage_deg: how much of the full turn about the axis the observed points cover (10 deg bins).
    """

    T_table_cam: np.ndarray
    centre: np.ndarray
    residual: float
    radius: float
    coverage_deg: float

    @property
    def accepted(self) -> bool:
        """Whether the points look like a surface of revolution about this axis."""
        return self.coverage_deg >= MIN_COVERAGE_DEG and self.residual <= MAX_RELATIVE_RESIDUAL * self.radius


def _radius_spread(xy: np.ndarray, bins: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """|r - mean r of the point's height bin| of table-frame points ``xy`` (metres) about ``centre``."""
    r = np.linalg.norm(xy - centre, axis=1)
    mean = np.bincount(bins, r) / np.bincount(bins)
    return np.abs(r - mean[bins])


def fit_axis(points_cam: np.ndarray, support_plane: np.ndarray, *, seed: int = 0) -> RevolutionAxis:
    """The vertical axis about which the observed points' radius is most nearly constant at each height.

    Args:
        points_cam: (N, 3) the segment's observed points, camera frame, metres.
        support_plane: ``(a, b, c, d)`` of the table in the camera frame (normal towards the camera).
        seed: picks the subsample of :data:`FIT_POINTS` points the search runs on.

    A coarse-to-fine grid search over the axis's position on the table plane, from the points'
    centroid out to 1.5 times their extent.
    """
    n, d = unit_plane(support_plane)
    T = table_frame(np.r_[n, d])
    pts = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) < 10:
        raise ValueError(f"{len(pts)} points are too few to fit an axis")
    if len(pts) > FIT_POINTS:
        pts = pts[np.random.default_rng(seed).choice(len(pts), FIT_POINTS, replace=False)]
    table = pts @ T[:3, :3].T + T[:3, 3]
    xy = table[:, :2]
    _, bins = np.unique(np.floor(table[:, 2] / BIN_HEIGHT).astype(np.int64), return_inverse=True)
    best = xy.mean(axis=0)
    best_cost = float(np.median(_radius_spread(xy, bins, best)))
    step = float(np.ptp(xy, axis=0).max()) / 10 + 1e-6
    span = 15 * step
    for _ in range(5):
        offsets = np.arange(-span, span + step / 2, step)
        centre = best
        for dx in offsets:
            for dy in offsets:
                c = centre + (dx, dy)
                cost = float(np.median(_radius_spread(xy, bins, c)))
                if cost < best_cost:
                    best, best_cost = c, cost
        span, step = 1.5 * step, step / 4
    rel = xy - best
    angles = np.arctan2(rel[:, 1], rel[:, 0])
    covered = np.histogram(angles, bins=36, range=(-np.pi, np.pi))[0] > 0
    return RevolutionAxis(T, best, best_cost, float(np.linalg.norm(rel, axis=1).mean()), float(covered.mean() * 360))


def revolve(
    probabilities: np.ndarray,
    frame: GridFrame,
    axis: RevolutionAxis,
    *,
    percentile: float = PROFILE_PERCENTILE,
    n_angles: int = N_ANGLES,
) -> np.ndarray:
    """The network's answer revolved about ``axis``: (40, 40, 40) float32, [x, y, z] in ``frame``.

    At every voxel, the larger of its own answer and the ``percentile`` of the answer (trilinear)
    at ``n_angles`` angles about the axis at the voxel's radius and height, over the angles whose
    point lies inside the grid; voxels under the table stay as they were.
    """
    p = np.asarray(probabilities, dtype=np.float32)
    dim = frame.dim
    index = np.stack(np.meshgrid(*[np.arange(dim)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    T = axis.T_table_cam
    T_cam_table = np.linalg.inv(T)
    table = frame.voxel_centers(index) @ T[:3, :3].T + T[:3, 3]
    radius = np.linalg.norm(table[:, :2] - axis.centre, axis=1)
    values = np.full((n_angles, len(index)), np.inf, dtype=np.float32)
    for k, angle in enumerate(np.linspace(0.0, 2 * np.pi, n_angles, endpoint=False)):
        around = np.c_[axis.centre[0] + radius * np.cos(angle), axis.centre[1] + radius * np.sin(angle), table[:, 2]]
        g = frame.to_grid(around @ T_cam_table[:3, :3].T + T_cam_table[:3, 3]) - 0.5
        inside = ((g >= 0) & (g <= dim - 1)).all(axis=1)
        values[k, inside] = ndimage.map_coordinates(p, g[inside].T, order=1)
    count = np.isfinite(values).sum(axis=0)
    ordered = np.sort(values, axis=0)  # the angles outside the grid (inf) sort last
    rank = percentile / 100 * np.maximum(count - 1, 0)
    lo = np.floor(rank).astype(np.int64)
    hi = np.minimum(lo + 1, np.maximum(count - 1, 0))
    cols = np.arange(len(index))
    w = rank - lo
    profile = ordered[lo, cols] * (1 - w) + np.where(w > 0, ordered[hi, cols], 0) * w
    keep = (count >= MIN_ANGLES_INSIDE) & (table[:, 2] > 0)
    profile = np.where(keep, profile, 0.0).reshape((dim,) * 3)
    return np.maximum(p, profile).astype(np.float32)
