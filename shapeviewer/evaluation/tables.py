"""The paper's tables: our summaries of a results folder, and their renderings beside the paper's
figures (:mod:`.paper`).

* Summaries: :func:`summarize` (completion rows -> means per view set and method) and
  :func:`summarize_grasps` (grasp entries and rows -> Tables IV/V cells).
* Renderings: Tables I-III (:func:`completion_tables_markdown`), per shape kind
  (:func:`kind_table_markdown`), Tables IV/V (:func:`grasp_tables_markdown`) and Table V per shape
  kind (:func:`kind_grasp_table_markdown`), every cell as CSV (:func:`write_tables_csv`) and the
  results store's CSV exports (:func:`view_csv`, :func:`objects_csv`). The Dataset tab's compact
  panel is :func:`shapeviewer.viewer.dataset.summary.panel_markdown`.

Units: Hausdorff distances and pose errors in mm, joint errors in degrees, times in seconds,
shares (lift success, force closure) as fractions, shown as percentages.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from ..fileio import atomic_write
from .methods import GRASP_TABLE_METHODS, METHODS
from .paper import PAPER, PAPER_GRASP, PAPER_METHODS, paper_figure, paper_grasp, paper_lift
from .records import GRASP_FIELDS, GRASP_MEANS, METRICS, CompletionRow, Metric
from .viewsets import SET_TITLES, VIEW_SETS

TABLES: tuple[tuple[str, Metric, str], ...] = (
    ("I", "jaccard", "Jaccard similarity (higher is better)"),
    ("II", "hausdorff_mean_mm", "Hausdorff distance, mean, mm (lower is better)"),
    ("III", "geodesic", "Geodesic divergence (lower is better)"),
    ("J80", "j80", "Jaccard of the solids sampled at 80^3 points, J80 (higher is better)"),
)


def robust_label(method: str) -> str:
    """Table V's column of a method's grasps ranked by robustness (:mod:`grasp.robust`); the paper
    has no such column, so :data:`PAPER_COLUMN` maps none."""
    return f"{method} (robust)"


# ----------------------------------------------------------------------------------------------
# Formatting


def fmt(v, digits: int = 3, scale: float = 1.0, suffix: str = "") -> str:
    """``scale * v`` with ``digits`` decimals and ``suffix``; "–" for a missing value (None, NaN)."""
    if v is None or math.isnan(v):
        return "–"
    return f"{scale * v:.{digits}f}{suffix}"


def fmt_metric(v, metric: str) -> str:
    """A completion metric: distances (mm) to 0.1, ratios to 0.001."""
    return fmt(v, 1 if metric.startswith("hausdorff") else 3)


def fmt_share(v, digits: int = 1) -> str:
    """A fraction as a percentage."""
    return fmt(v, digits, 100.0, "%")


def csv_text(fields: tuple[str, ...], rows: Iterable[dict]) -> str:
    """Rows as CSV text with a header of ``fields`` (other keys ignored, missing ones blank)."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=fields, extrasaction="ignore")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


# ----------------------------------------------------------------------------------------------
# Summaries


def nanmean(values) -> float:
    """Mean of the values that are not NaN (NaN when none are)."""
    vals = [float(v) for v in values if not math.isnan(float(v))]
    return float(np.mean(vals)) if vals else math.nan


def summarize(rows: Sequence[CompletionRow]) -> dict:
    """``{view_set: {method: {metric: mean, "seconds": mean, "n": ok rows, "failed": rows}}}``:
    means over the completion rows without error (NaN where none)."""
    out: dict = {}
    for s in VIEW_SETS:
        out[s] = {}
        for m in METHODS:
            sel = [r for r in rows if r.view_set == s and r.method == m]
            ok = [r for r in sel if r.ok]
            cell = {k: (float(np.mean([getattr(r, k) for r in ok])) if ok else math.nan) for k in (*METRICS, "seconds")}
            cell.update(n=len(ok), failed=len(sel) - len(ok))
            out[s][m] = cell
    return out


