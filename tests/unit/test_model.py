import numpy as np
import pytest
import torch

from shapeviewer.completion.model import WeightsError, build, load_completer, save_weights


def _box_grid():
    g = np.zeros((40, 40, 40), bool)
    g[12:28, 12:28, 14:18] = True
    return g


def test_completer_predicts_probabilities_single_and_batched(tmp_path):
    torch.manual_seed(0)
    path = tmp_path / "w.pt"
    save_weights(path, build("unet3d"), "unet3d", {"steps": 1})
    c = load_completer(path)
    assert c.trained and c.arch == "unet3d"
    one = c.predict(_box_grid())
    assert one.shape == (40, 40, 40) and one.dtype == np.float32
    assert 0 <= one.min() and one.max() <= 1
    batch = c.predict(np.stack([_box_grid(), np.zeros((40, 40, 40), bool), _box_grid()]))
    assert batch.shape == (3, 40, 40, 40)
    # Batching does not change the answer.
    np.testing.assert_allclose(batch[0], one, atol=1e-5)
    np.testing.assert_allclose(batch[2], one, atol=1e-5)
    with pytest.raises(ValueError, match="40,40,40"):
        c.predict(np.zeros((32, 32, 32), bool))


def test_weights_round_trip_exactly(tmp_path):
    torch.manual_seed(1)
    net = build("unet3d").eval()
    path = tmp_path / "w.pt"
    save_weights(path, net, "unet3d", {"steps": 5})
    x = torch.from_numpy(_box_grid()[None, None].astype(np.float32))
    with torch.no_grad():
        ref = torch.sigmoid(net(x))[0, 0].numpy()
    np.testing.assert_allclose(load_completer(path).predict(_box_grid()), ref, atol=1e-5)


def test_missing_or_corrupt_weights_are_clear_errors(tmp_path):
    with pytest.raises(WeightsError, match="not found"):
        load_completer(tmp_path / "nope.pt")
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"this is not a torch file")
    with pytest.raises(WeightsError, match="cannot load"):
        load_completer(bad)
    # A pickle that is not tensors (here random bytes torch reads as one): refused, and the message
    # never advises loading it with weights_only=False (which would run the file's code).
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(np.random.default_rng(0).integers(0, 256, 1000, dtype=np.uint8).tobytes())
    with pytest.raises(WeightsError) as refused:
        load_completer(garbage)
    assert "weights_only=False" not in str(refused.value) and "torch.load" in str(refused.value)
    assert refused.value.__cause__ is None and refused.value.__suppress_context__


@pytest.mark.slow
def test_varley2017_is_the_papers_network_and_trains_on_cpu():
    torch.manual_seed(0)
    net = build("varley2017")
    n = sum(p.numel() for p in net.parameters())
    assert 425e6 < n < 435e6  # "about 430 million parameters"
    assert net.dense1.in_features == 21952 and net.dense1.out_features == 5000
    assert net.dense2.out_features == 64000
    x = torch.from_numpy(_box_grid()[None, None].astype(np.float32))
    out = net(x)
    assert out.shape == (1, 1, 40, 40, 40)
    out.sigmoid().mean().backward()
    assert net.features[0].weight.grad is not None and torch.isfinite(net.features[0].weight.grad).all()


