"""What a new user of the Pipeline tab runs into, driven without a browser: choosing a segment again
brings back what was made of it, execution's hidden layers come back, the Panda's joint error in
millimetres, a plan without a grasp that lifts says why and what to try, one clock per grasp stage
in the notices and the panel, and counts with the right plural.

The notices are read where :class:`~shapeviewer.viewer.audience.Audience` logs each one it shows
(``title: body``)."""

from __future__ import annotations

import contextlib
import dataclasses
import logging
from collections.abc import Iterator

import numpy as np
import pytest
import trimesh

from shapeviewer.perception.capture import SceneObject
from shapeviewer.sim.demo_scene import capture_scene
from shapeviewer.viewer.rays import ray_through
from shapeviewer.viewer.session import Session

from helpers import headless_session, node

BOX_EXTENTS = (0.10, 0.10, 0.14)  # metres: wider than the Panda opens (80 mm) whichever way it turns
N_BOX_GRASPS = 4


@contextlib.contextmanager
def notices() -> Iterator[list[str]]:
    """The notifications the viewer shows meanwhile, as ``title: body``."""
    logger = logging.getLogger("shapeviewer.viewer.audience")
    shown: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            shown.append(record.getMessage())

    handler, level = Keep(logging.INFO), logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    try:
        yield shown
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)


def box_capture():
    """A simulated capture of one 10 x 10 x 14 cm box standing on the table (ground truth included)."""
    T_world_obj = np.eye(4)
    T_world_obj[2, 3] = BOX_EXTENTS[2] / 2
    box = SceneObject("box", trimesh.creation.box(extents=BOX_EXTENTS), T_world_obj)
    return capture_scene([box], seed=0, noise=None)


def largest_segments(app: Session) -> list[int]:
    return sorted(app.scene.segments, key=lambda s: -len(app.scene.points_world[s]))


def option_of(app: Session, sid: int) -> str:
    """The Segment dropdown's entry for segment ``sid``."""
    return next(label for label, s in app.segment_options.items() if s == sid)


@pytest.fixture(scope="module")
def app():
    with headless_session(seed=0) as app:
        yield app


@pytest.fixture(scope="module")
def made(app):
    """The largest segment of the default scene completed, with its detailed mesh, its Hull baseline
    and two Barrett grasps: ``(segment id, what was made)``."""
    sid = largest_segments(app)[0]
    c = app.complete(sid)
    assert c is not None and c.fast_mesh is not None
    meshes = {kind: app.compute_mesh(kind, sid) for kind in ("detailed", "hull")}
    assert all(m is not None for m in meshes.values())
    job = app.plan_grasps(sid, "barrett", "fast", 2, seed=0)
    assert job is not None and job.error is None and job.result is not None and job.result.grasps
    return sid, {"completion": c, "grasps": job.result, **meshes}


@pytest.fixture(scope="module")
def box_app():
    """A viewer on the box scene, Panda grasps planned on the box's fast mesh: ``(session, grasps,
    the notices planning showed)``."""
    with headless_session(seed=0) as app:
        assert app.load_capture(box_capture())
        (sid,) = app.scene.segments
        with notices() as shown:
            job = app.plan_grasps(sid, "panda", "fast", N_BOX_GRASPS, seed=0)
        assert job is not None and job.error is None and job.result is not None
        yield app, job.result, shown


def test_choosing_a_completed_segment_brings_back_what_was_made_of_it(app, made):
    sid, was = made
    other = largest_segments(app)[1]
    assert app.complete(other) is not None and app.selected == other
    assert app.grasps.current == sid  # the grasps listed are still the first segment's

    # A click on the first segment in 3D.
    centroid = app.segment_centroid_world(sid)
    origin = centroid + np.array([0.0, 0.0, 1.0])
    assert app.pick(*ray_through(origin, centroid)) == sid
    assert app.click(*ray_through(origin, centroid)) == "segment"
    assert app.selected == sid
    assert app.completions[sid] is was["completion"], "the segment was completed again"
    for kind in ("detailed", "hull"):
        assert app.mesh(kind, sid) is was[kind]
        assert node(app, f"/{kind}_mesh/seg_{sid}") is not None, kind
    for layer in ("fast_mesh", "cnn_input"):
        assert node(app, f"/{layer}/seg_{sid}") is not None, layer
    name, data = app.export_bytes("mesh", mesh="detailed")  # Export -> Mesh: detailed, of the selected segment
    assert f"seg{sid}_detailed" in name and len(data) > 0
    assert "completed earlier" in app.panel.timings.content and "detailed mesh" in app.panel.timings.content
    assert app.grasps.current == sid and app.grasps.sets[sid] is was["grasps"]
    assert app.grasps.panel.grasp.value.startswith("#1 ")
    # Its sample completions are there to step through.
    assert app.show_sample(2) is not None
    app.show_sample(0)

    # The other segment, then the first one again, in the Segment dropdown: the same.
    app.panel.segment.value = option_of(app, other)
    assert app.selected == other and app.mesh("detailed", sid) is was["detailed"]
    app.panel.segment.value = option_of(app, sid)
    assert app.selected == sid and app.completions[sid] is was["completion"]
    assert app.mesh("hull", sid) is was["hull"] and node(app, f"/hull_mesh/seg_{sid}") is not None
    assert app.export_bytes("mesh", mesh="hull")[1]

    # Complete segment makes it anew, on purpose: the meshes of the old completion go.
    c = app.complete(sid)
    assert c is not None and c is not was["completion"] and app.mesh("detailed", sid) is None


