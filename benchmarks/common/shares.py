"""The grasp benchmarks' one table: per ranking (or method), the share of views where its best grasp
lifted the true object, per view set and over all views (``benchmarks/studies/ranking.py``,
``grasp_ceiling.py``, ``envelope_grasps.py``)."""

from __future__ import annotations

from collections import defaultdict

import numpy as np

Shares = dict[str, dict[str, list[float]]]


def new_shares() -> Shares:
    """An empty table: ``{ranking: {view set or "all": [1.0 or 0.0 per view]}}``."""
    return defaultdict(lambda: defaultdict(list))


def add(shares: Shares, ranking: str, view_set: str, ok: float) -> None:
    """One view's outcome for ``ranking``, counted in its view set and in "all"."""
    for s in (view_set, "all"):
        shares[ranking][s].append(float(ok))


def print_shares(shares: Shares, label: str) -> None:
    """The table, one row per ranking and a column per view set ("all" last): share and view count."""
    sets = sorted({s for d in shares.values() for s in d}, key=lambda s: (s == "all", s))
    width = max(len(label), *map(len, shares))
    print(f"{label:{width}s} " + " ".join(f"{s:>24s}" for s in sets))
    for ranking, d in shares.items():
        cells = (f"{100 * np.mean(d[s]):17.1f}% n={len(d[s]):3d}" if d[s] else f"{'-':>24s}" for s in sets)
        print(f"{ranking:{width}s} " + " ".join(cells))