def test_completion_samples_agree_where_the_camera_looked_and_differ_behind():
    from scipy import ndimage

    from shapeviewer.completion.model import sample_spread
    from shapeviewer.completion.voxel import context_grids, partial_to_grid
    from shapeviewer.sim.tabletop import render_tabletop_view

    c = load_completer()
    v = render_tabletop_view("ycb/025_mug", 5, seed=3)
    grid, frame = partial_to_grid(v.points_cam, depth_shift=c.depth_shift)
    ctx = context_grids(v.points_cam, frame, support_plane=v.plane_cam)
    samples = c.predict_samples(grid, 8, context=ctx)
    assert samples.shape == (8, 40, 40, 40) and samples.dtype == np.float32
    assert np.array_equal(samples[0], c.predict(grid, context=ctx))  # sample 0 is the best estimate
    assert not (samples[:, ctx.any(axis=0)] > 0).any()  # no sample fills known-empty space
    # Over a few views of the mug, the samples spread less where the camera looked than behind.
    seen_side, unseen_side = [], []
    for view in (5, 6, 7):
        w = render_tabletop_view("ycb/025_mug", view, seed=3)
        g, f = partial_to_grid(w.points_cam, depth_shift=c.depth_shift)
        s = c.predict_samples(g, 8, context=context_grids(w.points_cam, f, support_plane=w.plane_cam))
        spread = sample_spread(s)
        active = (s > 0.05).any(axis=0)
        seen = ndimage.binary_dilation(g) & active
        assert spread.max() > 0.1
        seen_side.append(spread[seen].mean())
        unseen_side.append(spread[active & ~seen].mean())
    assert np.mean(seen_side) < np.mean(unseen_side)
    batch = c.predict_samples(np.stack([grid, grid]), 3, context=np.stack([ctx, ctx]))
    assert batch.shape == (3, 2, 40, 40, 40) and np.allclose(batch[:, 0], samples[:3], atol=1e-6)
    with pytest.raises(ValueError, match="between 1 and 8"):
        c.predict_samples(grid, 9)


def test_sample_spread_counts_disagreement_about_occupancy_not_about_probability():
    """Two samples that decide differently at the spread's level (0.3 and 0.5 about 0.4) are less
    sure of a voxel than two that both call it empty (0.05 and 0.25), though their probabilities
    differ as much; full agreement is no spread, an even split the most."""
    from shapeviewer.completion.model import SPREAD_LEVEL, sample_spread

    assert SPREAD_LEVEL == 0.4
    samples = np.array([[0.3, 0.05, 0.9, 0.0], [0.5, 0.25, 0.9, 1.0]], dtype=np.float32)
    split, agree, same, opposite = sample_spread(samples)
    assert split > 2 * agree and same == 0.0 and opposite == pytest.approx(0.5)
    assert sample_spread(samples[:, None]).shape == (1, 4)
    # At the label's surface (0.5) instead, 0.45 and 0.55 split; 0.3 and 0.5 about 0.4 do not.
    at_half = sample_spread(np.array([[0.45], [0.55]]), level=0.5)[0]
    assert at_half > sample_spread(np.array([[0.45], [0.55]]))[0]


def test_a_network_is_meshed_at_the_level_of_the_label_it_learnt(tmp_path):
    from shapeviewer.completion.pipeline import complete_points
    from shapeviewer.completion.reconstruct import MESH_LEVEL

    # The shipped network, saved as if trained on Y and as if trained on the soft label (whose 0.5
    # contour is the surface).
    blob = torch.load(load_completer().source, weights_only=True)
    meta = {k: v for k, v in blob["meta"].items() if k != "mesh_level"}
    net = build(blob["arch"], **meta.get("arch_kwargs", {}))
    net.load_state_dict(blob["state_dict"])
    save_weights(tmp_path / "hard.pt", net, blob["arch"], {**meta, "label": "solid"})
    save_weights(tmp_path / "soft.pt", net, blob["arch"], {**meta, "label": "fraction"})
    shipped, soft = load_completer(tmp_path / "hard.pt"), load_completer(tmp_path / "soft.pt")
    assert shipped.mesh_level == MESH_LEVEL and soft.mesh_level == 0.5
    rng = np.random.default_rng(0)
    u, v = rng.uniform(-1, 1, (2, 4000))
    points = np.stack([0.04 * u, 0.04 * v, 0.8 - 0.04 * np.sqrt(np.clip(1 - u**2 - v**2, 0, 1))], axis=1)
    points = points[u**2 + v**2 < 1]
    (a,) = complete_points([points], shipped)
    (b,) = complete_points([points], soft)
    assert b.mesh_level == 0.5 and np.array_equal(a.probabilities, b.probabilities)
    # Meshed lower, the same answer gives a larger solid: the level reaches the mesh.
    assert b.fast_mesh.volume > a.fast_mesh.volume
