import numpy as np
import pytest
import trimesh

from shapeviewer.completion.reconstruct import grid_mesh
from shapeviewer.completion.voxel import (
    GridFrame,
    partial_to_grid,
    points_to_grid,
    solid_fraction,
    solid_grid,
    surface_samples,
)


def _cloud(seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform([-0.04, -0.03, 0.9], [0.06, 0.05, 0.95], size=(5000, 3))


def test_bounding_box_centre_lands_on_voxel_20_20_18():
    pts = _cloud()
    grid, frame = partial_to_grid(pts)
    lo, hi = pts.min(0), pts.max(0)
    np.testing.assert_allclose(frame.to_grid(((lo + hi) / 2)[None])[0], [20, 20, 18], atol=1e-9)
    assert grid.shape == (40, 40, 40) and grid.dtype == bool


def test_largest_side_spans_32_voxels():
    pts = _cloud()
    grid, frame = partial_to_grid(pts)
    assert frame.voxel_size == pytest.approx(0.1 / 32, rel=0.01)
    occupied = np.argwhere(grid)
    spans = occupied.max(0) - occupied.min(0) + 1
    assert spans.max() in (32, 33)  # the top face lies exactly on a voxel boundary
    # x is the largest side (10 cm), so x occupies voxels 4..35
    assert occupied[:, 0].min() == 4


def test_round_trip_to_metres_within_half_a_voxel():
    pts = _cloud(1)
    grid, frame = partial_to_grid(pts)
    idx = frame.to_index(pts)
    back = frame.voxel_centers(idx)
    assert np.abs(back - pts).max() <= frame.voxel_size / 2 + 1e-12
    np.testing.assert_allclose(frame.to_metres(frame.to_grid(pts)), pts, atol=1e-12)
    T = frame.grid_to_camera()
    np.testing.assert_allclose(frame.to_grid(pts) @ T[:3, :3].T + T[:3, 3], pts, atol=1e-12)


def test_nan_rows_are_ignored_and_empty_cloud_is_an_error():
    pts = _cloud()
    pts[::3] = np.nan
    grid, _ = partial_to_grid(pts)
    assert grid.any()
    with pytest.raises(ValueError, match="no finite points"):
        partial_to_grid(np.full((10, 3), np.nan))
    with pytest.raises(ValueError, match="zero extent"):
        partial_to_grid(np.ones((10, 3)))


def test_frame_serialises():
    frame = GridFrame(np.array([0.1, -0.2, 1.0]), 0.004)
    again = GridFrame.from_dict(frame.to_dict())
    np.testing.assert_array_equal(again.center, frame.center)
    assert again.voxel_size == frame.voxel_size and again.dim == 40


def test_solid_grid_marks_interior_and_every_surface_voxel_of_a_thin_shell():
    # A thin-walled open-top cup: the interior of the walls is tiny, the surface voxels dominate.
    outer = trimesh.creation.cylinder(radius=0.04, height=0.1, sections=64)
    inner = trimesh.creation.cylinder(radius=0.036, height=0.1, sections=64)
    inner.apply_translation([0, 0, 0.01])
    cup = outer.difference(inner)
    assert cup.is_watertight
    T = np.eye(4)
    T[:3, 3] = [0, 0, 1.0]
    frame = GridFrame(np.array([0, 0, 1.0]), 0.11 / 32)
    y = solid_grid(cup, frame, T)
    # Every surface sample's voxel is marked ...
    s = surface_samples(cup, spacing=frame.voxel_size / 4) + T[:3, 3]
    assert np.all(y[tuple(frame.to_index(s).T)])
    # ... and the cup's hollow stays empty: a voxel at the centre, half way up, is free.
    centre = frame.to_index(np.array([[0, 0, 1.02]]))[0]
    assert not y[tuple(centre)]
    # Solid volume is between the true volume and the volume plus one voxel layer of surface.
    vox_volume = y.sum() * frame.voxel_size**3
    assert cup.volume < vox_volume < cup.volume + cup.area * frame.voxel_size * 1.5


def test_the_soft_label_puts_its_half_contour_on_the_surface_and_keeps_thin_walls():
    frame = GridFrame(np.array([0, 0, 1.0]), 0.1 / 32)
    T = np.eye(4)
    T[:3, 3] = [0.001, -0.0013, 1.0007]  # off the voxel lattice
    box = trimesh.creation.box([0.1, 0.06, 0.04])
    hard = solid_grid(box, frame, T)
    soft = solid_fraction(box, frame, hard, T)
    assert soft.dtype == np.float32 and soft.min() >= 0 and soft.max() <= 1
    assert np.all(soft[~hard] == 0) and np.all(soft[hard] > 0)
    # The 0.5 contour of Y lies outside the box (up to a voxel); the soft label's a quarter voxel out.
    v_hard = grid_mesh(hard.astype(np.float32), frame, 0.5).volume
    v_soft = grid_mesh(soft, frame, 0.5).volume
    grown = np.prod(np.array(box.extents) + 0.5 * frame.voxel_size)
    assert v_hard > 1.1 * box.volume
    assert abs(v_soft - grown) < 0.03 * grown
    # A plate a third of a voxel thick stays above 0.5 across its whole extent.
    plate = trimesh.creation.box([0.08, 0.08, frame.voxel_size / 3])
    T[:3, 3] = [0.0, 0.0, 1.0 + 0.5 * frame.voxel_size]  # through a layer of voxel centres
    soft = solid_fraction(plate, frame, solid_grid(plate, frame, T), T)
    columns = (soft > 0.5).any(axis=2)
    inner = frame.to_index(np.array([[-0.035, -0.035, 1.0], [0.035, 0.035, 1.0]]))
    assert columns[inner[0, 0] : inner[1, 0], inner[0, 1] : inner[1, 1]].all()


def test_points_outside_the_grid_are_dropped():
    frame = GridFrame(np.zeros(3), 0.01)
    g = points_to_grid(np.array([[0.0, 0, 0], [10.0, 0, 0], [-10, 0, 0]]), frame)
    assert g.sum() == 1


def test_depth_shift_moves_the_object_towards_the_camera_but_keeps_its_front_inside():
    rng = np.random.default_rng(2)
    shallow = rng.uniform([-0.05, -0.03, 0.90], [0.05, 0.03, 0.95], size=(3000, 3))  # 16 voxels deep
    _, paper = partial_to_grid(shallow)
    _, moved = partial_to_grid(shallow, depth_shift=4)
    centre = ((shallow.min(0) + shallow.max(0)) / 2)[None]
    assert moved.voxel_size == paper.voxel_size
    np.testing.assert_allclose(moved.to_grid(centre)[0], [20, 20, 14], atol=1e-9)
    # A cloud as deep as it is wide already fills the grid from voxel 2: it stays where it is.
    deep = rng.uniform([-0.05, -0.05, 0.90], [0.05, 0.05, 1.00], size=(3000, 3))
    _, paper = partial_to_grid(deep)
    grid, moved = partial_to_grid(deep, depth_shift=4)
    np.testing.assert_allclose(moved.center, paper.center)
    assert np.argwhere(grid)[:, 2].min() == 2
    with pytest.raises(ValueError, match="depth_shift"):
        partial_to_grid(shallow, depth_shift=-1)
