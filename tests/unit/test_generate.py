import json

import numpy as np
import pytest
import trimesh
from scipy import ndimage

from shapeviewer.cli import main
from shapeviewer.completion.voxel import GridFrame
from shapeviewer.sim import catalogue
from shapeviewer.training.generate import (
    GenerationConfig,
    generate,
    generate_object,
    orientation,
    view_noise_scale,
    view_pose,
)
from shapeviewer.training.train import load_grid_sets


def _unpack(a):
    return np.unpackbits(a, axis=1).reshape(-1, 40, 40, 40).astype(bool)


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    out = tmp_path_factory.mktemp("gen")
    cfg = GenerationConfig(views=6, seed=0)
    summary = generate(out, cfg, objects=["ycb/025_mug", "ycb/003_cracker_box"], workers=1, progress=False)
    return out, cfg, summary


def test_orientation_grid_is_the_papers_11_6_11():
    Rs = np.stack([orientation(v) for v in range(726)])
    np.testing.assert_allclose(Rs @ Rs.transpose(0, 2, 1), np.broadcast_to(np.eye(3), (726, 3, 3)), atol=1e-12)
    # 726 distinct orientations
    assert len(np.unique(np.round(Rs.reshape(726, -1), 6), axis=0)) == 726


def test_pairs_have_x_mostly_inside_y_in_the_right_frame(generated):
    out, cfg, summary = generated
    assert summary["errors"] == []
    for name in ("ycb/025_mug", "ycb/003_cracker_box"):
        with np.load(out / "shards" / (name.replace("/", "__") + ".npz")) as z:
            x, y, views, centers, sizes, T = (
                _unpack(z["x"]),
                _unpack(z["y"]),
                z["views"],
                z["center"],
                z["voxel_size"],
                z["T_cam_obj"],
            )
        assert len(views) >= 4
        assert (x.sum((1, 2, 3)) >= 100).all()  # the paper's rejection rule
        inside = (x & y).sum((1, 2, 3)) / x.sum((1, 2, 3))
        assert np.median(inside) >= 0.8
        assert (y.sum((1, 2, 3)) > 2 * x.sum((1, 2, 3))).all()  # Y adds the occluded back
        mesh = catalogue.load_mesh(name)
        mesh.apply_translation(-mesh.bounding_box.centroid)
        for i in range(len(views)):
            frame = GridFrame(centers[i], sizes[i])
            Ti = np.vstack([T[i], [0, 0, 0, 1]])
            assert np.allclose(Ti, view_pose(name, int(views[i]), cfg.seed))
            # Frame check: the true mesh's vertices, put in the camera by T_cam_obj, fall in Y.
            v = trimesh.transform_points(mesh.vertices, Ti)
            idx = frame.to_index(v)
            ok = np.all((idx >= 0) & (idx < 40), axis=1)
            # The grid is sized by the visible part, so a long object seen end-on may stick out.
            assert ok.mean() > 0.5
            assert y[i][tuple(idx[ok].T)].all()
            # and the visible surface is in front (smaller z) of the object's centre
            zs = np.argwhere(x[i])[:, 2]
            assert zs.mean() < frame.to_grid(Ti[:3, 3][None])[0, 2]


def test_rejection_rule_drops_views_with_too_few_voxels(tmp_path, monkeypatch):
    import shapeviewer.training.generate as gen

    monkeypatch.setattr(gen, "MIN_X_VOXELS", 10**6)
    r = generate_object("ycb/025_mug", tmp_path, GenerationConfig(views=3))
    assert r["kept"] == 0 and r["rejected"]["few_voxels"] == 3


def test_manifest_and_splits(generated):
    out, cfg, _ = generated
    manifest = json.loads((out / "manifest.json").read_text())
    assert {s["object"]: s["split"] for s in manifest["shards"]} == {
        "ycb/025_mug": "train",
        "ycb/003_cracker_box": "holdout_model",
    }
    sets = load_grid_sets(out)
    assert len(sets["holdout_model"]) == sum(s["views"] for s in manifest["shards"] if s["split"] == "holdout_model")
    assert set(sets["training_view"].objects) | set(sets["holdout_view"].objects) == {"ycb/025_mug"}


def test_generation_resumes_without_redoing_work(generated):
    out, cfg, _ = generated
    r = generate_object("ycb/025_mug", out, cfg)
    assert r["skipped"]


