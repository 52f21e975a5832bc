"""The runtime pipeline of the paper (Fig. 5): capture -> segment -> voxelize -> CNN -> mesh.

Plain functions that the CLI and the viewer both call. Every returned mesh and point array is in
the camera optical frame (metres) unless its name says otherwise; ``Capture.T_world_cam`` (or the
segmentation's estimate) takes them to the world frame.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Literal

import numpy as np
import trimesh

from ..errors import ShapeviewerError
from .cuboid import Cuboid, fit_cuboid, occupancy
from .model import SYMMETRIES, Completer, sample_spread
from .reconstruct import MESH_LEVEL, detailed_mesh, fast_mesh
from .revolve import RevolutionAxis, fit_axis, revolve
from .voxel import GridFrame, context_grids, partial_to_grid

MIN_SEGMENT_POINTS = 50
MIN_SEGMENT_EXTENT = 0.01  # metres


class SegmentTooSmallError(ShapeviewerError, ValueError):
    """A segment has too few points or too small an extent to place a grid on."""


@dataclass(frozen=True)
class Completion:
    """One segment's completion: what the network and the shape priors made of it (read-only).

    The meshes made later on request (Algorithm 1's detailed mesh, the baselines, the grasp
    envelope) are not part of it: each caller keeps them (the viewer on its per-segment
    :class:`~shapeviewer.viewer.results.SegmentResult`).

    Attributes:
        segment_id: the segment completed.
        grid_in: (40, 40, 40) bool CNN input, [x, y, z].
        frame: the grid frame (grid coordinates <-> camera metres).
        context: (2, 40, 40, 40) bool known-empty space (seen free, under the table), [x, y, z]
            (:func:`~shapeviewer.completion.voxel.context_grids`); the CNN output is 0 there.
        support_plane: the table ``(a, b, c, d)`` in the camera frame, or None.
        probabilities: (40, 40, 40) float32 CNN output: the mean of its ``samples``, the network's
            answers for the 8 mirrored views (test-time augmentation: averaging removes part of each
            answer's error; docs/studies/grid-placement.md has the figures).
        fast_mesh: marching cubes of the output (camera frame, metres), None if the output is empty.
        samples: (8, 40, 40, 40) sample completions (:meth:`~shapeviewer.completion.model.Completer.predict_samples`),
            the answers the output averages; their per-voxel disagreement (:attr:`spread`) is the
            completion's uncertainty.
        timings: seconds per stage (``voxelize``, ``cnn``, ``priors``, ``fast_mesh``); a caller may
            add the stages it runs after (the CLI adds ``detailed_mesh``).
        error: why a mesh is missing, if it is.
        mesh_level: the probability its meshes are taken at (the network's
            :attr:`~shapeviewer.completion.model.Completer.mesh_level`).
        grid_level: the probability above which a voxel is in :attr:`grid_out` (the network's
            :attr:`~shapeviewer.completion.model.Completer.grid_level`).
        axis: the vertical axis fitted to the segment on the table (:func:`~shapeviewer.completion.revolve.fit_axis`),
            or None (no table, or not asked for); when it is accepted the samples, and so the
            output, are the network's answers revolved about it (:attr:`revolved`).
        cuboid: the box fitted to the segment on the table (:func:`~shapeviewer.completion.cuboid.fit_cuboid`), or
            None (no table, or not asked for); when it is accepted the samples, and so the output, are
            its occupancy (:attr:`boxed`).
    """

    segment_id: int
    grid_in: np.ndarray
    frame: GridFrame
    probabilities: np.ndarray
    fast_mesh: trimesh.Trimesh | None
    samples: np.ndarray
    context: np.ndarray | None = None
    support_plane: np.ndarray | None = None
    timings: dict[str, float] = field(default_factory=dict)
    error: str | None = None
    mesh_level: float = MESH_LEVEL
    grid_level: float = 0.5
    axis: RevolutionAxis | None = None
    cuboid: Cuboid | None = None

    @property
    def boxed(self) -> bool:
        """Whether the completion is the box fitted to the points (:mod:`shapeviewer.completion.cuboid`)."""
        return self.cuboid is not None and self.cuboid.accepted

    @property
    def revolved(self) -> bool:
        """Whether the answers were revolved about the table's normal (:mod:`shapeviewer.completion.revolve`)."""
        return self.axis is not None and self.axis.accepted

    @property
    def prior(self) -> str:
        """The shape prior applied to the answers, as the evaluation records it: ``"box"``
        (:attr:`boxed`), ``"revolution"`` (:attr:`revolved`) or ``""``."""
        return "box" if self.boxed else "revolution" if self.revolved else ""

    @property
    def grid_out(self) -> np.ndarray:
        """(40, 40, 40) bool: the CNN's output grid, the voxels with occupancy probability above
        :attr:`grid_level` (its estimate of the paper's Y: every voxel the object's surface passes through)."""
        return self.probabilities > self.grid_level

    @property
    def solid(self) -> np.ndarray:
        """(40, 40, 40) bool: the voxels the completion's meshes enclose, probability above
        :attr:`mesh_level`; what its uncertainty (:func:`confidence_figures`) is measured on."""
        return self.probabilities > self.mesh_level

    def require_fast_mesh(self) -> trimesh.Trimesh:
        """The fast mesh, or :class:`~.reconstruct.EmptyCompletionError` saying why there is none."""
        if self.fast_mesh is None:
            from .reconstruct import EmptyCompletionError

            raise EmptyCompletionError(self.error or "the completion is empty")
        return self.fast_mesh

    @property
    def spread(self) -> np.ndarray:
        """(40, 40, 40) float32 per-voxel disagreement of the ``samples`` (the uncertainty,
        :func:`~shapeviewer.completion.model.sample_spread`)."""
        return sample_spread(self.samples)


# A completed voxel whose samples spread more than this (model.sample_spread) is a guess, not seen.
GUESS_SPREAD = 0.1


def confidence_figures(
    grid_in: np.ndarray, solid: np.ndarray, spread: np.ndarray
) -> tuple[list[tuple[str, float]], float]:
    """How sure a completion is: ``([(side, mean spread)], share of guessed voxels)``.

    A completed voxel is on the ``seen`` side when it is occupied in the CNN input or next to an
    occupied input voxel, else ``unseen`` (sides without voxels are left out); ``spread`` is the
    per-voxel disagreement of sample completions (:func:`~shapeviewer.completion.model.sample_spread`),
    ``grid_in`` / ``solid`` (the completed voxels, :attr:`Completion.solid`) boolean grids of the
    same shape. A guessed voxel is a completed one with a spread above :data:`GUESS_SPREAD`.
    """
    from scipy import ndimage

    occupied = np.asarray(solid, dtype=bool)
    seen = ndimage.binary_dilation(grid_in) & occupied
    unseen = occupied & ~seen
    figures = [(what, float(spread[m].mean())) for what, m in (("seen", seen), ("unseen", unseen)) if m.any()]
    guessed = float((spread[occupied] > GUESS_SPREAD).mean()) if occupied.any() else 0.0
    return figures, guessed


def completion_detailed_mesh(c: Completion, points_cam: np.ndarray, *, timings: dict | None = None) -> trimesh.Trimesh:
    """Algorithm 1's mesh of completion ``c`` (camera frame, metres) from its segment's observed
    points (camera frame, metres), on the table ``c.support_plane``; ``timings`` gets Algorithm 1's
    step times (seconds)."""
    return detailed_mesh(
        c.probabilities, c.frame, points_cam, timings=timings, support_plane=c.support_plane, level=c.mesh_level
    )


def check_segment(points_cam: np.ndarray) -> np.ndarray:
    """Finite (N, 3) points of a segment, or :class:`SegmentTooSmallError` saying what is wrong."""
    pts = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) < MIN_SEGMENT_POINTS:
        raise SegmentTooSmallError(f"segment has {len(pts)} valid points; at least {MIN_SEGMENT_POINTS} are needed")
    extent = float((pts.max(0) - pts.min(0)).max())
    if extent < MIN_SEGMENT_EXTENT:
        raise SegmentTooSmallError(
            f"segment is {extent * 1000:.1f} mm across; at least {MIN_SEGMENT_EXTENT * 1000:.0f} mm is needed"
        )
    return pts


