"""Grasps in the viewer (paper Fig. 5, step 6; SPEC section 8): plan on a segment's mesh, draw the
hands, execute them on the true object of a synthetic scene, export them.

Frames: everything here is in the viewer's WORLD frame (metres, z up, table top z = 0). A segment's
mesh (camera frame on its :class:`~shapeviewer.pipeline.Completion`) is mapped with
``scene.T_world_cam`` before planning; a grasp's ``T_world_palm`` places the palm frame, in which
:func:`~shapeviewer.grasp.hands.hand_meshes` gives the hand's links. A synthetic scene's true object
is ``SceneObject.mesh`` (object frame) mapped with ``T_world_obj``.

Scene nodes (layer ``grasps``):

- ``/grasps/seg_<id>``: one frame per segment with grasps;
- ``/grasps/seg_<id>/g<k>``: a frame at grasp k's ``T_world_palm``, its children ``<link>`` the
  hand's links in the palm frame, coloured by epsilon (:func:`epsilon_colors`);
- ``/grasps/seg_<id>/truth``: the true object, translucent, once a grasp was executed on it;
- ``/grasps/seg_<id>/exec_g<k>``: the hand as executed on the true object (blue, translucent).

Jobs: planning and execution run in a background thread, one grasp job at a time, outside the
app's job lock (``ViewerApp._job_slot``), so the rest of the viewer keeps working meanwhile; a
mesh that the planner needs and the segment lacks is made first through the app (which takes
that lock for the few moments it needs). The GUI is shared by every browser, so the progress
bar and the Cancel button are too.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import trimesh
import viser

from ..camera import transform_points
from ..capture import Capture, SceneObject
from ..grasp.execute import ExecutionResult, execute_grasps, lift_test
from ..grasp.serialize import grasps_to_json, scene_zip
from ..grasp.hands import HAND_NAMES, Hand, get_hand, hand_meshes
from ..grasp.plan import Grasp, PlanStats, plan
from ..segment import Segment
from .panel import MESH_KINDS
from .rays import first_hit, sample_segments
from .visuals import shade

if TYPE_CHECKING:
    from .app import ViewerApp

log = logging.getLogger(__name__)

NO_GRASP = "(none)"
DEFAULT_GRASPS = 20
MAX_GRASPS = 50
NO_CLOSURE_COLOR = (150, 150, 150)  # grasps without force closure (epsilon <= 0)
EPSILON_STOPS = (0.0, 0.5, 1.0)  # epsilon / the best epsilon ...
EPSILON_COLORS = ((215, 40, 30), (235, 160, 0), (20, 160, 60))  # ... red, amber, green
EXECUTED_COLOR = (40, 110, 235)
EXECUTED_OPACITY = 0.6
TRUTH_COLOR = (250, 200, 60)  # gold: unlike any segment colour
TRUTH_OPACITY = 0.5
SKELETON_THICKNESS = 0.003  # m: the stick figures of the grasps other than the selected one
# A click picks a hand when its ray passes within PICK_TOLERANCE (+ 1 % of the distance) of a
# point along the hand's stick figure; nearer than a segment's tolerance, since hands crowd.
PICK_SPACING = 0.004  # m between those points
PICK_TOLERANCE = 0.006  # m
PALM_SHADE = 0.7  # the palm a little darker than the fingers, so the hand's shape reads at a glance
MIN_GROUND_TRUTH_SHARE = 0.5  # a segment is an object when at least this share of its labelled points are


# ---------------------------------------------------------------------------------------------
# Plain values (no viser): colours, ground truth, panel text.

def epsilon_colors(epsilons: Sequence[float]) -> list[tuple[int, int, int]]:
    """RGB of each grasp by its epsilon: red (near 0) through amber to green (the best of
    ``epsilons``); grey without force closure (epsilon <= 0). Relative to the best so that one
    object's grasps spread over the whole scale whatever its size. (Saturated stops, not
    matplotlib's RdYlGn, whose pale middle vanishes against the light table.)"""
    eps = np.asarray(epsilons, dtype=np.float64)
    best = float(eps.max()) if len(eps) and eps.max() > 0 else 1.0
    x = np.clip(eps / best, 0.0, 1.0)
    rgb = np.stack([np.interp(x, EPSILON_STOPS, [c[i] for c in EPSILON_COLORS]) for i in range(3)], axis=-1)
    return [NO_CLOSURE_COLOR if e <= 0 else tuple(int(round(v)) for v in c) for e, c in zip(eps, rgb)]


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
    return trimesh.Trimesh(transform_points(obj.T_world_obj, obj.mesh.vertices), np.asarray(obj.mesh.faces),
                           process=False)


