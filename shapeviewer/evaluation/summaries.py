"""What the results store returns: plain, frozen records of objects, views, completions and grasps
(:class:`~shapeviewer.evaluation.results.ResultsStore`'s read API). No SQLite, no viser."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from .records import view_stem


@dataclass(frozen=True)
class ObjectSummary:
    """One catalogue object (or an object that only the results know) with its results.

    Attributes:
        name: catalogue name, e.g. ``ycb/025_mug``.
        split: ``train`` or ``holdout_model``.
        source: ``ycb`` or ``pybullet`` (``unknown`` when the catalogue does not know the object).
        extents: (3,) bounding-box size in metres (NaN when unknown).
        views: number of views with results.
        means: method -> metric -> mean over the views where the method succeeded (NaN if none).
        failed: method -> number of views where the method failed.
    """

    name: str
    split: str
    source: str
    extents: tuple[float, float, float]
    views: int
    means: dict[str, dict[str, float]] = field(default_factory=dict)
    failed: dict[str, int] = field(default_factory=dict)

    def mean(self, method: str, metric: str) -> float:
        return self.means.get(method, {}).get(metric, math.nan)


@dataclass(frozen=True)
class ViewInfo:
    """One view with results.

    Attributes:
        object, view: which view (``view`` numbers the 726-view orientation grid).
        view_set: ``training_view``, ``holdout_view`` or ``holdout_model``.
        seed: the evaluation seed (None for the first file format, which did not record it: 0 was
            its default).
        file: the view file, relative to the store root.
        truth, points: mesh files relative to the root (None when missing).
    """

    object: str
    view: int
    view_set: str
    seed: int | None
    file: str
    truth: str | None
    points: str | None

    @property
    def stem(self) -> str:
        return view_stem(self.object, self.view)


@dataclass(frozen=True)
class CompletionResult:
    """One method's completion of a view: the metrics (NaN when it failed), its time and mesh file,
    and the shape prior the pipeline applied to it (``"box"``: completed as the box fitted to the
    points, ``"revolution"``: the answers revolved about the table's normal; ``""``: none)."""

    method: str
    jaccard: float
    j80: float
    hausdorff_mean_mm: float
    hausdorff_max_mm: float
    hausdorff_rms_mm: float
    geodesic: float
    seconds: float
    error: str
    mesh: str | None
    prior: str = ""

    @property
    def ok(self) -> bool:
        return not self.error


@dataclass(frozen=True)
class GraspSummary:
    """The grasps planned on one method's completion of a view and executed on the true object.

    Attributes:
        method, hand: the completion the grasps were planned on, and the hand.
        file: the grasps JSON (``grasp.export`` format) relative to the root, or None.
        n: number of grasps.
        joint_error_deg, pose_error_mm: planned vs executed (paper Table IV), means over the grasps.
        epsilon_planned, epsilon_executed: GraspIt's epsilon quality, planned and executed.
        force_closure_planned: as the evaluation recorded it (a share of grasps, or a flag).
        lift_success: as the evaluation recorded it (a share of grasps, or a flag).
        seconds_plan: planning time.
        error: why planning or execution failed ("" when it did not).
    """

    method: str
    hand: str
    file: str | None
    n: int
    joint_error_deg: float
    pose_error_mm: float
    epsilon_planned: float
    epsilon_executed: float
    force_closure_planned: float
    lift_success: float
    seconds_plan: float
    error: str


@dataclass
class SyncReport:
    """What one :meth:`ResultsStore.sync` did: view files added, updated, removed, skipped (path, why)."""

    added: int = 0
    updated: int = 0
    removed: int = 0
    skipped: list[tuple[str, str]] = field(default_factory=list)

    @property
    def changed(self) -> bool:
        return bool(self.added or self.updated or self.removed)
