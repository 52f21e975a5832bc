"""The paper's two completion baselines (Varley et al. 2017, Sec. VI-A).

* :func:`partial_mesh`: marching cubes of the observed points alone, then cotangent Laplacian
  smoothing. It has no notion of the unseen side: a thin closed shell around the visible surface.
* :func:`hull_mesh`: the convex hull of the observed points, the most naive completion there is
  (not in the paper): the first thing a sceptical user compares a completion against.
* :func:`mirror_mesh`: Bohg et al., ICRA 2011, "Mind the gap": the object is assumed symmetric
  about a plane perpendicular to the support plane. The plane that best explains the view
  (:func:`find_mirror_plane`) mirrors the observed points, and Poisson surface reconstruction of
  both sets gives a closed mesh.

Every point, plane and mesh is in the camera optical frame (x right, y down, z forward), metres.
A plane ``(a, b, c, d)`` is the set ``a x + b y + c z + d = 0`` with unit normal ``(a, b, c)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import trimesh
from scipy import ndimage, sparse

from .reconstruct import grid_mesh, mean_nn_distance
from .voxel import GridFrame, points_to_grid, unit_plane

MIN_POINTS = 20
MAX_GRID_DIM = 256  # voxels per side; larger means outliers or a far too dense cloud

# Partial baseline: the observed cloud alone.
PARTIAL_LEAF_FACTOR = 4.0  # leaf = 4 x the observed mean nearest-neighbour distance
PARTIAL_ISO_LEVEL = 0.5
SMOOTHING_ITERATIONS = 6
SMOOTHING_LAMBDA = 0.5

# Mirror baseline: the plane search and its visibility score.
ORIENTATION_STEP_DEG = 5.0  # coarse candidates about the support-plane normal, over 180 degrees
OFFSET_STEP_FACTOR = 4.0  # coarse offset step = 4 x the mean nearest-neighbour distance
REFINE_STEPS = 8  # refinement: +/- 8 steps of a quarter of the coarse ones
SCORE_POINTS = 1000  # observed points mirrored per candidate (evenly subsampled)
BIN_FACTOR = 2.0  # depth-map bins: 2 x the mean point spacing, as an angle
DEPTH_TOLERANCE_FACTOR = 3.0  # "in front of" / "behind" the observed surface: 3 x the mean spacing
# score = violating fraction - SURFACE_REWARD x on-surface fraction - HIDDEN_REWARD x hidden
#         fraction + DEPTH_PENALTY x mean depth behind the surface / cloud size;
# (SURFACE_REWARD, HIDDEN_REWARD) of the coarse search and of the refinement:
COARSE_REWARDS = (0.0, 0.25)
REFINE_REWARDS = (0.25, 0.15)
DEPTH_PENALTY = 0.1
POISSON_DEPTH = 5  # Bohg et al. reconstructed at octree depth 5
NORMAL_NEIGHBOURS = 20


@dataclass(frozen=True)
class SymmetryPlane:
    """A candidate mirror plane and how well the mirrored view agrees with the observation.

    Attributes:
        normal: (3,) unit normal, camera frame.
        offset: ``d`` of ``normal . p + d = 0`` (metres).
        violation: fraction of mirrored points in space the camera sees as free.
        surface: fraction of mirrored points on the observed surface.
        hidden: fraction of mirrored points hidden behind the observed surface (new shape).
        behind: mean depth (metres) by which mirrored points lie behind the observed surface
            along their rays (0 for points that are not hidden).
        score: see :func:`find_mirror_plane`; lower is better.
    """

    normal: np.ndarray
    offset: float
    violation: float
    surface: float
    hidden: float
    behind: float
    score: float

    def reflect(self, points: np.ndarray) -> np.ndarray:
        """Mirror (N, 3) camera-frame points (metres) about the plane."""
        return _reflect(points, self.normal, self.offset)


def _reflect(points: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """Mirror (N, 3) points about the plane ``normal . p + offset = 0`` (unit normal)."""
    points = np.asarray(points, dtype=np.float64)
    return points - 2.0 * (points @ normal + offset)[:, None] * normal


def _reflect_directions(vectors: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Mirror (N, 3) direction vectors (e.g. surface normals) about a plane with unit ``normal``."""
    return _reflect(vectors, normal, 0.0)


