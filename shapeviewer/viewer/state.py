"""The Pipeline tab's scene as plain values: a capture, its segmentation and its world frame.

No viser: tests and the app build a :class:`LoadedScene` with :func:`load_scene`. Positions are
WORLD metres (z up, table top at z = 0) unless a name says ``cam`` (the camera optical frame).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from ..completion.baselines import hull_mesh, mirror_mesh, partial_mesh
from ..completion.pipeline import Completion, SegmentTooSmallError, check_segment, completion_detailed_mesh
from ..evaluation.methods import MESH_KINDS as ALL_MESH_KINDS
from ..evaluation.methods import METHOD_INFO, MeshKind, method_of
from ..perception.camera import transform_points
from ..perception.capture import MAX_CAPTURE_POINTS, Capture, decimate
from ..perception.segment import Segment, Segmentation, segment_scene, world_frame

# The meshes a segment can have, by their short key (one per evaluation method,
# :mod:`shapeviewer.evaluation.methods`), drawn in layer ``<kind>_mesh``.
MESH_KINDS: tuple[MeshKind, ...] = ALL_MESH_KINDS
# What the panel calls the meshes made on request (the fast mesh comes with every completion).
MESH_TITLES: dict[str, str] = {k: METHOD_INFO[method_of(k)].mesh_title for k in MESH_KINDS if k != "fast"}


@dataclass
class LoadedScene:
    """A capture with its segmentation, ready to be shown.

    Attributes:
        capture: the capture (camera-frame points).
        segmentation: ``segment_scene(capture)``.
        T_world_cam: 4x4 camera pose in the world frame the viewer draws in.
        frame_note: where that world frame comes from (see :func:`~shapeviewer.perception.segment.world_frame`).
        seg_seconds: wall time of the segmentation.
        segments: segment id -> segment.
        points_world: segment id -> its finite points in world metres (for picking).
    """

    capture: Capture
    segmentation: Segmentation
    T_world_cam: np.ndarray
    frame_note: str
    seg_seconds: float
    segments: dict[int, Segment]
    points_world: dict[int, np.ndarray]

    @property
    def title(self) -> str:
        """What the panel calls the capture: ``default(seed=N)`` or the file's name."""
        src = self.capture.source
        return src if src.startswith("default(") else Path(src).name

    @property
    def name(self) -> str:
        """A short file-name stem for downloads."""
        src = self.capture.source
        if src.startswith("default(seed="):
            return f"default_seed{src[len('default(seed=') : -1]}"
        return Path(src).stem or "capture"

    @property
    def segment_options(self) -> dict[str, int]:
        """The Segment dropdown's entries: label (or ``segment <id>``) -> segment id."""
        return {s.label or f"segment {s.id}": s.id for s in self.segmentation.segments}

    def focus(self) -> tuple[np.ndarray, float]:
        """World point the view centres on and the width (m) of the region to show.

        Both come from the 2nd-98th percentiles of the segment points (of the cloud when there
        are no segments), so that a few small far-away segments do not pull the view off the
        objects that make up most of the scene.
        """
        pts = [p for p in self.points_world.values() if len(p)]
        if pts:
            allp = np.concatenate(pts)
        else:
            cloud = self.capture.flat_points()[self.capture.valid_mask()]
            allp = transform_points(self.T_world_cam, cloud[:: max(1, len(cloud) // 20000)])
        lo, hi = np.percentile(allp, [2, 98], axis=0)
        return (lo + hi) / 2, float((hi - lo)[:2].max())

    def display_points(self, max_points: int) -> dict[int, np.ndarray]:
        """Segment id -> the world points to draw for it: one common stride keeps ``max_points`` in all."""
        total = sum(len(p) for p in self.points_world.values())
        stride = max(1, -(-total // max_points))
        return {sid: p[::stride] for sid, p in self.points_world.items()}


def usable(segment: Segment) -> bool:
    """Whether a segment has enough points and extent to be completed."""
    try:
        check_segment(segment.points_cam)
        return True
    except SegmentTooSmallError:
        return False


def load_scene(capture: Capture, require_segment: bool = False) -> LoadedScene:
    """Decimate (see :func:`~shapeviewer.perception.capture.decimate`) and segment ``capture``, in its world frame.

    ``require_segment``: raise ValueError for a capture without a segment that can be completed,
    so that the viewer can keep the user's scene rather than replace it with an empty one.
    """
    capture = decimate(capture, MAX_CAPTURE_POINTS)  # load_capture did it for files; not for Captures
    t0 = time.perf_counter()
    seg = segment_scene(capture)
    seg_seconds = time.perf_counter() - t0
    if require_segment and not any(usable(s) for s in seg.segments):
        found = (
            (
                "its only segment is too small to complete"
                if len(seg.segments) == 1
                else f"none of its {len(seg.segments)} segments is large enough to complete"
            )
            if seg.segments
            else f"no segments found among its {int(capture.valid_mask().sum()):,} valid points"
        )
        raise ValueError(f"{found}; the current scene is kept")
    T, note = world_frame(capture, seg)
    points_world = {}
    for s in seg.segments:
        pts = np.asarray(s.points_cam, dtype=np.float64)
        points_world[s.id] = transform_points(T, pts[np.isfinite(pts).all(axis=1)])
    return LoadedScene(capture, seg, T, note, seg_seconds, {s.id: s for s in seg.segments}, points_world)


def make_mesh(kind: MeshKind, c: Completion, scene: LoadedScene, steps: dict[str, float]) -> trimesh.Trimesh:
    """Camera-frame mesh ``kind`` (``detailed``, ``envelope``, ``partial``, ``hull`` or ``mirror``)
    of completion ``c``'s segment; ``steps`` gets Algorithm 1's step times (seconds)."""
    points = scene.segments[c.segment_id].points_cam
    if kind == "detailed":
        return completion_detailed_mesh(c, points, timings=steps)
    if kind == "envelope":
        from ..grasp.robust import envelope_mesh

        return envelope_mesh(c.samples, c.frame, np.eye(4))
    if kind == "partial":
        return partial_mesh(points)
    if kind == "hull":
        return hull_mesh(points)
    return mirror_mesh(points, scene.segmentation.plane_cam)
