"""The Dataset tab: browse a results store (:mod:`shapeviewer.evaluation.results`) like the paper's website (SPEC §9).

The tab lists the catalogue objects with their results, and shows one view at a time in 3D, left
to right as in the paper's Fig. 1: the ground truth, the partial view (points), then each method's
completion (Partial, Mirror, Ours-fast, Ours-detailed), each labelled with its metrics and, when
the store has them, its grasps (planned on the completion vs executed on the true object).

Frames. The store keeps every mesh in the camera optical frame of its view. For display, all of a
view's items share one *display frame*: the object's own frame (catalogue axes, z up), turned
about z so that the side the sensor did not see faces the browser camera, with the ground truth
standing on z = 0; each item is then shifted along +x into its column (:func:`layout_view`).

viser's 3D scene is shared by the tabs (and the browser does not report tab changes), so the
dataset is drawn under its own root frame ``/dataset`` that is only visible while the dataset is
*shown*; showing it hides the pipeline's nodes and restores them afterwards (the app's
``set_pipeline_visible``). Selecting a view shows the dataset; "Back to the pipeline" and "Open in
pipeline" return.

Without a browser, tests call :meth:`DatasetTab.select`, :meth:`DatasetTab.step`,
:meth:`DatasetTab.export_bytes` and read :attr:`DatasetTab.drawn`.
"""

from __future__ import annotations

import io
import logging
import math
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
import viser

from .. import export
from ..camera import transform_points
from ..evaluation.run import METHODS, PAPER_COLUMN, PAPER_GRASP, SET_TITLES, VIEW_SETS, paper_figure
from ..evaluation.results import HIGHER_IS_BETTER, KINDS, METRIC_TITLES, CompletionResult, GraspSummary, ObjectSummary, \
    ResultsStore, ViewInfo, build_sample_store, read_mesh, read_points, sample_store_complete, sample_store_dir

log = logging.getLogger(__name__)

ROOT = "/dataset"
# Display budget: meshes with more triangles are decimated for display (exports use the files).
DISPLAY_MAX_FACES = 20_000
DISPLAY_CACHE = 96  # display meshes kept in memory (about 16 views; a few hundred kB each)
POINT_SIZE = 0.003  # metres; viser draws points about twice this wide
# Column spacing / largest object footprint: room for the labels between the items.
SPACING_FACTOR = 1.3
# The browser camera: a narrow field of view from farther away keeps the perspective nearly the
# same for every column, so the items can be compared side by side.
DATASET_FOV = math.radians(30.0)
# Viewing direction: turned this far (azimuth) from straight opposite the sensor, so that both the
# occluded back and some of the seen side are visible; elevation clamped to this band.
OBLIQUE_AZIMUTH = math.radians(35.0)
ELEVATION_RANGE = (math.radians(15.0), math.radians(45.0))
TITLES = {"truth": "Ground truth", "points": "Partial view", "Partial": "Partial", "Mirror": "Mirror", "Hull": "Hull",
          "Ours-fast": "Ours (fast)", "Ours-detailed": "Ours (detailed)"}
# Partial and Mirror keep the pipeline tab's baseline colours; ours are warm, the truth neutral.
COLORS = {"truth": (150, 175, 150), "points": (40, 110, 220), "Partial": (160, 160, 160), "Mirror": (110, 150, 215),
          "Hull": (150, 120, 190),
          "Ours-fast": (240, 150, 60), "Ours-detailed": (205, 95, 45)}
PLANNED_HAND = ((70, 140, 255), 0.3)  # colour, opacity: the completion stays visible through the hand
EXECUTED_HAND = ((250, 90, 60), 0.5)
SPLITS = {"all objects": None, "training models": "train", "holdout models": "holdout_model"}
ORDERS = {"worst first": "worst", "best first": "best", "name": "name", "most views": "views"}
INDEX_ROWS = 12  # rows of the index table in the panel
# Short column titles for the narrow panel.
SHORT = {"Partial": "Part.", "Mirror": "Mirr.", "Hull": "Hull", "Ours-fast": "Fast", "Ours-detailed": "Det.", "jaccard": "J",
         "hausdorff_mean_mm": "H mm", "geodesic": "G"}
SLIDER = {"jaccard": (0.0, 1.0, 0.01), "hausdorff_mean_mm": (0.0, 100.0, 0.5), "geodesic": (0.0, 1.0, 0.01)}
POLL_SECONDS = 5.0  # how often the tab looks for new view files
DEFAULT = "default"  # ``results=DEFAULT``: the sample store, built in the background when missing


# ----------------------------------------------------------------------------------------------
# Layout (plain numpy)


def _rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class ViewLayout:
    """Where a view's items go (display frame, metres, z up; the browser camera looks along +y).

    Attributes:
        T_display_cam: kind -> 4x4 map from the view's camera frame to that item's column.
        columns: kind -> (3,) base centre of the column (x of the column, y 0, z 0).
        top: height (m) of the tallest item above z = 0 (labels go above it).
        spacing: distance between columns (m).
        camera_position, look_at: the browser camera for the whole row.
        sensor_position: (3,) where the sensor was, relative to the points column, scaled in to
            the row (display frame); sensor_wxyz its orientation (camera optical axes).
    """

    T_display_cam: dict[str, np.ndarray]
    columns: dict[str, np.ndarray]
    top: float
    spacing: float
    camera_position: np.ndarray
    look_at: np.ndarray
    sensor_position: np.ndarray
    sensor_wxyz: np.ndarray