# ----------------------------------------------------------------------------------------------
# Partial baseline


def partial_mesh(
    points_cam: np.ndarray,
    *,
    leaf_factor: float = PARTIAL_LEAF_FACTOR,
    iso_level: float = PARTIAL_ISO_LEVEL,
    smoothing_iterations: int = SMOOTHING_ITERATIONS,
) -> trimesh.Trimesh:
    """The Partial baseline: marching cubes of the observed cloud alone, then smoothing.

    The points are voxelized at a leaf of ``leaf_factor`` x their mean nearest-neighbour distance,
    the occupancy is meshed at ``iso_level`` and the mesh gets ``smoothing_iterations`` steps of
    cotangent Laplacian smoothing.

    Args:
        points_cam: (N, 3) observed points of one object, camera frame, metres (non-finite rows
            are ignored).

    Returns:
        A closed (watertight) mesh in the camera frame, metres: a thin shell around the visible
        surface.

    Raises:
        ValueError: fewer than ``MIN_POINTS`` distinct finite points, or a cloud whose grid would
            exceed ``MAX_GRID_DIM`` voxels per side (outliers).
    """
    points = _observed_points(points_cam)
    return _voxel_mesh(points, leaf_factor * mean_nn_distance(points), iso_level, smoothing_iterations)


def hull_mesh(points_cam: np.ndarray) -> trimesh.Trimesh:
    """The Hull baseline: the convex hull of the observed points (camera frame, metres).

    Raises:
        ValueError: fewer than ``MIN_POINTS`` distinct finite points, or points that span no volume
            (all on one plane or line).
    """
    from scipy.spatial import ConvexHull, QhullError

    points = _observed_points(points_cam)
    try:
        hull = ConvexHull(points)
    except QhullError as e:
        raise ValueError(f"the points span no volume, so they have no convex hull: {str(e).splitlines()[0]}") from e
    mesh = trimesh.Trimesh(points[hull.vertices], np.searchsorted(hull.vertices, hull.simplices), process=False)
    trimesh.repair.fix_normals(mesh)
    return mesh


def _voxel_mesh(
    points: np.ndarray,
    leaf: float,
    iso_level: float,
    smoothing_iterations: int,
    fill_cavities: bool = False,
    table: tuple[np.ndarray, float] | None = None,
) -> trimesh.Trimesh:
    """Smoothed marching cubes of the points voxelized at ``leaf`` (metres).

    ``fill_cavities`` also marks the voxels enclosed by occupied ones; ``table`` ``(normal, d)``
    empties every voxel whose centre is below the plane (``normal . p + d < 0``).
    """
    frame = _box_frame(points, leaf)
    occupancy = points_to_grid(points, frame)
    if fill_cavities:
        occupancy = ndimage.binary_fill_holes(occupancy)
    if table is not None:
        normal, d = table
        # Height of every voxel centre above the plane, built axis by axis (the map is affine).
        centre = (np.arange(frame.dim) + 0.5) * frame.voxel_size
        height = (
            frame.to_metres(np.zeros((1, 3)))[0] @ normal
            + d
            + sum(np.expand_dims(centre * n, tuple(a for a in range(3) if a != axis)) for axis, n in enumerate(normal))
        )
        occupancy &= height >= 0
    mesh = grid_mesh(occupancy.astype(np.float32), frame, iso_level)
    return _cotangent_smooth(mesh, smoothing_iterations)


def _box_frame(points: np.ndarray, leaf: float) -> GridFrame:
    """A cubic :class:`GridFrame` of voxel size ``leaf`` whose voxel (0, 0, 0) starts at the
    points' minimum corner and which holds every point."""
    lo = points.min(axis=0)
    dim = int(np.ceil((points.max(axis=0) - lo).max() / leaf)) + 1
    if dim > MAX_GRID_DIM:
        raise ValueError(
            f"the cloud spans {dim} voxels of {leaf * 1000:.2f} mm: remove outliers "
            f"or downsample it (at most {MAX_GRID_DIM} per side)"
        )
    return GridFrame.from_corner(lo, leaf, dim)


