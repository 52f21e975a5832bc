"""The app's grasp pick, written once (shapeviewer.grasp.pick): the public robust_grasps on a real
capture, and the evaluation, the viewer's "Rank by robustness" and the ranking benchmark all
reaching the pick through rank_grasps."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import shapeviewer
from shapeviewer.errors import Cancelled
from shapeviewer.evaluation import records as rec
from shapeviewer.evaluation import run as ev
from shapeviewer.grasp import pick as P
from shapeviewer.grasp.execute import execute_grasps
from shapeviewer.grasp.plan import PlanSettings
from shapeviewer.grasp.robust import rank_robust
from shapeviewer.grasp.serialize import grasps_from_json
from shapeviewer.perception.camera import transform_points
from shapeviewer.perception.capture import load_capture
from shapeviewer.perception.segment import segment_scene

from helpers import headless_session

CAPTURE = Path(__file__).resolve().parents[2] / "static_assets" / "captures" / "milk_cartoon_all_small_clorox.pcd"


def assert_ranked(pick: P.Pick) -> None:
    """A pick's fields agree: every grasp ranked once, best first by robustness."""
    n = len(pick.grasps)
    assert n >= 1 and len(pick.robustness) == n and sorted(pick.order) == list(range(n))
    assert list(pick.order) == rank_robust(pick.robustness, [g.lift for g in pick.grasps])
    assert pick.best is pick.grasps[pick.order[0]] and pick.ranked[0] is pick.best
    assert [id(g) for g in pick.ranked] == [id(pick.grasps[i]) for i in pick.order]
    assert set(pick.seconds) == {"plan", "rank", "wider"} and all(t >= 0 for t in pick.seconds.values())


# ------------------------------------------------------------------------------------------------
# The public API on a real capture


@pytest.fixture(scope="module")
def milk():
    """The largest segment of the shipped real capture, its segmentation, and the README's pick on it."""
    segmentation = segment_scene(load_capture(CAPTURE))
    segment = max(segmentation.segments, key=lambda s: len(s.points_cam))
    shares: list[float] = []
    pick = shapeviewer.robust_grasps(
        segment.points_cam, support_plane=segmentation.plane_cam, hand="panda", n_grasps=6, progress=shares.append
    )
    return segment, segmentation, pick, shares


@pytest.mark.slow
def test_robust_grasps_on_a_real_capture_ranks_grasps_whose_best_lifts_its_completion(milk):
    segment, segmentation, pick, shares = milk
    assert isinstance(pick, P.Pick)
    assert_ranked(pick)
    assert all(g.hand == "panda" for g in pick.grasps) and len(pick.robustness[0].epsilons) == 8
    # The most robust grasp, executed on the completion it was ranked on, lifts it off the table.
    (done,) = execute_grasps([pick.best], pick.mesh_world, table=True, lift=True)
    assert done.lift is not None and done.lift.success, done.lift
    # The world frame is the segmentation's table frame: the points and the completion stand on z = 0.
    assert pick.T_world_cam.shape == (4, 4) and np.allclose(pick.T_world_cam, segmentation.T_world_cam)
    points_world = transform_points(pick.T_world_cam, segment.points_cam)
    assert np.percentile(points_world[:, 2], 1) > -0.01 and points_world[:, 2].max() > 0.05
    low, high = pick.mesh_world.bounds
    assert abs(low[2]) < 0.01 and high[2] > 0.05
    # The best palm is at the object, above the table.
    assert np.all(pick.best.position > low - 0.15) and np.all(pick.best.position < high + 0.15)
    assert pick.best.T_world_palm[2, 3] > 0.0
    # Progress runs from 0 to 1 and never back.
    assert shares[-1] == 1.0 and np.all(np.diff(shares) >= 0) and 0.0 <= shares[0] < 1.0


def test_robust_grasps_checks_its_options():
    points = np.zeros((100, 3))
    with pytest.raises(ValueError, match="unknown hand"):
        shapeviewer.robust_grasps(points, support_plane=np.array([0, -1, 0, 1.0]), hand="shadow")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="mode"):
        shapeviewer.robust_grasps(points, support_plane=np.array([0, -1, 0, 1.0]), mode="best")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="plane"):
        shapeviewer.robust_grasps(points, support_plane=np.array([0, 0, 0, 1.0]))


@pytest.mark.slow
def test_rank_grasps_needs_an_envelope_to_widen_and_stops_when_cancelled(milk):
    _, _, pick, _ = milk
    mesh = pick.mesh_world
    with pytest.raises(ValueError, match="envelope"):
        P.rank_grasps(mesh, [mesh], hand="panda", planned=pick.grasps[:1])
    with pytest.raises(Cancelled):
        P.rank_grasps(mesh, [mesh], hand="panda", planned=pick.grasps[:1], widen=False, cancel=lambda: True)
    with pytest.raises(ValueError, match="barrett"):
        P.rank_grasps(mesh, [mesh], hand="barrett", planned=pick.grasps[:1], widen=False)


