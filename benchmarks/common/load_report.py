"""The load benchmark's report (``benchmarks/load.py``): its figures as a dict (``summarize``), the
targets they are held to, and the markdown table it prints (``markdown``)."""

from __future__ import annotations

import os
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from .server_process import STOP_TARGET

TARGET_P95 = 0.5  # s, click -> own fast mesh received (lightweight sessions)
MEMORY_TOLERANCE = (0.10, 50.0)  # "back to baseline": within 10 % or 50 MB of it


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def fmt_s(v: float) -> str:
    return "n/a" if not np.isfinite(v) else f"{v:.2f} s" if v < 10 else f"{v:.0f} s"


def fmt_mb(v: float | None) -> str:
    return "n/a" if v is None else f"{v:,.0f} MB"


def summarize(stats: list, memory: dict[str, Any], info: dict[str, Any], args, url: str) -> dict[str, Any]:
    light = [s for s in stats if s.kind == "lightweight"]
    outcomes: Counter = Counter()
    unattributed: Counter = Counter()
    for s in stats:
        outcomes.update(s.outcomes)
        unattributed.update(s.unattributed)
    click_light = [x for s in light for x in s.click_seconds]
    click_browser = [x for s in stats if s.kind == "browser" for x in s.click_seconds]
    plans = [x for s in stats for x in s.plan_seconds]
    errors = sum(s.errors for s in stats) + info.get("server_tracebacks", 0)
    wrong = sum(len(s.wrong) for s in stats)
    by_kind = Counter()
    for k, n in outcomes.items():
        by_kind[k.split(" ", 1)[1]] += n
    for k, n in unattributed.items():
        by_kind[k] += n
    p95 = percentile(click_light, 95)
    base, after = memory.get("baseline"), memory.get("after")
    mem_ok = None
    if base is not None and after is not None:
        mem_ok = after <= base + max(MEMORY_TOLERANCE[0] * base, MEMORY_TOLERANCE[1])
    targets = {
        "errors": {"value": errors, "target": 0, "ok": errors == 0},
        "wrong_session_results": {"value": wrong, "target": 0, "ok": wrong == 0},
        "click_to_own_fast_mesh_p95_s": {
            "value": p95,
            "target": TARGET_P95,
            "ok": bool(click_light) and p95 <= TARGET_P95,
        },
        "memory_after_vs_baseline": {"value": memory, "target": "back to baseline", "ok": mem_ok},
    }
    return {
        "url": url,
        "config": {k: v for k, v in vars(args).items() if k != "json"},
        "info": info,
        "sessions": [s.as_dict() for s in stats],
        "totals": {
            "actions": sum(s.clicks + s.plans for s in stats),
            "clicks": sum(s.clicks for s in stats),
            "plans": sum(s.plans for s in stats),
            "outcomes": dict(outcomes),
            "errors": errors,
            "errors_by_kind": dict(by_kind),
            "wrong_session_results": wrong,
            "actions_disturbed": sum(s.disturbed for s in stats),
            "late_results": sum(s.late for s in stats),
            "red_notifications": sum(len(s.red) for s in stats),
            "click_to_own_fast_mesh_s": {
                "lightweight": {
                    "n": len(click_light),
                    "p50": percentile(click_light, 50),
                    "p95": p95,
                    "max": max(click_light, default=float("nan")),
                },
                "browser": {
                    "n": len(click_browser),
                    "p50": percentile(click_browser, 50),
                    "p95": percentile(click_browser, 95),
                    "max": max(click_browser, default=float("nan")),
                },
            },
            "plan_to_own_grasps_s": {
                "n": len(plans),
                "p50": percentile(plans, 50),
                "max": max(plans, default=float("nan")),
            },
        },
        "memory_mb": memory,
        "targets": targets,
    }


