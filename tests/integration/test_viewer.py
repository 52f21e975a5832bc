"""The viewer without a browser: scene nodes, completion, loading errors, ray picking, export."""

from __future__ import annotations

import dataclasses
import io
import time

import numpy as np
import pytest
import trimesh

from shapeviewer.perception.camera import transform_points
from shapeviewer.viewer.rays import first_hit, project_to_pixels, ray_through
from shapeviewer.viewer.session import Session
from shapeviewer.viewer.visuals import surface_voxels

from helpers import headless_session, job_running, node


@pytest.fixture(scope="module")
def app():
    with headless_session(seed=0) as app:
        yield app


def completed_segment(app: Session) -> int:
    """Id of a segment with a fast mesh (completing the largest segment if none is yet)."""
    for sid, c in app.completions.items():
        if c.fast_mesh is not None:
            return sid
    c = app.complete(max(app.scene.segments, key=lambda s: len(app.scene.points_world[s])))
    assert c is not None and c.fast_mesh is not None
    return c.segment_id


def test_default_scene_is_drawn_in_world_frame(app):
    scene = app.scene
    assert scene is not None and scene.segments, "the default scene should have segments"
    assert node(app, "/cloud/points") is not None
    assert node(app, "/sensor") is not None
    for sid in scene.segments:
        assert node(app, f"/segments/seg_{sid}") is not None
        assert node(app, f"/segments/label_{sid}") is not None
    # World frame of a synthetic scene: the table top is z = 0 and objects stand on it.
    allp = np.concatenate(list(scene.points_world.values()))
    assert allp[:, 2].min() > -0.02
    assert np.allclose(scene.T_world_cam, scene.capture.T_world_cam)
    # Every pipeline layer has a root frame (its visibility checkbox toggles it).
    for key in ("cloud", "segments", "cnn_input", "cnn_output", "fast_mesh", "detailed_mesh", "grasps"):
        assert node(app, f"/{key}") is not None
        assert key in app.panel.layers


def test_layer_checkbox_hides_layer(app):
    box = app.panel.layers["cloud"]
    box.value = False
    assert node(app, "/cloud").visible is False
    box.value = True
    assert node(app, "/cloud").visible is True


def test_complete_segment_adds_grids_and_mesh(app):
    sid = max(app.scene.segments, key=lambda s: len(app.scene.points_world[s]))
    c = app.complete(sid)
    assert c is not None and c.segment_id == sid
    assert app.selected == sid
    for layer in ("cnn_input", "fast_mesh"):
        assert node(app, f"/{layer}/seg_{sid}") is not None, layer
    # The CNN output's layer starts hidden: its cubes are drawn once it is shown.
    assert not app.panel.layers["cnn_output"].value and node(app, f"/cnn_output/seg_{sid}") is None
    app.panel.layers["cnn_output"].value = True
    out = node(app, f"/cnn_output/seg_{sid}")
    assert out is not None and len(out.batched_positions) == len(surface_voxels(c.grid_out))
    app.panel.layers["cnn_output"].value = False
    for k in ("segmentation", "voxelize", "cnn", "marching_cubes", "send", "click_to_mesh"):
        assert app.last_timings[k] > 0, k
    assert "click → mesh" in app.panel.timings.content
    # The CNN input cubes sit on the segment's points (world frame): every occupied voxel centre is
    # within a voxel diagonal of a segment point.
    inp = node(app, f"/cnn_input/seg_{sid}")
    centres = np.asarray(inp.batched_positions)
    assert len(centres) == len(surface_voxels(c.grid_in))
    pts = app.scene.points_world[sid]
    nearest = np.min(np.linalg.norm(centres[:, None, :] - pts[None, ::7, :], axis=2), axis=1)
    assert np.median(nearest) < c.frame.voxel_size
    # The fast mesh is the camera-frame mesh mapped with T_world_cam.
    mesh = node(app, f"/fast_mesh/seg_{sid}")
    expect = transform_points(app.scene.T_world_cam, c.fast_mesh.vertices)
    assert np.allclose(np.asarray(mesh.vertices), expect, atol=1e-5)


