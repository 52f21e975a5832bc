"""What the training label allows: J80 of meshes made from *perfect* 40^3 labels of tabletop test views.

A network can at best reproduce its label, so the label caps the meshes it can give. For each view
(``shapeviewer evaluate --views tabletop``'s sample) the true mesh is voxelized in the view's grid
frame as

  * ``Y``: every voxel the object touches (the paper's label, ``voxel.solid_grid``), meshed at the
    level a network trained on it is meshed at (``reconstruct.MESH_LEVEL``);
  * ``soft``: how much of each voxel the object fills (``voxel.solid_fraction``), meshed at 0.5;

each also blurred by a Gaussian of 0.7 voxels, about as smooth as a network's answer. Prints mean J80
per label and per shape kind.

    python -m benchmarks.studies.label_ceiling [--views-per-set 15] [--seed 1] [--per-kind 2]
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import numpy as np
from scipy import ndimage

from shapeviewer.completion.reconstruct import MESH_LEVEL, EmptyCompletionError, grid_mesh
from shapeviewer.completion.voxel import partial_to_grid, solid_fraction, solid_grid
from shapeviewer.evaluation.metrics import sampled_jaccard
from shapeviewer.evaluation.viewsets import render_view, sample_views
from shapeviewer.sim import catalogue

BLUR = 0.7  # voxels


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--views-per-set", type=int, default=15)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--per-kind", type=int, default=None, help="at most this many views of each shape kind")
    args = ap.parse_args()
    rows = []
    count: dict = defaultdict(int)
    for name, view, view_set in sample_views(args.views_per_set, args.seed, "tabletop"):
        kind = catalogue.shape_kind(name)
        if args.per_kind is not None and count[kind] >= args.per_kind:
            continue
        try:
            v = render_view(name, view, view_set, args.seed)
        except ValueError:
            continue
        count[kind] += 1
        _, frame = partial_to_grid(v.points_cam)
        y = solid_grid(v.truth_cam, frame)
        soft = solid_fraction(v.truth_cam, frame, y)
        hard = y.astype(np.float32)
        labels = {
            "Y": (hard, MESH_LEVEL),
            "Y blurred": (ndimage.gaussian_filter(hard, BLUR), MESH_LEVEL),
            "soft": (soft, 0.5),
            "soft blurred": (ndimage.gaussian_filter(soft, BLUR), 0.5),
        }
        row = {"kind": kind}
        for label, (values, level) in labels.items():
            try:
                row[label] = sampled_jaccard(grid_mesh(values, frame, level), v.truth_cam)
            except EmptyCompletionError:  # a wall too thin for the label: nothing to mesh
                row[label] = 0.0
        rows.append(row)
        print(f"{len(rows):3d} {name:32s} " + " ".join(f"{k} {row[k]:.3f}" for k in labels), flush=True)
    labels = [k for k in rows[0] if k != "kind"]
    print(f"\n{'kind':14s} {'n':>3s} " + " ".join(f"{k:>13s}" for k in labels))
    for kind in sorted({r["kind"] for r in rows}) + ["all"]:
        sel = [r for r in rows if kind in ("all", r["kind"])]
        print(f"{kind:14s} {len(sel):3d} " + " ".join(f"{np.mean([r[k] for r in sel]):13.3f}" for k in labels))


if __name__ == "__main__":
    main()
