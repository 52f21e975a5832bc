"""A box resting on a table, fitted to the points a camera sees of it, and completed as that box."""

from __future__ import annotations

import numpy as np
import pytest

from shapeviewer.completion.cuboid import SILHOUETTE_MARGIN, fit_cuboid, occupancy
from shapeviewer.completion.voxel import GridFrame

from helpers import seen_by, table_camera

YAW = np.deg2rad(25.0)  # of the box on the table, from the world's x axis
SIZE = np.array([0.12, 0.07, 0.09])  # metres: length, width, height
CENTRE = np.array([0.02, -0.01])  # its footprint's centre on the table (world x, y)


def _box(n=3000):
    """Points and outward normals of the box's top and four sides (world frame)."""
    rng = np.random.default_rng(0)
    pts, normals = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            if axis == 2 and sign < 0:
                continue  # it stands on the table
            local = rng.uniform(-0.5, 0.5, (n, 3)) * SIZE
            local[:, axis] = sign * SIZE[axis] / 2
            pts.append(local)
            normals.append(np.tile(np.eye(3)[axis] * sign, (n, 1)))
    c, s = np.cos(YAW), np.sin(YAW)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    lift = np.r_[CENTRE, SIZE[2] / 2]
    return np.vstack(pts) @ rot.T + lift, np.vstack(normals) @ rot.T


def _cylinder(radius, length, lying, n=6000):
    """Points and outward normals of a can standing on the table, or lying on it along world x."""
    rng = np.random.default_rng(0)
    a, h = rng.uniform(0, 2 * np.pi, n), rng.uniform(0, length, n)
    ring = np.c_[np.cos(a), np.sin(a)]
    if lying:  # its axis along x, resting on its side
        return np.c_[h - length / 2, radius * ring[:, 0], radius + radius * ring[:, 1]], np.c_[np.zeros(n), ring]
    side = np.c_[radius * ring, h]
    r = radius * np.sqrt(rng.uniform(0, 1, n))
    top = np.c_[r * np.cos(a), r * np.sin(a), np.full(n, length)]
    return np.vstack([side, top]), np.vstack([np.c_[ring, np.zeros(n)], np.tile([0.0, 0.0, 1.0], (n, 1))])


def test_a_box_is_fitted_to_the_faces_the_camera_sees():
    R, t, plane = table_camera()
    box = fit_cuboid(seen_by(*_box(), R, t, noise=0.0005), plane)
    assert box.accepted and box.fill > 0.95 and box.aligned > 0.85 and box.residual < 0.002
    # Its edges are the box's: the longer one first or second, either way round.
    sizes = np.sort(box.extents[:2] - 2 * SILHOUETTE_MARGIN)
    assert np.allclose(sizes, np.sort(SIZE[:2]), atol=0.002) and abs(box.extents[2] - SIZE[2]) < 0.002
    assert min(abs((box.yaw - YAW + np.pi / 4) % (np.pi / 2) - np.pi / 4), 1.0) < np.deg2rad(1.0)
    # The box's own corner, back in the camera frame, is on the fitted box's surface.
    corner_world = np.r_[CENTRE, 0.0] + np.array([[np.cos(YAW), -np.sin(YAW)], [np.sin(YAW), np.cos(YAW)]]) @ (
        SIZE[:2] / 2
    ) @ np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    corner_cam = R @ (corner_world + [0.0, 0.0, SIZE[2]]) + t
    assert abs(box.signed_distance(corner_cam[None])[0]) < SILHOUETTE_MARGIN + 0.002


@pytest.mark.parametrize("lying", [False, True], ids=["standing can", "lying can"])
def test_a_can_is_not_a_box(lying):
    """A standing can's points fill a disc, not a rectangle; a lying can's do fill one, but its side
    is curved: neither is completed as a box."""
    R, t, plane = table_camera()
    box = fit_cuboid(seen_by(*_cylinder(0.035, 0.12, lying), R, t, noise=0.0005), plane)
    assert not box.accepted
    assert (box.fill < 0.9) if not lying else (box.aligned < 0.8 and box.residual > 0.004)