def test_complete_all_is_one_batch(app):
    import threading

    # A spy on the network's forward pass (the real one still runs). Only the viewer's job workers'
    # calls count: the Dataset tab may be building its sample store with the same network meanwhile.
    def job_worker() -> bool:
        return threading.current_thread().name.startswith("viewer-job")

    batches: list[int] = []
    hook = app.res.completer.net.register_forward_hook(
        lambda _net, args, _out: batches.append(len(args[0])) if job_worker() else None
    )
    try:
        done = app.complete_all()
    finally:
        hook.remove()
    assert {c.segment_id for c in done} <= set(app.scene.segments)
    assert len(done) >= 2, "the default scene has several objects to complete"
    # The 8 mirrored views of every segment, in as few passes as the network's batch allows.
    n = 8 * len(done)
    expected = [min(app.res.completer.batch_size, n - i) for i in range(0, n, app.res.completer.batch_size)]
    assert batches == expected, f"expected passes {expected} over {len(done)} segments, got batches {batches}"
    for c in done:
        assert node(app, f"/cnn_input/seg_{c.segment_id}") is not None
    assert "All" in app.panel.timings.content


def test_a_full_job_queue_answers_at_once_and_the_queue_drains(app):
    """While a job runs, two more may wait; the next is refused at once with a message."""
    import threading

    sid = next(iter(app.scene.segments))
    results: list = []
    waiting = []
    with job_running(app, timeout=30):
        for _ in range(app.jobs.max_waiting):
            t = threading.Thread(target=lambda: results.append(app.complete(sid)))
            t.start()
            waiting.append(t)
        time.sleep(0.3)
        app.last_error = None
        t0 = time.perf_counter()
        assert app.complete(sid) is None  # the queue is full: refused without waiting
        assert time.perf_counter() - t0 < 5
        assert app.panel.complete.disabled  # the running job holds the buttons
    for t in waiting:
        t.join(60)
    assert len(results) == app.jobs.max_waiting and all(c is not None for c in results)
    assert not app.jobs.busy and not app.panel.complete.disabled


def test_bad_cloud_keeps_the_scene(app, tmp_path):
    before = app.scene
    assert app.load_cloud(tmp_path / "missing.pcd") is False
    assert "missing.pcd" in app.last_error
    corrupt = tmp_path / "corrupt.pcd"
    corrupt.write_bytes(b"# .PCD v0.7\nFIELDS x y z\nthis is not a point cloud\n")
    app.last_error = None
    assert app.load_cloud(corrupt) is False
    assert app.last_error and "corrupt.pcd" in app.last_error
    assert app.scene is before
    for sid in before.segments:
        assert node(app, f"/segments/seg_{sid}") is not None


def test_pick_ray_through_each_segment_centroid(app):
    scene = app.scene
    sensor = scene.T_world_cam[:3, 3]
    for sid in scene.segments:
        origin, direction = ray_through(sensor, app.segment_centroid_world(sid))
        assert app.pick(origin, direction) == sid
    # Straight up from above the objects: nothing there.
    top = np.concatenate(list(scene.points_world.values())).max(axis=0) + 0.1
    assert app.pick(top, np.array([0.0, 0.0, 1.0])) is None
    # Towards the empty table far from every object.
    far = np.concatenate(list(scene.points_world.values())).mean(axis=0) + np.array([3.0, 3.0, -0.1])
    assert app.pick(*ray_through(sensor, far)) is None


def test_pick_prefers_the_nearest_segment():
    rng = np.random.default_rng(0)
    blob = rng.normal(0, 0.02, (500, 3))
    segments = {7: blob + [0, 0, 1.0], 3: blob + [0, 0, 2.0]}
    key, t = first_hit([0, 0, 0], [0, 0, 1], segments)
    assert key == 7 and 0.9 < t < 1.0  # metres along the ray to the blob's near side
    assert first_hit([0, 0, 3], [0, 0, -1], segments)[0] == 3
    assert first_hit([0, 0, 0], [0, 0, -1], segments) == (None, np.inf)  # both behind the origin
    assert first_hit([0.5, 0, 0], [0, 0, 1], segments) == (None, np.inf)


