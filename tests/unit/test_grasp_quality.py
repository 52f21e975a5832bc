"""GraspIt-style epsilon and volume qualities."""

import numpy as np
import pytest

from shapeviewer.grasp.quality import (
    GraspQuality,
    contact_wrenches,
    friction_cone,
    grasp_quality,
    max_radius,
    wrench_space_quality,
)

R = 0.05  # sphere radius (m)


def on_sphere(directions) -> tuple[np.ndarray, np.ndarray]:
    """Contact points on a sphere of radius R at the origin, and the outward normals there."""
    n = np.asarray(directions, float)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return R * n, n


def test_friction_cone_edges():
    n = np.array([0.0, 0.0, 1.0])
    edges = friction_cone(n, mu=1.0, n_edges=8)
    assert edges.shape == (8, 3)
    np.testing.assert_allclose(edges @ n, 1.0)  # unit normal component
    tangential = edges - np.outer(edges @ n, n)
    np.testing.assert_allclose(np.linalg.norm(tangential, axis=1), 1.0)  # mu * unit
    np.testing.assert_allclose(edges.sum(axis=0), 8 * n, atol=1e-12)  # symmetric about the normal


def test_wrench_units():
    # One contact on the sphere's equator at +x, pushing in (-x): the torque of every edge is
    # (R x f) / R, so its size is the tangential force, 1 for mu = 1, and force and torque are
    # commensurate.
    points, normals = on_sphere([[1, 0, 0]])
    w = contact_wrenches(points, normals, np.zeros(3), R)
    assert w.shape == (8, 6)
    np.testing.assert_allclose(w[:, 0], -1.0)
    np.testing.assert_allclose(np.linalg.norm(w[:, 3:], axis=1), 1.0)
    np.testing.assert_allclose(w[:, 3], 0.0, atol=1e-12)  # no torque about the contact normal
    # Scale invariance: the same grasp on a 10x larger sphere has the same wrenches.
    np.testing.assert_allclose(contact_wrenches(10 * points, normals, np.zeros(3), 10 * R), w)


def test_max_radius():
    verts = np.array([[1.0, 0, 0], [0, 2.0, 0], [0, 0, -3.0]])
    assert max_radius(verts, np.zeros(3)) == pytest.approx(3.0)
    assert max_radius(verts, np.array([0, 0, 1.0])) == pytest.approx(4.0)


@pytest.mark.parametrize(
    "directions",
    [
        [[1, 0, 0], [-0.5, np.sqrt(3) / 2, 0], [-0.5, -np.sqrt(3) / 2, 0]],  # three around the equator
        [[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]],  # a tetrahedron
    ],
)
def test_symmetric_contacts_on_a_sphere_are_force_closure(directions):
    points, normals = on_sphere(directions)
    q = grasp_quality(points, normals, np.zeros(3), R)
    assert q.force_closure and 0.0 < q.epsilon < 1.0 and q.volume > 0.0


def test_more_contacts_never_lower_the_quality():
    points, normals = on_sphere([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]])
    four = grasp_quality(points, normals, np.zeros(3), R)
    p6, n6 = on_sphere([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    six = grasp_quality(np.vstack([points, p6]), np.vstack([normals, n6]), np.zeros(3), R)
    assert six.epsilon >= four.epsilon and six.volume > four.volume


def test_contacts_on_one_side_are_not_force_closure():
    points, normals = on_sphere([[1, 0, 0], [1, 0.3, 0.1]])
    q = grasp_quality(points, normals, np.zeros(3), R)
    assert not q.force_closure and q.epsilon <= 0.0


def test_antipodal_pair_cannot_resist_torque_about_its_axis():
    # Point contacts on opposite sides: torque about the line through them needs a soft finger.
    points, normals = on_sphere([[1, 0, 0], [-1, 0, 0]])
    q = grasp_quality(points, normals, np.zeros(3), R)
    assert q.epsilon == pytest.approx(0.0, abs=1e-9)
    assert not q.force_closure


def test_degenerate_inputs():
    assert wrench_space_quality(np.zeros((0, 6))) == GraspQuality(0.0, 0.0)
    points, normals = on_sphere([[0, 0, 1]])
    assert grasp_quality(points, normals, np.zeros(3), R) == GraspQuality(0.0, 0.0)
    # Wrenches lying in a 5-D subspace.
    w = np.random.default_rng(0).normal(size=(40, 6))
    w[:, 5] = 0.0
    assert wrench_space_quality(w) == GraspQuality(0.0, 0.0)
