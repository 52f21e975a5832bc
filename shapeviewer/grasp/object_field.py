"""The object as the cheap stage of planning sees it: a signed-distance grid and ray casting.

Frames: the world frame (the table top is z = 0, +z up), the mesh's. Units: metres.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy import ndimage
from scipy.spatial import cKDTree
from skimage import measure

from shapeviewer.geometry import centre_of_mass, o3d_tensor, raycasting_scene
from shapeviewer.grasp.quality import max_radius

ALIGN_WEIGHT = 0.05  # m per unit of (1 - cos): GraspIt's contact energy adds 100 mm / 2 per unit
APPROACH_MARGIN = 0.004  # m: the cheap approach keeps the hand this far from the object until it stops
FIELD_MARGIN = 0.04  # m around the object covered by its signed-distance grid; farther counts as this far
FIELD_CELLS = 150_000  # signed-distance grid size cap
FIELD_MIN_STEP = 0.0025  # m: finest signed-distance grid step


class ObjectField:
    """Signed distance (m, negative inside) and its gradient around a mesh (world frame), on a
    grid of step ``h`` covering the bounds plus ``FIELD_MARGIN``.

    Inside/outside comes from ray parity (voting over three rays, which tolerates small holes in a
    mesh that is not watertight); distances from a Euclidean distance transform of that grid,
    replaced near the surface by the distance to dense surface samples (accurate to about a
    millimetre). Points off the grid read the border values, at least about the margin.
    Approach rays hit the surface ``APPROACH_MARGIN`` outside the object (marching cubes of the grid).
    """

    def __init__(self, mesh: trimesh.Trimesh, seed: int = 0):
        self.mesh = mesh
        self.com = centre_of_mass(mesh)
        self.max_radius = max_radius(mesh.vertices, self.com)
        lo = mesh.bounds[0] - FIELD_MARGIN
        hi = mesh.bounds[1] + FIELD_MARGIN
        self.h = h = max(FIELD_MIN_STEP, float(np.prod(hi - lo) / FIELD_CELLS) ** (1 / 3))
        shape = np.ceil((hi - lo) / h).astype(int) + 1
        self.origin = lo
        self.shape = shape
        axes = [lo[i] + h * np.arange(shape[i]) for i in range(3)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        scene = raycasting_scene(mesh)
        votes = 1 if mesh.is_watertight else 3
        occupancy = scene.compute_occupancy(o3d_tensor(grid.astype(np.float32)), nsamples=votes).numpy()
        inside = (occupancy > 0.5).reshape(shape)
        # Node-to-node distances to the other side put the surface about half a step away.
        sd = np.where(
            inside,
            0.5 * h - h * ndimage.distance_transform_edt(inside),
            h * ndimage.distance_transform_edt(~inside) - 0.5 * h,
        ).reshape(-1)
        # A k-d tree query is cheap near the samples and slow far from them: only the band.
        band = np.flatnonzero(np.abs(sd) < 2.5 * h)
        n_samples = int(np.clip(mesh.area / 1e-6, 5_000, 40_000))  # about one per mm^2
        samples, _ = trimesh.sample.sample_surface(mesh, n_samples, seed=seed)
        dist, _ = cKDTree(samples).query(grid[band])
        sd[band] = np.where(inside.reshape(-1)[band], -dist, dist)
        self.sd = sd = np.clip(sd, -FIELD_MARGIN, FIELD_MARGIN).reshape(shape).astype(np.float32)
        self.grad = np.stack(np.gradient(sd, h), axis=-1).astype(np.float32)
        # The approach casts rays at the surface offset by APPROACH_MARGIN: a hand sliding past
        # the object closer than that (which the exact rays would allow, and pybullet's slightly
        # padded convex parts would not) counts as touching it.
        verts, faces_, _, _ = measure.marching_cubes(sd, level=APPROACH_MARGIN, spacing=(self.h,) * 3)
        self.offset_scene = raycasting_scene(trimesh.Trimesh(verts + lo, faces_, process=False))

    def _corners(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat indices (N x 8) of the grid cell corners around each point and their weights (N x 8)."""
        f = (np.asarray(points, np.float32).reshape(-1, 3) - self.origin.astype(np.float32)) / np.float32(self.h)
        f = np.clip(f, 0.0, (self.shape - 1) - 1e-3)
        i = f.astype(np.int64)
        t = f - i
        ny, nz = self.shape[1], self.shape[2]
        base = (i[:, 0] * ny + i[:, 1]) * nz + i[:, 2]
        idx, w = [], []
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    idx.append(base + (dx * ny + dy) * nz + dz)
                    w.append(
                        (t[:, 0] if dx else 1 - t[:, 0])
                        * (t[:, 1] if dy else 1 - t[:, 1])
                        * (t[:, 2] if dz else 1 - t[:, 2])
                    )
        return np.stack(idx, axis=1), np.stack(w, axis=1)

    def nearest_signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (m) of the grid node nearest each point (... x 3, world frame): within
        about ``h`` of the exact value, one lookup per point where interpolation takes eight."""
        f = (np.asarray(points, np.float32) - self.origin.astype(np.float32)) * np.float32(1.0 / self.h)
        i = np.rint(f).astype(np.int32)
        np.minimum(np.maximum(i, 0, out=i), (self.shape - 1).astype(np.int32), out=i)
        return self.sd.reshape(-1)[(i[..., 0] * self.shape[1] + i[..., 1]) * self.shape[2] + i[..., 2]]

    def distance_and_normal(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance (m) and the outward unit normal (gradient direction) at ``points``."""
        idx, w = self._corners(points)
        sd = np.einsum("ij,ij->i", self.sd.reshape(-1)[idx], w)
        g = np.einsum("ijk,ij->ik", self.grad.reshape(-1, 3)[idx], w)
        g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-9)
        lead = np.shape(points)[:-1]
        return sd.reshape(lead), g.reshape(*lead, 3)

    def offset_ray_hits(self, origins: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """Distance (m) along unit ``direction`` (... x 3, broadcast) from each origin to the
        surface APPROACH_MARGIN outside the object; inf on a miss."""
        o = np.asarray(origins, np.float32).reshape(-1, 3)
        d = np.broadcast_to(np.asarray(direction, np.float32), np.shape(origins)).reshape(-1, 3)
        rays = o3d_tensor(np.ascontiguousarray(np.hstack([o, d])))
        return self.offset_scene.cast_rays(rays)["t_hit"].numpy().reshape(np.shape(origins)[:-1])

    def contact_energy(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """GraspIt's contact energy (m) of virtual contacts (... x V x 3 points and hand-outward
        normals, world frame): mean over V of |distance| + ALIGN_WEIGHT * (1 - cos) between the
        contact normal and the direction into the object."""
        sd, n_obj = self.distance_and_normal(points)
        cos = -np.einsum("...i,...i->...", normals, n_obj)
        return np.mean(np.minimum(np.abs(sd), FIELD_MARGIN) + ALIGN_WEIGHT * (1.0 - cos), axis=-1)
