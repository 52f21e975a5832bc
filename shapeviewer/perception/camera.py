"""The pinhole depth camera: intrinsics, poses and back-projection of depth images.

Frames: the camera optical frame has x right, y down, z forward (metres). ``T_world_cam`` is the
4x4 pose of the camera in the world (maps camera-frame points to world-frame points).
Depth images are (H, W) float32 metres along the optical axis, 0 where there is no measurement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics (OpenCV convention: pixel (u, v) centre at integer coordinates)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def kinect(cls) -> Intrinsics:
        """The Kinect v1 depth camera: 640x480, fx = fy = 525 (vertical FOV about 0.86 rad)."""
        return cls(640, 480, 525.0, 525.0, 319.5, 239.5)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    @property
    def vertical_fov(self) -> float:
        """Full vertical field of view, radians (image height over the focal length in pixels)."""
        return 2.0 * math.atan2(self.height / 2.0, self.fy)

    @property
    def aspect(self) -> float:
        """Image width / height (pixels)."""
        return self.width / self.height

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in ("width", "height", "fx", "fy", "cx", "cy")}

    @classmethod
    def from_dict(cls, d: dict) -> Intrinsics:
        return cls(int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"]), float(d["cx"]), float(d["cy"]))

    def pixel_directions(self) -> np.ndarray:
        """(H, W, 3) camera-frame ray directions with z = 1, so a hit's ray parameter is its depth.

        Read-only (cached per intrinsics).
        """
        return _pixel_directions(self)


@lru_cache(maxsize=8)
def _pixel_directions(intr: Intrinsics) -> np.ndarray:
    u, v = np.meshgrid(np.arange(intr.width, dtype=np.float32), np.arange(intr.height, dtype=np.float32))
    d = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], axis=-1)
    d.setflags(write=False)
    return d


def look_at(eye: npt.ArrayLike, target: npt.ArrayLike, up: npt.ArrayLike = (0.0, 0.0, 1.0)) -> np.ndarray:
    """``T_world_cam`` of an optical-frame camera at ``eye`` looking at ``target`` (world metres)."""
    eye, target, up = (np.asarray(a, dtype=np.float64) for a in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:  # looking along `up`: any perpendicular x will do
        x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, eye
    return T


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to (N, 3) points (NaN rows stay NaN)."""
    points = np.asarray(points, dtype=np.float64)
    return points @ T[:3, :3].T + T[:3, 3]


def backproject(depth: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """Organized camera-frame cloud (H, W, 3) metres from a depth image; NaN where depth is 0/invalid."""
    depth = np.asarray(depth, dtype=np.float32)
    if depth.shape != (intr.height, intr.width):
        raise ValueError(f"depth image is {depth.shape}, intrinsics say {(intr.height, intr.width)}")
    pts = intr.pixel_directions() * depth[..., None]
    pts[~(np.isfinite(depth) & (depth > 0))] = np.nan
    return pts


def backproject_valid(depth: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """Camera-frame points (N, 3) metres of the measured pixels of a depth image (row-major order)."""
    depth = np.asarray(depth, dtype=np.float32)
    v, u = np.nonzero(np.isfinite(depth) & (depth > 0))
    z = depth[v, u]
    return np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], axis=1)
