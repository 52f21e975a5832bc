"""What the Dataset tab says and plots: labels, markdown tables and the per-object bars.

Plain values in (records of :mod:`shapeviewer.evaluation.results`), markdown or PNG bytes out; no
viser, so tests can call every function without a server. Distances are millimetres where a name
says ``mm``, sizes centimetres in the tables (the records keep metres).

Names that come from the store's files (objects, sources, error messages) are escaped
(:func:`~shapeviewer.viewer.sources.markdown_text`): they show as written and never as markup.
viser draws a markdown table's cells without padding, so each table sits in a block styled by
:data:`TABLE_STYLE` (:func:`table_block`): padded cells, figures kept on one line, long object
names wrapped, the table scrolling sideways rather than cut off in a narrow panel.
"""

from __future__ import annotations

import io
import math

import numpy as np

from ...evaluation.methods import GRASP_TABLE_METHODS, METHOD_INFO, METHODS, Method
from ...evaluation.paper import paper_figure, paper_grasp
from ...evaluation.records import HIGHER_IS_BETTER, METRIC_TITLES, Metric
from ...evaluation.summaries import CompletionResult, GraspSummary, ObjectSummary, ViewInfo
from ...evaluation.tables import fmt, fmt_share
from ...evaluation.viewsets import SET_TITLES, VIEW_SETS, ViewSet
from ..sources import markdown_text

# A column's title: the truth, the partial view, each method's (:data:`~shapeviewer.evaluation.methods.METHOD_INFO`).
TITLES: dict[str, str] = {
    "truth": "Ground truth",
    "points": "Partial view",
    **{m: info.title for m, info in METHOD_INFO.items()},
}
# Partial and Mirror keep the pipeline tab's baseline colours; ours are warm, the truth neutral.
COLORS: dict[str, tuple[int, int, int]] = {
    "truth": (150, 175, 150),
    "points": (40, 110, 220),
    "Partial": (160, 160, 160),
    "Mirror": (110, 150, 215),
    "Hull": (150, 120, 190),
    "Ours-fast": (240, 150, 60),
    "Ours-detailed": (205, 95, 45),
}
# The shape priors a completion row may record (pipeline.Completion.prior): its label's word, and
# the view panel's phrase.
PRIORS = {
    "box": ("fitted box", "the box fitted to the points"),
    "revolution": ("revolved", "revolved about the table's normal"),
}
# The look of the tables (class :data:`TABLE_CLASS`): viser's markdown puts a table's cells in bare
# <td>s, without padding, so "1.9 | 100%" would read "1.9100%". Sizes in CSS px.
# Figures stay on one line; a row's first cell may wrap between words ("table h." / "model"), an
# object's name (class NAMES_CLASS) anywhere; a folder path (class PATH_CLASS) wraps too.
TABLE_CLASS = "sv-table"
NAMES_CLASS = "sv-names"
COMPACT_CLASS = "sv-compact"  # the summary's tables of seven columns
PATH_CLASS = "sv-path"
TABLE_STYLE = (
    "<style>"
    f".{TABLE_CLASS}{{overflow-x:auto;max-width:100%;margin:0.25em 0 0.5em}}"
    f".{TABLE_CLASS} table{{border-collapse:collapse;font-size:12px;line-height:1.35}}"
    f".{TABLE_CLASS} th,.{TABLE_CLASS} td{{padding:2px 4px;white-space:nowrap;vertical-align:top}}"
    f".{TABLE_CLASS} th{{font-weight:600;text-align:left;border-bottom:1px solid rgba(128,128,128,0.45)}}"
    f".{TABLE_CLASS} td:first-child,.{TABLE_CLASS} th:first-child{{padding-left:0}}"
    f".{TABLE_CLASS} td:first-child{{white-space:normal}}"
    f".{NAMES_CLASS} td:first-child{{overflow-wrap:anywhere}}"
    f".{COMPACT_CLASS} table{{font-size:11px}}"
    f".{COMPACT_CLASS} th,.{COMPACT_CLASS} td{{padding:2px 3px}}"
    f".{TABLE_CLASS} tr:nth-child(even) td{{background:rgba(128,128,128,0.08)}}"
    f"code.{PATH_CLASS}{{white-space:normal;overflow-wrap:anywhere}}"
    "</style>"
)
INDEX_ROWS = 12  # rows of the index table in the panel
BARS_OBJECTS = 25  # objects in the per-object chart
# Short column titles for the narrow panel.
SHORT: dict[str, str] = {
    **{m: info.short for m, info in METHOD_INFO.items()},
    "jaccard": "J",
    "hausdorff_mean_mm": "H mm",
    "geodesic": "G",
}
SHORT_SET: dict[ViewSet, str] = {
    "training_view": "train",
    "holdout_view": "h. view",
    "holdout_model": "h. model",
    "tabletop_train_object": "table",
    "tabletop_holdout_model": "table h. model",
}