def _cotangent_smooth(mesh: trimesh.Trimesh, iterations: int, lamb: float = SMOOTHING_LAMBDA) -> trimesh.Trimesh:
    """``iterations`` explicit Laplacian steps with cotangent weights of the input mesh.

    Negative weights (obtuse angles, frequent in marching-cubes meshes) are clipped to 0 so that
    every step moves a vertex towards a convex combination of its neighbours and stays stable.
    """
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    rows, cols, weights = [], [], []
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        e1, e2 = v[f[:, j]] - v[f[:, i]], v[f[:, k]] - v[f[:, i]]
        # cot of the angle at corner i, which weighs the opposite edge (j, k).
        cot = np.einsum("ij,ij->i", e1, e2) / np.maximum(np.linalg.norm(np.cross(e1, e2), axis=1), 1e-12)
        w = 0.5 * np.clip(cot, 0.0, None)
        rows += [f[:, j], f[:, k]]
        cols += [f[:, k], f[:, j]]
        weights += [w, w]
    W = sparse.csr_matrix(
        (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(len(v), len(v))
    )
    degree = np.asarray(W.sum(axis=1)).ravel()
    # A vertex whose every angle is obtuse keeps its place (row of the identity).
    stuck = degree <= 0
    operator = sparse.diags(np.where(stuck, 0.0, 1.0 / np.where(stuck, 1.0, degree))) @ W + sparse.diags(stuck * 1.0)
    return trimesh.smoothing.filter_laplacian(
        mesh.copy(), lamb=lamb, iterations=iterations, volume_constraint=False, laplacian_operator=operator.tocsr()
    )


# ----------------------------------------------------------------------------------------------
# Mirror baseline


def mirror_mesh(
    points_cam: np.ndarray,
    support_plane_cam: np.ndarray | None,
    *,
    camera_center: npt.ArrayLike = (0.0, 0.0, 0.0),
    poisson_depth: int = POISSON_DEPTH,
) -> trimesh.Trimesh:
    """The Mirror baseline (Bohg et al., ICRA 2011): complete the object by its mirror image.

    1. The symmetry plane comes from :func:`find_mirror_plane`; the observed points are mirrored
       about it. Observed points get normals (``NORMAL_NEIGHBOURS`` neighbours, oriented towards
       the camera), mirrored points the mirrored normals.
    2. The bottom of an object on a table is never seen, and Poisson reconstruction of a cloud
       with an open side flares into an open surface there. So, with a support plane, the merged
       cloud is also reflected about the table: the sides continue through it and the surface
       closes. Without a support plane this step and the cut in 3 are skipped.
    3. Screened Poisson reconstruction at octree depth ``poisson_depth`` (5, as Bohg et al.), cut
       at the support plane with manifold3d (a flat bottom on the table), largest part kept
       (Poisson leaves small bubbles where samples are sparse).
    4. When the Poisson surface is not a closed manifold (thin walls such as a mug's, whose two
       sides fall into one octree cell, tear it), the fallback is marching cubes of the voxelized
       merged cloud (as :func:`partial_mesh`, with enclosed cavities filled and nothing below the
       table). ``mesh.metadata["reconstruction"]`` says which: ``"poisson"`` or ``"voxels"``.

    Args:
        points_cam: (N, 3) observed points of one object, camera frame, metres.
        support_plane_cam: ``(a, b, c, d)`` of the table in the camera frame, or None when no
            table was found (see :func:`find_mirror_plane` for what is assumed then).
        camera_center: (3,) the viewpoint of the observation, camera frame (the origin).
        poisson_depth: octree depth of the Poisson reconstruction.

    Returns:
        A closed (watertight) mesh in the camera frame, metres.

    Raises:
        ValueError: too few points, points not in front of the camera or an invalid plane.
    """
    import open3d as o3d

    points = _observed_points(points_cam)
    center = np.asarray(camera_center, dtype=np.float64).reshape(3)
    plane = find_mirror_plane(points, support_plane_cam, center)
    table = None if support_plane_cam is None else unit_plane(support_plane_cam, center)

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(NORMAL_NEIGHBOURS))
    cloud.orient_normals_towards_camera_location(center)
    normals = np.asarray(cloud.normals)
    merged = np.concatenate([points, plane.reflect(points)])
    merged_normals = np.concatenate([normals, _reflect_directions(normals, plane.normal)])
    if table is not None:
        merged_normals = np.concatenate([merged_normals, _reflect_directions(merged_normals, table[0])])
        merged = np.concatenate([merged, _reflect(merged, *table)])

    mesh = _poisson_solid(merged, merged_normals, poisson_depth, table)
    if mesh is not None:
        mesh.metadata["reconstruction"] = "poisson"
        return mesh
    mesh = _voxel_mesh(
        merged,
        PARTIAL_LEAF_FACTOR * mean_nn_distance(points),
        PARTIAL_ISO_LEVEL,
        SMOOTHING_ITERATIONS,
        fill_cavities=True,
        table=table,
    )
    mesh.metadata["reconstruction"] = "voxels"
    return mesh


