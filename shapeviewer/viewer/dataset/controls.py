"""The Dataset tab's controls: its GUI, the index filters they set, the object and view dropdowns
kept in step with the tab, and the wiring of every control to the tab's actions.

viser runs GUI callbacks in a thread pool, and setting a dropdown from the server fires its
callback too: :meth:`DatasetControls.quiet` marks the tab's own changes, so that the callbacks
only act on the user's.
"""

from __future__ import annotations

import contextlib
import io
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, TypedDict, cast

import numpy as np
import viser

from ...evaluation.methods import METHODS, Method
from ...evaluation.records import KINDS, Metric
from ...evaluation.results import Order
from ...evaluation.viewsets import Split
from ...export import MESH_FORMATS
from ..gui import set_value

if TYPE_CHECKING:
    # Not exported by viser: what add_progress_bar returns, and add_command's hotkey and modifier.
    from viser._gui_handles import GuiProgressBarHandle
    from viser._messages import HotkeyKey, KeyModifier

SPLITS: dict[str, Split | None] = {"all objects": None, "training models": "train", "holdout models": "holdout_model"}
ORDERS: dict[str, Order] = {"worst first": "worst", "best first": "best", "name": "name", "most views": "views"}
# Metric -> (min, max, step) of the range slider, in the metric's unit.
SLIDER: dict[Metric, tuple[float, float, float]] = {
    "jaccard": (0.0, 1.0, 0.01),
    "hausdorff_mean_mm": (0.0, 100.0, 0.5),
    "geodesic": (0.0, 1.0, 0.01),
}
STEPS = {"◀ object": ("object", -1), "◀ view": ("view", -1), "view ▶": ("view", 1), "object ▶": ("object", 1)}
# Command palette entries: (label, hotkey, modifier, what, delta).
HOTKEYS: tuple[tuple[str, HotkeyKey, KeyModifier | None, str, int], ...] = (
    ("Next view", "N", None, "view", 1),
    ("Previous view", "P", None, "view", -1),
    ("Next object", "N", "shift", "object", 1),
    ("Previous object", "P", "shift", "object", -1),
)
NO_OBJECT = "(no object)"


class IndexFilters(TypedDict):
    """The index filters the controls set: keyword arguments of :meth:`ResultsStore.objects`."""

    search: str
    split: Split | None
    with_results: bool
    method: Method
    metric: Metric
    order: Order
    metric_range: tuple[float, float] | None


NO_VIEW = "(no view)"


class DatasetActions(Protocol):
    """What the controls call on the tab (see :class:`~.tab.DatasetTab` for each)."""

    active: bool

    def shown_view(self) -> tuple[str, int] | None: ...

    def select(self, name: str, view: int | None = None, client: viser.ClientHandle | None = None) -> bool: ...

    def step(self, what: str, delta: int, client: viser.ClientHandle | None = None) -> bool: ...

    def show(self, client: viser.ClientHandle | None = None) -> None: ...

    def leave(self, client: viser.ClientHandle | None = None) -> None: ...

    def open_in_pipeline(self, client: viser.ClientHandle | None = None) -> bool: ...

    def download(self, client: viser.ClientHandle | None, what: str) -> None: ...

    def refresh_index(self) -> None: ...


