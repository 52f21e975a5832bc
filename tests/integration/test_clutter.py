"""The clutter-removal benchmark: seeded scenes, the execution protocol, the side view, rounds and the summary."""

import json
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from shapeviewer.cli.commands import main
from shapeviewer.clutter import run as R
from shapeviewer.clutter.execute import GraspPose, execute_grasp, palm_to_tcp
from shapeviewer.clutter.methods import WorldInfo, depth_scale, highest
from shapeviewer.clutter.scene import (
    MAX_OPENING,
    TABLE_Z,
    ClutterError,
    ClutterWorld,
    ObjectSet,
    Setup,
    generate_scene,
)
from shapeviewer.clutter.sensor import capture_view, dex_noise
from shapeviewer.perception.segment import segment_scene

CLUTTER_DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "clutter"


def _write_object(folder: Path, name: str, mesh: trimesh.Trimesh, mass: float = 0.1) -> None:
    mesh.export(folder / f"{name}_visual.obj")
    mesh.export(folder / f"{name}_collision.obj")
    (folder / f"{name}.urdf").write_text(
        f"""<?xml version="1.0"?>
<robot name="{name}">
  <link name="base_link">
    <contact><lateral_friction value="1.0"/></contact>
    <inertial><mass value="{mass}"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>
    <visual><geometry><mesh filename="{name}_visual.obj"/></geometry></visual>
    <collision><geometry><mesh filename="{name}_collision.obj"/></geometry></collision>
  </link>
</robot>
"""
    )


@pytest.fixture(scope="module")
def objects_dir(tmp_path_factory) -> Path:
    """A small object set: a box and a cylinder, each narrower than the Panda's opening."""
    folder = tmp_path_factory.mktemp("objects")
    _write_object(folder, "box", trimesh.creation.box(extents=(0.05, 0.04, 0.08)))
    _write_object(folder, "can", trimesh.creation.cylinder(radius=0.025, height=0.07, sections=24))
    return folder


@pytest.fixture(scope="session")
def clutter_data() -> Path:
    """The VGN/GIGA object sets in ../shared/data/clutter (never copied into the repo)."""
    if not (CLUTTER_DATA / "packed" / "train").is_dir():
        pytest.skip(f"clutter object sets not found at {CLUTTER_DATA}")
    return CLUTTER_DATA


def _box_world(objects_dir: Path) -> ClutterWorld:
    world = ClutterWorld()
    world.add_object(objects_dir / "box.urdf", (0.15, 0.15, TABLE_Z + 0.041), (0, 0, 0, 1), 1.0)
    world.settle()
    return world


def _top_down(x: float, y: float, palm_z: float) -> np.ndarray:
    """A palm pose approaching straight down, the fingers closing along world y."""
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [x, y, palm_z]
    return T


def test_scene_generator_is_seeded(objects_dir):
    objects = ObjectSet.load(objects_dir)

    def poses(seed):
        with ClutterWorld() as world:
            generate_scene(world, "packed", objects, 3, np.random.default_rng(seed))
            return world.object_poses()

    a, b, c = poses([7, 0]), poses([7, 0]), poses([8, 0])
    assert len(a) >= 1
    assert [o["name"] for o in a] == [o["name"] for o in b]
    np.testing.assert_allclose([o["position"] for o in a], [o["position"] for o in b], atol=1e-9)
    assert [o["position"] for o in a] != [o["position"] for o in c]
    # Packed objects stand on the table inside the workspace.
    for o in a:
        assert 0.0 < o["position"][0] < 0.3 and 0.0 < o["position"][1] < 0.3 and o["position"][2] > TABLE_Z


def test_pile_scene_drops_objects_on_the_table(objects_dir):
    with ClutterWorld() as world:
        generate_scene(world, "pile", ObjectSet.load(objects_dir), 3, np.random.default_rng(0))
        assert 1 <= world.num_objects <= 3
        for o in world.object_poses():
            assert TABLE_Z < o["position"][2] < TABLE_Z + 0.15  # settled, the box gone


