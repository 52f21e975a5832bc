"""The web viewer of the paper's runtime pipeline (Fig. 5, steps 1-5a), served with viser.

Everything is drawn in the WORLD frame (metres, z up): a synthetic capture knows its camera pose
(``Capture.T_world_cam``, table top at z = 0); for a real capture the segmentation estimates a
table-aligned world frame (``Segmentation.T_world_cam``). Pipeline results come in the camera
optical frame and are mapped with that ``T_world_cam`` before they are sent.

Scene nodes: every pipeline stage is a layer, a frame ``/<layer key>`` (see :data:`panel.LAYERS`)
whose children are that stage's nodes, e.g. ``/segments/seg_3``, ``/cnn_input/seg_3``,
``/fast_mesh/seg_3``, ``/detailed_mesh/seg_3``, ``/mirror_mesh/seg_3``; the layer checkbox toggles
the frame's visibility. ``/sensor`` is the camera frustum and ``/table`` the table-plane hint.
The Dataset tab (:mod:`.dataset`) draws under ``/dataset`` and hides all of these while it is shown.
Grasps (:mod:`.grasps`, step 6) are hands under ``/grasps/seg_3/g0``, ...

:class:`ViewerApp` can be driven without a browser (tests call :meth:`ViewerApp.complete`,
:meth:`ViewerApp.pick`, ...); GUI callbacks call the same methods. Plain ``def`` callbacks run in
viser's thread pool, so one lock serialises jobs (loading, completing, detailed and baseline
meshes) and the job buttons are disabled while one runs. Grasp planning and execution run in their
own background thread outside that lock (:class:`~.grasps.GraspController`, one grasp job at a time).
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
import viser
from PIL import Image

from .. import export
from ..baselines import hull_mesh, mirror_mesh, partial_mesh
from ..camera import Intrinsics, transform_points
from ..capture import MAX_CAPTURE_POINTS, Capture, decimate, load_capture
from ..model import load_completer, training_curves
from ..pipeline import Completion, SegmentTooSmallError, check_segment, complete_points
from ..reconstruct import detailed_mesh
from ..segment import Segment, Segmentation, segment_scene
from . import panel as P
from .dataset import DatasetHooks, DatasetTab
from .grasps import GraspController, GraspJob
from .guard import Guard, server_url, start_server
from .rays import first_hit
from .visuals import (default_view, depth_colors, probability_colors, shade, spread_colors, surface_voxels,
                      voxel_cubes)

log = logging.getLogger(__name__)

CLOUD_POINT_SIZE = 0.0015  # metres; viser draws points about twice this wide
SEGMENT_POINT_SIZE = 0.002  # a little larger, so segment colours win over the cloud at the same spots
INPUT_VOXEL_FILL = 0.5  # cube edge / voxel edge: small cubes let the fast mesh show between them
OUTPUT_VOXEL_FILL = 0.95
# Fixed colours for the baselines, so that they never pass for one of our own (segment-coloured) meshes.
PARTIAL_COLOR = (160, 160, 160)
MIRROR_COLOR = (110, 150, 215)
HULL_COLOR = (150, 120, 190)
MESH_TITLES = {"detailed": "Detailed mesh", "partial": "Partial baseline", "mirror": "Mirror baseline",
               "hull": "Hull baseline"}
# Algorithm 1's steps, as keys of the ``timings`` dict that ``detailed_mesh`` fills, with panel labels.
ALGORITHM_1_STEPS = (("density", "density ratio"), ("upsample", "up-sample CNN output"), ("merge", "merge"),
                     ("fill_gaps", "fill gaps"), ("smooth", "smooth"), ("marching_cubes", "marching cubes"))
READY = "Ready. Click a segment to complete it."
# Points sent to a browser per scene (the cloud and the segments; picking and the pipeline use all
# of them): a browser draws 300k points smoothly, millions not at all. The segments get up to
# MAX_SEGMENT_POINTS of the budget, the cloud the rest.
MAX_SENT_POINTS = 300_000
MAX_SEGMENT_POINTS = 100_000


@dataclass
class LoadedScene:
    """A capture with its segmentation, ready to be shown.

    Attributes:
        capture: the capture (camera-frame points).
        segmentation: ``segment_scene(capture)``.
        T_world_cam: 4x4 camera pose in the world frame the viewer draws in.
        seg_seconds: wall time of the segmentation.
        segments: segment id -> segment.
        points_world: segment id -> its finite points in world metres (for picking).
    """

    capture: Capture
    segmentation: Segmentation
    T_world_cam: np.ndarray
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
            return f"default_seed{src[len('default(seed='):-1]}"
        return Path(src).stem or "capture"


class ViewerApp:
    """The viewer: a viser server, its panel, and the currently loaded scene.

    Args:
        host, port: where to serve (viser takes the next free port if ``port`` is busy: see ``.port``).
        seed: seed of the generated default scene (used when ``cloud`` is None).
        cloud: a capture file path (.pcd/.ply/.png/.npy), a :class:`Capture`, or None (default scene).
        weights: CNN weights file; None = the shipped model (untrained fallback when absent).
        intrinsics: camera intrinsics for depth images.
        max_cloud_points: draw at most this many points of the Cloud layer (None = what is left of
            :data:`MAX_SENT_POINTS` after the segments); picking and completion use every point.
        announce: called with the URL as soon as the server listens (before the scene is built).
        token: the URL token required off localhost (default: a random one; see :mod:`.guard`).
        allow_hosts: further ``Host`` names to answer to besides localhost and ``host``.
        results: the Dataset tab's results store: a folder written by ``shapeviewer evaluate``,
            ``"default"`` (a small sample store, built in the background on first use), or None (none).
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 8080, seed: int = 0,
                 cloud: str | Path | Capture | None = None, weights: str | Path | None = None,
                 intrinsics: Intrinsics | None = None, max_cloud_points: int | None = None,
                 announce: Callable[[str], None] | None = None, results: str | Path | None = None,
                 token: str | None = None, allow_hosts: tuple[str, ...] = ()) -> None:
        # Only this machine's browser (or, off localhost, holders of the token) may drive the app.
        self.guard = Guard.for_host(host, token, allow_hosts)
        self.server = start_server(host, port, self.guard)
        self.port = self.server.get_port()
        self.host = host
        self.intrinsics = intrinsics
        self.max_cloud_points = max_cloud_points
        self.scene: LoadedScene | None = None
        self.completions: dict[int, Completion] = {}
        self.selected: int | None = None
        self.last_timings: dict[str, float] = {}
        self.last_error: str | None = None
        self._job = threading.Lock()
        self._nodes: dict[str, viser.SceneNodeHandle] = {}
        self._loading_notes: dict[int, viser.NotificationHandle] = {}
        self._segment_options: dict[str, int] = {}  # dropdown entry -> segment id
        self.dataset: DatasetTab | None = None
        self._pipeline_visible = True  # False while the Dataset tab shows its scene

        self.server.gui.configure_theme(control_width="medium", show_share_button=False)
        # Docked, the panel takes its own column instead of floating over (and hiding) the scene.
        self.server.gui.main_panel.dock_right()
        self.server.scene.set_up_direction("+z")
        tabs = self.server.gui.add_tab_group()
        pipeline_tab = tabs.add_tab("Pipeline", viser.Icon.CUBE)
        dataset_tab = tabs.add_tab("Dataset", viser.Icon.DATABASE)
        with pipeline_tab:
            self.panel = P.build_panel(self.server.gui, seed)
        self._layer_roots = {layer.key: self.server.scene.add_frame(f"/{layer.key}", show_axes=False,
                                                                    visible=layer.visible)
                             for layer in P.LAYERS}
        with pipeline_tab:
            # The Grasps folder goes right after Completion (viser orders folders by a global counter).
            self.grasps = GraspController(self, order=self.panel.timings.order + 0.5)
        self._wire_callbacks()
        if announce is not None:
            announce(self.url)

        try:
            self.dataset = DatasetTab(self.server, dataset_tab, pipeline_tab, results,
                                      DatasetHooks(self.set_pipeline_visible, self.load_capture, self._notify), weights)
            with self._job_slot(None) as ok:
                assert ok  # nothing else can run yet
                self.completer = load_completer(weights)
                self.dataset.start_background(self.completer)
                c = self.completer
                self.panel.model.content = P.model_markdown(c.arch, Path(c.source).name, c.trained, c.meta)
                curves = training_curves(c)
                if curves is not None:  # the paper's Fig. 4 for these weights
                    with self.panel.model_folder:
                        self.server.gui.add_image(np.asarray(Image.open(curves).convert("RGB")),
                                                  label="Jaccard during training", format="png")
                if isinstance(cloud, Capture):
                    capture = cloud
                elif cloud is not None:
                    capture = self._read_capture(cloud)
                else:
                    capture = self._default_capture(seed)
                self._set_scene(capture)
        except BaseException:  # a bad --cloud/--weights/--results: do not leave the server thread running
            self.server.stop()
            raise

    # ------------------------------------------------------------------------------------------
    # Public API (the GUI callbacks call these too)

    @property
    def url(self) -> str:
        """The URL to open (with ``?token=...`` when the server is reachable off this machine)."""
        return server_url(self.host, self.port, self.guard)

    def stop(self) -> None:
        self.grasps.shutdown()
        if self.dataset is not None:
            self.dataset.shutdown()
        self.server.stop()

    def load_default(self, seed: int, client: viser.ClientHandle | None = None) -> bool:
        """Generate and show the tabletop scene of ``seed``. False (and a notification) on failure."""
        return self._load(lambda: self._default_capture(seed), f"scene seed {seed}", client)

    def load_cloud(self, path: str | Path, client: viser.ClientHandle | None = None) -> bool:
        """Load and show a capture file. On a bad file: False, an error notification, old scene kept."""
        return self._load(lambda: self._read_capture(path), str(path), client)

    def load_capture(self, capture: Capture, client: viser.ClientHandle | None = None) -> bool:
        """Show an already loaded capture."""
        return self._load(lambda: capture, capture.source, client)

    def set_pipeline_visible(self, visible: bool) -> None:
        """Show or hide every pipeline node (the Dataset tab draws in the same 3D scene); layers keep
        their checkboxes' state."""
        self._pipeline_visible = visible
        for key, root in self._layer_roots.items():
            root.visible = visible and self.panel.layers[key].value
        for name in ("/sensor", "/table"):
            if name in self._nodes:
                self._nodes[name].visible = visible

    def pick(self, ray_origin: np.ndarray, ray_direction: np.ndarray) -> int | None:
        """The segment a world-frame ray hits first (None when it misses all segments)."""
        return self.pick_hit(ray_origin, ray_direction)[0]

    def pick_hit(self, ray_origin: np.ndarray, ray_direction: np.ndarray) -> tuple[int | None, float]:
        """:meth:`pick` and how far along the ray (metres) it hits: ``(None, inf)`` on a miss."""
        if self.scene is None:
            return None, np.inf
        return first_hit(ray_origin, ray_direction, self.scene.points_world)

    def click(self, ray_origin: np.ndarray, ray_direction: np.ndarray,
              client: viser.ClientHandle | None = None) -> str:
        """A click in the 3D view (world-frame ray): a grasp's hand in front of the segments
        selects that grasp, a segment is completed. Returns what happened: ``"grasp"``,
        ``"segment"`` or ``"nothing"``."""
        k, t_hand = self.grasps.pick(ray_origin, ray_direction)
        sid, t_segment = self.pick_hit(ray_origin, ray_direction)
        if k is not None and t_hand <= t_segment:
            self.grasps.select(k)
            return "grasp"
        if sid is None:
            self._notify(client, "No segment there", "Click on a coloured segment, or on a grasp's hand.",
                         auto_close=3.0)
            return "nothing"
        self.complete(sid, client)
        return "segment"

    def segment_centroid_world(self, segment_id: int) -> np.ndarray:
        """Mean of a segment's points, world metres."""
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

    def compute_mesh(self, kind: str, segment_id: int | None = None,
                     client: viser.ClientHandle | None = None) -> trimesh.Trimesh | None:
        """Compute, store on the completion and draw a segment's ``detailed``, ``partial``, ``mirror`` or ``hull`` mesh.

        The segment (default: the selected one) is fast-completed first if it has no completion yet.
        Returns the camera-frame mesh, or None when it cannot be made or another job is running
        (the client is told why).
        """
        if kind not in MESH_TITLES:
            raise ValueError(f"unknown mesh {kind!r}; choose one of {tuple(MESH_TITLES)}")
        sid = self.selected if segment_id is None else segment_id
        if sid is None:
            self._notify(client, "No segment selected", "Click a segment or pick one above.", "yellow")
            return None
        with self._job_slot(client) as ok:
            if not ok or self.scene is None:
                return None
            if kind == "mirror" and self.scene.segmentation.plane_cam is None:
                self._notify(client, "Mirror needs a support plane",
                             "No table plane was found in this capture, and the Mirror baseline searches its "
                             "symmetry plane perpendicular to the table.", "red")
                return None
            c = self.completions.get(sid)
            if c is None:
                done = self._complete_in_slot([sid], client)
                if not done:
                    return None
                c = done[0]
            self._select(sid)
            return self._compute_mesh_in_slot(kind, c, client)

    def plan_grasps(self, segment_id: int | None = None, hand: str = "barrett", method: str = "fast",
                    n_grasps: int = 20, client: viser.ClientHandle | None = None, wait: bool = True, seed: int = 0,
                    budget_seconds: float | None = None) -> GraspJob | None:
        """Plan grasps on a segment's (default: the selected one's) ``method`` mesh in the background,
        outside the job lock; see :meth:`GraspController.plan`. ``job.result``: the
        :class:`~shapeviewer.viewer.grasps.SegmentGrasps` (None when cancelled)."""
        return self.grasps.plan(self.selected if segment_id is None else segment_id, hand, method, n_grasps,
                                client, wait, seed, budget_seconds)

    def cancel_grasps(self) -> bool:
        """Stop the running grasp job (False when none runs)."""
        return self.grasps.cancel()

    def execute_grasps(self, segment_id: int | None = None, indices: list[int] | None = None,
                       client: viser.ClientHandle | None = None, wait: bool = True,
                       lift: bool = True) -> GraspJob | None:
        """Execute a segment's grasps ``indices`` (None: all) on its true object (synthetic scenes);
        ``job.result``: the :class:`~shapeviewer.grasp.execute.ExecutionResult` list."""
        return self.grasps.execute(self.grasps.current if segment_id is None else segment_id, indices, client,
                                   wait, lift)

    def export_grasps(self, segment_id: int | None = None, fmt: str = "json") -> tuple[str, bytes]:
        """``(file name, content)`` of a segment's grasps: ``json`` or the pybullet scene ``zip``."""
        return self.grasps.export(self.grasps.current if segment_id is None else segment_id, fmt)

    def export_bytes(self, kind: str, segment_id: int | None = None, mesh_format: str = "ply",
                     frame: str = "world", mesh: str = "fast") -> tuple[str, bytes]:
        """``(file name, content)`` of an export of a segment (default: the selected one).

        Args:
            kind: ``points`` (PLY of the segment's points), ``grids`` (NPZ of the CNN input grid,
                output probabilities and grid frame) or ``mesh``.
            mesh_format: ``ply``, ``obj``, ``stl`` or ``glb`` (meshes only).
            frame: ``world`` or ``camera`` coordinates (points and meshes; grids carry both).
            mesh: which mesh, one of :data:`panel.MESH_KINDS` (``fast``, ``detailed``, ``partial``, ``mirror``).

        Raises:
            ValueError: with a message for the user (nothing selected, not completed yet, ...).
        """
        sid = self.selected if segment_id is None else segment_id
        if self.scene is None or sid is None or sid not in self.scene.segments:
            raise ValueError("Select a segment first (click it, or pick it in the Completion folder).")
        T, stem = self.scene.T_world_cam, f"{self.scene.name}_seg{sid}"
        if kind == "points":
            seg = self.scene.segments[sid]
            colors = self.scene.capture.flat_colors()
            data = export.points_ply_bytes(seg.points_cam, None if colors is None else colors[seg.indices],
                                           frame, T)
            return f"{stem}_points_{frame}.ply", data
        c = self.completions.get(sid)
        if c is None:
            raise ValueError(f"Segment {sid} has no completion yet: complete it first.")
        if kind == "grids":
            return f"{stem}_grids.npz", export.grids_npz_bytes(c.grid_in, c.probabilities, c.frame, T)
        if kind == "mesh":
            if mesh not in P.MESH_KINDS:
                raise ValueError(f"unknown mesh {mesh!r}; choose one of {P.MESH_KINDS}")
            m = getattr(c, f"{mesh}_mesh")
            if m is None and mesh == "fast":
                raise ValueError(f"Segment {sid} has no fast mesh: {c.error}")
            if m is None:
                raise ValueError(f"Segment {sid} has no {MESH_TITLES[mesh].lower()} yet: compute it in the "
                                 "Completion folder first.")
            return f"{stem}_{mesh}_{frame}.{mesh_format}", export.mesh_bytes(m, mesh_format, frame, T)
        raise ValueError(f"unknown export {kind!r}")

    # ------------------------------------------------------------------------------------------
    # Completing

    def _complete(self, ids: list[int] | None, client: viser.ClientHandle | None) -> list[Completion]:
        """Complete segments ``ids`` (None: all) in one batch, draw them, and fill the timings table."""
        with self._job_slot(client) as ok:
            if not ok or self.scene is None:
                return []
            return self._complete_in_slot(ids, client)

    def _complete_in_slot(self, ids: list[int] | None, client: viser.ClientHandle | None) -> list[Completion]:
        """:meth:`_complete` for a caller that holds the job slot (and has a scene)."""
        single = ids is not None
        if single:
            missing = [i for i in ids if i not in self.scene.segments]
            if missing:
                self._notify(client, "No such segment", f"Segment {missing[0]} is not in this scene.", "red")
                return []
            self._select(ids[0])
        usable, skipped = [], []
        for sid in ids if single else list(self.scene.segments):
            try:
                usable.append((sid, check_segment(self.scene.segments[sid].points_cam)))
            except SegmentTooSmallError as e:
                skipped.append(f"segment {sid}: {e}")
        if skipped:
            self._notify(client, "Cannot complete" if single else "Some segments were skipped",
                         "; ".join(skipped), "red" if single else "yellow")
        if not usable:
            return []
        what = f"segment {usable[0][0]}" if single else f"{len(usable)} segments"
        self.panel.status.content = f"_Completing {what}..._"
        try:
            done = complete_points([p for _, p in usable], self.completer, [sid for sid, _ in usable],
                                   support_plane=self.scene.segmentation.plane_cam)
            t0 = time.perf_counter()
            for c in done:
                self._draw_completion(c)
            self.server.flush()
            send = time.perf_counter() - t0
        except Exception as e:  # keep the app alive whatever the model or mesher does
            log.exception("completing %s failed", what)
            self._notify(client, "Completion failed", f"{what}: {e}", "red")
            self.panel.status.content = READY
            return []
        self.completions.update({c.segment_id: c for c in done})
        title = f"Segment **{done[0].segment_id}**" if single else f"All **{len(done)}** segments (totals)"
        self._show_timings(title, done, send)
        self.panel.status.content = f"Completed {what}. Click a segment to complete it."
        empty = [f"segment {c.segment_id}: {c.error}" for c in done if c.fast_mesh is None]
        if empty:
            self._notify(client, "Empty completion", "; ".join(empty), "yellow")
        return done

    def _compute_mesh_in_slot(self, kind: str, c: Completion,
                              client: viser.ClientHandle | None) -> trimesh.Trimesh | None:
        """Make, draw and store mesh ``kind`` of completion ``c`` (the caller holds the job slot)."""
        sid, title = c.segment_id, MESH_TITLES[kind]
        what = f"the {title.lower()} of segment {sid}"
        notes = self._show_loading(client, f"Computing {what}...")
        self.panel.status.content = f"_Computing {what}..._"
        steps: dict[str, float] = {}
        try:
            t0 = time.perf_counter()
            mesh = self._make_mesh(kind, c, steps)
            seconds = time.perf_counter() - t0
            t0 = time.perf_counter()
            self._draw_mesh(kind, sid, mesh)
            self.server.flush()
            send = time.perf_counter() - t0
        except Exception as e:  # an empty completion, a degenerate cloud, ...: keep the app alive
            log.warning("computing %s failed: %s", what, e, exc_info=not isinstance(e, ValueError))
            self._notify(client, f"{title} failed", f"Segment {sid}: {e}", "red")
            return None
        finally:
            for note in notes:
                note.remove()
            self.panel.status.content = READY
        setattr(c, f"{kind}_mesh", mesh)
        c.timings[f"{kind}_mesh"] = seconds
        if kind == "detailed":
            c.timings["detailed_steps"] = steps
        self.panel.layers[f"{kind}_mesh"].value = True  # the user asked to see it
        self._show_mesh_timings(kind, c, send)
        self._notify(client, f"{title} ready", f"Segment {sid}: {len(mesh.faces):,} triangles in {seconds:.1f} s.",
                     "green")
        return mesh

    def _make_mesh(self, kind: str, c: Completion, steps: dict[str, float]) -> trimesh.Trimesh:
        """Camera-frame mesh ``kind`` of ``c``'s segment; ``steps`` gets Algorithm 1's step times."""
        points = self.scene.segments[c.segment_id].points_cam
        if kind == "detailed":
            return detailed_mesh(c.probabilities, c.frame, points, timings=steps, support_plane=c.support_plane)
        if kind == "partial":
            return partial_mesh(points)
        if kind == "hull":
            return hull_mesh(points)
        return mirror_mesh(points, self.scene.segmentation.plane_cam)

    # ------------------------------------------------------------------------------------------
    # Loading

    def _default_capture(self, seed: int) -> Capture:
        from ..sim.demo_scene import default_scene  # pybullet and the object catalogue: only when needed

        return default_scene(int(seed))

    def _read_capture(self, path: str | Path) -> Capture:
        if not str(path).strip():
            raise ValueError("enter the path of a .pcd/.ply cloud or a depth image")
        return load_capture(Path(str(path).strip()).expanduser(), intrinsics=self.intrinsics)

    def _load(self, make: Callable[[], Capture], what: str, client: viser.ClientHandle | None) -> bool:
        with self._job_slot(client) as ok:
            if not ok:
                return False
            notes = self._show_loading(client, f"Loading {what}...")
            try:
                note = self._set_scene(make(), require_segment=True)
                if note is not None:
                    self._notify(client, "Large capture", note, "yellow")
                return True
            except Exception as e:  # any bad input: tell the user, keep the current scene
                log.warning("loading %s failed: %s", what, e, exc_info=not isinstance(e, (ValueError, OSError)))
                self._notify(client, "Could not load the capture", str(e) if what in str(e) else f"{what}: {e}", "red")
                return False
            finally:
                for note in notes:
                    note.remove()

    def _set_scene(self, capture: Capture, require_segment: bool = False) -> str | None:
        """Segment ``capture`` and replace the shown scene with it (raises, leaving the old scene, on failure).

        ``require_segment``: refuse (ValueError) a capture without a segment that can be completed,
        rather than replace the user's scene with an empty one. Returns a note for the user when
        the capture was decimated (see :func:`~shapeviewer.capture.decimate`), else None.
        """
        capture = decimate(capture, MAX_CAPTURE_POINTS)  # load_capture did it for files; not for Captures
        t0 = time.perf_counter()
        seg = segment_scene(capture)
        seg_seconds = time.perf_counter() - t0
        if require_segment and not any(_usable(s) for s in seg.segments):
            found = (f"none of its {len(seg.segments)} segments is large enough to complete" if seg.segments
                     else f"no segments found among its {int(capture.valid_mask().sum()):,} valid points")
            raise ValueError(f"{found}; the current scene is kept")
        # Synthetic scenes know the true table frame; real ones use the segmentation's estimate.
        T = np.asarray(capture.T_world_cam if capture.objects else seg.T_world_cam, dtype=np.float64)
        segments = {s.id: s for s in seg.segments}
        points_world = {}
        for s in seg.segments:
            pts = np.asarray(s.points_cam, dtype=np.float64)
            points_world[s.id] = transform_points(T, pts[np.isfinite(pts).all(axis=1)])
        scene = LoadedScene(capture, seg, T, seg_seconds, segments, points_world)

        if self.dataset is not None:
            self.dataset.leave()  # a new scene is what the user wants to see
        self._clear_nodes()
        self.grasps.clear()
        self.scene, self.completions, self.selected, self.last_timings = scene, {}, None, {}
        self._draw_cloud()
        self._draw_segments()
        self._draw_sensor_and_table()
        self._set_default_view()
        self.server.flush()

        n_valid = int(capture.valid_mask().sum())
        note = "world: simulated table frame" if capture.objects else "world: table plane from segmentation"
        self.panel.source.content = P.source_markdown(scene.title, len(capture.flat_points()), n_valid,
                                                      len(segments), seg_seconds, note)
        decimated = capture.decimation_note()
        sent = len(self._nodes["/cloud/points"].points) + sum(
            len(self._nodes[f"/segments/seg_{sid}"].points) for sid in segments if f"/segments/seg_{sid}" in self._nodes)
        if decimated is not None or sent < n_valid:
            decimated = "; ".join(filter(None, [decimated, f"showing {sent:,} points"]))
            self.panel.source.content += f"  \n_{decimated}_"
        self._segment_options = {s.label or f"segment {s.id}": s.id for s in seg.segments}
        self.panel.segment.options = (P.NO_SEGMENT, *self._segment_options)
        self.panel.segment.value = P.NO_SEGMENT
        if capture.colors is None:
            self.panel.cloud_colors.value = "depth"
        self.panel.timings.content = P.timings_markdown("No completion yet.", [("segmentation", seg_seconds)])
        self.panel.status.content = ("Ready. **Click a segment** in the 3D view to complete it." if segments
                                     else "**No segments found** in this capture.")
        return decimated if capture.original_points is not None else None

    # ------------------------------------------------------------------------------------------
    # Drawing

    def _add(self, name: str, make: Callable[..., viser.SceneNodeHandle], *args, **kwargs) -> None:
        """Add (or replace) scene node ``name`` and remember it so a new scene can clear it."""
        self._nodes[name] = make(name, *args, **kwargs)

    def _remove(self, name: str) -> None:
        handle = self._nodes.pop(name, None)
        if handle is not None:
            handle.remove()

    def _clear_nodes(self) -> None:
        for name in list(self._nodes):
            self._remove(name)

    def _draw_cloud(self) -> None:
        capture, T = self.scene.capture, self.scene.T_world_cam
        valid = capture.valid_mask()
        pts_cam = capture.flat_points()[valid]
        if self.panel.cloud_colors.value == "capture" and capture.colors is not None:
            colors = capture.flat_colors()[valid]
        else:
            colors = depth_colors(pts_cam[:, 2])
        budget = MAX_SENT_POINTS - sum(len(p) for p in self._segment_display_points().values())
        if self.max_cloud_points is not None:
            budget = min(budget, self.max_cloud_points)
        if len(pts_cam) > budget:
            keep = np.random.default_rng(0).choice(len(pts_cam), budget, replace=False)
            pts_cam, colors = pts_cam[keep], colors[keep]
        self._add("/cloud/points", self.server.scene.add_point_cloud, transform_points(T, pts_cam), colors,
                  point_size=CLOUD_POINT_SIZE, precision="float32", point_shading="flat")

    def _segment_display_points(self) -> dict[int, np.ndarray]:
        """Segment id -> the world points drawn for it: one common stride keeps MAX_SEGMENT_POINTS in all."""
        total = sum(len(p) for p in self.scene.points_world.values())
        stride = max(1, -(-total // MAX_SEGMENT_POINTS))
        return {sid: p[::stride] for sid, p in self.scene.points_world.items()}

    def _draw_segments(self) -> None:
        shown = self._segment_display_points()
        for sid, seg in self.scene.segments.items():
            pts = shown[sid]
            if len(pts) == 0:
                continue
            self._add(f"/segments/seg_{sid}", self.server.scene.add_point_cloud, pts,
                      tuple(int(v) for v in seg.color), point_size=SEGMENT_POINT_SIZE, precision="float32")
            top = pts[np.argmax(pts[:, 2])]
            self._add(f"/segments/label_{sid}", self.server.scene.add_label, str(sid),
                      position=top + np.array([0.0, 0.0, 0.03]), anchor="bottom-center", font_screen_scale=0.9)

    def _draw_sensor_and_table(self) -> None:
        T = self.scene.T_world_cam
        intr = self.scene.capture.intrinsics or Intrinsics.kinect()
        wxyz = viser.transforms.SO3.from_matrix(T[:3, :3]).wxyz
        self._add("/sensor", self.server.scene.add_camera_frustum, fov=2 * np.arctan2(intr.height / 2, intr.fy),
                  aspect=intr.width / intr.height, scale=0.08, thickness=0.003, color=(60, 60, 60),
                  wxyz=wxyz, position=T[:3, 3])
        focus, _ = self._focus()
        # The table (or floor) is the plane z = 0 of the world frame.
        self._add("/table", self.server.scene.add_grid, width=1.5, height=1.5, plane="xy", cell_size=0.1,
                  section_size=0.5, position=(focus[0], focus[1], 0.0), plane_color=(235, 230, 220),
                  plane_opacity=0.35, shadow_opacity=0.0)

    def _draw_completion(self, c: Completion) -> None:
        """Draw one completion's CNN input, CNN output and meshes in the world frame.

        A new completion has no detailed or baseline mesh yet, so this also removes those of an
        earlier completion of the same segment.
        """
        sid = c.segment_id
        color = np.asarray(self.scene.segments[sid].color)
        # The fast mesh goes first: it is what the user waits for (and what the benchmark times).
        for kind in P.MESH_KINDS:
            self._draw_mesh(kind, sid, getattr(c, f"{kind}_mesh"))
        self._draw_voxels(f"/cnn_input/seg_{sid}", surface_voxels(c.grid_in), c, INPUT_VOXEL_FILL,
                          shade(color, 0.55))
        self._draw_output(c)
        if self.panel.layers["confidence"].value:
            self._draw_confidence(c)

    def _draw_mesh(self, kind: str, sid: int, mesh: trimesh.Trimesh | None) -> None:
        """Draw (or, when None, remove) segment ``sid``'s camera-frame mesh ``kind`` in the world frame."""
        name = f"/{kind}_mesh/seg_{sid}"
        if mesh is None:
            self._remove(name)
            return
        color = np.asarray(self.scene.segments[sid].color)
        colors = {"fast": shade(color, 1.35), "detailed": shade(color, 0.7), "partial": PARTIAL_COLOR,
                  "mirror": MIRROR_COLOR, "hull": HULL_COLOR}
        self._add(name, self.server.scene.add_mesh_simple, transform_points(self.scene.T_world_cam, mesh.vertices),
                  np.asarray(mesh.faces), color=colors[kind], cast_shadow=False, receive_shadow=False)

    def _draw_output(self, c: Completion) -> None:
        idx = surface_voxels(c.grid_out)
        if self.panel.shade_output.value:
            colors = probability_colors(c.probabilities[tuple(idx.T)])
        else:
            colors = shade(np.asarray(self.scene.segments[c.segment_id].color), 1.5)
        self._draw_voxels(f"/cnn_output/seg_{c.segment_id}", idx, c, OUTPUT_VOXEL_FILL, colors)

    def _draw_confidence(self, c: Completion) -> None:
        """The surface voxels of the CNN output, coloured by the spread of 8 sample completions
        (computed on first use: about 8 CNN passes), and the spread on the seen and unseen side."""
        if c.samples is None:
            c.samples = self.completer.predict_samples(c.grid_in, 8, context=c.context)
        spread = c.samples.std(axis=0)
        idx = surface_voxels(c.grid_out)
        self._draw_voxels(f"/confidence/seg_{c.segment_id}", idx, c, OUTPUT_VOXEL_FILL,
                          spread_colors(spread[tuple(idx.T)]))
        from scipy import ndimage

        occupied = c.grid_out
        seen = ndimage.binary_dilation(c.grid_in) & occupied
        unseen = occupied & ~seen
        figures = [(what, float(spread[m].mean())) for what, m in (("seen", seen), ("unseen", unseen)) if m.any()]
        guessed = float((spread[occupied] > 0.1).mean()) if occupied.any() else 0.0
        self.panel.timings.content = (
            f"Segment **{c.segment_id}**: confidence of the completion  \n"
            + " · ".join(f"mean spread {what} side **{v:.3f}**" for what, v in figures)
            + f"  \n{100 * guessed:.0f}% of the completed voxels are a guess (spread > 0.1)")

    def _draw_voxels(self, name: str, indices: np.ndarray, c: Completion, fill: float, colors) -> None:
        if len(indices) == 0:
            self._remove(name)
            return
        cubes = voxel_cubes(indices, c.frame, self.scene.T_world_cam, fill)
        identity = np.broadcast_to(np.array([1.0, 0.0, 0.0, 0.0], np.float32), (len(indices), 4))
        self._add(name, self.server.scene.add_batched_meshes_simple, cubes.vertices, cubes.faces,
                  batched_wxyzs=identity, batched_positions=cubes.positions, batched_colors=colors,
                  lod="off", flat_shading=True, cast_shadow=False, receive_shadow=False)

    def _focus(self) -> tuple[np.ndarray, float]:
        """World point the view centres on and the width (m) of the region to show.

        Both come from the 2nd-98th percentiles of the segment points (of the cloud when there
        are no segments), so that a few small far-away segments do not pull the view off the
        objects that make up most of the scene.
        """
        pts = [p for p in self.scene.points_world.values() if len(p)]
        if pts:
            allp = np.concatenate(pts)
        else:
            cloud = self.scene.capture.flat_points()[self.scene.capture.valid_mask()]
            allp = transform_points(self.scene.T_world_cam, cloud[:: max(1, len(cloud) // 20000)])
        lo, hi = np.percentile(allp, [2, 98], axis=0)
        return (lo + hi) / 2, float((hi - lo)[:2].max())

    def _set_default_view(self) -> None:
        focus, extent = self._focus()
        position, look_at = default_view(self.scene.T_world_cam, focus, max(extent, 0.3))
        cam = self.server.initial_camera
        cam.position, cam.look_at, cam.up = position, look_at, (0.0, 0.0, 1.0)
        for client in self.server.get_clients().values():
            try:
                with client.atomic():
                    client.camera.up_direction = (0.0, 0.0, 1.0)
                    client.camera.position = position
                    client.camera.look_at = look_at
            except AssertionError:  # the client has not reported its camera yet; it starts from initial_camera
                pass

    # ------------------------------------------------------------------------------------------
    # Panel

    def _select(self, segment_id: int | None) -> None:
        self.selected = segment_id
        if segment_id is None:
            self.panel.segment.value = P.NO_SEGMENT
            return
        self.panel.segment.value = next(o for o, sid in self._segment_options.items() if sid == segment_id)

    def _show_timings(self, title: str, done: list[Completion], send: float) -> None:
        total = {k: sum(c.timings.get(k, 0.0) for c in done) for k in ("voxelize", "cnn", "fast_mesh")}
        self.last_timings = {"segmentation": self.scene.seg_seconds, "voxelize": total["voxelize"],
                             "cnn": total["cnn"], "marching_cubes": total["fast_mesh"], "send": send,
                             "click_to_mesh": sum(total.values()) + send}
        rows = [("segmentation (scene)", self.scene.seg_seconds), ("voxelize", total["voxelize"]),
                ("CNN", total["cnn"]), ("marching cubes", total["fast_mesh"]), ("send to browser", send),
                ("**click → mesh**", self.last_timings["click_to_mesh"])]
        self.panel.timings.content = P.timings_markdown(title, rows)

    def _show_mesh_timings(self, kind: str, c: Completion, send: float) -> None:
        """The timings table of a detailed (split by Algorithm 1's steps) or baseline mesh."""
        seconds = c.timings[f"{kind}_mesh"]
        title = f"Segment **{c.segment_id}**: {MESH_TITLES[kind].lower()}"
        if kind == "detailed":
            steps = c.timings["detailed_steps"]
            title += f" (Algorithm 1, up-sampling r = {steps['upsample_ratio']})"
            rows = [(label, steps[key]) for key, label in ALGORITHM_1_STEPS]
        else:
            rows = [(MESH_TITLES[kind], seconds)]
        rows += [("send to browser", send), ("**total**", seconds + send)]
        self.panel.timings.content = P.timings_markdown(title, rows)

    def _wire_callbacks(self) -> None:
        p = self.panel

        @self.server.scene.on_click()
        def _(event: viser.SceneClickEvent) -> None:
            if self._pipeline_visible:  # the dataset is on screen: its clicks are not picks
                self.click(event.ray_origin, event.ray_direction, event.client)

        @p.segment.on_update
        def _(event: viser.GuiEvent) -> None:
            sid = self._segment_options.get(p.segment.value)
            if event.client is None or sid == self.selected:
                return  # set by the app itself, or no change
            if sid is None:
                self.selected = None
            else:
                self.complete(sid, event.client)

        @p.complete.on_click
        def _(event: viser.GuiEvent) -> None:
            if self.selected is None:
                self._notify(event.client, "No segment selected", "Click a segment or pick one above.", "yellow")
            else:
                self.complete(self.selected, event.client)

        p.complete_all.on_click(lambda event: self.complete_all(event.client))
        for button, kind in ((p.detailed, "detailed"), (p.partial, "partial"), (p.mirror, "mirror"), (p.hull, "hull")):
            button.on_click(lambda event, kind=kind: self.compute_mesh(kind, None, event.client))
        p.new_scene.on_click(lambda event: self.load_default(int(p.seed.value), event.client))
        p.load_cloud.on_click(lambda event: self.load_cloud(p.cloud_path.value, event.client))

        for key, box in p.layers.items():
            box.on_update(lambda _event, key=key, box=box: setattr(self._layer_roots[key], "visible",
                                                                   box.value and self._pipeline_visible))

        @p.layers["confidence"].on_update
        def _(_event: viser.GuiEvent) -> None:
            if p.layers["confidence"].value:
                for c in list(self.completions.values()):
                    self._draw_confidence(c)

        @p.cloud_colors.on_update
        def _(_event: viser.GuiEvent) -> None:
            if self.scene is not None:
                self._draw_cloud()

        @p.shade_output.on_update
        def _(_event: viser.GuiEvent) -> None:
            for c in list(self.completions.values()):
                self._draw_output(c)

        for button, kind in ((p.export_points, "points"), (p.export_grids, "grids"), (p.export_mesh, "mesh")):
            button.on_click(lambda event, kind=kind: self._download(event.client, kind))

        self.server.on_client_connect(self._on_connect)
        self.server.on_client_disconnect(lambda client: self._loading_notes.pop(client.client_id, None))

    def _download(self, client: viser.ClientHandle | None, kind: str) -> None:
        try:
            name, data = self.export_bytes(kind, None, self.panel.mesh_format.value, self.panel.export_frame.value,
                                           self.panel.export_mesh_kind.value)
        except ValueError as e:
            self._notify(client, "Nothing to export", str(e), "red")
            return
        if client is not None:
            client.send_file_download(name, data, save_immediately=True)

    def _on_connect(self, client: viser.ClientHandle) -> None:
        if self.scene is None:  # still building the first scene
            self._loading_notes[client.client_id] = client.add_notification(
                "Loading the scene", "Generating and segmenting the capture...", loading=True,
                with_close_button=False)

    # ------------------------------------------------------------------------------------------
    # Jobs and notifications

    @contextlib.contextmanager
    def _job_slot(self, client: viser.ClientHandle | None) -> Iterator[bool]:
        """Run one job at a time: yields False (after telling the client) when another job runs."""
        if not self._job.acquire(blocking=False):
            self._notify(client, "Busy", "Another job is still running; try again in a moment.", auto_close=2.0)
            yield False
            return
        buttons = self.panel.job_buttons
        for b in buttons:
            b.disabled = True
        try:
            yield True
        finally:
            for b in buttons:
                b.disabled = False
            for note in self._loading_notes.values():
                note.remove()
            self._loading_notes.clear()
            self._job.release()

    def _clients(self, client: viser.ClientHandle | None) -> list[viser.ClientHandle]:
        return [client] if client is not None else list(self.server.get_clients().values())

    def _show_loading(self, client: viser.ClientHandle | None, body: str) -> list[viser.NotificationHandle]:
        return [c.add_notification("Loading", body, loading=True, with_close_button=False)
                for c in self._clients(client)]

    def _notify(self, client: viser.ClientHandle | None, title: str, body: str, color: str | None = None,
                auto_close: float | None = 8.0) -> None:
        """Tell one client (every client when None) something; red ones are remembered as ``last_error``."""
        if color == "red":
            self.last_error = f"{title}: {body}"
        log.info("%s: %s", title, body)
        for c in self._clients(client):
            c.add_notification(title, body, color=color, auto_close_seconds=auto_close)


def _usable(segment: Segment) -> bool:
    """Whether a segment has enough points and extent to be completed."""
    try:
        check_segment(segment.points_cam)
        return True
    except SegmentTooSmallError:
        return False


def serve(host: str = "127.0.0.1", port: int = 8080, seed: int = 0, cloud: str | Path | None = None,
          weights: str | Path | None = None, intrinsics: Intrinsics | None = None, block: bool = True,
          results: str | Path | None = None, allow_hosts: tuple[str, ...] = ()) -> ViewerApp:
    """Start the viewer (``python app.py`` and ``shapeviewer serve``); print its URL; serve until Ctrl-C.

    ``results``: the Dataset tab's results folder; None = the sample store in the user cache (built
    in the background on first run). ``allow_hosts``: more names the server answers to (see
    :mod:`.guard`). With ``block=False`` returns the running :class:`ViewerApp` instead.
    """
    app = ViewerApp(host, port, seed, cloud, weights, intrinsics,
                    announce=lambda url: print(f"shapeviewer: serving on {url} (building the scene...)", flush=True),
                    results="default" if results is None else results, allow_hosts=allow_hosts)
    print(f"shapeviewer: ready on {app.url}  (Ctrl-C to stop)", flush=True)
    if not block:
        return app
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        app.stop()
    return app