@dataclass
class DatasetControls:
    """Handles of the tab's controls, and the dropdown state behind them.

    ``object_options`` / ``view_options`` map the dropdown entries to object names / view numbers.
    """

    status: viser.GuiMarkdownHandle
    progress: GuiProgressBarHandle
    show: viser.GuiButtonHandle
    search: viser.GuiTextHandle
    split: viser.GuiDropdownHandle
    with_results: viser.GuiCheckboxHandle
    method: viser.GuiDropdownHandle
    metric: viser.GuiDropdownHandle
    order: viser.GuiDropdownHandle
    limit: viser.GuiCheckboxHandle
    range: viser.GuiMultiSliderHandle
    index: viser.GuiMarkdownHandle
    object: viser.GuiDropdownHandle
    view: viser.GuiDropdownHandle
    step: viser.GuiButtonGroupHandle
    details: viser.GuiMarkdownHandle
    show_grasps: viser.GuiCheckboxHandle
    open_pipeline: viser.GuiButtonHandle
    export_kind: viser.GuiDropdownHandle
    export_format: viser.GuiDropdownHandle
    export_frame: viser.GuiDropdownHandle
    export_mesh: viser.GuiButtonHandle
    export_grasps: viser.GuiButtonHandle
    export_view_csv: viser.GuiButtonHandle
    export_index_csv: viser.GuiButtonHandle
    export_rows_csv: viser.GuiButtonHandle
    export_tables: viser.GuiButtonHandle
    summary: viser.GuiMarkdownHandle
    bars_folder: viser.GuiFolderHandle
    bars_note: viser.GuiMarkdownHandle
    pipeline_note: viser.GuiButtonHandle
    bars_image: viser.GuiImageHandle | None = None
    object_options: dict[str, str] = field(default_factory=dict)
    view_options: dict[str, int] = field(default_factory=dict)
    updating: bool = False  # True while the tab itself sets controls
    _lock: threading.RLock = field(default_factory=threading.RLock)

    @property
    def downloads(self) -> tuple[tuple[viser.GuiButtonHandle, str], ...]:
        """The export buttons and what each exports (see :func:`~.exports.export_bytes`)."""
        return (
            (self.export_mesh, "mesh"),
            (self.export_grasps, "grasps"),
            (self.export_view_csv, "view_csv"),
            (self.export_index_csv, "index_csv"),
            (self.export_rows_csv, "rows_csv"),
            (self.export_tables, "tables"),
        )

    def filters(self) -> IndexFilters:
        """The index filters, as keyword arguments of :meth:`ResultsStore.objects`."""
        lo, hi = self.range.value
        return {
            "search": self.search.value,
            "split": SPLITS[self.split.value],
            "with_results": self.with_results.value,
            "method": cast(Method, self.method.value),
            "metric": cast(Metric, self.metric.value),
            "order": ORDERS[self.order.value],
            "metric_range": (float(lo), float(hi)) if self.limit.value else None,
        }

    @contextlib.contextmanager
    def quiet(self) -> Iterator[None]:
        """Mark the controls' changes inside the block as the tab's own (their callbacks ignore them)."""
        with self._lock:
            self.updating = True
            try:
                yield
            finally:
                self.updating = False

    def sync_selectors(
        self, object_options: dict[str, str], selected: str | None, view_options: dict[str, int], view: int | None
    ) -> None:
        """Fill the Object and View dropdowns (entry -> object name / view number) and show the
        ``selected`` object's ``view`` (None: the first entry / no view)."""
        with self.quiet():
            self.object_options = object_options
            options = tuple(object_options) or (NO_OBJECT,)
            self.object.options = options
            set_value(self.object, next((k for k, v in object_options.items() if v == selected), options[0]))
            self.view_options = view_options
            if view_options:
                self.view.options = tuple(view_options)
                set_value(self.view, next((k for k, v in view_options.items() if v == view), self.view.options[0]))
            else:
                self.view.options = (NO_VIEW,)

    def set_shown(self, shown: bool) -> None:
        """The Show button and the note in the Pipeline tab, while the dataset is (not) on screen."""
        self.show.label = "Back to the pipeline scene" if shown else "Show the dataset in 3D"
        self.pipeline_note.visible = shown

    def show_bars(self, gui: viser.GuiApi, png: bytes | None, caption: str) -> None:
        """Put the per-object chart (PNG bytes; None: no object has results) in its folder."""
        from PIL import Image

        if png is None:
            self.bars_note.content = "_No object in the index has results._"
            if self.bars_image is not None:
                self.bars_image.visible = False
            return
        image = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
        self.bars_note.content = caption
        if self.bars_image is None:
            with self.bars_folder:
                self.bars_image = gui.add_image(image, format="png")
        else:
            self.bars_image.image = image
            self.bars_image.visible = True

    def wire(self, gui: viser.GuiApi, tab: DatasetActions) -> None:
        """Connect every control (and the N / P hotkeys) to ``tab``."""
        for h in (self.search, self.split, self.with_results, self.method, self.order):
            h.on_update(lambda _e: tab.refresh_index())

        @self.metric.on_update
        def _(_e) -> None:
            lo, hi, st = SLIDER[self.metric.value]
            with self.quiet():
                self.range.min, self.range.max, self.range.step = lo, hi, st
                set_value(self.range, (lo, hi))
            tab.refresh_index()

        @self.limit.on_update
        def _(_e) -> None:
            self.range.disabled = not self.limit.value
            tab.refresh_index()

        @self.range.on_update
        def _(_e) -> None:
            if not self.updating and self.limit.value:
                tab.refresh_index()

        @self.object.on_update
        def _(event: viser.GuiEvent) -> None:
            if self.updating or event.client is None:
                return
            name, shown = self.object_options.get(self.object.value), tab.shown_view()
            if name and (shown is None or shown[0] != name):
                tab.select(name, None, event.client)

        @self.view.on_update
        def _(event: viser.GuiEvent) -> None:
            shown = tab.shown_view()
            if self.updating or event.client is None or shown is None:
                return
            v = self.view_options.get(self.view.value)
            if v is not None and v != shown[1]:
                tab.select(shown[0], v, event.client)

        @self.step.on_click
        def _(event: viser.GuiEvent) -> None:
            tab.step(*STEPS[self.step.value], event.client)

        self.show.on_click(lambda event: tab.leave(event.client) if tab.active else tab.show(event.client))
        self.pipeline_note.on_click(lambda event: tab.leave(event.client))

        @self.open_pipeline.on_click
        def _(event: viser.GuiEvent) -> None:
            tab.open_in_pipeline(event.client)

        @self.show_grasps.on_update
        def _(event: viser.GuiEvent) -> None:
            shown = tab.shown_view()
            if shown is not None:
                tab.select(*shown, event.client)

        for button, what in self.downloads:

            def download(event: viser.GuiEvent, what: str = what) -> None:
                tab.download(event.client, what)

            button.on_click(download)
        for label, key, modifier, what, delta in HOTKEYS:
            cmd = gui.add_command(f"Dataset: {label.lower()}", hotkey=key, modifier=modifier, icon=viser.Icon.DATABASE)

            def step(event: viser.CommandEvent, what: str = what, delta: int = delta) -> None:
                tab.step(what, delta, event.client)

            cmd.on_trigger(step)


