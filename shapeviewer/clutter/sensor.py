"""The benchmark's single side view: a pinhole depth camera rendered with pybullet, and the "dex"
depth noise (GIGA's ``apply_dex_noise``), delivered as a :class:`~shapeviewer.perception.capture.Capture`.

Frames: the camera optical frame (x right, y down, z forward) and the benchmark's world frame
(:mod:`.scene`); depth images (H, W) float32 metres along the optical axis, 0 = no measurement.
"""

from __future__ import annotations

import math

import numpy as np

from ..perception.camera import Intrinsics, backproject, look_at
from ..perception.capture import Capture
from ..runtime.bullet import pybullet as p
from .scene import WORKSPACE, ClutterWorld

INTRINSICS = Intrinsics(640, 480, 540.0, 540.0, 320.0, 240.0)
NEAR, FAR = 0.1, 2.0  # m: the renderer's clipping planes
VIEW_TARGET = (WORKSPACE / 2, WORKSPACE / 2, WORKSPACE / 3)  # m: the point the camera looks at
VIEW_RADIUS = 2 * WORKSPACE  # m: the camera's distance from it
VIEW_POLAR = math.pi / 3  # rad from the vertical
VIEW_AZIMUTH = -math.pi / 2  # rad: the camera stands on the workspace's -y side
# "dex" noise: a multiplicative Gamma(k, theta) factor on the whole image, and with probability
# GP_RATE an additive Gaussian field of GP_SIGMA drawn at 1/GP_SCALE of the resolution, upsampled bilinearly.
GAMMA_SHAPE, GAMMA_SCALE = 1000.0, 0.001
GP_SIGMA, GP_SCALE, GP_RATE = 0.005, 4.0, 0.5


def side_view(radius: float = VIEW_RADIUS, polar: float = VIEW_POLAR, azimuth: float = VIEW_AZIMUTH) -> np.ndarray:
    """``T_world_cam`` of the camera on the sphere of ``radius`` (m) about VIEW_TARGET at ``polar``
    (from +z) and ``azimuth`` (from +x) angles (rad), looking at VIEW_TARGET with +z up."""
    target = np.asarray(VIEW_TARGET)
    eye = target + radius * np.array(
        [math.sin(polar) * math.cos(azimuth), math.sin(polar) * math.sin(azimuth), math.cos(polar)]
    )
    return look_at(eye, target, (0.0, 0.0, 1.0))


def _projection(intr: Intrinsics, near: float, far: float) -> np.ndarray:
    """The OpenGL projection matrix of pinhole intrinsics (pixel centres at integers)."""
    persp = np.array(
        [
            [intr.fx, 0.0, -intr.cx, 0.0],
            [0.0, intr.fy, -intr.cy, 0.0],
            [0.0, 0.0, near + far, near * far],
            [0.0, 0.0, -1.0, 0.0],
        ]
    )
    # glOrtho(0, width, height, 0, near, far)
    ortho = np.diag([2.0 / intr.width, -2.0 / intr.height, -2.0 / (far - near), 1.0])
    ortho[:3, 3] = [-1.0, 1.0, -(far + near) / (far - near)]
    return ortho @ persp


def render_depth(world: ClutterWorld, T_world_cam: np.ndarray, intr: Intrinsics = INTRINSICS) -> np.ndarray:
    """The ideal depth image (H, W) float32 metres of ``world`` seen from ``T_world_cam``; 0 where
    no surface lies within the far plane."""
    view = np.linalg.inv(T_world_cam)  # T_cam_world
    view[2, :] *= -1  # OpenGL's camera looks along -z
    w, h, _, zbuf, _ = p.getCameraImage(
        intr.width,
        intr.height,
        viewMatrix=view.flatten(order="F").tolist(),
        projectionMatrix=_projection(intr, NEAR, FAR).flatten(order="F").tolist(),
        renderer=p.ER_TINY_RENDERER,
        physicsClientId=world.client,
    )
    z = np.asarray(zbuf, dtype=np.float64).reshape(h, w)
    depth = FAR * NEAR / (FAR - (FAR - NEAR) * z)
    return np.where(z < 1.0 - 1e-7, depth, 0.0).astype(np.float32)


def dex_noise(depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``depth`` (metres, 0 = missing) with the "dex" noise: times one Gamma(GAMMA_SHAPE,
    GAMMA_SCALE) draw, plus with probability GP_RATE a Gaussian field (GP_SIGMA m) drawn on a grid
    GP_SCALE times coarser and resized bilinearly to the image. Missing pixels stay 0."""
    from skimage.transform import resize

    depth = np.asarray(depth, dtype=np.float64)
    out = depth * rng.gamma(GAMMA_SHAPE, GAMMA_SCALE)
    if rng.random() < GP_RATE:
        h, w = depth.shape
        field = rng.standard_normal((int(h / GP_SCALE), int(w / GP_SCALE))) * GP_SIGMA
        out = out + resize(field, (h, w), order=1, anti_aliasing=False, mode="constant")
    return np.where(depth > 0, out, 0.0).astype(np.float32)


def capture_view(
    world: ClutterWorld,
    rng: np.random.Generator | None,
    *,
    T_world_cam: np.ndarray | None = None,
    intr: Intrinsics = INTRINSICS,
    source: str = "clutter",
) -> tuple[Capture, np.ndarray]:
    """The capture of the side view (with "dex" noise drawn from ``rng``; None: ideal depth) and
    its depth image. The capture is organized, with the intrinsics and the true ``T_world_cam``."""
    T = side_view() if T_world_cam is None else np.asarray(T_world_cam, dtype=np.float64)
    depth = render_depth(world, T, intr)
    if rng is not None:
        depth = dex_noise(depth, rng)
    capture = Capture(points_cam=backproject(depth, intr), intrinsics=intr, T_world_cam=T, source=source)
    return capture, depth