def table_block(rows: list[str], names: bool = False, compact: bool = False) -> list[str]:
    """Markdown lines of a table (``rows``: its header, alignment and body lines) in a block of
    class :data:`TABLE_CLASS` (and :data:`NAMES_CLASS` when its first column holds object names,
    :data:`COMPACT_CLASS` for a smaller type), blank lines around it (markdown inside an HTML
    block needs them)."""
    classes = " ".join([TABLE_CLASS, *([NAMES_CLASS] if names else []), *([COMPACT_CLASS] if compact else [])])
    return ["", f'<div class="{classes}">', "", *rows, "", "</div>", ""]


def path_markdown(path: str) -> str:
    """A folder path in code style that wraps in the narrow panel (literal: escaped)."""
    return f'<code class="{PATH_CLASS}">{markdown_text(path)}</code>'


def panel_figure(v: float | None, metric: str) -> str:
    """A mean in the side panel's tables: distances (mm) to 0.1, ratios to 0.01 (the downloaded
    tables keep 0.001)."""
    return fmt(v, 1 if metric.startswith("hausdorff") else 2)


def styled(lines: list[str]) -> str:
    """``lines`` joined into one markdown text, after the tables' style."""
    return "\n".join([TABLE_STYLE, "", *lines])


# Labels sit above their column, which is about 25 characters wide on a laptop screen: short lines.
def completion_label(c: CompletionResult) -> str:
    """A completion's label lines: Jaccard and geodesic divergence, then the mean Hausdorff (mm), and
    the shape prior the pipeline applied, if any."""
    if not c.ok:
        return "failed:\n" + c.error[:24]
    prior = f"\n{PRIORS[c.prior][0]}" if c.prior in PRIORS else ""
    return f"J {fmt(c.jaccard, 2)} · G {fmt(c.geodesic, 2)}\nH {fmt(c.hausdorff_mean_mm, 1)} mm{prior}"


def grasp_label(g: GraspSummary) -> str:
    """A grasp summary's label lines: planned vs executed joint (deg) and pose (mm) errors, lift successes."""
    if g.error:
        return "grasps failed"
    lifted = (
        f"lifted {round(g.lift_success * g.n)}/{g.n}"
        if g.n and 0 <= g.lift_success <= 1
        else f"lift {fmt_share(g.lift_success, 0)}"
    )
    return f"grasp {fmt(g.joint_error_deg, 1)}° · {fmt(g.pose_error_mm, 1)} mm\n{lifted}"


def column_label(kind: str, n_points: int, completion: CompletionResult | None, grasps: list[GraspSummary]) -> str:
    """The label above an item's column: its title, then (as they apply) the number of partial-view
    points, the completion's metrics and the grasps planned on it."""
    text = TITLES[kind]
    if kind == "points":
        text += f"\n{n_points:,} points, seen from the frustum"
    if completion is not None:
        text += "\n" + completion_label(completion)
    for g in grasps:
        if g.method == kind:
            text += "\n" + grasp_label(g)
    return text


def object_label(o: ObjectSummary, method: Method, metric: Metric) -> str:
    """An object's entry in the Object dropdown: name, number of views, ``method``'s mean ``metric``."""
    v = o.mean(method, metric)
    return f"{o.name} · {o.views} view{'s' if o.views != 1 else ''}" + (
        "" if math.isnan(v) else f" · {SHORT[metric]} {fmt(v, 1 if 'mm' in metric else 2)}"
    )


def view_label(info: ViewInfo) -> str:
    """A view's entry in the View dropdown: its number and evaluation set."""
    return f"view {info.view} · {SET_TITLES.get(info.view_set, info.view_set)}"


def status_markdown(counts: dict[str, int], root: str, building: bool) -> str:
    """The tab's status line: what the store at ``root`` holds (``ResultsStore.counts``), unreadable
    files, and whether the sample store is being built."""
    text = (
        f"**{counts['views']}** views of **{counts['objects']}** objects · {counts['grasps']} grasp results  \n"
        + path_markdown(root)
    )
    if not counts["views"] and not building:
        text += "  \nNo views yet: fill it with `shapeviewer evaluate --out DIR`."
    if counts["skipped"]:
        text += f"  \n⚠ {counts['skipped']} unreadable view file(s) skipped"
    if building:
        text = "_Building the sample store..._  \n" + text
    return styled([text])


