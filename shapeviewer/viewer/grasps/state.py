"""The grasp controller's state as plain values: a segment's grasps, a background job, and the
true object a segment shows (synthetic scenes). No viser.

Frames: the viewer's WORLD frame (metres, z up, table top z = 0); a synthetic scene's true object
is ``SceneObject.mesh`` (object frame) mapped with ``T_world_obj``.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np
import trimesh

from ...errors import ShapeviewerError
from ...grasp.execute import ExecutionResult
from ...grasp.plan import Grasp, PlanStats
from ...grasp.robust import Robustness
from ...perception.camera import transform_points
from ...perception.capture import Capture, SceneObject
from ...perception.segment import Segment

MIN_GROUND_TRUTH_SHARE = 0.5  # a segment is an object when at least this share of its labelled points are
MAX_GRASPS = 50  # the most grasps one plan keeps (the Grasps folder's count)


@dataclass(eq=False)
class SegmentGrasps:
    """The grasps planned on one segment's mesh and what became of them on the true object.

    Attributes:
        segment_id: the segment.
        hand: hand name (see :data:`~shapeviewer.grasp.hands.HAND_NAMES`).
        method: which of the segment's meshes was planned on (one of :data:`~..state.MESH_KINDS`).
        mesh_world: that mesh in the world frame (metres), as given to the planner.
        table: whether the planner (and execution) had the table plane z = 0.
        seed: planning seed.
        grasps: best first.
        stats: what planning did.
        executions: per grasp, its execution on the true object (None until executed).
        truth_name: the true object's catalogue name once executed (synthetic scenes).
        truth_world: the true object's world-frame mesh once executed.
        robustness: per grasp, how it fares re-closed on the completion's sample completions,
            once ranked by robustness (None before).
        wider_from: the index from which ``grasps`` come from the ranking's wider search, planned
            on the grasp envelope because no grasp of ``method`` held up on the samples
            (:func:`~shapeviewer.grasp.robust.is_weak`); None when it did not run.
        seconds: wall-clock seconds of each stage the grasps went through, as the user waited for
            it: ``"plan"`` (planning), then, once ranked by robustness, ``"rank"`` (scoring them on
            the samples) and ``"wider"`` (the wider search, when it ran), as in
            :attr:`~shapeviewer.grasp.pick.Pick.seconds`. The notices and the panel show these.
        width: the narrowest extent of ``mesh_world`` (metres, the smallest edge of its oriented
            bounding box), to compare with a parallel gripper's opening; None when unknown.
    """

    segment_id: int
    hand: str
    method: str
    mesh_world: trimesh.Trimesh
    table: bool
    seed: int
    grasps: list[Grasp]
    stats: PlanStats
    executions: list[ExecutionResult | None] = field(default_factory=list)
    truth_name: str | None = None
    truth_world: trimesh.Trimesh | None = None
    robustness: list[Robustness] | None = None
    wider_from: int | None = None
    seconds: dict[str, float] = field(default_factory=dict)
    width: float | None = None

    def __post_init__(self) -> None:
        if not self.executions:
            self.executions = [None] * len(self.grasps)


def narrowest_width(mesh: trimesh.Trimesh) -> float:
    """The smallest edge (metres) of ``mesh``'s oriented bounding box: about how wide a hand must
    open to close around the object the narrow way."""
    _, extents = trimesh.bounds.oriented_bounds(mesh)
    return float(np.min(extents))


@dataclass(eq=False)
class GraspJob:
    """A planning, execution or robustness-ranking job running in the background.

    ``done`` is set when it has finished (``result`` then holds what it made, ``error`` a message
    when it failed, ``cancelled`` whether Cancel stopped it).
    """

    kind: str
    segment_id: int
    cancel_event: threading.Event = field(default_factory=threading.Event)
    done: threading.Event = field(default_factory=threading.Event)
    result: object = None
    error: str | None = None
    cancelled: bool = False
    thread: threading.Thread | None = None

    def wait(self, timeout: float | None = None) -> bool:
        """Block until the job finishes (or ``timeout`` seconds pass); True when it has finished."""
        return self.done.wait(timeout)

    def cancel(self) -> None:
        self.cancel_event.set()


class GraspJobError(ShapeviewerError):
    """A job that cannot go on; the message is for the user."""


def ground_truth_object(capture: Capture, segment: Segment) -> tuple[int, float] | None:
    """``(index into capture.objects, share of the segment's labelled points on it)`` of the object a
    segment shows, from the capture's per-pixel ground-truth labels; None for a real capture (no
    labels) or when no object has at least MIN_GROUND_TRUTH_SHARE of the labelled points."""
    if not capture.objects or capture.labels is None:
        return None
    labels = np.asarray(capture.labels).reshape(-1)[segment.indices]
    labels = labels[labels >= 0]
    if len(labels) == 0:
        return None
    counts = np.bincount(labels, minlength=len(capture.objects))
    index = int(np.argmax(counts))
    share = float(counts[index] / len(labels))
    return (index, share) if share >= MIN_GROUND_TRUTH_SHARE else None


def object_mesh_world(obj: SceneObject) -> trimesh.Trimesh:
    """A true object's mesh in the world frame (metres)."""
    return trimesh.Trimesh(
        transform_points(obj.T_world_obj, obj.mesh.vertices), np.asarray(obj.mesh.faces), process=False
    )


def ground_truth(capture: Capture, segment: Segment) -> tuple[str, trimesh.Trimesh] | str:
    """``(name, world-frame mesh)`` of the true object ``segment`` shows, or a message saying why
    there is none (a real capture; a segment covering several objects)."""
    if not capture.objects:
        return (
            "No ground truth: this is a real capture, so there is no true object to execute grasps on. "
            "Grasps can still be planned, inspected and exported."
        )
    match = ground_truth_object(capture, segment)
    if match is None:
        return f"No ground truth for segment {segment.id}: its points do not belong mostly to one object of the scene."
    obj = capture.objects[match[0]]
    return obj.name, object_mesh_world(obj)