def best_grasp_lifts(rows: list[dict], rank: str = "rank") -> dict[tuple[str, int, str, str], float]:
    """``{(object, view, method, hand): lift success}`` of each view's best grasp by ``rank``
    (``"rank"``: the planner's order; ``"robust_rank"``: by robustness), from grasp rows
    (:func:`records.load_grasp_rows`). A view without grasps, or never ranked so, has no key."""
    return {(r["object"], int(r["view"]), r["method"], r["hand"]): r["lift_success"] for r in rows if r[rank] == 0}


def summarize_grasps(records: list[dict], rows: list[dict]) -> dict:
    """``{hand: {view_set or "all": {method: cell}}}`` over every grasp entry of the records.

    ``records``: dicts with ``object``, ``view``, ``view_set`` and ``grasps`` (entries with
    ``method``, ``hand``, ``n``, ``seconds_plan``, ``error``); ``rows``: their grasps
    (:func:`records.load_grasp_rows`). A cell pools the grasps of its views: ``GRASP_MEANS`` means
    over grasps planned on the completion (not the wider search's, rows with ``wider`` 1), medians
    of the joint and pose errors (``joint_error_deg_median``, ``pose_error_mm_median``), ``grasps``
    (their number), ``lift_success_best`` (mean over views of
    the lift of the planner's top grasp, rank 0, 0 for a view without grasps),
    ``lift_success_best_robust`` (the same for the grasp ranked first by robustness, robust rank 0,
    which may come from the wider search; NaN when no grasp of the cell was ranked by robustness), ``views`` (entries
    without error), ``no_grasp`` (of those, views where the planner found none), ``failed``
    (entries with an error) and ``seconds_plan`` (mean per view).
    """
    best, best_robust = (best_grasp_lifts(rows, rank) for rank in ("rank", "robust_rank"))
    hands = sorted({g["hand"] for rec in records for g in rec.get("grasps", [])})
    out: dict = {}
    for hand in hands:
        out[hand] = {}
        for s in (*VIEW_SETS, "all"):
            out[hand][s] = {}
            for m in GRASP_TABLE_METHODS:
                entries = [
                    (rec, g)
                    for rec in records
                    if s in ("all", rec["view_set"])
                    for g in rec["grasps"]
                    if g["hand"] == hand and g["method"] == m
                ]
                if not entries:
                    continue
                ok = [(rec, g) for rec, g in entries if not g["error"]]
                pooled = [r for r in rows if r["hand"] == hand and r["method"] == m and s in ("all", r["view_set"])]
                # The means are over the grasps planned on the completion; the wider search's
                # grasps (on the grasp envelope) only compete for the robust pick.
                sel = [r for r in pooled if not r.get("wider")]
                cell = {
                    k: nanmean(r[k] for r in sel)
                    if k not in ("force_closure_planned", "force_closure_executed")
                    else nanmean(float(r[k.replace("force_closure", "epsilon")] > 0) for r in sel)
                    for k in GRASP_MEANS
                }
                # Medians too: a few grasps whose fingers meet the true object far ahead of the
                # completion stop 50-150 mm early and dominate the means.
                for k in ("joint_error_deg", "pose_error_mm"):
                    vals = [r[k] for r in sel if not math.isnan(r[k])]
                    cell[f"{k}_median"] = float(np.median(vals)) if vals else math.nan
                cell.update(
                    grasps=len(sel),
                    views=len(ok),
                    failed=len(entries) - len(ok),
                    no_grasp=sum(1 for _, g in ok if g["n"] == 0),
                    # A view without grasps counts as a failed lift: a robot had nothing to try.
                    lift_success_best=nanmean(
                        best.get((rec["object"], int(rec["view"]), m, hand), 0.0) for rec, _ in ok
                    ),
                    lift_success_best_robust=nanmean(
                        best_robust.get((rec["object"], int(rec["view"]), m, hand), 0.0) for rec, _ in ok
                    )
                    if any(r["robust_rank"] == 0 for r in pooled)
                    else math.nan,
                    seconds_plan=nanmean(g["seconds_plan"] for _, g in ok),
                )
                out[hand][s][m] = cell
    return out


