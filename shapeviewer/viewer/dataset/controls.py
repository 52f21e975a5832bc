"""The Dataset tab's controls: its GUI, the index filters they set, the object and view dropdowns
kept in step with the tab, and the wiring of every control to the tab's actions.

viser runs GUI callbacks in a thread pool, and setting a dropdown from the server fires its
callback too: :meth:`DatasetControls.quiet` marks the tab's own changes, so that the callbacks
only act on the user's.

viser takes whatever value a browser sends for a dropdown, an entry of it or not. Every choice is
checked against its entries on the server (:meth:`DatasetControls.accept`): an unknown one is
answered with a notice and the control goes back to its last valid value, which is also what
:meth:`DatasetControls.choice` reads meanwhile, so the index never filters by it.
"""

from __future__ import annotations

import contextlib
import io
import math
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, TypedDict, cast

import numpy as np
import viser

from ...evaluation.methods import METHODS, Method
from ...evaluation.records import KINDS, Metric
from ...evaluation.results import Order
from ...evaluation.viewsets import Split
from ...export import MESH_FORMATS
from ..gui import ProgressBar, set_value
from ..sources import one_line

if TYPE_CHECKING:
    # Not exported by viser: add_command's hotkey and modifier (literal types).
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
NO_OBJECT = "(no object)"  # the Object dropdown's only entry when the index is empty
# The Object dropdown's first entry while no view is shown: nothing is chosen, so choosing any
# object (the first one too) shows its first view.
CHOOSE_OBJECT = "(choose an object)"
# The longest forged value a notice quotes (characters).
QUOTE_CHARS = 60


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


# (client, title, body, color): tell a browser something (:meth:`~..audience.Audience.notify`).
Notify = Callable[..., None]