def hand_skeleton(hand: Hand, joints: Sequence[float]) -> np.ndarray:
    """A stick figure of the hand at ``joints``: (N, 2, 3) line segments in the palm frame (metres).

    The wrist axis (from the palm face back to the end of the palm, along -approach), a segment
    from each link's parent frame to its own, and from each fingertip link to the centre of its
    far end. Twenty of them show where the grasps are without hiding the object the way twenty
    solid (or translucent) hands do.
    """
    poses = hand.link_poses(joints)

    def visual_points(link: str) -> np.ndarray:
        pts = [g.mesh().vertices @ (poses[link] @ g.T_link_geom)[:3, :3].T + (poses[link] @ g.T_link_geom)[:3, 3]
               for g in hand.model.visuals.get(link, ())]
        return np.vstack(pts) if pts else poses[link][None, :3, 3]

    palm = visual_points(hand.palm_link)
    approach = np.asarray(hand.approach, float)
    segments = [(np.zeros(3), approach * float(np.min(palm @ approach)))]
    parents = {j.child: j.parent for j in hand.model.joints}
    for link, parent in parents.items():
        origin = poses[link][:3, 3]
        segments.append((poses[parent][:3, 3], origin))
        if link not in parents.values():  # a fingertip link: on to the middle of its far end
            pts = visual_points(link)
            d = np.linalg.norm(pts - origin, axis=1)
            segments.append((origin, pts[d >= 0.9 * d.max()].mean(axis=0)))
    return np.asarray(segments, dtype=np.float64)


def _joint_value(hand: Hand, name: str, value: float) -> str:
    """A joint value for people: degrees for revolute joints, millimetres for prismatic ones."""
    kind = next(j.kind for j in hand.model.joints if j.name == name)
    return f"{1000 * value:.1f} mm" if kind == "prismatic" else f"{math.degrees(value):.1f}°"


def _epsilon_text(epsilon: float) -> str:
    return f"{epsilon:.4f}" if epsilon > 0 else f"{epsilon:.4f} (no force closure)"


def _lift_text(e: ExecutionResult) -> str:
    if e.lift is None:
        return "lift test not run"
    verdict = "**lifted** ✓" if e.lift.success else "**dropped** ✗"
    return f"{verdict} (rose {1000 * e.lift.rise:.0f} mm, slipped {1000 * e.lift.slip:.0f} mm)"


# ---------------------------------------------------------------------------------------------
# State.

@dataclass(eq=False)
class SegmentGrasps:
    """The grasps planned on one segment's mesh and what became of them on the true object.

    Attributes:
        segment_id: the segment.
        hand: hand name (see :data:`HAND_NAMES`).
        method: which of the segment's meshes was planned on (one of :data:`panel.MESH_KINDS`).
        mesh_world: that mesh in the world frame (metres), as given to the planner.
        table: whether the planner (and execution) had the table plane z = 0.
        seed: planning seed.
        grasps: best first.
        stats: what planning did.
        executions: per grasp, its execution on the true object (None until executed).
        truth_name: the true object's catalogue name once executed (synthetic scenes).
        truth_world: the true object's world-frame mesh once executed.
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

    def __post_init__(self) -> None:
        if not self.executions:
            self.executions = [None] * len(self.grasps)


@dataclass(eq=False)
class GraspJob:
    """A planning or execution job running in the background.

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


class GraspJobError(Exception):
    """A job that cannot go on; the message is for the user."""


# ---------------------------------------------------------------------------------------------
# Panel.

@dataclass
class GraspPanel:
    """Handles of the Grasps folder."""

    hand: viser.GuiDropdownHandle
    method: viser.GuiDropdownHandle
    count: viser.GuiNumberHandle
    plan: viser.GuiButtonHandle
    progress: viser.GuiProgressBarHandle
    cancel: viser.GuiButtonHandle
    grasp: viser.GuiDropdownHandle
    show_all: viser.GuiCheckboxHandle
    info: viser.GuiMarkdownHandle
    execute: viser.GuiButtonHandle
    execute_all: viser.GuiButtonHandle
    export_json: viser.GuiButtonHandle
    export_zip: viser.GuiButtonHandle

    @property
    def job_buttons(self) -> tuple[viser.GuiButtonHandle, ...]:
        """Buttons that start a grasp job (disabled while one runs)."""
        return (self.plan, self.execute, self.execute_all)


