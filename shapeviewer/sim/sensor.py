"""The simulated depth sensor: ray-cast rendering of meshes and Kinect / RealSense depth noise.

Frames and units as in :mod:`shapeviewer.perception.camera`: camera optical frame (x right, y down,
z forward, metres); depth images (H, W) float32 metres along the optical axis, 0 = no measurement.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, replace

import numpy as np

from ..geometry import o3d_tensor, raycasting_scene
from ..perception.camera import Intrinsics, transform_points


class RaycastRenderer:
    """Renders depth and per-pixel mesh ids of triangle meshes with Open3D's ray casting.

    Meshes are given in the world frame (metres). Only rays inside the meshes' projected bounding
    box are cast, which makes single-object renders fast.
    """

    def __init__(self, meshes_world: list) -> None:
        self.scene = raycasting_scene(*meshes_world)
        self.bounds = [np.asarray(m.bounds) for m in meshes_world]

    def render(
        self, intr: Intrinsics, T_world_cam: np.ndarray, crop_to_objects: bool = True, with_normals: bool = False
    ) -> tuple[np.ndarray, ...]:
        """Depth (H, W) float32 metres (0 = no hit) and mesh ids (H, W) int32 (-1 = no hit).

        With ``with_normals``, a third output: the hit triangles' unit normals (H, W, 3) float32 in
        the world frame, as stored in the meshes (not flipped towards the camera), 0 where no hit.
        """
        dirs_cam = intr.pixel_directions()
        v0, v1, u0, u1 = 0, intr.height, 0, intr.width
        depth = np.zeros((intr.height, intr.width), np.float32)
        gid = np.full((intr.height, intr.width), -1, np.int32)
        normals = np.zeros((intr.height, intr.width, 3), np.float32) if with_normals else None
        outputs: tuple[np.ndarray, ...] = (depth, gid) if normals is None else (depth, gid, normals)
        if crop_to_objects and self.bounds:
            box = _projected_box(self.bounds, intr, T_world_cam)
            if box is None:
                return outputs
            v0, v1, u0, u1 = box
        R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
        d = dirs_cam[v0:v1, u0:u1] @ R.T.astype(np.float32)
        rays = np.concatenate([np.broadcast_to(t.astype(np.float32), d.shape), d], axis=-1)
        hit = self.scene.cast_rays(o3d_tensor(np.ascontiguousarray(rays)))
        t_hit = hit["t_hit"].numpy()
        ids = hit["geometry_ids"].numpy().astype(np.int64)
        ok = np.isfinite(t_hit)
        depth[v0:v1, u0:u1] = np.where(ok, t_hit, 0.0)
        gid[v0:v1, u0:u1] = np.where(ok, ids, -1)
        if normals is not None:
            normals[v0:v1, u0:u1] = np.where(ok[..., None], hit["primitive_normals"].numpy(), 0.0)
        return outputs


def _projected_box(bounds: list, intr: Intrinsics, T_world_cam: np.ndarray):
    import trimesh

    corners = np.concatenate([trimesh.bounds.corners(b) for b in bounds])
    pc = transform_points(np.linalg.inv(T_world_cam), corners)
    if np.any(pc[:, 2] <= 1e-6):  # a box reaches behind the camera: cast everything
        return 0, intr.height, 0, intr.width
    u = pc[:, 0] / pc[:, 2] * intr.fx + intr.cx
    v = pc[:, 1] / pc[:, 2] * intr.fy + intr.cy
    u0, u1 = int(max(0, np.floor(u.min()))), int(min(intr.width, np.ceil(u.max()) + 1))
    v0, v1 = int(max(0, np.floor(v.min()))), int(min(intr.height, np.ceil(v.max()) + 1))
    if u0 >= u1 or v0 >= v1:
        return None
    return v0, v1, u0, u1


@dataclass(frozen=True)
class DepthNoise(ABC):
    """A depth sensor model: :meth:`apply` turns an ideal depth image into a measured one.

    Every model's depth error has a constant part ``sigma_a`` and a part ``sigma_b`` that grows
    with the depth (metres); each subclass says how it grows.
    """

    sigma_a: float = 0.0
    sigma_b: float = 0.0

    @property
    def reach_px(self) -> int | None:
        """How far (pixels) from the measured pixels the noise reaches; None: anywhere in the image."""
        return None

    def scaled(self, factor: float) -> DepthNoise:
        """The same sensor with ``factor`` times the depth error (``sigma_a`` and ``sigma_b``): a
        worse sensor, or a worse surface, than the model's, for stress tests and training."""
        return replace(self, sigma_a=self.sigma_a * factor, sigma_b=self.sigma_b * factor)

    def apply(self, depth: np.ndarray, seed: int | np.random.Generator = 0) -> np.ndarray:
        """A noisy copy of an ideal depth image (metres, 0 = missing), drawn from ``seed``."""
        depth = np.asarray(depth, dtype=np.float32)
        rows, cols = np.nonzero(np.any(depth > 0, axis=1))[0], np.nonzero(np.any(depth > 0, axis=0))[0]
        out = np.zeros_like(depth)
        if len(rows) == 0:
            return out
        rng = np.random.default_rng(seed)
        if self.reach_px is None:
            return self._noisy(depth, rng)
        # Work on the measured region only (single-object renders cover a small part of the image).
        pad = self.reach_px
        v0, v1 = max(0, rows[0] - pad), min(depth.shape[0], rows[-1] + pad + 1)
        u0, u1 = max(0, cols[0] - pad), min(depth.shape[1], cols[-1] + pad + 1)
        out[v0:v1, u0:u1] = self._noisy(depth[v0:v1, u0:u1], rng)
        return out

    @abstractmethod
    def _noisy(self, depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The noisy image of a float32 depth image (or of its region within ``reach_px``)."""


@dataclass(frozen=True)
class KinectNoise(DepthNoise):
    """A Kinect v1 style depth sensor model (Khoshelham & Elberink 2012; Nguyen et al. 2012).

    * axial noise: Gaussian with sigma(z) = ``sigma_a + sigma_b * (z - 0.4)^2`` metres;
    * lateral noise: the depth is sampled up to ``lateral_px`` pixels away;
    * disparity quantisation: depth steps of ``quant * z^2`` metres (1/8 pixel disparity, 7.5 cm baseline);
    * missing pixels at depth edges (jumps over ``edge_jump`` metres within ``edge_px`` pixels),
      on grazing surfaces, and a few at random (``dropout``); range limits ``near``-``far``.
    """

    sigma_a: float = 0.0012
    sigma_b: float = 0.0019
    lateral_px: float = 0.5
    quant: float = 0.00285
    edge_jump: float = 0.03
    edge_px: int = 1
    dropout: float = 0.01
    near: float = 0.4
    far: float = 4.0

    @property
    def reach_px(self) -> int:
        """The margin kept around the measured pixels: depth edges within ``edge_px`` of them and the
        lateral jitter's neighbours."""
        return self.edge_px + 2

    def _noisy(self, depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        valid = depth > 0
        out = depth.copy()
        if self.lateral_px > 0:
            h, w = depth.shape
            vv, uu = np.nonzero(valid)
            du = np.rint(rng.normal(0, self.lateral_px, len(uu))).astype(int)
            dv = np.rint(rng.normal(0, self.lateral_px, len(vv))).astype(int)
            out[vv, uu] = depth[np.clip(vv + dv, 0, h - 1), np.clip(uu + du, 0, w - 1)]
        z = out
        noisy = z + rng.normal(0.0, 1.0, z.shape).astype(np.float32) * (self.sigma_a + self.sigma_b * (z - 0.4) ** 2)
        step = self.quant * noisy**2
        noisy = np.where(step > 0, np.round(noisy / np.maximum(step, 1e-9)) * step, noisy)
        ok = valid & (out > 0) & (noisy > self.near) & (noisy < self.far)
        ok &= ~depth_edges(depth, self.edge_jump, self.edge_px)
        ok &= rng.random(depth.shape) >= self.dropout
        return np.where(ok, noisy, 0.0).astype(np.float32)


def depth_edges(depth: np.ndarray, jump: float, radius: int = 1) -> np.ndarray:
    """Pixels within ``radius`` of a depth discontinuity larger than ``jump`` metres (or of a hole)."""
    from scipy import ndimage

    d = np.where(depth > 0, depth, np.inf)
    size = 2 * radius + 1
    hi = ndimage.maximum_filter(d, size=size, mode="nearest")
    lo = ndimage.minimum_filter(d, size=size, mode="nearest")
    with np.errstate(invalid="ignore"):
        return (depth > 0) & ((hi - lo) > jump)


@dataclass(frozen=True)
class RealSenseNoise(DepthNoise):
    """An Intel RealSense D400 style active-stereo depth model (Ahn et al. 2019; Intel's tuning guide).

    * depth error growing with z^2: Gaussian sigma(z) = ``sigma_a + sigma_b * z^2`` metres
      (subpixel disparity noise over a 5 cm baseline), correlated over ``blob_px`` pixels as the
      stereo matcher's window smears it;
    * flying pixels at depth edges: within ``edge_px`` of a jump over ``edge_jump`` metres, a pixel
      takes a depth between the near and the far side (``flying``) or is dropped (``edge_dropout``);
    * holes: blobs of missing pixels covering about ``hole_fraction`` of the image, plus
      ``dropout`` at random; range limits ``near``-``far``.
    """

    sigma_a: float = 0.0008
    sigma_b: float = 0.0025
    blob_px: float = 2.0
    edge_jump: float = 0.02
    edge_px: int = 1
    flying: float = 0.2
    edge_dropout: float = 0.4
    hole_fraction: float = 0.03
    dropout: float = 0.005
    near: float = 0.2
    far: float = 4.0

    def _noisy(self, depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        from scipy import ndimage

        valid = depth > 0
        smooth = ndimage.gaussian_filter(rng.normal(0.0, 1.0, depth.shape).astype(np.float32), self.blob_px)
        smooth /= max(float(smooth.std()), 1e-9)
        out = depth + smooth * (self.sigma_a + self.sigma_b * depth**2)
        # Flying pixels: mix the near and far sides of each edge.
        edges = depth_edges(depth, self.edge_jump, self.edge_px)
        d = np.where(valid, depth, np.inf)
        size = 2 * self.edge_px + 1
        near_side = ndimage.minimum_filter(d, size=size, mode="nearest")
        far_side = ndimage.maximum_filter(np.where(valid, depth, 0.0), size=size, mode="nearest")
        u = rng.random(depth.shape)
        fly = edges & (u < self.flying) & np.isfinite(near_side) & (far_side > 0)
        mix = rng.random(depth.shape).astype(np.float32)
        with np.errstate(invalid="ignore"):  # inf where a window holds no measurement; not used there
            out = np.where(fly, near_side + mix * (far_side - near_side), out)
        drop = edges & (u >= self.flying) & (u < self.flying + self.edge_dropout)
        # Holes: thresholded smooth noise gives blobs of a few to tens of pixels.
        blobs = ndimage.gaussian_filter(rng.normal(0.0, 1.0, depth.shape).astype(np.float32), 4.0)
        holes = blobs > np.quantile(blobs, 1.0 - self.hole_fraction)
        ok = valid & ~drop & ~holes & (rng.random(depth.shape) >= self.dropout)
        ok &= (out > self.near) & (out < self.far)
        return np.where(ok, out, 0.0).astype(np.float32)


def noise_model(name: str | None) -> DepthNoise | None:
    """The sensor model by name: ``kinect``, ``realsense`` or None / ``none`` (an ideal sensor)."""
    models = {"kinect": KinectNoise, "realsense": RealSenseNoise}
    if name is None or name == "none":
        return None
    if name not in models:
        raise ValueError(f"unknown sensor noise {name!r}; choose one of {sorted(models)} or 'none'")
    return models[name]()