def complete_points(
    segments_points_cam: list[np.ndarray],
    completer: Completer,
    segment_ids: list[int] | None = None,
    *,
    support_plane: np.ndarray | None = None,
    revolve_answers: bool = False,
    fit_boxes: bool = True,
) -> list[Completion]:
    """Fast-complete several segments (camera-frame points, metres): one batched CNN call, the 8
    mirrored views of every segment (:meth:`~shapeviewer.completion.model.Completer.predict_samples`).

    ``support_plane``: the table ``(a, b, c, d)`` in the camera frame (normal towards the camera),
    or None. With the seen free space of each segment it is the CNN's context, and nothing is
    completed where the camera saw through or under the table.

    ``revolve_answers``: on a table, a segment whose points look like a surface of revolution about
    the table's normal (a bowl, cup, can or jar: :attr:`~shapeviewer.completion.revolve.RevolutionAxis.accepted`)
    has each of its answers revolved about that axis (:func:`~shapeviewer.completion.revolve.revolve`), which
    gives the far side the near side's shape; the seen free space stays empty. Off by default: it
    closes upside-down bowls and cups' far walls but fattens cans and fruit, and over 500 tabletop
    views it moves neither the meshes nor the grasps (docs/studies/revolve-prior.md).

    ``fit_boxes``: on a table, a segment whose points fill a rectangle on the table, lie on the faces
    of a box within depth noise and face along its edges (:attr:`~shapeviewer.completion.cuboid.Cuboid.accepted`)
    is completed as that box (:func:`~shapeviewer.completion.cuboid.occupancy` in place of every answer): the
    network's boxes are about 10 mm too large along every edge. On by default: over 500 tabletop
    views it takes 12 boxes and nothing else, brings 11 of them closer to the truth and lifts 4 more
    of them with the robust grasp (docs/studies/box-prior.md).

    Raises :class:`SegmentTooSmallError` if any segment is unusable (check first with
    :func:`check_segment` to skip those).
    """
    ids = list(range(len(segments_points_cam))) if segment_ids is None else list(segment_ids)
    t0 = time.perf_counter()
    pts = [check_segment(p) for p in segments_points_cam]
    grids, frames = zip(*(partial_to_grid(p, depth_shift=completer.depth_shift) for p in pts)) if pts else ((), ())
    contexts = [context_grids(p, f, support_plane=support_plane) for p, f in zip(pts, frames)]
    t1 = time.perf_counter()
    samples = (
        completer.predict_samples(np.stack(grids), len(SYMMETRIES), context=np.stack(contexts))
        if grids
        else np.zeros((len(SYMMETRIES), 0, 40, 40, 40), np.float32)
    )
    t2 = time.perf_counter()
    n = max(1, len(grids))
    plane = None if support_plane is None else np.asarray(support_plane, dtype=np.float64)
    out = []
    for i, (sid, g, fr, ctx) in enumerate(zip(ids, grids, frames, contexts)):
        t3 = time.perf_counter()
        own = np.ascontiguousarray(samples[:, i])
        axis = box = None
        if plane is not None and fit_boxes:
            box = fit_cuboid(pts[i], plane)
            if box.accepted:
                own = np.broadcast_to(occupancy(box, fr), own.shape).copy()
        if plane is not None and revolve_answers and not (box and box.accepted):
            axis = fit_axis(pts[i], plane)
            if axis.accepted:
                own = revolve(own, fr, axis, free=ctx[0])
        t4 = time.perf_counter()
        p = own.mean(axis=0)
        try:
            mesh, err = fast_mesh(p, fr, level=completer.mesh_level), None
        except ValueError as e:
            mesh, err = None, str(e)
        timings = {
            "voxelize": (t1 - t0) / n,
            "cnn": (t2 - t1) / n,
            "priors": t4 - t3,
            "fast_mesh": time.perf_counter() - t4,
        }
        out.append(
            Completion(
                sid,
                g,
                fr,
                p,
                mesh,
                own,
                ctx,
                plane,
                timings=timings,
                error=err,
                mesh_level=completer.mesh_level,
                grid_level=completer.grid_level,
                axis=axis,
                cuboid=box,
            )
        )
    return out