def test_soft_labels_fill_y_and_an_older_shard_gains_them_on_resume(generated, tmp_path):
    out, cfg, _ = generated
    shard = out / "shards" / "ycb__025_mug.npz"
    with np.load(shard) as z:
        arrays = dict(z)
    y = _unpack(arrays["y"])
    frac = arrays["yfrac"].reshape(y.shape)
    deep = y & ~ndimage.binary_dilation(~y, np.ones((1, 3, 3, 3)), border_value=1)
    assert np.all(frac[~y] == 0) and np.all(frac[deep] == 255)
    # The soft label is thinner than Y (its 0.5 contour lies on the surface, Y's outside it) ...
    assert 0.5 * y.sum() < (frac > 127).sum() < 0.95 * y.sum()
    # ... and a shard written before it existed gains the same label from its stored poses.
    old = tmp_path / "shards" / shard.name
    old.parent.mkdir()
    np.savez(old, **{k: v for k, v in arrays.items() if k != "yfrac"})
    assert generate_object("ycb/025_mug", tmp_path, cfg)["skipped"]
    with np.load(old) as z:
        assert np.abs(z["yfrac"].astype(int) - arrays["yfrac"]).max() <= 1


def test_split_rule_is_stable():
    assert catalogue.model_split("ycb/035_power_drill") == "holdout_model"
    assert catalogue.model_split("ycb/025_mug") == "train"
    names = [f"random/{i:03d}" for i in range(1000)]
    frac = np.mean([catalogue.model_split(n) == "holdout_model" for n in names])
    assert 0.12 < frac < 0.18
    views = [catalogue.view_split("ycb/025_mug", v) for v in range(726)]
    assert 0.15 < views.count("holdout_view") / 726 < 0.25


@pytest.mark.slow
def test_ray_backend_gives_the_same_shards(generated, tmp_path):
    ray = pytest.importorskip("ray")
    out, cfg, _ = generated
    try:
        r = generate(
            tmp_path, cfg, objects=["ycb/025_mug", "ycb/003_cracker_box"], workers=2, backend="ray", progress=False
        )
    finally:
        ray.shutdown()
    assert r["errors"] == [] and r["objects"] == 2
    for name in ("ycb__025_mug.npz", "ycb__003_cracker_box.npz"):
        with np.load(out / "shards" / name) as a, np.load(tmp_path / "shards" / name) as b:
            for k in ("x", "y", "views", "center"):
                np.testing.assert_array_equal(a[k], b[k])


def test_each_view_draws_its_depth_error_factor_from_the_range():
    cfg = GenerationConfig(noise_scale=(0.7, 3.0))
    scales = np.array([view_noise_scale("ycb/025_mug", v, cfg) for v in range(200)])
    assert (scales >= 0.7).all() and (scales <= 3.0).all() and scales.std() > 0.5  # spread over the range
    # Seeded by the view: a rerun (or a resumed generation) draws the same factors.
    assert view_noise_scale("ycb/025_mug", 7, cfg) == scales[7]
    assert view_noise_scale("ycb/025_mug", 7, GenerationConfig()) == 1.0  # the default: the sensor model as is


def test_a_reversed_or_negative_noise_range_is_refused_with_a_clear_error(tmp_path, capsys):
    for bad in ((3.0, 0.7), (-1.0, 2.0), (1.0, float("nan"))):
        with pytest.raises(ValueError, match="LO <= HI"):
            GenerationConfig(noise_scale=bad)
    out = tmp_path / "gen"
    code = main(["generate", "--out", str(out), "--objects", "ycb/025_mug", "--noise-scale", "3", "0.7"])
    assert code == 2 and "LO <= HI" in capsys.readouterr().err
    assert not out.exists()  # the folder the command would have made is not left behind


def test_a_folder_refuses_views_in_another_grid_placement(generated):
    out, cfg, _ = generated
    with pytest.raises(ValueError, match="mix two grid placements"):
        generate(out, GenerationConfig(views=6, seed=0, depth_shift=4), objects=["ycb/025_mug"], workers=1)
    assert json.loads((out / "manifest.json").read_text())["config"]["depth_shift"] == 0


def test_an_interrupted_first_run_still_guards_its_placement(tmp_path, monkeypatch):
    import shapeviewer.training.generate as gen

    def interrupted(task):
        raise KeyboardInterrupt

    out = tmp_path / "gen"
    monkeypatch.setattr(gen, "_task", interrupted)
    with pytest.raises(KeyboardInterrupt):
        generate(out, GenerationConfig(views=2, seed=0, depth_shift=4), objects=["ycb/025_mug"], workers=1)
    assert gen.folder_depth_shift(out) == 4  # recorded before the first shard
    with pytest.raises(ValueError, match="mix two grid placements"):
        generate(out, GenerationConfig(views=2, seed=0), objects=["ycb/025_mug"], workers=1)