def build_grasp_panel(gui: viser.GuiApi, order: float | None = None) -> GraspPanel:
    """Add the Grasps folder to ``gui`` (at ``order`` among the top-level folders)."""
    with gui.add_folder("Grasps", order=order):
        hand = gui.add_dropdown("Hand", HAND_NAMES, hint="Barrett BH8-280 (the paper's) or the Franka Panda gripper")
        method = gui.add_dropdown("Plan on", MESH_KINDS,
                                  hint="Which mesh of the selected segment to plan on (made first if missing)")
        count = gui.add_number("Grasps", DEFAULT_GRASPS, min=1, max=MAX_GRASPS, step=1,
                               hint="How many distinct grasps to keep (the paper: 20)")
        plan_b = gui.add_button("Plan grasps", icon=viser.Icon.HAND_GRAB,
                                hint="Plan grasps on the selected segment's mesh (a few seconds, in the background)")
        progress = gui.add_progress_bar(0.0, visible=False, animated=True)
        cancel = gui.add_button("Cancel", icon=viser.Icon.PLAYER_STOP, color="red", disabled=True,
                                hint="Stop the running grasp job")
        grasp = gui.add_dropdown("Grasp", (NO_GRASP,), hint="Select a grasp: it is highlighted and described below")
        show_all = gui.add_checkbox("Show all", True, hint="Show the other grasps dimmed (off: only the selected one)")
        info = gui.add_markdown("_Select a segment, then plan grasps on it._")
        execute = gui.add_button("Execute on ground truth", icon=viser.Icon.PLAYER_PLAY,
                                 hint="Run the selected grasp on the true object (synthetic scenes): "
                                      "approach, close, lift")
        execute_all = gui.add_button("Execute all", icon=viser.Icon.LIST_CHECK,
                                     hint="Run every grasp of this segment on the true object")
        export_json = gui.add_button("Grasps (JSON)", icon=viser.Icon.DOWNLOAD,
                                     hint="Palm poses, joints, contacts, qualities and executions (world frame)")
        export_zip = gui.add_button("pybullet scene (zip)", icon=viser.Icon.FILE_ZIP,
                                    hint="Object mesh, its convex decomposition and URDF, the hand URDFs, grasps.json")
    return GraspPanel(hand, method, count, plan_b, progress, cancel, grasp, show_all, info, execute, execute_all,
                      export_json, export_zip)


# ---------------------------------------------------------------------------------------------
# The controller.

@dataclass(eq=False)
class _HandNodes:
    """One drawn hand: its palm frame, the frame holding its link meshes (``solid``), its stick
    figure (planned grasps only), which grasp (index in its segment's list) it shows, and whether
    as planned or as executed on the true object."""

    frame: viser.SceneNodeHandle
    solid: viser.SceneNodeHandle
    skeleton: viser.SceneNodeHandle | None
    index: int
    executed: bool
    pick_points: np.ndarray  # (N, 3) world metres along the stick figure, for click picking


