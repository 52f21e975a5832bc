"""Meshes from the CNN output (paper Fig. 5, steps 5a and 5b).

* :func:`fast_mesh`: marching cubes straight on the 40^3 occupancy probabilities (for obstacles
  and planning scenes).
* :func:`detailed_mesh`: Algorithm 1 of the paper, which merges the dense observed points with the
  up-sampled CNN output and smooths the result (Lempitsky 2010) before marching cubes.

Meshes are returned in the camera optical frame, metres.
"""

from __future__ import annotations

import numpy as np
import trimesh
from skimage import measure

from ..errors import ShapeviewerError
from ..geometry import concatenate_meshes
from .voxel import GridFrame, below_plane, seen_free

# A network trained on Y marks its output grid at p > 0.5 (the paper's, scored against Y at
# 40^3), but its meshes are taken higher. Y marks every voxel the object's surface passes through
# (as binvox marked it), so such a network learns a shape up to a voxel fatter than the object and its 0.5
# contour lies outside the true surface: fast meshes at 0.5 held 1.35 times the object's volume
# (median, 100 tabletop views). Procedural shapes fit best at 0.7, the scanned YCB objects at
# 0.6-0.65 (docs/studies/soft-labels.md). A network's own level is ``Completer.mesh_level``.
MESH_LEVEL = 0.6
# On a binary volume the saddle of every face with two diagonal occupied corners lies exactly on
# the level 0.5, and marching cubes may then join four triangles at one edge (not watertight).
# A hair above the level keeps diagonal voxels apart; on real-valued data it changes nothing.
LEVEL_NUDGE = 1e-4
# A node whose value lies almost on the level puts the vertices of all its edges almost at the
# node: distinct sheets then meet within nanometres, and a reader that merges close vertices
# (trimesh.load of a float32 file) joins them into non-manifold edges. Node values are kept at
# least this far from the level, which moves the surface by micrometres.
OFF_LEVEL = 1e-3


class EmptyCompletionError(ShapeviewerError, ValueError):
    """The CNN marked no voxel as occupied, so there is no surface to extract."""


def grid_mesh(values: np.ndarray, frame: GridFrame, level: float) -> trimesh.Trimesh:
    """Closed iso-surface of voxel-centre samples ``values`` ([x, y, z], frame ``frame``) at ``level``.

    The volume is padded with one layer below ``level`` so the surface closes at the grid border.
    Returns a watertight mesh in the camera frame (metres) with outward normals.
    """
    iso = level + LEVEL_NUDGE
    values = np.asarray(values, dtype=np.float32)
    if not np.any(values > iso):
        raise EmptyCompletionError("no voxel is above the iso level: the completion is empty")
    values = np.where(
        np.abs(values - iso) < OFF_LEVEL, np.where(values >= iso, iso + OFF_LEVEL, iso - OFF_LEVEL), values
    )
    pad_value = min(float(values.min()), level) - 1.0
    padded = np.pad(values, 1, constant_values=pad_value)
    verts, faces, _, _ = measure.marching_cubes(padded, level=iso)
    # Padded index i is voxel i - 1, whose centre sits at grid coordinate (i - 1) + 0.5.
    # process=False: marching cubes already shares every vertex; trimesh's merging of vertices
    # closer than its tolerance joins distinct sheets that nearly touch (non-manifold edges).
    mesh = trimesh.Trimesh(frame.to_metres(verts - 0.5), faces, process=False)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def fast_mesh(probabilities: np.ndarray, frame: GridFrame, *, level: float = MESH_LEVEL) -> trimesh.Trimesh:
    """The paper's fast mesh: marching cubes of the CNN output, at p = ``level``.

    Args:
        probabilities: (40, 40, 40) float occupancy probabilities indexed [x, y, z].
        frame: the grid frame of the CNN input (maps grid coordinates to camera metres).
        level: the iso level (:data:`MESH_LEVEL`, chosen for the shipped model).

    Returns:
        A watertight triangle mesh in the camera optical frame, metres.
    """
    probabilities = np.asarray(probabilities)
    if probabilities.shape != (frame.dim,) * 3:
        raise ValueError(f"probabilities have shape {probabilities.shape}, the frame is {frame.dim}^3")
    return grid_mesh(probabilities, frame, level)


