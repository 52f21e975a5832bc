"""Capture (paper Fig. 5, step 1): a depth camera's view of a tabletop as a camera-frame point cloud.

A :class:`Capture` is what every later stage starts from, whether it came from the simulated
Kinect of a generated scene (:mod:`shapeviewer.scene`) or from a real sensor file.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from .camera import Intrinsics


@dataclass
class SceneObject:
    """A ground-truth object of a synthetic scene.

    Attributes:
        name: catalogue name (see :mod:`shapeviewer.dataset`).
        mesh: watertight mesh in the object frame, metres.
        T_world_obj: 4x4 pose of the object in the world frame.
    """

    name: str
    mesh: trimesh.Trimesh
    T_world_obj: np.ndarray


@dataclass
class Capture:
    """One depth capture.

    Attributes:
        points_cam: camera optical frame metres (x right, y down, z forward); (H, W, 3) when the
            cloud is organized, else (N, 3). NaN rows mark invalid pixels.
        colors: uint8 RGB with the same leading shape as ``points_cam``, or None.
        intrinsics: the camera's intrinsics when known (organized clouds, depth images).
        T_world_cam: 4x4 pose of the camera in the world frame. Synthetic scenes know it; for real
            captures it is identity until segmentation estimates a table-aligned world frame.
        source: where the capture came from (a path, or ``default(seed=N)``).
        objects: ground truth of synthetic scenes (empty for real captures).
        labels: per-pixel ground-truth object index (same leading shape, -1 = none) for synthetic scenes.
    """

    points_cam: np.ndarray
    colors: np.ndarray | None = None
    intrinsics: Intrinsics | None = None
    T_world_cam: np.ndarray = field(default_factory=lambda: np.eye(4))
    source: str = ""
    objects: list[SceneObject] = field(default_factory=list)
    labels: np.ndarray | None = None

    @property
    def organized(self) -> bool:
        return self.points_cam.ndim == 3

    def flat_points(self) -> np.ndarray:
        """(N, 3) camera-frame metres, NaN rows kept (index i matches ``flat_colors()[i]``)."""
        return self.points_cam.reshape(-1, 3)

    def flat_colors(self) -> np.ndarray | None:
        return None if self.colors is None else self.colors.reshape(-1, 3)

    def valid_mask(self) -> np.ndarray:
        """(N,) bool: rows of ``flat_points()`` that are finite."""
        return np.isfinite(self.flat_points()).all(axis=1)
