"""Executing grasps on the true object (the paper's Table IV protocol), the lift test, and the JSON/zip export."""

import io
import json
import zipfile

import numpy as np
import pybullet as p
import pytest
import trimesh

from shapeviewer.grasp import execute as E
from shapeviewer.grasp import serialize as X
from shapeviewer.grasp.hands import get_hand
from shapeviewer.grasp.lift import lift_test
from shapeviewer.grasp.plan import PlanSettings, plan

from helpers import load_exported_grasp

SETTINGS = PlanSettings(samples=512, chains=32, steps=60, simulate=20)  # enough for a box


@pytest.fixture(scope="module")
def box() -> trimesh.Trimesh:
    mesh = trimesh.creation.box(extents=[0.06, 0.06, 0.12])
    mesh.apply_translation([0.0, 0.0, 0.06])
    return mesh


@pytest.fixture(scope="module")
def grasps(box):
    return plan(box, n_grasps=3, seed=0, settings=SETTINGS).grasps


@pytest.fixture(scope="module")
def executions(grasps, box):
    return E.execute_grasps(grasps, box)


def test_planned_on_truth_executes_as_planned(grasps, executions):
    for g, e in zip(grasps, executions):
        assert e.start_clear
        assert e.joint_error < 2.0  # degrees
        assert e.pose_error < 3.0  # mm
        assert e.epsilon == pytest.approx(g.epsilon, abs=0.02)
        assert {c.link for c in e.contacts} == {c.link for c in g.contacts}


def test_shrunken_completion_shows_pose_error(box):
    shrunk = box.copy()
    shrunk.apply_scale(0.8)
    shrunk.apply_translation(box.centroid - shrunk.centroid)
    planned = plan(shrunk, n_grasps=3, seed=0, settings=SETTINGS).grasps
    results = E.execute_grasps(planned, box)
    # The true box is larger: the approach meets it early.
    assert all(r.pose_error > 3.0 for r in results)
    assert all(r.approach_contact for r in results)


def test_joint_error_units():
    hand = get_hand("barrett")
    planned = dict.fromkeys(hand.joint_names, 0.0)
    executed = dict(planned, f1_proximal=np.radians(6.0), f1_spread=1.0)
    # Six finger joints (the spread is not one): 6 degrees over six joints.
    assert E.joint_error(hand, planned, executed) == pytest.approx(1.0)
    panda = get_hand("panda")
    assert E.joint_error(
        panda,
        {"left_finger_joint": 0.01, "right_finger_joint": 0.0},
        {"left_finger_joint": 0.012, "right_finger_joint": 0.0},
    ) == pytest.approx(1.0)


def test_lift_succeeds_on_a_good_grasp_and_fails_far_away(grasps, executions, box):
    lifted = lift_test(executions[0], box, shake=True)
    assert lifted.success and lifted.rise > 0.1 and lifted.slip < 0.03
    far = box.copy()
    far.apply_translation([0.3, 0.0, 0.0])
    dropped = lift_test(executions[0], far)
    assert not dropped.success and abs(dropped.rise) < 0.01


def test_json_round_trip_is_exact(grasps, executions, box):
    executions = list(executions)
    executions[0].lift = lift_test(executions[0], box)
    with_none = executions[:-1] + [None]
    text = X.grasps_to_json(grasps, with_none, meta={"object": "box"})
    back = X.grasps_from_json(text)
    assert X.grasps_to_json(back.grasps, back.executions, back.meta) == text
    assert back.meta == {"object": "box"} and back.executions[-1] is None
    for g, h in zip(grasps, back.grasps):
        assert np.array_equal(g.T_world_palm, h.T_world_palm)
        assert g.joints == h.joints and g.dofs == h.dofs and list(g.joints) == list(h.joints)
        assert (g.epsilon, g.volume, g.energy) == (h.epsilon, h.volume, h.energy)
        for c, d in zip(g.contacts, h.contacts):
            assert c.link == d.link and np.array_equal(c.position, d.position) and np.array_equal(c.normal, d.normal)
    e, f = executions[0], back.executions[0]
    assert np.array_equal(e.T_world_palm, f.T_world_palm) and e.joints == f.joints
    assert (e.joint_error, e.pose_error, e.lift) == (f.joint_error, f.pose_error, f.lift)
    # The derived pose fields agree with the matrix.
    d = json.loads(text)["grasps"][0]
    T = np.array(d["T_world_palm"])
    np.testing.assert_allclose(d["position"], T[:3, 3])
    q = np.array(d["quaternion_xyzw"])
    np.testing.assert_allclose(np.array(p.getMatrixFromQuaternion(q)).reshape(3, 3), T[:3, :3], atol=1e-12)
    with pytest.raises(ValueError):
        X.grasps_from_json(json.dumps({"format": "other"}))


def test_scene_zip_loads_in_pybullet(grasps, box, tmp_path):
    data = X.scene_zip(box, grasps)
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        assert {
            "object.obj",
            "object_collision.obj",
            "object.urdf",
            "grasps.json",
            "README.txt",
            "hands/barrett_bh8_280.urdf",
        } <= set(z.namelist())
        z.extractall(tmp_path)
    c = p.connect(p.DIRECT)
    try:
        obj, hand = load_exported_grasp(tmp_path, tmp_path / "hands" / "barrett_bh8_280.urdf", c)
        rows = p.getClosestPoints(hand, obj, 0.002, physicsClientId=c)
        # The exported grasp touches the exported object, as planned.
        assert rows and min(r[8] for r in rows) > -0.001
    finally:
        p.disconnect(physicsClientId=c)


def test_plan_mesh_file_writes_json_and_zip(box, tmp_path):
    lifted = box.copy()
    lifted.apply_translation([0.0, 0.0, 0.05])  # the file's mesh floats; on_table sets it down
    src = tmp_path / "box.obj"
    lifted.export(src)
    grasps = X.plan_mesh_file(src, tmp_path / "grasps.json", n_grasps=2, budget_seconds=3.0)
    doc = X.grasps_from_json((tmp_path / "grasps.json").read_text())
    assert len(doc.grasps) == len(grasps) <= 2
    np.testing.assert_allclose(np.array(doc.meta["T_world_mesh"])[:3, 3], [0.0, 0.0, -0.05], atol=1e-9)
    X.plan_mesh_file(src, tmp_path / "scene.zip", n_grasps=1, budget_seconds=2.0)
    with zipfile.ZipFile(tmp_path / "scene.zip") as z:
        assert "grasps.json" in z.namelist()