def test_execution_lifts_a_box_it_is_placed_around(objects_dir):
    with _box_world(objects_dir) as world:
        # The box (4 cm along y, 8 cm tall, top at 0.13 m): fingertips 3 cm below its top.
        outcome = execute_grasp(world, GraspPose(_top_down(0.15, 0.15, TABLE_Z + 0.08 + 0.016)))
        assert outcome.kind == "success" and outcome.object == "box"
        assert 0.03 < outcome.width < 0.05
        assert world.num_objects == 0


def test_execution_closing_on_air_fails(objects_dir):
    with _box_world(objects_dir) as world:
        outcome = execute_grasp(world, GraspPose(_top_down(0.05, 0.05, TABLE_Z + 0.1)))
        assert outcome.kind == "closed_on_nothing"
        assert outcome.width < 0.1 * MAX_OPENING
        assert world.num_objects == 1


def test_execution_fails_when_the_pregrasp_collides(objects_dir):
    with _box_world(objects_dir) as world:
        # 5 cm back from this grasp the palm is inside the box.
        outcome = execute_grasp(world, GraspPose(_top_down(0.15, 0.15, TABLE_Z + 0.03)))
        assert outcome.kind == "pregrasp_contact"
        assert world.num_objects == 1


def test_side_view_and_highest_grasp_the_box(objects_dir):
    with _box_world(objects_dir) as world:
        capture, depth = capture_view(world, None)  # ideal depth
        assert depth.shape == (480, 640) and capture.points_cam.shape == (480, 640, 3)
        segmentation = segment_scene(capture)
        assert len(segmentation.segments) == 1
        info = WorldInfo(capture.T_world_cam)
        assert depth_scale(segmentation, info) == pytest.approx(1.0, abs=2e-3)
        # The table seen through the noise's Gamma factor is that much nearer or farther.
        noisy, noisy_depth = capture_view(world, np.random.default_rng(3))
        factor = float(np.median(noisy_depth[depth > 0] / depth[depth > 0]))
        assert depth_scale(segment_scene(noisy), info) == pytest.approx(factor, abs=0.005)
        grasps = highest(capture, segmentation, info)
        assert len(grasps) == 1
        tcp = palm_to_tcp(grasps[0].T_world_palm)
        assert np.linalg.norm(tcp[:2, 3] - [0.15, 0.15]) < 0.015  # over the box
        assert tcp[2, 2] == pytest.approx(-1.0)  # approaching straight down
        assert abs(tcp[:3, 1] @ [0.0, 1.0, 0.0]) > 0.95  # closing across the box's 4 cm side
        assert execute_grasp(world, grasps[0]).kind == "success"


def test_dex_noise_is_seeded_and_keeps_missing_pixels():
    depth = np.full((48, 64), 0.6, np.float32)
    depth[:10] = 0.0
    a, b = dex_noise(depth, np.random.default_rng(1)), dex_noise(depth, np.random.default_rng(1))
    np.testing.assert_array_equal(a, b)
    assert np.all(a[:10] == 0.0) and np.all(a[10:] > 0.5)
    assert 0.5 < float(a[10:].mean()) < 0.7


