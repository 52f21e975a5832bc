"""The captures the speed benchmarks run on (``pipeline.py``, ``detailed.py``): generated default
scenes and the organized real captures in ../shared/data/real (Kinect-style, 640x480)."""

from __future__ import annotations

import sys
from pathlib import Path

REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "real"
ORGANIZED_REAL = (
    "milk_cartoon_all_small_clorox.pcd",
    "table_scene_mug_stereo_textured.pcd",
    "frame_20121214T142255.814212.pcd",
)


def load_captures(seeds: list[int]) -> list:
    """The default scenes of ``seeds`` (:func:`~shapeviewer.sim.demo_scene.default_scene`), then the
    organized real captures found in :data:`REAL` (a missing one is skipped with a note on stderr)."""
    from shapeviewer.perception.capture import load_capture
    from shapeviewer.sim.demo_scene import default_scene

    caps = [default_scene(s) for s in seeds]
    for name in ORGANIZED_REAL:
        if (REAL / name).exists():
            caps.append(load_capture(REAL / name))
        else:
            print(f"(skipping {name}: not found in {REAL})", file=sys.stderr)
    return caps
