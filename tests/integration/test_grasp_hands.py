"""Hands (URDF, coupling, limits, kinematics, meshes) and the kinematic grasp world."""

import math

import numpy as np
import pybullet as p
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from shapeviewer.geometry import pq_to_pose
from shapeviewer.grasp import hands as H
from shapeviewer.grasp import world as W
from shapeviewer.grasp.quality import grasp_quality, max_radius

DEG = math.pi / 180.0
# Palm facing down (approach = -z world): x stays, y and z flip.
PALM_DOWN = np.diag([1.0, -1.0, -1.0])


def palm_at(z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = PALM_DOWN
    T[2, 3] = z
    return T


@pytest.fixture
def client():
    c = p.connect(p.DIRECT)
    yield c
    p.disconnect(physicsClientId=c)


def joint_state(hb: H.HandBody) -> np.ndarray:
    return np.array([p.getJointState(hb.body, i, physicsClientId=hb.client)[0] for i in hb.joint_index])


@pytest.mark.parametrize("name", H.HAND_NAMES)
def test_hand_loads_and_kinematics_match_pybullet(client, name):
    hand = H.get_hand(name)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [0.3, -0.5, 1.0]).as_matrix()
    T[:3, 3] = [0.1, 0.2, 0.3]
    hb = H.load_hand(client, name, T)
    assert set(hb.link_index) >= {"palm", *(n for f in hand.fingers for n in f.links)}
    np.testing.assert_allclose(H.palm_pose(hb), T, atol=1e-9)
    H.set_joints(hb, 0.6 * np.array(hand.dof_upper))
    poses = hand.link_poses(hb.joints)
    for link, i in hb.link_index.items():
        if i >= 0:
            state = p.getLinkState(hb.body, i, computeForwardKinematics=True, physicsClientId=client)
            np.testing.assert_allclose(pq_to_pose(state[4], state[5]), T @ poses[link], atol=1e-6)


def test_barrett_limits_clip(client):
    hb = H.load_hand(client, "barrett")
    H.set_joints(hb, [4.0, 3.0, -1.0, 10.0])
    np.testing.assert_allclose(hb.dofs, [math.pi, 140 * DEG, 0.0, 140 * DEG])
    lower, upper = hb.hand.joint_limits
    H.set_joint_positions(hb, np.full(8, 5.0))
    np.testing.assert_allclose(joint_state(hb), upper, atol=1e-9)
    H.set_joint_positions(hb, np.full(8, -5.0))
    np.testing.assert_allclose(joint_state(hb), lower, atol=1e-9)


def test_barrett_coupling(client):
    hb = H.load_hand(client, "barrett")
    spread, q1, q2, q3 = 0.5, 0.3, 1.2, 140 * DEG
    H.set_joints(hb, [spread, q1, q2, q3])
    got = dict(zip(hb.hand.joint_names, joint_state(hb)))
    assert got["f1_spread"] == pytest.approx(spread) and got["f2_spread"] == pytest.approx(spread)
    for f, q in (("f1", q1), ("f2", q2), ("f3", q3)):
        assert got[f"{f}_proximal"] == pytest.approx(q)
        assert got[f"{f}_distal"] == pytest.approx(q / 3 + 42 * DEG)


def test_closing_moves_the_fingers_not_the_spread():
    barrett, panda = H.get_hand("barrett"), H.get_hand("panda")
    assert barrett.closing_dofs.tolist() == [False, True, True, True]
    closing = dict(zip(barrett.joint_names, barrett.closing_joints))
    assert [n for n, c in closing.items() if not c] == ["f1_spread", "f2_spread"]
    assert panda.closing_dofs.all() and panda.closing_joints.all()


def test_barrett_spread_turns_fingers_1_and_2_opposite_ways():
    hand = H.get_hand("barrett")
    at = {s: hand.link_poses(hand.joints_from_dofs([s, 0, 0, 0])) for s in (0.0, math.pi / 2, math.pi)}
    # Spread 0: fingers 1 and 2 side by side at y = +50 mm, finger 3 opposite at y = -50 mm.
    np.testing.assert_allclose(at[0.0]["f1_proximal"][:3, 3], [0.025, 0.05, 0], atol=1e-9)
    np.testing.assert_allclose(at[0.0]["f2_proximal"][:3, 3], [-0.025, 0.05, 0], atol=1e-9)
    np.testing.assert_allclose(at[0.0]["f3_proximal"][:3, 3], [0, -0.05, 0], atol=1e-9)
    # Spread 90 deg: they face each other along x.
    np.testing.assert_allclose(at[math.pi / 2]["f1_proximal"][:3, 3], [0.075, 0, 0], atol=1e-9)
    np.testing.assert_allclose(at[math.pi / 2]["f2_proximal"][:3, 3], [-0.075, 0, 0], atol=1e-9)
    np.testing.assert_allclose(at[math.pi]["f3_proximal"][:3, 3], [0, -0.05, 0], atol=1e-9)
    # Closing moves every fingertip towards the palm axis.
    closed = hand.link_poses(hand.joints_from_dofs([0, 1.0, 1.0, 1.0]))
    for f in ("f1", "f2", "f3"):
        assert np.linalg.norm(closed[f"{f}_distal"][:2, 3]) < np.linalg.norm(at[0.0][f"{f}_distal"][:2, 3])


@pytest.mark.parametrize("name", H.HAND_NAMES)
def test_hand_mesh_in_palm_frame(name):
    hand = H.get_hand(name)
    mesh = H.hand_mesh(hand, hand.joints_from_dofs(hand.dof_open))
    assert len(mesh.faces) > 0 and mesh.visual.face_colors.shape[0] == len(mesh.faces)
    lo, hi = mesh.bounds
    # The palm body lies behind the palm face (z < 0) and the fingers reach forward (z > 0).
    assert lo[2] < -0.02 and hi[2] > 0.04
    assert len(H.hand_meshes(hand, hand.joints_from_dofs(hand.dof_open))) == sum(
        len(g) for g in hand.model.visuals.values()
    )