def test_packed_round_runs_to_its_end_and_the_summary_adds_up(objects_dir, tmp_path):
    lines: list[str] = []
    out = tmp_path / "out"
    summary = R.clear_table(out, scene="packed", objects=objects_dir, rounds=2, seeds=[0], count=3, report=lines.append)
    assert len(lines) == 2 and all("Highest seed 0 round" in line for line in lines)
    m = summary["methods"]["Highest"]
    records = [json.loads((out / "Highest" / "seed_0" / f"round_{r:03d}.json").read_text()) for r in range(2)]
    assert m["rounds"] == 2
    assert m["objects"] == sum(r["objects"] for r in records) >= 2
    failures = sum(v for k, v in m["failures"].items() if k != "no_grasp")
    assert m["attempts"] == m["successes"] + failures == sum(len(r["log"]) for r in records) - m["failures"]["no_grasp"]
    assert m["gsr"] == pytest.approx(100.0 * m["successes"] / m["attempts"])
    assert m["dr"] == pytest.approx(100.0 * m["successes"] / m["objects"])
    for r in records:  # every round ended for one of the protocol's reasons
        assert r["end"] in ("cleared", "failures", "no_grasp")
        assert (r["end"] == "cleared") == (r["left"] == 0)
        assert r["successes"] + r["left"] <= r["objects"]
        with np.load(out / "Highest" / "seed_0" / r["log"][0]["depth"]) as saved:
            assert saved["depth"].shape == (480, 640) and saved["T_world_cam"].shape == (4, 4)
    assert json.loads((out / "summary.json").read_text()) == summary
    assert summary["hand"] == "panda" and summary["scene"] == "packed" and summary["seeds"] == [0]

    # Resumable: finished rounds are read back, not run again.
    again: list[str] = []
    t0 = time.perf_counter()
    assert (
        R.clear_table(out, scene="packed", objects=objects_dir, rounds=2, seeds=[0], count=3, report=again.append)
        == summary
    )
    assert time.perf_counter() - t0 < 2.0 and all("done before" in line for line in again)


def test_a_method_past_its_time_ends_the_round(objects_dir, monkeypatch):
    def stubborn(capture, segmentation, info):
        time.sleep(5.0)  # never asks info.cancel()
        return highest(capture, segmentation, info)

    monkeypatch.setitem(R.METHODS, "Stubborn", stubborn)
    monkeypatch.setattr(R, "ATTEMPT_GRACE", 0.3)
    t0 = time.perf_counter()
    record = R.run_round(
        "packed", ObjectSet.load(objects_dir), "Stubborn", seed=0, round_index=0, count=2, attempt_seconds=0.5
    )
    assert time.perf_counter() - t0 < 4.5
    assert record["end"] == "no_grasp" and record["attempts"] == 0
    assert record["log"][0]["timed_out"] and record["log"][0]["outcome"] == "no_grasp"


def test_cli_clutter_writes_the_summary_and_refuses_a_bad_folder(objects_dir, tmp_path, capsys):
    out = tmp_path / "cli"
    assert (
        main(["clutter", "--scene", "packed", "--objects", str(objects_dir), "--rounds", "1", "--out", str(out)]) == 0
    )
    printed = capsys.readouterr().out
    assert "Highest seed 0 round 1/1" in printed and "GSR" in printed
    assert json.loads((out / "summary.json").read_text())["methods"]["Highest"]["rounds"] == 1

    missing = tmp_path / "nowhere"
    assert main(["clutter", "--scene", "pile", "--objects", str(missing), "--out", str(tmp_path / "x")]) == 2
    assert "not a folder" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()  # the failed command leaves no empty folder
    assert (
        main(["clutter", "--scene", "pile", "--objects", str(objects_dir), "--methods", "Nope", "--out", str(out)]) == 2
    )
    assert "unknown clutter method 'Nope'" in capsys.readouterr().err


def test_object_set_must_hold_urdfs(tmp_path):
    with pytest.raises(ClutterError, match="no .urdf"):
        ObjectSet.load(tmp_path)


def test_real_object_sets_run_a_round(clutter_data):
    for scene in ("packed", "pile"):
        record = R.run_round(
            scene,
            ObjectSet.load(clutter_data / scene / "train"),
            "Highest",
            seed=0,
            round_index=0,
            setup=Setup.load(clutter_data / "setup"),
        )
        assert record["objects"] >= 1 and record["end"] in ("cleared", "failures", "no_grasp")
        assert record["attempts"] >= 1