# ----------------------------------------------------------------------------------------------
# Markdown


def _header(columns: list[str]) -> list[str]:
    return ["| " + " | ".join(columns) + " |", "|---" * len(columns) + "|"]


def completion_tables_markdown(summary: dict, n_per_set: int | None = None, seed: int | None = None) -> str:
    """Tables I-III (and J80) per view set, our methods beside the paper's figures, and the mean
    completion time. ``summary``: :func:`summarize`; ``n_per_set`` and ``seed`` describe the run."""
    lines = ["# Completion results (paper Tables I–III)", ""]
    if n_per_set is not None:
        lines += [
            f"{n_per_set} views per set, seed {seed}. Our means, then the paper's figures (theirs, on their "
            'data; the paper has one "Ours"). Means over views where the method succeeded; '
            "n = successes/views.",
            "",
        ]
    sets = [s for s in VIEW_SETS if any(summary[s][m]["n"] + summary[s][m]["failed"] for m in METHODS)]
    for number, metric, title in TABLES:
        lines += [
            f"## Table {number}: {title}",
            "",
            *_header(["View set", *METHODS, "paper Partial", "paper Mirror", "paper Ours"]),
        ]
        for s in sets:
            cells = [
                f"{fmt_metric(summary[s][m][metric], metric)} (n={summary[s][m]['n']}/"
                f"{summary[s][m]['n'] + summary[s][m]['failed']})"
                for m in METHODS
            ]
            paper = [fmt_metric(paper_figure(metric, s, m), metric) for m in PAPER_METHODS]
            lines.append(f"| {SET_TITLES[s]} | " + " | ".join(cells + paper) + " |")
        lines.append("")
    lines += ["## Mean completion time, seconds (all view sets)", "", *_header(list(METHODS))]
    times = []
    for m in METHODS:
        vals = [(summary[s][m]["seconds"], summary[s][m]["n"]) for s in sets if summary[s][m]["n"]]
        n = sum(c for _, c in vals)
        times.append(fmt(sum(v * c for v, c in vals) / n if n else None, 2))
    lines += [
        "| " + " | ".join(times) + " |",
        "",
        "Other metrics (Hausdorff max and RMS) are in rows.csv and tables.csv.",
        "",
    ]
    return "\n".join(lines)


def kind_table_markdown(rows: Sequence[CompletionRow]) -> str:
    """J80 and mean surface distance (mm) per view set and shape kind (:func:`catalogue.shape_kind`),
    so that a weak family shows; empty when the rows carry no kinds."""
    kinds = sorted({r.kind for r in rows} - {""})
    if not kinds:
        return ""
    lines = [
        "## Per shape kind: J80 / mean surface distance (mm)",
        "",
        *_header(["View set", "kind", "views", *METHODS]),
    ]
    for s in VIEW_SETS:
        for k in kinds:
            sel = [r for r in rows if r.view_set == s and r.kind == k]
            if not sel:
                continue
            cells = []
            for m in METHODS:
                ok = [r for r in sel if r.method == m and r.ok]
                cells.append(
                    f"{fmt_metric(nanmean(r.j80 for r in ok), 'j80')} / "
                    f"{fmt_metric(nanmean(r.hausdorff_mean_mm for r in ok), 'hausdorff_mean_mm')}"
                    if ok
                    else "–"
                )
            lines.append(
                f"| {SET_TITLES[s]} | {k} | {len({(r.object, r.view) for r in sel})} | " + " | ".join(cells) + " |"
            )
    return "\n".join(lines + [""])


