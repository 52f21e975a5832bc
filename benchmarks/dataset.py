"""Dataset tab: time to load and show one view of a results store (budget: 0.5 s).

Usage: ``python benchmarks/dataset.py [--results DIR] [--runs 3]``. Default store: the sample store
that ``python app.py`` builds in the user cache (built here first if missing, a few minutes).

A view load is :meth:`DatasetTab.select` in a running viewer without a browser: reading the index,
loading the meshes and points (cold: from the PLY files, decimated to the display budget; warm:
from the tab's cache), laying the row out and sending every node, flushed (the browser's drawing is
not included). Prints the median of the cold loads (each view the first time) and of the warm ones
(the same view ``--runs`` more times).
"""

from __future__ import annotations

import argparse
import os
import socket
import statistics
import time
from pathlib import Path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", type=Path, default=None, help="results folder (default: the sample store)")
    ap.add_argument("--runs", type=int, default=3, help="warm loads per view")
    args = ap.parse_args()

    from shapeviewer.evaluation.results import ResultsStore
    from shapeviewer.evaluation.sample_store import build_sample_store, sample_store_complete, sample_store_dir
    from shapeviewer.perception.capture import Capture
    from shapeviewer.viewer import ViewerApp

    root = args.results or sample_store_dir()
    if args.results is None and not sample_store_complete(root):
        print(f"building the sample store in {root} ...", flush=True)
        build_sample_store(root, progress=lambda done, total, what: print(f"  {done}/{total} {what}", flush=True))
    store = ResultsStore(root)
    views = [(v.object, v.view) for o in store.objects() for v in store.views(o.name)]
    if not views:
        raise SystemExit(f"no views with results in {root}")
    # The pipeline tab gets the first view's capture: the benchmark is about the Dataset tab.
    capture: Capture = store.capture(*views[0])
    app = ViewerApp(port=free_port(), cloud=capture, results=root, sessions=False)
    try:
        d = app.open_session().dataset  # a session without a browser
        assert d is not None
        print(f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}; {len(views)} views in {root}")
        # The tab draws its per-object chart in the background at start: let it finish first.
        deadline = time.monotonic() + 30
        while d.bars_drawn != d.bars.key and time.monotonic() < deadline:
            time.sleep(0.1)
        cold, warm = [], []
        for name, view in views:
            t0 = time.perf_counter()
            assert d.select(name, view), d.last_error
            cold.append(time.perf_counter() - t0)
            again = []
            for _ in range(args.runs):
                t0 = time.perf_counter()
                d.select(name, view)
                again.append(time.perf_counter() - t0)
            warm += again
            faces = sum(len(h.faces) for h in d.drawn.values() if hasattr(h, "faces"))
            print(
                f"{name:28s} view {view:3d}: cold {cold[-1]:.3f} s, warm {statistics.median(again):.3f} s "
                f"({faces:,} triangles shown)"
            )
        print(
            f"\nview load, median: cold {statistics.median(cold):.3f} s (max {max(cold):.3f}), "
            f"warm {statistics.median(warm):.3f} s (max {max(warm):.3f}); budget 0.5 s"
        )
    finally:
        app.stop()


if __name__ == "__main__":
    main()
