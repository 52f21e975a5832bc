"""CNN inference speed on this machine (targets: <= 30 ms for one grid, <= 10 ms per grid in
batches of 8, on 2 CPU cores). Prints medians over repeated runs.

    python benchmarks/model.py [--weights PATH] [--repeats 20]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from shapeviewer.completion.model import load_completer


def median_seconds(fn, repeats: int) -> float:
    fn()  # warm-up: oneDNN primitives are created on the first call
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--weights", default=None)
    ap.add_argument("--repeats", type=int, default=20)
    args = ap.parse_args()
    completer = load_completer(args.weights)
    rng = np.random.default_rng(0)
    one = rng.random((40, 40, 40)) < 0.03
    eight = rng.random((8, 40, 40, 40)) < 0.03
    t1 = median_seconds(lambda: completer.predict(one), args.repeats)
    t8 = median_seconds(lambda: completer.predict(eight), args.repeats) / 8
    print(f"model: {completer.arch} ({completer.source}), device {completer.device}")
    print(f"{'case':24s} {'median ms':>10s} {'target ms':>10s}")
    print(f"{'one grid':24s} {t1 * 1000:10.1f} {30:10d}")
    print(f"{'per grid, batch of 8':24s} {t8 * 1000:10.1f} {10:10d}")


if __name__ == "__main__":
    main()
