"""The paper's figures (Varley et al. 2017): Tables I-III (completion), Table IV (grasp joint and
pose errors) and Table V (real-robot lift success), and the one map from our methods to the
paper's columns, :data:`PAPER_COLUMN`.

The paper compares Partial, Mirror and one "Ours", its full pipeline (CNN + Algorithm 1), which
our Ours-detailed reproduces; Hull, Ours-fast and Ours-envelope have no paper figure. Units as in
the paper: Hausdorff distances and pose errors in mm, joint errors in degrees, lift success a
fraction.
"""

from __future__ import annotations

import math

from .methods import Method

# The paper's Tables I-III, {metric: {view_set: (Partial, Mirror, Ours)}}.
PAPER: dict[str, dict[str, tuple[float, float, float]]] = {
    "jaccard": {
        "training_view": (0.118, 0.233, 0.777),
        "holdout_view": (0.131, 0.239, 0.749),
        "holdout_model": (0.093, 0.192, 0.650),
    },
    "hausdorff_mean_mm": {
        "training_view": (11.4, 7.5, 3.6),
        "holdout_view": (12.3, 8.2, 4.0),
        "holdout_model": (13.6, 10.7, 5.9),
    },
    "geodesic": {
        "training_view": (0.377, 0.291, 0.087),
        "holdout_view": (0.494, 0.337, 0.093),
        "holdout_model": (0.341, 0.280, 0.141),
    },
}
# The paper's Table IV, {quantity: {view_set: (Partial, Mirror, Ours)}}. Only its training-view and
# holdout-model rows are recorded; the holdout-view row is left blank rather than guessed.
PAPER_GRASP: dict[str, dict[str, tuple[float, float, float]]] = {
    "joint_error_deg": {"training_view": (6.09, 4.20, 1.75), "holdout_model": (7.59, 5.82, 4.56)},
    "pose_error_mm": {"training_view": (16.0, 11.5, 4.3), "holdout_model": (18.3, 15.0, 13.2)},
}
# The paper's Table V, real-robot grasp success (15 objects), Partial / Mirror / Ours.
PAPER_LIFT: tuple[float, float, float] = (0.714, 0.733, 0.933)
# Our method -> column of the paper's (Partial, Mirror, Ours) figures. The paper's one "Ours" is
# its full pipeline (CNN + Algorithm 1), i.e. our Ours-detailed; methods not listed have none.
PAPER_METHODS: tuple[Method, ...] = ("Partial", "Mirror", "Ours-detailed")  # in the paper's column order
PAPER_COLUMN: dict[str, int] = {m: i for i, m in enumerate(PAPER_METHODS)}


def _paper_cell(row: tuple[float, float, float] | None, method: str) -> float:
    col = PAPER_COLUMN.get(method)
    return math.nan if row is None or col is None else row[col]


def paper_figure(metric: str, view_set: str, method: str) -> float:
    """The paper's Table I-III figure for a cell (NaN where the paper has none)."""
    return _paper_cell(PAPER.get(metric, {}).get(view_set), method)


def paper_grasp(quantity: str, view_set: str, method: str) -> float:
    """The paper's Table IV figure (``joint_error_deg`` or ``pose_error_mm``) for a cell, or NaN."""
    return _paper_cell(PAPER_GRASP.get(quantity, {}).get(view_set), method)


def paper_lift(method: str) -> float:
    """The paper's Table V real-robot lift success of a method (a fraction), or NaN."""
    return _paper_cell(PAPER_LIFT, method)