def build_controls(gui: viser.GuiApi, tab: viser.GuiTabHandle, pipeline_tab: viser.GuiTabHandle) -> DatasetControls:
    """Add the Dataset tab's controls to ``tab``, and its "back to the pipeline" button to ``pipeline_tab``."""
    with pipeline_tab:
        # Shown at the top of the Pipeline tab while the dataset is in the 3D view.
        pipeline_note = gui.add_button(
            "Back to the pipeline scene", icon=viser.Icon.ARROW_BACK_UP, visible=False, order=-1.0, color="orange"
        )
    with tab:
        gui.add_markdown(
            "Browse the evaluation results: each object's views, the ground truth, the partial "
            "view and every method's completion side by side (paper Fig. 1)."
        )
        status = gui.add_markdown("_Opening the results store..._")
        progress = gui.add_progress_bar(0.0, visible=False, animated=True)
        show = gui.add_button("Show the dataset in 3D", icon=viser.Icon.EYE)
        with gui.add_folder("Find an object"):
            search = gui.add_text("Search", "", hint="Part of an object's name, e.g. mug or ycb/0")
            split = gui.add_dropdown("Split", tuple(SPLITS), hint="The object's split: training or holdout models")
            with_results = gui.add_checkbox(
                "Only with results", True, hint="Hide catalogue objects that have no evaluated view"
            )
            method = gui.add_dropdown(
                "Method", METHODS, initial_value="Ours-fast", hint="Whose mean metric orders and filters the index"
            )
            metric = gui.add_dropdown("Metric", tuple(SLIDER))
            order = gui.add_dropdown("Order", tuple(ORDERS), hint="Worst first: lowest Jaccard, largest distances")
            limit = gui.add_checkbox("Metric range", False, hint="Keep objects whose mean lies in the range below")
            lo, hi, st = SLIDER["jaccard"]
            rng = gui.add_multi_slider("Range", lo, hi, st, (lo, hi), disabled=True)
            index = gui.add_markdown("")
            obj = gui.add_dropdown("Object", (NO_OBJECT,), hint="Choose an object to show its first view")
        with gui.add_folder("View"):
            view = gui.add_dropdown("View", (NO_VIEW,))
            step = gui.add_button_group(
                "Step", tuple(STEPS), hint="Keys: N / P next / previous view, Shift+N / Shift+P object"
            )
            details = gui.add_markdown("_Choose an object._")
            # Off by default: a hand is as large as the object and hides the shapes being compared.
            show_grasps = gui.add_checkbox(
                "Show best grasp",
                False,
                hint="Hands of each completion's best planned grasp (blue) and of its "
                "execution on the true object (red)",
            )
            open_pipeline = gui.add_button(
                "Open in pipeline",
                icon=viser.Icon.PLAYER_PLAY,
                hint="Send this view's partial points to the Pipeline tab to complete and grasp them yourself",
            )
        with gui.add_folder("Export"):
            export_kind = gui.add_dropdown("Mesh", KINDS, initial_value="Ours-fast")
            export_format = gui.add_dropdown("Format", MESH_FORMATS)
            export_frame = gui.add_dropdown(
                "Frame",
                ("camera", "object"),
                hint="camera: the view's optical frame (as stored); object: the object's own frame",
            )
            export_mesh = gui.add_button("Mesh (full resolution)", icon=viser.Icon.DOWNLOAD)
            export_grasps = gui.add_button("Grasps of this method (JSON)", icon=viser.Icon.DOWNLOAD)
            export_view_csv = gui.add_button("View metrics (CSV)", icon=viser.Icon.DOWNLOAD)
            export_index_csv = gui.add_button(
                "Index (CSV)",
                icon=viser.Icon.DOWNLOAD,
                hint="The objects of the index: split, source, size, views, mean metrics of every method",
            )
            export_rows_csv = gui.add_button(
                "Metrics of the index's views (CSV)",
                icon=viser.Icon.DOWNLOAD,
                hint="Every view of the objects in the index, all methods",
            )
            export_tables = gui.add_button("Tables I-IV (markdown)", icon=viser.Icon.DOWNLOAD)
        with gui.add_folder("Summary", expand_by_default=False):
            summary = gui.add_markdown("")
        with gui.add_folder("Per-object bars", expand_by_default=False) as bars_folder:
            bars_note = gui.add_markdown("_Drawing..._")
    return DatasetControls(
        status,
        progress,
        show,
        search,
        split,
        with_results,
        method,
        metric,
        order,
        limit,
        rng,
        index,
        obj,
        view,
        step,
        details,
        show_grasps,
        open_pipeline,
        export_kind,
        export_format,
        export_frame,
        export_mesh,
        export_grasps,
        export_view_csv,
        export_index_csv,
        export_rows_csv,
        export_tables,
        summary,
        bars_folder,
        bars_note,
        pipeline_note,
    )