def test_projection_matches_a_ray():
    # A camera at (0, -1, 0.5) looking at the origin (OpenCV axes: x right, y down, z forward).
    from shapeviewer.perception.camera import look_at

    T = look_at([0, -1, 0.5], [0, 0, 0])
    p = np.array([[0.0, 0.0, 0.0], [0.1, 0.05, 0.02]])
    uv = project_to_pixels(p, T[:3, 3], T[:3, :3], fov=np.radians(60), width=800, height=600)
    assert np.allclose(uv[0], [400, 300])
    f = 300 / np.tan(np.radians(30))
    ray_cam = np.array([(uv[1, 0] - 400) / f, (uv[1, 1] - 300) / f, 1.0])
    _, d = ray_through(T[:3, 3], p[1])
    assert np.allclose(T[:3, :3] @ ray_cam / np.linalg.norm(ray_cam), d, atol=1e-9)


@pytest.mark.parametrize("fmt", ["ply", "obj", "stl", "glb"])
def test_export_mesh_formats(app, fmt):
    sid = completed_segment(app)
    for frame in ("world", "camera"):
        name, data = app.export_bytes("mesh", sid, fmt, frame)
        assert name.endswith(f".{fmt}") and frame in name
        loaded = trimesh.load(io.BytesIO(data), file_type=fmt, force="mesh")
        assert len(loaded.faces) == len(app.completions[sid].fast_mesh.faces)


def test_export_points_and_grids(app):
    sid = completed_segment(app)
    name, data = app.export_bytes("points", sid, frame="world")
    assert name.endswith(".ply") and len(trimesh.load(io.BytesIO(data), file_type="ply").vertices) > 0
    name, data = app.export_bytes("grids", sid)
    with np.load(io.BytesIO(data)) as z:
        assert z["grid_in"].shape == (40, 40, 40) and z["probabilities"].dtype == np.float32
        assert z["grid_to_camera"].shape == (4, 4)
    with pytest.raises(ValueError, match="Select a segment"):
        app.export_bytes("points", 10_000)


def test_tiny_segment_gives_a_clear_error(app):
    seg = app.scene.segments[next(iter(app.scene.segments))]
    full = seg.points_cam
    seg.points_cam = full[:10]
    try:
        app.last_error = None
        assert app.complete(seg.id) is None
        assert "valid points" in app.last_error
    finally:
        seg.points_cam = full


def test_real_capture_is_drawn_on_its_table_plane(real_data):
    with headless_session(cloud=real_data / "milk_cartoon_all_small_clorox.pcd") as app:
        scene = app.scene
        assert scene.title == "milk_cartoon_all_small_clorox.pcd"
        assert np.allclose(scene.T_world_cam, scene.segmentation.T_world_cam)
        # The table-aligned world frame puts the floor at z = 0 and the objects above it.
        table = transform_points(scene.T_world_cam, scene.capture.flat_points()[scene.segmentation.table_indices])
        assert abs(np.median(table[:, 2])) < 0.01
        for sid, pts in scene.points_world.items():
            assert np.median(pts[:, 2]) > 0, sid
            assert node(app, f"/segments/seg_{sid}") is not None
        sid = max(scene.segments, key=lambda s: len(scene.points_world[s]))
        assert app.complete(sid) is not None
        assert node(app, f"/fast_mesh/seg_{sid}") is not None


def test_unorganized_cloud_without_colours_uses_depth_colours(real_data):
    with headless_session(cloud=real_data / "milk.pcd") as app:
        assert app.scene.capture.colors is None
        assert app.panel.cloud_colors.value == "depth"
        assert len(node(app, "/cloud/points").points) == int(app.scene.capture.valid_mask().sum())


