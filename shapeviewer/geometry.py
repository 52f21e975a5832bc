"""Geometry shared by the camera, the metrics, the voxel grids, the simulator and the grasp planner.

- :func:`raycasting_scene`: trimesh meshes in an Open3D ray-casting scene (rays, distances, inside tests).
- :func:`o3d_tensor`: a numpy array as an Open3D tensor (rays and query points for that scene).
- :func:`concatenate_meshes`: triangle meshes as one.
- :func:`pose_to_pq` / :func:`pq_to_pose`: a 4x4 pose and its position + pybullet quaternion.
- :func:`centre_of_mass`: where a mesh's mass sits (grasp torques, dynamic bodies).

Poses are 4x4 homogeneous matrices; ``T_a_b`` maps coordinates in frame b to frame a. Quaternions
are in pybullet's (x, y, z, w) order. Units: metres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import open3d as o3d
    import trimesh


def raycasting_scene(*meshes: trimesh.Trimesh, origin: np.ndarray | None = None) -> o3d.t.geometry.RaycastingScene:
    """An Open3D ray-casting scene holding ``meshes`` (one frame, metres); a hit's geometry id ``i``
    is ``meshes[i]``.

    Open3D stores and casts in float32, whose resolution shrinks with the distance from the origin
    (about 0.06 micrometre at 1 m). With ``origin`` (3, metres, the meshes' frame), the scene holds
    the vertices minus ``origin``: pick one near the meshes to keep their detail, and shift rays
    and query points by ``-origin`` too.
    """
    import open3d as o3d  # heavy: loaded only where rays are cast

    scene = o3d.t.geometry.RaycastingScene()
    for mesh in meshes:
        vertices = np.asarray(mesh.vertices) if origin is None else np.asarray(mesh.vertices) - origin
        scene.add_triangles(o3d_tensor(vertices.astype(np.float32)), o3d_tensor(np.asarray(mesh.faces, np.uint32)))
    return scene


def o3d_tensor(array: np.ndarray) -> o3d.core.Tensor:
    """A copy of ``array`` as an Open3D CPU tensor of the same dtype."""
    import open3d as o3d

    # Open3D's stub omits the defaults (None: the array's dtype, the CPU) of dtype and device.
    return o3d.core.Tensor(array)  # type: ignore[call-overload]


def concatenate_meshes(meshes: Sequence[trimesh.Trimesh]) -> trimesh.Trimesh:
    """``meshes`` as one mesh (``trimesh.util.concatenate``, which returns a Trimesh for Trimesh parts)."""
    import trimesh

    mesh = trimesh.util.concatenate(meshes)
    assert isinstance(mesh, trimesh.Trimesh)
    return mesh


def pose_to_pq(T: np.ndarray) -> tuple[list[float], list[float]]:
    """Position (m) and pybullet quaternion (x, y, z, w, with w >= 0) of a 4x4 pose.

    Shepperd's method in plain Python: these conversions run on every pose set or read in the
    grasp world, where scipy's Rotation would cost about a millisecond each.
    """
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = np.asarray(T, float)[:3, :3].tolist()
    trace = m00 + m11 + m22
    if trace > max(m00, m11, m22):
        s = 2.0 * math.sqrt(1.0 + trace)
        q = [(m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s, s / 4]
    elif m00 >= m11 and m00 >= m22:
        s = 2.0 * math.sqrt(max(1.0 + m00 - m11 - m22, 1e-300))
        q = [s / 4, (m01 + m10) / s, (m02 + m20) / s, (m21 - m12) / s]
    elif m11 >= m22:
        s = 2.0 * math.sqrt(max(1.0 + m11 - m00 - m22, 1e-300))
        q = [(m01 + m10) / s, s / 4, (m12 + m21) / s, (m02 - m20) / s]
    else:
        s = 2.0 * math.sqrt(max(1.0 + m22 - m00 - m11, 1e-300))
        q = [(m02 + m20) / s, (m12 + m21) / s, s / 4, (m10 - m01) / s]
    norm = math.copysign(math.sqrt(sum(c * c for c in q)), q[3] if q[3] != 0.0 else 1.0)
    return [float(v) for v in np.asarray(T, float)[:3, 3]], [c / norm for c in q]


def pq_to_pose(pos: Sequence[float], quat: Sequence[float]) -> np.ndarray:
    """4x4 pose from a position (m) and pybullet quaternion (x, y, z, w)."""
    x, y, z, w = quat
    n = x * x + y * y + z * z + w * w
    s = 2.0 / n if n > 0 else 0.0
    return np.array(
        [
            [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w), pos[0]],
            [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w), pos[1]],
            [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y), pos[2]],
            [0.0, 0.0, 0.0, 1.0],
        ],
        dtype=float,
    )


def centre_of_mass(mesh: trimesh.Trimesh) -> np.ndarray:
    """The centre of mass (3,) of a uniform solid ``mesh``, in the mesh's frame (m); for an open
    mesh, which bounds no solid, the area-weighted centroid of its surface."""
    return np.asarray(mesh.center_mass if mesh.is_watertight else mesh.centroid, float)