def _poisson_solid(
    points: np.ndarray, normals: np.ndarray, depth: int, table: tuple[np.ndarray, float] | None
) -> trimesh.Trimesh | None:
    """Poisson surface of oriented points, cut at ``table`` (kept: its normal's side), largest
    part; None if the surface is not a closed manifold."""
    import manifold3d
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.normals = o3d.utility.Vector3dVector(normals)
    # One thread: the multi-threaded solver sums in a varying order, so results would not repeat.
    poisson, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud, depth=depth, n_threads=1)
    solid = manifold3d.Manifold(
        manifold3d.Mesh(np.asarray(poisson.vertices, np.float32), np.asarray(poisson.triangles, np.uint32))
    )
    if solid.status() != manifold3d.Error.NoError or solid.is_empty():
        return None
    if table is not None:
        solid = solid.trim_by_plane(table[0], -table[1])  # keeps normal . p >= -d
    parts = [p for p in solid.decompose() if p.volume() > 0]
    if not parts:
        return None
    out = max(parts, key=lambda p: p.volume()).to_mesh()
    # process=False: manifold3d's topology is already closed; merging coincident vertices of
    # parts that touch would make trimesh see non-manifold edges.
    return trimesh.Trimesh(np.asarray(out.vert_properties)[:, :3], np.asarray(out.tri_verts), process=False)


