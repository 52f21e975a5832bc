"""Random clouds through the runtime pipeline (segmentation -> voxelization -> CNN -> meshes): every
input either completes into closed meshes that cover the segment, or is refused with one of the
pipeline's own error types. Hypothesis draws the clouds (derandomized: the same cases on every run)."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shapeviewer.completion.model import load_completer
from shapeviewer.completion.pipeline import SegmentTooSmallError, check_segment, complete_points
from shapeviewer.completion.reconstruct import EmptyCompletionError, detailed_mesh
from shapeviewer.perception.segment import SegmentationError, segment_scene

REFUSALS = (SegmentationError, SegmentTooSmallError, EmptyCompletionError)


@pytest.fixture(scope="module")
def completer():
    return load_completer()


@st.composite
def clouds(draw) -> np.ndarray:
    """(N, 3) camera-frame clouds, metres: a table seen from above with boxes and balls on it, pure
    noise, degenerate shapes, and any of them with NaN/inf rows, far outliers or a huge scale."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    # Tabletops (where completions happen) three times as often as each degenerate kind.
    kind = draw(st.sampled_from(["tabletop"] * 3 + ["noise", "line", "point", "plane_only", "tiny"]))
    if kind == "tabletop":
        # A 1 m table 0.8 m below the camera, tilted towards it, with 0-4 objects standing on it.
        table = np.c_[rng.uniform(-0.5, 0.5, (6000, 2)), np.zeros(6000)]
        parts = [table]
        for _ in range(draw(st.integers(0, 4))):
            size = rng.uniform(0.01, 0.25, 3)
            centre = np.r_[rng.uniform(-0.35, 0.35, 2), size[2] / 2]
            n = int(draw(st.integers(5, 3000)))
            if rng.random() < 0.5:
                pts = centre + (rng.random((n, 3)) - 0.5) * size
            else:
                d = rng.normal(size=(n, 3))
                pts = centre + size.min() / 2 * d / np.linalg.norm(d, axis=1, keepdims=True)
            parts.append(pts)
        world = np.concatenate(parts)
        tilt = np.deg2rad(draw(st.floats(20, 70)))
        R = np.array([[1, 0, 0], [0, -np.sin(tilt), -np.cos(tilt)], [0, np.cos(tilt), -np.sin(tilt)]])
        pts = world @ R.T + [0, 0, 0.9]
    elif kind == "noise":
        pts = rng.uniform(-1, 1, (draw(st.integers(0, 20000)), 3)) + [0, 0, 1.5]
    elif kind == "line":
        pts = np.outer(rng.uniform(0.5, 1.5, draw(st.integers(1, 3000))), [0.1, 0.2, 1.0])
    elif kind == "point":
        pts = np.tile([0.0, 0.0, 1.0], (draw(st.integers(1, 3000)), 1))
    elif kind == "plane_only":
        pts = np.c_[rng.uniform(-0.6, 0.6, (5000, 2)), np.full(5000, 1.0)]
    else:
        pts = rng.normal(0, 0.001, (draw(st.integers(1, 300)), 3)) + [0, 0, 0.8]
    pts = np.asarray(pts, dtype=np.float64)
    if len(pts) and draw(st.booleans()):  # sensor dropouts and garbage
        bad = rng.random(len(pts)) < draw(st.floats(0.0, 1.0))
        pts[bad] = draw(st.sampled_from([np.nan, np.inf, -np.inf]))
    if len(pts) and draw(st.booleans()):
        pts[rng.integers(0, len(pts), 5)] = rng.uniform(-1e6, 1e6, (5, 3))
    return pts * draw(st.sampled_from([1.0, 1.0, 1e-3, 1e3]))


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(points=clouds())
def test_random_clouds_complete_or_are_refused_clearly(completer, points):
    try:
        seg = segment_scene(points)
    except REFUSALS as e:
        assert str(e)
        return
    usable = []
    for s in seg.segments:
        try:
            usable.append(check_segment(s.points_cam))
        except SegmentTooSmallError as e:
            assert str(e)
    for pts, c in zip(usable, complete_points(usable, completer, support_plane=seg.plane_cam)):
        assert c.probabilities.shape == (40, 40, 40) and np.isfinite(c.probabilities).all()
        if c.fast_mesh is None:
            assert c.error
            continue
        assert c.fast_mesh.is_watertight
        try:
            mesh = detailed_mesh(c.probabilities, c.frame, pts, support_plane=seg.plane_cam)
        except EmptyCompletionError as e:
            assert str(e)
            continue
        assert mesh.is_watertight and np.isfinite(mesh.vertices).all()
        # The completion is where the segment is: its box overlaps the points' box.
        lo, hi = pts.min(0), pts.max(0)
        assert (mesh.bounds[0] <= hi + 0.05).all() and (mesh.bounds[1] >= lo - 0.05).all()