def grasp_tables_markdown(g_summary: dict) -> str:
    """Table IV (joint and pose error) and the simulated analogue of Table V (lift success) for
    each hand in ``g_summary`` (:func:`summarize_grasps`), with the paper's figures."""
    from ..grasp.robust import WIDEN_BELOW

    lines = []
    for hand, by_set in g_summary.items():
        methods = [m for m in GRASP_TABLE_METHODS if any(m in by_set[s] for s in VIEW_SETS)]
        lines += [
            f"# Grasp results (paper Tables IV and V), {hand} hand",
            "",
            "Grasps planned on each completion (the paper's views: no table, the object floating as rendered; "
            "tabletop views: on the table the segmentation found, in its frame), every planned grasp "
            "executed on the true mesh with the protocol of the authors' GraspIt evaluation and lifted in "
            "simulation. Means "
            "over all executed grasps of the view set, shown as mean / median (the paper reports means); "
            "n = grasps (views without a grasp: see the quality table). Paper figures: theirs, on their data; "
            'their "Ours" beside our Ours-detailed; no holdout-view row of Table IV is recorded.',
            "",
        ]
        for key, title, digits in (
            ("joint_error_deg", "joint error, degrees (lower is better)", 2),
            ("pose_error_mm", "palm pose error, mm (lower is better)", 1),
        ):
            lines += [
                f"## Table IV: {title}",
                "",
                *_header(["View set", *methods, "paper Partial", "paper Mirror", "paper Ours"]),
            ]
            for s in (s for s in VIEW_SETS if by_set[s]):
                cells = [
                    f"{fmt(c[key], digits)} / {fmt(c[key + '_median'], digits)} (n={c['grasps']})"
                    if (c := by_set[s].get(m))
                    else "–"
                    for m in methods
                ]
                paper = [fmt(paper_grasp(key, s, m), digits) for m in PAPER_METHODS]
                lines.append(f"| {SET_TITLES[s]} | " + " | ".join(cells + paper) + " |")
            lines.append("")
        # The grasps of a method ranked by robustness too: the same grasps, another best one.
        robust = [
            m for m in methods if not math.isnan(by_set["all"].get(m, {}).get("lift_success_best_robust", math.nan))
        ]
        columns = [(m, "lift_success_best") for m in methods] + [(m, "lift_success_best_robust") for m in robust]
        lines += [
            "## Table V analogue: simulated lift success, all grasps / best grasp per view (higher is better)",
            "",
            *_header(["View set", *methods, *map(robust_label, robust)]),
        ]
        for row_set in (*(s for s in VIEW_SETS if by_set[s]), "all"):
            cells = [
                f"{fmt_share(c['lift_success'])} / {fmt_share(c[best])} (n={c['grasps']}/{c['views']})"
                if (c := by_set[row_set].get(m))
                else "–"
                for m, best in columns
            ]
            lines.append(f"| {SET_TITLES.get(row_set, 'All views')} | " + " | ".join(cells) + " |")
        paper = [fmt_share(paper_lift(m)) for m in methods] + [fmt_share(paper_lift(robust_label(m))) for m in robust]
        lines += [
            "| paper, real robot (15 objects) | " + " | ".join(paper) + " |",
            "",
            "Best grasp: the planner's top-ranked grasp of each view (what a robot would execute; a view "
            "without any grasp counts as a failure), n = grasps/views. The paper's figures are real-robot "
            "trials, ours a pybullet lift of 12 cm (the paper's views: object free, no table)."
            + (
                " (robust): the same grasps, the best by robustness over the CNN's 8 sample completions, "
                "each grasped with the palm a few millimetres and degrees off (the share of samples it "
                "lifts, then the share on which it keeps force closure, then its lower-quartile epsilon); "
                f"where even that grasp lifted fewer than {WIDEN_BELOW:.0%} of its sample tests, as many grasps again "
                "were planned on the grasp envelope and the most robust of both kept (the wider search)."
                if robust
                else ""
            )
            + (
                " Ours-envelope: grasps planned on the grasp envelope of those 8 sample completions (the mesh "
                "of their mean at p = 0.3, which keeps what the network hedges on: a vessel out to its unseen "
                "wall, a hidden end), executed on the true mesh like the others."
                if "Ours-envelope" in methods
                else ""
            ),
            "",
            "## Grasp quality and planning (all views)",
            "",
            *_header(
                [
                    "Method",
                    "epsilon planned",
                    "epsilon executed",
                    "force closure planned",
                    "force closure executed",
                    "start clear",
                    "views without grasp",
                    "failed",
                    "plan s/view",
                ]
            ),
        ]
        for m in methods:
            c = by_set["all"][m]
            lines.append(
                f"| {m} | {fmt(c['epsilon_planned'], 3)} | {fmt(c['epsilon_executed'], 3)} | "
                f"{fmt_share(c['force_closure_planned'])} | {fmt_share(c['force_closure_executed'])} | "
                f"{fmt_share(c['start_clear'])} | {c['no_grasp']}/{c['views']} | {c['failed']} | "
                f"{fmt(c['seconds_plan'], 1)} |"
            )
        lines += ["", "Per-grasp values are in grasp_rows.csv, per-view means in views/*.json.", ""]
    return "\n".join(lines)