def markdown(r: dict[str, Any]) -> str:
    t, c, mem, tg = r["totals"], r["config"], r["memory_mb"], r["targets"]

    def verdict(key: str) -> str:
        ok = tg[key]["ok"]
        return "n/a" if ok is None else "ok" if ok else "**MISSED**"

    n_light = c["sessions"]
    planners = min(c["planners"], n_light)
    kinds = t["errors_by_kind"]
    error_parts = [f"{kinds.get(k, 0)} {k}" for k in ("timeout", "refused", "error", "missed", "not ready")]
    if r["info"].get("server_tracebacks"):
        error_parts.append(f"{r['info']['server_tracebacks']} tracebacks in the server's log")
    light, browser, plans = (
        t["click_to_own_fast_mesh_s"]["lightweight"],
        t["click_to_own_fast_mesh_s"]["browser"],
        t["plan_to_own_grasps_s"],
    )
    lines = [
        f"## Load: {n_light} lightweight session{'s' if n_light != 1 else ''} ({planners} planning grasps)"
        + (" + 1 browser" if c["browser"] else "")
        + f" x {c['minutes']:g} min on {r['url']}",
        "",
        f"{os.cpu_count()} CPUs; load average {r['info'].get('load_average_start', float('nan')):.1f} at the start, "
        f"{r['info'].get('load_average_end', float('nan')):.1f} at the end; "
        f"{r['info'].get('bytes_received', 0) / 1e6:,.0f} MB received by the sessions.",
        "",
        "| figure | measured | target | |",
        "|---|---|---|---|",
        f"| sessions | {n_light} lightweight" + (" + 1 browser" if c["browser"] else "") + " | | |",
        f"| actions | {t['actions']}: {t['clicks']} segment clicks, {t['plans']} grasp plans | | |",
        f"| errors | {t['errors']}: " + ", ".join(error_parts) + f" | 0 | {verdict('errors')} |",
        f"| results shown in the wrong session | {t['wrong_session_results']} (in {t['actions_disturbed']} actions "
        f"another session's result arrived while waiting) | 0 | {verdict('wrong_session_results')} |",
        f"| click -> own fast mesh received, lightweight (n={light['n']}) | p50 {fmt_s(light['p50'])}, "
        f"p95 {fmt_s(light['p95'])}, max {fmt_s(light['max'])} | p95 <= {TARGET_P95} s "
        f"| {verdict('click_to_own_fast_mesh_p95_s')} |",
    ]
    if c["browser"]:
        lines.append(
            f"| click -> own fast mesh received, browser (n={browser['n']}) | p50 {fmt_s(browser['p50'])}, "
            f"p95 {fmt_s(browser['p95'])}, max {fmt_s(browser['max'])} | | |"
        )
    lines += [
        f"| Plan grasps -> own grasps received (n={plans['n']}) | p50 {fmt_s(plans['p50'])}, "
        f"max {fmt_s(plans['max'])} | | |",
        f"| server memory (RSS) | start {fmt_mb(mem.get('start'))}, baseline {fmt_mb(mem.get('baseline'))} "
        f"(after the warm-up sessions), peak {fmt_mb(mem.get('peak'))}, "
        f"after {fmt_mb(mem.get('after'))} ({c['settle']:g} s after all closed) "
        f"| back to baseline (+{MEMORY_TOLERANCE[0]:.0%} / {MEMORY_TOLERANCE[1]:.0f} MB) "
        f"| {verdict('memory_after_vs_baseline')} |",
    ]
    if r["info"].get("server_stop_seconds") is not None:
        left = r["info"].get("server_children_left", [])
        lines.append(
            f"| server stopped after Ctrl-C (SIGINT) in | {r['info']['server_stop_seconds']:.1f} s, "
            f"{len(left)} child process(es) left {STOP_TARGET:.0f} s after it{': ' if left else ''}"
            f"{'; '.join(left)} | | |"
        )
    lines += [
        "",
        "| session | clicks | plans | errors | wrong-session results | click -> mesh p50 / p95 / max | outcomes |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in r["sessions"]:
        x = s["click_to_own_fast_mesh_s"]
        lines.append(
            f"| {s['name']} ({s['kind']}{', plans' if s['planner'] else ''}) | {s['clicks']} | {s['plans']} "
            f"| {s['errors']} | {s['wrong_session_results']} "
            f"| {fmt_s(percentile(x, 50))} / {fmt_s(percentile(x, 95))} / {fmt_s(max(x, default=float('nan')))} "
            f"| {', '.join(f'{k}: {n}' for k, n in sorted(s['outcomes'].items()))} |"
        )
    red = [m for s in r["sessions"] for m in s["red_notifications"]]
    if red:
        lines += ["", f"Red notifications ({len(red)}): " + "; ".join(sorted(set(red))[:5])]
    other = [f"{s['name']}: {d}" for s in r["sessions"] for d in s["details"] if "Busy" not in d]
    if other:
        lines += ["", "Other errors (first 5): " + "; ".join(other[:5])]
    return "\n".join(lines)


def _plain(value: Any) -> Any:
    """``value`` for JSON: numpy numbers as Python ones, NaN as null."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, Path):
        return str(value)
    return value
