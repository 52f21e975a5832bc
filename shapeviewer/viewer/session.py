"""One browser tab's viewer session: its capture, selection, completions, grasps and Dataset tab.

Everything is drawn in the WORLD frame (metres, z up): a synthetic capture knows its camera pose
(``Capture.T_world_cam``, table top at z = 0); for a real capture the segmentation estimates a
table-aligned world frame (``Segmentation.T_world_cam``); see :func:`~shapeviewer.perception.segment.world_frame`.
Pipeline results come in the camera optical frame and are mapped with that ``T_world_cam``
before they are sent.

A session ties its parts together: the scene as plain values (:mod:`.state`), its scene nodes
(:mod:`.drawing`: a layer frame per pipeline stage), the control panel (:mod:`.panel`), the job
queue (:mod:`.jobs`), the downloads (:mod:`.exports`), the Dataset tab (:mod:`.dataset`, drawn
under ``/dataset``; it hides the pipeline's nodes while it is shown) and the grasps
(:mod:`.grasps`, step 6: hands under ``/grasps/seg_3/g0``, ...). All of it goes to the session's
:class:`~.audience.Audience`: its own browser tab, or every browser for a session a script or test
drives without one. What sessions share (the model, the default scenes, the worker pools) is a
:class:`SessionResources` that :class:`~.app.ViewerApp` loads once.

:class:`Session` can be driven without a browser (tests call :meth:`Session.complete`,
:meth:`Session.pick`, ...); GUI callbacks call the same methods. Jobs (loading, completing,
detailed and baseline meshes) go through the session's :class:`~.jobs.JobQueue`; grasp planning
and execution run in their own background thread (:class:`~.grasps.GraspController`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import trimesh
import viser

from ..completion.model import Completer
from ..completion.pipeline import (
    Completion,
    SegmentTooSmallError,
    check_segment,
    complete_points,
    confidence_figures,
)
from ..completion.reconstruct import fast_mesh
from ..grasp.robust import sample_meshes
from ..perception.camera import Intrinsics
from ..perception.capture import Capture, CaptureError, load_capture
from ..runtime.processes import ProcessPool
from . import panel as P
from . import sources
from .audience import Audience
from .dataset import DatasetHooks, DatasetTab, SampleBuild
from .drawing import PipelineDrawing
from .exports import segment_export
from .grasps import GraspController, GraspHost, GraspJob
from .gui import set_value
from .jobs import READY, JobQueue, WorkerPool
from .rays import first_hit
from .state import MESH_TITLES, LoadedScene, load_scene, make_mesh
from .wiring import wire_callbacks

if TYPE_CHECKING:
    from viser._gui_api import LiteralColor

log = logging.getLogger(__name__)


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
        self.scene: LoadedScene | None = None
        self.completions: dict[int, Completion] = {}
        self.selected: int | None = None
        self.last_timings: dict[str, float] = {}
        self.last_error: str | None = None
        self.segment_options: dict[str, int] = {}  # dropdown entry -> segment id
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
        host_api = GraspHost(
            scene=lambda: self.scene,
            selected_segment=lambda: self.selected,
            mesh=self._existing_mesh,
            make_mesh=self._make_mesh_for_grasps,
            samples=self._sample_meshes_world,
            show_layer=self._show_layer,
            set_status=self._set_status,
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
        self._load(res.first_scene, "the scene", None)

    # ------------------------------------------------------------------------------------------
    # Public API (the GUI callbacks call these too)

    def close(self) -> None:
        """End the session (its tab closed or the server stops): refuse and drop waiting jobs,
        cancel grasp work, stop the Dataset tab's threads and let go of the scene."""
        self.jobs.close()
        self.grasps.shutdown()
        if self.dataset is not None:
            self.dataset.shutdown()
        self.scene, self.completions, self.selected = None, {}, None

    def load_default(self, seed: int, client: viser.ClientHandle | None = None) -> bool:
        """Generate and show the tabletop scene of ``seed``. False (and a notification) on failure."""
        return self._load(lambda: self.res.default_scene(int(seed)), f"scene seed {seed}", client)

    def load_cloud(self, path: str | Path, client: viser.ClientHandle | None = None) -> bool:
        """Load and show a capture file. On a bad file: False, an error notification, old scene kept."""
        return self._load(lambda: self._read_capture(path), str(path), client)

    def load_upload(self, name: str, content: bytes, client: viser.ClientHandle | None = None) -> bool:
        """Load and show a capture a browser uploaded (``name``: the browser's file name, whose suffix
        picks the reader; ``content``: the file). On a bad file: False, an error notification, old
        scene kept. The bytes are read from a private temporary folder (:func:`.sources.read_upload`).
        """
        shown = sources.upload_name(name)
        problem = sources.upload_problem(shown, len(content), self.res.max_upload_bytes)
        if problem is not None:
            self.notify(client, "Could not load the capture", f"{shown}: {problem}", "red")
            return False
        notes: list[str] = []

        def read() -> Capture:
            capture, note = sources.read_upload(shown, content, self.res.intrinsics)
            notes.extend([note] if note else [])
            return capture

        ok = self._load(read, shown, client)
        if ok and notes:
            self.notify(client, "Assumed intrinsics", notes[0], "yellow", auto_close=15.0)
        return ok

    def data_files(self) -> tuple[str, ...]:
        """Names of the capture files in the data folder (:func:`.sources.data_files`)."""
        return sources.data_files(self.res.data_dir)

    def load_data_file(self, name: str, client: viser.ClientHandle | None = None) -> bool:
        """Load a capture file of the data folder (``name`` relative to it). Anything that resolves
        outside the folder is refused; without a data folder every path is. The dropdown is
        re-read from the folder each time: files may have come or gone."""
        if self.res.data_dir is None:
            self.notify(
                client, "Server files are off", "Start the server with --data-dir DIR to load its files.", "red"
            )
            return False
        name = str(name).strip()
        if not name or name == P.NO_DATA_FILE:
            self.notify(client, "No file chosen", "The server's data folder has no .pcd/.ply/.png/.npy file.", "red")
            return False
        try:
            path = sources.data_file(self.res.data_dir, name)
        except CaptureError as e:
            self.notify(client, "Could not load the capture", str(e), "red")
            return False
        finally:
            self._refresh_data_files()
        return self.load_cloud(path, client)

    def _refresh_data_files(self) -> None:
        dropdown = self.panel.cloud_path
        if dropdown is not None:
            options = P.data_file_options(self.data_files())
            if tuple(dropdown.options) != options:
                dropdown.options = options

    def load_capture(self, capture: Capture, client: viser.ClientHandle | None = None) -> bool:
        """Show an already loaded capture."""
        return self._load(lambda: capture, capture.source, client)

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
        selects that grasp, a segment is completed. Returns what happened: ``"grasp"``,
        ``"segment"`` or ``"nothing"``."""
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
        self.complete(sid, client)
        return "segment"

    def segment_centroid_world(self, segment_id: int) -> np.ndarray:
        """Mean of a segment's points, world metres."""
        assert self.scene is not None  # set in __init__ (which fails without a scene)
        return self.scene.points_world[segment_id].mean(axis=0)

    def complete(self, segment_id: int, client: viser.ClientHandle | None = None) -> Completion | None:
        """Fast-complete one segment and draw its CNN input, CNN output and fast mesh.

        Returns the completion, or None when the segment cannot be completed or another job is
        running (the client is told why).
        """
        done = self._complete([segment_id], client)
        return done[0] if done else None

    def complete_all(self, client: viser.ClientHandle | None = None) -> list[Completion]:
        """Fast-complete every usable segment with one batched CNN pass (the paper's crowded scenes)."""
        return self._complete(None, client)

    def compute_mesh(
        self, kind: str, segment_id: int | None = None, client: viser.ClientHandle | None = None
    ) -> trimesh.Trimesh | None:
        """Compute, store on the completion and draw a segment's ``detailed``, ``partial``, ``mirror`` or ``hull`` mesh.

        The segment (default: the selected one) is fast-completed first if it has no completion yet.
        Returns the camera-frame mesh, or None when it cannot be made or another job is running
        (the client is told why).
        """
        if kind not in MESH_TITLES:
            raise ValueError(f"unknown mesh {kind!r}; choose one of {tuple(MESH_TITLES)}")
        sid = self.selected if segment_id is None else segment_id
        if sid is None:
            self.notify(client, "No segment selected", "Click a segment or pick one above.", "yellow")
            return None
        with self.jobs.take(client) as ok:
            if not ok or self.scene is None:
                return None
            if kind == "mirror" and self.scene.segmentation.plane_cam is None:
                self.notify(
                    client,
                    "Mirror needs a support plane",
                    "No table plane was found in this capture, and the Mirror baseline searches its "
                    "symmetry plane perpendicular to the table.",
                    "red",
                )
                return None
            c = self.completions.get(sid)
            if c is None:
                done = self._complete_in_slot([sid], client)
                if not done:
                    return None
                c = done[0]
            self._select(sid)
            return self._compute_mesh_in_slot(kind, c, client)

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
            self.completions,
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
        color: LiteralColor | None = None,
        auto_close: float | None = 8.0,
    ) -> None:
        """Tell one client (every client when None) something; red ones are remembered as ``last_error``."""
        if color == "red":
            self.last_error = f"{title}: {body}"
        self.audience.notify(client, title, body, color, auto_close)

    # ------------------------------------------------------------------------------------------
    # Completing

    def _complete(self, ids: list[int] | None, client: viser.ClientHandle | None) -> list[Completion]:
        """Complete segments ``ids`` (None: all) in one batch, draw them, and fill the timings table."""
        with self.jobs.take(client) as ok:
            if not ok or self.scene is None:
                return []
            return self._complete_in_slot(ids, client)

    def _complete_in_slot(self, ids: list[int] | None, client: viser.ClientHandle | None) -> list[Completion]:
        """:meth:`_complete` for a caller that holds the job slot (and has a scene)."""
        scene = self.scene
        assert scene is not None  # the callers return early without one
        single = ids is not None
        if ids is not None:
            missing = [i for i in ids if i not in scene.segments]
            if missing:
                self.notify(client, "No such segment", f"Segment {missing[0]} is not in this scene.", "red")
                return []
            self._select(ids[0])
        usable, skipped = [], []
        for sid in ids if ids is not None else list(scene.segments):
            try:
                usable.append((sid, check_segment(scene.segments[sid].points_cam)))
            except SegmentTooSmallError as e:
                skipped.append(f"segment {sid}: {e}")
        if skipped:
            self.notify(
                client,
                "Cannot complete" if single else "Some segments were skipped",
                "; ".join(skipped),
                "red" if single else "yellow",
            )
        if not usable:
            return []
        what = f"segment {usable[0][0]}" if single else f"{len(usable)} segments"
        self.panel.status.content = f"_Completing {what}..._"
        try:
            done = self.res.pool.run(
                complete_points,
                [p for _, p in usable],
                self.res.completer,
                [sid for sid, _ in usable],
                support_plane=scene.segmentation.plane_cam,
                revolve_answers=self.panel.revolve.value,
                fit_boxes=self.panel.fit_boxes.value,
            )
            t0 = time.perf_counter()
            for c in done:
                self._draw_completion(c)
            self.audience.flush()
            send = time.perf_counter() - t0
        except Exception as e:  # keep the app alive whatever the model or mesher does
            log.exception("completing %s failed", what)
            self.notify(client, "Completion failed", f"{what}: {e}", "red")
            self.panel.status.content = READY
            return []
        self.completions.update({c.segment_id: c for c in done})
        title = f"Segment **{done[0].segment_id}**" if single else f"All **{len(done)}** segments (totals)"
        self.last_timings = P.completion_timings(done, scene.seg_seconds, send)
        self.panel.timings.content = P.completion_timings_markdown(title, self.last_timings)
        self.panel.status.content = f"Completed {what}. Click a segment to complete it."
        empty = [f"segment {c.segment_id}: {c.error}" for c in done if c.fast_mesh is None]
        if empty:
            self.notify(client, "Empty completion", "; ".join(empty), "yellow")
        return done

    def _compute_mesh_in_slot(
        self, kind: str, c: Completion, client: viser.ClientHandle | None
    ) -> trimesh.Trimesh | None:
        """Make, draw and store mesh ``kind`` of completion ``c`` (the caller holds the job slot)."""
        scene = self.scene
        assert scene is not None  # ``c`` is a completion of it
        sid, title = c.segment_id, MESH_TITLES[kind]
        what = f"the {title.lower()} of segment {sid}"
        notes = self.audience.loading(client, f"Computing {what}...")
        self.panel.status.content = f"_Computing {what}..._"
        steps: dict[str, float] = {}
        try:
            t0 = time.perf_counter()
            mesh = self.res.pool.run(make_mesh, kind, c, scene, steps)
            seconds = time.perf_counter() - t0
            t0 = time.perf_counter()
            self.drawing.draw_mesh(scene, kind, sid, mesh)
            self.audience.flush()
            send = time.perf_counter() - t0
        except Exception as e:  # an empty completion, a degenerate cloud, ...: keep the app alive
            log.warning("computing %s failed: %s", what, e, exc_info=not isinstance(e, ValueError))
            self.notify(client, f"{title} failed", f"Segment {sid}: {e}", "red")
            return None
        finally:
            for note in notes:
                note.remove()
            self.panel.status.content = READY
        setattr(c, f"{kind}_mesh", mesh)
        c.timings[f"{kind}_mesh"] = seconds
        if kind == "detailed":
            c.timings["detailed_steps"] = steps
        set_value(self.panel.layers[f"{kind}_mesh"], True)  # the user asked to see it
        self.panel.timings.content = P.mesh_timings_markdown(kind, c, send)
        self.notify(
            client, f"{title} ready", f"Segment {sid}: {len(mesh.faces):,} triangles in {seconds:.1f} s.", "green"
        )
        return mesh

    def _draw_completion(self, c: Completion) -> None:
        assert self.scene is not None  # ``c`` is a completion of it
        self.drawing.draw_completion(
            self.scene, c, self.panel.shade_output.value, self.panel.layers["cnn_output"].value
        )
        self.drawing.draw_sample(self.scene, c.segment_id, None)  # a sample of the previous completion
        set_value(self.panel.sample, 0)
        if self.panel.layers["confidence"].value:
            self.show_confidence(c)

    def show_confidence(self, c: Completion) -> None:
        """The Confidence layer of ``c`` (the disagreement of its 8 sample completions) and its
        figures in the stage panel."""
        spread = c.spread
        assert self.scene is not None  # ``c`` is a completion of it
        self.drawing.draw_confidence(self.scene, c, spread)
        self.panel.timings.content = P.confidence_markdown(
            c.segment_id, *confidence_figures(c.grid_in, c.solid, spread), c.axis, c.cuboid
        )

    def show_sample(self, k: int, client: viser.ClientHandle | None = None) -> trimesh.Trimesh | None:
        """Show sample completion ``k`` (1..8) of the selected segment as a translucent mesh in the
        Confidence layer (turned on), or none (``k`` = 0). Returns the camera-frame mesh shown."""
        sid = self.selected
        c = None if sid is None else self.completions.get(sid)
        if c is None or self.scene is None:
            if k:
                self.notify(client, "No completion selected", "Complete a segment, then step through its samples.")
            return None
        if not 0 <= k <= P.N_SAMPLES:
            raise ValueError(f"sample {k} out of range 0..{P.N_SAMPLES}")
        with self.jobs.take(client) as ok:
            if not ok:
                return None
            mesh = None
            if k:
                try:
                    mesh = self.res.pool.run(fast_mesh, c.samples[k - 1], c.frame, level=c.mesh_level)
                except ValueError as e:  # this sample has no surface: nothing to show
                    self.notify(client, "Empty sample", f"Sample {k} of segment {c.segment_id}: {e}", "yellow")
            self.drawing.draw_sample(self.scene, c.segment_id, mesh)
            self.audience.flush()
        if k:
            set_value(self.panel.layers["confidence"], True)  # the sample is drawn in that layer
            self.panel.status.content = f"Sample completion **{k}** of {P.N_SAMPLES} of segment {c.segment_id}."
        return mesh

    # ------------------------------------------------------------------------------------------
    # Loading

    def _read_capture(self, path: str | Path) -> Capture:
        if not str(path).strip():
            raise ValueError("enter the path of a .pcd/.ply cloud or a depth image")
        return load_capture(Path(str(path).strip()).expanduser(), intrinsics=self.res.intrinsics)

    def _load(self, make: Callable[[], Capture | LoadedScene], what: str, client: viser.ClientHandle | None) -> bool:
        with self.jobs.take(client) as ok:
            if not ok:
                return False
            notes = self.audience.loading(client, f"Loading {what}...")
            try:
                decimated = self._set_scene(self.res.pool.run(make), require_segment=True)
                if decimated is not None:
                    self.notify(client, "Large capture", decimated, "yellow")
                return True
            except Exception as e:  # any bad input: tell the user, keep the current scene
                log.warning("loading %s failed: %s", what, e, exc_info=not isinstance(e, (ValueError, OSError)))
                self.notify(client, "Could not load the capture", str(e) if what in str(e) else f"{what}: {e}", "red")
                return False
            finally:
                for note in notes:
                    note.remove()

    def _set_scene(self, source: Capture | LoadedScene, require_segment: bool = False) -> str | None:
        """Segment a capture (a :class:`LoadedScene` is already segmented: sessions share those,
        read-only) and replace the shown scene with it (raises, leaving the old scene, on failure).

        ``require_segment``: see :func:`~.state.load_scene`. Returns a note for the user when the
        capture was decimated (see :func:`~shapeviewer.perception.capture.decimate`), else None.
        """
        scene = source if isinstance(source, LoadedScene) else self.res.pool.run(load_scene, source, require_segment)
        capture = scene.capture
        if self.dataset is not None:
            self.dataset.leave()  # a new scene is what the user wants to see
        self.grasps.clear()
        self.scene, self.completions, self.selected, self.last_timings = scene, {}, None, {}
        self.drawing.show_scene(scene, self.panel.cloud_colors.value == "capture")
        self.audience.flush()

        n_valid = int(capture.valid_mask().sum())
        self.panel.source.content = P.source_markdown(
            scene.title,
            len(capture.flat_points()),
            n_valid,
            len(scene.segments),
            scene.seg_seconds,
            f"world: {scene.frame_note}",
            scene.segmentation.min_height,
        )
        decimated = capture.decimation_note()
        sent = self.drawing.sent_points()
        if decimated is not None or sent < n_valid:
            decimated = "; ".join(filter(None, [decimated, f"showing {sent:,} points"]))
            self.panel.source.content += f"  \n_{decimated}_"
        self.segment_options = scene.segment_options
        self.panel.segment.options = (P.NO_SEGMENT, *self.segment_options)
        set_value(self.panel.segment, P.NO_SEGMENT)
        if capture.colors is None:
            set_value(self.panel.cloud_colors, "depth")
        self.panel.timings.content = P.timings_markdown("No completion yet.", [("segmentation", scene.seg_seconds)])
        self.panel.status.content = (
            "Ready. **Click a segment** in the 3D view to complete it."
            if scene.segments
            else "**No segments found** in this capture."
        )
        return decimated if capture.original_points is not None else None

    # ------------------------------------------------------------------------------------------
    # Panel and the grasp controller's host

    def _select(self, segment_id: int | None) -> None:
        self.selected = segment_id
        if segment_id is None:
            set_value(self.panel.segment, P.NO_SEGMENT)
            return
        set_value(self.panel.segment, next(o for o, sid in self.segment_options.items() if sid == segment_id))

    def _set_status(self, text: str) -> None:
        self.panel.status.content = text

    def _show_layer(self, key: str, visible: bool) -> None:
        set_value(self.panel.layers[key], visible)

    def _existing_mesh(self, kind: str, segment_id: int) -> trimesh.Trimesh | None:
        c = self.completions.get(segment_id)
        return None if c is None else getattr(c, f"{kind}_mesh")

    def _sample_meshes_world(self, segment_id: int) -> list[trimesh.Trimesh] | None:
        c, scene = self.completions.get(segment_id), self.scene
        if c is None or scene is None:
            return None
        return sample_meshes(c.samples, c.frame, scene.T_world_cam, level=c.mesh_level)

    def _make_mesh_for_grasps(
        self, kind: str, segment_id: int, client: viser.ClientHandle | None
    ) -> trimesh.Trimesh | None:
        if kind == "fast":
            c = self.complete(segment_id, client)
            return None if c is None else c.fast_mesh
        return self.compute_mesh(kind, segment_id, client)
