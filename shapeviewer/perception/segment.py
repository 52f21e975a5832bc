"""Segmentation (paper Fig. 5, step 2): support plane removal, then Euclidean cluster extraction.

Everything is in the camera optical frame (metres; x right, y down, z forward):

1. keep the finite points in front of the camera closer than ``max_range``;
2. find the support plane by RANSAC on a random subsample, refined by least squares on its
   inliers. The plane must hold ``min_plane_fraction`` of the subsample and span ``min_plane_extent``
   (so a box face is not taken for a table); among up to three planes the first that faces the
   camera's up (-y) wins, else the largest. No such plane: everything is clustered;
3. keep the points between ``min_height`` and ``max_height`` above the plane, on the camera's side
   (by default ``min_height`` is :func:`table_band`: just above the table's own depth noise);
4. voxel-downsample them, join voxel centroids closer than ``cluster_tolerance`` (Euclidean
   clustering is the connected components of that graph) and give every point its voxel's cluster;
5. drop each cluster's flying pixels (:func:`flying_pixels`) and cluster what is left again: a
   depth camera's silhouette pixels trail off an object towards what lies behind it, and bridge
   the gap to a neighbour 3-12 cm away;
6. drop the clusters of fewer than ``min_points`` points or whose bounding box is longer than
   ``max_extent`` (walls, furniture), and number the rest left to right in the image.

The RANSAC is our own vectorised numpy one: Open3D's ``segment_plane`` runs its iterations on
several threads and returns different planes for the same seed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import ShapeviewerError
from .camera import transform_points
from .capture import Capture
from .flying_pixels import _flying_pixels_organized, flying_pixels

# Occupied voxels clustered at most (see segment_scene's max_voxels): 200k voxels with their
# 2.5 cm neighbourhoods take about a second; real 640x480 tabletop frames have 300-5,000.
MAX_VOXELS = 200_000
# Defaults that segment_scene and isolate share, so that a segment cut by either looks the same.
VOXEL_SIZE = 0.01  # m: voxels clustered
CLUSTER_TOLERANCE = 0.025  # m: the largest gap inside one cluster
# The band above the support plane left to the table: its depth noise, measured on the points just
# below it (nothing solid lies under a table, so they are noise), times TABLE_NOISE_SIGMAS, within
# MIN_HEIGHT..MAX_MIN_HEIGHT. A fixed 1.5 cm cut the table's noise off in the worst views but also
# 60 % of a plate's points, 30 % of a bowl's and the foot of every object the network completes.
MIN_HEIGHT = 0.005  # m: the band when the table is noiseless or absent from the points
MAX_MIN_HEIGHT = 0.015  # m: the band for the noisiest table
TABLE_NOISE_SIGMAS = 3.5  # the band in the table's noise (RMS height of the points under it)
TABLE_NOISE_DEPTH = 0.03  # m: points this far below the plane at most count as its noise
TABLE_NOISE_MIN_POINTS = 20  # fewer points under the plane than this: no table in the points
MAX_HEIGHT = 0.5  # m above the support plane
OBJECT_RANGE = 1.5  # m from the camera: the workspace segments are kept in (segment_scene's object_range)
# isolate: a selection of one object's points (a mask) can fall apart into clusters where a part's
# connection is hidden or dropped at depth edges (a dumbbell's bar, a mug's handle); a cluster of
# at least PART_SHARE of the largest one's points within PART_GAP of it is part of the object, not
# a stray pixel or the table's edge.
PART_SHARE = 0.2
PART_GAP = 0.1  # m
# Up to this many planes are tried when looking for a horizontal one (a wall may be larger).
_MAX_PLANES = 3
# A support plane faces the camera's up (-y) within this many degrees.
_MAX_TILT_DEG = 60.0
# Distinct colours (Trubetskoy's list) without greys, which the table and the cloud use.
PALETTE = np.array(
    [
        (230, 25, 75),
        (60, 180, 75),
        (0, 130, 200),
        (245, 130, 48),
        (145, 30, 180),
        (70, 240, 240),
        (240, 50, 230),
        (210, 245, 60),
        (250, 190, 212),
        (0, 128, 128),
        (170, 110, 40),
        (255, 225, 25),
    ],
    dtype=np.uint8,
)


class SegmentationError(ShapeviewerError, ValueError):
    """Input that cannot be segmented at all (malformed, empty, no finite point, bad parameters)."""


@dataclass
class Segment:
    """One object candidate.

    Attributes:
        id: position in :attr:`Segmentation.segments` (left to right in the image).
        indices: (N,) int64 rows of ``capture.flat_points()`` that belong to the segment.
        points_cam: (N, 3) those points, camera optical frame metres.
        color: (3,) uint8 RGB display colour, distinct from the other segments' (up to 12).
        label: human-readable summary, e.g. ``segment 0 (1234 pts, 12 cm)`` (longest box side).
    """

    id: int
    indices: np.ndarray
    points_cam: np.ndarray
    color: np.ndarray
    label: str

    @property
    def centroid(self) -> np.ndarray:
        """(3,) mean of the points, camera frame metres."""
        return self.points_cam.mean(axis=0)

    @property
    def extent(self) -> np.ndarray:
        """(3,) side lengths of the camera-frame axis-aligned bounding box, metres."""
        return self.points_cam.max(axis=0) - self.points_cam.min(axis=0)


@dataclass
class Segmentation:
    """The result of :func:`segment_scene`.

    Attributes:
        segments: the objects found, numbered nearest first (their centroid's distance from the camera).
        plane_cam: (4,) support plane ``(a, b, c, d)`` in the camera frame, ``n . p + d = 0`` with
            unit normal ``n`` pointing to the camera's side (so ``d`` is the camera's height above
            it); None when no support plane was found.
        T_world_cam: 4x4 camera pose in a table-aligned world frame (metres): z is the plane
            normal (up), the origin is the camera centre's foot on the plane, x follows the
            camera's x. Identity when there is no plane.
        timings: seconds per stage (``prepare``, ``plane``, ``downsample``, ``cluster``,
            ``segments``) and ``total``.
        table_indices: (M,) int64 rows of ``capture.flat_points()`` within ``plane_distance`` of the plane.
        min_height: the bottom of the height band the segments were cut from (m above the plane;
            :func:`table_band` unless given); None when there is no plane.
    """

    segments: list[Segment]
    plane_cam: np.ndarray | None
    T_world_cam: np.ndarray
    timings: dict[str, float] = field(default_factory=dict)
    table_indices: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    min_height: float | None = None


def segment_scene(
    capture_or_points: Capture | np.ndarray,
    *,
    voxel_size: float = VOXEL_SIZE,
    plane_distance: float = 0.01,
    cluster_tolerance: float = CLUSTER_TOLERANCE,
    min_points: int = 200,
    max_extent: float = 0.5,
    min_height: float | None = None,
    max_height: float = MAX_HEIGHT,
    max_range: float = 3.0,
    object_range: float | None = OBJECT_RANGE,
    min_plane_fraction: float = 0.1,
    min_plane_extent: float = 0.4,
    ransac_iterations: int = 400,
    ransac_samples: int = 2000,
    seed: int = 0,
    max_voxels: int = MAX_VOXELS,
) -> Segmentation:
    """Remove the support plane and split what stands on it into Euclidean clusters.

    Args:
        capture_or_points: a :class:`Capture`, or camera-frame points (N, 3) or (H, W, 3), metres;
            NaN rows allowed. Segment indices refer to the flattened points.
        voxel_size: voxel edge (m) of the downsampling done before clustering. The clustering
            cost grows with (cluster_tolerance / voxel_size)^2 neighbours per voxel: 1 cm keeps a
            640x480 frame within the paper's 0.119 s and splits the same objects as 5 mm did.
        plane_distance: RANSAC inlier distance (m); also the band reported as table.
        cluster_tolerance: largest gap (m) inside one cluster; at least ``voxel_size``. 2.5 cm
            rather than PCL's customary 2 cm: the Kinect drops pixels at depth edges, which left a
            2.2 cm gap between the bleach bottle and its handle in the real capture.
        min_points: smallest cluster kept, counted in original points.
        max_extent: clusters with a longer bounding-box side (m) are dropped.
        min_height, max_height: height band (m) above the plane kept for clustering; None:
            ``min_height`` is :func:`table_band` of the frame's points.
        max_range: points farther along z (m) are ignored.
        object_range: segments whose centroid is farther than this from the camera (m) are dropped: a
            robot's tabletop workspace. A plane seen to the back of a room carries the far background's
            fragments (a few hundred points, 1.5-2.5 m away in the real captures), which are not
            objects to complete. None keeps every segment within ``max_range``.
        min_plane_fraction: smallest share of the points a support plane must hold.
        min_plane_extent: smallest in-plane span (m, longer axis) of a support plane.
        ransac_iterations, ransac_samples: RANSAC hypotheses and the subsample they are scored on.
        seed: the random seed; the result is a function of the input and the seed.
        max_voxels: more occupied voxels than this (real tabletop frames have a few thousand) are
            clustered at a coarser voxel size, which bounds the time and memory of the clustering.

    Returns:
        The segmentation. A cloud with nothing standing on the plane, or whose clusters are all
        too small or too large, honestly gives an empty ``segments`` list.

    Raises:
        SegmentationError: input that is not (N, 3)/(H, W, 3) numbers, empty, without any finite
            point in range, or nonsensical parameters.
    """
    t0 = time.perf_counter()
    timings: dict[str, float] = {}

    def lap(stage: str) -> None:
        timings[stage] = time.perf_counter() - t0 - sum(timings.values())

    _check_parameters(
        voxel_size=voxel_size,
        plane_distance=plane_distance,
        cluster_tolerance=cluster_tolerance,
        max_extent=max_extent,
        max_range=max_range,
        min_plane_extent=min_plane_extent,
    )
    if cluster_tolerance < voxel_size:
        raise SegmentationError(
            f"cluster_tolerance ({cluster_tolerance} m) must be at least voxel_size "
            f"({voxel_size} m), or every voxel becomes its own cluster"
        )
    if min_height is not None and not 0 <= min_height < max_height:
        raise SegmentationError(f"need 0 <= min_height < max_height, got {min_height} and {max_height}")
    points = _flat_points(capture_or_points)
    raw = capture_or_points.points_cam if isinstance(capture_or_points, Capture) else capture_or_points
    width = int(np.shape(raw)[1]) if np.ndim(raw) == 3 else None  # organized: rows of `width` pixels
    with np.errstate(invalid="ignore"):
        # A sum is finite exactly when its terms are, and is much faster than isfinite(...).all(axis=1).
        finite = np.isfinite(points[:, 0] + points[:, 1] + points[:, 2])
        if not finite.any():
            raise SegmentationError(f"the cloud has no finite points (all {len(points)} are NaN/inf)")
        keep = finite & (points[:, 2] > 0) & (points[:, 2] < max_range)
    idx = np.flatnonzero(keep)
    if len(idx) == 0:
        raise SegmentationError(
            f"none of the {int(finite.sum())} finite points is in front of the camera "
            f"closer than max_range={max_range} m"
        )
    pts = np.take(points, idx, axis=0)
    lap("prepare")

    rng = np.random.default_rng(seed)
    sample = pts if len(pts) <= ransac_samples else pts[rng.integers(0, len(pts), ransac_samples)]
    plane = _support_plane(sample, rng, ransac_iterations, plane_distance, min_plane_fraction, min_plane_extent)
    table = np.zeros(0, dtype=np.int64)
    T_world_cam = np.eye(4)
    if plane is None:
        min_height = None
    else:
        height = np.einsum("ij,j->i", pts, plane[:3]) + plane[3]
        table = idx[np.abs(height) <= plane_distance]
        min_height = table_band(height) if min_height is None else min_height
        band = (height >= min_height) & (height <= max_height)
        idx, pts = idx[band], pts[band]
        T_world_cam = table_frame(plane)
    lap("plane")

    inverse, centroids = _voxel_downsample(pts, voxel_size)
    while len(centroids) > max_voxels:
        # Not a tabletop (random points, a whole room): the neighbour graph of this many voxels
        # would cost seconds and gigabytes. Coarser voxels (and a tolerance no finer) bound it.
        voxel_size *= 1.2 * (len(centroids) / max_voxels) ** 0.5  # steeper than ^(1/3): sparse voxels merge
        cluster_tolerance = max(cluster_tolerance, voxel_size)
        inverse, centroids = _voxel_downsample(pts, voxel_size)
    lap("downsample")
    pairs = _close_pairs(centroids, cluster_tolerance)
    labels = _components(len(centroids), pairs)[inverse]
    lap("cluster")
    segments = _make_segments(idx, pts, labels, min_points, max_extent, inverse, centroids, pairs, object_range, width)
    lap("segments")
    timings["total"] = time.perf_counter() - t0
    return Segmentation(segments, plane, T_world_cam, timings, table, min_height)


def isolate(
    points_cam: np.ndarray,
    *,
    support_plane: np.ndarray | None = None,
    voxel_size: float = VOXEL_SIZE,
    cluster_tolerance: float = CLUSTER_TOLERANCE,
    min_height: float | None = None,
    max_height: float = MAX_HEIGHT,
) -> np.ndarray:
    """Which of one object's points (N, 3), camera frame, metres, :func:`segment_scene` would have
    kept as its segment: (N,) bool.

    Points from elsewhere (a mask from known poses, a detector's box) also hold the table's edge
    around the object, the bottom ``min_height`` of the object, and stray depth pixels; the network
    only ever saw segments without them. So, with the same defaults as :func:`segment_scene`: with a
    ``support_plane`` ``(a, b, c, d)`` (camera frame), only points ``min_height``..``max_height`` above
    it count (``min_height`` None: :func:`table_band` of these points, whose table ring, if any, tells
    the table's noise); of those, the largest Euclidean cluster is kept with every cluster of at least
    ``PART_SHARE`` of its points within ``PART_GAP`` of it (the parts of an object whose connection the
    camera did not see), without their :func:`flying_pixels`. Non-finite points are never kept. When
    this leaves fewer than a tenth of the finite points, every finite point is kept instead (a flat
    object, such as a plate, lies almost wholly in the band)."""
    from ..completion.voxel import unit_plane

    pts = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    finite = np.asarray(np.isfinite(pts).all(axis=1))
    keep = finite.copy()
    if support_plane is not None:
        normal, d = unit_plane(support_plane)
        height = np.where(finite, np.nan_to_num(pts) @ normal + d, np.nan)
        band = table_band(height) if min_height is None else min_height
        with np.errstate(invalid="ignore"):
            keep &= (height >= band) & (height <= max_height)
    idx = np.flatnonzero(keep)
    if len(idx):
        inverse, centroids = _voxel_downsample(pts[idx], voxel_size)
        voxel_labels = _euclidean_clusters(centroids, max(cluster_tolerance, voxel_size))
        parts = _object_parts(centroids, voxel_labels, np.bincount(voxel_labels[inverse]))
        kept = idx[np.isin(voxel_labels[inverse], parts)]
        keep[:] = False
        keep[kept[~flying_pixels(pts[kept])]] = True
    if keep.sum() < 0.1 * finite.sum():
        return finite
    return keep


def table_band(heights: np.ndarray) -> float:
    """The ``min_height`` (m) that leaves a table's depth noise below it.

    Args:
        heights: (N,) signed heights (m) of a frame's or a mask's points above the support plane.

    Returns:
        ``TABLE_NOISE_SIGMAS`` times the RMS height of the points at most ``TABLE_NOISE_DEPTH`` below
        the plane (the table's noise: nothing solid lies under it), clipped to
        ``MIN_HEIGHT``..``MAX_MIN_HEIGHT``; ``MIN_HEIGHT`` when fewer than ``TABLE_NOISE_MIN_POINTS``
        points lie there (no table among the points).
    """
    h = np.asarray(heights, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        below = h[(h < 0) & (h >= -TABLE_NOISE_DEPTH)]
    if len(below) < TABLE_NOISE_MIN_POINTS:
        return MIN_HEIGHT
    return float(np.clip(TABLE_NOISE_SIGMAS * np.sqrt(np.mean(below**2)), MIN_HEIGHT, MAX_MIN_HEIGHT))


def world_frame(capture: Capture, segmentation: Segmentation) -> tuple[np.ndarray, str]:
    """``(T_world_cam, what it is)``: the 4x4 camera pose (metres) to show and export a capture in.

    A synthetic capture (one with ground-truth objects) knows its true table frame, which its
    objects' poses use too; a real one has only the table-aligned frame that segmentation
    estimated (identity when no plane was found).
    """
    if capture.objects:
        return np.asarray(capture.T_world_cam, dtype=np.float64), "simulated table frame"
    return np.asarray(segmentation.T_world_cam, dtype=np.float64), "table plane from segmentation"


def table_frame(plane_cam: np.ndarray) -> np.ndarray:
    """``T_world_cam`` of the table-aligned world frame of a plane (see :class:`Segmentation`).

    Args:
        plane_cam: (4,) ``(a, b, c, d)``, unit normal pointing to the camera, camera frame metres.
    """
    n, d = np.asarray(plane_cam[:3], dtype=np.float64), float(plane_cam[3])
    x = np.array([1.0, 0.0, 0.0]) - n[0] * n
    if np.linalg.norm(x) < 1e-6:  # the camera's x is the plane normal: use its z instead
        x = np.array([0.0, 0.0, 1.0]) - n[2] * n
    x /= np.linalg.norm(x)
    R_cam_world = np.column_stack([x, np.cross(n, x), n])
    T = np.eye(4)
    T[:3, :3] = R_cam_world.T
    T[:3, 3] = R_cam_world.T @ (d * n)  # the camera centre sits d above its foot -d*n on the plane
    return T


def points_on_table(
    points_cam: np.ndarray, support_plane: np.ndarray, *, fitting: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(T_table_cam, points_cam, points_table)``: the finite rows of (N, 3) camera-frame points
    (metres), and the same points in the table frame of ``support_plane`` (``(a, b, c, d)``, camera
    frame; :func:`table_frame`: the table at z = 0, z up, metres).

    Raises:
        ValueError: fewer than 10 finite points, too few for ``fitting`` (named in the message), or a
            malformed plane.
    """
    from ..completion.voxel import unit_plane

    n, d = unit_plane(support_plane)
    T = table_frame(np.r_[n, d])
    pts = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) < 10:
        raise ValueError(f"{len(pts)} points are too few to fit {fitting}")
    return T, pts, transform_points(T, pts)


def _check_parameters(**positive: float) -> None:
    for name, value in positive.items():
        if not (np.isfinite(value) and value > 0):
            raise SegmentationError(f"{name} must be a positive number of metres, got {value!r}")


def _flat_points(capture_or_points: Capture | np.ndarray) -> np.ndarray:
    """(N, 3) float64 camera-frame points of a capture or array (rows match ``flat_points()``)."""
    raw = capture_or_points.points_cam if isinstance(capture_or_points, Capture) else capture_or_points
    try:
        points = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise SegmentationError(f"the points are not an array of numbers ({e})") from None
    if points.ndim not in (2, 3) or points.shape[-1] != 3:
        raise SegmentationError(f"expected camera-frame points of shape (N, 3) or (H, W, 3), got {points.shape}")
    if points.size == 0:
        raise SegmentationError("the cloud is empty")
    return points.reshape(-1, 3)


def _support_plane(
    sample: np.ndarray,
    rng: np.random.Generator,
    iterations: int,
    distance: float,
    min_fraction: float,
    min_extent: float,
) -> np.ndarray | None:
    """The support plane (4,) of a camera-frame subsample, normal towards the camera, or None."""
    remaining, fallback = sample, None
    for _ in range(_MAX_PLANES):
        found = _ransac_plane(remaining, rng, iterations, distance)
        if found is None:
            break
        plane, inliers = found
        if inliers.sum() < min_fraction * len(sample):
            break  # later planes are smaller still
        if plane[3] < 0:
            plane = -plane
        if _in_plane_span(remaining[inliers], plane) >= min_extent:
            if -plane[1] >= np.cos(np.radians(_MAX_TILT_DEG)):
                return plane
            fallback = plane if fallback is None else fallback  # the first is the largest
        remaining = remaining[~inliers]
    return fallback


def _ransac_plane(
    points: np.ndarray, rng: np.random.Generator, iterations: int, distance: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """Plane (4,) with the most inliers among random 3-point hypotheses, least-squares refined.

    Returns ``(plane, inlier mask)`` or None when the points define no plane.
    """
    if len(points) < 3:
        return None
    tri = points[rng.integers(0, len(points), (iterations, 3))]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-12  # collinear or repeated samples
    if not ok.any():
        return None
    normals = normals[ok] / norms[ok, None]
    offsets = -np.einsum("ij,ij->i", normals, tri[ok, 0])
    # float32 halves the cost of this (points x hypotheses) matrix; the refit below is float64.
    residuals = points.astype(np.float32) @ normals.T.astype(np.float32) + offsets.astype(np.float32)
    scores = np.count_nonzero(np.abs(residuals) < distance, axis=0)
    best = int(np.argmax(scores))
    plane = np.append(normals[best], offsets[best])
    for _ in range(2):  # refit to the inliers, which moves the plane off the three noisy samples
        inliers = np.abs(points @ plane[:3] + plane[3]) < distance
        if inliers.sum() < 3:
            break
        centre = points[inliers].mean(axis=0)
        normal = np.linalg.svd(points[inliers] - centre, full_matrices=False)[2][2]
        plane = np.append(normal, -normal @ centre)
    return plane, np.abs(points @ plane[:3] + plane[3]) < distance


def _in_plane_span(points: np.ndarray, plane: np.ndarray) -> float:
    """Longer in-plane side (m) of the 2nd-98th percentile box of points on a plane."""
    in_plane = points @ table_frame(plane)[:2, :3].T
    lo, hi = np.percentile(in_plane, [2, 98], axis=0)
    return float((hi - lo).max())


def _voxel_downsample(points: np.ndarray, voxel_size: float) -> tuple[np.ndarray, np.ndarray]:
    """``(inverse, centroids)``: each point's voxel (N,) and the (V, 3) mean point of every voxel."""
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    cell = np.floor(points / voxel_size).astype(np.int64)
    cell -= cell.min(axis=0)
    dims = cell.max(axis=0) + 1
    key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    sums = np.stack([np.bincount(inverse, points[:, k], len(counts)) for k in range(3)], axis=1)
    return inverse, sums / counts[:, None]


def _box_distance(points: np.ndarray) -> float:
    """Distance (m) from the camera centre to the axis-aligned bounding box of (N, 3) camera-frame points."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    return float(np.linalg.norm(np.clip(0.0, lo, hi)))


def _object_parts(centroids: np.ndarray, labels: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """The cluster labels :func:`isolate` keeps: the largest cluster (``sizes``: points per label)
    and every cluster of at least ``PART_SHARE`` of its points with a voxel ``centroids`` within
    ``PART_GAP`` (m) of one of its voxels (``labels``: each voxel's cluster)."""
    from scipy.spatial import cKDTree

    largest = int(sizes.argmax())
    candidates = np.flatnonzero((sizes >= PART_SHARE * sizes[largest]) & (np.arange(len(sizes)) != largest))
    if not len(candidates):
        return np.array([largest])
    tree = cKDTree(centroids[labels == largest])
    gaps = [tree.query(centroids[labels == c], distance_upper_bound=PART_GAP)[0] for c in candidates]
    near = [c for c, gap in zip(candidates, gaps) if np.isfinite(gap).any()]
    return np.array([largest, *near])


def _euclidean_clusters(points: np.ndarray, tolerance: float) -> np.ndarray:
    """(N,) cluster label of every point: the connected components of "closer than ``tolerance``"."""
    return _components(len(points), _close_pairs(points, tolerance))


def _close_pairs(points: np.ndarray, tolerance: float) -> np.ndarray:
    """(P, 2) int rows ``i < j`` of the (N, 3) points (metres) closer than ``tolerance`` (m) to each other."""
    from scipy.spatial import cKDTree

    if len(points) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    return cKDTree(points).query_pairs(tolerance, output_type="ndarray")


def _components(n: int, pairs: np.ndarray) -> np.ndarray:
    """(n,) label of every node: the connected components of the graph of edges ``pairs`` (P, 2)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if n == 0:
        return np.zeros(0, dtype=np.int64)
    graph = coo_matrix((np.ones(len(pairs), dtype=bool), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def _make_segments(
    idx: np.ndarray,
    points: np.ndarray,
    labels: np.ndarray,
    min_points: int,
    max_extent: float,
    inverse: np.ndarray,
    centroids: np.ndarray,
    pairs: np.ndarray,
    object_range: float | None = None,
    width: int | None = None,
) -> list[Segment]:
    """Segments of the clusters (``labels``: each point's) without their :func:`flying_pixels`,
    each split again into Euclidean clusters of its voxels (``inverse``: each point's voxel,
    ``centroids``: the voxels' mean points, ``pairs``: the voxels closer than the cluster tolerance,
    :func:`_close_pairs`) where only voxels of flying pixels joined it to a neighbour; the parts that
    pass the size tests and lie within ``object_range`` (m) of the camera, numbered nearest first (by
    their centroid's distance from the camera). ``width``: the pixels per image row of an organized
    cloud (``idx`` are then pixel numbers), None for an unorganized one."""
    counts = np.bincount(labels, minlength=1)
    kept = []
    for label in np.flatnonzero(counts >= max(min_points, 1)):
        members = np.flatnonzero(labels == label)  # few clusters pass: cheaper than sorting all labels
        if object_range is not None and _box_distance(points[members]) > object_range * (1 + 1e-9):
            continue  # every part's centroid lies in the cluster's box, so none is within object_range
        voxels = inverse[members]
        if width is None:
            solid = ~flying_pixels(points[members])
        else:
            solid = ~_flying_pixels_organized(points[members], *np.divmod(idx[members], width))
        members, solid_voxels = members[solid], voxels[solid]
        kept_voxels = np.flatnonzero(np.bincount(solid_voxels, minlength=len(centroids)))
        parts = np.zeros(len(members), dtype=np.int64)
        if len(kept_voxels) < np.count_nonzero(np.bincount(voxels, minlength=len(centroids))):
            # Voxels of flying pixels alone may have bridged a gap: the clusters of the voxels left are
            # the components of the voxel graph without the others.
            position = np.full(len(centroids), -1)
            position[kept_voxels] = np.arange(len(kept_voxels))
            ends = position[pairs]
            kept_pairs = ends[(ends[:, 0] >= 0) & (ends[:, 1] >= 0)]
            parts = _components(len(kept_voxels), kept_pairs)[position[solid_voxels]]
        for part in np.flatnonzero(np.bincount(parts, minlength=1) >= max(min_points, 1)):
            part_members = members[parts == part]
            pts = points[part_members]
            size = float((pts.max(axis=0) - pts.min(axis=0)).max())
            distance = float(np.linalg.norm(pts.mean(axis=0)))
            if size <= max_extent and (object_range is None or distance <= object_range):
                kept.append((distance, -len(part_members), idx[part_members], pts, size))
    kept.sort(key=lambda k: k[:2])
    return [
        Segment(
            i,
            indices.astype(np.int64),
            pts,
            PALETTE[i % len(PALETTE)].copy(),
            f"segment {i} ({len(pts)} pts, {100 * size:.0f} cm)",
        )
        for i, (_, _, indices, pts, size) in enumerate(kept)
    ]