def complete(
    points_cam: np.ndarray,
    *,
    support_plane: np.ndarray | None = None,
    mode: Literal["fast", "detailed"] = "detailed",
    completer: Completer | None = None,
    revolve_answers: bool = False,
    fit_boxes: bool = True,
) -> trimesh.Trimesh:
    """Complete one object's points into a closed mesh: the one entry point every caller uses.

    The points are first cut as the app's segmentation would have cut them
    (:func:`segment.isolate`: above the table's bottom band, the largest cluster and the large
    parts near it, without flying pixels), so a mask from known poses or a detector completes like
    the segments the network learnt from.

    Args:
        points_cam: (N, 3) the object's observed points, camera optical frame (x right, y down,
            z forward), metres; non-finite rows are ignored.
        support_plane: ``(a, b, c, d)`` of the table in the camera frame, ``a x + b y + c z + d = 0``
            with the normal pointing to the camera's side; None when no table is known (a floating
            object). The completion then rests on the table and stops there.
        mode: ``"fast"`` (marching cubes of the CNN output, the mean of the network's answers for
            the 8 mirrored views) or ``"detailed"`` (Algorithm 1 on that output:
            :func:`completion_detailed_mesh`).
        completer: the network (default: the shipped model, loaded once and kept).
        revolve_answers: on a table, revolve the answers of a segment that looks like a surface of
            revolution about the table's normal (:func:`complete_points`).
        fit_boxes: on a table, complete a segment that is a box as the box fitted to its points
            (:func:`complete_points`; on by default).

    Returns:
        A watertight ``trimesh.Trimesh`` in the camera frame, metres.

    Raises:
        SegmentTooSmallError: too few points or too small an object to place a grid on.
        EmptyCompletionError: the network completed nothing.
        ValueError: an unknown ``mode`` or a malformed ``support_plane``.
    """
    return complete_with_samples(
        points_cam,
        support_plane=support_plane,
        mode=mode,
        completer=completer,
        revolve_answers=revolve_answers,
        fit_boxes=fit_boxes,
    )[1]