# ----------------------------------------------------------------------------------------------
# Detailed mesh: Algorithm 1 of the paper with the numbers the authors' code used.

DENSITY_SAMPLE_STEP = 10  # density estimated on every 10th point against the whole cloud
UPSAMPLE_RATIO_SCALE = 3 / 8  # r = ceil(3/8 * observed density / CNN density)
# The paper's r was "usually 2 or 3" (a Kinect at 0.5-1 m). A camera closer or finer than that (a
# RealSense at 1280 x 720, 0.35 m) makes r 5-9, a merged grid of up to 300^3 and up to a minute of
# smoothing for a mesh within 0.01 J80 of the one at r = 3 (docs/studies/grid-placement.md).
MAX_UPSAMPLE_RATIO = 3
MERGE_LEAF_FACTOR = 2.0  # re-voxelize at 2 x the observed mean nearest-neighbour distance
MERGE_PADDING = 6  # voxels of padding on every side of the merged grid
# Each observed point marks the merge voxel this many leaves behind it along its camera ray, not the
# voxel it falls in: the union of the voxels of noisy points grows the visible side outward by half a
# leaf to a leaf, and the soft-label network (``train --label fraction``) already puts its surface on
# the points.
OBSERVED_INSET = 1.0
BAND = 4  # Lempitsky smoothing optimises a band of 4 voxels around the boundary
BAND_VALUE = 5.0  # F is fixed at +/-5 outside the band
SMOOTH_ITERATIONS = 100  # FISTA steps (see lempitsky_smooth); the paper ran 500 Jacobi steps
# An addition to the paper's steps. Merge: CNN voxels more than one voxel in front of the
# observed surface along a camera ray are space the camera saw as free, and are carved away.
# Marching cubes runs at F = 0, Lempitsky's level set, as in the paper. With the paper's merge (a
# voxel occupied when a point falls in it) the surface lay about half a merge voxel (1-3 mm for a
# Kinect at 0.5-1 m) outside the points; OBSERVED_INSET now puts it on them on the visible side,
# and F = 0 keeps the unseen side where the CNN put it.
# A higher level fits everything more tightly but leaves parts of the true object a millimetre
# outside the mesh here and there, and the open fingers of a grasp planned on it, passing that
# close, hit them on the true object and stop the hand early. On a development sample (36 views,
# seed 1; the tables use seed 0), mean Jaccard / Hausdorff 0.700 / 3.31 mm at F = 0, 0.715 / 3.10
# at 0.1, 0.727 / 2.87 at 0.25 (fast mesh 0.701 / 3.31); 20 grasps per view executed on the true
# mesh, median joint / pose error and lift success 1.4 deg / 0.0 mm / 69 % at F = 0, 1.7 / 1.4 /
# 62 % at 0.1, 3.4 / 5.4 / 54 % at 0.25.
SURFACE_LEVEL = 0.0
# Cleanup: closed parts smaller than this share of the largest part's volume are specks (a few
# stray observed points, a CNN island) and are dropped; larger separate parts are kept.
MIN_PART_SHARE = 0.1


def mean_nn_distance(points: np.ndarray, step: int = DENSITY_SAMPLE_STEP) -> float:
    """Mean nearest-neighbour distance of every ``step``-th point to the whole cloud (same unit)."""
    from scipy.spatial import cKDTree

    points = np.asarray(points, dtype=np.float64)
    if len(points) < 2:
        raise ValueError("need at least two points to estimate a density")
    d, _ = cKDTree(points).query(points[::step], k=2)
    return float(np.mean(d[:, 1]))


def upsample_ratio(observed_spacing: float, cnn_spacing: float) -> int:
    """Algorithm 1, line 1: r = ceil(3/8 * observed density / CNN density), at least 1 and at most
    :data:`MAX_UPSAMPLE_RATIO`.

    Density is 1 / mean nearest-neighbour distance (:func:`mean_nn_distance`); the CNN's points
    are its occupied voxel centres. Both spacings in the same unit.
    """
    return min(MAX_UPSAMPLE_RATIO, max(1, int(np.ceil(UPSAMPLE_RATIO_SCALE * cnn_spacing / observed_spacing))))


