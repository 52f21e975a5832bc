"""Speed of the detailed mesh (Algorithm 1) on tabletop captures, step by step.

    python benchmarks/detailed.py [--seeds 0 1 2] [--repeats 3] [--weights PATH] [--close]

Inputs: the generated default scenes of ``--seeds`` (Kinect model, 640x480, objects about 0.8-1.1 m
from the camera) and the organized real captures in ../shared/data/real; with ``--close``, also YCB
objects on a table seen from 0.35 and 0.6 m by a 1280x720 RealSense-like camera (fx 910 px): clouds
of 20k-330k points, up to 9 times denser than a Kinect's at 1 m.

For every segment that can be completed: voxelize + CNN (:func:`pipeline.complete_points`: the 8
mirrored passes whose mean is the output), then :func:`pipeline.completion_detailed_mesh`
``--repeats`` times (median per segment). End to end = voxelize + CNN + Algorithm 1, what the
viewer's "Detailed mesh" button costs on a segment not yet completed.
Printed: medians over segments of each step of Algorithm 1 and of the total, with the segment's
distance from the camera.

The paper (CUDA solver, Titan X): 2.136 s per detailed completion. Targets on 2 CPU cores:
detailed mesh <= 1.0 s end to end, the smoothing solver <= 0.5 s.

To time another revision, run its copy from a ``git worktree`` with ``PYTHONPATH=<worktree>`` (e.g.
``PYTHONPATH=../old python ../old/benchmarks/detailed.py``), so that shapeviewer is imported from the
worktree rather than from the installed checkout.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "2")
import shapeviewer  # noqa: E402,F401  (sets OMP_WAIT_POLICY before torch loads)

from common.captures import load_captures  # noqa: E402  (benchmarks/common/captures.py)

STEPS = (
    ("density", "density ratio"),
    ("upsample", "up-sample CNN output"),
    ("merge", "merge + carve"),
    ("fill_gaps", "fill gaps along z"),
    ("smooth", "smoothing solver"),
    ("marching_cubes", "marching cubes"),
)
TARGET = {"smooth": 0.5, "total": 1.0}
PAPER_SECONDS = 2.136


CLOSE_OBJECTS = ("ycb/003_cracker_box", "ycb/005_tomato_soup_can", "ycb/019_pitcher_base", "ycb/025_mug")
CLOSE_DISTANCES = (0.35, 0.6)  # m from the camera to the object's middle


def close_segments():
    """``(label, points_cam, support_plane)`` of each of :data:`CLOSE_OBJECTS` standing on a table,
    seen from 45 degrees at each of :data:`CLOSE_DISTANCES` by a 1280x720 camera with the RealSense
    noise model: the object's pixels only (camera frame, metres), the table's plane exact."""
    import numpy as np

    from shapeviewer.perception.camera import Intrinsics, backproject_valid, look_at
    from shapeviewer.sim import catalogue
    from shapeviewer.sim.sensor import RaycastRenderer, RealSenseNoise

    intr = Intrinsics(1280, 720, 910.0, 910.0, 640.0, 360.0)
    for name in CLOSE_OBJECTS:
        mesh = catalogue.centred_mesh(name)
        mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])  # standing on the table z = 0
        for distance in CLOSE_DISTANCES:
            eye = np.array([distance * 0.7, 0.1, distance * 0.7])
            T_world_cam = look_at(eye, [0.0, 0.0, mesh.bounds[1, 2] / 2])
            depth, _ = RaycastRenderer([mesh]).render(intr, T_world_cam)
            points = backproject_valid(RealSenseNoise().apply(depth, 0), intr)
            T_cam_world = np.linalg.inv(T_world_cam)
            normal, origin = T_cam_world[:3, 2], T_cam_world[:3, 3]
            yield f"{name} at {distance} m", points, np.r_[normal, -normal @ origin]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="default-scene seeds")
    ap.add_argument("--repeats", type=int, default=3, help="detailed meshes per segment")
    ap.add_argument("--weights", default=None, help="CNN weights (default: the shipped model)")
    ap.add_argument("--close", action="store_true", help="also dense clouds of objects 0.35-0.6 m away")
    args = ap.parse_args(argv)

    from shapeviewer.completion.model import load_completer
    from shapeviewer.completion.pipeline import (
        SegmentTooSmallError,
        check_segment,
        complete_points,
        completion_detailed_mesh,
    )
    from shapeviewer.perception.segment import segment_scene

    completer = load_completer(args.weights)
    rows: dict[str, list[float]] = {k: [] for k, _ in STEPS} | {"cnn": [], "algorithm_1": [], "total": []}
    ratios, distances = [], []
    warm = False

    def segments():
        for cap in load_captures(args.seeds):
            for seg in segment_scene(cap).segments:
                yield f"{cap.source} segment {seg.id}", seg.points_cam, None
        if args.close:
            yield from close_segments()

    for label, points, plane in segments():
        try:
            points = check_segment(points)
        except SegmentTooSmallError:
            continue
        t0 = time.perf_counter()
        c = complete_points([points], completer, support_plane=plane)[0]
        cnn = time.perf_counter() - t0
        if c.fast_mesh is None:
            continue
        if not warm:  # the first torch call of the solver pays one-off set-up costs
            completion_detailed_mesh(c, points)
            warm = True
        runs = []
        for _ in range(args.repeats):
            steps: dict = {}
            t0 = time.perf_counter()
            completion_detailed_mesh(c, points, timings=steps)
            runs.append((time.perf_counter() - t0, steps))
        seconds, steps = sorted(runs, key=lambda r: r[0])[len(runs) // 2]
        for key, _ in STEPS:
            rows[key].append(steps[key])
        rows["cnn"].append(cnn)
        rows["algorithm_1"].append(seconds)
        rows["total"].append(cnn + seconds)
        ratios.append(steps["upsample_ratio"])
        distances.append(float(statistics.median(points[:, 2])))
        print(
            f"{label}: {len(points)} points at {distances[-1]:.2f} m, r = {ratios[-1]}, Algorithm 1 {seconds:.3f} s",
            file=sys.stderr,
        )

    print(
        f"\nSegments: {len(ratios)} (distance from camera {min(distances):.2f}-{max(distances):.2f} m, "
        f"median {statistics.median(distances):.2f} m; up-sampling ratio r: "
        f"{', '.join(f'{r}: {ratios.count(r)}' for r in sorted(set(ratios)))})"
    )
    print(f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}; load average {os.getloadavg()[0]:.1f}\n")
    print(f"| {'step':34s} | {'median':>9s} | {'target':>10s} |")
    print(f"|{'-' * 36}|{'-' * 11}|{'-' * 12}|")
    ok = True
    table = (
        [("voxelize + CNN", "cnn")]
        + [(f"  {label}", key) for key, label in STEPS]
        + [("8 passes + Algorithm 1 (sum)", "algorithm_1"), ("**end to end**", "total")]
    )
    for label, key in table:
        med = statistics.median(rows[key])
        target = ""
        if key in TARGET:
            ok &= med <= TARGET[key]
            target = f"{'ok' if med <= TARGET[key] else 'MISSED'} {TARGET[key]:.1f} s"
        print(f"| {label:34s} | {med:7.3f} s | {target:>10s} |")
    print(f"\nThe paper: {PAPER_SECONDS} s per detailed completion (CUDA).")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