def find_mirror_plane(
    points_cam: np.ndarray, support_plane_cam: np.ndarray | None, camera_center: npt.ArrayLike = (0.0, 0.0, 0.0)
) -> SymmetryPlane:
    """The symmetry plane perpendicular to the support plane that best explains the view.

    Each candidate mirrors an even subsample of the points, which are compared with the observed
    depth along their camera rays (:class:`_DepthMap`). A mirrored point is

    * in front of the observed surface (by more than ``DEPTH_TOLERANCE_FACTOR`` point spacings),
      or outside the observed silhouette: in space the camera saw as free, a violation (Bohg et
      al.'s visibility constraint), weight 1;
    * on the observed surface: evidence of the symmetry (weight ``-SURFACE_REWARD``);
    * hidden behind the surface: plausible new shape, no evidence (weight ``-HIDDEN_REWARD``).
      The deeper behind, the more it costs (``DEPTH_PENALTY`` x mean depth / cloud diagonal):
      visibility cannot bound how far back the unseen side reaches where the mirrored copy stays
      inside the silhouette, and the most compact completion consistent with the view is the
      likeliest.

    The search runs in two stages with different rewards:

    1. Coarse, which symmetry: normals in the support plane every ``ORIENTATION_STEP_DEG`` over
       180 degrees, for each the positions every ``OFFSET_STEP_FACTOR`` point spacings from half
       the cloud's size in front of its nearest point to half its size behind its farthest (along
       that normal). Only hidden points are rewarded (``COARSE_REWARDS``): a plane containing the
       viewing ray maps the visible side onto itself (every vertical plane through a cylinder's
       axis is a symmetry plane) and would win on evidence while completing nothing; of a box's
       two symmetry planes, the one that completes more wins.
    2. Fine, where exactly: +/- ``REFINE_STEPS`` quarter steps of angle and position around the
       best, now rewarding evidence above hidden points (``REFINE_REWARDS``). With hidden points
       rewarded most, tilting the plane so that mirrored points leave the observed surface for
       the space behind it gains score at almost no visibility cost, and a box's plane wanders
       by 10 degrees.

    Without a support plane the orientation cannot be searched: the normal is then the
    horizontal component of the direction from the camera to the points' centroid ("horizontal"
    meaning perpendicular to the camera's y axis, i.e. a level camera), so the unseen back is
    assumed to mirror the front; only the position is searched.

    Args:
        points_cam: (N, 3) observed points, camera frame, metres.
        support_plane_cam: ``(a, b, c, d)`` of the table, camera frame; the normal is normalised
            and flipped if needed so that the camera is on its positive side. None: see above.
        camera_center: (3,) the viewpoint, camera frame; the camera looks along +z.

    Returns:
        The best :class:`SymmetryPlane` (ties go to the first candidate, so results repeat).
    """
    points = _observed_points(points_cam)
    center = np.asarray(camera_center, dtype=np.float64).reshape(3)
    if np.any(points[:, 2] <= center[2]):
        raise ValueError("every point must lie in front of the camera (z greater than the camera's)")
    spacing = mean_nn_distance(points)
    visibility = _DepthMap(points, center, spacing)
    sample = points[np.linspace(0, len(points) - 1, min(SCORE_POINTS, len(points))).astype(int)]
    centroid = points.mean(axis=0)
    view = centroid - center
    if support_plane_cam is None:
        up = np.array([0.0, -1.0, 0.0])
        angles = np.zeros(1)
    else:
        up, _ = unit_plane(support_plane_cam, center)
        angles = np.radians(np.arange(0.0, 180.0, ORIENTATION_STEP_DEG))
    e1 = view - (view @ up) * up
    if np.linalg.norm(e1) < 1e-9 * np.linalg.norm(view):
        # Looking straight down at the table: any in-plane direction can start the sweep.
        e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)

    size = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    step = OFFSET_STEP_FACTOR * spacing

    def best_of(thetas: np.ndarray, positions_for, rewards: tuple[float, float]) -> tuple[SymmetryPlane, float]:
        best: SymmetryPlane | None = None
        for theta in thetas:
            normal = np.cos(theta) * e1 + np.sin(theta) * e2
            candidate = _best_position(sample, normal, positions_for(normal), visibility, size, *rewards)
            if best is None or candidate.score < best.score:
                best, best_theta = candidate, theta
        assert best is not None  # thetas is never empty
        return best, best_theta

    def coarse_positions(normal: np.ndarray) -> np.ndarray:
        along = points @ normal
        return np.arange(along.min() - size / 2, along.max() + size / 2 + step, step)

    plane, theta = best_of(angles, coarse_positions, COARSE_REWARDS)
    fine_angles = (
        angles
        if support_plane_cam is None
        else (theta + np.radians(ORIENTATION_STEP_DEG / 4) * np.arange(-REFINE_STEPS, REFINE_STEPS + 1))
    )
    # Refined planes turn about the best plane's point nearest the centroid, so that they stay
    # where the object is.
    anchor = centroid - (centroid @ plane.normal + plane.offset) * plane.normal
    fine_positions = step / 4 * np.arange(-REFINE_STEPS, REFINE_STEPS + 1)
    return best_of(fine_angles, lambda n: anchor @ n + fine_positions, REFINE_REWARDS)[0]


