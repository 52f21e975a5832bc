"""Flying pixels: the stray points a depth camera puts between an object's silhouette and what lies
behind it, found per segment (:func:`flying_pixels`) and, for organized clouds, with the image's own
neighbours first (:func:`_flying_pixels_organized`, the same answer for less work).

Points are camera optical frame, metres.
"""

from __future__ import annotations

import numpy as np

# Flying pixels: silhouette pixels a depth camera puts between an object and what lies behind it
# (RealSense-style sensors make many). They trail off the surface in ones and twos, while a point
# on any surface, even at its edge or on a one-pixel-wide handle, has neighbours within a few point
# spacings. Removing them from the segments brought completions of RealSense views up to those of
# Kinect views (docs/studies/tabletop-ablation.md); clustering again without them splits an object
# from the neighbour they joined it to (3 of 200 tabletop test views had a neighbour in the target's
# segment).
FLYING_RADIUS = 3.0  # neighbourhood radius, in the segment's median nearest-neighbour distances
FLYING_NEIGHBOURS = 6  # fewer other points than this within it: a flying pixel


def flying_pixels(points_cam: np.ndarray) -> np.ndarray:
    """Which of one object's points (N, 3), camera frame, metres, are flying pixels: (N,) bool.

    A point is one when fewer than :data:`FLYING_NEIGHBOURS` other points lie within
    :data:`FLYING_RADIUS` times the points' median nearest-neighbour distance of it."""
    pts = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    if len(pts) <= FLYING_NEIGHBOURS:
        return np.zeros(len(pts), dtype=bool)
    from scipy.spatial import cKDTree

    # Distances to each point's nearest FLYING_NEIGHBOURS others (column 0 is the point itself).
    distances = cKDTree(pts).query(pts, FLYING_NEIGHBOURS + 1)[0]
    spacing = float(np.median(distances[:, 1]))
    if spacing <= 0:  # more than half the points repeat: nothing to measure against
        return np.zeros(len(pts), dtype=bool)
    return distances[:, FLYING_NEIGHBOURS] > FLYING_RADIUS * spacing


# The image neighbours (row, column offsets) that the organized flying-pixel test measures: half of
# the 3x3 window, each pair being measured once for both of its pixels.
_HALF_WINDOW = ((0, 1), (1, -1), (1, 0), (1, 1))
# Relative margin kept between a distance measured here and a threshold: numpy and the KD-tree compute
# the same sum of squares, and anything closer than this is settled by the KD-tree itself.
_MARGIN = 1e-9


def _flying_pixels_organized(points: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """:func:`flying_pixels` of one cluster of an organized cloud, the same answer at a fraction of the cost.

    Args:
        points: (N, 3) the cluster's points, camera frame, metres.
        rows, cols: (N,) their pixels (distinct) in the depth image.

    The KD-tree answers only the questions that the image cannot settle. Each point's distance to
    its nearest 3x3 image neighbour in the cluster bounds its nearest-neighbour distance from above,
    so the points whose bound lies clearly below the middle of the bounds' order are below the
    median and need no query; the others' nearest neighbours are looked up (within the median of the
    bounds, which the median lies below), and the median they give is checked to be theirs. A point
    with :data:`FLYING_NEIGHBOURS` image neighbours within the radius is not a flying pixel; only the
    others (silhouettes, depth edges) are counted with the KD-tree. Anything not settled this way
    falls back to the full queries of :func:`flying_pixels`.
    """
    n = len(points)
    if n <= FLYING_NEIGHBOURS:
        return np.zeros(n, dtype=bool)
    from scipy.spatial import cKDTree

    # The cluster's points as images (NaN where no cluster point), one pixel of padding all round.
    r = rows - rows.min() + 1
    c = cols - cols.min() + 1
    shape = (int(r.max()) + 2, int(c.max()) + 2)
    image = np.full((3, *shape), np.nan)
    image[:, r, c] = points.T
    pairs = []  # (slice of the first pixels, slice of their neighbours, distance image)
    upper = np.full(shape, np.inf)  # each pixel's nearest image neighbour's distance
    for dr, dc in _HALF_WINDOW:
        a = (slice(0, shape[0] - dr), slice(max(0, -dc), shape[1] - max(0, dc)))
        b = (slice(dr, shape[0]), slice(max(0, dc), shape[1] - max(0, -dc)))
        diff = image[(slice(None), *a)] - image[(slice(None), *b)]
        distance = np.sqrt(diff[0] * diff[0] + diff[1] * diff[1] + diff[2] * diff[2])
        np.fmin(upper[a], distance, out=upper[a])
        np.fmin(upper[b], distance, out=upper[b])
        pairs.append((a, b, distance))
    bound = upper[r, c]

    # The median nearest-neighbour distance, exactly as np.median of all of them (flying_pixels).
    tree = cKDTree(points, leafsize=32, balanced_tree=False)  # quicker to build, as quick to query
    lo_k, hi_k = (n - 1) // 2, n // 2  # np.median's middle elements
    ordered = np.partition(bound, [(9 * n) // 20, hi_k])
    top = ordered[hi_k]  # the median lies at or below the median of the upper bounds
    spacing = None
    if top <= 0:
        spacing = 0.0
    elif np.isfinite(top):
        low = ordered[(9 * n) // 20]
        below = bound < low * (1 - _MARGIN)  # surely below `low`, so below the middle elements
        nearest = np.full(n, -np.inf)
        query = ~below
        nearest[query] = tree.query(points[query], 2, distance_upper_bound=top * (1 + _MARGIN))[0][:, 1]
        middle = np.partition(nearest, [lo_k, hi_k])
        if middle[lo_k] >= low and np.isfinite(middle[hi_k]):  # the middle elements are exact
            spacing = float(np.median(nearest))
    if spacing is None:
        spacing = float(np.median(tree.query(points, 2)[0][:, 1]))
    if spacing <= 0:
        return np.zeros(n, dtype=bool)

    # Image neighbours surely within the radius; the points with fewer are counted by the KD-tree.
    radius = FLYING_RADIUS * spacing
    within = np.zeros(shape, dtype=np.int64)
    for a, b, distance in pairs:
        close = distance <= radius * (1 - _MARGIN)
        within[a] += close
        within[b] += close
    flying = np.zeros(n, dtype=bool)
    unsure = np.flatnonzero(within[r, c] < FLYING_NEIGHBOURS)
    if len(unsure):
        sixth = tree.query(points[unsure], FLYING_NEIGHBOURS + 1, distance_upper_bound=radius * (1 + 1e-6))[0]
        flying[unsure] = sixth[:, FLYING_NEIGHBOURS] > radius
    return flying
