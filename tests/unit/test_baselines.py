"""The Partial and Mirror baselines on rendered views of YCB objects standing on a table."""

from functools import cache

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from shapeviewer.completion.baselines import PARTIAL_LEAF_FACTOR, find_mirror_plane, mirror_mesh, partial_mesh
from shapeviewer.completion.reconstruct import mean_nn_distance
from shapeviewer.evaluation.metrics import hausdorff, jaccard
from shapeviewer.perception.camera import Intrinsics, backproject_valid, look_at
from shapeviewer.sim.catalogue import load_mesh
from shapeviewer.sim.sensor import KinectNoise, RaycastRenderer

BOX, BOTTLE, MUG = "ycb/004_sugar_box", "ycb/006_mustard_bottle", "ycb/025_mug"


@cache
def tabletop_view(name: str, yaw_deg: float = 30.0):
    """A noisy Kinect view of ``name`` standing on the table z = 0, yawed by ``yaw_deg`` about z,
    seen from 0.8 m at 45 degrees down.

    Returns ``(points_cam, support_plane_cam, truth_cam, T_cam_obj)``: the observed points, the
    table (a, b, c, d) with its normal towards the camera, and the true mesh, all in the camera
    frame, plus the object's pose there.
    """
    mesh = load_mesh(name)
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    T_world_obj = np.eye(4)
    T_world_obj[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T_world_obj[2, 3] = -mesh.bounds[0, 2]
    world = mesh.copy().apply_transform(T_world_obj)
    target = world.bounds.mean(axis=0)
    T_world_cam = look_at(target + 0.8 * np.array([np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4)]), target)
    intr = Intrinsics.kinect()
    depth, _ = RaycastRenderer([world]).render(intr, T_world_cam)
    points = backproject_valid(KinectNoise().apply(depth, seed=0), intr)
    T_cam_world = np.linalg.inv(T_world_cam)
    # The table z = 0 in the camera frame: normal R^T e_z; the camera's height above it is d.
    plane = np.array([*T_cam_world[:3, :3] @ [0.0, 0.0, 1.0], T_world_cam[2, 3]])
    return points, plane, world.copy().apply_transform(T_cam_world), T_cam_world @ T_world_obj


@cache
def completions(name: str):
    points, plane, _, _ = tabletop_view(name)
    return partial_mesh(points), mirror_mesh(points, plane)


@pytest.mark.parametrize("name", [BOX, BOTTLE])
def test_partial_mesh_is_a_closed_thin_shell_around_the_observed_points(name):
    points, _, truth, _ = tabletop_view(name)
    partial, _ = completions(name)
    assert partial.is_watertight and partial.volume > 0
    assert partial.volume < 0.5 * truth.volume
    leaf = PARTIAL_LEAF_FACTOR * mean_nn_distance(points)
    # Observed points lie inside the shell, within a leaf of its surface ...
    d = np.abs(trimesh.proximity.signed_distance(partial, points[::7]))
    assert d.mean() < 0.75 * leaf and d.max() < 1.5 * leaf
    # ... and the shell invents nothing away from them (no unseen side).
    gap, _ = cKDTree(points).query(partial.vertices)
    assert gap.max() < 1.5 * leaf


def test_smoothing_takes_the_voxel_steps_off_the_surface():
    rng = np.random.default_rng(0)
    v = rng.uniform(-1.0, 1.0, size=(40000, 3))
    ball = 0.9 + 0.05 * v[np.linalg.norm(v, axis=1) < 1.0][:20000]  # a solid ball of points
    rough, smooth = partial_mesh(ball, smoothing_iterations=0), partial_mesh(ball)
    assert smooth.is_watertight
    radius = [np.linalg.norm(m.vertices - 0.9, axis=1) for m in (rough, smooth)]
    assert radius[1].std() < 0.6 * radius[0].std()
    assert radius[1].mean() == pytest.approx(0.05, rel=0.1)  # six steps barely shrink it


@pytest.mark.parametrize("name", [BOX, BOTTLE, MUG])
def test_mirror_mesh_is_closed_and_extends_behind_the_visible_surface(name):
    points, plane, _, _ = tabletop_view(name)
    _, mirror = completions(name)
    assert mirror.is_watertight and mirror.volume > 0
    assert mirror.metadata["reconstruction"] in ("poisson", "voxels")
    assert mirror.centroid[2] > points[:, 2].mean()
    # Nothing below the table.
    assert (mirror.vertices @ plane[:3] + plane[3]).min() > -1e-4


