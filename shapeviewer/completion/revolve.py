"""Surfaces of revolution on a table: the far side of a bowl, a cup or a can read off its near side.

Bowls, plates, cups, cans, jars and bottles rest on a table as surfaces of revolution about its
normal, upright or upside down. The network completes the side the camera sees and hedges on the far
side; an upside-down bowl's completion is the near half of the dome (docs/studies/grasp-misses.md). Here
the vertical axis is fitted to the observed points and the network's answer is revolved about it: at
every voxel, the answer's 75th percentile over the angles about the axis at the voxel's radius and
height, where it is larger than the answer itself.

:func:`shapeviewer.completion.pipeline.complete_points` does this for every segment on a table whose axis is
:attr:`RevolutionAxis.accepted` (points seen all round one side, at one radius per height within
depth noise); what only looks revolved from one side (a banana's arc, a box, a pitcher's handle) is
left as the network answered. All coordinates are metres; frames are named where they are used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..perception.camera import transform_points
from ..perception.segment import points_on_table
from .voxel import GridFrame

BIN_HEIGHT = 0.005  # metres: the observed points' radius is compared within height bins this tall
N_ANGLES = 36  # angles about the axis the answer is read at
PROFILE_PERCENTILE = 75.0  # of the answer over those angles (50 leaves domes open, 90 thickens walls)
MIN_ANGLES_INSIDE = 3  # a voxel whose circle has fewer angles inside the grid keeps its answer
CELLS_PER_VOXEL = 1  # the profile is sampled this many times per voxel size in radius and height
# A surface of revolution is seen from at least one side all round its axis, and its points lie at
# one radius per height; a banana's top is a circular arc about a vertical axis (40-150 deg of it
# seen) and a box's corners are far from any one radius (0.11-0.23 of it): both are left alone.
# A pitcher's handle and spout leave its body's points 6 mm from one radius at 84-100 mm (within
# 8 %), while a bowl's, cup's or mug's lie within 1-4 mm: depth noise, not shape.
MIN_COVERAGE_DEG = 180.0
MAX_RELATIVE_RESIDUAL = 0.08
MAX_RESIDUAL = 0.005  # metres
SEARCH_LEVELS = 4  # of the coarse-to-fine search: the last one steps 1/448 of the points' extent
FIT_POINTS = 1000  # the axis is fitted on a seeded subsample of this many points


@dataclass(frozen=True)
class RevolutionAxis:
    """A vertical axis (the table's normal) through an object resting on the table.

    Attributes:
        T_table_cam: 4x4 transform, camera frame -> table frame (metres; the table at z = 0, z up:
            :func:`~shapeviewer.perception.segment.table_frame`).
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
        return self.coverage_deg >= MIN_COVERAGE_DEG and self.residual <= min(
            MAX_RELATIVE_RESIDUAL * self.radius, MAX_RESIDUAL
        )


def _radius_spread(
    x: np.ndarray, y: np.ndarray, bins: np.ndarray, onehot: np.ndarray, centres: np.ndarray
) -> np.ndarray:
    """(C,) median |r - mean r of the point's height bin| of table-frame points (``x``, ``y``: (N,),
    metres) about each of ``centres`` (C, 2); ``bins`` (N,) the points' height bins, ``onehot``
    (N, B) the same as columns scaled by 1 / the bin's count."""
    r = np.hypot(x[None] - centres[:, :1], y[None] - centres[:, 1:])
    return np.median(np.abs(r - (r @ onehot)[:, bins]), axis=1)


def fit_axis(points_cam: np.ndarray, support_plane: np.ndarray, *, seed: int = 0) -> RevolutionAxis:
    """The vertical axis about which the observed points' radius is most nearly constant at each height.

    Args:
        points_cam: (N, 3) the segment's observed points, camera frame, metres.
        support_plane: ``(a, b, c, d)`` of the table in the camera frame (normal towards the camera).
        seed: picks the subsample of :data:`FIT_POINTS` points the search runs on.

    A coarse-to-fine grid search over the axis's position on the table plane, from the points'
    centroid out to 1.4 times their extent.
    """
    T, pts, table = points_on_table(points_cam, support_plane, fitting="an axis")
    if len(pts) > FIT_POINTS:
        keep = np.random.default_rng(seed).choice(len(pts), FIT_POINTS, replace=False)
        pts, table = pts[keep], table[keep]
    x, y = table[:, 0].astype(np.float32), table[:, 1].astype(np.float32)
    _, bins = np.unique(np.floor(table[:, 2] / BIN_HEIGHT).astype(np.int64), return_inverse=True)
    onehot = np.zeros((len(pts), bins.max() + 1), np.float32)
    onehot[np.arange(len(pts)), bins] = 1.0
    onehot /= onehot.sum(axis=0)
    best = table[:, :2].mean(axis=0)
    best_cost = float(_radius_spread(x, y, bins, onehot, best[None])[0])
    step = float(np.ptp(table[:, :2], axis=0).max()) / 7 + 1e-6
    span = 10 * step
    for _ in range(SEARCH_LEVELS):
        offsets = np.arange(-span, span + step / 2, step)
        centres = best + np.stack(np.meshgrid(offsets, offsets, indexing="ij"), axis=-1).reshape(-1, 2)
        costs = _radius_spread(x, y, bins, onehot, centres.astype(np.float32))
        k = int(np.argmin(costs))
        if costs[k] < best_cost:
            best, best_cost = centres[k], float(costs[k])
        span, step = 1.5 * step, step / 4
    rel = table[:, :2] - best
    angles = np.arctan2(rel[:, 1], rel[:, 0])
    covered = np.histogram(angles, bins=36, range=(-np.pi, np.pi))[0] > 0
    return RevolutionAxis(T, best, best_cost, float(np.linalg.norm(rel, axis=1).mean()), float(covered.mean() * 360))


def _percentile(values: np.ndarray, percentile: float, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """``(percentile, count)`` of the finite entries of ``values`` along ``axis`` (inf marks a missing
    entry), linear between ranks as :func:`numpy.percentile`; 0 where none is finite."""
    count = np.isfinite(values).sum(axis=axis)
    ordered = np.moveaxis(np.sort(values, axis=axis), axis, 0)  # the missing (inf) sort last
    rank = percentile / 100 * np.maximum(count - 1, 0)
    lo = np.floor(rank).astype(np.int64)
    hi = np.minimum(lo + 1, np.maximum(count - 1, 0))
    w = rank - lo
    low = np.take_along_axis(ordered, lo[None], axis=0)[0]
    high = np.take_along_axis(ordered, hi[None], axis=0)[0]
    value = np.where(count > 0, low, 0.0) * (1 - w) + np.where(w > 0, high, 0.0) * w
    return value, count


def revolve(
    probabilities: np.ndarray,
    frame: GridFrame,
    axis: RevolutionAxis,
    *,
    free: np.ndarray | None = None,
    percentile: float = PROFILE_PERCENTILE,
    n_angles: int = N_ANGLES,
) -> np.ndarray:
    """The network's answer revolved about ``axis``, [x, y, z] in ``frame``, float32.

    Args:
        probabilities: (40, 40, 40) one answer, or (K, 40, 40, 40) several (the sample completions),
            each revolved on its own; the result has the same shape.
        frame: the grid's frame (grid coordinates <-> camera metres).
        axis: the fitted axis (:func:`fit_axis`).
        free: (40, 40, 40) bool voxels known to be empty (the camera saw through them,
            :func:`~shapeviewer.completion.voxel.context_grids`); they keep their answer.
        percentile, n_angles: the profile at a radius and height is this percentile of the answer
            (trilinear) at ``n_angles`` angles about the axis, over the angles whose point lies inside
            the grid.

    Every voxel takes the larger of its own answer and the profile at its radius and height (the
    profile is sampled every voxel size in radius and height and read bilinearly); voxels under the
    table, and where fewer than :data:`MIN_ANGLES_INSIDE` angles fall in the grid, keep their answer.
    """
    p = np.asarray(probabilities, dtype=np.float32)
    stack = p.reshape((-1,) + p.shape[-3:])
    dim = frame.dim
    h = frame.voxel_size / CELLS_PER_VOXEL
    index = np.indices((dim,) * 3).reshape(3, -1).T
    T = axis.T_table_cam
    table = transform_points(T, frame.voxel_centers(index))
    keep = table[:, 2] > 0
    if free is not None:
        keep &= ~np.asarray(free, dtype=bool).reshape(-1)
    if not keep.any():
        return p.copy()
    # The profile's cells: radius j * h, height z0 + k * h (j, k = 0, 1, ...); only the cells a kept
    # voxel's bilinear read touches are computed.
    radius = np.linalg.norm(table[keep, :2] - axis.centre, axis=1)
    z0 = float(table[keep, 2].min())
    at = np.stack([radius / h, (table[keep, 2] - z0) / h])
    corner = np.floor(at).astype(np.int64)
    n_r, n_z = corner[0].max() + 2, corner[1].max() + 2
    needed = np.zeros((n_r, n_z), bool)
    for dr in (0, 1):
        for dz in (0, 1):
            needed[corner[0] + dr, corner[1] + dz] = True
    cells = np.argwhere(needed) * h
    angles = np.linspace(0.0, 2 * np.pi, n_angles, endpoint=False)
    around = np.stack(
        [
            axis.centre[0] + cells[None, :, 0] * np.cos(angles)[:, None],
            axis.centre[1] + cells[None, :, 0] * np.sin(angles)[:, None],
            np.broadcast_to(z0 + cells[None, :, 1], (n_angles, len(cells))),
        ],
        axis=-1,
    ).reshape(-1, 3)
    g = frame.to_grid(transform_points(np.linalg.inv(T), around)) - 0.5
    inside = ((g >= 0) & (g <= dim - 1)).all(axis=1)
    values = np.full((len(stack), len(g)), np.inf, dtype=np.float32)
    for i, grid in enumerate(stack):
        values[i, inside] = ndimage.map_coordinates(grid, g[inside].T, order=1)
    profile, count = _percentile(values.reshape(len(stack), n_angles, len(cells)), percentile, axis=1)
    profiles = np.zeros((len(stack), n_r, n_z), np.float32)
    profiles[:, needed] = np.where(count >= MIN_ANGLES_INSIDE, profile, 0.0)
    # Bilinear read of every profile at the kept voxels' radius and height.
    w = at - corner
    read = sum(
        profiles[:, corner[0] + dr, corner[1] + dz] * ((w[0] if dr else 1 - w[0]) * (w[1] if dz else 1 - w[1]))
        for dr in (0, 1)
        for dz in (0, 1)
    )
    out = stack.reshape(len(stack), -1).copy()
    out[:, keep] = np.maximum(out[:, keep], read)
    return out.reshape(p.shape)