def test_a_new_completion_shows_the_layers_that_execution_hid(app, made):
    sid, _ = made
    layers = app.panel.layers
    app.panel.segment.value = option_of(app, sid)
    if app.mesh("fast", sid) is None:
        assert app.complete(sid) is not None
    layers["cnn_input"].value = False  # the user's own choice: it stays off
    job = app.execute_grasps(sid, [0], lift=False)
    assert job is not None and job.error is None
    assert not layers["fast_mesh"].value and not node(app, "/fast_mesh").visible

    other = largest_segments(app)[2]
    c = app.complete(other)
    assert c is not None and c.fast_mesh is not None
    assert layers["fast_mesh"].value and node(app, "/fast_mesh").visible, "the new completion is not shown"
    assert node(app, f"/fast_mesh/seg_{other}") is not None
    assert not layers["cnn_input"].value  # not hidden by the execution: left as the user set it
    layers["cnn_input"].value = True


def test_panda_joint_error_is_in_millimetres(box_app):
    app, s, _ = box_app
    with notices() as shown:
        job = app.execute_grasps(s.segment_id, [0], lift=False)
    assert job is not None and job.error is None
    (e,) = job.result
    info = app.grasps.panel.info.content
    assert f"joint error **{e.joint_error:.2f} mm**" in info
    assert "°" not in info.split("joint error")[1].split("pose error")[0]
    executed = next(n for n in shown if n.startswith("Executed"))
    assert f"joint error {e.joint_error:.1f} mm," in executed and "°" not in executed


def test_a_plan_without_a_grasp_that_lifts_says_why_and_what_to_try(box_app):
    app, s, shown = box_app
    assert s.grasps and not any(g.lifted for g in s.grasps)
    ready = next(n for n in shown if n.startswith("Grasps ready"))
    info = app.grasps.panel.info.content
    for text in (ready, info):
        assert "wider than the panda opens (8 cm)" in text
        assert f"None of the {len(s.grasps)} grasps lifts the fast mesh" in text
        assert "Try the barrett hand" in text
    assert s.width is not None and s.width > 0.08
    # Were it narrow enough, more grasps and the robust ranking would be worth a try too.
    from shapeviewer.viewer.grasps.summary import plan_advice

    advice = plan_advice(dataclasses.replace(s, width=0.05))
    assert advice is not None and "wider than" not in advice
    assert "Try the barrett hand, more grasps (up to 50) or Rank by robustness" in advice


@pytest.mark.slow
def test_one_clock_per_grasp_stage_in_the_notice_and_the_panel(box_app):
    app, s, shown = box_app
    planning = f"planning {s.seconds['plan']:.1f} s"
    ready = next(n for n in shown if n.startswith("Grasps ready"))
    assert planning in ready and planning in app.grasps.panel.info.content
    with notices() as ranked:
        job = app.grasps.rank(s.segment_id)
    assert job is not None and job.error is None, job and job.error
    assert set(s.seconds) == {"plan", "rank", "wider"}  # no grasp of the box lifts: the search widened
    stages = f"planning {s.seconds['plan']:.1f} s · ranking {s.seconds['rank']:.1f} s · wider search"
    stages += f" {s.seconds['wider']:.1f} s"
    assert planning in stages  # the planning figure stays what it was
    notice = next(n for n in ranked if n.startswith("Ranked by robustness"))
    assert stages in notice and stages in app.grasps.panel.info.content
    assert f"#{N_BOX_GRASPS + 1}-#" in app.grasps.panel.info.content


def test_counts_have_the_right_plural():
    with headless_session(seed=0) as app:
        assert app.load_capture(box_capture()) and len(app.scene.segments) == 1
        assert "**1** segment," in app.panel.source.content
        done = app.complete_all()
        assert len(done) == 1
        assert "Completed 1 segment." in app.panel.status.content
        assert "segments" not in app.panel.timings.content.split("\n")[0]
