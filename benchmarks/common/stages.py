"""One speed measurement of one stage, on whichever ``shapeviewer`` is first on ``PYTHONPATH``.

    PYTHONPATH=TREE python benchmarks/common/stages.py STAGE --captures DIR [--runs 3]

Prints one JSON object: ``{"stage", "seconds", "runs", "module", "note"}`` (``seconds`` None with the
reason in ``note`` when the revision lacks the stage). :mod:`benchmarks.compare` runs this file in a fresh
process per measurement, once with the working tree and once with an older revision on ``PYTHONPATH``, so
each stage is measured by this one piece of code for both. It uses only the public API that every
revision has (``load_capture``, ``segment_scene``, ``load_completer``, ``partial_to_grid``,
``context_grids``, ``complete``, ``fast_mesh``, ``detailed_mesh``, ``plan_grasps``, ``robust_grasps``),
found on the package (``shapeviewer.NAME``) or, for an older flat layout without those exports, in the
flat module that defined it; it imports nothing else from this repository.

Stages (seconds; setup and a warm-up run are never timed):

* ``segmentation``: ``segment_scene`` of a 640x480 cloud: the mean over the organized captures in DIR and
  the generated default scene (seed 0) of each one's median over ``--runs``;
* ``cnn``: the network's passes for one segment as the app runs them (the 8 sample passes with the
  context channels where the completer has ``predict_samples``, else one ``predict``);
* ``fast_mesh``: click -> fast mesh: voxelize + CNN + marching cubes of one segment (``complete(...,
  mode="fast")``, else ``complete_points``);
* ``detailed_mesh``: the detailed mesh end to end (``complete(..., mode="detailed")``, else
  ``complete_points`` + ``detailed_mesh``);
* ``grasp``: 20 Barrett grasps planned (``plan_grasps``) on the segment's fast mesh in the table frame;
* ``pick``: the app's pick for one object (``robust_grasps``, its defaults, 20 Barrett grasps).

"One segment" is the largest segment of the first organized capture in DIR (the same object in every
revision), with the support plane its segmentation found.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import statistics
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "2")

STAGES = ("segmentation", "cnn", "fast_mesh", "detailed_mesh", "grasp", "pick")
# Where a revision without the package-level exports defined each function (its flat layout).
FLAT: dict[str, tuple[str, ...]] = {
    "load_capture": ("capture", "perception.capture"),
    "segment_scene": ("segment", "perception.segment"),
    "load_completer": ("model", "completion.model"),
    "partial_to_grid": ("voxel", "completion.voxel"),
    "context_grids": ("voxel", "completion.voxel"),
    "complete_points": ("pipeline", "completion.pipeline"),
    "fast_mesh": ("reconstruct", "completion.reconstruct"),
    "detailed_mesh": ("reconstruct", "completion.reconstruct"),
    "plan_grasps": ("grasp.plan",),
    "default_scene": ("sim.demo_scene", "scene"),
}


class Missing(Exception):
    """The revision has no such function: the stage is not available there."""


def api(name: str) -> Any:
    """``shapeviewer.NAME`` where the package exports it, else NAME from the module that defined it."""
    import shapeviewer

    try:
        return getattr(shapeviewer, name)
    except AttributeError:
        pass
    home = Path(shapeviewer.__file__).resolve().parent
    for module in FLAT.get(name, ()):
        if not (home / (module.replace(".", "/") + ".py")).is_file():
            # An editable install's import hook would find a module this tree lacks in another tree.
            continue
        found = importlib.import_module(f"shapeviewer.{module}")
        if hasattr(found, name):
            return getattr(found, name)
    raise Missing(f"this revision has no {name}")


def captures(folder: Path) -> list[Any]:
    """The organized captures in ``folder`` (sorted by name), then the default generated scene."""
    load_capture = api("load_capture")
    found = [c for c in (load_capture(p) for p in sorted(folder.glob("*.pcd"))) if c.organized]
    if not found:
        raise SystemExit(f"no organized .pcd captures in {folder}")
    return [*found, api("default_scene")(0)]


def timed(call: Callable[[], Any], runs: int) -> float:
    """Median wall-clock seconds of ``runs`` calls."""
    seconds = []
    for _ in range(runs):
        t0 = time.perf_counter()
        call()
        seconds.append(time.perf_counter() - t0)
    return statistics.median(seconds)


def one_segment(folder: Path) -> tuple[Any, Any]:
    """``(points_cam (N, 3), segmentation)`` of the largest segment of the first organized capture."""
    load_capture = api("load_capture")
    first = next(c for c in (load_capture(p) for p in sorted(folder.glob("*.pcd"))) if c.organized)
    segmentation = api("segment_scene")(first)
    if not segmentation.segments:
        raise SystemExit(f"{first.source}: no segment")
    largest = max(segmentation.segments, key=lambda s: len(s.points_cam))
    return largest.points_cam, segmentation


def fast_completion(points: Any, plane: Any, completer: Any) -> Any:
    """The app's fast mesh of one segment (camera frame)."""
    try:
        complete = api("complete")
    except Missing:
        return api("complete_points")([points], completer)[0].fast_mesh
    return complete(points, support_plane=plane, mode="fast", completer=completer)


