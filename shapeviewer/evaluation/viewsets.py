"""The test views of ``shapeviewer evaluate``: the paper's three view sets and the tabletop set.

* ``paper`` (as in the paper): *training views*, *holdout views* and *holdout models*
  (:func:`catalogue.view_split`), drawn with a seed from the catalogue objects and the 726-view
  orientation grid, each rendered exactly as the training data is (:func:`generate.view_pose`,
  :func:`generate.render_view`, the Kinect model and the same noise seed), so a *training view*
  here is the very view the network may have trained on. The object floats: no table.
* ``tabletop`` (how a robot uses completion, :mod:`shapeviewer.sim.tabletop`): the object rests on a
  table among neighbours, a Kinect or RealSense looks from 20-70 degrees above the table at
  0.4-1.2 m, and the app's own segmentation cuts the segment and finds the support plane. Two
  sets: *tabletop, training objects* (views numbered from ``TABLETOP_VIEW_OFFSET``, which training
  data never uses) and *tabletop, holdout models*. Objects are drawn kind by kind
  (:func:`catalogue.shape_kind`), so every family of shapes is represented.

The objects are the catalogue's in use: with folders of URDF objects (``--objects-dir``,
``SHAPEVIEWER_OBJECTS``, :func:`catalogue.objects_from`) their ``urdf/<set>/<NAME>`` objects are drawn too,
split by :func:`catalogue.model_split` like the others (a *training view* of an object is one the network
trained on only when its training data held that object).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np
import trimesh

from ..sim import catalogue

PaperSet = Literal["training_view", "holdout_view", "holdout_model"]
TabletopSet = Literal["tabletop_train_object", "tabletop_holdout_model"]
ViewSet = PaperSet | TabletopSet
# The catalogue's model splits (:func:`catalogue.model_split`) the view sets draw their objects from.
Split = Literal["train", "holdout_model"]
Views = Literal["paper", "tabletop"]  # which kind of test views (``shapeviewer evaluate --views``)
PAPER_SETS: tuple[PaperSet, ...] = get_args(PaperSet)
TABLETOP_SETS: tuple[TabletopSet, ...] = get_args(TabletopSet)
VIEW_SETS: tuple[ViewSet, ...] = PAPER_SETS + TABLETOP_SETS
SET_TITLES: dict[str, str] = {
    "training_view": "Training Views",
    "holdout_view": "Holdout Views",
    "holdout_model": "Holdout Models",
    "tabletop_train_object": "Tabletop, training objects",
    "tabletop_holdout_model": "Tabletop, holdout models",
}
TABLETOP_VIEW_OFFSET = 10_000  # tabletop test views are numbered from here; training data starts at 0
TABLETOP_SIZE = (0.05, 0.30)  # largest side (m) of objects put on the test table: fits a hand


@dataclass
class EvalView:
    """One test view, camera optical frame (metres).

    Attributes:
        points_cam: (N, 3) the observed points of the object (its segment on a tabletop).
        truth_cam: the true mesh, closed.
        support_plane: ``(a, b, c, d)`` the segmentation found (tabletop), or None (floating).
        sensor: ``kinect`` or ``realsense``.
    """

    points_cam: np.ndarray
    truth_cam: trimesh.Trimesh
    support_plane: np.ndarray | None = None
    sensor: str = "kinect"


def set_names(views: Views) -> tuple[ViewSet, ...]:
    """The view sets of a kind of test views (``paper`` or ``tabletop``)."""
    if views not in ("paper", "tabletop"):
        raise ValueError(f"unknown views {views!r} (use 'paper' or 'tabletop')")
    return PAPER_SETS if views == "paper" else TABLETOP_SETS


def sample_views(n_per_set: int = 50, seed: int = 0, views: Views = "paper") -> list[tuple[str, int, str]]:
    """A seeded sample of ``n_per_set`` distinct views per view set: ``(object, view, view_set)``."""
    return _sample_paper(n_per_set, seed) if set_names(views) == PAPER_SETS else _sample_tabletop(n_per_set, seed)


def _sample_paper(n_per_set: int, seed: int) -> list[tuple[str, int, str]]:
    """Holdout-model views: a holdout object, then a view, uniformly. Training/holdout views: a
    training object, then a view, until the view's :func:`catalogue.view_split` is the wanted set."""
    from ..training.generate import ORIENTATION_GRID

    rng = np.random.default_rng([seed, 4])
    names = sorted(e.name for e in catalogue.catalogue())
    by_split = {
        "train": [n for n in names if catalogue.model_split(n) == "train"],
        "holdout_model": [n for n in names if catalogue.model_split(n) == "holdout_model"],
    }
    total = int(np.prod(ORIENTATION_GRID))
    out: list[tuple[str, int, str]] = []
    for view_set in PAPER_SETS:
        pool = by_split["holdout_model" if view_set == "holdout_model" else "train"]
        if not pool:
            raise ValueError(f"no catalogue object for {view_set}")
        chosen: set[tuple[str, int]] = set()
        for _ in range(1000 * max(n_per_set, 1)):
            if len(chosen) >= n_per_set:
                break
            name = pool[int(rng.integers(len(pool)))]
            view = int(rng.integers(total))
            if (name, view) not in chosen and catalogue.view_split(name, view) == view_set:
                chosen.add((name, view))
                out.append((name, view, view_set))
    return out


