"""The Pipeline tab's completion jobs (paper Fig. 5, steps 3-5): a segment's fast completion, the
meshes made of it on request (Algorithm 1's detailed mesh, the baselines, the grasp envelope), and
its confidence (the 8 sample completions).

Every job takes the session's job slot (:class:`~.jobs.JobQueue`), computes in the server's worker
pool and draws through :class:`~.drawing.PipelineDrawing`; results are kept on the session's
:class:`~.results.PipelineState` (one :class:`~.results.SegmentResult` per segment). Choosing a
segment that has a result brings it back as it was made (:meth:`CompletionJobs.choose`); only
Complete segment and Complete all make a segment's completion anew. Meshes are computed in the
camera optical frame and drawn in the world frame.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import trimesh
import viser

from ..completion.pipeline import Completion, SegmentTooSmallError, check_segment, complete_points, confidence_figures
from ..completion.reconstruct import fast_mesh
from ..grasp.robust import sample_meshes
from . import panel as P
from .context import SessionContext
from .gui import plural, set_value
from .jobs import READY
from .results import SegmentResult
from .state import MESH_TITLES, make_mesh

log = logging.getLogger(__name__)


class CompletionJobs:
    """Completes a session's segments and makes, draws and keeps their meshes.

    Args:
        ctx: the session's parts (its results go to ``ctx.state``).
        moved_on: called when a completion is drawn (made, or brought back by choosing its
            segment): the user has moved on from what was shown before (the session shows the layers
            that executing a grasp on the ground truth hid).
    """

    def __init__(self, ctx: SessionContext, moved_on: Callable[[], None] = lambda: None) -> None:
        self.ctx = ctx
        self.moved_on = moved_on

    def complete(self, ids: list[int] | None, client: viser.ClientHandle | None) -> list[Completion]:
        """Complete segments ``ids`` (None: every usable one) in one batch, draw them, and fill the
        timings table. Returns the completions ([] when none was made: the client is told why)."""
        with self.ctx.jobs.take(client) as ok:
            if not ok or self.ctx.state.scene is None:
                return []
            return self._complete_in_slot(ids, client)

    def choose(self, segment_id: int, client: viser.ClientHandle | None) -> Completion | None:
        """Select segment ``segment_id`` (picked in the Segment dropdown or clicked in 3D).

        A segment completed earlier comes back as it was made, without computing anything: its
        completion (CNN input and output, sample completions, fast mesh), the detailed mesh,
        baselines and grasp envelope made of it, and its stage times, drawn again. Any other
        segment is completed. Returns the segment's completion, or None when it has none and cannot
        be completed or another job is running (the client is told why).
        """
        ctx, state = self.ctx, self.ctx.state
        with ctx.jobs.take(client) as ok:
            if not ok or state.scene is None:
                return None
            result = state.results.get(segment_id)
            if result is None:
                done = self._complete_in_slot([segment_id], client)
                return done[0] if done else None
            self._bring_back(result)
            return result.completion

    def compute_mesh(
        self, kind: str, segment_id: int | None, client: viser.ClientHandle | None
    ) -> trimesh.Trimesh | None:
        """Compute, keep and draw a segment's mesh ``kind`` (a key of :data:`~.state.MESH_TITLES`),
        completing the segment (default: the selected one) first when it has no completion yet.
        Returns the camera-frame mesh, or None when it cannot be made (the client is told why)."""
        if kind not in MESH_TITLES:
            raise ValueError(f"unknown mesh {kind!r}; choose one of {tuple(MESH_TITLES)}")
        ctx, state = self.ctx, self.ctx.state
        sid = state.selected if segment_id is None else segment_id
        if sid is None:
            ctx.notify(client, "No segment selected", "Click a segment or pick one above.", "yellow")
            return None
        with ctx.jobs.take(client) as ok:
            if not ok or state.scene is None:
                return None
            if kind == "mirror" and state.scene.segmentation.plane_cam is None:
                ctx.notify(
                    client,
                    "Mirror needs a support plane",
                    "No table plane was found in this capture, and the Mirror baseline searches its "
                    "symmetry plane perpendicular to the table.",
                    "red",
                )
                return None
            result = state.results.get(sid)
            if result is None:
                if not self._complete_in_slot([sid], client):
                    return None
                result = state.results[sid]
            ctx.select(sid)
            return self._compute_mesh_in_slot(kind, result, client)

    def show_confidence(self, c: Completion) -> None:
        """The Confidence layer of ``c`` (the disagreement of its 8 sample completions) and its
        figures in the stage panel."""
        scene = self.ctx.state.scene
        assert scene is not None  # ``c`` is a completion of it
        spread = c.spread
        self.ctx.drawing.draw_confidence(scene, c, spread)
        self.ctx.panel.timings.content = P.confidence_markdown(
            c.segment_id, *confidence_figures(c.grid_in, c.solid, spread), c.axis, c.cuboid
        )

    def show_sample(self, k: int, client: viser.ClientHandle | None) -> trimesh.Trimesh | None:
        """Show sample completion ``k`` (1..8) of the selected segment as a translucent mesh in the
        Confidence layer (turned on), or none (``k`` = 0). Returns the camera-frame mesh shown."""
        ctx, state = self.ctx, self.ctx.state
        c = None if state.selected is None else state.completion(state.selected)
        if c is None or state.scene is None:
            if k:
                ctx.notify(client, "No completion selected", "Complete a segment, then step through its samples.")
            return None
        if not 0 <= k <= P.N_SAMPLES:
            raise ValueError(f"sample {k} out of range 0..{P.N_SAMPLES}")
        with ctx.jobs.take(client) as ok:
            if not ok:
                return None
            mesh = None
            if k:
                try:
                    mesh = ctx.res.pool.run(fast_mesh, c.samples[k - 1], c.frame, level=c.mesh_level)
                except ValueError as e:  # this sample has no surface: nothing to show
                    ctx.notify(client, "Empty sample", f"Sample {k} of segment {c.segment_id}: {e}", "yellow")
            ctx.drawing.draw_sample(state.scene, c.segment_id, mesh)
            ctx.audience.flush()
        if k:
            set_value(ctx.panel.layers["confidence"], True)  # the sample is drawn in that layer
            ctx.set_status(f"Sample completion **{k}** of {P.N_SAMPLES} of segment {c.segment_id}.")
        return mesh

    # ------------------------------------------------------------------------------------------
    # For the grasp controller

    def sample_meshes_world(self, segment_id: int) -> list[trimesh.Trimesh] | None:
        """The meshes of a segment's sample completions (world frame, metres), None without a completion."""
        c, scene = self.ctx.state.completion(segment_id), self.ctx.state.scene
        if c is None or scene is None:
            return None
        return sample_meshes(c.samples, c.frame, scene.T_world_cam, level=c.mesh_level)

    def make_mesh_for_grasps(
        self, kind: str, segment_id: int, client: viser.ClientHandle | None
    ) -> trimesh.Trimesh | None:
        """Make (completing first when needed) and draw a segment's mesh ``kind`` for grasp planning."""
        if kind == "fast":
            done = self.complete([segment_id], client)
            return done[0].fast_mesh if done else None
        return self.compute_mesh(kind, segment_id, client)

    # ------------------------------------------------------------------------------------------
    # In the job slot

    def _complete_in_slot(self, ids: list[int] | None, client: viser.ClientHandle | None) -> list[Completion]:
        """:meth:`complete` for a caller that holds the job slot (and has a scene)."""
        ctx, state = self.ctx, self.ctx.state
        scene = state.scene
        assert scene is not None  # the callers return early without one
        single = ids is not None
        if ids is not None:
            missing = [i for i in ids if i not in scene.segments]
            if missing:
                ctx.notify(client, "No such segment", f"Segment {missing[0]} is not in this scene.", "red")
                return []
            ctx.select(ids[0])
        usable, skipped = [], []
        for sid in ids if ids is not None else list(scene.segments):
            try:
                usable.append((sid, check_segment(scene.segments[sid].points_cam)))
            except SegmentTooSmallError as e:
                skipped.append(f"segment {sid}: {e}")
        if skipped:
            ctx.notify(
                client,
                "Cannot complete" if single else "Some segments were skipped",
                "; ".join(skipped),
                "red" if single else "yellow",
            )
        if not usable:
            return []
        what = f"segment {usable[0][0]}" if single else plural(len(usable), "segment")
        ctx.set_status(f"_Completing {what}..._")
        try:
            done = ctx.res.pool.run(
                complete_points,
                [p for _, p in usable],
                ctx.res.completer,
                [sid for sid, _ in usable],
                support_plane=scene.segmentation.plane_cam,
                revolve_answers=ctx.panel.revolve.value,
                fit_boxes=ctx.panel.fit_boxes.value,
            )
            t0 = time.perf_counter()
            for c in done:
                self._draw_completion(c)
            ctx.audience.flush()
            send = time.perf_counter() - t0
        except Exception as e:  # keep the app alive whatever the model or mesher does
            log.exception("completing %s failed", what)
            ctx.notify(client, "Completion failed", f"{what}: {e}", "red")
            ctx.set_status(READY)
            return []
        # A new completion starts without the meshes made of the segment's earlier one.
        share = send / len(done)  # of sending the batch, each segment's (for when it is chosen again)
        state.results.update(
            {c.segment_id: SegmentResult(c, timings=P.completion_timings([c], scene.seg_seconds, share)) for c in done}
        )
        title = f"Segment **{done[0].segment_id}**" if len(done) == 1 else f"All **{len(done)}** segments (totals)"
        state.last_timings = P.completion_timings(done, scene.seg_seconds, send)
        ctx.panel.timings.content = P.completion_timings_markdown(title, state.last_timings)
        self.moved_on()
        ctx.set_status(f"Completed {what}. Click a segment to complete it.")
        empty = [f"segment {c.segment_id}: {c.error}" for c in done if c.fast_mesh is None]
        if empty:
            ctx.notify(client, "Empty completion", "; ".join(empty), "yellow")
        return done

    def _compute_mesh_in_slot(
        self, kind: str, result: SegmentResult, client: viser.ClientHandle | None
    ) -> trimesh.Trimesh | None:
        """Make, draw and keep mesh ``kind`` of a segment's ``result`` (the caller holds the job slot)."""
        ctx = self.ctx
        scene = ctx.state.scene
        assert scene is not None  # ``result`` is of one of its segments
        c = result.completion
        sid, title = c.segment_id, MESH_TITLES[kind]
        what = f"the {title.lower()} of segment {sid}"
        notes = ctx.audience.loading(client, f"Computing {what}...")
        ctx.set_status(f"_Computing {what}..._")
        steps: dict[str, float] = {}
        try:
            t0 = time.perf_counter()
            mesh = ctx.res.pool.run(make_mesh, kind, c, scene, steps)
            seconds = time.perf_counter() - t0
            t0 = time.perf_counter()
            ctx.drawing.draw_mesh(scene, kind, sid, mesh)
            ctx.audience.flush()
            send = time.perf_counter() - t0
        except Exception as e:  # an empty completion, a degenerate cloud, ...: keep the app alive
            log.warning("computing %s failed: %s", what, e, exc_info=not isinstance(e, ValueError))
            ctx.notify(client, f"{title} failed", f"Segment {sid}: {e}", "red")
            return None
        finally:
            for note in notes:
                note.remove()
            ctx.set_status(READY)
        result.add_mesh(kind, mesh, seconds, steps)
        set_value(ctx.panel.layers[f"{kind}_mesh"], True)  # the user asked to see it
        ctx.panel.timings.content = P.mesh_timings_markdown(kind, sid, seconds, result.detailed_steps, send)
        ctx.notify(
            client, f"{title} ready", f"Segment {sid}: {len(mesh.faces):,} triangles in {seconds:.1f} s.", "green"
        )
        return mesh

    def _bring_back(self, result: SegmentResult) -> None:
        """Select, draw and describe a segment's ``result`` as it was made (the caller holds the job slot)."""
        ctx = self.ctx
        scene = ctx.state.scene
        assert scene is not None  # ``result`` is of one of its segments
        c = result.completion
        sid = c.segment_id
        ctx.select(sid)
        self._draw_completion(c)
        for kind, mesh in result.meshes.items():
            ctx.drawing.draw_mesh(scene, kind, sid, mesh)
        ctx.audience.flush()
        self.moved_on()
        kept = [MESH_TITLES[kind].lower() for kind in result.meshes]
        title = f"Segment **{sid}** (completed earlier" + (f"; kept: {', '.join(kept)})" if kept else ")")
        ctx.panel.timings.content = P.completion_timings_markdown(title, result.timings)
        ctx.set_status(
            f"Segment {sid}: its completion"
            + (f" and {', '.join(kept)}" if kept else "")
            + " as made earlier. **Complete segment** makes it anew."
        )

    def _draw_completion(self, c: Completion) -> None:
        ctx = self.ctx
        scene = ctx.state.scene
        assert scene is not None  # ``c`` is a completion of it
        ctx.drawing.draw_completion(scene, c, ctx.panel.shade_output.value, ctx.panel.layers["cnn_output"].value)
        ctx.drawing.draw_sample(scene, c.segment_id, None)  # a sample of the previous completion
        set_value(ctx.panel.sample, 0)
        if ctx.panel.layers["confidence"].value:
            self.show_confidence(c)
