"""The default scene: objects settled on a table (pybullet) and captured by the simulated Kinect."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest
import trimesh

from shapeviewer.geometry import raycasting_scene
from shapeviewer.perception.camera import Intrinsics, transform_points
from shapeviewer.perception.capture import Capture, SceneObject
from shapeviewer.sim.demo_scene import build_tabletop, capture_scene, default_scene


def world_mesh(obj: SceneObject) -> trimesh.Trimesh:
    return trimesh.Trimesh(transform_points(obj.T_world_obj, obj.mesh.vertices), obj.mesh.faces, process=False)


def distance_to_surface(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Unsigned distance (m) of each point to the mesh surface."""
    return raycasting_scene(mesh).compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


def object_points_world(cap: Capture, i: int) -> np.ndarray:
    """World-frame points (N, 3) of the pixels labelled as object ``i``."""
    return transform_points(cap.T_world_cam, cap.points_cam[cap.labels == i])


@pytest.fixture(scope="module")
def scene0() -> Capture:
    return default_scene(0)


def test_seed0_has_a_mix_of_visible_objects(scene0):
    names = [o.name for o in scene0.objects]
    assert 4 <= len(names) <= 6 and len(set(names)) == len(names)
    assert any(n.startswith("ycb/") for n in names)
    assert any(n.startswith(("random/", "pybullet/")) for n in names)
    valid = np.isfinite(scene0.points_cam).all(axis=-1)
    for i in range(len(names)):
        assert np.sum((scene0.labels == i) & valid) >= 500, names[i]


def test_organized_cloud_layout(scene0):
    h, w = 480, 640
    assert scene0.organized and scene0.points_cam.shape == (h, w, 3)
    assert scene0.colors.shape == (h, w, 3) and scene0.colors.dtype == np.uint8
    assert scene0.labels.shape == (h, w) and scene0.intrinsics == Intrinsics.kinect()
    assert scene0.source == "default(seed=0)"
    missing = ~np.isfinite(scene0.points_cam).all(axis=-1)
    assert 0.005 < missing.mean() < 0.5  # the sensor model drops pixels, the table fills most of the view
    assert np.isnan(scene0.points_cam[missing]).all()
    assert (scene0.labels[missing] == -1).all() and (scene0.colors[missing] == 0).all()
    R = scene0.T_world_cam[:3, :3]
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(R), 1.0)
    assert scene0.T_world_cam[2, 3] > 0.3  # above the table, looking down at it


def test_objects_rest_on_the_table_apart(scene0):
    meshes = [world_mesh(o) for o in scene0.objects]
    for o, m in zip(scene0.objects, meshes):
        assert -0.002 < m.vertices[:, 2].min() < 0.01, o.name
    # Neither touching nor interpenetrating: every vertex of one object is well clear of the others.
    for b, mesh in enumerate(meshes):
        others = np.concatenate([m.vertices for a, m in enumerate(meshes) if a != b])
        assert distance_to_surface(mesh, others).min() > 0.02, scene0.objects[b].name


def test_objects_fully_in_the_image(scene0):
    intr = scene0.intrinsics
    for o in scene0.objects:
        p = transform_points(np.linalg.inv(scene0.T_world_cam), world_mesh(o).vertices)
        u = p[:, 0] / p[:, 2] * intr.fx + intr.cx
        v = p[:, 1] / p[:, 2] * intr.fy + intr.cy
        assert (p[:, 2] > 0).all() and u.min() > 0 and v.min() > 0, o.name
        assert u.max() < intr.width - 1 and v.max() < intr.height - 1, o.name


def test_points_lie_on_the_true_surfaces(scene0):
    for i, o in enumerate(scene0.objects):
        assert np.median(distance_to_surface(world_mesh(o), object_points_world(scene0, i))) < 0.005, o.name
    table = transform_points(scene0.T_world_cam, scene0.points_cam[(scene0.labels == -1)])
    table = table[np.isfinite(table).all(axis=1)]
    assert abs(np.median(table[:, 2])) < 0.005
    # Without sensor noise the frames must agree to well under a millimetre.
    ideal = capture_scene(scene0.objects, seed=0, noise=None)
    for i, o in enumerate(ideal.objects):
        assert np.median(distance_to_surface(world_mesh(o), object_points_world(ideal, i))) < 2e-4, o.name


def test_same_seed_same_capture(scene0):
    again = default_scene(0)
    assert [o.name for o in again.objects] == [o.name for o in scene0.objects]
    assert all(np.array_equal(a.T_world_obj, b.T_world_obj) for a, b in zip(again.objects, scene0.objects))
    assert np.array_equal(again.points_cam, scene0.points_cam, equal_nan=True)
    assert np.array_equal(again.colors, scene0.colors) and np.array_equal(again.labels, scene0.labels)
    assert np.array_equal(again.T_world_cam, scene0.T_world_cam)


def test_other_seed_other_scene(scene0):
    # Seed 12's objects are cheap to set up: only one needs a (cached) convex decomposition.
    other = build_tabletop(12)
    assert [o.name for o in other] != [o.name for o in scene0.objects]
    cap = capture_scene(other, seed=12)
    assert cap.source == "default(seed=12)"
    assert not np.array_equal(cap.points_cam, scene0.points_cam, equal_nan=True)


def test_requested_object_count():
    assert len(build_tabletop(3, n_objects=4)) == 4