def _sample_tabletop(n_per_set: int, seed: int) -> list[tuple[str, int, str]]:
    """Per set: kinds in turn (a seeded order), an object of that kind, then a fresh view number."""
    rng = np.random.default_rng([seed, 5])
    out: list[tuple[str, int, str]] = []
    splits: tuple[Split, ...] = get_args(Split)
    for view_set, split in zip(TABLETOP_SETS, splits):
        by_kind: dict[str, list[str]] = {}
        for e in catalogue.catalogue():
            if e.split == split and TABLETOP_SIZE[0] <= max(e.extents) <= TABLETOP_SIZE[1]:
                by_kind.setdefault(catalogue.shape_kind(e.name), []).append(e.name)
        kinds = sorted(by_kind)
        if not kinds:
            raise ValueError(f"no catalogue object for {view_set}")
        order = [kinds[i] for i in rng.permutation(len(kinds))]
        for i in range(n_per_set):
            pool = sorted(by_kind[order[i % len(order)]])
            name = pool[int(rng.integers(len(pool)))]
            out.append((name, TABLETOP_VIEW_OFFSET + int(rng.integers(1_000_000)), view_set))
    return out


def view_set_of(name: str, view: int) -> str:
    """The view set a view number belongs to: tabletop views are numbered from
    ``TABLETOP_VIEW_OFFSET``, the paper's views by :func:`catalogue.view_split`."""
    if view >= TABLETOP_VIEW_OFFSET:
        return TABLETOP_SETS[catalogue.model_split(name) == "holdout_model"]
    return catalogue.view_split(name, view)


def render_view(name: str, view: int, view_set: str, seed: int = 0) -> EvalView:
    """The observation and ground truth of one test view (see the module docstring).

    Raises:
        ValueError: a tabletop view that did not come out (the target hidden or not segmented).
    """
    if view_set in TABLETOP_SETS:
        from ..sim.tabletop import render_tabletop_view

        v = render_tabletop_view(name, view, seed=seed)
        if v is None:
            raise ValueError(f"tabletop view {view} of {name}: the object was hidden or not segmented")
        return EvalView(v.points_cam, v.truth_cam(), v.plane_cam, v.sensor)
    from ..perception.camera import Intrinsics
    from ..sim.sensor import KinectNoise, RaycastRenderer
    from ..training.generate import noise_seed, view_pose
    from ..training.generate import render_view as render_object

    mesh = catalogue.centred_mesh(name)
    T = view_pose(name, view, seed)
    _, points = render_object(RaycastRenderer([mesh]), T, Intrinsics.kinect(), KinectNoise(), noise_seed(seed, view))
    return EvalView(points, mesh.copy().apply_transform(T))
