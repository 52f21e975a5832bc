"""The detailed mesh of a fitted box against the network's, on the views of an evaluation folder.

For each tabletop view: the cuboid fitted to the observed points (:func:`shapeviewer.completion.cuboid.fit_cuboid`)
and whether it is accepted as a box; for the accepted views (every view with ``--all``) the segment is
completed again, as the network answers it (``complete_points(..., fit_boxes=False)``) and as the
box (its occupancy in place of the answers, what the pipeline does by default for an accepted box),
and both detailed meshes are scored against the true mesh.

    shapeviewer evaluate --out results/table7 --views tabletop --views-per-set 50 --seed 7
    python -m benchmarks.studies.cuboid results/table7 [--all] [--kinds box]

Prints one line per view (the fit's fill, aligned share and residual; J80 and mean surface distance,
network -> box), then the means per kind (views not boxed: the folder's Ours-detailed scores).
"""

from __future__ import annotations

from dataclasses import replace
from functools import cache
from pathlib import Path

import numpy as np

from benchmarks.common.prior_study import main, tabletop_view


@cache
def _completer():
    from shapeviewer.completion.model import load_completer

    return load_completer()


def view_scores(root: Path, file: Path, every: bool) -> dict | None:
    """One view's figures (:mod:`prior_study`), None without a table or an Ours-detailed row."""
    from shapeviewer.completion.cuboid import fit_cuboid, occupancy
    from shapeviewer.completion.pipeline import complete_points, completion_detailed_mesh
    from shapeviewer.evaluation.metrics import hausdorff, sampled_jaccard
    from shapeviewer.evaluation.results import read_mesh

    view = tabletop_view(root, file)
    if view is None:
        return None
    record, out, plane, points = view
    box = fit_cuboid(points, plane)
    out.update(accepted=box.accepted, fill=box.fill, aligned=box.aligned, residual_mm=box.residual * 1000)
    if not (box.accepted or every):
        return out
    truth = read_mesh(root / record["files"]["truth"])
    (network,) = complete_points([points], _completer(), support_plane=plane, fit_boxes=False)
    occupied = occupancy(box, network.frame)
    boxed = replace(network, probabilities=occupied, samples=np.broadcast_to(occupied, network.samples.shape))
    for suffix, c in (("", network), ("_after", boxed)):
        mesh = completion_detailed_mesh(c, points)
        out[f"j80{suffix}"] = sampled_jaccard(mesh, truth)
        out[f"mm{suffix}"] = hausdorff(mesh, truth)["mean_mm"]
    return out


def describe(s: dict) -> str:
    """The fit's fill, aligned share and residual."""
    return f"fill {s['fill']:.2f} aligned {s['aligned']:.2f} residual {s['residual_mm']:4.1f} mm"


if __name__ == "__main__":
    main(__doc__, view_scores, describe)
