"""The detailed mesh of the network's answer revolved about the table's normal, against the shipped one.

For each tabletop view of an evaluation folder: the vertical axis fitted to the observed points
(:func:`shapeviewer.completion.revolve.fit_axis`), whether it is accepted as a surface of revolution, and, for the
accepted views (every view with ``--all``), Algorithm 1's mesh of the mean of the revolved sample
completions (:func:`shapeviewer.completion.revolve.revolve` on the saved samples, the seen free space left
empty: what ``complete_points(..., revolve_answers=True)`` gives) scored against the true mesh beside
the folder's own Ours-detailed scores (the folder evaluated without revolving, the default).

    shapeviewer evaluate --out results/table7 --views tabletop --views-per-set 50 --seed 7
    python -m benchmarks.studies.revolve results/table7 [--all] [--kinds bowl cup]

Prints one line per view (J80 and mean surface distance, shipped -> revolved; the axis's angular
coverage and relative residual), then the means per kind.
"""

from __future__ import annotations

from pathlib import Path

from benchmarks.common.prior_study import main, tabletop_view


def view_scores(root: Path, file: Path, every: bool) -> dict | None:
    """One view's figures, None without a table, samples or Ours-detailed row."""
    from shapeviewer.completion.reconstruct import detailed_mesh
    from shapeviewer.completion.revolve import fit_axis, revolve
    from shapeviewer.completion.voxel import context_grids
    from shapeviewer.evaluation.metrics import hausdorff, sampled_jaccard
    from shapeviewer.evaluation.records import samples_file, view_stem
    from shapeviewer.evaluation.results import read_mesh
    from shapeviewer.evaluation.run import load_samples

    view = tabletop_view(root, file)
    if view is None:
        return None
    record, out, plane, points = view
    samples = root / samples_file(view_stem(record["object"], record["view"]))
    if not samples.exists():
        return None
    axis = fit_axis(points, plane)
    out.update(
        accepted=axis.accepted,
        coverage_deg=axis.coverage_deg,
        relative_residual=axis.residual / max(axis.radius, 1e-9),
    )
    if not (axis.accepted or every):
        return out
    answers, frame, level = load_samples(samples)
    free = context_grids(points, frame, support_plane=plane)[0]
    mean = revolve(answers, frame, axis, free=free).mean(axis=0)
    mesh = detailed_mesh(mean, frame, points, support_plane=plane, level=level)
    truth = read_mesh(root / record["files"]["truth"])
    out["j80_after"] = sampled_jaccard(mesh, truth)
    out["mm_after"] = hausdorff(mesh, truth)["mean_mm"]
    return out


def describe(s: dict) -> str:
    """The axis's angular coverage and relative residual."""
    return f"coverage {s['coverage_deg']:3.0f} residual {s['relative_residual']:.3f}"


if __name__ == "__main__":
    main(__doc__, view_scores, describe)