def upsample_occupancy(occupied: np.ndarray, r: int) -> np.ndarray:
    """Algorithm 1, line 2: up-sample a bool grid by ``r`` with the inverse-L1 corner vote.

    Inside each cube whose 8 corners are neighbouring voxel centres, r^3 points are placed at
    ``corner + (k + 0.5) / r`` (k = 0..r-1 per axis). A point is occupied when the sum over the 8
    corners of (+1 occupied / -1 empty) / (L1 distance to the corner) is positive or zero, which
    gives piecewise-linear separating surfaces like marching cubes. (Ties count as occupied: at
    r = 1 the one new point is the cube's centre, where a face of 4 occupied corners ties; counted
    empty, every solid would lose a whole voxel per side and parts 2-3 voxels thin would vanish.)

    Returns a bool array of shape ``(n - 1) * r`` per axis: fine point ``f`` sits at coarse voxel-centre
    coordinate ``f / r + 0.5 / r`` (centre-to-centre units, origin at the centre of voxel 0).
    """
    sign = np.where(np.asarray(occupied, dtype=bool), 1.0, -1.0).astype(np.float32)
    m = tuple(n - 1 for n in sign.shape)
    corners = {(i, j, k): sign[i : i + m[0], j : j + m[1], k : k + m[2]] for i, j, k in np.ndindex(2, 2, 2)}
    t = (np.arange(r) + 0.5) / r
    fine = np.empty((m[0], r, m[1], r, m[2], r), dtype=bool)
    for a, b, c in np.ndindex(r, r, r):
        vote = np.zeros(m, np.float32)
        for (i, j, k), s in corners.items():
            vote += s / (abs(t[a] - i) + abs(t[b] - j) + abs(t[c] - k))
        fine[:, a, :, b, :, c] = vote >= 0
    return fine.reshape(m[0] * r, m[1] * r, m[2] * r)


def upsample_probabilities(values: np.ndarray, r: int) -> np.ndarray:
    """Up-sample a float grid by ``r`` by trilinear interpolation, at the points of :func:`upsample_occupancy`.

    Thresholded at a level, this is the surface marching cubes takes through the same values: it
    keeps where between two voxel centres the network's probability crosses the level, which the
    corner vote on thresholded voxels cannot (its surfaces always pass half way).

    Returns float32 of shape ``(n - 1) * r`` per axis, fine point ``f`` at coarse voxel-centre
    coordinate ``f / r + 0.5 / r``.
    """
    v = np.asarray(values, dtype=np.float32)
    m = tuple(n - 1 for n in v.shape)
    t = ((np.arange(r) + 0.5) / r).astype(np.float32)
    fine = np.empty((m[0], r, m[1], r, m[2], r), dtype=np.float32)
    for a, b, c in np.ndindex(r, r, r):
        acc = np.zeros(m, np.float32)
        for i, j, k in np.ndindex(2, 2, 2):
            w = (t[a] if i else 1 - t[a]) * (t[b] if j else 1 - t[b]) * (t[c] if k else 1 - t[c])
            acc += w * v[i : i + m[0], j : j + m[1], k : k + m[2]]
        fine[:, a, :, b, :, c] = acc
    return fine.reshape(m[0] * r, m[1] * r, m[2] * r)


def fill_gaps_along_z(occ: np.ndarray, max_gap: int) -> np.ndarray:
    """Algorithm 1, line 4: in every z column (the viewing direction), fill the first gap after the
    first occupied voxel when the next occupied voxel is fewer than ``max_gap`` voxels further on.

    This closes the seam between the observed surface and the CNN's (coarser) surface behind it.
    """
    occ = occ.copy()
    nz = occ.shape[2]
    z = np.arange(nz)
    any_occ = occ.any(axis=2)
    first = np.where(any_occ, occ.argmax(axis=2), nz)
    # End of the first run of occupied voxels: first empty voxel after `first`.
    after_first = z[None, None, :] > first[..., None]
    empty_after = ~occ & after_first
    gap_start = np.where(empty_after.any(axis=2), empty_after.argmax(axis=2), nz)
    occ_after_gap = occ & (z[None, None, :] > gap_start[..., None])
    gap_end = np.where(occ_after_gap.any(axis=2), occ_after_gap.argmax(axis=2), nz)
    # gap_end - first_empty is the gap length; "closer than r + 1" from the last occupied voxel.
    fill = (gap_end < nz) & (gap_end - (gap_start - 1) < max_gap)
    mask = fill[..., None] & (z[None, None, :] >= gap_start[..., None]) & (z[None, None, :] < gap_end[..., None])
    occ |= mask
    return occ