def test_the_boxes_occupancy_is_one_inside_and_zero_outside_with_its_surface_at_one_half():
    R, t, plane = table_camera()
    box = fit_cuboid(seen_by(*_box(), R, t, noise=0.0005), plane)
    frame = GridFrame(R @ np.r_[CENTRE, SIZE[2] / 2] + t, 0.005)
    p = occupancy(box, frame).reshape(-1)
    index = np.indices((40, 40, 40)).reshape(3, -1).T
    sdf = box.signed_distance(frame.voxel_centers(index))
    assert np.all(p[sdf < -0.005] == 1.0) and np.all(p[sdf > 0.005] == 0.0)
    assert np.all((p > 0.5) == (sdf < 0))
    assert abs(p.sum() * 0.005**3 - np.prod(box.extents)) < 0.05 * np.prod(box.extents)


def test_too_few_points_are_an_error_not_a_box():
    _, _, plane = table_camera()
    with pytest.raises(ValueError, match="too few"):
        fit_cuboid(np.zeros((5, 3)), plane)


def test_a_wooden_block_on_the_table_is_completed_as_its_box():
    """The YCB wooden block seen by a RealSense on the table: its points are a box's, and the
    completion is that box, closer to the true block than the network's answer; a can is left as
    the network answered it."""
    import shapeviewer
    from shapeviewer.completion.model import load_completer
    from shapeviewer.completion.pipeline import complete_points
    from shapeviewer.evaluation.metrics import hausdorff
    from shapeviewer.sim.tabletop import render_tabletop_view

    v = render_tabletop_view("ycb/036_wood_block", 0, seed=0, sensor="realsense")
    assert v is not None and v.plane_cam is not None
    completer = load_completer()
    (c,) = complete_points([v.points_cam], completer, support_plane=v.plane_cam)
    assert c.boxed and np.allclose(c.samples, occupancy(c.cuboid, c.frame)) and c.timings["priors"] > 0
    truth = v.truth_cam()
    boxed = shapeviewer.complete(v.points_cam, support_plane=v.plane_cam)
    plain = shapeviewer.complete(v.points_cam, support_plane=v.plane_cam, fit_boxes=False)
    assert boxed.is_watertight
    assert hausdorff(boxed, truth)["mean_mm"] < hausdorff(plain, truth)["mean_mm"] - 1.0
    can = render_tabletop_view("ycb/002_master_chef_can", 2, seed=0, sensor="realsense")
    (kept,) = complete_points([can.points_cam], completer, support_plane=can.plane_cam)  # on by default
    (off,) = complete_points([can.points_cam], completer, support_plane=can.plane_cam, fit_boxes=False)
    assert kept.cuboid is not None and not kept.boxed and np.allclose(kept.samples, off.samples, atol=1e-6)
    assert off.cuboid is None


@pytest.mark.slow
def test_an_evaluated_box_view_records_its_box_and_the_dataset_tab_says_so(tmp_path):
    """A tabletop view of a box in the evaluation (and the sample store): our completions' rows say
    they are the fitted box, the results store keeps it, and the Dataset tab's label shows it."""
    from shapeviewer.completion.model import load_completer
    from shapeviewer.evaluation.results import ResultsStore
    from shapeviewer.evaluation.run import complete_view
    from shapeviewer.evaluation.viewsets import view_set_of
    from shapeviewer.viewer.dataset.summary import completion_label, view_markdown

    name, view = "household/box_034", 522_697
    record = complete_view(tmp_path, name, view, view_set_of(name, view), 0, load_completer())
    priors = {r["method"]: r["prior"] for r in record["rows"]}
    assert priors == {"Partial": "", "Mirror": "", "Hull": "", "Ours-fast": "box", "Ours-detailed": "box"}
    store = ResultsStore(tmp_path)
    store.sync()
    detailed = next(c for c in store.completions(name, view) if c.method == "Ours-detailed")
    assert detailed.prior == "box" and detailed.j80 > 0.85 and "fitted box" in completion_label(detailed)
    assert {r.prior for r in store.rows() if r.method == "Hull"} == {""}
    text = view_markdown(store.object(name), store.view(name, view), store.completions(name, view), [])
    assert "Ours: the box fitted to the points" in text
