"""Is the completion's uncertainty calibrated? On held-out grids of generated data:

* reliability of the mean probability (expected calibration error over 10 bins);
* error rate per decile of the samples' per-voxel spread (``model.sample_spread`` of
  ``Completer.predict_samples``; ``--plain-std``: the plain std of their probabilities),
  over the *active* voxels (any sample above 0.05, or truly occupied): voxels of the top decile
  should be wrong far more often than those around the median;
* mean spread on the observed side (within one voxel of an observed voxel) against the unseen side
  (the other active voxels).

    python -m benchmarks.studies.calibration --data data/tabletop16 [--weights PATH] [--views 200] [--samples 8]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy import ndimage

from shapeviewer.completion.model import load_completer, sample_spread
from shapeviewer.training.train import check_placement, load_grid_sets


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", nargs="+", required=True)
    ap.add_argument("--weights", default=None)
    ap.add_argument("--views", type=int, default=200)
    ap.add_argument("--samples", type=int, default=8)
    ap.add_argument("--set", default="holdout_model", choices=["training_view", "holdout_view", "holdout_model"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--plain-std", action="store_true", help="rank by the std of the probabilities instead")
    args = ap.parse_args()
    completer = load_completer(args.weights)
    check_placement(completer, args.data)
    gs = load_grid_sets(args.data)[args.set]
    rng = np.random.default_rng(args.seed)
    idx = np.sort(rng.choice(len(gs), size=min(args.views, len(gs)), replace=False))
    spreads, errors, probs, truths, observed = [], [], [], [], []
    times = []
    for i in range(0, len(idx), 8):
        x, _, ctx = gs.grids(idx[i : i + 8])
        y = gs.truth(idx[i : i + 8], completer.label)
        for b in range(len(x)):
            t0 = time.perf_counter()
            s = completer.predict_samples(x[b], args.samples, context=ctx[b])
            times.append(time.perf_counter() - t0)
            mean, sd = s.mean(0), (s.std(0) if args.plain_std else sample_spread(s))
            active = (s > 0.05).any(0) | y[b]
            spreads.append(sd[active])
            errors.append(((mean > 0.5) != y[b])[active])
            probs.append(mean[active])
            truths.append(y[b][active])
            observed.append(ndimage.binary_dilation(x[b])[active])
    sd, err, p, t, obs = (np.concatenate(a) for a in (spreads, errors, probs, truths, observed))
    bins = np.minimum((p * 10).astype(int), 9)
    ece = sum(
        abs(p[bins == k].mean() - t[bins == k].mean()) * np.mean(bins == k) for k in range(10) if (bins == k).any()
    )
    print(
        f"{len(idx)} {args.set} views, {len(sd):,} active voxels, {args.samples} samples; "
        f"median {1000 * np.median(times):.0f} ms per segment"
    )
    print(f"expected calibration error of the mean probability: {ece:.4f}")
    order = np.argsort(sd, kind="stable")
    deciles = np.array_split(order, 10)
    print("spread decile: mean spread / error rate")
    rates = []
    for k, d in enumerate(deciles):
        rates.append(err[d].mean())
        print(f"  {k + 1:2d}: {sd[d].mean():.3f} / {err[d].mean():.3f}")
    median = (rates[4] + rates[5]) / 2
    print(f"top decile error rate / median deciles' (5th-6th) = {rates[9] / max(median, 1e-9):.2f}x")
    print(f"mean spread: observed side {sd[obs].mean():.4f}, unseen side {sd[~obs].mean():.4f}")


if __name__ == "__main__":
    main()
