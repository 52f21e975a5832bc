"""One browser tab's viewer session: its capture, selection, completions, grasps and Dataset tab.

Everything is drawn in the WORLD frame (metres, z up): a synthetic capture knows its camera pose
(``Capture.T_world_cam``, table top at z = 0); for a real capture the segmentation estimates a
table-aligned world frame (``Segmentation.T_world_cam``); see :func:`~shapeviewer.perception.segment.world_frame`.
Pipeline results come in the camera optical frame and are mapped with that ``T_world_cam``
before they are sent.

A session ties its parts together: the scene and what has been made of it as plain values
(:mod:`.state`, :mod:`.results`), its scene nodes (:mod:`.drawing`: a layer frame per pipeline
stage), the control panel (:mod:`.panel`, wired in :func:`wire_callbacks`), the job queue (:mod:`.jobs`),
its jobs (:mod:`.loading`: capture and segmentation; :mod:`.completing`: completions, meshes and
confidence), the downloads (:mod:`.exports`), the Dataset tab (:mod:`.dataset`, drawn under
``/dataset``; it hides the pipeline's nodes while it is shown) and the grasps (:mod:`.grasps`,
step 6: hands under ``/grasps/seg_3/g0``, ...). All of it goes to the session's
:class:`~.audience.Audience`: its own browser tab, or every browser for a session a script or test
drives without one. What sessions share (the model, the default scenes, the worker pools) is a
:class:`~.context.SessionResources` that :class:`~.app.ViewerApp` loads once.

:class:`Session` can be driven without a browser (tests call :meth:`Session.complete`,
:meth:`Session.pick`, ...); GUI callbacks call the same methods. Jobs (loading, completing,
detailed and baseline meshes) go through the session's :class:`~.jobs.JobQueue`; grasp planning
and execution run in their own background thread (:class:`~.grasps.GraspController`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
import viser

from ..completion.pipeline import Completion
from ..perception.capture import Capture
from . import panel as P
from . import sources
from .audience import Audience, NotificationColor
from .completing import CompletionJobs
from .context import SessionContext, SessionResources
from .dataset import DatasetHooks, DatasetTab
from .drawing import PipelineDrawing
from .exports import segment_export
from .grasps import GraspController, GraspHost, GraspJob
from .gui import set_value, take_upload
from .jobs import JobQueue, send_download
from .loading import SceneLoading
from .rays import first_hit
from .results import PipelineState, SegmentResult
from .state import LoadedScene


class Session:
    """One browser tab's pipeline and Dataset tabs, their scene and their jobs.

    Args:
        audience: the tab (or every browser, for a headless session) to draw for.
        res: what the server's sessions share.
        seed: the seed the "New scene" field starts at.
    """

    def __init__(self, audience: Audience, res: SessionResources, seed: int = 0) -> None:
        self.audience = audience
        self.res = res
        self.state = PipelineState()
        self.last_error: str | None = None
        self.dataset: DatasetTab | None = None

        gui = audience.gui
        tabs = gui.add_tab_group()
        pipeline_tab = tabs.add_tab("Pipeline", viser.Icon.CUBE)
        dataset_tab = tabs.add_tab("Dataset", viser.Icon.DATABASE)
        with pipeline_tab:
            files = None if res.data_dir is None else sources.data_files(res.data_dir)
            self.panel = P.build_panel(gui, seed, files)
        self.drawing = PipelineDrawing(audience, res.max_cloud_points)
        self.jobs = JobQueue(self.panel.job_buttons, self.notify)
        self.ctx = SessionContext(audience, res, self.panel, self.drawing, self.jobs, self.state, self.notify)
        # A completion drawn (made or brought back): the layers that executing a grasp on the
        # ground truth hid come back (the lambda reads self.grasps once it exists).
        self.completing = CompletionJobs(self.ctx, moved_on=lambda: self.grasps.restore_layers())
        self.loading = SceneLoading(self.ctx, self._before_new_scene)
        host_api = GraspHost(
            scene=lambda: self.state.scene,
            selected_segment=lambda: self.state.selected,
            mesh=self.state.mesh,
            make_mesh=self.completing.make_mesh_for_grasps,
            samples=self.completing.sample_meshes_world,
            show_layer=self._show_layer,
            layer_shown=lambda key: bool(self.panel.layers[key].value),
            set_status=self.ctx.set_status,
            notify=self.notify,
        )
        with pipeline_tab:
            # The Grasps folder goes right after Completion (viser orders folders by a global counter).
            self.grasps = GraspController(audience, host_api, res.grasp_pool, order=self.panel.timings.order + 0.5)
        wire_callbacks(self)
        self.panel.model.content = res.model_markdown
        if res.curves_png is not None:  # the paper's Fig. 4 for these weights
            with self.panel.model_folder:
                gui.add_image(res.curves_png, label="Jaccard during training", format="png")
        self.dataset = DatasetTab(
            audience,
            dataset_tab,
            pipeline_tab,
            res.results,
            DatasetHooks(self.set_pipeline_visible, self.load_capture, self.notify),
            res.sample_build,
        )
        self.loading.load(res.first_scene, "the scene", None)

    # ------------------------------------------------------------------------------------------
    # The state (kept on ``self.state``)

    @property
    def scene(self) -> LoadedScene | None:
        """The shown scene (None once the session is closed)."""
        return self.state.scene

    @property
    def results(self) -> dict[int, SegmentResult]:
        """Segment id -> its completion and the meshes made of it (drop one to forget it)."""
        return self.state.results

    @property
    def completions(self) -> dict[int, Completion]:
        """Segment id -> its completion (a new dict each time: read-only)."""
        return self.state.completions

    @property
    def selected(self) -> int | None:
        """The selected segment, or None."""
        return self.state.selected

    @selected.setter
    def selected(self, segment_id: int | None) -> None:
        self.state.selected = segment_id

    @property
    def segment_options(self) -> dict[str, int]:
        """The Segment dropdown's entries: label -> segment id."""
        return self.state.segment_options

    @property
    def last_timings(self) -> dict[str, float]:
        """Seconds per stage of the last fast completion."""
        return self.state.last_timings

    # ------------------------------------------------------------------------------------------
    # Public API (the GUI callbacks call these too)

    def close(self) -> None:
        """End the session (its tab closed or the server stops): refuse and drop waiting jobs,
        cancel grasp work, stop the Dataset tab's threads and let go of the scene."""
        self.jobs.close()
        self.grasps.shutdown()
        if self.dataset is not None:
            self.dataset.shutdown()
        self.state.show(None)

    def load_default(self, seed: int, client: viser.ClientHandle | None = None) -> bool:
        """Generate and show the tabletop scene of ``seed``. False (and a notification) on failure."""
        return self.loading.load_default(seed, client)

    def load_cloud(self, path: str | Path, client: viser.ClientHandle | None = None) -> bool:
        """Load and show a capture file. On a bad file: False, an error notification, old scene kept."""
        return self.loading.load_cloud(path, client)

    def load_upload(self, name: str, content: bytes, client: viser.ClientHandle | None = None) -> bool:
        """Load and show a capture a browser uploaded (``name``: the browser's file name, whose suffix
        picks the reader; ``content``: the file). On a bad file: False, an error notification, old
        scene kept. The bytes are read from a private temporary folder (:func:`.sources.read_upload`).
        """
        return self.loading.load_upload(name, content, client)

    def data_files(self) -> tuple[str, ...]:
        """Names of the capture files in the data folder (:func:`.sources.data_files`)."""
        return self.loading.data_files()

    def load_data_file(self, name: str, client: viser.ClientHandle | None = None) -> bool:
        """Load a capture file of the data folder (``name`` relative to it). Anything that resolves
        outside the folder is refused; without a data folder every path is. The dropdown is
        re-read from the folder each time: files may have come or gone."""
        return self.loading.load_data_file(name, client)

    def load_capture(self, capture: Capture, client: viser.ClientHandle | None = None) -> bool:
        """Show an already loaded capture."""
        return self.loading.load(lambda: capture, capture.source, client)

    def set_pipeline_visible(self, visible: bool) -> None:
        """Show or hide every pipeline node (the Dataset tab draws in the same 3D scene); layers keep
        their checkboxes' state."""
        self.drawing.set_visible(visible, {key: box.value for key, box in self.panel.layers.items()})

    def pick(self, ray_origin: np.ndarray, ray_direction: np.ndarray) -> int | None:
        """The segment a world-frame ray hits first (None when it misses all segments)."""
        return self.pick_hit(ray_origin, ray_direction)[0]

    def pick_hit(self, ray_origin: np.ndarray, ray_direction: np.ndarray) -> tuple[int | None, float]:
        """:meth:`pick` and how far along the ray (metres) it hits: ``(None, inf)`` on a miss."""
        if self.scene is None:
            return None, np.inf
        return first_hit(ray_origin, ray_direction, self.scene.points_world)

    def click(self, ray_origin: np.ndarray, ray_direction: np.ndarray, client: viser.ClientHandle | None = None) -> str:
        """A click in the 3D view (world-frame ray): a grasp's hand in front of the segments
        selects that grasp, a segment is chosen (:meth:`choose_segment`: completed, or brought back
        when it was completed earlier). Returns what happened: ``"grasp"``, ``"segment"`` or
        ``"nothing"``."""
        k, t_hand = self.grasps.pick(ray_origin, ray_direction)
        sid, t_segment = self.pick_hit(ray_origin, ray_direction)
        if k is not None and t_hand <= t_segment:
            self.grasps.select(k)
            return "grasp"
        if sid is None:
            self.notify(
                client, "No segment there", "Click on a coloured segment, or on a grasp's hand.", auto_close=3.0
            )
            return "nothing"
        self.choose_segment(sid, client)
        return "segment"

    def segment_centroid_world(self, segment_id: int) -> np.ndarray:
        """Mean of a segment's points, world metres."""
        assert self.scene is not None  # set in __init__ (which fails without a scene)
        return self.scene.points_world[segment_id].mean(axis=0)

    def choose_segment(self, segment_id: int, client: viser.ClientHandle | None = None) -> Completion | None:
        """Select a segment (the Segment dropdown, a click in 3D). One completed earlier comes back
        as it was made, drawn, without computing anything: its completion and sample completions,
        the detailed mesh, baselines and envelope made of it, its grasps. Any other is
        fast-completed (:meth:`complete`). Returns its completion, or None (the client is told why)."""
        return self.completing.choose(segment_id, client)

    def complete(self, segment_id: int, client: viser.ClientHandle | None = None) -> Completion | None:
        """Fast-complete one segment (anew, when it was completed before: the meshes made of its
        earlier completion are dropped) and draw its CNN input, CNN output and fast mesh.

        Returns the completion, or None when the segment cannot be completed or another job is
        running (the client is told why).
        """
        done = self.completing.complete([segment_id], client)
        return done[0] if done else None

    def complete_all(self, client: viser.ClientHandle | None = None) -> list[Completion]:
        """Fast-complete every usable segment with one batched CNN pass (the paper's crowded scenes)."""
        return self.completing.complete(None, client)

    def compute_mesh(
        self, kind: str, segment_id: int | None = None, client: viser.ClientHandle | None = None
    ) -> trimesh.Trimesh | None:
        """Compute, keep and draw a segment's ``detailed``, ``partial``, ``mirror`` or ``hull`` mesh.

        The segment (default: the selected one) is fast-completed first if it has no completion yet.
        Returns the camera-frame mesh (also :meth:`mesh` from then on), or None when it cannot be
        made or another job is running (the client is told why).
        """
        return self.completing.compute_mesh(kind, segment_id, client)

    def mesh(self, kind: str, segment_id: int | None = None) -> trimesh.Trimesh | None:
        """A segment's (default: the selected one's) camera-frame mesh ``kind`` (one of
        :data:`~.state.MESH_KINDS`) once made, else None."""
        sid = self.selected if segment_id is None else segment_id
        return None if sid is None else self.state.mesh(kind, sid)

    def show_confidence(self, c: Completion) -> None:
        """The Confidence layer of ``c`` (the disagreement of its 8 sample completions) and its
        figures in the stage panel."""
        self.completing.show_confidence(c)

    def show_sample(self, k: int, client: viser.ClientHandle | None = None) -> trimesh.Trimesh | None:
        """Show sample completion ``k`` (1..8) of the selected segment as a translucent mesh in the
        Confidence layer (turned on), or none (``k`` = 0). Returns the camera-frame mesh shown."""
        return self.completing.show_sample(k, client)

    def plan_grasps(
        self,
        segment_id: int | None = None,
        hand: str = "barrett",
        method: str = "fast",
        n_grasps: int = 20,
        client: viser.ClientHandle | None = None,
        wait: bool = True,
        seed: int = 0,
        budget_seconds: float | None = None,
    ) -> GraspJob | None:
        """Plan grasps on a segment's (default: the selected one's) ``method`` mesh in the background,
        outside the job slot; see :meth:`GraspController.plan`. ``job.result``: the
        :class:`~shapeviewer.viewer.grasps.SegmentGrasps` (None when cancelled)."""
        return self.grasps.plan(
            self.selected if segment_id is None else segment_id,
            hand,
            method,
            n_grasps,
            client,
            wait,
            seed,
            budget_seconds,
        )

    def cancel_grasps(self) -> bool:
        """Stop the running grasp job (False when none runs)."""
        return self.grasps.cancel()

    def execute_grasps(
        self,
        segment_id: int | None = None,
        indices: list[int] | None = None,
        client: viser.ClientHandle | None = None,
        wait: bool = True,
        lift: bool = True,
    ) -> GraspJob | None:
        """Execute a segment's grasps ``indices`` (None: all) on its true object (synthetic scenes);
        ``job.result``: the :class:`~shapeviewer.grasp.execute.ExecutionResult` list."""
        return self.grasps.execute(
            self.grasps.current if segment_id is None else segment_id, indices, client, wait, lift
        )

    def export_grasps(self, segment_id: int | None = None, fmt: str = "json") -> tuple[str, bytes]:
        """``(file name, content)`` of a segment's grasps: ``json`` or the pybullet scene ``zip``."""
        return self.grasps.export(self.grasps.current if segment_id is None else segment_id, fmt)

    def export_bytes(
        self,
        kind: str,
        segment_id: int | None = None,
        mesh_format: str = "ply",
        frame: str = "world",
        mesh: str = "fast",
    ) -> tuple[str, bytes]:
        """``(file name, content)`` of an export of a segment (default: the selected one); see
        :func:`~.exports.segment_export`. Raises ValueError with a message for the user."""
        return segment_export(
            self.scene,
            self.state.results,
            self.selected if segment_id is None else segment_id,
            kind,
            mesh_format,
            frame,
            mesh,
        )

    def notify(
        self,
        client: viser.ClientHandle | None,
        title: str,
        body: str,
        color: NotificationColor | None = None,
        auto_close: float | None = 8.0,
    ) -> None:
        """Tell one client (every client when None) something; red ones are remembered as ``last_error``."""
        if color == "red":
            self.last_error = f"{title}: {body}"
        self.audience.notify(client, title, body, color, auto_close)

    # ------------------------------------------------------------------------------------------
    # Hooks of the parts

    def _before_new_scene(self) -> None:
        if self.dataset is not None:
            self.dataset.leave()  # a new scene is what the user wants to see
        self.grasps.clear()

    def _show_layer(self, key: str, visible: bool) -> None:
        set_value(self.panel.layers[key], visible)