def layout_view(T_cam_obj: np.ndarray, truth_cam: np.ndarray, extents_cam: dict[str, np.ndarray],
                kinds: tuple[str, ...], aspect: float = 1.3, fov: float = DATASET_FOV) -> ViewLayout:
    """Lay out a view's items in one row, the unseen side towards the camera.

    Args:
        T_cam_obj: 4x4 object pose in the view's camera frame.
        truth_cam: (N, 3) ground-truth vertices, camera frame (metres).
        extents_cam: kind -> (M, 3) vertices (camera frame) of each item, for the column width.
        kinds: the items left to right.
        aspect, fov: the browser camera's aspect ratio and vertical field of view (radians).
    """
    T_obj_cam = np.linalg.inv(np.asarray(T_cam_obj, dtype=np.float64))
    sensor_obj = T_obj_cam[:3, 3]
    away = -sensor_obj / max(np.linalg.norm(sensor_obj), 1e-9)  # from the object towards its unseen side
    horizontal = float(np.hypot(away[0], away[1]))
    azimuth = math.atan2(away[1], away[0]) + OBLIQUE_AZIMUTH if horizontal > 1e-6 else -math.pi / 2
    elevation = float(np.clip(math.atan2(away[2], horizontal), *ELEVATION_RANGE))
    # Turn about z so that the viewing azimuth points to -y (where the browser camera stands).
    R = np.eye(4)
    R[:3, :3] = _rot_z(-math.pi / 2 - azimuth)
    T_common = R @ T_obj_cam
    truth = transform_points(T_common, truth_cam)
    lo, hi = truth.min(axis=0), truth.max(axis=0)
    T_common[:3, 3] -= [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]]
    truth_width = float(np.linalg.norm(hi[:2] - lo[:2]))
    widths = []
    for pts in extents_cam.values():
        if len(pts):
            p = transform_points(T_common, pts)
            # A failed completion can be huge; it may overlap its neighbours rather than shrink the row.
            widths.append(min(float(np.linalg.norm(p[:, :2].max(0) - p[:, :2].min(0))), 1.6 * truth_width))
    spacing = SPACING_FACTOR * max([truth_width, *widths, 0.05])
    n = len(kinds)
    T_display_cam, columns = {}, {}
    for i, kind in enumerate(kinds):
        T = T_common.copy()
        T[0, 3] += (i - (n - 1) / 2) * spacing
        T_display_cam[kind] = T
        columns[kind] = np.array([(i - (n - 1) / 2) * spacing, 0.0, 0.0])
    tops = [float(transform_points(T_common, p)[:, 2].max()) for p in extents_cam.values() if len(p)]
    top = max([float(hi[2] - lo[2]), *[min(t, 2.0 * (hi[2] - lo[2])) for t in tops]])
    # Fit the row (and the labels above it) in view: half-width over tan(horizontal half-fov).
    half_w = 0.5 * n * spacing * 1.04
    half_h = 0.5 * (top + 0.9 * spacing) * 1.1
    distance = max(half_w / (math.tan(fov / 2) * aspect), half_h / math.tan(fov / 2))
    look_at = np.array([0.0, 0.0, 0.5 * top + 0.12 * spacing])
    direction = np.array([0.0, -math.cos(elevation), math.sin(elevation)])
    # The sensor, pulled in to 1.3 object widths from the points column's object centre.
    sensor_common = transform_points(T_common, T_obj_cam[:3, 3][None])[0]
    centre = np.array([0.0, 0.0, (hi[2] - lo[2]) / 2])
    ray = sensor_common - centre
    sensor_pos = columns.get("points", np.zeros(3)) + centre + ray / np.linalg.norm(ray) * 0.55 * spacing
    R_disp_cam = T_common[:3, :3]
    sensor_wxyz = viser.transforms.SO3.from_matrix(R_disp_cam).wxyz
    return ViewLayout(T_display_cam, columns, top, spacing, look_at + distance * direction, look_at, sensor_pos,
                      np.asarray(sensor_wxyz))


def points_colors(depth: np.ndarray) -> np.ndarray:
    """uint8 RGB (N, 3) of the partial view's colour, light for points near the sensor, dark for far ones."""
    d = np.asarray(depth, dtype=np.float64)
    lo, hi = (np.percentile(d, [2, 98]) if len(d) else (0.0, 1.0))
    x = np.clip((d - lo) / max(hi - lo, 1e-6), 0.0, 1.0)[:, None]
    near, far = np.array([120, 185, 255]), np.array([20, 60, 150])
    return (near + (far - near) * x).astype(np.uint8)


def decimate(mesh: trimesh.Trimesh, max_faces: int = DISPLAY_MAX_FACES) -> trimesh.Trimesh:
    """``mesh`` with at most ``max_faces`` triangles (quadric decimation, open3d), for display only."""
    if len(mesh.faces) <= max_faces:
        return mesh
    import open3d as o3d

    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(mesh.vertices, np.float64)),
                                  o3d.utility.Vector3iVector(np.asarray(mesh.faces, np.int32)))
    m = m.simplify_quadric_decimation(target_number_of_triangles=int(max_faces))
    return trimesh.Trimesh(np.asarray(m.vertices), np.asarray(m.triangles), process=False)


# ----------------------------------------------------------------------------------------------
# Text (plain values in, markdown out)


def _f(v: float, digits: int = 3) -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}f}"


def _share(v: float) -> str:
    if v is None or math.isnan(v):
        return "–"
    return f"{100 * v:.0f}%" if 0 <= v <= 1 else f"{v:g}"


# Labels sit above their column, which is about 25 characters wide on a laptop screen: short lines.
def completion_label(c: CompletionResult) -> str:
    """A completion's label lines: Jaccard and geodesic divergence, then the mean Hausdorff (mm)."""
    if not c.ok:
        return "failed:\n" + c.error[:24]
    return f"J {_f(c.jaccard, 2)} · G {_f(c.geodesic, 2)}\nH {_f(c.hausdorff_mean_mm, 1)} mm"


def grasp_label(g: GraspSummary) -> str:
    """A grasp summary's label lines: planned vs executed joint (deg) and pose (mm) errors, lift successes."""
    if g.error:
        return "grasps failed"
    lifted = (f"lifted {round(g.lift_success * g.n)}/{g.n}" if g.n and 0 <= g.lift_success <= 1
              else f"lift {_share(g.lift_success)}")
    return f"grasp {_f(g.joint_error_deg, 1)}° · {_f(g.pose_error_mm, 1)} mm\n{lifted}"


def index_markdown(objects: list[ObjectSummary], method: str, metric: str, selected: str | None,
                   total: int) -> str:
    """The first rows of the filtered index as a markdown table (the selected object in bold)."""
    if not objects:
        return "_No object matches._"
    head = (f"{len(objects)} of {total} objects · size = longest side · means of **{method}**  \n"
            f"| object | split | cm | views | {SHORT.get(metric, metric[:4])} |\n|---|---|---:|:---:|---:|")
    rows = []
    for o in objects[:INDEX_ROWS]:
        name = f"**{o.name}**" if o.name == selected else o.name
        split = "holdout" if o.split == "holdout_model" else "train"
        size = "?" if any(math.isnan(x) for x in o.extents) else f"{100 * max(o.extents):.0f}"
        rows.append(f"| {name} | {split} | {size} | {o.views} | "
                    f"{_f(o.mean(method, metric), 1 if 'mm' in metric else 2)} |")
    more = [f"| _… {len(objects) - INDEX_ROWS} more_ | | | | |"] if len(objects) > INDEX_ROWS else []
    return "\n".join([head, *rows, *more])