def complete_with_samples(
    points_cam: np.ndarray,
    *,
    support_plane: np.ndarray | None = None,
    mode: Literal["fast", "detailed"] = "detailed",
    completer: Completer | None = None,
    revolve_answers: bool = False,
    fit_boxes: bool = True,
) -> tuple[Completion, trimesh.Trimesh]:
    """What :func:`complete` computes, with the :class:`Completion` it meshed (its CNN grids, frame
    and 8 sample completions) beside the mesh: for callers that need the samples too (the pick,
    :func:`~shapeviewer.grasp.pick.robust_grasps`). Arguments, frames and errors as :func:`complete`."""
    if mode not in ("fast", "detailed"):
        raise ValueError(f"mode must be 'fast' or 'detailed', got {mode!r}")
    from ..perception.segment import isolate

    completer = completer or _shipped_completer()
    pts = check_segment(points_cam)
    kept = pts[isolate(pts, support_plane=support_plane)]
    if len(kept) >= MIN_SEGMENT_POINTS:
        pts = kept
    c = complete_points(
        [pts], completer, support_plane=support_plane, revolve_answers=revolve_answers, fit_boxes=fit_boxes
    )[0]
    return c, (c.require_fast_mesh() if mode == "fast" else completion_detailed_mesh(c, pts))


@lru_cache(maxsize=1)
def _shipped_completer() -> Completer:
    from .model import load_completer

    return load_completer()
