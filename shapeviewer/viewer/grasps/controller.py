"""The grasp controller: plans, executes and ranks by robustness the grasps on the app's segments,
keeps which are listed and selected, and wires the Grasps folder. It reaches the app only through a
:class:`GraspHost`."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import trimesh
import viser

from ...errors import Cancelled
from ...grasp.execute import ExecutionResult, execute_grasps
from ...grasp.hands import HAND_NAMES
from ...grasp.pick import rank_grasps
from ...grasp.plan import plan
from ...grasp.robust import ROBUST_QUANTILE, WIDEN_BELOW, Robustness
from ...grasp.serialize import grasps_to_json, scene_zip
from ...runtime.processes import ProcessPool
from ..audience import Audience
from ..gui import plural, set_value
from ..jobs import Notify, send_download
from ..state import MESH_KINDS, LoadedScene
from .controls import DEFAULT_GRASPS, NO_GRASP, build_grasp_panel
from .drawing import GraspDrawing
from .state import MAX_GRASPS, GraspJob, GraspJobError, SegmentGrasps, ground_truth, narrowest_width
from .summary import execution_summary, grasp_options, info_markdown, plan_advice, stage_times
from .work import GraspJobs

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GraspHost:
    """What the grasp controller needs from the app (it never sees the app itself).

    Attributes:
        scene: the loaded scene (world frame), None before the first.
        selected_segment: the segment chosen in the Completion folder, or None.
        mesh: ``(kind, segment id)`` -> that segment's camera-frame mesh of ``kind`` (one of
            :data:`~..state.MESH_KINDS`) when it has been made, else None.
        make_mesh: ``(kind, segment id, client)`` -> make and draw that mesh (taking the app's job
            slot for the moments it needs); None when it cannot be made (the client was told why).
        samples: segment id -> the meshes of its completion's sample completions (world frame,
            metres; the samples are made when missing), None when the segment has no completion.
        show_layer: ``(layer key, visible)``: tick or untick a layer's checkbox.
        layer_shown: layer key -> whether its checkbox is ticked.
        set_status: show a line in the panel's status.
        notify: ``(client, title, body, color=None, auto_close=8.0)``; red ones are errors.
    """

    scene: Callable[[], LoadedScene | None]
    selected_segment: Callable[[], int | None]
    mesh: Callable[[str, int], trimesh.Trimesh | None]
    make_mesh: Callable[[str, int, viser.ClientHandle | None], trimesh.Trimesh | None]
    samples: Callable[[int], list[trimesh.Trimesh] | None]
    show_layer: Callable[[str, bool], None]
    layer_shown: Callable[[str], bool]
    set_status: Callable[[str], None]
    notify: Notify


class GraspController:
    """Plans, executes, ranks, draws and exports the grasps of the app's segments (one job at a time).

    Args:
        audience: the browser tab (or every browser) of the session: the Grasps folder goes in its
            GUI, the hands in its scene.
        host: see :class:`GraspHost`.
        pool: the worker processes grasp jobs compute in (shared by the sessions).
        order: where the Grasps folder goes among the panel's folders.

    Attributes:
        widen_below: "Rank by robustness" plans as many grasps again on the grasp envelope when
            the most robust grasp lifts fewer than this share of its sample tests
            (:func:`~shapeviewer.grasp.robust.is_weak`; 0: never).
    """

    def __init__(self, audience: Audience, host: GraspHost, pool: ProcessPool, order: float | None = None) -> None:
        self.audience = audience
        self.host = host
        self.panel = build_grasp_panel(audience.gui, order)
        self.drawing = GraspDrawing(audience)
        self.jobs = GraspJobs(self.panel, pool, host.notify, host.set_status, self._has_grasps)
        self.sets: dict[int, SegmentGrasps] = {}
        self.current: int | None = None  # the segment whose grasps the dropdown lists
        self.selected: int | None = None  # index of the selected grasp in that segment's list
        self._state = threading.RLock()  # guards sets/current/selected
        self._options: dict[str, int] = {}  # grasp dropdown entry -> index
        # Layers that executing a grasp on the ground truth switched off, ticked again once the user
        # moves on (restore_layers).
        self._hidden_layers: list[str] = []
        self.widen_below = WIDEN_BELOW
        self._wire()

    @property
    def job(self) -> GraspJob | None:
        """The running (or last) grasp job."""
        return self.jobs.job

    # ------------------------------------------------------------------------------------------
    # Jobs

    def plan(
        self,
        segment_id: int | None,
        hand: str = "barrett",
        method: str = "fast",
        n_grasps: int = DEFAULT_GRASPS,
        client: viser.ClientHandle | None = None,
        wait: bool = True,
        seed: int = 0,
        budget_seconds: float | None = None,
    ) -> GraspJob | None:
        """Plan ``n_grasps`` grasps with ``hand`` on segment ``segment_id``'s ``method`` mesh.

        The mesh is made first when the segment lacks it. Runs in a background thread (``wait``:
        return once it has finished). Returns the job (its ``result`` the :class:`SegmentGrasps`),
        or None when it cannot start (the client is told why).
        """
        if hand not in HAND_NAMES:
            raise ValueError(f"unknown hand {hand!r}; choose one of {HAND_NAMES}")
        if method not in MESH_KINDS:
            raise ValueError(f"unknown mesh {method!r}; choose one of {MESH_KINDS}")
        scene = self.host.scene()
        if scene is None or segment_id is None or segment_id not in scene.segments:
            self.host.notify(
                client,
                "No segment selected",
                "Click a segment or pick one in the Completion folder, then plan grasps on it.",
                "yellow",
            )
            return None
        n_grasps = int(np.clip(n_grasps, 1, MAX_GRASPS))
        return self.jobs.start(
            "plan",
            segment_id,
            client,
            wait,
            lambda job: self._plan_job(job, scene, segment_id, hand, method, n_grasps, seed, budget_seconds, client),
        )

    def execute(
        self,
        segment_id: int | None,
        indices: Sequence[int] | None,
        client: viser.ClientHandle | None = None,
        wait: bool = True,
        lift: bool = True,
    ) -> GraspJob | None:
        """Execute grasps ``indices`` (None: all) of segment ``segment_id`` on its true object, with
        the lift test when ``lift``. Synthetic scenes only: for a real capture (or a segment that is
        no single object) the client is told there is no ground truth and None is returned."""
        scene = self.host.scene()
        if scene is None or segment_id is None or segment_id not in scene.segments:
            self.host.notify(client, "No grasps", "Plan grasps on a segment first.", "yellow")
            return None
        truth = ground_truth(scene.capture, scene.segments[segment_id])  # first: a real capture never has any
        if isinstance(truth, str):
            self.host.notify(client, "No ground truth", truth, "blue")  # information: nothing failed
            return None
        s = self.sets.get(segment_id)
        if s is None or not s.grasps:
            self.host.notify(client, "No grasps", f"Plan grasps on segment {segment_id} first.", "yellow")
            return None
        picked = list(range(len(s.grasps))) if indices is None else [int(i) for i in indices]
        if not picked or not all(0 <= i < len(s.grasps) for i in picked):
            raise ValueError(f"grasp indices {indices} out of range 0..{len(s.grasps) - 1}")
        return self.jobs.start(
            "execute",
            segment_id,
            client,
            wait,
            lambda job: self._execute_job(job, scene, s, picked, truth, lift, client),
        )

    def rank(
        self, segment_id: int | None, client: viser.ClientHandle | None = None, wait: bool = True
    ) -> GraspJob | None:
        """Score segment ``segment_id``'s grasps over its completion's sample completions
        (:func:`~shapeviewer.grasp.robust.robustness`, against the mesh they were planned on), list
        them most robust first and select the most robust. Runs in a background thread like
        :meth:`plan`; ``job.result``: the scores in grasp order (None when cancelled)."""
        scene = self.host.scene()
        s = self.sets.get(segment_id) if segment_id is not None else None
        if scene is None or s is None or not s.grasps:
            self.host.notify(client, "No grasps", "Plan grasps on a segment first, then rank them.", "yellow")
            return None
        return self.jobs.start("rank", s.segment_id, client, wait, lambda job: self._rank_job(job, scene, s, client))

    def cancel(self) -> bool:
        """Ask the running grasp job to stop; False when none runs."""
        return self.jobs.cancel()

    def shutdown(self, timeout: float = 10.0) -> None:
        """Cancel the running job and wait for its thread (before the session closes)."""
        self.jobs.shutdown(timeout)

    def _mesh(self, segment_id: int, method: str, client: viser.ClientHandle | None) -> trimesh.Trimesh:
        """Segment ``segment_id``'s camera-frame ``method`` mesh, made through the app when missing."""
        mesh = self.host.mesh(method, segment_id)
        if mesh is not None:
            return mesh
        self.host.set_status(f"_Grasps: making the {method} mesh of segment {segment_id} first..._")
        mesh = self.host.make_mesh(method, segment_id, client)
        if mesh is None:
            raise GraspJobError(
                f"Segment {segment_id} has no {method} mesh to plan on and it could not be made "
                "(see the message above)."
            )
        return mesh

    def _plan_job(
        self,
        job: GraspJob,
        scene: LoadedScene,
        segment_id: int,
        hand: str,
        method: str,
        n_grasps: int,
        seed: int,
        budget_seconds: float | None,
        client: viser.ClientHandle | None,
    ) -> SegmentGrasps | None:
        mesh_cam = self._mesh(segment_id, method, client)
        if job.cancel_event.is_set():
            return None
        mesh_world = mesh_cam.copy()
        mesh_world.apply_transform(scene.T_world_cam)
        # A synthetic scene stands on the table z = 0; a real one when segmentation found the plane.
        table = bool(scene.capture.objects) or scene.segmentation.plane_cam is not None
        self.host.set_status(f"_Planning {plural(n_grasps, hand + ' grasp')} on segment {segment_id}..._")
        t0 = time.perf_counter()
        result = self.jobs.compute(
            job, plan, mesh_world, hand=hand, n_grasps=n_grasps, seed=seed, table=table, budget_seconds=budget_seconds
        )
        seconds = time.perf_counter() - t0
        if result.stats.cancelled or job.cancel_event.is_set():
            self.host.notify(client, "Planning cancelled", f"Segment {segment_id}: no grasps kept.", "yellow")
            return None
        s = SegmentGrasps(segment_id, hand, method, mesh_world, table, seed, result.grasps, result.stats)
        s.seconds["plan"] = seconds
        s.width = narrowest_width(mesh_world)
        with self._state:
            if self.host.scene() is not scene:  # a new scene was loaded meanwhile
                self.host.notify(client, "Grasps dropped", "The scene changed while planning.", "yellow")
                return None
            self.sets[segment_id] = s
            self.current, self.selected = segment_id, (0 if s.grasps else None)
            self.drawing.draw_segment(s)
            self._refresh_panel()
        self.restore_layers()  # a new plan: what an execution hid comes back
        self.host.show_layer("grasps", True)  # the user asked to see them
        n_fc = sum(g.force_closure for g in s.grasps)
        n_up = sum(g.lifted for g in s.grasps)
        advice = plan_advice(s)
        if s.grasps:
            self.host.notify(
                client,
                "Grasps ready",
                f"Segment {segment_id}: {plural(len(s.grasps), hand + ' grasp')} "
                f"({n_fc} force closure, {n_up} lift the mesh in simulation) on the {method} mesh; "
                f"{stage_times(s.seconds)}." + ("" if advice is None else f" {advice}"),
                "green" if advice is None else "yellow",
                auto_close=8.0 if advice is None else 20.0,
            )
        else:
            self.host.notify(
                client,
                "No grasp found",
                f"Segment {segment_id}: no {hand} grasp touches the {method} "
                "mesh with every finger. " + (advice or "Try the other hand or another mesh."),
                "yellow",
                auto_close=20.0,
            )
        return s

    def _execute_job(
        self,
        job: GraspJob,
        scene: LoadedScene,
        s: SegmentGrasps,
        picked: list[int],
        truth: tuple[str, trimesh.Trimesh],
        lift: bool,
        client: viser.ClientHandle | None,
    ) -> list[ExecutionResult]:
        name, truth_world = truth
        sid = s.segment_id
        self.host.set_status(f"_Executing {plural(len(picked), 'grasp')} of segment {sid} on {name}..._")
        results = self.jobs.compute(
            job, execute_grasps, [s.grasps[i] for i in picked], truth_world, table=s.table, lift=lift
        )
        with self._state:
            if self.host.scene() is not scene or self.sets.get(sid) is not s:  # re-planned or a new scene
                return results
            for i, r in zip(picked, results):
                s.executions[i] = r
            s.truth_name, s.truth_world = name, truth_world
            self.drawing.draw_executions(s, picked)
            self._restyle()
            self._show_info()
        # The opaque completion and its input voxels would hide the (translucent) true object; they
        # come back once the user moves on (restore_layers).
        for layer in (f"{s.method}_mesh", "cnn_input"):
            if self.host.layer_shown(layer):
                self.host.show_layer(layer, False)
                if layer not in self._hidden_layers:
                    self._hidden_layers.append(layer)
        cancelled = " (cancelled before every lift test)" if job.cancel_event.is_set() else ""
        self.host.notify(client, "Executed" + cancelled, execution_summary(sid, name, s.hand, results), "green")
        return results

    def _rank_job(
        self, job: GraspJob, scene: LoadedScene, s: SegmentGrasps, client: viser.ClientHandle | None
    ) -> list[Robustness] | None:
        """The app's pick on segment ``s``'s grasps (:func:`~shapeviewer.grasp.pick.rank_grasps`, its
        heavy stages in the worker processes): scored over the sample completions, and when no grasp
        holds up, the wider search on the grasp envelope (re-scoring the envelope's grasps of an
        earlier ranking rather than planning them again). Returns the scores in grasp order, None
        when cancelled."""
        sid = s.segment_id
        self.host.set_status(f"_Grasps: meshing the sample completions of segment {sid}..._")
        samples = self.host.samples(sid)
        if samples is None:
            raise GraspJobError(f"Segment {sid} has no completion to sample: complete it, then rank again.")
        first = len(s.grasps) if s.wider_from is None else s.wider_from
        self.host.set_status(
            f"_Re-closing {plural(first, 'grasp')} on {plural(len(samples), 'sample completion')}, "
            "then lifting the best..._"
        )

        def envelope() -> trimesh.Trimesh:
            """The grasp envelope in the world frame, made through the app when missing (the wider search needs it)."""
            self.host.set_status(
                f"_No grasp lifted {self.widen_below:.0%} of its sample tests: "
                + (
                    f"planning {plural(first, 'more grasp')} on the grasp envelope of segment {sid}..._"
                    if s.wider_from is None
                    else f"re-closing the grasps of the grasp envelope of segment {sid} on the sample completions..._"
                )
            )
            mesh = self._mesh(sid, "envelope", client).copy()
            mesh.apply_transform(scene.T_world_cam)
            return mesh

        try:
            pick = rank_grasps(
                s.mesh_world,
                samples,
                hand=s.hand,
                n_grasps=first,
                seed=s.seed,
                table=s.table,
                planned=s.grasps[:first],
                wider=s.grasps[first:] or None,
                widen=s.method != "envelope",
                widen_below=self.widen_below,
                envelope=envelope,
                runner=self.jobs.runner(job),
                progress=self.jobs.progress,
                cancel=job.cancel_event.is_set,
            )
        except Cancelled:
            self.host.notify(client, "Ranking cancelled", f"Segment {sid}: the grasps keep their order.", "yellow")
            return None
        if pick.wider_error is not None:
            self.host.notify(
                client,
                "Wider search failed",
                f"Segment {sid}: {pick.wider_error}. The {s.method} mesh's grasps are ranked alone.",
                "yellow",
            )
        more = list(pick.grasps[first:])
        scores = list(pick.robustness)
        order = list(pick.order)
        with self._state:
            if self.host.scene() is not scene or self.sets.get(sid) is not s:  # re-planned or a new scene
                return scores
            if more or s.wider_from is not None:
                known = s.executions[first:]  # a re-ranking keeps what the wider grasps did
                s.grasps = s.grasps[:first] + more
                s.executions = s.executions[:first] + (known if len(known) == len(more) else [None] * len(more))
                s.wider_from = first if more else None
                self.drawing.draw_segment(s)
            s.robustness = scores
            # The planning figure stays; ranking (and the wider search, when it ran) get their own.
            s.seconds = {"plan": s.seconds.get("plan", 0.0), "rank": pick.seconds["rank"]}
            if pick.wider_from is not None or pick.wider_error is not None:  # the wider search ran
                s.seconds["wider"] = pick.seconds["wider"]
            self.current, self.selected = sid, order[0]  # the user asked for the most robust one
            self._refresh_panel()
        best = scores[order[0]]
        advice = plan_advice(s)
        self.host.notify(
            client,
            "Ranked by robustness",
            f"Segment {sid}: grasp #{order[0] + 1} is the most robust"
            + (" (planned on the grasp envelope)" if order[0] >= first else "")
            + f"; it holds on {round(best.fraction * len(samples))} of "
            + plural(len(samples), "sample completion")
            + (
                "."
                if best.lifted is None
                else f"; it lifted them in {round(best.lifted * best.lift_tests)} of {plural(best.lift_tests, 'test')}."
            )
            + (
                f" No grasp of the {s.method} mesh lifted {self.widen_below:.0%} of its tests, so "
                f"{plural(len(more), 'more grasp was', 'more grasps were')} planned on the grasp envelope "
                f"(#{first + 1}-#{first + len(more)})."
                if more
                else ""
            )
            + f" {stage_times(s.seconds)}."
            + ("" if advice is None else f" {advice}"),
            "green" if advice is None else "yellow",
        )
        return scores

    # ------------------------------------------------------------------------------------------
    # Selection, export, scene changes

    def pick(self, ray_origin: np.ndarray, ray_direction: np.ndarray) -> tuple[int | None, float]:
        """``(index, t)`` of the listed segment's grasp whose visible hand a world-frame click ray
        hits first, ``t`` metres along the ray; ``(None, inf)`` when it misses them all."""
        return self.drawing.pick(self.current, ray_origin, ray_direction)

    def select(self, index: int | None, segment_id: int | None = None) -> None:
        """Select grasp ``index`` of segment ``segment_id`` (default: the listed one) and restyle."""
        with self._state:
            if segment_id is not None and segment_id in self.sets:
                self.current = segment_id
            s = self._listed()
            self.selected = None if s is None or index is None else int(np.clip(index, 0, len(s.grasps) - 1))
            self._refresh_panel()

    def restore_layers(self) -> None:
        """Tick again the layers that executing a grasp on the ground truth switched off (the
        completion's mesh, its CNN input): the user has moved on (a new completion, another
        segment chosen, a new plan or a new scene)."""
        hidden, self._hidden_layers = self._hidden_layers, []
        for layer in hidden:
            self.host.show_layer(layer, True)

    def follow_segment(self, segment_id: int | None) -> None:
        """The app selected ``segment_id``: list its grasps, when it has some."""
        if segment_id is not None and segment_id in self.sets and segment_id != self.current:
            self.select(0 if self.sets[segment_id].grasps else None, segment_id)

    def export(self, segment_id: int | None, fmt: str = "json") -> tuple[str, bytes]:
        """``(file name, content)`` of a segment's grasps: ``json`` (with executions and robustness
        when present) or ``zip`` (the pybullet scene of the mesh they were planned on, that JSON
        included). Raises ValueError for the user."""
        s = self.sets.get(segment_id) if segment_id is not None else None
        if s is None or not s.grasps:
            raise ValueError("No grasps to export: plan grasps on a segment first.")
        scene = self.host.scene()
        assert scene is not None  # grasps are planned on a scene and forgotten with it
        meta = {
            "source": scene.capture.source,
            "segment": s.segment_id,
            "mesh": s.method,
            "hand": s.hand,
            "seed": s.seed,
            "table": s.table,
            "T_world_cam": np.asarray(scene.T_world_cam).tolist(),
            "planning_seconds": s.seconds.get("plan"),
            "ground_truth": s.truth_name,
            # The quantile each grasp's robustness.epsilon_low is of its epsilons over the samples.
            "robust_quantile": None if s.robustness is None else ROBUST_QUANTILE,
            # Grasps from this index on were planned on the grasp envelope (the ranking's wider search).
            "wider_from": s.wider_from,
        }
        stem = f"{scene.name}_seg{s.segment_id}_{s.method}_{s.hand}"
        if fmt == "json":
            return f"{stem}_grasps.json", grasps_to_json(s.grasps, s.executions, meta, s.robustness).encode()
        if fmt == "zip":
            return f"{stem}_pybullet.zip", scene_zip(
                s.mesh_world, s.grasps, s.executions, meta, robustness=s.robustness
            )
        raise ValueError(f"unknown grasp export {fmt!r}; choose json or zip")

    def clear(self) -> None:
        """Forget every segment's grasps and remove their nodes (a new scene); cancels a running job."""
        job = self.jobs.running_job()
        if job is not None:
            job.cancel()
        with self._state:
            self.drawing.clear()
            self.sets, self.current, self.selected = {}, None, None
            self._refresh_panel()
        self.restore_layers()

    def info_markdown(self) -> str:
        """The Grasps folder's text: the listed segment's plan, the selected grasp, its execution."""
        scene = self.host.scene()
        if scene is None:
            return info_markdown(None, False, None)
        return info_markdown(self._listed(), not scene.capture.objects, self.selected)

    # ------------------------------------------------------------------------------------------
    # Panel

    def _listed(self) -> SegmentGrasps | None:
        """The grasps of the segment the dropdown lists (None: no segment or no grasps)."""
        return None if self.current is None else self.sets.get(self.current)

    def _has_grasps(self) -> bool:
        """Whether the listed segment has grasps (to rank)."""
        s = self._listed()
        return s is not None and bool(s.grasps)

    def _restyle(self) -> None:
        self.drawing.restyle(self.current, self.selected, bool(self.panel.show_all.value))

    def _refresh_panel(self) -> None:
        """Grasp dropdown, styles and info for the listed segment."""
        s = self._listed()
        if s is None or not s.grasps:
            self._options = {}
            self.panel.grasp.options = (NO_GRASP,)
            set_value(self.panel.grasp, NO_GRASP)
        else:
            self._options = grasp_options(s)
            options = tuple(self._options)
            if tuple(self.panel.grasp.options) != options:
                self.panel.grasp.options = options
            # Entries follow the robust order once ranked: find the selected grasp's entry by index.
            entry = {k: o for o, k in self._options.items()}
            value = NO_GRASP if self.selected is None else entry[self.selected]
            if self.panel.grasp.value != value:
                set_value(self.panel.grasp, value)
        self.jobs.refresh_rank()
        self._restyle()
        self._show_info()

    def _show_info(self) -> None:
        self.panel.info.content = self.info_markdown()

    def _wire(self) -> None:
        p = self.panel

        @p.plan.on_click
        def _(event: viser.GuiEvent) -> None:
            self.plan(
                self.host.selected_segment(), p.hand.value, p.method.value, int(p.count.value), event.client, wait=False
            )

        @p.cancel.on_click
        def _(_event: viser.GuiEvent) -> None:
            self.cancel()

        @p.rank.on_click
        def _(event: viser.GuiEvent) -> None:
            self.rank(self.current, event.client, wait=False)

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
                self.host.notify(event.client, "No grasp selected", "Plan grasps and pick one first.", "yellow")
            else:
                self.execute(self.current, [self.selected], event.client, wait=False)

        @p.execute_all.on_click
        def _(event: viser.GuiEvent) -> None:
            self.execute(self.current, None, event.client, wait=False)

        for fmt, button in p.exports.items():

            def download(event: viser.GuiEvent, fmt: str = fmt) -> None:
                send_download(event.client, lambda: self.export(self.current, fmt), self.host.notify)

            button.on_click(download)
