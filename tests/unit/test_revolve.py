"""The vertical axis of a surface of revolution on a table, and the network's answer revolved about it."""

from __future__ import annotations

import numpy as np

from shapeviewer.completion.revolve import fit_axis, revolve
from shapeviewer.completion.voxel import GridFrame

from helpers import seen_by, table_camera

AXIS_WORLD = np.array([0.03, -0.02])  # where the object stands on the table (world x, y, metres)


def _cylinder(radius: float, height: float, n: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    """Points and outward normals of a can's side and top (world frame)."""
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 2 * np.pi, n)
    side = np.c_[AXIS_WORLD[0] + radius * np.cos(a), AXIS_WORLD[1] + radius * np.sin(a), rng.uniform(0, height, n)]
    side_n = np.c_[np.cos(a), np.sin(a), np.zeros(n)]
    r = radius * np.sqrt(rng.uniform(0, 1, n // 2))
    b = rng.uniform(0, 2 * np.pi, n // 2)
    top = np.c_[AXIS_WORLD[0] + r * np.cos(b), AXIS_WORLD[1] + r * np.sin(b), np.full(n // 2, height)]
    return np.vstack([side, top]), np.vstack([side_n, np.tile([0.0, 0.0, 1.0], (n // 2, 1))])


def test_a_cans_axis_is_found_from_its_visible_half():
    R, t, plane = table_camera()
    pts, normals = _cylinder(0.04, 0.12)
    axis = fit_axis(seen_by(pts, normals, R, t), plane)
    world_cam = np.linalg.inv(axis.T_table_cam)
    # The table frame's axis through ``centre``, back in the world: the can's own axis.
    foot_cam = world_cam[:3, :3] @ np.r_[axis.centre, 0.0] + world_cam[:3, 3]
    foot_world = R.T @ (foot_cam - t)
    assert np.linalg.norm(foot_world[:2] - AXIS_WORLD) < 0.002
    assert abs(axis.radius - 0.04) < 0.01 and axis.accepted


def test_a_box_and_a_bananas_arc_are_not_surfaces_of_revolution():
    R, t, plane = table_camera()
    rng = np.random.default_rng(1)
    u, v = rng.uniform(-1, 1, (2, 3000))
    box = np.vstack(
        [np.c_[0.06 * u, 0.04 * v, np.full(3000, 0.08)], np.c_[0.06 * u, np.full(3000, -0.04), 0.04 + 0.04 * v]]
    )
    box_n = np.vstack([np.tile([0.0, 0.0, 1.0], (3000, 1)), np.tile([0.0, -1.0, 0.0], (3000, 1))])
    assert not fit_axis(seen_by(box, box_n, R, t), plane).accepted
    # A banana's top: a 60 deg arc of a 15 cm circle, 3 cm wide, lying on the table.
    a = rng.uniform(-np.pi / 6, np.pi / 6, 4000)
    r = 0.15 + rng.uniform(-0.015, 0.015, 4000)
    arc = np.c_[r * np.sin(a), 0.1 - r * np.cos(a), np.full(4000, 0.035)]
    assert not fit_axis(seen_by(arc, np.tile([0.0, 0.0, 1.0], (4000, 1)), R, t), plane).accepted


def test_revolving_closes_the_far_half_of_a_ring():
    R, t, plane = table_camera()
    pts, normals = _cylinder(0.04, 0.12)
    seen = seen_by(pts, normals, R, t)
    axis = fit_axis(seen, plane)
    centre_cam = R @ np.r_[AXIS_WORLD, 0.06] + t
    frame = GridFrame(centre_cam, 0.005)
    index = np.stack(np.meshgrid(*[np.arange(40)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    world = (frame.voxel_centers(index) - t) @ R  # camera -> world
    radius = np.linalg.norm(world[:, :2] - AXIS_WORLD, axis=1)
    wall = (np.abs(radius - 0.04) < 0.006) & (world[:, 2] > 0.01) & (world[:, 2] < 0.11)
    eye = -R.T @ t
    near = ((world[:, :2] - AXIS_WORLD) @ (eye[:2] - AXIS_WORLD)) > 0
    answer = np.where(wall & near, 0.95, 0.1).reshape(40, 40, 40).astype(np.float32)
    out = revolve(answer, frame, axis).reshape(-1)
    far_wall = wall & ~near
    assert (out[far_wall] > 0.5).mean() > 0.9  # the far half of the wall is now there
    assert (out[~wall & (radius < 0.025)] > 0.5).mean() < 0.01  # and the inside stays empty
    assert np.all(out >= answer.reshape(-1))  # nothing the network completed is taken away
    # Space the camera saw through stays empty; several answers are revolved one by one.
    free = (far_wall & (world[:, 0] > AXIS_WORLD[0])).reshape(40, 40, 40)
    both = revolve(np.stack([answer, answer]), frame, axis, free=free)
    assert both.shape == (2, 40, 40, 40) and np.array_equal(both[0], both[1])
    assert np.array_equal(both[0][free], answer[free]) and free.any()
    assert np.array_equal(both[0][~free], out.reshape(40, 40, 40)[~free])
