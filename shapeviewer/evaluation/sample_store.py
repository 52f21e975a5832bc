"""The sample store: a few evaluated views for a first look in the Dataset tab (``python app.py``
without ``--results``), built in the background by the viewer and kept per CNN weights under
:func:`~shapeviewer.fileio.cache_dir`."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Iterable
from pathlib import Path

from ..fileio import atomic_write
from ..sim import catalogue
from .records import load_view
from .run import GraspOptions, complete_view, grasp_and_save, pending_grasps
from .viewsets import view_set_of

# Household YCB objects of both model splits and a pybullet toy, views from all three evaluation
# sets, and tabletop views (numbered from viewsets.TABLETOP_VIEW_OFFSET) of a mug and procedural
# shapes, among them a box the pipeline completes as the box fitted to its points (shapeviewer.completion.cuboid).
SAMPLE_VIEWS: tuple[tuple[str, int], ...] = (
    ("ycb/021_bleach_cleanser", 0),
    ("ycb/021_bleach_cleanser", 120),
    ("ycb/006_mustard_bottle", 100),
    ("ycb/006_mustard_bottle", 420),
    ("ycb/025_mug", 180),
    ("ycb/025_mug", 0),
    ("ycb/035_power_drill", 300),
    ("pybullet/duck", 0),
    ("ycb/025_mug", 10_003),
    ("household/spray_bottle_004", 10_001),
    ("household/bowl_003", 10_002),
    ("household/box_034", 522_697),
)
SAMPLE_VERSION = 3
SAMPLE_DONE = "SAMPLE_DONE"  # marker file: every sample view has its completions and grasps


def sample_grasp_options() -> GraspOptions:
    """Grasps of the sample store: 5 Barrett grasps per completion from a smaller (still
    deterministic) search than the evaluation's, about 5 s per view and method on 2 cores."""
    from ..grasp.plan import PlanSettings

    return GraspOptions(n_grasps=5, settings=PlanSettings(samples=256, chains=16, steps=100, simulate=15))


def sample_store_dir(weights: str | Path | None = None) -> Path:
    """Where the sample store of the given CNN weights lives (under :func:`~shapeviewer.fileio.cache_dir`).

    The folder name holds a hash of the weights file, so new weights get a new sample store.
    """
    from ..completion.model import DEFAULT_WEIGHTS

    path = Path(weights) if weights is not None else DEFAULT_WEIGHTS
    tag = hashlib.sha1(path.read_bytes()).hexdigest()[:10] if path.is_file() else "untrained"
    return catalogue.cache_dir() / f"results_sample_v{SAMPLE_VERSION}_{tag}"


def sample_store_complete(root: str | Path) -> bool:
    return (Path(root) / SAMPLE_DONE).is_file()


def build_sample_store(
    root: str | Path,
    *,
    views: Iterable[tuple[str, int]] = SAMPLE_VIEWS,
    weights=None,
    seed: int = 0,
    progress: Callable[[int, int, str], None] | None = None,
    completer=None,
    grasps: GraspOptions | bool | None = True,
):
    """Evaluate ``views`` as :func:`evaluate` does into a results store (returned, a
    :class:`~.results.ResultsStore`): first every view's completions, then (``grasps``: True for
    :func:`sample_grasp_options`, a :class:`GraspOptions`, or None) grasps planned on each and
    executed on the truth.

    Finished work is skipped, so an interrupted build resumes. ``progress(done, total, what)`` is
    called before each step and at the end; the store is synced after every step so that a reader
    sees the views as they arrive. Writes the :data:`SAMPLE_DONE` marker when all is done.
    """
    from .results import ResultsStore

    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    store = ResultsStore(root)
    views = list(views)
    options = sample_grasp_options() if grasps is True else (grasps or None)
    total = len(views) * (2 if options is not None else 1)
    done = 0

    def step(what: str) -> None:
        if progress is not None:
            progress(done, total, what)

    records = {}
    for name, view in views:
        record = load_view(root, name, view, seed)
        if record is None:
            step(f"completing {name} view {view}")
            if completer is None:
                from ..completion.model import load_completer

                completer = load_completer(weights)
            record = complete_view(root, name, view, view_set_of(name, view), seed, completer)
            store.sync()
        records[(name, view)] = record
        done += 1
    if options is not None:
        for name, view in views:
            record = records[(name, view)]
            for method in pending_grasps(record, options):
                step(f"grasping {name} view {view} ({method})")
                grasp_and_save(root, record, method, options)
                store.sync()
            done += 1
    atomic_write(root / SAMPLE_DONE, json.dumps({"views": views, "grasps": options is not None}))
    step("done")
    return store
