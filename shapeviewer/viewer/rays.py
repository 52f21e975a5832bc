"""Picking segments with a click ray, and projecting world points to a browser camera's pixels.

viser point clouds are not clickable, so a click on the canvas only gives a ray (world frame,
metres). :func:`first_hit` finds the point set nearest along that ray: the app's segments, and the
grasp controller's hands as points along their stick figures (:func:`sample_segments`).
:func:`project_to_pixels` is the inverse direction (used by the browser test to click a point).

Pure numpy: no viser import, so tests can call it directly.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TypeVar

import numpy as np

# A click ray must pass within ABS_TOLERANCE + REL_TOLERANCE * distance of a segment point. The
# distance term is a cone of about 0.6 degrees, i.e. a few pixels at any zoom; the constant covers
# the gaps between points of a sparse segment (Kinect points are 2-4 mm apart at 1 m).
ABS_TOLERANCE = 0.01  # metres
REL_TOLERANCE = 0.01  # metres per metre along the ray

K = TypeVar("K")


def first_hit(
    origin: np.ndarray,
    direction: np.ndarray,
    point_sets: Mapping[K, np.ndarray],
    abs_tolerance: float = ABS_TOLERANCE,
    rel_tolerance: float = REL_TOLERANCE,
) -> tuple[K | None, float]:
    """``(key, t)`` of the point set the ray hits first, or ``(None, inf)``.

    Args:
        origin: (3,) ray origin, world metres.
        direction: (3,) ray direction, world frame (any length).
        point_sets: key -> (N, 3) finite points, world metres.
        abs_tolerance, rel_tolerance: a point counts as hit when its perpendicular distance to the
            ray is at most ``abs_tolerance + rel_tolerance * t`` (t = its distance along the ray).

    Returns:
        Among the sets with a hit point in front of the origin, the one whose hit point is nearest
        along the ray (what the user sees in front), and that distance ``t`` (metres).
    """
    o = np.asarray(origin, dtype=np.float64).reshape(3)
    d = np.asarray(direction, dtype=np.float64).reshape(3)
    norm = np.linalg.norm(d)
    if not np.isfinite(norm) or norm == 0:
        return None, np.inf
    d = d / norm
    best_key, best_t = None, np.inf
    for key, pts in point_sets.items():
        v = np.asarray(pts, dtype=np.float64).reshape(-1, 3) - o
        t = v @ d
        perp2 = np.einsum("ij,ij->i", v, v) - t * t
        hit = (t > 0) & (perp2 <= (abs_tolerance + rel_tolerance * t) ** 2)
        if hit.any():
            t_hit = float(t[hit].min())
            if t_hit < best_t:
                best_key, best_t = key, t_hit
    return best_key, best_t


def sample_segments(segments: np.ndarray, spacing: float) -> np.ndarray:
    """Points about ``spacing`` apart along line segments ((N, 2, 3), same unit), ends included:
    a stick figure as a point set :func:`first_hit` can pick."""
    segments = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 3)
    out = []
    for a, b in segments:
        n = max(int(np.ceil(np.linalg.norm(b - a) / spacing)), 1)
        out.append(a + np.linspace(0.0, 1.0, n + 1)[:, None] * (b - a))
    return np.vstack(out) if out else np.zeros((0, 3))


def ray_through(origin: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(origin, unit direction)`` of the ray from ``origin`` through ``target`` (world metres)."""
    o = np.asarray(origin, dtype=np.float64)
    d = np.asarray(target, dtype=np.float64) - o
    return o, d / np.linalg.norm(d)


def project_to_pixels(
    points_world: np.ndarray, position: np.ndarray, R_world_camera: np.ndarray, fov: float, width: int, height: int
) -> np.ndarray:
    """Pixel coordinates (N, 2) of world points seen by a viser client camera.

    Args:
        points_world: (N, 3) world metres.
        position: (3,) camera position in the world (viser ``client.camera.position``).
        R_world_camera: 3x3 camera orientation, OpenCV convention (+z looks forward, +y points
            down on screen), as viser's ``client.camera.wxyz``.
        fov: vertical field of view, radians.
        width, height: canvas size in pixels.

    Returns:
        (N, 2) pixel coordinates (u right, v down, origin at the canvas's top-left); NaN for points
        behind the camera.
    """
    p = (np.asarray(points_world, dtype=np.float64).reshape(-1, 3) - np.asarray(position)) @ np.asarray(R_world_camera)
    f = (height / 2.0) / np.tan(fov / 2.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([f * p[:, 0] / p[:, 2] + width / 2.0, f * p[:, 1] / p[:, 2] + height / 2.0], axis=1)
    uv[p[:, 2] <= 0] = np.nan
    return uv