# Per axis the normal equations of sum ||D2 F||^2 have the stencil [1, -4, 6, -4, 1].
_STENCIL = ((-2, 1.0), (-1, -4.0), (1, -4.0), (2, 1.0))


def _second_difference_gradient(F, out):
    """Half the gradient of sum ||D2 F||^2 over x, y and z, written into ``out`` (same shape as F).

    F is padded by 2: ``out`` gets the gradient on the interior and zero on the pad. In-place adds
    of shifted views: the solver's time is almost all here.
    """
    out.zero_()
    inner = out[2:-2, 2:-2, 2:-2]
    inner.add_(F[2:-2, 2:-2, 2:-2], alpha=18.0)
    for axis in range(3):
        n = F.shape[axis]
        for k, w in _STENCIL:
            idx = [slice(2, -2)] * 3
            idx[axis] = slice(2 + k, n - 2 + k)
            inner.add_(F[tuple(idx)], alpha=w)
    return out


def lempitsky_smooth(occ: np.ndarray, iterations: int = SMOOTH_ITERATIONS, band: int = BAND, device=None) -> np.ndarray:
    """Algorithm 1, line 5: the embedding function F of Lempitsky (CVPR 2010), float32 array.

    Minimises the sum over voxels of squared second differences of F along x, y and z subject to
    sign constraints: inside voxels keep F >= margin, outside voxels F <= -margin, where a voxel's
    margin is its chessboard distance (in voxels) to the boundary layer. Only a band of ``band``
    voxels around the boundary is optimised; F is fixed at +/-5 outside it. The surface is the
    level set F = 0 (F is about a signed distance in voxels near it).

    Solver, in torch (CUDA when present, else CPU), starting at +/-margin: accelerated projected
    gradient descent (FISTA, step 1/48 = 1 / the largest eigenvalue of the stencil) instead of the
    paper's 500 damped Jacobi steps. Same objective, same constraints; on merged grids of this
    project 100 FISTA steps reach a lower energy than 500 Jacobi steps and leave the surface within
    0.03 voxel (mean) of the converged one, in a fifth of the time.
    """
    import torch
    from scipy import ndimage

    occ = np.asarray(occ, dtype=bool)
    # 0 on the boundary layer on either side, growing by one per voxel away from it.
    d_in = ndimage.distance_transform_cdt(occ, metric="chessboard") - 1
    d_out = ndimage.distance_transform_cdt(~occ, metric="chessboard") - 1
    margin = np.where(occ, d_in, d_out).astype(np.float32)
    sign = np.where(occ, 1.0, -1.0).astype(np.float32)
    in_band = margin < band
    F0 = np.where(in_band, sign * margin, sign * BAND_VALUE).astype(np.float32)
    # Bounds: inside margin <= F, outside F <= -margin; voxels outside the band are pinned.
    lower = np.where(~in_band, F0, np.where(occ, margin, -np.inf)).astype(np.float32)
    upper = np.where(~in_band, F0, np.where(occ, np.inf, -margin)).astype(np.float32)
    dev = (
        torch.device(device)
        if device is not None
        else (torch.device("cuda") if torch.cuda.is_available() else torch.device("cpu"))
    )
    # Edge padding by 2 gives the stencil its neighbours at the grid border; pinned like the rest.
    F, lo, hi = (torch.from_numpy(np.pad(a, 2, mode="edge")).to(dev) for a in (F0, lower, upper))
    # One CPU thread: each step is ~20 passes over at most a few 100k voxels, too little work to
    # share; with two threads on a busy 2-core machine the solve was 5-20x slower (thread hand-offs).
    threads = torch.get_num_threads()
    if dev.type == "cpu":
        torch.set_num_threads(1)
    try:
        previous, gradient, t = F.clone(), torch.empty_like(F), 1.0
        for _ in range(iterations):
            t_next = (1.0 + (1.0 + 4.0 * t * t) ** 0.5) / 2.0
            y = torch.add(F, F - previous, alpha=(t - 1.0) / t_next)
            previous = F
            F = y.sub_(_second_difference_gradient(y, gradient), alpha=1.0 / 48.0)
            F = torch.minimum(F, hi, out=F)
            F = torch.maximum(F, lo, out=F)
            t = t_next
    finally:
        torch.set_num_threads(threads)
    return F[2:-2, 2:-2, 2:-2].cpu().numpy()