def view_markdown(o: ObjectSummary, info: ViewInfo, completions: list[CompletionResult],
                  grasps: list[GraspSummary]) -> str:
    """The chosen view's object facts, per-method metrics table and grasp table."""
    size = " × ".join(f"{100 * x:.1f}" for x in o.extents) if not any(math.isnan(x) for x in o.extents) else "?"
    lines = [f"**{o.name}** · view {info.view} · {SET_TITLES.get(info.view_set, info.view_set)}  \n"
             f"{o.source} · {'holdout model' if o.split == 'holdout_model' else 'training model'} · {size} cm",
             "", "| method | J ↑ | H mm ↓ | G ↓ | s |", "|---|---:|---:|---:|---:|"]
    for c in completions:
        if c.ok:
            lines.append(f"| {c.method} | {_f(c.jaccard, 3)} | {_f(c.hausdorff_mean_mm, 1)} | {_f(c.geodesic, 3)} | "
                         f"{_f(c.seconds, 2)} |")
        else:
            lines.append(f"| {c.method} | failed | | | |")
    failed = [f"{c.method}: {c.error}" for c in completions if not c.ok]
    if failed:
        lines += ["", *(f"_{e}_  " for e in failed)]
    if grasps:
        hands = sorted({g.hand for g in grasps})
        lines += ["", f"**Grasps** ({', '.join(hands)}): planned on the completion, executed on the truth; "
                  "errors planned vs executed, share lifted", "",
                  "| on | n | joint° | mm | lift |", "|---|---:|---:|---:|---:|"]
        for g in grasps:
            on = SHORT.get(g.method, g.method) + (f" ({g.hand})" if len(hands) > 1 else "")
            if g.error:
                lines.append(f"| {on} | failed | | | |")
            else:
                lines.append(f"| {on} | {g.n} | {_f(g.joint_error_deg, 1)} | {_f(g.pose_error_mm, 1)} | "
                             f"{_share(g.lift_success)} |")
    else:
        lines += ["", "_No grasp results for this view._"]
    return "\n".join(lines)


SET_SHORT = {"training_view": "train", "holdout_view": "h. view", "holdout_model": "h. model",
             "tabletop_train_object": "table", "tabletop_holdout_model": "table h. model"}


def summary_markdown(summary: dict, grasps: dict) -> str:
    """Per-set means (paper Tables I–III, and IV when grasps exist), compact enough for the panel.

    ``summary``: :meth:`ResultsStore.summary`; ``grasps``: :meth:`ResultsStore.grasp_summary`. The
    "paper" column is the paper's "Ours" (theirs, on their data, SPEC §7-8).
    """
    counts = {s: max(summary[s][m]["n"] + summary[s][m]["failed"] for m in METHODS) for s in VIEW_SETS
              if s in summary}
    sets = [s for s, n in counts.items() if n]
    out = ["Views per set: " + ", ".join(f"{SET_TITLES[s]} ({SET_SHORT[s]}) {counts[s]}" for s in sets)
           + ". Means over the views where the method succeeded.", ""]
    for number, metric, title in (("I", "jaccard", "Jaccard ↑"), ("II", "hausdorff_mean_mm", "Hausdorff mean, mm ↓"),
                                  ("III", "geodesic", "Geodesic divergence ↓")):
        digits = 1 if "mm" in metric else 3
        out += [f"**Table {number}: {title}**", "",
                "| set | " + " | ".join(SHORT[m] for m in METHODS) + " | paper |",
                "|---|" + "---:|" * (len(METHODS) + 1)]
        for s in sets:
            cells = [_f(summary[s][m][metric], digits) if summary[s][m]["n"] else "–" for m in METHODS]
            out.append(f"| {SET_SHORT[s]} | " + " | ".join(cells)
                       + f" | {_f(paper_figure(metric, s, 'Ours-detailed'), digits)} |")
        out.append("")
    if grasps:
        out += ["**Table IV: grasps**, planned on the completion, executed on the truth: joint and pose "
                "errors (mean), share lifted; paper: joint ° / pose mm", "",
                "| method | joint ° | pose mm | lift | paper |", "|---|---:|---:|:---:|---:|"]
        for s in VIEW_SETS:
            rows = []
            for m in METHODS:
                c = grasps.get(s, {}).get(m)
                if not c:
                    continue
                col = PAPER_COLUMN.get(m, -1)
                ref = PAPER_GRASP["joint_error_deg"].get(s)
                paper = (f"{ref[col]:.1f} / {PAPER_GRASP['pose_error_mm'][s][col]:.0f}" if ref and col >= 0 else "–")
                rows.append(f"| {SHORT[m]} | {_f(c['joint_error_deg'], 1)} | {_f(c['pose_error_mm'], 1)} | "
                            f"{_share(c['lift_success'])} | {paper} |")
            if rows:
                out += [f"| _{SET_TITLES[s]}_ | | | | |", *rows]
    else:
        out.append("_Table IV: no grasp results in this store._")
    return "\n".join(out)


def bars_png(objects: list[ObjectSummary], metric: str, methods: tuple[str, ...] = METHODS, limit: int = 25,
             width_px: int = 420) -> bytes | None:
    """Per-object bars of ``metric`` (one bar per method) for the first ``limit`` objects, as PNG bytes."""
    rows = [o for o in objects if any(not math.isnan(o.mean(m, metric)) for m in methods)][:limit]
    if not rows:
        return None
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    dpi = 100
    n = len(methods)
    fig = Figure(figsize=(width_px / dpi, 1.3 + 0.1 * n * len(rows) + 0.1 * len(rows)), dpi=dpi)
    ax = fig.add_subplot()
    h = 0.8 / n
    y = np.arange(len(rows))
    for k, m in enumerate(methods):
        vals = [o.mean(m, metric) for o in rows]
        ax.barh(y + (k - (n - 1) / 2) * h, [0 if math.isnan(v) else v for v in vals], height=h,
                color=np.asarray(COLORS[m]) / 255, label=m)
    ax.set_yticks(y, [o.name for o in rows], fontsize=9)
    ax.invert_yaxis()
    ax.set_xlabel(METRIC_TITLES[metric] + (", higher is better" if HIGHER_IS_BETTER[metric] else ", lower is better"),
                  fontsize=9)
    ax.tick_params(axis="x", labelsize=8)
    ax.legend(fontsize=8, ncols=2, loc="lower left", bbox_to_anchor=(0.0, 1.0), frameon=False)
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout(pad=0.4)
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


# ----------------------------------------------------------------------------------------------
# The tab


@dataclass
class DatasetHooks:
    """What the tab needs from the app: hide/show the pipeline's nodes, open a capture in the pipeline."""

    set_pipeline_visible: Callable[[bool], None]
    open_capture: Callable[..., bool]  # (capture, client) -> loaded
    notify: Callable[..., None]  # (client, title, body, color=None)


@dataclass
class _Controls:
    status: viser.GuiMarkdownHandle
    progress: viser.GuiProgressBarHandle
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


NO_OBJECT = "(no object)"


@dataclass
class _Shown:
    """The view on screen: its records, layout and display meshes (display frame)."""

    object: ObjectSummary
    info: ViewInfo
    completions: list[CompletionResult]
    grasps: list[GraspSummary]
    layout: ViewLayout
    seconds: float = 0.0
    nodes: list[str] = field(default_factory=list)