def _best_position(
    sample: np.ndarray,
    normal: np.ndarray,
    positions: np.ndarray,
    visibility: _DepthMap,
    size: float,
    surface_reward: float,
    hidden_reward: float,
) -> SymmetryPlane:
    """Best of the planes ``normal . p = position`` for the given positions (one orientation)."""
    along = sample @ normal
    # Mirrored points for every position at once: (positions, points, 3).
    mirrored = sample[None] + 2.0 * (positions[:, None] - along[None])[..., None] * normal
    violation, surface, behind = (a.reshape(len(positions), -1) for a in visibility.classify(mirrored.reshape(-1, 3)))
    violation, surface, hidden, behind = violation.mean(1), surface.mean(1), (behind > 0).mean(1), behind.mean(1)
    score = violation - surface_reward * surface - hidden_reward * hidden + DEPTH_PENALTY * behind / size
    i = int(np.argmin(score))
    return SymmetryPlane(
        normal.copy(),
        -float(positions[i]),
        float(violation[i]),
        float(surface[i]),
        float(hidden[i]),
        float(behind[i]),
        float(score[i]),
    )


class _DepthMap:
    """The observed surface as a depth map of a virtual pinhole camera at the viewpoint.

    Bins are ``BIN_FACTOR`` x the mean point spacing wide (as an angle at the median depth), so
    every bin on the object holds points; each keeps the nearest depth (conservative: noise and
    depth edges then never make a point behind the surface look in front of it). The silhouette is
    closed and grown by one bin so that dropped pixels and edge noise do not count as free space.
    """

    def __init__(self, points: np.ndarray, center: np.ndarray, spacing: float) -> None:
        rel = points - center
        self.center = center
        self.pitch = BIN_FACTOR * spacing / float(np.median(rel[:, 2]))
        self.tolerance = DEPTH_TOLERANCE_FACTOR * spacing
        uv = rel[:, :2] / rel[:, 2:3]
        self.lo = uv.min(axis=0) - 2 * self.pitch
        idx = np.floor((uv - self.lo) / self.pitch).astype(int)
        self.shape = tuple(idx.max(axis=0) + 3)
        depth = np.full(self.shape, np.inf)
        np.minimum.at(depth, (idx[:, 0], idx[:, 1]), rel[:, 2])
        # Inside the silhouette but without a point (dropouts): depth +inf, nothing is in front.
        self.depth = depth
        self.silhouette = ndimage.binary_dilation(ndimage.binary_closing(np.isfinite(depth)), iterations=1)

    def classify(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For (N, 3) points: whether each is in seen-free space and whether it is on the observed
        surface (bool (N,) each), and how far (metres) it is hidden behind the surface along its
        ray (0 if it is not hidden). Points in bins without a measurement are none of these."""
        rel = points - self.center
        z = rel[:, 2]
        ahead = z > 0
        uv = rel[:, :2] / np.where(ahead, z, 1.0)[:, None]
        idx = np.floor((uv - self.lo) / self.pitch).astype(int)
        inside = ahead & np.all((idx >= 0) & (idx < self.shape), axis=1)
        inside[inside] = self.silhouette[idx[inside, 0], idx[inside, 1]]
        observed = np.full(len(points), np.inf)
        observed[inside] = self.depth[idx[inside, 0], idx[inside, 1]]
        # Outside the silhouette the camera saw past the object: free space at any depth.
        violation = ~inside | (z < observed - self.tolerance)
        surface = inside & (np.abs(z - observed) <= self.tolerance)
        hidden = inside & (z > observed + self.tolerance)
        return violation, surface, np.where(hidden, z - observed, 0.0)


# ----------------------------------------------------------------------------------------------
# Input checks


def _observed_points(points_cam: np.ndarray) -> np.ndarray:
    """The distinct finite rows of (N, 3) points, float64 (sorted, so the order of the input does
    not matter); ValueError if fewer than ``MIN_POINTS``."""
    points = np.asarray(points_cam, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"expected (N, 3) points, got shape {points.shape}")
    # Duplicates would make the mean nearest-neighbour distance, hence every leaf size, zero.
    points = np.unique(points[np.isfinite(points).all(axis=1)], axis=0)
    if len(points) < MIN_POINTS:
        raise ValueError(f"need at least {MIN_POINTS} distinct finite points, got {len(points)}")
    return points
