"""Where the Dataset tab puts a view's items and its browser camera: plain numpy, no viser.

The display frame: the object's own frame (catalogue axes, z up, metres), turned about z so that
the side the sensor did not see faces the browser camera (which looks along +y), with the ground
truth standing on z = 0; each item is then shifted along +x into its column.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...perception.camera import transform_points

# Column spacing / largest object footprint: room for the labels between the items.
SPACING_FACTOR = 1.3
# Column spacing / the widest reach of two neighbouring columns along the row (items and the hands
# drawn with them): a gap between whatever stands in one column and in the next.
REACH_FACTOR = 1.15
# The browser camera: a narrow field of view from farther away keeps the perspective nearly the
# same for every column, so the items can be compared side by side.
DATASET_FOV = math.radians(30.0)
DEFAULT_ASPECT = 1.3  # browser canvas width / height until a client reports its own
# Viewing direction: turned this far (azimuth) from straight opposite the sensor, so that both the
# occluded back and some of the seen side are visible; elevation clamped to this band.
OBLIQUE_AZIMUTH = math.radians(35.0)
ELEVATION_RANGE = (math.radians(15.0), math.radians(45.0))


def _rot_z(angle: float) -> np.ndarray:
    """3x3 rotation by ``angle`` radians about z."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class ViewLayout:
    """Where a view's items go (display frame, metres, z up; the browser camera looks along +y).

    Attributes:
        T_display_cam: kind -> 4x4 map from the view's camera frame to that item's column.
        columns: kind -> (3,) base centre of the column (x of the column, y 0, z 0).
        top: height (m) of the tallest item above z = 0 (labels go above it).
        spacing: distance between columns (m).
        camera_position, look_at: the browser camera for the whole row.
        sensor_position: (3,) where the sensor was, relative to the points column, scaled in to
            the row (display frame); sensor_rotation the 3x3 orientation of its optical axes there.
    """

    T_display_cam: dict[str, np.ndarray]
    columns: dict[str, np.ndarray]
    top: float
    spacing: float
    camera_position: np.ndarray
    look_at: np.ndarray
    sensor_position: np.ndarray
    sensor_rotation: np.ndarray


def layout_view(
    T_cam_obj: np.ndarray,
    truth_cam: np.ndarray,
    extents_cam: dict[str, np.ndarray],
    kinds: tuple[str, ...],
    aspect: float = DEFAULT_ASPECT,
    fov: float = DATASET_FOV,
    *,
    extras_cam: dict[str, np.ndarray] | None = None,
) -> ViewLayout:
    """Lay out a view's items in one row, the unseen side towards the camera.

    Args:
        T_cam_obj: 4x4 object pose in the view's camera frame.
        truth_cam: (N, 3) ground-truth vertices, camera frame (metres).
        extents_cam: kind -> (M, 3) vertices (camera frame) of each item, for the column width.
        kinds: the items left to right.
        aspect, fov: the browser camera's aspect ratio and vertical field of view (radians).
        extras_cam: kind -> (K, 3) vertices (camera frame) of what is drawn with that item in its
            column (the hands of its best grasp): the columns are spaced so that none of it reaches
            into the next column, and the labels go above it.
    """
    T_obj_cam = np.linalg.inv(np.asarray(T_cam_obj, dtype=np.float64))
    sensor_obj = T_obj_cam[:3, 3]
    away = -sensor_obj / max(float(np.linalg.norm(sensor_obj)), 1e-9)  # from the object towards its unseen side
    horizontal = float(np.hypot(away[0], away[1]))
    azimuth = math.atan2(away[1], away[0]) + OBLIQUE_AZIMUTH if horizontal > 1e-6 else -math.pi / 2
    elevation = float(np.clip(math.atan2(away[2], horizontal), *ELEVATION_RANGE))
    # Turn about z so that the viewing azimuth points to -y (where the browser camera stands).
    R = np.eye(4)
    R[:3, :3] = _rot_z(-math.pi / 2 - azimuth)
    T_common = R @ T_obj_cam
    truth = transform_points(T_common, truth_cam)
    lo, hi = truth.min(axis=0), truth.max(axis=0)
    T_common[:3, 3] -= [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]]
    truth_width = float(np.linalg.norm(hi[:2] - lo[:2]))
    widths = []
    for pts in extents_cam.values():
        if len(pts):
            p = transform_points(T_common, pts)
            # A failed completion can be huge; it may overlap its neighbours rather than shrink the row.
            widths.append(min(float(np.linalg.norm(p[:, :2].max(0) - p[:, :2].min(0))), 1.6 * truth_width))
    spacing = SPACING_FACTOR * max([truth_width, *widths, 0.05])
    if extras_cam:
        # How far each column's contents reach left and right of its centre line (x, display frame).
        # An item reaches at most as far as the width cap above lets it; hands as far as they do.
        reach: dict[str, tuple[float, float]] = {}
        for kind in kinds:
            left = right = 0.0
            parts = ((extents_cam.get(kind), 0.8 * truth_width), (extras_cam.get(kind), math.inf))
            for part, cap in parts:
                if part is not None and len(part):
                    x = transform_points(T_common, part)[:, 0]
                    left, right = max(left, min(-float(x.min()), cap)), max(right, min(float(x.max()), cap))
            reach[kind] = (left, right)
        pairs = [reach[a][1] + reach[b][0] for a, b in zip(kinds, kinds[1:])]
        spacing = max([spacing, *(REACH_FACTOR * p for p in pairs)])
    n = len(kinds)
    T_display_cam, columns = {}, {}
    for i, kind in enumerate(kinds):
        T = T_common.copy()
        T[0, 3] += (i - (n - 1) / 2) * spacing
        T_display_cam[kind] = T
        columns[kind] = np.array([(i - (n - 1) / 2) * spacing, 0.0, 0.0])
    tops = [float(transform_points(T_common, p)[:, 2].max()) for p in extents_cam.values() if len(p)]
    top = max([float(hi[2] - lo[2]), *[min(t, 2.0 * (hi[2] - lo[2])) for t in tops]])
    for p in (extras_cam or {}).values():
        if len(p):
            top = max(top, float(transform_points(T_common, p)[:, 2].max()))
    # Fit the row (and the labels above it) in view: half-width over tan(horizontal half-fov).
    half_w = 0.5 * n * spacing * 1.04
    half_h = 0.5 * (top + 0.9 * spacing) * 1.1
    distance = max(half_w / (math.tan(fov / 2) * aspect), half_h / math.tan(fov / 2))
    look_at = np.array([0.0, 0.0, 0.5 * top + 0.12 * spacing])
    direction = np.array([0.0, -math.cos(elevation), math.sin(elevation)])
    # The sensor, pulled in to 1.3 object widths from the points column's object centre.
    sensor_common = transform_points(T_common, T_obj_cam[:3, 3][None])[0]
    centre = np.array([0.0, 0.0, (hi[2] - lo[2]) / 2])
    ray = sensor_common - centre
    sensor_pos = columns.get("points", np.zeros(3)) + centre + ray / np.linalg.norm(ray) * 0.55 * spacing
    return ViewLayout(
        T_display_cam,
        columns,
        top,
        spacing,
        look_at + distance * direction,
        look_at,
        sensor_pos,
        T_common[:3, :3].copy(),
    )