class DatasetTab:
    """The Dataset tab's controls and 3D drawing.

    Args:
        server: the viser server (its scene is shared with the pipeline tab).
        tab: the tab to put the controls in; ``pipeline_tab`` gets a "back to the pipeline" button
            shown while the dataset is on screen.
        results: a results folder, :data:`DEFAULT` (the sample store in the user cache, built in a
            background thread when missing), or None (no store: the tab says how to open one).
        hooks: see :class:`DatasetHooks`.
        weights: CNN weights for building the sample store (None: the shipped model).
    """

    def __init__(self, server: viser.ViserServer, tab, pipeline_tab, results: str | Path | None,
                 hooks: DatasetHooks, weights: str | Path | None = None) -> None:
        self.server = server
        self.hooks = hooks
        self.weights = weights
        self.store: ResultsStore | None = None
        self.active = False
        self.shown: _Shown | None = None
        self.objects: list[ObjectSummary] = []  # the filtered index
        self.total_objects = 0
        self.building = False
        self.last_error: str | None = None
        self._lock = threading.RLock()  # GUI callbacks run in a thread pool
        self._updating = False  # set while the tab itself changes its dropdowns
        self._saved_cameras: dict[int, tuple] = {}
        self._display_cache: OrderedDict[tuple, tuple] = OrderedDict()
        self._root = server.scene.add_frame(ROOT, show_axes=False, visible=False)
        self._bars_image = None
        self._bars_key = None
        self.bars_drawn = None  # the (method, metric, objects) key of the chart on screen
        self._bars_request = None
        self._bars_wanted = threading.Event()
        self._closed = threading.Event()  # set by shutdown(): background threads stop touching the GUI
        self._build_notes: dict[int, viser.NotificationHandle] = {}  # client id -> progress notification
        self._build_step = ""
        self._sample_to_build: Path | None = None
        self._generation = -1  # the store generation the index shows
        server.on_client_connect(self._add_build_note)
        server.on_client_disconnect(lambda client: self._build_notes.pop(client.client_id, None))
        self.c = self._build_controls(tab, pipeline_tab)
        self._wire()
        self._open(results)
        # Started once the store is open (a bad --results folder raises above and leaves no thread).
        self._threads = [threading.Thread(target=self._bars_worker, name="dataset-bars", daemon=True)]
        if self.store is not None:
            self._threads.append(threading.Thread(target=self._poll, name="dataset-poll", daemon=True))
        for t in self._threads:
            t.start()

    # ------------------------------------------------------------------------------------------
    # Public API

    def select(self, name: str, view: int | None = None, client: viser.ClientHandle | None = None) -> bool:
        """Show object ``name``'s view ``view`` (default: its first) in 3D. False when there is none."""
        with self._lock:
            if self.store is None:
                self.hooks.notify(client, "No results store", "Open one with --results DIR.", "yellow")
                return False
            views = self.store.views(name)
            if not views:
                self.hooks.notify(client, "No results", f"{name} has no view with results.", "yellow")
                return False
            info = next((v for v in views if v.view == view), None) if view is not None else views[0]
            if info is None:
                self.hooks.notify(client, "No such view", f"{name} has no results for view {view}.", "yellow")
                return False
            try:
                self._show(info, client)
            except Exception as e:  # a missing or broken mesh file: say so, keep the app alive
                log.warning("showing %s view %d failed: %s", name, info.view, e, exc_info=True)
                self.last_error = f"{name} view {info.view}: {e}"
                self.hooks.notify(client, "Cannot show the view", self.last_error, "red")
                return False
            self._sync_selectors()
            return True

    def step(self, what: str, delta: int, client: viser.ClientHandle | None = None) -> bool:
        """Go to the next (``delta`` = 1) or previous (-1) ``view`` of the object, or ``object`` of the index."""
        with self._lock:
            if self.store is None or not self.objects:
                return False
            if self.shown is None:
                return self.select(self.objects[0].name, None, client)
            name, view = self.shown.info.object, self.shown.info.view
            if what == "view":
                views = [v.view for v in self.store.views(name)]
                i = views.index(view) if view in views else 0
                return self.select(name, views[(i + delta) % len(views)], client)
            names = [o.name for o in self.objects if o.views]
            if not names:
                return False
            i = names.index(name) if name in names else (-1 if delta > 0 else 0)
            return self.select(names[(i + delta) % len(names)], None, client)

    def show(self, client: viser.ClientHandle | None = None) -> None:
        """Put the dataset on screen (hides the pipeline's nodes); shows the first object if none is chosen."""
        with self._lock:
            if self.shown is None:
                first = next((o.name for o in self.objects if o.views), None)
                if first is None:
                    self.hooks.notify(client, "Nothing to show", "No object in the index has a view with results.",
                                      "yellow")
                    return
                self.select(first, None, client)
                return
            self._activate(client, self.shown.layout)

    def leave(self, client: viser.ClientHandle | None = None) -> None:
        """Back to the pipeline: hide the dataset, show the pipeline's nodes and the cameras as they were."""
        with self._lock:
            if not self.active:
                return
            self.active = False
            self._root.visible = False
            self.hooks.set_pipeline_visible(True)
            for c in self.server.get_clients().values():
                saved = self._saved_cameras.pop(c.client_id, None)
                if saved is None:
                    continue
                try:
                    with c.atomic():
                        c.camera.fov, c.camera.up_direction, c.camera.position, c.camera.look_at = saved
                except AssertionError:  # camera not reported yet
                    pass
            self.c.show.label = "Show the dataset in 3D"
            self.c.pipeline_note.visible = False

    def open_in_pipeline(self, client: viser.ClientHandle | None = None) -> bool:
        """Send the shown view's capture (its saved partial points) to the Pipeline tab."""
        with self._lock:
            if self.shown is None:
                self.hooks.notify(client, "No view", "Choose a view first.", "yellow")
                return False
            info = self.shown.info
            try:
                capture = self.store.capture(info.object, info.view)
            except Exception as e:
                self.hooks.notify(client, "Cannot open the view", f"{info.object} view {info.view}: {e}", "red")
                return False
            self.leave(client)
        ok = self.hooks.open_capture(capture, client)
        if ok:
            self.hooks.notify(client, "Opened in the Pipeline tab",
                              f"{info.object} view {info.view}: switch to the Pipeline tab and click the segment to "
                              "complete it.", "green")
        return ok

    def export_bytes(self, what: str, kind: str | None = None, mesh_format: str = "ply",
                     frame: str = "camera") -> tuple[str, bytes]:
        """``(file name, content)`` of an export of the shown view (full resolution).

        Args:
            what: ``mesh`` (``kind``: truth, points or a method), ``grasps`` (the grasps JSON of
                method ``kind``), ``view_csv`` (per-method metrics of the view), ``index_csv`` (the
                objects of the current index), ``rows_csv`` (every row of those objects' views) or
                ``tables`` (Tables I-IV, markdown).
            mesh_format: ``ply``, ``obj``, ``stl`` or ``glb`` (meshes; points are always PLY).
            frame: ``camera`` (the view's camera optical frame, as stored) or ``object`` (the
                object's frame: catalogue axes, bounding-box centre at the origin).

        Raises:
            ValueError: with a message for the user.
        """
        if self.store is None:
            raise ValueError("No results store is open.")
        if what == "index_csv":
            return "results_index.csv", self.store.objects_csv(self.objects).encode()
        if what == "rows_csv":
            names = [o.name for o in self.objects if o.views]
            return "results_rows.csv", self.store.rows_csv(names).encode()
        if what == "tables":
            return "results_tables.md", self.store.tables_markdown().encode()
        if self.shown is None:
            raise ValueError("Choose a view first.")
        info = self.shown.info
        stem = info.stem
        if what == "view_csv":
            return f"{stem}_metrics.csv", self.store.view_csv(info.object, info.view).encode()
        if what == "grasps":
            g = next((g for g in self.shown.grasps if g.method == kind and g.file), None)
            if g is None:
                raise ValueError(f"No grasps planned on {kind} for this view.")
            return f"{stem}__{kind}_grasps.json", self.store.path(g.file).read_bytes()
        if what != "mesh":
            raise ValueError(f"unknown export {what!r}")
        if kind not in KINDS:
            raise ValueError(f"unknown mesh {kind!r}; choose one of {KINDS}")
        if frame not in ("camera", "object"):
            raise ValueError(f"unknown frame {frame!r} (camera or object)")
        T = np.linalg.inv(self.store.T_cam_obj(info.object, info.view))  # object <- camera
        out_frame = "world" if frame == "object" else "camera"
        try:
            if kind == "points":
                return f"{stem}__points_{frame}.ply", export.points_ply_bytes(
                    self.store.load_points(info.object, info.view), None, out_frame, T)
            mesh = self.store.load_mesh(info.object, info.view, kind)
        except KeyError:
            raise ValueError(f"This view has no {TITLES.get(kind, kind).lower()} file.") from None
        return f"{stem}__{kind}_{frame}.{mesh_format}", export.mesh_bytes(mesh, mesh_format, out_frame, T)

    @property
    def drawn(self) -> dict[str, viser.SceneNodeHandle]:
        """The dataset's scene nodes now on the server, by name."""
        if self.shown is None:
            return {}
        out = {}
        for name in self.shown.nodes:
            h = self.server.scene.get_handle_by_name(name)
            if h is not None:
                out[name] = h
        return out

    def refresh(self) -> None:
        """Re-read the store (new views of a running evaluation) and redraw the index if it changed."""
        with self._lock:
            if self.store is None:
                return
            report = self.store.sync()
            if self._closed.is_set():  # the server stopped meanwhile: no GUI to update
                return
            generation = self.store.generation()  # also changed by other stores on the folder
            if generation != self._generation:
                self._refresh_index()
            elif report.skipped:
                self.c.status.content = self._status_text()

    def _poll(self) -> None:
        """Pick up views that a running evaluation (or the sample build) adds, every few seconds."""
        while not self._closed.wait(POLL_SECONDS):
            try:
                self.refresh()
            except Exception:  # an unreadable folder for a moment: try again next time
                log.warning("refreshing the results store failed", exc_info=True)

    # ------------------------------------------------------------------------------------------
    # Opening a store

    def _open(self, results) -> None:
        if results is None:
            self.c.status.content = ("_No results store._ Start the viewer with `--results DIR` (a folder written by "
                                     "`shapeviewer evaluate`).")
            return
        if results == DEFAULT:
            root = sample_store_dir(self.weights)
            self.store = ResultsStore(root)
            self._refresh_index()
            if not sample_store_complete(root):
                self._sample_to_build = root  # started by start_background() once the app has its CNN
            return
        root = Path(results).expanduser()
        if not root.is_dir():
            raise FileNotFoundError(f"results folder not found: {root}")
        self.store = ResultsStore(root)
        self._refresh_index()

    def start_background(self, completer) -> None:
        """Start building the sample store, if it is wanted and missing, with the app's CNN.

        Sharing the app's :class:`~shapeviewer.model.Completer` (inference only) also keeps two
        threads from loading models at once: TorchScript parses Python source, and CPython 3.11's
        ``ast.parse`` is not safe in two threads at the same time.
        """
        root, self._sample_to_build = self._sample_to_build, None
        if root is not None and not self._closed.is_set():
            threading.Thread(target=self._build_sample, args=(root, completer), name="sample-store",
                             daemon=True).start()

    def _build_sample(self, root: Path, completer) -> None:
        """Evaluate the sample views in the background; the index fills in as views finish.

        Every browser (also those connecting later) sees a progress notification until it is done.
        """
        self.building = True
        self.c.progress.visible = True
        self._build_step = "starting"

        def progress(done: int, total: int, what: str) -> None:
            if self._closed.is_set():
                raise _Stopped
            self.c.progress.value = 100.0 * done / max(total, 1)
            if what == "done":
                return
            self._build_step = f"step {done + 1} of {total}: {what}"
            self.c.status.content = f"_Building the sample results store ({self._build_step})..._  \n`{root}`"
            for note in list(self._build_notes.values()):
                note.body = self._build_note_body()
            if done:
                self.refresh()

        for client in self.server.get_clients().values():
            self._add_build_note(client)
        try:
            build_sample_store(root, weights=self.weights, progress=progress, completer=completer)
        except _Stopped:
            return
        except Exception as e:  # keep the viewer alive; say why in the tab
            log.exception("building the sample store failed")
            self.last_error = f"sample store: {e}"
            self.c.status.content = f"**Building the sample store failed:** {e}"
            return
        finally:
            self.building = False
            if not self._closed.is_set():
                self.c.progress.visible = False
                for note in list(self._build_notes.values()):
                    note.remove()
            self._build_notes.clear()
        self.refresh()
        self.c.status.content = self._status_text()

    def _build_note_body(self) -> str:
        return (f"The Dataset tab is evaluating a few sample views in the background (first run only): "
                f"{self._build_step}. Views appear in the tab as they finish.")

    def _add_build_note(self, client: viser.ClientHandle) -> None:
        if self.building and client.client_id not in self._build_notes:
            self._build_notes[client.client_id] = client.add_notification(
                "Dataset tab: building sample results", self._build_note_body(), loading=True,
                with_close_button=True)

    # ------------------------------------------------------------------------------------------
    # Index

    def _filters(self) -> dict:
        c = self.c
        rng = tuple(c.range.value) if c.limit.value else None
        return {"search": c.search.value, "split": SPLITS[c.split.value], "with_results": c.with_results.value,
                "method": c.method.value, "metric": c.metric.value, "order": ORDERS[c.order.value],
                "metric_range": rng}

    def _refresh_index(self) -> None:
        with self._lock:
            if self.store is None:
                return
            f = self._filters()
            self._generation = self.store.generation()
            self.objects = self.store.objects(**f)
            self.total_objects = len(self.store.objects(with_results=f["with_results"]))
            selected = self.shown.info.object if self.shown else None
            self.c.index.content = index_markdown(self.objects, f["method"], f["metric"], selected, self.total_objects)
            self.c.status.content = self._status_text()
            self._sync_selectors()
            self._refresh_summary()

    def _status_text(self) -> str:
        counts = self.store.counts()
        text = (f"**{counts['views']}** views of **{counts['objects']}** objects · {counts['grasps']} grasp results  \n"
                f"`{self.store.root}`")
        if not counts["views"] and not self.building:
            text += "  \nNo views yet: fill it with `shapeviewer evaluate --out DIR`."
        if counts["skipped"]:
            text += f"  \n⚠ {counts['skipped']} unreadable view file(s) skipped"
        if self.building:
            text = "_Building the sample store..._  \n" + text
        return text

    def _object_label(self, o: ObjectSummary) -> str:
        m, k = self.c.method.value, self.c.metric.value
        v = o.mean(m, k)
        return f"{o.name} · {o.views} view{'s' if o.views != 1 else ''}" + ("" if math.isnan(v) else
                                                                            f" · {SHORT[k]} {_f(v, 1 if 'mm' in k else 2)}")

    def _sync_selectors(self) -> None:
        """Fill the object and view dropdowns from the index and the shown view (no callbacks fire)."""
        self._updating = True
        try:
            labels = {self._object_label(o): o.name for o in self.objects[:500]}
            self._object_options = labels
            selected = self.shown.info.object if self.shown else None
            if selected is not None and selected not in labels.values():
                o = next((o for o in self.objects if o.name == selected), None) or self.shown.object
                labels = {self._object_label(o): selected, **labels}
                self._object_options = labels
            options = tuple(labels) or (NO_OBJECT,)
            self.c.object.options = options
            self.c.object.value = next((k for k, v in labels.items() if v == selected), options[0])
            if self.shown is not None:
                views = self.store.views(self.shown.info.object)
                self._view_options = {f"view {v.view} · {SET_TITLES.get(v.view_set, v.view_set)}": v.view for v in views}
                self.c.view.options = tuple(self._view_options)
                self.c.view.value = next(k for k, v in self._view_options.items() if v == self.shown.info.view)
            else:
                self._view_options = {}
                self.c.view.options = ("(no view)",)
        finally:
            self._updating = False

    def _refresh_summary(self) -> None:
        summary = self.store.summary()
        self.c.summary.content = summary_markdown(summary, self.store.grasp_summary())
        method, metric = self.c.method.value, self.c.metric.value
        key = (method, metric, tuple((o.name, o.views) for o in self.objects))
        if key != self._bars_key:
            self._bars_key = key
            # Drawing the chart takes most of a second: a worker draws the latest request, so that
            # typing in the search box stays quick.
            self._bars_request = (key, sorted(self.objects, key=lambda o: _sort_worst(o, method, metric)), method,
                                  metric)
            self._bars_wanted.set()

    def shutdown(self) -> None:
        """Stop the background work before the server goes away (waits for a chart or index update
        in progress; the sample build stops at its next step)."""
        self._closed.set()
        self._bars_wanted.set()
        for t in self._threads:
            t.join(timeout=10.0)

    def _bars_worker(self) -> None:
        while not self._closed.is_set():
            self._bars_wanted.wait()
            self._bars_wanted.clear()
            if self._closed.is_set():
                return
            key, objects, method, metric = self._bars_request
            try:
                png = bars_png(objects, metric)
            except Exception:  # a chart must never take the tab down
                log.exception("drawing the per-object bars failed")
                continue
            if self._bars_wanted.is_set() or self._closed.is_set():  # a newer request came in, or closing
                continue
            self._show_bars(png, method, metric)
            self.bars_drawn = key

    def _show_bars(self, png: bytes | None, method: str, metric: str) -> None:
        from PIL import Image

        if png is None:
            self.c.bars_note.content = "_No object in the index has results._"
            if self._bars_image is not None:
                self._bars_image.visible = False
            return
        image = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
        self.c.bars_note.content = (f"{METRIC_TITLES[metric]}, mean per object, worst {method} first "
                                    f"(the first 25 objects of the index).")
        if self._bars_image is None:
            with self.c.bars_folder:
                self._bars_image = self.server.gui.add_image(image, format="png")
        else:
            self._bars_image.image = image
            self._bars_image.visible = True

    # ------------------------------------------------------------------------------------------
    # Drawing a view

    def _display_mesh(self, rel: str, points: bool):
        """(vertices, faces) of a mesh file (camera frame, decimated for display), or (points, None);
        cached by path and modification time."""
        path = self.store.path(rel)
        key = (str(path), path.stat().st_mtime_ns)
        hit = self._display_cache.get(key)
        if hit is not None:
            self._display_cache.move_to_end(key)
            return hit
        if points:
            value = (read_points(path).astype(np.float32), None)
        else:
            m = decimate(read_mesh(path))
            value = (np.asarray(m.vertices, np.float32), np.asarray(m.faces, np.int32))
        self._display_cache[key] = value
        while len(self._display_cache) > DISPLAY_CACHE:
            self._display_cache.popitem(last=False)
        return value

    def _show(self, info: ViewInfo, client: viser.ClientHandle | None) -> None:
        t0 = time.perf_counter()
        name = info.object
        o = next((x for x in self.objects if x.name == name), None) or self.store.object(name)
        completions = self.store.completions(name, info.view)
        grasps = self.store.grasps(name, info.view)
        by_method = {c.method: c for c in completions}
        files = {"truth": info.truth, "points": info.points, **{m: c.mesh for m, c in by_method.items()}}
        items: dict[str, tuple] = {}
        for kind in KINDS:
            if files.get(kind):
                items[kind] = self._display_mesh(files[kind], kind == "points")
        if "truth" not in items:
            raise ValueError("the view has no ground-truth mesh file")
        kinds = tuple(k for k in KINDS if k in items or k in by_method)
        T_cam_obj = self.store.T_cam_obj(name, info.view)
        aspect = self._aspect(client)
        layout = layout_view(T_cam_obj, items["truth"][0], {k: v[0] for k, v in items.items()}, kinds, aspect)

        # Show the root before adding to it: labels added under a hidden frame stay hidden in the
        # browser when the frame is shown later (viser 1.1).
        self._activate(client)
        self._clear_view()
        nodes: list[str] = []
        scene = self.server.scene
        floor = f"{ROOT}/floor"
        width = layout.spacing * (len(kinds) + 0.4)
        scene.add_grid(floor, width=width, height=layout.spacing * 1.6, plane="xy", cell_size=0.05,
                       section_size=layout.spacing, plane_color=(236, 232, 224), plane_opacity=0.5,
                       shadow_opacity=0.0, cell_color=(215, 210, 200), section_color=(190, 185, 175))
        nodes.append(floor)
        for kind in kinds:
            T = layout.T_display_cam[kind]
            node = f"{ROOT}/{kind}"
            if kind in items:
                verts, faces = items[kind]
                pts = transform_points(T, verts).astype(np.float32)
                if faces is None:
                    # Shaded by depth from the sensor (near light, far dark): a flat colour hides the shell's shape.
                    scene.add_point_cloud(node, pts, points_colors(verts[:, 2]), point_size=POINT_SIZE,
                                          precision="float32", point_shading="flat")
                else:
                    scene.add_mesh_simple(node, pts, faces, color=COLORS[kind], cast_shadow=False,
                                          receive_shadow=False, flat_shading=False)
                nodes.append(node)
            text = TITLES[kind]
            if kind == "points":
                text += f"\n{len(items[kind][0]):,} points, seen from the frustum"
            c = by_method.get(kind)
            if c is not None:
                text += "\n" + completion_label(c)
            for g in grasps:
                if g.method == kind:
                    text += "\n" + grasp_label(g)
            label = f"{ROOT}/label_{kind}"
            scene.add_label(label, text, position=layout.columns[kind] + [0.0, 0.0, layout.top + 0.12 * layout.spacing],
                            anchor="bottom-center", font_screen_scale=0.8)
            nodes.append(label)
        if "points" in items:
            fov = 2 * math.atan2(240, 525)  # the Kinect's vertical field of view (SPEC: 640x480, f = 525 px)
            scene.add_camera_frustum(f"{ROOT}/sensor", fov=fov, aspect=640 / 480, scale=0.12 * layout.spacing,
                                     thickness=0.004 * layout.spacing, color=(60, 60, 60), wxyz=layout.sensor_wxyz,
                                     position=layout.sensor_position)
            nodes.append(f"{ROOT}/sensor")
        if self.c.show_grasps.value:
            nodes += self._draw_grasps(info, grasps, layout)
        self.shown = _Shown(o, info, completions, grasps, layout, nodes=nodes)
        self.c.details.content = view_markdown(o, info, completions, grasps)
        self._activate(client, layout)
        self.server.flush()
        self.shown.seconds = time.perf_counter() - t0
        self.c.index.content = index_markdown(self.objects, self.c.method.value, self.c.metric.value, name,
                                              self.total_objects)

    def _draw_grasps(self, info: ViewInfo, grasps: list[GraspSummary], layout: ViewLayout) -> list[str]:
        """The best planned grasp on each completion (blue) and its execution on the true object (red)."""
        from ..grasp.hands import get_hand, hand_mesh

        nodes = []
        for g in grasps:
            if not g.file or g.method not in layout.T_display_cam:
                continue
            try:
                gs = self.store.grasp_set(info.object, info.view, g.method, g.hand)
            except Exception as e:  # an unreadable grasp file: the labels still show the summary
                log.warning("grasps of %s view %d %s: %s", info.object, info.view, g.method, e)
                continue
            if gs is None or not gs.grasps:
                continue
            # Grasp files are in a "world" frame; the evaluation records its camera pose there.
            T_world_cam = np.asarray(gs.meta.get("T_world_cam", np.eye(4)), dtype=np.float64)
            T_disp_world = layout.T_display_cam[g.method] @ np.linalg.inv(T_world_cam)
            best = max(range(len(gs.grasps)), key=lambda i: gs.grasps[i].epsilon)
            hand = get_hand(gs.grasps[best].hand)
            states = [("planned", gs.grasps[best], PLANNED_HAND)]
            if gs.executions[best] is not None:
                states.append(("executed", gs.executions[best], EXECUTED_HAND))
            for tag, state, (color, opacity) in states:
                mesh = hand_mesh(hand, [state.joints[n] for n in hand.joint_names])
                T = T_disp_world @ np.asarray(state.T_world_palm)
                node = f"{ROOT}/grasp_{g.method}_{tag}"
                self.server.scene.add_mesh_simple(node, transform_points(T, mesh.vertices).astype(np.float32),
                                                  np.asarray(mesh.faces, np.int32), color=color, opacity=opacity,
                                                  cast_shadow=False, receive_shadow=False)
                nodes.append(node)
        return nodes

    def _clear_view(self) -> None:
        if self.shown is None:
            return
        for name in self.shown.nodes:
            h = self.server.scene.get_handle_by_name(name)
            if h is not None:
                h.remove()
        self.shown.nodes = []

    def _aspect(self, client: viser.ClientHandle | None) -> float:
        for c in ([client] if client is not None else list(self.server.get_clients().values())):
            try:
                return float(c.camera.aspect)
            except (AssertionError, AttributeError):
                continue
        return 1.3

    def _activate(self, client: viser.ClientHandle | None, layout: ViewLayout | None = None) -> None:
        """Show the dataset root (hiding the pipeline) and point every browser camera at ``layout``'s row."""
        if not self.active:
            self.active = True
            self.hooks.set_pipeline_visible(False)
            self._root.visible = True
            self.c.show.label = "Back to the pipeline scene"
            self.c.pipeline_note.visible = True
        if layout is None:
            return
        for c in self.server.get_clients().values():
            try:
                with c.atomic():
                    if c.client_id not in self._saved_cameras:
                        cam = c.camera
                        self._saved_cameras[c.client_id] = (cam.fov, tuple(cam.up_direction), tuple(cam.position),
                                                            tuple(cam.look_at))
                    c.camera.fov = DATASET_FOV
                    c.camera.up_direction = (0.0, 0.0, 1.0)
                    c.camera.position = layout.camera_position
                    c.camera.look_at = layout.look_at
            except AssertionError:  # the client has not reported its camera yet
                pass

    # ------------------------------------------------------------------------------------------
    # Controls

    def _build_controls(self, tab, pipeline_tab) -> _Controls:
        gui = self.server.gui
        with pipeline_tab:
            # Shown at the top of the Pipeline tab while the dataset is in the 3D view.
            pipeline_note = gui.add_button("Back to the pipeline scene",
                                           icon=viser.Icon.ARROW_BACK_UP, visible=False, order=-1.0, color="orange")
        with tab:
            gui.add_markdown("Browse the evaluation results: each object's views, the ground truth, the partial "
                             "view and every method's completion side by side (paper Fig. 1).")
            status = gui.add_markdown("_Opening the results store..._")
            progress = gui.add_progress_bar(0.0, visible=False, animated=True)
            show = gui.add_button("Show the dataset in 3D", icon=viser.Icon.EYE)
            with gui.add_folder("Find an object"):
                search = gui.add_text("Search", "", hint="Part of an object's name, e.g. mug or ycb/0")
                split = gui.add_dropdown("Split", tuple(SPLITS), hint="The object's split (SPEC §4)")
                with_results = gui.add_checkbox("Only with results", True,
                                                hint="Hide catalogue objects that have no evaluated view")
                method = gui.add_dropdown("Method", METHODS, initial_value="Ours-fast",
                                          hint="Whose mean metric orders and filters the index")
                metric = gui.add_dropdown("Metric", ("jaccard", "hausdorff_mean_mm", "geodesic"))
                order = gui.add_dropdown("Order", tuple(ORDERS), hint="Worst first: lowest Jaccard, largest distances")
                limit = gui.add_checkbox("Metric range", False, hint="Keep objects whose mean lies in the range below")
                lo, hi, st = SLIDER["jaccard"]
                rng = gui.add_multi_slider("Range", lo, hi, st, (lo, hi), disabled=True)
                index = gui.add_markdown("")
                obj = gui.add_dropdown("Object", (NO_OBJECT,), hint="Choose an object to show its first view")
            with gui.add_folder("View"):
                view = gui.add_dropdown("View", ("(no view)",))
                step = gui.add_button_group("Step", ("◀ object", "◀ view", "view ▶", "object ▶"),
                                            hint="Keys: N / P next / previous view, Shift+N / Shift+P object")
                details = gui.add_markdown("_Choose an object._")
                # Off by default: a hand is as large as the object and hides the shapes being compared.
                show_grasps = gui.add_checkbox("Show best grasp", False,
                                               hint="Hands of each completion's best planned grasp (blue) and of its "
                                                    "execution on the true object (red)")
                open_pipeline = gui.add_button("Open in pipeline", icon=viser.Icon.PLAYER_PLAY,
                                               hint="Send this view's partial points to the Pipeline tab to complete "
                                                    "and grasp them yourself")
            with gui.add_folder("Export"):
                export_kind = gui.add_dropdown("Mesh", KINDS, initial_value="Ours-fast")
                export_format = gui.add_dropdown("Format", export.MESH_FORMATS)
                export_frame = gui.add_dropdown("Frame", ("camera", "object"),
                                                hint="camera: the view's optical frame (as stored); object: the "
                                                     "object's own frame")
                export_mesh = gui.add_button("Mesh (full resolution)", icon=viser.Icon.DOWNLOAD)
                export_grasps = gui.add_button("Grasps of this method (JSON)", icon=viser.Icon.DOWNLOAD)
                export_view_csv = gui.add_button("View metrics (CSV)", icon=viser.Icon.DOWNLOAD)
                export_index_csv = gui.add_button("Index (CSV)", icon=viser.Icon.DOWNLOAD,
                                                  hint="The objects of the index: split, source, size, views, "
                                                       "mean metrics of every method")
                export_rows_csv = gui.add_button("Metrics of the index's views (CSV)", icon=viser.Icon.DOWNLOAD,
                                                 hint="Every view of the objects in the index, all methods")
                export_tables = gui.add_button("Tables I-IV (markdown)", icon=viser.Icon.DOWNLOAD)
            with gui.add_folder("Summary", expand_by_default=False):
                summary = gui.add_markdown("")
            with gui.add_folder("Per-object bars", expand_by_default=False) as bars_folder:
                bars_note = gui.add_markdown("_Drawing..._")
        return _Controls(status, progress, show, search, split, with_results, method, metric, order, limit, rng, index,
                         obj, view, step, details, show_grasps, open_pipeline, export_kind, export_format,
                         export_frame, export_mesh, export_grasps, export_view_csv, export_index_csv, export_rows_csv,
                         export_tables,
                         summary, bars_folder, bars_note, pipeline_note)

    def _wire(self) -> None:
        c = self.c
        for h in (c.search, c.split, c.with_results, c.method, c.order):
            h.on_update(lambda _e: self._refresh_index())

        @c.metric.on_update
        def _(_e) -> None:
            lo, hi, st = SLIDER[c.metric.value]
            with self._lock:
                self._updating = True
                try:
                    c.range.min, c.range.max, c.range.step = lo, hi, st
                    c.range.value = (lo, hi)
                finally:
                    self._updating = False
            self._refresh_index()

        @c.limit.on_update
        def _(_e) -> None:
            c.range.disabled = not c.limit.value
            self._refresh_index()

        @c.range.on_update
        def _(_e) -> None:
            if not self._updating and c.limit.value:
                self._refresh_index()

        @c.object.on_update
        def _(event: viser.GuiEvent) -> None:
            if self._updating or event.client is None:
                return
            name = getattr(self, "_object_options", {}).get(c.object.value)
            if name and (self.shown is None or self.shown.info.object != name):
                self.select(name, None, event.client)

        @c.view.on_update
        def _(event: viser.GuiEvent) -> None:
            if self._updating or event.client is None or self.shown is None:
                return
            v = getattr(self, "_view_options", {}).get(c.view.value)
            if v is not None and v != self.shown.info.view:
                self.select(self.shown.info.object, v, event.client)

        steps = {"◀ object": ("object", -1), "◀ view": ("view", -1), "view ▶": ("view", 1), "object ▶": ("object", 1)}
        c.step.on_click(lambda event: self.step(*steps[c.step.value], event.client))

        @c.show.on_click
        def _(event: viser.GuiEvent) -> None:
            if self.active:
                self.leave(event.client)
            else:
                self.show(event.client)

        c.pipeline_note.on_click(lambda event: self.leave(event.client))
        c.open_pipeline.on_click(lambda event: self.open_in_pipeline(event.client))

        @c.show_grasps.on_update
        def _(event: viser.GuiEvent) -> None:
            if self.shown is not None:
                self.select(self.shown.info.object, self.shown.info.view, event.client)

        downloads = ((c.export_mesh, "mesh"), (c.export_grasps, "grasps"), (c.export_view_csv, "view_csv"),
                     (c.export_index_csv, "index_csv"), (c.export_rows_csv, "rows_csv"), (c.export_tables, "tables"))
        for button, what in downloads:
            button.on_click(lambda event, what=what: self._download(event.client, what))

        gui = self.server.gui
        for label, key, mod, what, delta in (("Next view", "N", None, "view", 1), ("Previous view", "P", None, "view", -1),
                                             ("Next object", "N", "shift", "object", 1),
                                             ("Previous object", "P", "shift", "object", -1)):
            cmd = gui.add_command(f"Dataset: {label.lower()}", hotkey=key, modifier=mod, icon=viser.Icon.DATABASE)
            cmd.on_trigger(lambda event, what=what, delta=delta: self.step(what, delta, event.client))

    def _download(self, client: viser.ClientHandle | None, what: str) -> None:
        try:
            name, data = self.export_bytes(what, self.c.export_kind.value, self.c.export_format.value,
                                           self.c.export_frame.value)
        except (ValueError, OSError) as e:
            self.hooks.notify(client, "Nothing to export", str(e), "red")
            return
        if client is not None:
            client.send_file_download(name, data, save_immediately=True)


class _Stopped(Exception):
    """Raised in the sample build's progress callback when the viewer stops."""


def _sort_worst(o: ObjectSummary, method: str, metric: str) -> tuple:
    v = o.mean(method, metric)
    if math.isnan(v):
        return (1, 0.0, o.name)
    return (0, v if HIGHER_IS_BETTER[metric] else -v, o.name)
