"""Tabletop views (how a robot sees an object), the RealSense model and the context the CNN reads."""

import numpy as np
import pytest

from shapeviewer.completion.voxel import below_plane, context_grids, partial_to_grid, solid_grid
from shapeviewer.sim.sensor import KinectNoise, RealSenseNoise, noise_model
from shapeviewer.sim.tabletop import render_tabletop_view


@pytest.fixture(scope="module")
def mug_view():
    view = render_tabletop_view("ycb/025_mug", 3, seed=0, sensor="kinect")
    assert view is not None
    return view


def test_a_tabletop_view_is_the_segmented_object_resting_on_the_found_table(mug_view):
    v = mug_view
    truth = v.truth_cam()
    assert v.plane_cam is not None and v.target_share > 0.9
    n, d = v.plane_cam[:3], v.plane_cam[3]
    # The object rests on the table the segmentation found: its lowest point is within 5 mm of it.
    heights = truth.vertices @ n + d
    assert abs(heights.min()) < 0.005 and heights.max() > 0.05
    # Every segment point is on the true surface (sensor noise and a few flying pixels aside).
    from trimesh.proximity import ProximityQuery

    dist = np.abs(ProximityQuery(truth).signed_distance(v.points_cam))
    assert np.median(dist) < 0.003 and np.mean(dist < 0.01) > 0.95
    # The camera looks down at the table from 20-70 degrees and 0.4-1.2 m.
    elevation = np.degrees(np.arcsin(d / np.linalg.norm(truth.centroid)))
    assert 10 < elevation < 80 and 0.3 < np.linalg.norm(truth.centroid) < 1.4


def test_tabletop_views_are_seeded():
    a = render_tabletop_view("random/042", 5, seed=1)
    b = render_tabletop_view("random/042", 5, seed=1)
    c = render_tabletop_view("random/042", 6, seed=1)
    assert np.array_equal(a.points_cam, b.points_cam) and a.neighbours == b.neighbours
    assert not np.array_equal(a.T_cam_obj, c.T_cam_obj)


def test_context_never_marks_the_true_object_empty(mug_view):
    v = mug_view
    x, frame = partial_to_grid(v.points_cam)
    y = solid_grid(v.mesh, frame, v.T_cam_obj)
    ctx = context_grids(v.points_cam, frame, support_plane=v.plane_cam)
    assert ctx[0].sum() > 1000 and ctx[1].sum() > 1000  # the camera saw through a lot, the table hides a lot
    assert (ctx[0] & y).sum() <= 0.01 * y.sum() and (ctx[1] & y).sum() == 0
    assert not (ctx[0] & x).any()


def test_below_plane_is_the_cubes_wholly_under_it():
    plane = np.array([0.0, -1.0, 0.0, 0.1])  # y = 0.1 m, normal towards the camera (-y)
    centres = np.array([[0, 0.2, 1], [0, 0.104, 1], [0, 0.106, 1], [0, 0.0, 1]])
    assert below_plane(centres, plane, half_extent=0.005).tolist() == [True, False, True, False]
    assert below_plane(centres, -plane, half_extent=0.005).tolist() == [True, False, True, False]  # either sign


def test_realsense_noise_grows_with_distance_and_flies_at_edges():
    depth = np.zeros((120, 160), np.float32)
    depth[:, :80], depth[:, 80:] = 0.5, 1.5
    noisy = RealSenseNoise().apply(depth, seed=0)
    near, far = noisy[:, 10:70], noisy[:, 90:150]
    sd = lambda a: float(np.std(a[a > 0]))  # noqa: E731
    assert sd(far) > 3 * sd(near)  # z^2: (1.5 / 0.5)^2 = 9 times the part that grows
    edge = noisy[:, 78:83]
    flying = (edge > 0.55) & (edge < 1.45)
    assert flying.any()  # mixed pixels between the two surfaces
    assert 0.01 < np.mean(noisy == 0) < 0.15  # holes, but most pixels measured
    assert isinstance(noise_model("kinect"), KinectNoise) and noise_model("none") is None
    with pytest.raises(ValueError, match="unknown sensor noise"):
        noise_model("lidar")


@pytest.mark.parametrize("sensor", ["kinect", "realsense"])
def test_a_scaled_sensor_has_that_many_times_the_depth_error(sensor):
    depth = np.full((120, 160), 0.9, np.float32)
    base = noise_model(sensor)
    err = lambda noise: float(np.std((d := noise.apply(depth, seed=3))[d > 0] - 0.9))  # noqa: E731
    assert err(base.scaled(1.0)) == pytest.approx(err(base))
    # Kinect's disparity steps (about 2 mm at 0.9 m) keep its error from scaling exactly.
    assert 2.0 < err(base.scaled(3.0)) / err(base) < 3.5
    assert err(base.scaled(0.5)) < err(base)