def test_model_panel_says_whether_weights_are_trained(app):
    from shapeviewer.viewer.panel import model_markdown

    warning = "Untrained weights: completions are not meaningful"
    assert warning in model_markdown("unet3d", "untrained", False, {})
    shown = model_markdown("unet3d", "unet3d.pt", True, {"steps": 1000, "eval": {"holdout_view": {"jaccard": 0.74}}})
    assert warning not in shown and "1,000 training steps" in shown and "holdout view 0.74" in shown
    averaged = model_markdown("unet3d", "unet3d.pt", True, {"steps": 3000, "averaged_from": ["a.pt", "b.pt"]})
    assert "the mean of 2 weights files" in averaged
    assert (warning in app.panel.model.content) == (not app.res.completer.trained)


def test_detailed_mesh_is_drawn_stored_timed_and_exported(app):
    sid = completed_segment(app)
    mesh = app.compute_mesh("detailed", sid)
    result = app.results[sid]
    assert mesh is not None and app.mesh("detailed", sid) is mesh and mesh.is_watertight
    assert result.mesh("detailed") is mesh and result.seconds["detailed"] > 0
    # Drawn in the world frame like the fast mesh, and its layer is switched on.
    drawn = node(app, f"/detailed_mesh/seg_{sid}")
    assert np.allclose(np.asarray(drawn.vertices), transform_points(app.scene.T_world_cam, mesh.vertices), atol=1e-5)
    assert app.panel.layers["detailed_mesh"].value and node(app, "/detailed_mesh").visible
    # The timings table splits the time by Algorithm 1's steps.
    steps = result.detailed_steps
    for key in ("density", "upsample", "merge", "fill_gaps", "smooth", "marching_cubes"):
        assert steps[key] >= 0, key
    assert "detailed mesh" in app.panel.timings.content and "fill gaps" in app.panel.timings.content
    name, data = app.export_bytes("mesh", sid, "ply", "world", mesh="detailed")
    assert name.endswith("_detailed_world.ply") and data
    assert len(trimesh.load(io.BytesIO(data), file_type="ply", force="mesh").faces) == len(mesh.faces)


def test_baselines_complete_the_segment_first_and_get_their_own_layers(app):
    sid = completed_segment(app)
    app.results.pop(sid)
    for kind in ("partial", "mirror"):
        mesh = app.compute_mesh(kind, sid)
        assert mesh is not None and app.mesh(kind, sid) is mesh
        assert node(app, f"/{kind}_mesh/seg_{sid}") is not None
        assert app.panel.layers[f"{kind}_mesh"].value
    assert app.completions[sid].fast_mesh is not None
    # A new completion of the segment has no baselines yet: their stale nodes go too, and the
    # completion itself is never written to (the meshes are the viewer's, beside it).
    old = app.completions[sid]
    app.complete(sid)
    assert node(app, f"/partial_mesh/seg_{sid}") is None and app.mesh("partial", sid) is None
    assert app.completions[sid] is not old
    with pytest.raises(dataclasses.FrozenInstanceError):
        old.fast_mesh = None  # type: ignore[misc]
    with pytest.raises(ValueError, match="no mirror baseline yet"):
        app.export_bytes("mesh", sid, mesh="mirror")


def test_mirror_needs_a_support_plane(app, monkeypatch):
    sid = completed_segment(app)
    monkeypatch.setattr(app.scene.segmentation, "plane_cam", None)
    app.last_error = None
    assert app.compute_mesh("mirror", sid) is None
    assert "support plane" in app.last_error
    assert not app.panel.mirror.disabled