@pytest.mark.parametrize("name", [BOX, BOTTLE])
def test_mirror_beats_partial_on_symmetric_objects(name):
    points, _, truth, _ = tabletop_view(name)
    partial, mirror = completions(name)
    assert mirror.metadata["reconstruction"] == "poisson"
    assert mirror.centroid[2] > points[:, 2].mean() + 0.01
    j_partial, j_mirror = jaccard(partial, truth), jaccard(mirror, truth)
    h_partial, h_mirror = hausdorff(partial, truth)["mean_mm"], hausdorff(mirror, truth)["mean_mm"]
    assert j_mirror > j_partial + 0.3
    assert h_mirror < 0.5 * h_partial


@pytest.mark.parametrize("yaw", [30.0, 65.0])
def test_mirror_plane_of_a_box_seen_at_an_angle_is_a_symmetry_plane(yaw):
    points, plane, _, T_cam_obj = tabletop_view(BOX, yaw)
    found = find_mirror_plane(points, plane)
    assert abs(found.normal @ plane[:3]) < 1e-9  # perpendicular to the table
    # The box's symmetry planes: normals along its x and y axes through its centre.
    box = load_mesh(BOX)
    R = T_cam_obj[:3, :3]
    cosines = np.abs(R[:, :2].T @ found.normal)
    assert np.degrees(np.arccos(cosines.max())) < 15.0
    centre_cam = R @ box.bounds.mean(axis=0) + T_cam_obj[:3, 3]
    assert abs(centre_cam @ found.normal + found.offset) < 0.01


def test_the_support_plane_may_come_unnormalised_and_facing_away():
    points, plane, _, _ = tabletop_view(BOX)
    a, b = find_mirror_plane(points, plane), find_mirror_plane(points, -3.0 * plane)
    np.testing.assert_allclose(a.normal, b.normal)
    assert a.offset == pytest.approx(b.offset)


def test_mirror_mesh_repeats():
    points, plane, _, _ = tabletop_view(BOTTLE)
    again = mirror_mesh(points[::-1], plane)
    _, first = completions(BOTTLE)
    np.testing.assert_array_equal(first.vertices, again.vertices)
    np.testing.assert_array_equal(first.faces, again.faces)


def test_without_a_support_plane_the_mirror_faces_the_camera_and_the_mesh_is_closed():
    points, _, _, _ = tabletop_view(BOTTLE)
    found = find_mirror_plane(points, None)
    assert found.normal[1] == 0.0  # perpendicular to the camera's y axis
    horizontal_view = points.mean(axis=0) * [1.0, 0.0, 1.0]
    np.testing.assert_allclose(abs(found.normal @ horizontal_view) / np.linalg.norm(horizontal_view), 1.0)
    mesh = mirror_mesh(points, None)
    assert mesh.is_watertight and mesh.centroid[2] > points[:, 2].mean()


@pytest.mark.parametrize(
    "points, message",
    [
        (np.zeros((5, 3)) + np.arange(5)[:, None] * 0.01, "at least 20 distinct"),
        (np.full((100, 3), 0.5), "at least 20 distinct"),
        (np.full((100, 3), np.nan), "at least 20 distinct"),
        (np.zeros((100, 2)), r"\(N, 3\)"),
    ],
)
def test_too_little_input_is_a_clear_error(points, message):
    with pytest.raises(ValueError, match=message):
        partial_mesh(points)
    with pytest.raises(ValueError, match=message):
        mirror_mesh(points, np.array([0.0, -1.0, 0.0, 0.5]))


def test_bad_planes_and_points_behind_the_camera_are_clear_errors():
    points, plane, _, _ = tabletop_view(BOX)
    with pytest.raises(ValueError, match="normal"):
        mirror_mesh(points, np.array([0.0, 0.0, 0.0, 1.0]))
    with pytest.raises(ValueError, match="4 finite numbers"):
        mirror_mesh(points, np.array([0.0, 1.0, 0.0]))
    with pytest.raises(ValueError, match="in front of the camera"):
        mirror_mesh(points * [1.0, 1.0, -1.0], plane)
