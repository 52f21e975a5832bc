"""Grasp planning: the object field, the cheap stage against pybullet, and planned grasps."""

import math

import numpy as np
import pytest
import trimesh

from shapeviewer.grasp import plan as P
from shapeviewer.grasp.hands import get_hand
from shapeviewer.grasp.lift import lift_test
from shapeviewer.grasp.object_field import APPROACH_MARGIN, ObjectField
from shapeviewer.grasp.samples import hand_samples
from shapeviewer.grasp.search import DISTINCT_ANGLE, DISTINCT_POSITION, distinct, search
from shapeviewer.grasp.world import GraspWorld
from shapeviewer.sim import household

SMALL = P.PlanSettings(samples=256, chains=16, steps=10, simulate=12)
MEDIUM = P.PlanSettings(samples=512, chains=32, steps=60, simulate=20)  # enough for boxes and cylinders


def on_table(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    mesh = mesh.copy()
    mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])
    return mesh


@pytest.fixture(scope="module")
def box() -> trimesh.Trimesh:
    return on_table(trimesh.creation.box(extents=[0.06, 0.06, 0.12]))


@pytest.fixture(scope="module")
def cylinder() -> trimesh.Trimesh:
    return on_table(trimesh.creation.cylinder(radius=0.035, height=0.12, sections=48))


@pytest.fixture(scope="module")
def box_plan(box):
    return P.plan(box, n_grasps=5, seed=0)


def check_grasps(grasps: list[P.Grasp], mesh: trimesh.Trimesh) -> None:
    hand = get_hand("barrett")
    assert grasps
    best = grasps[0]
    # Every finger touches the object, and the best grasp is force closure.
    for g in grasps:
        links = {c.link for c in g.contacts}
        assert all(links & set(f.links) for f in hand.fingers)
    assert best.epsilon > 0.0 and best.volume > 0.0
    # Grasps that lift the mesh come first (the lift check), then by epsilon within each group.
    group = [0 if g.lift is not None and g.lift.success else 1 if g.lift is None else 2 for g in grasps]
    assert group == sorted(group)
    for k in set(group):
        eps = [g.epsilon for g, q in zip(grasps, group) if q == k and g.force_closure]
        assert eps == sorted(eps, reverse=True)
    for g in grasps:
        assert g.approach[2] <= 1e-6  # never from below the table
        assert g.frame == "world" and g.T_world_palm.shape == (4, 4)
        np.testing.assert_allclose(g.T_world_palm[:3, :3] @ g.T_world_palm[:3, :3].T, np.eye(3), atol=1e-9)
        assert set(g.joints) == set(hand.joint_names) and set(g.dofs) == set(hand.dof_names)
        # Contacts lie on the object's surface (its convex decomposition is within a few mm).
        d = np.abs(trimesh.proximity.signed_distance(mesh, np.array([c.position for c in g.contacts])))
        assert d.max() < 0.004
    # Distinct: no two grasps within 1 cm and 15 degrees of each other.
    for i, a in enumerate(grasps):
        for b in grasps[i + 1 :]:
            dp = np.linalg.norm(a.position - b.position)
            cos = (np.trace(a.T_world_palm[:3, :3].T @ b.T_world_palm[:3, :3]) - 1) / 2
            assert dp > DISTINCT_POSITION or cos < math.cos(DISTINCT_ANGLE)


def test_object_field_matches_the_box(box):
    field = ObjectField(box)
    rng = np.random.default_rng(0)
    pts = rng.uniform(box.bounds[0] - 0.02, box.bounds[1] + 0.02, size=(2000, 3))
    exact = -trimesh.proximity.signed_distance(box, pts)  # trimesh: positive inside
    near = np.abs(exact) < 0.01
    sd, normal = field.distance_and_normal(pts)
    error = np.abs(sd - exact)[near]
    assert np.median(error) < 0.0005 and error.max() < 0.003  # the largest at edges and corners
    assert np.abs(field.nearest_signed_distance(pts) - exact)[near].max() < 0.004
    # On the +x face the outward normal is +x.
    sd, normal = field.distance_and_normal(np.array([[0.032, 0.0, 0.06]]))
    np.testing.assert_allclose(normal[0], [1, 0, 0], atol=0.05)
    # Rays stop at the surface inflated by the approach margin.
    t = field.offset_ray_hits(np.array([[0.2, 0.0, 0.06]]), np.array([-1.0, 0.0, 0.0]))
    assert t[0] == pytest.approx(0.2 - 0.03 - APPROACH_MARGIN, abs=0.0015)