def worst_first(objects: list[ObjectSummary], method: Method, metric: Metric) -> list[ObjectSummary]:
    """``objects`` ordered by ``method``'s mean ``metric``, worst first; objects without it last."""

    def key(o: ObjectSummary) -> tuple:
        v = o.mean(method, metric)
        if math.isnan(v):
            return (1, 0.0, o.name)
        return (0, v if HIGHER_IS_BETTER[metric] else -v, o.name)

    return sorted(objects, key=key)


def index_markdown(
    objects: list[ObjectSummary], method: Method, metric: Metric, selected: str | None, total: int
) -> str:
    """The first rows of the filtered index as a markdown table (the selected object in bold,
    holdout models in italics: four columns fit the side panel)."""
    if not objects:
        return "_No object matches._"
    head = (
        f"{len(objects)} of {total} objects · means of **{method}** · cm: longest side · n: views · "
        "_italics_: holdout model"
    )
    rows = [f"| object | cm | n | {SHORT.get(metric, metric[:4])} |", "|---|---:|---:|---:|"]
    for o in objects[:INDEX_ROWS]:
        name = markdown_text(o.name)
        name = f"*{name}*" if o.split == "holdout_model" else name
        name = f"**{name}**" if o.name == selected else name
        size = "?" if any(math.isnan(x) for x in o.extents) else f"{100 * max(o.extents):.0f}"
        rows.append(f"| {name} | {size} | {o.views} | {fmt(o.mean(method, metric), 1 if 'mm' in metric else 2)} |")
    if len(objects) > INDEX_ROWS:
        rows.append(f"| _… {len(objects) - INDEX_ROWS} more_ | | | |")
    return styled([head, *table_block(rows, names=True)])


def view_markdown(
    o: ObjectSummary, info: ViewInfo, completions: list[CompletionResult], grasps: list[GraspSummary]
) -> str:
    """The chosen view's object facts, per-method metrics table and grasp table."""
    size = " × ".join(f"{100 * x:.1f}" for x in o.extents) if not any(math.isnan(x) for x in o.extents) else "?"
    view_set = markdown_text(SET_TITLES.get(info.view_set, info.view_set))
    lines = [
        f"**{markdown_text(o.name)}** · view {info.view} · {view_set}  \n"
        f"{markdown_text(o.source)} · {'holdout model' if o.split == 'holdout_model' else 'training model'} · "
        f"{size} cm",
    ]
    rows = ["| method | J ↑ | H mm ↓ | G ↓ | s |", "|---|---:|---:|---:|---:|"]
    for c in completions:
        if c.ok:
            rows.append(
                f"| {markdown_text(c.method)} | {fmt(c.jaccard, 3)} | {fmt(c.hausdorff_mean_mm, 1)} | "
                f"{fmt(c.geodesic, 3)} | {fmt(c.seconds, 2)} |"
            )
        else:
            rows.append(f"| {markdown_text(c.method)} | failed | | | |")
    lines += table_block(rows)
    failed = [f"{markdown_text(c.method)}: {markdown_text(c.error)}" for c in completions if not c.ok]
    if failed:
        lines += [*(f"_{e}_  " for e in failed)]
    priors = sorted({c.prior for c in completions if c.ok and c.prior})
    if priors:
        what = "; ".join(PRIORS[p][1] if p in PRIORS else markdown_text(p) for p in priors)
        lines += ["", f"Ours: {what} (a shape prior of the pipeline)"]
    if grasps:
        hands = sorted({g.hand for g in grasps})
        lines += [
            "",
            f"**Grasps** ({markdown_text(', '.join(hands))}): planned on the completion, executed on the truth; "
            "errors planned vs executed, share lifted",
        ]
        rows = ["| on | n | joint° | mm | lift |", "|---|---:|---:|---:|---:|"]
        for g in grasps:
            on = markdown_text(SHORT.get(g.method, g.method) + (f" ({g.hand})" if len(hands) > 1 else ""))
            if g.error:
                rows.append(f"| {on} | failed | | | |")
            else:
                rows.append(
                    f"| {on} | {g.n} | {fmt(g.joint_error_deg, 1)} | {fmt(g.pose_error_mm, 1)} | "
                    f"{fmt_share(g.lift_success, 0)} |"
                )
        lines += table_block(rows)
    else:
        lines += ["", "_No grasp results for this view._"]
    return styled(lines)


