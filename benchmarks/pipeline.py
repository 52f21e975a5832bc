"""Speed of the runtime pipeline against the paper's figures (Varley et al. 2017, Sec. VI).

    python benchmarks/pipeline.py [--repeats 5] [--seeds 0] [--weights PATH]

Inputs: the default generated scene(s) and the organized real captures in ../shared/data/real.

What is measured (medians over every capture, and over every segment for completions):

* segmentation: ``segment_scene(capture)`` on the full 640x480 cloud (``--repeats`` runs per capture).
* voxelize, CNN, marching cubes: the pipeline's own per-stage timings of one segment's fast completion.
* click -> fast mesh: from the moment the viewer starts handling a click on a segment
  (:meth:`Session.complete` of the client's own session) until that client has RECEIVED the scene-node message of
  that segment's fast mesh over the websocket (the mesh is queued first, then the CNN grids).
  The client is a minimal viser websocket client in this process (benchmarks/common/viser_client.py) that
  decodes viser's wire format and timestamps arrivals; it does not render, so browser drawing time
  is not included.

The paper's figures (Titan X GPU): segmentation 0.119 s, one fast (non-target) completion 0.142 s.
Targets on 2 CPU cores: segmentation <= 0.12 s, click -> fast mesh <= 0.15 s.

To time another revision, run its copy from a ``git worktree`` with ``PYTHONPATH=<worktree>`` (e.g.
``PYTHONPATH=../old python ../old/benchmarks/pipeline.py``), so that shapeviewer is imported from the
worktree rather than from the installed checkout.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "2")
import shapeviewer  # noqa: E402,F401  (sets OMP_WAIT_POLICY before torch loads)

from common.captures import load_captures  # noqa: E402  (benchmarks/common/captures.py)
from common.viser_client import ArrivalClock, free_port  # noqa: E402  (benchmarks/common/viser_client.py)

PAPER = {"segmentation": 0.119, "click_to_mesh": 0.142}
TARGET = {"segmentation": 0.12, "click_to_mesh": 0.15}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0], help="default-scene seeds")
    ap.add_argument("--repeats", type=int, default=5, help="segmentation runs per capture")
    ap.add_argument("--weights", default=None, help="CNN weights (default: the shipped model)")
    args = ap.parse_args(argv)

    from shapeviewer.perception.segment import segment_scene
    from shapeviewer.viewer import ViewerApp

    captures = load_captures(args.seeds)
    segmentation = []
    for cap in captures:
        segment_scene(cap)  # warm-up (Open3D's first call allocates)
        runs = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            segment_scene(cap)
            runs.append(time.perf_counter() - t0)
        segmentation.append(statistics.median(runs))
        print(f"segmentation {cap.source}: median {statistics.median(runs) * 1000:.1f} ms", file=sys.stderr)

    app = ViewerApp(port=free_port(), cloud=captures[0], weights=args.weights)
    stages: dict[str, list[float]] = {k: [] for k in ("voxelize", "cnn", "marching_cubes", "send", "click_to_mesh")}
    try:
        clock = ArrivalClock(app.url)
        deadline = time.time() + 60
        while not app.sessions and time.time() < deadline:  # the client's own session
            time.sleep(0.05)
        session = next(iter(app.sessions.values()))
        for cap in captures:
            if cap is not captures[0] and not session.load_capture(cap):
                raise RuntimeError(f"could not show {cap.source}: {session.last_error}")
            time.sleep(1.0)  # let the scene's own messages drain before timing clicks
            assert session.scene is not None
            ids = list(session.scene.segments)
            if ids:
                session.complete(ids[0])  # warm-up: first CNN call, first mesh message
            for sid in ids:
                t0 = time.perf_counter()
                c = session.complete(sid)
                if c is None or c.fast_mesh is None:
                    print(
                        f"  {cap.source} segment {sid}: no fast mesh ({session.last_error or c and c.error})",
                        file=sys.stderr,
                    )
                    continue
                t_arrived = clock.wait_for(f"/fast_mesh/seg_{sid}", after=t0)
                for k in ("voxelize", "cnn", "marching_cubes", "send"):
                    stages[k].append(session.last_timings[k])
                stages["click_to_mesh"].append(t_arrived - t0)
                time.sleep(0.2)
    finally:
        app.stop()

    n_seg = len(stages["click_to_mesh"])
    completer = app.res.completer
    model = f"{completer.arch} ({'trained' if completer.trained else 'UNTRAINED'}: {completer.source})"
    print(f"\nCaptures: {len(captures)} ({', '.join(c.source for c in captures)}); completed segments: {n_seg}")
    print(
        f"Model: {model}; OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}, "
        f"OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY')}; load average {os.getloadavg()[0]:.1f}\n"
    )
    rows = [
        ("segmentation (640x480 cloud)", segmentation, "segmentation"),
        ("  voxelize", stages["voxelize"], None),
        ("  CNN forward", stages["cnn"], None),
        ("  marching cubes", stages["marching_cubes"], None),
        ("  send (queue scene nodes, server side)", stages["send"], None),
        ("click -> fast mesh received by client", stages["click_to_mesh"], "click_to_mesh"),
    ]
    print(f"| {'stage':42s} | {'median':>9s} | {'paper':>8s} | {'target':>8s} |")
    print(f"|{'-' * 44}|{'-' * 11}|{'-' * 10}|{'-' * 10}|")
    ok = True
    for label, values, key in rows:
        med = statistics.median(values) if values else float("nan")
        paper = f"{PAPER[key]:.3f} s" if key else ""
        target = ""
        if key:
            passed = med <= TARGET[key]
            ok &= passed
            target = f"{'ok' if passed else 'MISSED'} {TARGET[key]:.2f}"
        print(f"| {label:42s} | {med:7.3f} s | {paper:>8s} | {target:>8s} |")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