def kind_grasp_table_markdown(records: list[dict], rows: Sequence[CompletionRow], grasp_rows: list[dict]) -> str:
    """The best grasp's lift success per shape kind and method, every view set pooled, for each
    hand: Table V's "best grasp" per kind, so that a family the grasps fail on shows.

    ``records``: the views with their grasp entries (as for :func:`summarize_grasps`); ``rows``:
    their completion rows, which carry each object's ``kind``; ``grasp_rows``: their grasps. A view
    whose planner found no grasp counts as a failed lift; entries with an error are left out.
    Empty when no grasp entry or no kind is known."""
    kind_of = {r.object: r.kind for r in rows if r.kind}
    best, best_robust = (best_grasp_lifts(grasp_rows, rank) for rank in ("rank", "robust_rank"))
    entries = [(rec, g) for rec in records for g in rec.get("grasps", []) if not g["error"]]
    if not kind_of or not entries:
        return ""
    lines = []
    for hand in sorted({g["hand"] for _, g in entries}):
        methods = [m for m in GRASP_TABLE_METHODS if any(g["method"] == m and g["hand"] == hand for _, g in entries)]
        robust = [m for m in methods if any(k[2:] == (m, hand) for k in best_robust)]
        columns = [(m, best) for m in methods] + [(m, best_robust) for m in robust]
        lines += [
            f"## Per shape kind: best grasp's lift success, {hand} hand (all view sets)",
            "",
            *_header(["kind", "views", *methods, *map(robust_label, robust)]),
        ]
        for kind in sorted({kind_of.get(rec["object"], "") for rec, _ in entries} - {""}):
            cells: list[str] = []
            views: set[tuple[str, int]] = set()
            for m, lifts in columns:
                keys = [
                    (rec["object"], int(rec["view"]), m, hand)
                    for rec, g in entries
                    if g["method"] == m and g["hand"] == hand and kind_of.get(rec["object"]) == kind
                ]
                views.update(k[:2] for k in keys)
                cells.append(f"{fmt_share(nanmean(lifts.get(k, 0.0) for k in keys), 0)}" if keys else "–")
            lines.append(f"| {kind} | {len(views)} | " + " | ".join(cells) + " |")
        lines += [
            "",
            "The share of a kind's views whose best grasp lifted the true object (a view without "
            "grasps counts as a failure), over the views each method was grasped on.",
            "",
        ]
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------
# CSV

# A grasp cell's own values (``summarize_grasps``), as CSV columns.
GRASP_CELL_FIELDS = (
    "grasps",
    "no_grasp",
    *GRASP_MEANS,
    "joint_error_deg_median",
    "pose_error_mm_median",
    "lift_success_best",
    "lift_success_best_robust",
    "seconds_plan",
)