def bars_png(
    objects: list[ObjectSummary],
    metric: Metric,
    methods: tuple[Method, ...] = METHODS,
    limit: int = BARS_OBJECTS,
    width_px: int = 420,
) -> bytes | None:
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
        ax.barh(
            y + (k - (n - 1) / 2) * h,
            [0 if math.isnan(v) else v for v in vals],
            height=h,
            color=np.asarray(COLORS[m]) / 255,
            label=m,
        )
    ax.set_yticks(y, [o.name for o in rows], fontsize=9)
    ax.invert_yaxis()
    ax.set_xlabel(
        METRIC_TITLES[metric] + (", higher is better" if HIGHER_IS_BETTER[metric] else ", lower is better"), fontsize=9
    )
    ax.tick_params(axis="x", labelsize=8)
    ax.legend(fontsize=8, ncols=2, loc="lower left", bbox_to_anchor=(0.0, 1.0), frameon=False)
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout(pad=0.4)
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


def bars_caption(method: Method, metric: Metric) -> str:
    """The line above the per-object bars."""
    return (
        f"{METRIC_TITLES[metric]}, mean per object, worst {method} first "
        f"(the first {BARS_OBJECTS} objects of the index)."
    )


def panel_markdown(summary: dict, grasps: dict) -> str:
    """Per-set means (paper Tables I–III, and IV when grasps exist), compact enough for a side panel.

    ``summary``: :func:`~shapeviewer.evaluation.tables.summarize`'s format; ``grasps``:
    :meth:`ResultsStore.grasp_summary`'s (``{view_set: {method: {"joint_error_deg",
    "pose_error_mm", "lift_success", ...}}}``, means over views). The "paper" column is the paper's
    "Ours" (theirs, on their data).
    """
    counts = {s: max(summary[s][m]["n"] + summary[s][m]["failed"] for m in METHODS) for s in VIEW_SETS if s in summary}
    sets = [s for s, n in counts.items() if n]
    out = [
        "Views per set: "
        + ", ".join(f"{SET_TITLES[s]} ({SHORT_SET[s]}) {counts[s]}" for s in sets)
        + ". Means over the views where the method succeeded.",
        "",
    ]
    for number, metric, title in (
        ("I", "jaccard", "Jaccard ↑"),
        ("II", "hausdorff_mean_mm", "Hausdorff mean, mm ↓"),
        ("III", "geodesic", "Geodesic divergence ↓"),
    ):
        rows = [
            "| set | " + " | ".join(SHORT[m] for m in METHODS) + " | paper |",
            "|---|" + "---:|" * (len(METHODS) + 1),
        ]
        for s in sets:
            cells = [panel_figure(summary[s][m][metric] if summary[s][m]["n"] else None, metric) for m in METHODS]
            rows.append(
                f"| {SHORT_SET[s]} | "
                + " | ".join(cells)
                + f" | {panel_figure(paper_figure(metric, s, 'Ours-detailed'), metric)} |"
            )
        out += [f"**Table {number}: {title}**", *table_block(rows, compact=True)]
    if not grasps:
        out.append("_Table IV: no grasp results in this store._")
        return styled(out)
    out += [
        "**Table IV: grasps**, planned on the completion, executed on the truth: joint and pose "
        "errors (mean), share lifted; paper: joint ° / pose mm",
    ]
    rows = ["| method | joint ° | pose mm | lift | paper |", "|---|---:|---:|---:|---:|"]
    for s in VIEW_SETS:
        set_rows = []
        for m in GRASP_TABLE_METHODS:
            c = grasps.get(s, {}).get(m)
            if not c:
                continue
            joint, pose = paper_grasp("joint_error_deg", s, m), paper_grasp("pose_error_mm", s, m)
            paper = "–" if math.isnan(joint) else f"{fmt(joint, 1)} / {fmt(pose, 0)}"
            set_rows.append(
                f"| {SHORT[m]} | {fmt(c['joint_error_deg'], 1)} | {fmt(c['pose_error_mm'], 1)} | "
                f"{fmt_share(c['lift_success'], 0)} | {paper} |"
            )
        if set_rows:
            rows += [f"| _{SHORT_SET[s]}_ | | | | |", *set_rows]
    out += table_block(rows, compact=True)
    return styled(out)
