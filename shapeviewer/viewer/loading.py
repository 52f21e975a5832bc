"""The Pipeline tab's scene jobs (paper Fig. 5, steps 1-2): load a capture (a generated scene, a
file of the server's data folder or an upload), segment it and show it.

A capture that cannot be read or has no segment to complete leaves the shown scene as it was and
tells the client why. Segmentation estimates the world frame of a real capture
(:func:`~shapeviewer.perception.segment.world_frame`); everything is drawn in that frame.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import viser

from ..perception.capture import Capture, CaptureError, load_capture
from . import panel as P
from . import sources
from .context import SessionContext
from .gui import set_value, unlisted_problem
from .state import LoadedScene, load_scene

log = logging.getLogger(__name__)


class SceneLoading:
    """Loads, segments and shows a session's captures.

    Args:
        ctx: the session's parts (the scene goes to ``ctx.state``).
        before_new_scene: called once a new scene is segmented, before it replaces the shown one
            (the session leaves the Dataset tab and drops the old scene's grasps).
    """

    def __init__(self, ctx: SessionContext, before_new_scene: Callable[[], None]) -> None:
        self.ctx = ctx
        self.before_new_scene = before_new_scene

    def load_default(self, seed: int, client: viser.ClientHandle | None) -> bool:
        """Generate and show the tabletop scene of ``seed``. False (and a notification) on failure."""
        return self.load(lambda: self.ctx.res.default_scene(int(seed)), f"scene seed {seed}", client)

    def load_cloud(self, path: str | Path, client: viser.ClientHandle | None) -> bool:
        """Load and show a capture file. On a bad file: False, an error notification, old scene kept."""
        return self.load(lambda: self._read_capture(path), str(path), client)

    def load_upload(self, name: str, content: bytes, client: viser.ClientHandle | None) -> bool:
        """Load and show a capture a browser uploaded (``name``: the browser's file name, whose suffix
        picks the reader; ``content``: the file); see :meth:`~.session.Session.load_upload`."""
        ctx = self.ctx
        shown = sources.upload_name(name)
        problem = sources.upload_problem(shown, len(content), ctx.res.max_upload_bytes)
        if problem is not None:
            ctx.notify(client, "Could not load the capture", f"{shown}: {problem}", "red")
            return False
        notes: list[str] = []

        def read() -> Capture:
            capture, note = sources.read_upload(shown, content, ctx.res.intrinsics)
            notes.extend([note] if note else [])
            return capture

        ok = self.load(read, shown, client)
        if ok and notes:
            ctx.notify(client, "Assumed intrinsics", notes[0], "yellow", auto_close=15.0)
        return ok

    def data_files(self) -> tuple[str, ...]:
        """Names of the capture files in the data folder (:func:`.sources.data_files`)."""
        return sources.data_files(self.ctx.res.data_dir)

    def load_data_file(self, name: str, client: viser.ClientHandle | None) -> bool:
        """Load a capture file of the data folder (``name`` relative to it); see
        :meth:`~.session.Session.load_data_file`."""
        ctx = self.ctx
        if ctx.res.data_dir is None:
            ctx.notify(client, "Server files are off", "Start the server with --data-dir DIR to load its files.", "red")
            return False
        name = str(name).strip()
        if not name or name == P.NO_DATA_FILE:
            ctx.notify(client, "No file chosen", "The server's data folder has no .pcd/.ply/.png/.npy file.", "red")
            return False
        try:
            path = sources.data_file(ctx.res.data_dir, name)
            problem = unlisted_problem(name, self.data_files())  # a value the client forged
            if problem is not None:
                raise CaptureError(problem)
        except CaptureError as e:
            ctx.notify(client, "Could not load the capture", str(e), "red")
            return False
        finally:
            self._refresh_data_files()
        shown = sources.one_line(name)  # messages name the file as listed, never the server's path
        return self.load(lambda: load_capture(path, intrinsics=ctx.res.intrinsics, name=shown), shown, client)

    def load(self, make: Callable[[], Capture | LoadedScene], what: str, client: viser.ClientHandle | None) -> bool:
        """Show the capture (or segmented scene) ``make`` returns, computed in the worker pool;
        ``what`` names it in messages. False, an error notification and the old scene on failure."""
        ctx = self.ctx
        with ctx.jobs.take(client) as ok:
            if not ok:
                return False
            notes = ctx.audience.loading(client, f"Loading {what}...")
            try:
                decimated = self._set_scene(ctx.res.pool.run(make), require_segment=True)
                if decimated is not None:
                    ctx.notify(client, "Large capture", decimated, "yellow")
                return True
            except Exception as e:  # any bad input: tell the user, keep the current scene
                log.warning(
                    "loading %s failed: %s",
                    sources.one_line(what),
                    sources.one_line(str(e)),
                    exc_info=not isinstance(e, (ValueError, OSError)),
                )
                ctx.notify(client, "Could not load the capture", str(e) if what in str(e) else f"{what}: {e}", "red")
                return False
            finally:
                for note in notes:
                    note.remove()

    def _refresh_data_files(self) -> None:
        dropdown = self.ctx.panel.cloud_path
        if dropdown is not None:
            options = P.data_file_options(self.data_files())
            if tuple(dropdown.options) != options:
                dropdown.options = options

    def _read_capture(self, path: str | Path) -> Capture:
        if not str(path).strip():
            raise ValueError("enter the path of a .pcd/.ply cloud or a depth image")
        return load_capture(Path(str(path).strip()).expanduser(), intrinsics=self.ctx.res.intrinsics)

    def _set_scene(self, source: Capture | LoadedScene, require_segment: bool = False) -> str | None:
        """Segment a capture (a :class:`LoadedScene` is already segmented: sessions share those,
        read-only) and replace the shown scene with it (raises, leaving the old scene, on failure).

        ``require_segment``: see :func:`~.state.load_scene`. Returns a note for the user when the
        capture was decimated (see :func:`~shapeviewer.perception.capture.decimate`), else None.
        """
        ctx = self.ctx
        scene = source if isinstance(source, LoadedScene) else ctx.res.pool.run(load_scene, source, require_segment)
        capture, panel = scene.capture, ctx.panel
        self.before_new_scene()
        ctx.state.show(scene)
        ctx.drawing.show_scene(scene, panel.cloud_colors.value == "capture")
        ctx.audience.flush()

        n_valid = int(capture.valid_mask().sum())
        panel.source.content = P.source_markdown(
            sources.markdown_text(scene.title),
            len(capture.flat_points()),
            n_valid,
            len(scene.segments),
            scene.seg_seconds,
            f"world: {scene.frame_note}",
            scene.segmentation.min_height,
        )
        decimated = capture.decimation_note()
        sent = ctx.drawing.sent_points()
        if decimated is not None or sent < n_valid:
            decimated = "; ".join(filter(None, [decimated, f"showing {sent:,} points"]))
            panel.source.content += f"  \n_{decimated}_"
        panel.segment.options = (P.NO_SEGMENT, *ctx.state.segment_options)
        set_value(panel.segment, P.NO_SEGMENT)
        if capture.colors is None:
            set_value(panel.cloud_colors, "depth")
        panel.timings.content = P.timings_markdown("No completion yet.", [("segmentation", scene.seg_seconds)])
        ctx.set_status(
            "Ready. **Click a segment** in the 3D view to complete it."
            if scene.segments
            else "**No segments found** in this capture."
        )
        return decimated if capture.original_points is not None else None