def detailed_completion(points: Any, plane: Any, completer: Any) -> Any:
    """The detailed mesh of one segment end to end (camera frame)."""
    try:
        complete = api("complete")
    except Missing:
        c = api("complete_points")([points], completer)[0]
        return api("detailed_mesh")(c.probabilities, c.frame, points)
    return complete(points, support_plane=plane, mode="detailed", completer=completer)


def network_passes(points: Any, plane: Any, completer: Any) -> Callable[[], Any]:
    """A call that runs the network's passes for one segment as the app does."""
    grid, frame = api("partial_to_grid")(points)
    if not hasattr(completer, "predict_samples"):
        return lambda: completer.predict(grid[None])
    context = None
    if getattr(completer, "in_channels", 1) > 1:
        context = api("context_grids")(points, frame, support_plane=plane)[None]
    return lambda: completer.predict_samples(grid[None], context=context)


def measure(stage: str, folder: Path, runs: int) -> float:
    """Seconds of one ``stage`` (see the module docstring)."""
    if stage == "segmentation":
        segment_scene = api("segment_scene")
        per_capture = []
        for capture in captures(folder):
            segment_scene(capture)  # warm-up: imports and caches
            per_capture.append(timed(partial(segment_scene, capture), runs))
        return statistics.fmean(per_capture)
    robust_grasps = api("robust_grasps") if stage == "pick" else None  # n/a before any loading
    points, segmentation = one_segment(folder)
    plane = segmentation.plane_cam
    completer = api("load_completer")()
    mesh = fast_completion(points, plane, completer)  # warm-up: the first torch call
    if stage == "cnn":
        passes = network_passes(points, plane, completer)
        passes()
        return timed(passes, runs)
    if stage == "fast_mesh":
        return timed(lambda: fast_completion(points, plane, completer), runs)
    if stage == "detailed_mesh":
        return timed(lambda: detailed_completion(points, plane, completer), runs)
    if stage == "grasp":
        plan_grasps = api("plan_grasps")
        mesh_world = mesh.copy().apply_transform(segmentation.T_world_cam)
        return timed(lambda: plan_grasps(mesh_world, hand="barrett", n_grasps=20, seed=0), runs)
    if robust_grasps is not None:
        return timed(lambda: robust_grasps(points, support_plane=plane, hand="barrett", n_grasps=20), runs)
    raise SystemExit(f"unknown stage {stage!r}; one of {', '.join(STAGES)}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stage", choices=STAGES)
    ap.add_argument("--captures", type=Path, required=True, help="folder of .pcd captures")
    ap.add_argument("--runs", type=int, default=3, help="timed calls per measurement (median)")
    args = ap.parse_args(argv)
    import shapeviewer

    result: dict[str, Any] = {"stage": args.stage, "runs": args.runs, "module": shapeviewer.__file__, "note": ""}
    try:
        result["seconds"] = measure(args.stage, args.captures, max(1, args.runs))
    except Missing as e:
        result["seconds"], result["note"] = None, str(e)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