CSV_FIELDS = (
    "table",
    "view_set",
    "method",
    "n",
    "failed",
    *METRICS,
    "seconds",
    "paper_jaccard",
    "paper_hausdorff_mean_mm",
    "paper_geodesic",
    "hand",
    *GRASP_CELL_FIELDS,
    "paper_joint_error_deg",
    "paper_pose_error_mm",
    "paper_lift_success",
)


def write_tables_csv(summary: dict, path: str | Path, g_summary: dict | None = None) -> None:
    """Every table cell as a CSV row: completion cells (``table`` "I-III") and, with
    ``g_summary``, grasp cells (``table`` "IV-V", view set "all" too; ``n`` = views, ``failed`` =
    views whose grasp stage failed). Cells a row does not have are blank; the paper's figures
    follow :data:`PAPER_COLUMN` (NaN for methods the paper does not have)."""
    rows = []
    for s in VIEW_SETS:
        for m in METHODS:
            c = summary[s][m]
            if not c["n"] + c["failed"]:
                continue
            rows.append(
                {
                    "table": "I-III",
                    "view_set": s,
                    "method": m,
                    "n": c["n"],
                    "failed": c["failed"],
                    **{k: c[k] for k in (*METRICS, "seconds")},
                    **{f"paper_{k}": paper_figure(k, s, m) for k in PAPER},
                }
            )
    for hand, by_set in (g_summary or {}).items():
        for s, cells in by_set.items():
            for m, c in cells.items():
                rows.append(
                    {
                        "table": "IV-V",
                        "view_set": s,
                        "method": m,
                        "n": c["views"],
                        "failed": c["failed"],
                        "hand": hand,
                        **{k: c[k] for k in GRASP_CELL_FIELDS},
                        **{f"paper_{k}": paper_grasp(k, s, m) for k in PAPER_GRASP},
                        # Table V has no view sets: the paper's figure sits on the "all" row.
                        "paper_lift_success": paper_lift(m) if s == "all" else math.nan,
                    }
                )
    atomic_write(path, csv_text(CSV_FIELDS, rows))


def _csv(header: list[str], rows: list[list]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(header)
    w.writerows(rows)
    return buf.getvalue()


def view_csv(info, completions, grasps) -> str:
    """One view's per-method metrics and grasp summaries as CSV text, from the results store's
    :class:`ViewInfo`, :class:`CompletionResult` list and :class:`GraspSummary` list."""
    by_method = {g.method: g for g in grasps}
    rows = []
    for c in completions:
        g = by_method.get(c.method)
        gcols = [g.hand, *(getattr(g, k) for k in GRASP_FIELDS), g.error] if g else [""] * (len(GRASP_FIELDS) + 2)
        rows.append(
            [
                info.object,
                info.view,
                info.view_set,
                c.method,
                *(getattr(c, k) for k in METRICS),
                c.seconds,
                c.error,
                c.mesh or "",
                *gcols,
            ]
        )
    return _csv(
        [
            "object",
            "view",
            "view_set",
            "method",
            *METRICS,
            "seconds",
            "error",
            "mesh",
            "grasp_hand",
            *(f"grasp_{k}" for k in GRASP_FIELDS),
            "grasp_error",
        ],
        rows,
    )


def objects_csv(objects) -> str:
    """Objects (:class:`ObjectSummary`) as CSV text: name, split, source, size (m), views, and each
    method's mean metrics and failures."""
    means = (*METRICS, "seconds")
    rows = [
        [
            o.name,
            o.split,
            o.source,
            *o.extents,
            o.views,
            *(v for m in METHODS for v in (*(o.mean(m, k) for k in means), o.failed.get(m, 0))),
        ]
        for o in objects
    ]
    return _csv(
        [
            "object",
            "split",
            "source",
            "extent_x_m",
            "extent_y_m",
            "extent_z_m",
            "views",
            *(f"{m}_{k}" for m in METHODS for k in (*means, "failed")),
        ],
        rows,
    )