def test_cheap_stage_agrees_with_pybullet(box):
    """The palm positions the cheap stage predicts are where pybullet's approach stops."""
    hs = hand_samples("barrett")
    obj = ObjectField(box)
    found, evaluations, _ = search(
        obj, hs, np.random.default_rng(0), True, SMALL, lambda f: None, lambda: False, lambda: False
    )
    # Every random sample points down or sideways; annealing proposals pointing up are not evaluated.
    assert SMALL.samples < evaluations <= SMALL.samples + SMALL.chains * SMALL.steps
    order = np.argsort(found.energy)
    picks = distinct(found.palm, found.R, order[np.isfinite(found.energy[order])], 20)
    errors = []
    with GraspWorld("barrett") as world:
        world.add_object(box, decompose=True)
        for i in picks:
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = found.R[i], found.palm[i]
            P.approach_and_close(world, T, hs.preshapes[found.shape[i]], max_approach=0.23, targets=())
            errors.append(np.linalg.norm(world.palm_pose()[:3, 3] - found.palm[i]))
    assert np.median(errors) < 0.005


def test_box_grasps(box, box_plan):
    check_grasps(box_plan.grasps, box)
    stats = box_plan.stats
    assert stats.evaluations >= 8000 and stats.evaluations_per_second > 0 and not stats.cancelled


def test_cylinder_grasps(cylinder):
    check_grasps(P.plan(cylinder, n_grasps=5, seed=1, settings=MEDIUM).grasps, cylinder)


def test_lift_check_puts_grasps_that_lift_first():
    """A long, thin tool lying on the table: the grasp with the best epsilon does not pick it up (epsilon
    knows neither gravity nor how the fingers squeeze); the planner's lift check puts one that does first."""
    tool = household.make("tool", 18)
    poses, probability = tool.compute_stable_poses(n_samples=1)
    tool = on_table(tool.apply_transform(poses[np.argmax(probability)]))
    checked = P.plan(tool, n_grasps=4, seed=0, settings=MEDIUM)
    plain = P.plan(tool, n_grasps=4, seed=0, settings=MEDIUM, lift_check=False)
    assert all(g.lift is None for g in plain.grasps) and "lift" not in plain.stats.seconds
    assert not lift_test(plain.grasps[0], tool).success
    assert checked.grasps and all(g.lift is not None for g in checked.grasps)
    check_grasps(checked.grasps, tool)
    best = checked.grasps[0]
    assert best.lift.success and best.lift.rise > 0.06 and lift_test(best, tool).success
    assert checked.stats.evaluations == plain.stats.evaluations  # the same search, re-ranked


def test_deterministic_for_a_seed(box):
    a = P.plan(box, n_grasps=3, seed=3, settings=SMALL).grasps
    b = P.plan(box, n_grasps=3, seed=3, settings=SMALL).grasps
    assert len(a) == len(b) > 0
    for x, y in zip(a, b):
        assert np.array_equal(x.T_world_palm, y.T_world_palm) and x.joints == y.joints and x.epsilon == y.epsilon


def test_progress_and_cancel(box):
    seen = []
    P.plan(box, n_grasps=2, seed=0, settings=SMALL, progress=seen.append)
    assert seen[-1] == 1.0 and all(0.0 <= f <= 1.0 for f in seen) and seen == sorted(seen)
    calls = []

    def cancel() -> bool:
        calls.append(1)
        return len(calls) > 3

    result = P.plan(box, n_grasps=2, seed=0, settings=SMALL, cancel=cancel)
    assert result.stats.cancelled and result.grasps == [] and result.stats.simulated == 0


def test_panda_plans_on_the_cylinder(cylinder):
    grasps = P.plan(cylinder, hand="panda", n_grasps=3, seed=0, settings=MEDIUM).grasps
    assert grasps and grasps[0].force_closure
    assert {c.link for c in grasps[0].contacts} >= {"left_finger", "right_finger"}