def test_confidence_layer_shades_the_output_by_the_samples_spread(app):
    sid = completed_segment(app)
    c = app.completions[sid]
    box = app.panel.layers["confidence"]
    box.value = True  # the checkbox's handler draws the samples' spread of every completion
    try:
        from shapeviewer.viewer.visuals import SPREAD_FULL_SCALE, spread_colors

        assert c.samples is not None and c.samples.shape == (8, 40, 40, 40)
        handle = node(app, f"/confidence/seg_{sid}")
        assert handle is not None and node(app, "/confidence").visible
        colours = np.asarray(handle.batched_colors)
        # Seen voxels are pale and guessed ones dark: the layer is not one flat colour.
        assert len(np.unique(colours, axis=0)) > 3
        pale, dark = spread_colors(np.array([0.0, SPREAD_FULL_SCALE])).astype(int)
        assert pale.sum() > 600 and dark.sum() < 250  # agreeing samples pale, a guess dark
        assert "unseen side" in app.panel.timings.content and "guess" in app.panel.timings.content
        # A new completion of the segment is drawn with its confidence while the layer is on.
        again = app.complete(sid)
        assert again.samples is not None
    finally:
        box.value = False
    assert node(app, "/confidence").visible is False


def test_revolve_on_table_fits_an_axis_and_says_so(app):
    """With "Revolve on table" ticked, a completion carries the fitted axis, and the Confidence layer
    says whether its answers were revolved; unticked, none is fitted."""
    sid = completed_segment(app)
    assert app.completions[sid].axis is None  # off by default
    app.panel.revolve.value = True
    box = app.panel.layers["confidence"]
    try:
        c = app.complete(sid)
        assert c is not None and c.axis is not None and c.timings["priors"] > 0
        box.value = True
        text = app.panel.timings.content
        assert "Surface of revolution" in text
        assert ("revolved about the table's normal" in text) == c.revolved
    finally:
        box.value = False
        app.panel.revolve.value = False
    assert app.complete(sid).axis is None


def test_fit_boxes_on_table_fits_a_box_and_says_so(app):
    """With "Fit boxes on table" ticked (the default), a completion carries the box fitted to its
    segment, and the Confidence layer says whether it was completed as that box; unticked, none is
    fitted."""
    sid = completed_segment(app)
    assert app.panel.fit_boxes.value and app.completions[sid].cuboid is not None  # on by default
    layer = app.panel.layers["confidence"]
    try:
        c = app.complete(sid)
        assert c is not None and c.cuboid is not None
        layer.value = True
        text = app.panel.timings.content
        assert "Box:" in text and ("completed as the fitted box" in text) == c.boxed
        app.panel.fit_boxes.value = False
        assert app.complete(sid).cuboid is None
    finally:
        layer.value = False
        app.panel.fit_boxes.value = True


def test_sample_slider_steps_through_the_sample_completions(app):
    """Sample k is the marching cubes of the k-th sample completion, drawn in the Confidence layer
    beside the completion (which stays as it was); 0 removes it."""
    sid = completed_segment(app)
    app.complete(sid)  # selected, slider back at 0
    c = app.completions[sid]
    assert app.panel.sample.value == 0 and node(app, f"/confidence/sample_seg_{sid}") is None
    meshes = [app.show_sample(k) for k in (1, 5)]
    assert c.samples is not None and c.samples.shape == (8, 40, 40, 40)
    for m in meshes:
        assert m is not None and m.is_watertight
        # A sample is a plausible completion of the same object: about the size of the fast mesh.
        assert np.allclose(m.bounds, c.fast_mesh.bounds, atol=4 * c.frame.voxel_size)
    # Sample 1 is the network's answer for the view as seen, the others for the view mirrored;
    # the completion is their mean, none of them.
    assert not np.array_equal(meshes[0].vertices, meshes[1].vertices)
    assert not any(np.array_equal(m.vertices, c.fast_mesh.vertices) for m in meshes)
    assert node(app, f"/confidence/sample_seg_{sid}") is not None
    assert app.panel.layers["confidence"].value and node(app, "/confidence").visible
    assert "Sample completion **5** of 8" in app.panel.status.content
    assert node(app, f"/fast_mesh/seg_{sid}") is not None  # the completion itself is still there
    assert app.show_sample(0) is None and node(app, f"/confidence/sample_seg_{sid}") is None
    with pytest.raises(ValueError, match="out of range"):
        app.show_sample(9)