# ------------------------------------------------------------------------------------------------
# The evaluation and the ranking benchmark


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory):
    """One paper view evaluated with a small grasp search, ranked by robustness with the wider search
    forced (any share below 101 %): ``(results folder, record, entry, the picks rank_grasps returned)``."""
    picks: list[P.Pick] = []
    real = P.rank_grasps

    def spy(*args, **kwargs):
        picks.append(real(*args, **kwargs))
        return picks[-1]

    folder = tmp_path_factory.mktemp("pick_eval")
    views = ev.sample_views(1, seed=0)[:1]
    options = ev.GraspOptions(
        methods=("Ours-fast",),
        n_grasps=3,
        settings=PlanSettings(samples=256, chains=16, steps=10, simulate=8),
        robust=True,
        widen_below=1.01,
    )
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(P, "rank_grasps", spy)
        assert ev.run_views(folder, views, workers=1, grasps=options, progress=False) == 1
    name, view, _ = views[0]
    record = rec.load_view(folder, name, view)
    (entry,) = record["grasps"]
    return folder, record, entry, picks


@pytest.mark.slow
def test_the_evaluation_picks_through_rank_grasps(evaluated):
    folder, _, entry, picks = evaluated
    assert entry["error"] == "" and entry["robust"]
    (pick,) = picks  # one pick per view and method
    assert_ranked(pick)
    assert pick.wider_from == entry["n"] and len(pick.grasps) == entry["n"] + entry["n_wider"]
    saved = json.loads((folder / entry["file"]).read_text())
    # The file's robust ranks are the pick's order, and the robust best grasp is the pick's best.
    ranks = [r["rank"] for r in saved["meta"]["robustness"]]
    assert [ranks.index(k) for k in range(len(ranks))] == list(pick.order)
    best = saved["grasps"][pick.order[0]]
    assert np.allclose(best["T_world_palm"], pick.best.T_world_palm)
    assert entry["lift_success_best_robust"] == float(best["execution"]["lift"]["success"])
    # Dropping the wider search's grasps ranks the completion's own alone.
    alone = pick.without_wider("execution failed")
    assert len(alone.grasps) == entry["n"] and alone.wider_from is None and alone.wider_error == "execution failed"
    assert list(alone.order) == rank_robust(alone.robustness, [g.lift for g in alone.grasps])


@pytest.mark.slow
def test_the_ranking_benchmark_reproduces_the_evaluations_pick(evaluated):
    from benchmarks.studies.ranking import rerank

    folder, record, entry, picks = evaluated
    saved = grasps_from_json((folder / entry["file"]).read_text())
    assert saved.meta["wider"]["first"] == entry["n"]
    index = rerank(folder, record, "Ours-fast", saved.grasps, saved.meta["wider"], {})
    assert index == picks[0].order[0]
    # Without the wider search's grasps saved, only the completion's compete.
    alone = rerank(folder, record, "Ours-fast", saved.grasps[: entry["n"]], None, {})
    assert alone == picks[0].without_wider("not saved").order[0]


# ------------------------------------------------------------------------------------------------
# The viewer


@pytest.mark.slow
def test_the_viewer_ranks_through_rank_grasps_with_the_same_order(monkeypatch):
    """Rank by robustness in the viewer (its stages in the worker processes, the envelope made
    through the app) gives the pick rank_grasps gives in this process for the same grasps and seed,
    wider search included."""
    from shapeviewer.viewer.grasps import controller

    calls: list[dict] = []
    real = controller.rank_grasps

    def spy(*args, **kwargs):
        calls.append(kwargs)
        return real(*args, **kwargs)

    monkeypatch.setattr(controller, "rank_grasps", spy)
    with headless_session(seed=0) as app:
        sid = max(app.scene.segments, key=lambda s: len(app.scene.points_world[s]))
        job = app.plan_grasps(sid, "barrett", "fast", 4, seed=0)
        assert job is not None and job.error is None and job.result is not None and job.result.grasps
        s = job.result
        first = list(s.grasps)
        app.grasps.widen_below = 1.01  # always widen
        job = app.grasps.rank(sid)
        assert job is not None and job.error is None, job.error
        assert len(calls) == 1 and calls[0]["runner"] is not None and calls[0]["planned"] == first
        assert s.wider_from == len(first) and len(s.grasps) > len(first)
        envelope = app.grasps.host.mesh("envelope", sid).copy().apply_transform(app.scene.T_world_cam)
        direct = P.rank_grasps(
            s.mesh_world,
            app.grasps.host.samples(sid),
            hand=s.hand,
            n_grasps=len(first),
            seed=s.seed,
            table=s.table,
            planned=first,
            widen_below=1.01,
            envelope=envelope,
        )
        viewer_order = rank_robust(s.robustness, [g.lift for g in s.grasps])
        assert list(direct.order) == viewer_order and app.grasps.selected == direct.order[0]
        assert list(direct.robustness) == s.robustness and direct.wider_from == s.wider_from
        for a, b in zip(direct.grasps, s.grasps, strict=True):
            assert np.allclose(a.T_world_palm, b.T_world_palm) and a.dofs == b.dofs