# The Pipeline tab's controls wired to the session: which method each button, dropdown and checkbox
# calls. Kept apart from the class so that it reads as its jobs, this as its layout's events.
def wire_callbacks(app: Session) -> None:
    """Connect every control of ``app.panel`` and the scene's clicks to the session ``app``'s methods."""
    p = app.panel

    @app.audience.scene.on_click()
    def _(event: viser.SceneClickEvent) -> None:
        if app.drawing.visible:  # the dataset is on screen: its clicks are not picks
            app.click(np.asarray(event.ray_origin), np.asarray(event.ray_direction), event.client)

    # First, so that a segment's grasps are listed before completing it starts.
    p.segment.on_update(lambda _event: app.grasps.follow_segment(app.segment_options.get(p.segment.value)))

    @p.segment.on_update
    def _(event: viser.GuiEvent) -> None:
        sid = app.segment_options.get(p.segment.value)
        if sid == app.selected:
            return  # no change (the app selects before it sets the dropdown)
        if sid is None:
            app.selected = None
        else:
            app.choose_segment(sid, event.client)

    @p.complete.on_click
    def _(event: viser.GuiEvent) -> None:
        if app.selected is None:
            app.notify(event.client, "No segment selected", "Click a segment or pick one above.", "yellow")
        else:
            app.complete(app.selected, event.client)

    @p.complete_all.on_click
    def _(event: viser.GuiEvent) -> None:
        app.complete_all(event.client)

    for button, kind in ((p.detailed, "detailed"), (p.partial, "partial"), (p.mirror, "mirror"), (p.hull, "hull")):

        def compute(event: viser.GuiEvent, kind: str = kind) -> None:
            app.compute_mesh(kind, None, event.client)

        button.on_click(compute)

    @p.new_scene.on_click
    def _(event: viser.GuiEvent) -> None:
        app.load_default(int(p.seed.value), event.client)

    @p.upload.on_upload
    def _(event: viser.GuiEvent) -> None:
        file = take_upload(p.upload)  # the button lets go of the bytes once they are read
        app.audience.end_upload_notice(event.client)  # viser's "uploaded successfully": the load says what happened
        app.load_upload(file.name, file.content, event.client)

    if p.load_cloud is not None and p.cloud_path is not None:
        cloud_path = p.cloud_path

        @p.load_cloud.on_click
        def _(event: viser.GuiEvent) -> None:
            app.load_data_file(cloud_path.value, event.client)

    for key, box in p.layers.items():

        def toggle(_event: viser.GuiEvent, key: str = key, box: viser.GuiCheckboxHandle = box) -> None:
            app.drawing.set_layer(key, box.value)

        box.on_update(toggle)

    @p.layers["confidence"].on_update
    def _(_event: viser.GuiEvent) -> None:
        if p.layers["confidence"].value:
            # Every completion's layer; the selected segment's figures last, so the panel shows them.
            done = sorted(app.completions.values(), key=lambda c: c.segment_id == app.selected)
            for c in done:
                app.show_confidence(c)

    @p.sample.on_update
    def _(event: viser.GuiEvent) -> None:
        if event.client is None:
            return  # reset by the app, not moved by the user
        k = int(np.clip(p.sample.value, 0, P.N_SAMPLES))  # a typed number may lie outside 0..8
        if k != p.sample.value:
            set_value(p.sample, k)
        app.show_sample(k, event.client)

    @p.cloud_colors.on_update
    def _(_event: viser.GuiEvent) -> None:
        if app.scene is not None:
            app.drawing.draw_cloud(app.scene, p.cloud_colors.value == "capture")

    @p.shade_output.on_update
    @p.layers["cnn_output"].on_update
    def _(_event: viser.GuiEvent) -> None:
        # The CNN output is drawn only while its layer is shown (see PipelineDrawing.draw_completion).
        if app.scene is not None and p.layers["cnn_output"].value:
            for c in list(app.completions.values()):
                app.drawing.draw_output(app.scene, c, p.shade_output.value)

    for button, kind in ((p.export_points, "points"), (p.export_grids, "grids"), (p.export_mesh, "mesh")):

        def export(event: viser.GuiEvent, kind: str = kind) -> None:
            send_download(
                event.client,
                lambda: app.export_bytes(
                    kind, None, p.mesh_format.value, p.export_frame.value, p.export_mesh_kind.value
                ),
                app.notify,
            )

        button.on_click(export)
