"""Export of pipeline results as bytes (for browser downloads) or files (for the CLI).

Meshes and points are stored in the camera optical frame or the world frame (metres), as the
caller chooses; grids are stored as ``.npz`` with their grid frame so they map back to metres.
"""

from __future__ import annotations

import io
import json
from typing import Any

import numpy as np
import trimesh

from .completion.voxel import GridFrame
from .perception.camera import transform_points

MESH_FORMATS = ("ply", "obj", "stl", "glb")


def to_frame(points_cam: np.ndarray, frame: str, T_world_cam: np.ndarray) -> np.ndarray:
    """Camera-frame points (N, 3) expressed in ``frame`` (``camera`` or ``world``)."""
    if frame == "camera":
        return np.asarray(points_cam, dtype=np.float64)
    if frame == "world":
        return transform_points(T_world_cam, points_cam)
    raise ValueError(f"unknown frame {frame!r} (use 'camera' or 'world')")


def mesh_bytes(
    mesh_cam: trimesh.Trimesh, fmt: str, frame: str = "world", T_world_cam: np.ndarray | None = None
) -> bytes:
    """A camera-frame mesh encoded as PLY, OBJ, STL or GLB in the camera or world frame (metres)."""
    fmt = fmt.lower().lstrip(".")
    if fmt not in MESH_FORMATS:
        raise ValueError(f"unsupported mesh format {fmt!r}; choose one of {MESH_FORMATS}")
    T = np.eye(4) if T_world_cam is None else T_world_cam
    mesh = trimesh.Trimesh(to_frame(mesh_cam.vertices, frame, T), mesh_cam.faces, process=False)
    if fmt == "glb":
        return trimesh.Scene(mesh).export(file_type="glb")
    data = mesh.export(file_type=fmt)
    assert isinstance(data, (str, bytes))  # a dict only for trimesh's "dict" formats
    return data.encode() if isinstance(data, str) else data


def points_ply_bytes(
    points_cam: np.ndarray,
    colors: np.ndarray | None = None,
    frame: str = "world",
    T_world_cam: np.ndarray | None = None,
) -> bytes:
    """Points (and uint8 RGB colours) as a binary PLY in the camera or world frame (metres)."""
    T = np.eye(4) if T_world_cam is None else T_world_cam
    cloud = trimesh.PointCloud(
        to_frame(points_cam, frame, T), colors=None if colors is None else np.asarray(colors, np.uint8)
    )
    return cloud.export(file_type="ply")


def grids_npz_bytes(
    grid_in: np.ndarray,
    probabilities: np.ndarray,
    frame: GridFrame,
    T_world_cam: np.ndarray | None = None,
    *,
    grid_out: np.ndarray | None = None,
    samples: np.ndarray | None = None,
) -> bytes:
    """CNN input and output grids with their frame: ``grid_in`` (bool), ``probabilities`` (float32),
    ``grid_out`` (bool, the output grid when given: :attr:`~shapeviewer.completion.pipeline.Completion.grid_out`),
    ``grid_to_camera`` (4x4, grid coordinates -> camera metres; voxel (i,j,k) centre at (i,j,k)+0.5),
    ``T_world_cam`` (4x4) and ``frame_json``; with ``samples`` ((n, 40, 40, 40) sample completions,
    :meth:`~shapeviewer.completion.model.Completer.predict_samples`) also ``samples`` (float16) and ``spread``
    (float32, their per-voxel disagreement, :func:`~shapeviewer.completion.model.sample_spread`: the
    completion's uncertainty)."""
    arrays: dict[str, Any] = {} if grid_out is None else {"grid_out": np.asarray(grid_out, bool)}
    if samples is not None:
        from .completion.model import sample_spread  # torch is loaded only by callers that have samples

        samples = np.asarray(samples, np.float32)
        arrays |= {"samples": samples.astype(np.float16), "spread": sample_spread(samples)}
    buf = io.BytesIO()
    np.savez_compressed(
        buf,
        grid_in=np.asarray(grid_in, bool),
        probabilities=np.asarray(probabilities, np.float32),
        grid_to_camera=frame.grid_to_camera(),
        T_world_cam=np.eye(4) if T_world_cam is None else np.asarray(T_world_cam),
        frame_json=np.array(json.dumps(frame.to_dict())),
        **arrays,
    )
    return buf.getvalue()
