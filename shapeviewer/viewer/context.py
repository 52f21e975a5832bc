"""What a viewer session's jobs share: the server's :class:`SessionResources` and the session's own
:class:`SessionContext` (its tab, panel, scene nodes, job slot and :class:`~.results.PipelineState`).

The session's jobs (:mod:`.loading`: capture and segmentation; :mod:`.completing`: completions,
meshes and confidence) each take a context rather than the session, so each reads as its job.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..completion.model import Completer
from ..perception.camera import Intrinsics
from ..runtime.processes import ProcessPool
from . import panel as P
from .audience import Audience
from .dataset import SampleBuild
from .drawing import PipelineDrawing
from .gui import set_value
from .jobs import JobQueue, Notify, WorkerPool
from .results import PipelineState
from .state import LoadedScene


@dataclass
class SessionResources:
    """What every session of a server shares, loaded once (read-only to the sessions).

    Attributes:
        completer: the CNN.
        model_markdown: the Model folder's text.
        curves_png: the weights' training curves (paper Fig. 4) as an RGB image, or None.
        first_scene: the scene a new session starts with (``--cloud`` or the default scene).
        default_scene: the generated tabletop scene of a seed (cached).
        pool: the worker pool every session's jobs compute in.
        grasp_pool: the (smaller) set of worker processes grasp planning, execution and ranking run in.
        intrinsics: camera intrinsics for uploaded depth images (None: ask / assume).
        data_dir: the server folder browsers may load captures from (None: uploads only).
        max_upload_bytes: the upload cap.
        max_cloud_points: see :class:`~.drawing.PipelineDrawing`.
        results: the Dataset tab's results folder (None: no store).
        sample_build: the background build of the sample results store, or None.
    """

    completer: Completer
    model_markdown: str
    curves_png: np.ndarray | None
    first_scene: Callable[[], LoadedScene]
    default_scene: Callable[[int], LoadedScene]
    pool: WorkerPool
    grasp_pool: ProcessPool
    intrinsics: Intrinsics | None = None
    data_dir: Path | None = None
    max_upload_bytes: int = P.MAX_UPLOAD_MB * 1024 * 1024
    max_cloud_points: int | None = None
    results: Path | None = None
    sample_build: SampleBuild | None = None


@dataclass(frozen=True)
class SessionContext:
    """One session's parts, as its jobs use them.

    Attributes:
        audience: the tab (or every browser, for a headless session) drawn for.
        res: what the server's sessions share.
        panel: the Pipeline tab's controls.
        drawing: the pipeline's scene nodes.
        jobs: the session's job slot (one job at a time).
        state: the scene, its results and the selection.
        notify: ``(client, title, body, color=None, auto_close=8.0)``; red ones are errors.
    """

    audience: Audience
    res: SessionResources
    panel: P.Panel
    drawing: PipelineDrawing
    jobs: JobQueue
    state: PipelineState
    notify: Notify

    def select(self, segment_id: int | None) -> None:
        """Make ``segment_id`` (None: none) the selected segment and show it in the Segment dropdown."""
        self.state.selected = segment_id
        if segment_id is None:
            set_value(self.panel.segment, P.NO_SEGMENT)
            return
        option = next(o for o, sid in self.state.segment_options.items() if sid == segment_id)
        set_value(self.panel.segment, option)

    def set_status(self, text: str) -> None:
        """Show ``text`` (markdown) as the panel's status line."""
        self.panel.status.content = text