def _carve_seen_free_space(
    occ: np.ndarray, origin: np.ndarray, leaf: float, observed_points_cam: np.ndarray
) -> np.ndarray:
    """Empty every voxel the camera saw through (:func:`voxel.seen_free` with a one-voxel margin).

    ``occ`` is a grid of voxel size ``leaf`` whose voxel 0 starts at ``origin`` (camera metres).
    """
    idx = np.argwhere(occ)
    free = seen_free(origin + (idx + 0.5) * leaf, observed_points_cam, leaf)
    out = occ.copy()
    out[tuple(idx[free].T)] = False
    return out


def _drop_specks(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """``mesh`` without the connected parts smaller than ``MIN_PART_SHARE`` of the largest."""
    parts = mesh.split(only_watertight=False)
    if len(parts) < 2:
        return mesh
    volumes = np.abs([p.volume for p in parts])
    return concatenate_meshes([p for p, v in zip(parts, volumes) if v >= MIN_PART_SHARE * volumes.max()])


def detailed_mesh(
    probabilities: np.ndarray,
    frame: GridFrame,
    observed_points_cam: np.ndarray,
    *,
    timings: dict | None = None,
    smooth_iterations: int = SMOOTH_ITERATIONS,
    support_plane: np.ndarray | None = None,
    level: float = MESH_LEVEL,
    upsample: str = "vote",
    observed_inset: float = OBSERVED_INSET,
) -> trimesh.Trimesh:
    """Algorithm 1: merge the dense observed points with the up-sampled CNN output, smooth, mesh.

    Steps (keys of ``timings``): ``density`` (ratio r), ``upsample`` (corner vote), ``merge``
    (re-voxelize at max(2 x observed spacing, voxel / r), carve the seen free space), ``fill_gaps``
    (along z), ``smooth`` (Lempitsky), ``marching_cubes`` (at F = 0, then specks dropped).
    The constants above say where this departs from the paper and why.

    Args:
        probabilities: (40, 40, 40) CNN output, [x, y, z], in ``frame``.
        frame: the grid frame of the CNN input.
        observed_points_cam: (N, 3) the segment's observed points, camera frame, metres.
        timings: if given, filled with seconds per step of Algorithm 1.
        support_plane: ``(a, b, c, d)`` of the table in the camera frame (normal towards the
            camera), or None; merged voxels wholly under it are emptied, so the mesh stops at the
            table and stays closed.
        level: the CNN's voxels above this probability are the occupancy Algorithm 1 up-samples.
        upsample: ``vote`` (the paper's corner vote on the voxels above ``level``,
            :func:`upsample_occupancy`, whose surfaces pass half way between voxel centres) or
            ``linear`` (the probabilities interpolated, then thresholded at ``level``: the surface
            lies where the network's answer crosses the level, as in the fast mesh). The model card
            compares them: ``linear`` helps a network trained on Y, not the shipped one.
        observed_inset: each observed point marks the merge voxel this many merge voxels (leaves)
            behind it along its camera ray (0: the voxel it falls in, as the paper merged).

    Returns:
        A closed mesh in the camera optical frame, metres.

    Raises:
        EmptyCompletionError: nothing above the level (empty CNN output, or too thin to mesh).
        ValueError: fewer than two observed points, or a cloud too dense for its size.
    """
    import time

    t = {} if timings is None else timings
    t0 = time.perf_counter()
    obs = np.asarray(observed_points_cam, dtype=np.float64).reshape(-1, 3)
    obs = obs[np.isfinite(obs).all(axis=1)]
    occ = np.asarray(probabilities) > level
    if not occ.any():
        raise EmptyCompletionError(f"no voxel is above {level}: the completion is empty")
    cnn_pts = frame.voxel_centers(np.argwhere(occ))
    obs_nn = mean_nn_distance(obs)
    r = upsample_ratio(obs_nn, mean_nn_distance(cnn_pts)) if len(cnn_pts) > 1 else 1
    t["density"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    # Only the cubes around the occupied region matter: crop with one voxel of margin.
    lo = np.maximum(np.argwhere(occ).min(0) - 1, 0)
    hi = np.minimum(np.argwhere(occ).max(0) + 2, frame.dim)
    crop = (slice(lo[0], hi[0]), slice(lo[1], hi[1]), slice(lo[2], hi[2]))
    if upsample == "vote":
        fine = upsample_occupancy(occ[crop], r)
    elif upsample == "linear":
        fine = upsample_probabilities(np.asarray(probabilities)[crop], r) > level
    else:
        raise ValueError(f"unknown upsample {upsample!r} (use 'vote' or 'linear')")
    fine_idx = np.argwhere(fine)
    # Fine point f sits at coarse voxel-centre coordinate lo + f / r + 0.5 / r, i.e. grid coordinate + 0.5.
    up_pts = frame.to_metres(lo + (fine_idx + 0.5) / r + 0.5)
    t["upsample"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    merged = np.concatenate([obs, up_pts])
    # The paper merges at (40 r)^3, i.e. a leaf of voxel_size / r; their code used 2 x the observed
    # spacing. The larger of the two keeps the up-sampled CNN points (voxel_size / r apart) free of
    # gaps at the merge resolution and bounds the grid for very dense clouds.
    leaf = max(MERGE_LEAF_FACTOR * obs_nn, frame.voxel_size / r)
    # Anchor the grid so that the up-sampled points' lattice sits at voxel centres: with a leaf of
    # exactly their spacing, points on voxel faces would fall on either side by rounding, leaving
    # some voxels empty and others doubly hit (holes through thin parts).
    anchor = up_pts[0] if len(up_pts) else merged[0]
    origin = anchor - (np.ceil((anchor - merged.min(0)) / leaf) + MERGE_PADDING + 0.5) * leaf
    shape = np.ceil((merged.max(0) + MERGE_PADDING * leaf - origin) / leaf).astype(int) + 1
    if np.prod(shape) > 400**3:
        raise ValueError(
            f"the merged grid would be {tuple(shape)} voxels: the observed cloud is too dense "
            f"for its size (mean spacing {obs_nn * 1000:.2f} mm); downsample it first"
        )
    cnn_idx = np.floor((up_pts - origin) / leaf).astype(int)
    rays = obs / np.maximum(np.linalg.norm(obs, axis=1, keepdims=True), 1e-12)
    obs_idx = np.clip(np.floor((obs + observed_inset * leaf * rays - origin) / leaf).astype(int), 0, shape - 1)
    cnn = np.zeros(shape, bool)
    cnn[cnn_idx[:, 0], cnn_idx[:, 1], cnn_idx[:, 2]] = True
    grid = _carve_seen_free_space(cnn, origin, leaf, obs)
    if support_plane is not None:
        cells = np.argwhere(grid)
        under = below_plane(origin + (cells + 0.5) * leaf, support_plane, leaf / 2)
        grid[tuple(cells[under].T)] = False
    grid[obs_idx[:, 0], obs_idx[:, 1], obs_idx[:, 2]] = True
    t["merge"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    grid = fill_gaps_along_z(grid, r + 1)
    t["fill_gaps"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    F = lempitsky_smooth(grid, iterations=smooth_iterations)
    t["smooth"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    mesh = _drop_specks(grid_mesh(F, GridFrame.from_corner(origin, leaf, int(shape.max())), SURFACE_LEVEL))
    t["marching_cubes"] = time.perf_counter() - t0
    t["upsample_ratio"] = r
    return mesh