class GraspController:
    """Plans, executes, draws and exports the grasps of the app's segments (one job at a time).

    Args:
        app: the viewer; its ``scene``, ``completions`` and ``panel`` are read, and missing meshes
            are made with its ``complete`` / ``compute_mesh``.
        order: where the Grasps folder goes among the panel's folders.
    """

    def __init__(self, app: ViewerApp, order: float | None = None) -> None:
        self.app = app
        self.server = app.server
        self.panel = build_grasp_panel(app.server.gui, order)
        self.sets: dict[int, SegmentGrasps] = {}
        self.current: int | None = None  # the segment whose grasps the dropdown lists
        self.selected: int | None = None  # index of the selected grasp in that segment's list
        self.job: GraspJob | None = None
        self._busy = threading.Lock()  # held by the running job
        self._state = threading.RLock()  # guards sets/current/selected and the drawn nodes
        self._roots: dict[int, viser.SceneNodeHandle] = {}
        self._hands: dict[tuple[int, str], _HandNodes] = {}  # (segment, node key "g<k>" | "exec_g<k>")
        self._options: dict[str, int] = {}
        self._last_progress = -1
        self._wire()

    # ------------------------------------------------------------------------------------------
    # Jobs

    def plan(self, segment_id: int | None, hand: str = "barrett", method: str = "fast",
             n_grasps: int = DEFAULT_GRASPS, client: viser.ClientHandle | None = None, wait: bool = True,
             seed: int = 0, budget_seconds: float | None = None) -> GraspJob | None:
        """Plan ``n_grasps`` grasps with ``hand`` on segment ``segment_id``'s ``method`` mesh.

        The mesh is made first when the segment lacks it. Runs in a background thread (``wait``:
        return once it has finished). Returns the job (its ``result`` the :class:`SegmentGrasps`),
        or None when it cannot start (the client is told why).
        """
        if hand not in HAND_NAMES:
            raise ValueError(f"unknown hand {hand!r}; choose one of {HAND_NAMES}")
        if method not in MESH_KINDS:
            raise ValueError(f"unknown mesh {method!r}; choose one of {MESH_KINDS}")
        scene = self.app.scene
        if scene is None or segment_id is None or segment_id not in scene.segments:
            self._notify(client, "No segment selected", "Click a segment or pick one in the Completion folder, "
                         "then plan grasps on it.", "yellow")
            return None
        n_grasps = int(np.clip(n_grasps, 1, MAX_GRASPS))
        return self._start("plan", segment_id, client, wait,
                           lambda job: self._plan_job(job, scene, segment_id, hand, method, n_grasps, seed,
                                                      budget_seconds, client))

    def execute(self, segment_id: int | None, indices: Sequence[int] | None, client: viser.ClientHandle | None = None,
                wait: bool = True, lift: bool = True) -> GraspJob | None:
        """Execute grasps ``indices`` (None: all) of segment ``segment_id`` on its true object, with
        the lift test when ``lift``. Synthetic scenes only: for a real capture (or a segment that is
        no single object) the client is told there is no ground truth and None is returned."""
        scene = self.app.scene
        if scene is None or segment_id is None or segment_id not in scene.segments:
            self._notify(client, "No grasps", "Plan grasps on a segment first.", "yellow")
            return None
        truth = self.ground_truth(segment_id)  # first: a real capture never has any
        if isinstance(truth, str):
            self._notify(client, "No ground truth", truth, "red")
            return None
        s = self.sets.get(segment_id)
        if s is None or not s.grasps:
            self._notify(client, "No grasps", f"Plan grasps on segment {segment_id} first.", "yellow")
            return None
        picked = list(range(len(s.grasps))) if indices is None else [int(i) for i in indices]
        if not picked or not all(0 <= i < len(s.grasps) for i in picked):
            raise ValueError(f"grasp indices {indices} out of range 0..{len(s.grasps) - 1}")
        return self._start("execute", segment_id, client, wait,
                           lambda job: self._execute_job(job, scene, s, picked, truth, lift, client))

    def cancel(self) -> bool:
        """Ask the running grasp job to stop; False when none runs."""
        job = self.job
        if job is None or job.done.is_set():
            return False
        job.cancel()
        self.app.panel.status.content = "_Cancelling the grasp job..._"
        return True

    def shutdown(self, timeout: float = 10.0) -> None:
        """Cancel the running job and wait for its thread (before the server stops)."""
        job = self.job
        if job is not None and job.thread is not None:
            job.cancel()
            job.thread.join(timeout)

    def ground_truth(self, segment_id: int) -> tuple[str, trimesh.Trimesh] | str:
        """``(name, world-frame mesh)`` of the true object segment ``segment_id`` shows, or a message
        saying why there is none (a real capture; a segment covering several objects)."""
        scene = self.app.scene
        if not scene.capture.objects:
            return ("No ground truth: this is a real capture, so there is no true object to execute grasps on. "
                    "Grasps can still be planned, inspected and exported.")
        match = ground_truth_object(scene.capture, scene.segments[segment_id])
        if match is None:
            return (f"No ground truth for segment {segment_id}: its points do not belong mostly to one "
                    "object of the scene.")
        obj = scene.capture.objects[match[0]]
        return obj.name, object_mesh_world(obj)

    def _start(self, kind: str, segment_id: int, client: viser.ClientHandle | None, wait: bool,
               work: Callable[[GraspJob], object]) -> GraspJob | None:
        """Run ``work(job)`` in a background thread unless a grasp job already runs."""
        if not self._busy.acquire(blocking=False):
            self._notify(client, "Busy", "A grasp job is running: wait for it or press Cancel.", auto_close=3.0)
            return None
        job = GraspJob(kind, segment_id)
        self.job = job
        self._set_running(True)

        def run() -> None:
            try:
                job.result = work(job)
            except GraspJobError as e:
                job.error = str(e)
                if not job.cancel_event.is_set():  # after Cancel (or a new scene) it is no news
                    self._notify(client, "Grasps", str(e), "red")
            except Exception as e:  # a bad mesh, pybullet, a vanished client...: keep the app alive
                log.exception("grasp %s job on segment %s failed", kind, segment_id)
                job.error = f"{type(e).__name__}: {e}"
                self._notify(client, f"Grasp {'planning' if kind == 'plan' else 'execution'} failed",
                             f"Segment {segment_id}: {e}", "red")
            finally:
                job.cancelled = job.cancel_event.is_set()
                self._set_running(False)
                self._busy.release()
                job.done.set()

        job.thread = threading.Thread(target=run, name=f"grasp-{kind}-seg{segment_id}", daemon=True)
        job.thread.start()
        if wait:
            job.thread.join()
        return job

    def _set_running(self, running: bool) -> None:
        """Buttons, progress bar and status while a job runs (and back when it ends)."""
        try:
            for b in self.panel.job_buttons:
                b.disabled = running
            self.panel.cancel.disabled = not running
            self.panel.progress.value = 0.0
            self.panel.progress.visible = running
            self._last_progress = -1
            if not running:
                from .app import READY  # app imports this module

                self.app.panel.status.content = READY
        except Exception:  # the server is stopping
            log.debug("could not update the grasp panel", exc_info=True)

    def _progress(self, fraction: float) -> None:
        """The planner's progress (0..1) on the bar, sent only when a whole percent changes."""
        pct = int(np.clip(100 * fraction, 0, 100))
        if pct != self._last_progress:
            self._last_progress = pct
            self.panel.progress.value = float(pct)

    def _mesh(self, segment_id: int, method: str, client: viser.ClientHandle | None) -> trimesh.Trimesh:
        """Segment ``segment_id``'s camera-frame ``method`` mesh, made through the app when missing."""
        c = self.app.completions.get(segment_id)
        mesh = None if c is None else getattr(c, f"{method}_mesh")
        if mesh is not None:
            return mesh
        self.app.panel.status.content = f"_Grasps: making the {method} mesh of segment {segment_id} first..._"
        if method == "fast":
            c = self.app.complete(segment_id, client)
            mesh = None if c is None else c.fast_mesh
        else:
            mesh = self.app.compute_mesh(method, segment_id, client)
        if mesh is None:
            raise GraspJobError(f"Segment {segment_id} has no {method} mesh to plan on and it could not be made "
                                "(see the message above).")
        return mesh

    def _plan_job(self, job: GraspJob, scene, segment_id: int, hand: str, method: str, n_grasps: int, seed: int,
                  budget_seconds: float | None, client: viser.ClientHandle | None) -> SegmentGrasps | None:
        mesh_cam = self._mesh(segment_id, method, client)
        if job.cancel_event.is_set():
            return None
        mesh_world = mesh_cam.copy()
        mesh_world.apply_transform(scene.T_world_cam)
        # A synthetic scene stands on the table z = 0; a real one when segmentation found the plane.
        table = bool(scene.capture.objects) or scene.segmentation.plane_cam is not None
        self.app.panel.status.content = f"_Planning {n_grasps} {hand} grasps on segment {segment_id}..._"
        t0 = time.perf_counter()
        result = plan(mesh_world, hand, n_grasps, seed, table, budget_seconds, self._progress,
                      job.cancel_event.is_set)
        seconds = time.perf_counter() - t0
        if result.stats.cancelled or job.cancel_event.is_set():
            self._notify(client, "Planning cancelled", f"Segment {segment_id}: no grasps kept.", "yellow")
            return None
        s = SegmentGrasps(segment_id, hand, method, mesh_world, table, seed, result.grasps, result.stats)
        with self._state:
            if self.app.scene is not scene:  # a new scene was loaded meanwhile
                self._notify(client, "Grasps dropped", "The scene changed while planning.", "yellow")
                return None
            self.sets[segment_id] = s
            self.current, self.selected = segment_id, (0 if s.grasps else None)
            self._draw_segment(s)
            self._refresh_panel()
        self.app.panel.layers["grasps"].value = True  # the user asked to see them
        n_fc = sum(g.force_closure for g in s.grasps)
        if s.grasps:
            self._notify(client, "Grasps ready", f"Segment {segment_id}: {len(s.grasps)} {hand} grasps "
                         f"({n_fc} force closure) on the {method} mesh in {seconds:.1f} s.", "green")
        else:
            self._notify(client, "No grasp found", f"Segment {segment_id}: no {hand} grasp touches the {method} "
                         "mesh with every finger. Try the other hand or another mesh.", "yellow")
        return s

    def _execute_job(self, job: GraspJob, scene, s: SegmentGrasps, picked: list[int],
                     truth: tuple[str, trimesh.Trimesh], lift: bool,
                     client: viser.ClientHandle | None) -> list[ExecutionResult]:
        name, truth_world = truth
        sid = s.segment_id
        self.app.panel.status.content = f"_Executing {len(picked)} grasp(s) of segment {sid} on {name}..._"
        results = execute_grasps([s.grasps[i] for i in picked], truth_world, table=s.table, lift=False)
        self._progress(0.1 if lift else 1.0)
        if lift:
            for j, r in enumerate(results):
                if job.cancel_event.is_set():
                    break
                r.lift = lift_test(r, truth_world, table=s.table)
                self._progress(0.1 + 0.9 * (j + 1) / len(results))
        with self._state:
            if self.app.scene is not scene or self.sets.get(sid) is not s:  # re-planned or a new scene
                return results
            for i, r in zip(picked, results):
                s.executions[i] = r
            s.truth_name, s.truth_world = name, truth_world
            self._draw_executions(s, picked)
            self._show_info()
        # The opaque completion and its input voxels would hide the (translucent) true object.
        for layer in (f"{s.method}_mesh", "cnn_input"):
            self.app.panel.layers[layer].value = False
        lifted = [r.lift.success for r in results if r.lift is not None]
        body = (f"Segment {sid} on {name}: joint error {np.mean([r.joint_error for r in results]):.1f}°, "
                f"pose error {np.mean([r.pose_error for r in results]):.1f} mm"
                + (f", lifted {sum(lifted)}/{len(lifted)}" if lifted else "") + ".")
        self._notify(client, "Executed" + (" (cancelled before every lift test)" if job.cancel_event.is_set() else ""),
                     body, "green")
        return results

    # ------------------------------------------------------------------------------------------
    # Selection, export, scene changes

    def pick(self, ray_origin: np.ndarray, ray_direction: np.ndarray) -> tuple[int | None, float]:
        """``(index, t)`` of the listed segment's grasp whose visible hand a world-frame click ray
        hits first, ``t`` metres along the ray; ``(None, inf)`` when it misses them all."""
        with self._state:
            shown = {nodes.index: nodes.pick_points for (sid, _key), nodes in self._hands.items()
                     if sid == self.current and not nodes.executed and nodes.frame.visible}
        return first_hit(ray_origin, ray_direction, shown, PICK_TOLERANCE)

    def select(self, index: int | None, segment_id: int | None = None) -> None:
        """Select grasp ``index`` of segment ``segment_id`` (default: the listed one) and restyle."""
        with self._state:
            if segment_id is not None and segment_id in self.sets:
                self.current = segment_id
            s = self.sets.get(self.current)
            self.selected = None if s is None or index is None else int(np.clip(index, 0, len(s.grasps) - 1))
            self._refresh_panel()

    def export(self, segment_id: int | None, fmt: str = "json") -> tuple[str, bytes]:
        """``(file name, content)`` of a segment's grasps: ``json`` (with executions when present) or
        ``zip`` (the pybullet scene of the mesh they were planned on). Raises ValueError for the user."""
        s = self.sets.get(segment_id) if segment_id is not None else None
        if s is None or not s.grasps:
            raise ValueError("No grasps to export: plan grasps on a segment first.")
        scene = self.app.scene
        meta = {"source": scene.capture.source, "segment": s.segment_id, "mesh": s.method, "hand": s.hand,
                "seed": s.seed, "table": s.table, "T_world_cam": np.asarray(scene.T_world_cam).tolist(),
                "planning_seconds": s.stats.seconds.get("total"), "ground_truth": s.truth_name}
        stem = f"{scene.name}_seg{s.segment_id}_{s.method}_{s.hand}"
        if fmt == "json":
            return f"{stem}_grasps.json", grasps_to_json(s.grasps, s.executions, meta).encode()
        if fmt == "zip":
            return f"{stem}_pybullet.zip", scene_zip(s.mesh_world, s.grasps, s.executions, meta)
        raise ValueError(f"unknown grasp export {fmt!r}; choose json or zip")

    def clear(self) -> None:
        """Forget every segment's grasps and remove their nodes (a new scene); cancels a running job."""
        if self.job is not None and not self.job.done.is_set():
            self.job.cancel()
        with self._state:
            for sid in list(self._roots):
                self._remove_segment(sid)
            self.sets, self.current, self.selected = {}, None, None
            self._refresh_panel()

    # ------------------------------------------------------------------------------------------
    # Drawing

    def _remove_segment(self, sid: int) -> None:
        root = self._roots.pop(sid, None)
        if root is not None:
            root.remove()  # removes every descendant too
        for key in [k for k in self._hands if k[0] == sid]:
            del self._hands[key]

    def _draw_hand(self, sid: int, k: int, executed: bool, hand: Hand, T_world_palm: np.ndarray,
                   joints: dict[str, float], color: tuple[int, int, int], opacity: float | None) -> None:
        """Grasp ``k``'s hand at ``T_world_palm`` (world) with ``joints`` (replacing an earlier drawing
        of it): a palm frame, under it ``hand/<link>`` meshes in the palm frame and, for a planned
        grasp, the ``skeleton`` stick figure; both in ``color``."""
        key = f"exec_g{k}" if executed else f"g{k}"
        old = self._hands.pop((sid, key), None)
        if old is not None:
            old.frame.remove()
        name = f"/grasps/seg_{sid}/{key}"
        scene = self.server.scene
        frame = scene.add_frame(name, show_axes=False, position=T_world_palm[:3, 3],
                                wxyz=viser.transforms.SO3.from_matrix(T_world_palm[:3, :3]).wxyz)
        solid = scene.add_frame(f"{name}/hand", show_axes=False)
        q = [joints[n] for n in hand.joint_names]
        parts = [(link, i) for link, geoms in hand.model.visuals.items() for i in range(len(geoms))]
        for (link, i), (mesh, T) in zip(parts, hand_meshes(hand, q)):
            rgb = shade(np.asarray(color), PALM_SHADE) if link == hand.palm_link else tuple(color)
            scene.add_mesh_simple(f"{name}/hand/{link}" + (f"_{i}" if i else ""), np.asarray(mesh.vertices, np.float32),
                                  np.asarray(mesh.faces, np.uint32), color=rgb, opacity=opacity, position=T[:3, 3],
                                  wxyz=viser.transforms.SO3.from_matrix(T[:3, :3]).wxyz, cast_shadow=False,
                                  receive_shadow=False)
        sticks = hand_skeleton(hand, q)
        skeleton = None if executed else scene.add_line_segments(
            f"{name}/skeleton", sticks.astype(np.float32), tuple(color), thickness=SKELETON_THICKNESS)
        pick_points = transform_points(T_world_palm, sample_segments(sticks, PICK_SPACING))
        self._hands[(sid, key)] = _HandNodes(frame, solid, skeleton, k, executed, pick_points)

    def _draw_segment(self, s: SegmentGrasps) -> None:
        """(Re)draw a segment's planned hands, and its executions if any."""
        sid = s.segment_id
        self._remove_segment(sid)
        self._roots[sid] = self.server.scene.add_frame(f"/grasps/seg_{sid}", show_axes=False)
        hand = get_hand(s.hand)
        for k, (g, color) in enumerate(zip(s.grasps, epsilon_colors([g.epsilon for g in s.grasps]))):
            self._draw_hand(sid, k, False, hand, g.T_world_palm, g.joints, color, None)
        self._draw_executions(s)

    def _draw_executions(self, s: SegmentGrasps, indices: Sequence[int] | None = None) -> None:
        """The true object and the executed hands ``indices`` (None: all executed) of segment ``s``;
        only the selected grasp's execution shows."""
        sid = s.segment_id
        if s.truth_world is None:
            return
        self.server.scene.add_mesh_simple(f"/grasps/seg_{sid}/truth", np.asarray(s.truth_world.vertices, np.float32),
                                          np.asarray(s.truth_world.faces, np.uint32), color=TRUTH_COLOR,
                                          opacity=TRUTH_OPACITY, cast_shadow=False, receive_shadow=False)
        hand = get_hand(s.hand)
        for k in range(len(s.executions)) if indices is None else indices:
            e = s.executions[k]
            if e is not None:
                self._draw_hand(sid, k, True, hand, e.T_world_palm, e.joints, EXECUTED_COLOR, EXECUTED_OPACITY)
        self._restyle()

    def _restyle(self) -> None:
        """The selected grasp as a solid hand; the others as stick figures (Show all) or hidden; an
        execution only with its grasp selected, and then the planned hand as a stick figure so that
        it does not hide the executed one (which is often where the planned one was)."""
        show_all = bool(self.panel.show_all.value)
        with self._state:  # the Show all callback runs while a job may be drawing
            for (sid, _key), nodes in self._hands.items():
                chosen = sid == self.current and nodes.index == self.selected
                nodes.frame.visible = chosen or (show_all and not nodes.executed)
                solid = chosen and (nodes.executed or (sid, f"exec_g{nodes.index}") not in self._hands)
                nodes.solid.visible = solid
                if nodes.skeleton is not None:
                    nodes.skeleton.visible = not solid

    def _refresh_panel(self) -> None:
        """Grasp dropdown, styles and info for the listed segment."""
        s = self.sets.get(self.current)
        if s is None or not s.grasps:
            self._options = {}
            self.panel.grasp.options = (NO_GRASP,)
            self.panel.grasp.value = NO_GRASP
        else:
            self._options = {f"#{k + 1}  ε {g.epsilon:.3f}" + ("" if g.force_closure else " (no closure)"): k
                             for k, g in enumerate(s.grasps)}
            options = tuple(self._options)
            if tuple(self.panel.grasp.options) != options:
                self.panel.grasp.options = options
            value = NO_GRASP if self.selected is None else options[self.selected]
            if self.panel.grasp.value != value:
                self.panel.grasp.value = value
        self._restyle()
        self._show_info()

    def _show_info(self) -> None:
        self.panel.info.content = self.info_markdown()

    def info_markdown(self) -> str:
        """The Grasps folder's text: the listed segment's plan, the selected grasp, its execution."""
        scene = self.app.scene
        s = self.sets.get(self.current)
        if scene is None or s is None:
            return "_Select a segment, then plan grasps on it._"
        n_fc = sum(g.force_closure for g in s.grasps)
        lines = [f"**Segment {s.segment_id}** · {s.hand} on the {s.method} mesh · **{len(s.grasps)}** grasps "
                 f"({n_fc} force closure) in {s.stats.seconds.get('total', 0.0):.1f} s"]
        if s.grasps:
            best = max(g.epsilon for g in s.grasps)
            lines.append(f"Colour: ε from red (0) to green (ε = {best:.3f}, the best); grey: no force closure.")
        if not scene.capture.objects:
            lines.append("**No ground truth**: this is a real capture; grasps cannot be executed on the true object.")
        done = [e for e in s.executions if e is not None]
        if len(done) > 1:
            lifted = [e.lift.success for e in done if e.lift is not None]
            lines.append(f"On the ground truth ({s.truth_name}), {len(done)} executed: mean joint error "
                         f"{np.mean([e.joint_error for e in done]):.2f}°, pose error "
                         f"{np.mean([e.pose_error for e in done]):.1f} mm"
                         + (f", lifted {sum(lifted)}/{len(lifted)}" if lifted else ""))
        text = "  \n".join(lines)
        if self.selected is None or not s.grasps:
            return text
        k = self.selected
        g, e, hand = s.grasps[k], s.executions[k], get_hand(s.hand)
        x, y, z = 1000 * g.position
        a = g.approach
        text += (f"\n\n**Grasp #{k + 1}** · ε **{_epsilon_text(g.epsilon)}** · volume {g.volume:.4f} · "
                 f"{len(g.contacts)} contacts · energy {1000 * g.energy:.1f} mm  \n"
                 f"palm ({x:.0f}, {y:.0f}, {z:.0f}) mm · approach ({a[0]:.2f}, {a[1]:.2f}, {a[2]:.2f})\n\n")
        header = "| joint | planned |" + (" executed |\n|---|---:|---:|" if e is not None else "\n|---|---:|")
        rows = [f"| {n} | {_joint_value(hand, n, g.joints[n])} |"
                + (f" {_joint_value(hand, n, e.joints[n])} |" if e is not None else "") for n in hand.joint_names]
        text += header + "\n" + "\n".join(rows)
        if e is not None:
            text += (f"\n\n**On the ground truth** ({s.truth_name}): ε {_epsilon_text(e.epsilon)} · joint error "
                     f"**{e.joint_error:.2f}°** · pose error **{e.pose_error:.1f} mm** · {_lift_text(e)}"
                     + ("" if e.start_clear else " · the backed-off start was in collision")
                     + "  \n_Blue: the hand as executed; gold: the true object; the stick figure: the planned "
                       "grasp. (The completion's mesh and CNN input layers were switched off to show the object.)_")
        return text

    # ------------------------------------------------------------------------------------------
    # GUI

    def _wire(self) -> None:
        p, app = self.panel, self.app

        @p.plan.on_click
        def _(event: viser.GuiEvent) -> None:
            self.plan(app.selected, p.hand.value, p.method.value, int(p.count.value), event.client, wait=False)

        p.cancel.on_click(lambda _event: self.cancel())

        @p.grasp.on_update
        def _(event: viser.GuiEvent) -> None:
            if event.client is None:
                return  # set by the controller itself
            k = self._options.get(p.grasp.value)
            if k != self.selected:
                self.select(k)

        p.show_all.on_update(lambda _event: self._restyle())

        @p.execute.on_click
        def _(event: viser.GuiEvent) -> None:
            if self.selected is None:
                self._notify(event.client, "No grasp selected", "Plan grasps and pick one first.", "yellow")
            else:
                self.execute(self.current, [self.selected], event.client, wait=False)

        p.execute_all.on_click(lambda event: self.execute(self.current, None, event.client, wait=False))
        p.export_json.on_click(lambda event: self._download(event.client, "json"))
        p.export_zip.on_click(lambda event: self._download(event.client, "zip"))

        @app.panel.segment.on_update
        def _(_event: viser.GuiEvent) -> None:
            # List the grasps of the segment the user (or the app) selected, when it has some.
            sid = app._segment_options.get(app.panel.segment.value)
            if sid is not None and sid in self.sets and sid != self.current:
                self.select(0 if self.sets[sid].grasps else None, sid)

    def _download(self, client: viser.ClientHandle | None, fmt: str) -> None:
        try:
            name, data = self.export(self.current, fmt)
        except ValueError as e:
            self._notify(client, "Nothing to export", str(e), "red")
            return
        if client is not None:
            client.send_file_download(name, data, save_immediately=True)

    def _notify(self, client: viser.ClientHandle | None, title: str, body: str, color: str | None = None,
                auto_close: float | None = 8.0) -> None:
        """Tell the client (every client when None or when it has gone) something; never raises.

        A job outlives the browser that started it, so its client may have disconnected by the
        time it reports: everyone connected then hears about it (they share the panel anyway).
        """
        if color == "red":
            self.app.last_error = f"{title}: {body}"
        log.info("%s: %s", title, body)
        clients = self.server.get_clients()
        targets = [client] if client is not None and client.client_id in clients else list(clients.values())
        for c in targets:
            try:
                c.add_notification(title, body, color=color, auto_close_seconds=auto_close)
            except Exception:  # the browser went away mid-call
                log.debug("notification to client %s failed", c.client_id, exc_info=True)