def test_close_barrett_around_cube_touches_every_finger():
    cube = trimesh.creation.box(extents=[0.06, 0.06, 0.06])
    with W.GraspWorld("barrett", table=False) as world:
        world.add_object(cube)
        # Palm 3 mm above the top face: the cube sits between the open fingers, under the
        # inward-bent distal links.
        world.set_palm_pose(palm_at(0.033))
        approach = world.approach(0.05)
        assert approach.contact and approach.distance < 0.003
        result = world.close_fingers()
        assert all(result.finger_blocked)
        touching = {c.link for c in result.contacts}
        for f in ("f1", "f2", "f3"):
            assert touching & {f"{f}_proximal", f"{f}_distal"}
        assert "palm" in touching
        for c in result.contacts:
            assert -1e-4 < c.distance <= world.contact_tol
            assert np.max(np.abs(c.position)) <= 0.03 + 1e-3  # on the cube's surface
        q = grasp_quality(
            [c.position for c in result.contacts],
            [c.normal for c in result.contacts],
            np.zeros(3),
            max_radius(cube.vertices, np.zeros(3)),
        )
        assert q.force_closure and q.volume > 0


def test_breakaway_distal_keeps_closing():
    # A post standing in front of finger 3's proximal link, out of reach of its distal link.
    # Palm down at z = 0, so palm y = -world y: finger 3's inner face is at world y = 0.04, and
    # the post (world y 0.025..0.035, palm z 0.002..0.032) is too narrow in x for fingers 1 and 2.
    post = trimesh.creation.box(extents=[0.01, 0.01, 0.03])
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.03, -0.017]
    with W.GraspWorld("barrett", table=False) as world:
        world.set_palm_pose(palm_at(0.0))
        world.add_object(post, T)
        assert not world.in_collision()
        result = world.close_fingers()
        joints = dict(zip(world.hand.hand.joint_names, result.joints))
        assert result.finger_blocked[2]
        assert 0.0 < joints["f3_proximal"] < 30 * DEG
        # The distal went past its coupled value, to its limit or onto the post.
        assert joints["f3_distal"] > joints["f3_proximal"] / 3 + 42 * DEG + 10 * DEG
        # Fingers 1 and 2 met nothing and closed fully.
        assert joints["f1_proximal"] == pytest.approx(140 * DEG)
        assert not result.finger_blocked[0]


def test_approach_stops_at_table_and_backs_off():
    with W.GraspWorld("barrett") as world:
        world.set_palm_pose(palm_at(0.3))
        result = world.approach(0.5)
        assert result.contact
        assert min(world.link_gaps().values()) <= world.contact_tol
        # The drawn hand (same primitives as the collision geometry) ends just above the table.
        mesh = H.hand_mesh(world.hand.hand, world.hand.joints)
        mesh.apply_transform(world.palm_pose())
        assert 0.0 < mesh.bounds[0, 2] <= world.contact_tol
        z = world.palm_pose()[2, 3]
        world.move_along_approach(-0.2)
        assert world.palm_pose()[2, 3] == pytest.approx(z + 0.2)
        limited = world.approach(0.05)
        assert not limited.contact and limited.distance == pytest.approx(0.05)


def test_panda_closes_on_cube_from_both_sides():
    cube = trimesh.creation.box(extents=[0.04, 0.04, 0.04])
    with W.GraspWorld("panda", table=False) as world:
        world.add_object(cube)
        world.set_palm_pose(palm_at(0.05))
        assert not world.in_collision()
        result = world.close_fingers()
        assert all(result.finger_blocked)
        # Each finger's inner face rests on a cube face 20 mm from the centre.
        np.testing.assert_allclose(result.dofs, [0.02, 0.02], atol=world.contact_tol + 1e-4)
        assert {c.link for c in result.contacts} == {"left_finger", "right_finger"}


def test_movable_object_uses_cached_decomposition(tmp_path, monkeypatch):
    monkeypatch.setenv("SHAPEVIEWER_CACHE", str(tmp_path))
    # A concave L-shaped object, which a single convex hull would fill in.
    a = trimesh.creation.box(extents=[0.08, 0.02, 0.02])
    b = trimesh.creation.box(extents=[0.02, 0.08, 0.02])
    b.apply_translation([-0.03, 0.03, 0.0])
    ell = trimesh.boolean.union([a, b])
    path = W.convex_decomposition(ell)
    assert path.exists() and path.parent == tmp_path / "vhacd"
    calls = []
    monkeypatch.setattr(W.subprocess, "Popen", lambda *a, **k: calls.append(a))
    with W.GraspWorld("barrett", table=False) as world:
        body = world.add_object(ell, movable=True)
        assert not calls  # reused from the cache
        T = np.eye(4)
        T[:3, 3] = [0.1, 0.2, 0.3]
        world.set_object_pose(body, T)
        np.testing.assert_allclose(world.object_pose(body), T, atol=1e-9)
        # The notch of the L stays empty: a point there is outside every part.
        probe = p.createCollisionShape(p.GEOM_SPHERE, radius=0.002, physicsClientId=world.client)
        sphere = p.createMultiBody(0, probe, basePosition=[0.1 + 0.01, 0.2 + 0.03, 0.3], physicsClientId=world.client)
        rows = p.getClosestPoints(sphere, body, 0.05, physicsClientId=world.client)
        assert min(r[8] for r in rows) > 0.003
