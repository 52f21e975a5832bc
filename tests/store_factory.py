"""Small results folders for the store and Dataset-tab tests, written in milliseconds.

The folders have the layout ``shapeviewer evaluate`` writes (view records from
:func:`records.view_record`, meshes as PLY in the camera frame, grasp files from
:func:`grasp.serialize.grasps_to_json` with the evaluation world frame in their meta), but the shapes
are boxes and the metrics are made-up numbers: the store indexes and shows results, it does not
judge them.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import trimesh

from shapeviewer.evaluation import records as rec
from shapeviewer.evaluation.records import METHODS, METRICS, view_stem
from shapeviewer.evaluation.run import T_WORLD_CAM
from shapeviewer.sim import catalogue
from shapeviewer.training.generate import view_pose

# (object, view): two views of one object, one of a holdout model, one of a pybullet object.
VIEWS = (("ycb/025_mug", 3), ("ycb/025_mug", 40), ("ycb/006_mustard_bottle", 7), ("pybullet/duck", 11))
SCALES = {
    "Partial": (1.0, 1.0, 0.45),
    "Mirror": (1.1, 1.05, 1.0),
    "Hull": (1.0, 1.0, 0.6),
    "Ours-fast": (0.95, 0.97, 1.02),
    "Ours-detailed": (1.0, 0.98, 0.99),
}


def jaccard_of(name: str, view: int, method: str) -> float:
    """The made-up Jaccard of a view and method (distinct per object, ordered Partial < ... < Ours)."""
    rank = METHODS.index(method)
    return round(0.15 + 0.18 * rank + 0.01 * (view % 7) + 0.05 * (len(name) % 3), 4)


def truth_cam(name: str, view: int) -> trimesh.Trimesh:
    """A box of the object's catalogue size, posed in the view's camera frame."""
    box = trimesh.creation.box(extents=catalogue.entry(name).extents)
    box.apply_transform(view_pose(name, view, 0))
    return box


def visible_points(mesh_cam: trimesh.Trimesh, n: int = 600, seed: int = 0) -> np.ndarray:
    """Surface points whose face looks at the camera (camera frame, origin = sensor)."""
    pts, faces = trimesh.sample.sample_surface_even(mesh_cam, n, seed=seed)
    facing = np.einsum("ij,ij->i", mesh_cam.face_normals[faces], -pts) > 0
    return np.asarray(pts[facing])


def grasp_doc(completion_cam: trimesh.Trimesh, n: int = 2) -> str:
    """A grasps file: ``n`` Barrett grasps above the completion (evaluation world frame) and their executions."""
    from shapeviewer.grasp.execute import ExecutionResult
    from shapeviewer.grasp.hands import get_hand
    from shapeviewer.grasp.plan import Grasp
    from shapeviewer.grasp.serialize import grasps_to_json
    from shapeviewer.grasp.state import LiftResult

    hand = get_hand("barrett")
    world = completion_cam.copy()
    world.apply_transform(T_WORLD_CAM)
    top = world.bounds[1]
    grasps, executions = [], []
    for k in range(n):
        T = np.eye(4)
        T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # approach (+z of the palm) points down
        T[:3, 3] = [world.centroid[0] + 0.01 * k, world.centroid[1], top[2] + 0.02]
        dofs = {d: 0.5 for d in hand.dof_names}
        joints = {j: 0.4 + 0.1 * k for j in hand.joint_names}
        grasps.append(Grasp("barrett", T, dofs, joints, (), 0.02 * (k + 1), 0.1, -0.01))
        Te = T.copy()
        Te[:3, 3] += [0.0, 0.0, -0.005]
        executions.append(
            ExecutionResult(
                "barrett",
                Te,
                dofs,
                {j: v + 0.05 for j, v in joints.items()},
                (),
                0.01,
                0.05,
                2.9,
                5.0,
                True,
                True,
                LiftResult(k == 0, 0.1, 0.0),
            )
        )
    return grasps_to_json(grasps, executions, meta={"T_world_cam": T_WORLD_CAM.tolist()})


def write_view(
    root: Path,
    name: str,
    view: int,
    old_format: bool = False,
    failed: tuple[str, ...] = (),
    grasp_methods: tuple[str, ...] = (),
) -> dict:
    """Write one view's meshes, grasps and record; returns the record (the rows as written)."""
    stem = view_stem(name, view)
    meshes = root / "meshes"
    meshes.mkdir(parents=True, exist_ok=True)
    truth = truth_cam(name, view)
    truth.export(meshes / f"{stem}__truth.ply")
    trimesh.PointCloud(visible_points(truth)).export(meshes / f"{stem}__points.ply")
    view_set = catalogue.view_split(name, view)
    rows = []
    for m in METHODS:
        row = {"object": name, "view": view, "view_set": view_set, "method": m}
        if m in failed:
            row.update({k: math.nan for k in METRICS}, seconds=math.nan, error="ValueError: too few points")
        else:
            mesh = truth.copy()
            T_obj_cam = np.linalg.inv(view_pose(name, view, 0))
            mesh.apply_transform(view_pose(name, view, 0) @ np.diag([*SCALES[m], 1.0]) @ T_obj_cam)
            mesh.export(meshes / f"{stem}__{m}.ply")
            j = jaccard_of(name, view, m)
            row.update(
                jaccard=j,
                j80=j,
                hausdorff_mean_mm=20 * (1 - j),
                hausdorff_max_mm=60 * (1 - j),
                hausdorff_rms_mm=25 * (1 - j),
                geodesic=0.5 * (1 - j),
                seconds=0.1 * (1 + METHODS.index(m)),
                error="",
            )
        rows.append(row)
    if old_format:
        (root / "views").mkdir(parents=True, exist_ok=True)
        (root / "views" / f"{stem}.json").write_text(json.dumps(rows))
        return {"object": name, "view": view, "view_set": view_set, "rows": rows, "grasps": []}
    record = rec.view_record(root, name, view, view_set, 0, rows)
    for m in grasp_methods:
        rel = rec.grasp_file(stem, m)
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(grasp_doc(trimesh.load(meshes / f"{stem}__{m}.ply")))
        record["grasps"].append(
            {
                "method": m,
                "hand": "barrett",
                "file": rel,
                "n": 2,
                "joint_error_deg": 2.9,
                "pose_error_mm": 5.0,
                "epsilon_planned": 0.03,
                "volume_planned": 0.1,
                "epsilon_executed": 0.01,
                "volume_executed": 0.05,
                "force_closure_planned": 1.0,
                "force_closure_executed": 1.0,
                "start_clear": 1.0,
                "lift_success": 0.5,
                "lift_success_best": 1.0,
                "n_requested": 2,
                "plan_seed": 1,
                "seconds_plan": 1.5,
                "seconds_execute": 0.2,
                "frame": "evaluation_world",
                "error": "",
            }
        )
    rec.save_view(root, record)
    return record


def make_store(root: Path) -> dict[tuple[str, int], dict]:
    """The test folder: :data:`VIEWS`, the second one in the first (bare list) format, Mirror failed
    on the mustard bottle, grasps on Ours-fast and Partial of the first mug view."""
    out = {}
    for i, (name, view) in enumerate(VIEWS):
        out[(name, view)] = write_view(
            root,
            name,
            view,
            old_format=(i == 1),
            failed=("Mirror",) if name == "ycb/006_mustard_bottle" else (),
            grasp_methods=("Ours-fast", "Partial") if i == 0 else (),
        )
    return out
