"""Voxel grids in the paper's placement (Varley et al. 2017, Sec. IV-B).

A partial view is scaled so that the largest side of its axis-aligned bounding box spans
``GRID_SPAN`` (32) voxels and translated so that the box centre lands on voxel coordinate
``CENTER_INDEX`` (20, 20, 18) of a ``GRID_DIM``^3 (40^3) grid. The two-voxel shift along z (the
camera's viewing direction) leaves room behind the visible surface for the network to fill.

Grids are bool/float arrays indexed ``[x, y, z]`` in the camera optical frame (x right, y down,
z forward). A :class:`GridFrame` carries the mapping between grid coordinates and camera metres;
keep it with every grid so CNN outputs and meshes go back to metres.

Coordinate conventions used throughout:

* *grid coordinates* are continuous; voxel ``(i, j, k)`` covers ``[i, i+1) x [j, j+1) x [k, k+1)``
  and its centre is at ``(i, j, k) + 0.5``.
* *index* is ``floor(grid coordinates)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from ..geometry import o3d_tensor, raycasting_scene

GRID_DIM = 40
GRID_SPAN = 32
CENTER_INDEX = np.array([20.0, 20.0, 18.0])
FRONT_MARGIN = 2.0  # voxels kept empty in front of the visible box when the placement moves it forward


@dataclass(frozen=True)
class GridFrame:
    """Maps grid coordinates of a ``dim``^3 grid to camera-frame metres.

    Attributes:
        center: (3,) camera-frame point (metres) that sits at grid coordinate ``CENTER_INDEX``.
        voxel_size: edge length of one voxel in metres.
        dim: number of voxels per side.
    """

    center: np.ndarray
    voxel_size: float
    dim: int = GRID_DIM

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", np.asarray(self.center, dtype=np.float64).reshape(3))
        object.__setattr__(self, "voxel_size", float(self.voxel_size))
        if not np.all(np.isfinite(self.center)) or not (self.voxel_size > 0):
            raise ValueError(f"invalid grid frame: center={self.center}, voxel_size={self.voxel_size}")

    @classmethod
    def from_corner(cls, corner: np.ndarray, voxel_size: float, dim: int) -> GridFrame:
        """The frame of a ``dim``^3 grid whose voxel (0, 0, 0) starts at ``corner`` (camera metres)."""
        # ``center`` sits at grid coordinate CENTER_INDEX * dim / 40: place it so that grid
        # coordinate 0 lands on ``corner``.
        return cls(np.asarray(corner, dtype=np.float64) + CENTER_INDEX * (dim / GRID_DIM) * voxel_size, voxel_size, dim)

    @property
    def offset(self) -> np.ndarray:
        """Grid coordinate of ``center`` (scaled with ``dim`` so up-sampled grids stay aligned)."""
        return CENTER_INDEX * (self.dim / GRID_DIM)

    def to_grid(self, points_cam: np.ndarray) -> np.ndarray:
        """Camera-frame metres (N, 3) -> continuous grid coordinates (N, 3)."""
        return (np.asarray(points_cam, dtype=np.float64) - self.center) / self.voxel_size + self.offset

    def to_index(self, points_cam: np.ndarray) -> np.ndarray:
        """Camera-frame metres (N, 3) -> integer voxel indices (N, 3) (may fall outside the grid)."""
        return np.floor(self.to_grid(points_cam)).astype(np.int64)

    def to_metres(self, grid_coords: np.ndarray) -> np.ndarray:
        """Continuous grid coordinates (N, 3) -> camera-frame metres (N, 3)."""
        return (np.asarray(grid_coords, dtype=np.float64) - self.offset) * self.voxel_size + self.center

    def voxel_centers(self, indices: np.ndarray) -> np.ndarray:
        """Integer voxel indices (N, 3) -> camera-frame metres (N, 3) of the voxel centres."""
        return self.to_metres(np.asarray(indices, dtype=np.float64) + 0.5)

    def grid_to_camera(self) -> np.ndarray:
        """4x4 homogeneous transform taking grid coordinates to camera-frame metres."""
        T = np.eye(4)
        T[:3, :3] *= self.voxel_size
        T[:3, 3] = self.center - self.offset * self.voxel_size
        return T

    def to_dict(self) -> dict:
        return {"center": self.center.tolist(), "voxel_size": self.voxel_size, "dim": self.dim}

    @classmethod
    def from_dict(cls, d: dict) -> GridFrame:
        return cls(np.asarray(d["center"], dtype=np.float64), float(d["voxel_size"]), int(d.get("dim", GRID_DIM)))


def frame_for_points(points_cam: np.ndarray, *, depth_shift: float = 0.0) -> GridFrame:
    """The grid placement for a partial view (camera-frame metres, (N, 3)).

    With ``depth_shift=0`` this is the paper's placement: the visible box's centre at voxel
    (20, 20, 18). That leaves the back of deep objects (cans, cups, fruit) outside the grid in
    most tabletop views (``benchmarks/studies/grid_room.py``), so a network can be trained with the
    object moved up to ``depth_shift`` voxels towards the camera instead; the front of the
    visible box stays at least ``FRONT_MARGIN`` voxels inside the grid. A network's placement is
    in its weights (:attr:`shapeviewer.completion.model.Completer.depth_shift`); inference must use it.
    """
    pts = _finite_points(points_cam)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    extent = float((hi - lo).max())
    if extent <= 0:
        raise ValueError("cannot place a grid on a cloud with zero extent (all points identical)")
    if not (np.isfinite(depth_shift) and depth_shift >= 0):
        raise ValueError(f"depth_shift must be a finite number of voxels >= 0, got {depth_shift}")
    voxel_size = extent / GRID_SPAN
    front = CENTER_INDEX[2] - (hi[2] - lo[2]) / voxel_size / 2.0
    shift = min(float(depth_shift), max(0.0, front - FRONT_MARGIN))
    return GridFrame(center=(lo + hi) / 2.0 + np.array([0.0, 0.0, shift * voxel_size]), voxel_size=voxel_size)


def points_to_grid(points_cam: np.ndarray, frame: GridFrame) -> np.ndarray:
    """Occupancy (bool, ``frame.dim``^3, [x, y, z]) of the voxels that camera-frame points fall in.

    Points outside the grid are dropped.
    """
    grid = np.zeros(frame.dim**3, dtype=bool)
    pts = _finite_points(points_cam, allow_empty=True)
    g = np.floor((pts - frame.center) * (1.0 / frame.voxel_size) + frame.offset)
    inside = np.all((g >= 0) & (g < frame.dim), axis=1)
    idx = g[inside].astype(np.int64)
    grid[(idx[:, 0] * frame.dim + idx[:, 1]) * frame.dim + idx[:, 2]] = True
    return grid.reshape((frame.dim,) * 3)


def partial_to_grid(points_cam: np.ndarray, *, depth_shift: float = 0.0) -> tuple[np.ndarray, GridFrame]:
    """Voxelize a partial view into the CNN's 40^3 input grid (the paper's placement by default).

    Args:
        points_cam: (N, 3) points in the camera optical frame (metres, x right, y down, z forward).
            Non-finite rows are ignored.
        depth_shift: voxels to move the object towards the camera (:func:`frame_for_points`).

    Returns:
        ``(grid, frame)``: a (40, 40, 40) bool occupancy array indexed [x, y, z] and its
        :class:`GridFrame` (index = floor((p - center) / voxel_size + (20, 20, 18))).
    """
    frame = frame_for_points(points_cam, depth_shift=depth_shift)
    return points_to_grid(points_cam, frame), frame


def solid_grid(
    mesh: trimesh.Trimesh,
    frame: GridFrame,
    T_cam_mesh: np.ndarray | None = None,
    surface_points: np.ndarray | None = None,
    scene=None,
) -> np.ndarray:
    """Every voxel a closed mesh touches: its interior and every voxel its surface passes through.

    This is the ground truth Y of the paper (binvox marks surface and interior).
    The interior comes from exact inside tests of the voxel centres; the surface voxels from dense
    surface samples. Never a hole-filled surface voxelization (that over-fills thin shells).

    Args:
        mesh: closed triangle mesh in its own frame (metres).
        frame: the grid frame (camera frame, usually the partial view's).
        T_cam_mesh: 4x4 pose of the mesh in the camera frame (identity when omitted).
        surface_points: dense samples of the surface in the mesh frame, spacing well under half a
            voxel (see :func:`surface_samples`). Sampled here when omitted.
        scene: an optional prebuilt ray-casting scene holding ``mesh`` (mesh frame; see
            :func:`~shapeviewer.geometry.raycasting_scene`), reused across views of one object.
    """
    T = np.eye(4) if T_cam_mesh is None else np.asarray(T_cam_mesh, dtype=np.float64)
    grid = np.zeros((frame.dim,) * 3, dtype=bool)
    corners = trimesh.bounds.corners(mesh.bounds)
    g = frame.to_grid(corners @ T[:3, :3].T + T[:3, 3])
    # Only voxels inside the mesh's bounding box can be inside it.
    lo = np.clip(np.floor(g.min(axis=0)).astype(int), 0, frame.dim)
    hi = np.clip(np.ceil(g.max(axis=0)).astype(int), 0, frame.dim)
    if np.all(hi > lo):
        ii, jj, kk = np.meshgrid(*(np.arange(a, b) for a, b in zip(lo, hi)), indexing="ij")
        idx = np.stack([ii.ravel(), jj.ravel(), kk.ravel()], axis=1)
        if scene is None:
            scene = raycasting_scene(mesh)
        centers_mesh = (frame.voxel_centers(idx) - T[:3, 3]) @ T[:3, :3]
        inside = scene.compute_occupancy(o3d_tensor(centers_mesh.astype(np.float32))).numpy().astype(bool)
        idx = idx[inside]
        grid[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    if surface_points is None:
        surface_points = surface_samples(mesh, spacing=frame.voxel_size / 4)
    grid |= points_to_grid(surface_points @ T[:3, :3].T + T[:3, 3], frame)
    return grid


FRACTION_MARGIN = 0.25  # voxels: the solid is grown by a quarter voxel, so walls thinner than a voxel survive


def solid_fraction(
    mesh: trimesh.Trimesh,
    frame: GridFrame,
    solid: np.ndarray,
    T_cam_mesh: np.ndarray | None = None,
    scene=None,
    margin: float = FRACTION_MARGIN,
) -> np.ndarray:
    """How much of each voxel a closed mesh fills, from the signed distance at its centre: a soft label.

    :func:`solid_grid` marks every voxel the surface touches, so its 0.5 contour lies up to a voxel
    outside the object and a shape learnt from it is fat. Here interior voxels are 1 and a voxel the
    surface passes through holds ``0.5 + margin - d / voxel_size`` (clipped to [0, 1]), ``d`` the
    signed distance of its centre (negative inside): the share of the voxel a plane at that distance
    leaves inside the solid grown by ``margin`` voxels. Its 0.5 contour lies ``margin`` voxels
    outside the surface; the margin keeps walls thinner than a voxel (a plate, a mug's wall) above
    0.5 where they cross a voxel centre.

    Args:
        mesh: closed triangle mesh in its own frame (metres).
        frame: the grid frame.
        solid: the :func:`solid_grid` of the same mesh and frame (bool, 40^3): the label is 0
            outside it.
        T_cam_mesh: 4x4 pose of the mesh in the camera frame (identity when omitted).
        scene: an optional prebuilt ray-casting scene holding ``mesh`` (mesh frame).
        margin: growth of the solid, in voxels.

    Returns:
        float32 (40, 40, 40) in [0, 1].
    """
    from scipy import ndimage

    T = np.eye(4) if T_cam_mesh is None else np.asarray(T_cam_mesh, dtype=np.float64)
    solid = np.asarray(solid, dtype=bool)
    out = solid.astype(np.float32)
    # Only voxels with an empty neighbour can hold the surface (the mesh has no inner cavities).
    boundary = solid & ~ndimage.binary_erosion(solid, np.ones((3, 3, 3), bool), border_value=0)
    idx = np.argwhere(boundary)
    if len(idx) == 0:
        return out
    if scene is None:
        scene = raycasting_scene(mesh)
    centres_mesh = (frame.voxel_centers(idx) - T[:3, 3]) @ T[:3, :3]
    signed = scene.compute_signed_distance(o3d_tensor(centres_mesh.astype(np.float32))).numpy()
    out[boundary] = np.clip(0.5 + margin - signed / frame.voxel_size, 0.0, 1.0)
    return out


def surface_samples(mesh: trimesh.Trimesh, spacing: float, max_points: int = 2_000_000, seed: int = 0) -> np.ndarray:
    """Points on the surface of ``mesh`` about ``spacing`` apart (same frame and unit as the mesh).

    Includes the vertices so that small features are never missed.
    """
    n = int(min(max_points, max(1000, 2.0 * mesh.area / spacing**2)))
    pts, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return np.concatenate([pts, mesh.vertices], axis=0)


def _finite_points(points: np.ndarray, allow_empty: bool = False) -> np.ndarray:
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    finite = np.isfinite(pts).all(axis=1)
    if not finite.all():
        pts = pts[finite]
    if len(pts) == 0 and not allow_empty:
        raise ValueError("the point cloud has no finite points")
    return pts


# ----------------------------------------------------------------------------------------------
# What the camera knows besides the points: free space and the support plane.

CONTEXT_CHANNELS = ("seen_free", "below_plane")


def seen_free(centres_cam: np.ndarray, observed_points_cam: np.ndarray, margin: float) -> np.ndarray:
    """Which camera-frame points lie in space the camera saw through, in front of the surface.

    The observed points are binned by ray direction (x/z, y/z) at ``margin`` metres' width at
    their median depth; a point is seen free when it lies more than ``margin`` in front of the
    nearest observed point of its own ray bin and of the 8 bins around it (so the silhouette's
    edge, where a bin is only partly covered, stays unknown). Bins without points are unknown.

    Args:
        centres_cam: (M, 3) query points, camera frame, metres (e.g. voxel centres).
        observed_points_cam: (N, 3) the segment's observed points, camera frame, metres.
        margin: metres; also the angular bin width at the points' median depth.

    Returns:
        (M,) bool.
    """
    pts = np.asarray(observed_points_cam, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1) & (pts[:, 2] > 0)]
    centres = np.asarray(centres_cam, dtype=np.float64).reshape(-1, 3)
    out = np.zeros(len(centres), bool)
    if len(pts) == 0 or len(centres) == 0:
        return out
    from scipy import ndimage

    step = margin / float(np.median(pts[:, 2]))
    rays = np.floor(pts[:, :2] / pts[:, 2:3] / step).astype(np.int64)
    lo = rays.min(0) - 1
    rays -= lo
    nearest = np.full(rays.max(0) + 2, np.inf)
    np.minimum.at(nearest, (rays[:, 0], rays[:, 1]), pts[:, 2])
    # A neighbour without points (inf) must not make its neighbours free: use -inf for unknown.
    nearest = ndimage.minimum_filter(
        np.where(np.isfinite(nearest), nearest, -np.inf), size=3, mode="constant", cval=-np.inf
    )
    ahead = centres[:, 2] > 1e-6
    bins = np.floor(centres[ahead, :2] / centres[ahead, 2:3] / step).astype(np.int64) - lo
    inside = ((bins >= 0) & (bins < nearest.shape)).all(axis=1)
    seen = np.full(len(bins), -np.inf)
    seen[inside] = nearest[bins[inside, 0], bins[inside, 1]]
    out[ahead] = centres[ahead, 2] < seen - margin
    return out


def below_plane(centres_cam: np.ndarray, plane_cam: np.ndarray, half_extent: float) -> np.ndarray:
    """Which axis-aligned cubes (centres (M, 3) camera metres, half side ``half_extent``) lie wholly
    under the support plane ``(a, b, c, d)`` (unit normal towards the camera, camera frame)."""
    n, d = unit_plane(plane_cam)
    height = np.asarray(centres_cam, dtype=np.float64).reshape(-1, 3) @ n + d
    return height < -half_extent * float(np.abs(n).sum())


def unit_plane(plane: np.ndarray, camera_center: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """``(normal, d)`` of a plane ``(a, b, c, d)``: unit normal, turned towards ``camera_center``
    (camera frame metres; the camera's own centre by default). ValueError if malformed."""
    plane = np.asarray(plane, dtype=np.float64).reshape(-1)
    if plane.shape != (4,) or not np.all(np.isfinite(plane)):
        raise ValueError(f"a plane is 4 finite numbers (a, b, c, d), got {plane}")
    length = np.linalg.norm(plane[:3])
    if length < 1e-12:
        raise ValueError("the support plane's normal (a, b, c) is zero")
    normal, d = plane[:3] / length, plane[3] / length
    centre = np.zeros(3) if camera_center is None else np.asarray(camera_center, dtype=np.float64)
    if normal @ centre + d < 0:
        normal, d = -normal, -d
    return normal, float(d)


def context_grids(points_cam: np.ndarray, frame: GridFrame, *, support_plane: np.ndarray | None = None) -> np.ndarray:
    """The network's context channels: (2, dim, dim, dim) bool, [x, y, z], in ``frame``.

    Channel 0 (``seen_free``): voxels whose centre the camera saw through, more than one voxel in
    front of the observed surface (:func:`seen_free`). Channel 1 (``below_plane``): voxels wholly
    under the support plane ``(a, b, c, d)`` (camera frame, normal towards the camera); all False
    when ``support_plane`` is None (no table known). Both are known to be empty.
    """
    idx = np.indices((frame.dim,) * 3).reshape(3, -1).T
    centres = frame.voxel_centers(idx)
    out = np.zeros((2, frame.dim**3), bool)
    out[0] = seen_free(centres, points_cam, frame.voxel_size)
    if support_plane is not None:
        out[1] = below_plane(centres, support_plane, frame.voxel_size / 2)
    return out.reshape((2,) + (frame.dim,) * 3)
