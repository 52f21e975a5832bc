"""What the viewer draws, as plain arrays: colours, voxel cubes, and the default view.

Everything here is numpy (no viser), so it can be tested without a server. Positions are world
metres (z up) unless a name says otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from ..completion.voxel import GridFrame
from ..perception.camera import transform_points


def depth_colors(depth: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """uint8 RGB (N, 3) of a turbo colormap over depth (metres); near is blue, far is red."""
    from matplotlib import colormaps

    depth = np.asarray(depth, dtype=np.float64)
    lo = float(np.percentile(depth, 2)) if lo is None else lo
    hi = float(np.percentile(depth, 98)) if hi is None else hi
    x = np.clip((depth - lo) / max(hi - lo, 1e-6), 0.0, 1.0)
    return (colormaps["turbo"](x)[:, :3] * 255).astype(np.uint8)


def probability_colors(p: np.ndarray, lo: float = 0.5) -> np.ndarray:
    """uint8 RGB (N, 3) for occupancy probabilities in [lo, 1]: pale yellow (unsure) to dark red (sure)."""
    from matplotlib import colormaps

    x = np.clip((np.asarray(p, dtype=np.float64) - lo) / max(1.0 - lo, 1e-6), 0.0, 1.0)
    return (colormaps["YlOrRd"](0.25 + 0.75 * x)[:, :3] * 255).astype(np.uint8)


SPREAD_FULL_SCALE = 0.4  # sample spread (model.sample_spread, 0 to 0.5) drawn at full colour


def spread_colors(spread: np.ndarray) -> np.ndarray:
    """uint8 RGB (N, 3) for the samples' per-voxel spread: pale yellow where they agree (the
    observation pins the shape down), through orange to dark purple where they disagree (a guess)."""
    from matplotlib import colormaps

    x = np.clip(np.asarray(spread, dtype=np.float64) / SPREAD_FULL_SCALE, 0.0, 1.0)
    return (colormaps["magma_r"](0.02 + 0.9 * x)[:, :3] * 255).astype(np.uint8)


def shade(color: np.ndarray, factor: float) -> tuple[int, int, int]:
    """An RGB colour darkened (factor < 1) or lightened towards white (factor > 1)."""
    c = np.asarray(color, dtype=np.float64)
    c = c * factor if factor <= 1 else c + (255 - c) * (factor - 1)
    r, g, b = (int(v) for v in np.clip(c, 0, 255))
    return r, g, b


def surface_voxels(grid: np.ndarray) -> np.ndarray:
    """Indices (N, 3) of occupied voxels with at least one empty 6-neighbour.

    Interior voxels can never be seen, so the viewer does not send them (a solid 40^3 output has
    tens of thousands of voxels, its shell a few thousand).
    """
    g = np.pad(np.asarray(grid, dtype=bool), 1)
    core = g[1:-1, 1:-1, 1:-1]
    interior = core.copy()
    for axis in range(3):
        for shift in (-1, 1):
            interior &= np.roll(g, shift, axis=axis)[1:-1, 1:-1, 1:-1]
    return np.argwhere(core & ~interior)


@dataclass
class VoxelCubes:
    """Instanced cubes of a voxel grid in the world: one cube mesh and a position per voxel.

    Attributes:
        vertices: (8, 3) cube vertices, already rotated into the world orientation of the grid and
            scaled to ``fill`` of a voxel, centred on the origin (so instances need no rotation).
        faces: (12, 3) triangles.
        positions: (N, 3) world metres of the voxel centres.
        indices: (N, 3) the voxels' grid indices (to look up per-voxel values such as probabilities).
    """

    vertices: np.ndarray
    faces: np.ndarray
    positions: np.ndarray
    indices: np.ndarray


def voxel_cubes(indices: np.ndarray, frame: GridFrame, T_world_cam: np.ndarray, fill: float = 0.9) -> VoxelCubes:
    """Cubes for voxel ``indices`` of a grid with ``frame`` (camera frame), placed in the world."""
    box = trimesh.creation.box(extents=(fill * frame.voxel_size,) * 3)
    # The grid is axis-aligned in the camera frame, so every cube shares the camera's orientation.
    vertices = np.asarray(box.vertices) @ np.asarray(T_world_cam)[:3, :3].T
    indices = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
    positions = transform_points(T_world_cam, frame.voxel_centers(indices))
    return VoxelCubes(vertices, np.asarray(box.faces), positions, indices)


def default_view(T_world_cam: np.ndarray, focus_world: np.ndarray, extent: float) -> tuple[np.ndarray, np.ndarray]:
    """A browser camera ``(position, look_at)`` (world metres) looking at ``focus_world`` from the sensor's side.

    The view direction is the sensor's, raised a little, and the distance is chosen so that a
    region ``extent`` metres wide fills about two thirds of the height of a 75 degree view
    (viser's default fov).
    """
    sensor = np.asarray(T_world_cam)[:3, 3]
    back = sensor - focus_world
    back[2] = max(back[2], 0.6 * np.linalg.norm(back[:2]))  # at least ~30 degrees from above
    back /= np.linalg.norm(back)
    distance = max(0.5, 0.75 * extent / np.tan(np.radians(75) / 2))
    return focus_world + distance * back, np.asarray(focus_world, dtype=np.float64)
