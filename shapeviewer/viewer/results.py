"""What the Pipeline tab has made of its scene, as plain values: per segment, its completion and the
meshes the user asked for after it.

No viser. A :class:`~shapeviewer.completion.pipeline.Completion` is read-only: the detailed mesh,
the baselines and the grasp envelope the user computes later are kept beside it on the segment's
:class:`SegmentResult`: choosing the segment again brings them back, and they go with the
completion only when the segment is completed anew (Complete segment, Complete all). Meshes are in
the camera optical frame (metres); the scene's ``T_world_cam`` takes them to the world frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import trimesh

from ..completion.pipeline import Completion
from .state import MESH_KINDS, MESH_TITLES, LoadedScene


@dataclass
class SegmentResult:
    """One segment's completion and the meshes made of it on request.

    Attributes:
        completion: the fast completion (CNN input and output, sample completions, fast mesh).
        meshes: kind (a key of :data:`~.state.MESH_TITLES`: ``detailed``, ``envelope``, ``partial``,
            ``mirror``, ``hull``) -> its camera-frame mesh, once computed.
        seconds: kind -> the seconds it took to compute that mesh.
        detailed_steps: Algorithm 1's step times (seconds, the dict
            :func:`~shapeviewer.completion.reconstruct.detailed_mesh` fills) of the detailed mesh.
        timings: seconds per stage of the completion, as the stage panel showed them (see
            :func:`~.panel.completion_timings`), shown again when the segment is chosen later.
    """

    completion: Completion
    meshes: dict[str, trimesh.Trimesh] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    detailed_steps: dict[str, float] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)

    def mesh(self, kind: str) -> trimesh.Trimesh | None:
        """Camera-frame mesh ``kind`` (one of :data:`~.state.MESH_KINDS`): the completion's fast mesh
        (None when the output is empty) or a mesh made on request (None until it is)."""
        if kind not in MESH_KINDS:
            raise ValueError(f"unknown mesh {kind!r}; choose one of {MESH_KINDS}")
        return self.completion.fast_mesh if kind == "fast" else self.meshes.get(kind)

    def add_mesh(self, kind: str, mesh: trimesh.Trimesh, seconds: float, steps: dict[str, float] | None = None) -> None:
        """Keep mesh ``kind`` (a key of :data:`~.state.MESH_TITLES`), made in ``seconds``
        (``steps``: Algorithm 1's step times, for the detailed mesh)."""
        if kind not in MESH_TITLES:
            raise ValueError(f"unknown mesh {kind!r}; choose one of {tuple(MESH_TITLES)}")
        self.meshes[kind] = mesh
        self.seconds[kind] = seconds
        if kind == "detailed":
            self.detailed_steps = dict(steps or {})


@dataclass
class PipelineState:
    """The Pipeline tab's scene, what has been made of it and what is selected.

    Attributes:
        scene: the shown scene (None before the first and after the session closed).
        results: segment id -> what has been made of that segment.
        selected: the segment chosen (clicked, or picked in the Segment dropdown), or None.
        segment_options: the Segment dropdown's entries, label -> segment id.
        last_timings: seconds per stage of the last fast completion (see
            :func:`~.panel.completion_timings`).
    """

    scene: LoadedScene | None = None
    results: dict[int, SegmentResult] = field(default_factory=dict)
    selected: int | None = None
    segment_options: dict[str, int] = field(default_factory=dict)
    last_timings: dict[str, float] = field(default_factory=dict)

    @property
    def completions(self) -> dict[int, Completion]:
        """Segment id -> its completion (a new dict: complete a segment to add one)."""
        return {sid: r.completion for sid, r in self.results.items()}

    def completion(self, segment_id: int) -> Completion | None:
        """The completion of a segment, or None when it has none."""
        result = self.results.get(segment_id)
        return None if result is None else result.completion

    def mesh(self, kind: str, segment_id: int) -> trimesh.Trimesh | None:
        """A segment's camera-frame mesh ``kind`` (:meth:`SegmentResult.mesh`), or None when the
        segment has no completion or not that mesh yet."""
        result = self.results.get(segment_id)
        return None if result is None else result.mesh(kind)

    def show(self, scene: LoadedScene | None) -> None:
        """Start over on ``scene``: nothing completed, nothing selected, no timings."""
        self.scene, self.results, self.selected, self.last_timings = scene, {}, None, {}
        self.segment_options = {} if scene is None else scene.segment_options