@dataclass
class DatasetControls:
    """Handles of the tab's controls, and the dropdown state behind them.

    ``object_options`` / ``view_options`` map the dropdown entries to object names / view numbers.
    """

    status: viser.GuiMarkdownHandle
    progress: ProgressBar
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
    # id(handle) -> its last valid value, for every choice a browser makes (see accept()).
    _valid: dict[int, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for handle in self.choices:
            self._valid[id(handle)] = handle.value
        self._valid[id(self.range)] = self.range.value

    @property
    def choices(self) -> tuple[viser.GuiDropdownHandle, ...]:
        """The dropdowns whose value must be one of their entries."""
        return (
            self.split,
            self.method,
            self.metric,
            self.order,
            self.object,
            self.view,
            self.export_kind,
            self.export_format,
            self.export_frame,
        )

    def choice(self, handle: viser.GuiDropdownHandle) -> str:
        """``handle``'s value when it is one of its entries, else its last valid value (a forged
        value that :meth:`accept` has not yet put back)."""
        value = handle.value
        return value if value in handle.options else self._valid.get(id(handle), handle.options[0])

    def range_value(self) -> tuple[float, float]:
        """The Range slider's ``(low, high)`` when it is a valid range of the slider, else its last valid value."""
        value = self.range.value
        return value if self._range_ok(value) else self._valid.get(id(self.range), (self.range.min, self.range.max))

    def _range_ok(self, value: Any) -> bool:
        try:
            lo, hi = (float(x) for x in value)
        except (TypeError, ValueError):
            return False
        return math.isfinite(lo) and math.isfinite(hi) and self.range.min <= lo <= hi <= self.range.max

    def accept(self, handle: Any, client: viser.ClientHandle | None, notify: Notify) -> bool:
        """Whether ``handle``'s new value is valid (one of its entries; for the Range slider, a range
        within it). A valid value becomes the one to fall back to; an invalid one is put back to the
        last valid value, and ``client`` is told. Returns False also when the value did not change
        from the last valid one (the tab putting a value back): nothing to act on."""
        value = handle.value
        if handle is self.range:
            ok = self._range_ok(value)
        elif isinstance(handle, viser.GuiButtonGroupHandle):
            return value in handle.options or self._refuse(handle, value, None, client, notify)
        else:
            ok = value in handle.options
        key = id(handle)
        if not ok:
            previous = self._valid.get(key)
            with self.quiet():
                if previous is not None:
                    set_value(handle, previous)
            return self._refuse(handle, value, previous, client, notify)
        if key in self._valid and self._valid[key] == value:
            return False
        self._valid[key] = value
        return True

    def _refuse(self, handle: Any, value: Any, kept: Any, client: viser.ClientHandle | None, notify: Notify) -> bool:
        quoted = one_line(repr(value))
        if len(quoted) > QUOTE_CHARS:
            quoted = quoted[: QUOTE_CHARS - 1] + "…"
        kept_text = "" if kept is None else f"; it stays at {one_line(str(kept))}"
        notify(
            client,
            "Unknown choice",
            f"{handle.label}: {quoted} is not one of its entries{kept_text}.",
            "red",  # the browser sent what the page never offers
        )
        return False

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
        lo, hi = self.range_value()
        return {
            "search": str(self.search.value),
            "split": SPLITS[self.choice(self.split)],
            "with_results": bool(self.with_results.value),
            "method": cast(Method, self.choice(self.method)),
            "metric": cast(Metric, self.choice(self.metric)),
            "order": ORDERS[self.choice(self.order)],
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
        ``selected`` object's ``view`` (None: nothing chosen, :data:`CHOOSE_OBJECT` / no view)."""
        with self.quiet():
            self.object_options = object_options
            options = tuple(object_options) or (NO_OBJECT,)
            if selected is None and object_options:
                options = (CHOOSE_OBJECT, *options)
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

    def wire(self, gui: viser.GuiApi, tab: DatasetActions, notify: Notify) -> None:
        """Connect every control (and the N / P hotkeys) to ``tab``; ``notify`` answers a value that
        is none of a control's entries (see :meth:`accept`)."""

        def checked(handle: Any, act: Callable[[viser.GuiEvent], None]) -> None:
            def update(event: viser.GuiEvent) -> None:
                if self.accept(handle, event.client, notify):
                    act(event)

            handle.on_update(update)

        self.search.on_update(lambda _e: tab.refresh_index())
        self.with_results.on_update(lambda _e: tab.refresh_index())
        for dropdown in (self.split, self.method, self.order):
            checked(dropdown, lambda _e: tab.refresh_index())
        for dropdown in (self.export_kind, self.export_format, self.export_frame):
            checked(dropdown, lambda _e: None)  # read when an export is asked for

        def metric(_e: viser.GuiEvent) -> None:
            lo, hi, st = SLIDER[cast(Metric, self.choice(self.metric))]
            with self.quiet():
                self.range.min, self.range.max, self.range.step = lo, hi, st
                set_value(self.range, (lo, hi))
                self._valid[id(self.range)] = (lo, hi)
            tab.refresh_index()

        checked(self.metric, metric)

        @self.limit.on_update
        def _(_e) -> None:
            self.range.disabled = not self.limit.value
            tab.refresh_index()

        def slider(_e: viser.GuiEvent) -> None:
            if not self.updating and self.limit.value:
                tab.refresh_index()

        checked(self.range, slider)

        def choose_object(event: viser.GuiEvent) -> None:
            if self.updating or event.client is None:
                return
            name, shown = self.object_options.get(self.object.value), tab.shown_view()
            if name and (shown is None or shown[0] != name):
                tab.select(name, None, event.client)

        checked(self.object, choose_object)

        def choose_view(event: viser.GuiEvent) -> None:
            shown = tab.shown_view()
            if self.updating or event.client is None or shown is None:
                return
            v = self.view_options.get(self.view.value)
            if v is not None and v != shown[1]:
                tab.select(shown[0], v, event.client)

        checked(self.view, choose_view)

        @self.step.on_click
        def _(event: viser.GuiEvent) -> None:
            if self.accept(self.step, event.client, notify):
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
