"""Evaluate the completion methods on two tabletop views (paper Tables I-III, in miniature).

Renders one training object and one holdout object on a table as a simulated depth camera sees
them, completes each with every method (Partial, Mirror, Hull, Ours-fast, Ours-detailed), scores the
meshes against the true object and writes the results folder. Run it again: finished views are
reused. Browse the folder with `python app.py --results OUTPUT_FOLDER`.

    python examples/evaluate_two_views.py [OUTPUT_FOLDER]
"""

import sys
import tempfile
from pathlib import Path

import shapeviewer as sv

if __name__ == "__main__":
    out = Path(sys.argv[1] if len(sys.argv) > 1 else tempfile.mkdtemp(prefix="shapeviewer_"))

    # One view per tabletop view set (training objects, holdout objects): two views in all.
    result = sv.evaluate(out, n_per_set=1, views="tabletop", seed=0, workers=1, progress=False)

    print(result["tables_md"])  # the same Markdown as OUTPUT_FOLDER/tables.md
    print(f"{result['computed']} views computed, {result['skipped']} reused, in {result['seconds']:.0f} s")
    print(f"wrote {out / 'tables.md'}, {out / 'rows.csv'} and the meshes in {out / 'meshes'}")
