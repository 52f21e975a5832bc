"""Grasp planning, execution and lift-test speed on this machine (targets, on 2 CPU cores:
20 grasps planned on a completed object <= 10 s; kinematic execution <= 50 ms per grasp; lift test
<= 0.5 s per grasp; GraspIt's simulated annealing took 70,000 steps per object).

The "completed object" is what a perfect CNN would give: the true mesh's 40^3 occupancy (the
paper's ground truth) meshed by marching cubes like the pipeline's fast mesh. Its grasps are then
executed on the true mesh. The V-HACD cache is a fresh temporary directory, so planning pays for
the decomposition of each new completion as the app would; the true mesh's decomposition, shared
by every method's grasps of an object, is made before execution is timed.

    python benchmarks/grasp.py [--objects ycb/006_mustard_bottle ...] [--hand barrett] [--grasps 20]
    python benchmarks/grasp.py --scene 0          # the viewer's case: the default scene's objects

With ``--scene SEED`` the objects are instead those of the viewer's default scene: each segment
that shows one true object is completed by the shipped CNN (its fast mesh, mapped to the world
frame with the scene's camera pose, exactly what the viewer's "Plan grasps" gives the planner),
and the grasps are executed on that true object as placed in the scene.

"check": seconds of the planner's lift check (its grasps lifted on the mesh planned on), "up": the
returned grasps that passed it; "lifted": the first ``--lifts`` executed grasps lifted, with a
shake, from the true object. Wall-clock times depend on what else runs; "cpu s" is the planning
process's own CPU time (its threads included, the V-HACD child process not), a load-independent
lower bound.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np
import trimesh

DEFAULT_OBJECTS = ("ycb/006_mustard_bottle", "ycb/025_mug", "ycb/004_sugar_box", "ycb/005_tomato_soup_can")


def completed(mesh_world: trimesh.Trimesh) -> trimesh.Trimesh:
    """A perfect-CNN completion of ``mesh_world`` (world frame): marching cubes of its 40^3 occupancy."""
    from shapeviewer.completion.reconstruct import fast_mesh
    from shapeviewer.completion.voxel import frame_for_points, solid_grid

    frame = frame_for_points(np.asarray(mesh_world.vertices))
    return fast_mesh(solid_grid(mesh_world, frame).astype(np.float32), frame)


Case = tuple[str, trimesh.Trimesh, trimesh.Trimesh]  # name, true mesh (world), mesh planned on (world)


def catalogue_cases(names: list[str]) -> list[Case]:
    """Each catalogue object standing on the table and its perfect-CNN completion (world frame)."""
    from shapeviewer.sim.catalogue import load_mesh

    cases = []
    for name in names:
        truth = load_mesh(name)
        truth.apply_translation([0.0, 0.0, -truth.bounds[0, 2]])
        mesh = completed(truth)
        mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])
        cases.append((name, truth, mesh))
    return cases


def scene_cases(seed: int) -> list[Case]:
    """The default scene's objects as the viewer plans on them: per segment showing one true object,
    the CNN's fast mesh in the world frame (the scene's ``T_world_cam``), and that object's true mesh."""
    from shapeviewer.completion.model import load_completer
    from shapeviewer.completion.pipeline import complete_points
    from shapeviewer.perception.segment import segment_scene
    from shapeviewer.sim.demo_scene import default_scene
    from shapeviewer.viewer.grasps import ground_truth_object, object_mesh_world

    capture = default_scene(seed)
    segments = segment_scene(capture).segments
    done = complete_points([s.points_cam for s in segments], load_completer(), [s.id for s in segments])
    cases = []
    for seg, c in zip(segments, done):
        match = ground_truth_object(capture, seg)
        if match is None or c.fast_mesh is None:
            continue
        obj = capture.objects[match[0]]
        mesh = c.fast_mesh.copy()
        mesh.apply_transform(capture.T_world_cam)
        cases.append((f"seg {seg.id} {obj.name}", object_mesh_world(obj), mesh))
    return cases


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", nargs="+", default=list(DEFAULT_OBJECTS))
    ap.add_argument("--hand", default="barrett")
    ap.add_argument("--grasps", type=int, default=20)
    ap.add_argument("--lifts", type=int, default=5, help="lift tests per object (each with a shake)")
    ap.add_argument(
        "--scene",
        type=int,
        default=None,
        metavar="SEED",
        help="plan on the CNN completions of this default scene's objects instead of --objects",
    )
    args = ap.parse_args()
    cases = catalogue_cases(args.objects) if args.scene is None else scene_cases(args.scene)
    # Only now: the meshes and scene come from the usual cache, every V-HACD of a plan is new.
    os.environ["SHAPEVIEWER_CACHE"] = tempfile.mkdtemp(prefix="grasp-bench-")

    from shapeviewer.grasp.execute import execute_grasps
    from shapeviewer.grasp.lift import lift_test
    from shapeviewer.grasp.plan import plan
    from shapeviewer.grasp.samples import hand_samples
    from shapeviewer.grasp.world import convex_decomposition

    t = time.perf_counter()
    hand_samples(args.hand)
    print(f"hand samples ({args.hand}, once per process): {time.perf_counter() - t:.2f} s")
    header = (
        f"{'object':28s} {'faces':>6s} {'plan s':>7s} {'cpu s':>6s} {'search':>7s} {'sim':>6s} {'evals':>6s}"
        f" {'evals/s':>8s} {'simul.':>6s} {'check':>6s} {'grasps':>6s} {'FC':>3s} {'up':>3s} {'exec ms':>8s}"
        f" {'joint deg':>9s} {'pose mm':>8s} {'lift s':>7s} {'lifted':>6s}"
    )
    print(header)
    rows = []
    for name, truth, mesh in cases:
        cpu = time.process_time()
        result = plan(mesh, hand=args.hand, n_grasps=args.grasps, seed=0)
        cpu = time.process_time() - cpu
        s = result.stats
        grasps = result.grasps
        convex_decomposition(truth)  # once per object, shared by every method's grasps
        t = time.perf_counter()
        executed = execute_grasps(grasps, truth)
        exec_ms = 1000 * (time.perf_counter() - t) / max(len(grasps), 1)
        lifts, lift_times = [], []
        for e in executed[: args.lifts]:
            t = time.perf_counter()
            lifts.append(lift_test(e, truth, shake=True).success)
            lift_times.append(time.perf_counter() - t)
        row = dict(
            plan=s.seconds["total"],
            cpu=cpu,
            rate=s.evaluations_per_second,
            exec_ms=exec_ms,
            lift=float(np.mean(lift_times)) if lift_times else float("nan"),
        )
        rows.append(row)
        print(
            f"{name:28s} {len(mesh.faces):6d} {s.seconds['total']:7.2f} {cpu:6.2f} {s.seconds['search']:7.2f}"
            f" {s.seconds['simulate']:6.2f} {s.evaluations:6d} {s.evaluations_per_second:8.0f} {s.simulated:6d}"
            f" {s.seconds.get('lift', 0.0):6.2f} {len(grasps):6d} {sum(g.force_closure for g in grasps):3d}"
            f" {sum(g.lifted for g in grasps):3d} {exec_ms:8.1f}"
            f" {np.mean([e.joint_error for e in executed]):9.2f} {np.mean([e.pose_error for e in executed]):8.2f}"
            f" {row['lift']:7.3f} {sum(lifts):3d}/{len(lifts):<2d}"
        )
    print(
        f"\n{'median':28s} plan {np.median([r['plan'] for r in rows]):.2f} s (target 10;"
        f" {np.median([r['cpu'] for r in rows]):.2f} s of this process's CPU time),"
        f" {np.median([r['rate'] for r in rows]):.0f} evaluations/s,"
        f" execution {np.median([r['exec_ms'] for r in rows]):.1f} ms (target 50),"
        f" lift {np.median([r['lift'] for r in rows]):.3f} s (target 0.5)"
    )


if __name__ == "__main__":
    main()
