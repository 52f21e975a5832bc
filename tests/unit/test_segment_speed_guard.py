"""The fast flying-pixel test of organized clouds gives the slow one's answer; the speed comparison's plumbing."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from benchmarks import compare
from shapeviewer.perception.capture import load_capture
from shapeviewer.perception.segment import _flying_pixels_organized, flying_pixels, segment_scene

CAPTURES = sorted((Path(__file__).resolve().parents[2] / "static_assets" / "captures").glob("*.pcd"))


def _organized_surface(seed: int, *, h: int = 60, w: int = 80, quantum: float = 0.0) -> np.ndarray:
    """(h, w, 3) camera-frame points (m) of a tilted, bumpy surface 0.7-0.9 m away, as a depth camera
    sees it (depth rounded to ``quantum`` m when given), with a silhouette's flying pixels trailing
    away behind its right edge and a few missing pixels."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:h, 0:w].astype(float)
    z = 0.7 + 0.002 * v + 0.01 * np.sin(u / 7.0) + rng.normal(0, 0.0005, (h, w))
    trail = u > w - 6  # the last columns: pixels that fly off towards the background
    z[trail] += rng.uniform(0.02, 0.3, trail.sum())
    if quantum:
        z = np.round(z / quantum) * quantum
    points = np.stack([(u - w / 2) * z / 525.0, (v - h / 2) * z / 525.0, z], -1)
    points[rng.random((h, w)) < 0.03] = np.nan
    return points


def _cluster(points_hw3: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The finite points of an organized cloud with their pixel rows and columns."""
    flat = points_hw3.reshape(-1, 3)
    pixels = np.flatnonzero(np.isfinite(flat).all(axis=1))
    rows, cols = np.divmod(pixels, points_hw3.shape[1])
    return flat[pixels], rows, cols


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("quantum", [0.0, 0.001])
def test_the_organized_flying_pixel_test_is_the_kd_tree_one(seed: int, quantum: float) -> None:
    points, rows, cols = _cluster(_organized_surface(seed, quantum=quantum))
    expected = flying_pixels(points)
    assert 10 < expected.sum() < len(points) // 2  # the trail is found, the surface is not
    assert np.array_equal(_flying_pixels_organized(points, rows, cols), expected)


def test_the_organized_test_agrees_where_the_image_settles_nothing() -> None:
    # Pixels scattered over the image: no point has an image neighbour, every answer comes from the tree.
    rng = np.random.default_rng(3)
    points = rng.normal(0, 0.01, (500, 3)) + [0, 0, 0.8]
    pixels = rng.choice(640 * 480 // 4, 500, replace=False) * 2  # even pixels only: never adjacent in a row
    rows, cols = np.divmod(pixels, 640)
    rows = rows * 2  # and never in adjacent rows
    assert np.array_equal(_flying_pixels_organized(points, rows, cols), flying_pixels(points))
    # Repeated points (a spacing of 0) and too few points: nothing is flying, as in flying_pixels.
    same = np.repeat(points[:3], 4, axis=0)
    assert not _flying_pixels_organized(same, np.arange(12) // 4, np.arange(12) % 4).any()
    assert not _flying_pixels_organized(points[:5], np.zeros(5, int), np.arange(5)).any()


def test_the_organized_test_agrees_when_the_nearest_point_is_no_image_neighbour() -> None:
    # A second layer 0.2 mm behind the surface, stored in other pixels: the image's bounds are all wrong.
    points, rows, cols = _cluster(_organized_surface(7))
    behind = points + [0.0, 0.0, 0.0002]
    both = np.concatenate([points, behind])
    assert np.array_equal(
        _flying_pixels_organized(both, np.concatenate([rows, rows + 100]), np.concatenate([cols, cols])),
        flying_pixels(both),
    )


@pytest.mark.parametrize("path", CAPTURES, ids=[p.name for p in CAPTURES])
def test_segments_of_a_real_capture_are_those_of_the_slow_way(path: Path) -> None:
    capture = load_capture(path)
    assert capture.organized
    fast = segment_scene(capture)
    # The same points without their image layout take the KD-tree-only path (flying_pixels).
    slow = segment_scene(np.asarray(capture.points_cam).reshape(-1, 3))
    assert [s.label for s in fast.segments] == [s.label for s in slow.segments]
    assert all(np.array_equal(a.indices, b.indices) for a, b in zip(fast.segments, slow.segments))
    # Clusters beyond the workspace are skipped before their flying pixels are sought: the same segments
    # as keeping every segment and dropping the far ones afterwards.
    everything = segment_scene(capture, object_range=None)
    near = [s for s in everything.segments if np.linalg.norm(s.centroid) <= 1.5]
    assert sorted(len(s.indices) for s in near) == sorted(len(s.indices) for s in fast.segments)
    if path.name.startswith("milk"):  # its chair legs and background lie 1.5-2.3 m away
        assert len(near) < len(everything.segments)


def test_compare_reports_a_stage_a_revision_lacks_as_n_a(tmp_path: Path) -> None:
    # A revision of the old flat layout that has segment_scene but no robust_grasps (nor sim/).
    old = tmp_path / "old"
    (old / "shapeviewer").mkdir(parents=True)
    (old / "shapeviewer" / "__init__.py").write_text('"""An old revision."""\n')
    (old / "shapeviewer" / "segment.py").write_text("def segment_scene(points):\n    return None\n")
    seconds, note = compare.measure_once("pick", old, tmp_path, 1)
    assert seconds is None and note == "this revision has no robust_grasps"
    # Its load_capture is missing too: the segmentation stage is n/a there, not taken from another tree.
    seconds, note = compare.measure_once("segmentation", old, tmp_path, 1)
    assert seconds is None and note == "this revision has no load_capture"
    figures: dict[str, dict[str, Any]] = {
        "segmentation": {"median_rev": 0.05, "median_tree": 0.04, "ratio": 0.8, "notes": {"rev": "", "tree": ""}},
        "pick": {"median_rev": None, "median_tree": 12.5, "ratio": None, "notes": {"rev": note, "tree": ""}},
    }
    text = compare.table("e1fa60f", figures)
    assert "| segmentation (640x480 cloud) | 0.050 s | 0.040 s | 0.80 |" in text
    assert "| the pick, one object | n/a | 12.500 s | n/a |" in text
    assert f"- the pick, one object, e1fa60f: {note}" in text
