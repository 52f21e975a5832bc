import csv

import numpy as np
import pytest
import torch

from shapeviewer.completion.model import load_completer
from shapeviewer.training.generate import GenerationConfig, generate
from shapeviewer.training.train import (
    PLANE_DROPOUT,
    TrainConfig,
    augment,
    bce_loss,
    evaluate_grids,
    jaccard_grids,
    load_grid_sets,
    soft_jaccard_loss,
    train,
    warm_start,
)


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    out = tmp_path_factory.mktemp("data")
    generate(
        out,
        # In the shipped network's grid placement, so it can be scored on these views.
        GenerationConfig(views=8, seed=1, depth_shift=load_completer().depth_shift),
        objects=["ycb/025_mug", "ycb/006_mustard_bottle", "random/001"],
        workers=1,
        progress=False,
    )
    return out


@pytest.mark.slow
def test_a_few_training_steps_lower_the_loss_and_checkpoints_round_trip(tiny_data, tmp_path):
    run = tmp_path / "run"
    cfg = TrainConfig(
        steps=12, batch_size=4, lr=1e-3, eval_every=6, eval_views=8, checkpoint_every=6, jaccard_weight=1000.0
    )
    train(tiny_data, run, cfg, progress=False)
    rows = list(csv.DictReader(open(run / "log.csv")))
    assert [int(r["step"]) for r in rows] == [6, 12]
    assert float(rows[1]["loss"]) < float(rows[0]["loss"])
    assert (run / "jaccard.png").stat().st_size > 1000
    # Resuming continues from the checkpoint instead of starting again.
    train(tiny_data, run, TrainConfig(**{**cfg.__dict__, "steps": 18}), progress=False)
    rows = list(csv.DictReader(open(run / "log.csv")))
    assert [int(r["step"]) for r in rows] == [6, 12, 18]
    # Saved weights load for inference and give the same answer as the training network.
    c = load_completer(run / "best_loss.pt")
    assert c.trained and c.meta["steps"] in (6, 12, 18)
    sets = load_grid_sets(tiny_data)
    r = evaluate_grids(c, sets, max_views=4)
    assert set(r) >= {"holdout_model"}


def test_training_on_the_soft_label_and_a_clear_error_for_shards_without_it(tiny_data, tmp_path):
    run = tmp_path / "run"
    cfg = TrainConfig(steps=4, batch_size=4, lr=1e-3, eval_every=4, eval_views=8, label="fraction", snapshot_every=2)
    r = train(tiny_data, run, cfg, progress=False)
    assert load_completer(run / "best_loss.pt").meta["label"] == "fraction"
    # Snapshots along the way, for a stochastic weight average: they differ, and the last is the final network.
    assert sorted(p.name for p in run.glob("step_*.pt")) == ["step_000002.pt", "step_000004.pt"]
    snaps = [torch.load(run / f"step_00000{k}.pt", weights_only=True)["state_dict"] for k in (2, 4)]
    final = torch.load(run / "last.pt", weights_only=True)["state_dict"]
    assert not torch.equal(snaps[0]["head.weight"], snaps[1]["head.weight"])
    assert all(torch.equal(snaps[1][k], final[k]) for k in final)
    assert 0 <= r["holdout_model"]["jaccard"] <= 1
    sets = load_grid_sets(tiny_data)
    t = sets["training_view"].targets(np.arange(4), "fraction")
    assert t.dtype == np.float32 and 0 < t.mean() < sets["training_view"].targets(np.arange(4), "solid").mean()
    # Shards from before the soft label: training on it stops at once and says what to run.
    old = tmp_path / "old"
    (old / "shards").mkdir(parents=True)
    for shard in (tiny_data / "shards").glob("*.npz"):
        with np.load(shard) as z:
            np.savez(old / "shards" / shard.name, **{k: v for k, v in z.items() if k != "yfrac"})
    with pytest.raises(ValueError, match="no soft label.*shapeviewer generate"):
        train(old, tmp_path / "run2", cfg, progress=False)


def test_augmentation_keeps_pairs_and_context_aligned():
    rng = np.random.default_rng(0)
    x = rng.random((64, 40, 40, 40)) < 0.1
    y = x | (rng.random((64, 40, 40, 40)) < 0.1)
    # The context marks known-empty space: wherever Y is empty, so it never meets Y.
    ctx = np.stack([~y & (rng.random(y.shape) < 0.5), ~y & (rng.random(y.shape) < 0.5)], axis=1)
    hidden = 0
    for seed in range(8):
        xa, ya, ca = augment(x, y, ctx, np.random.default_rng(seed))
        assert xa.sum() == x.sum() and (xa & ~ya).sum() == 0
        assert ca[:, 0].sum() == ctx[:, 0].sum() and not (ca & ya[:, None]).any()
        hidden += int((ca[:, 1].reshape(64, -1).sum(1) == 0).sum())
    assert 0.1 < hidden / (8 * 64) < 0.3  # the support plane is hidden in about PLANE_DROPOUT of them
    assert PLANE_DROPOUT == 0.2


def test_warm_start_widens_a_one_channel_network_without_changing_it():
    from shapeviewer.completion.model import UNet3D, network_input

    torch.manual_seed(0)
    old = UNet3D(in_channels=1)
    path = tmp = __import__("tempfile").mkdtemp() + "/old.pt"
    torch.save({"arch": "unet3d", "state_dict": old.state_dict(), "meta": {}}, tmp)
    new = UNet3D(in_channels=3)
    warm_start(new, path)
    x = np.random.default_rng(0).random((2, 40, 40, 40)) < 0.2
    ctx = np.random.default_rng(1).random((2, 2, 40, 40, 40)) < 0.2
    with torch.no_grad():
        a = old(network_input(x, None, 1))
        b = new(network_input(x, ctx, 3))
    assert torch.allclose(a, b, atol=1e-5)


def test_warm_start_widens_a_narrow_network_and_its_new_units_learn(tmp_path):
    from shapeviewer.completion.model import UNet3D, network_input

    torch.manual_seed(0)
    old = UNet3D(width=8, in_channels=3)
    torch.save({"arch": "unet3d", "state_dict": old.state_dict(), "meta": {}}, tmp_path / "old.pt")
    new = UNet3D(width=12, in_channels=3)
    warm_start(new, tmp_path / "old.pt")
    x = network_input(np.random.default_rng(0).random((2, 40, 40, 40)) < 0.2, None, 3)
    with torch.no_grad():
        assert torch.allclose(old(x), new(x), atol=1e-5)
    bce_loss(new(x), torch.ones(2, 1, 40, 40, 40)).backward()
    grad = new.dec1[0].weight.grad
    assert grad is not None and grad[:8, 8:].abs().sum() > 0  # old units learn to read the new ones
    with pytest.raises(ValueError, match="larger than"):
        warm_start(UNet3D(width=4, in_channels=3), tmp_path / "old.pt")


def test_loss_is_the_papers_summed_bce():
    logits = torch.zeros(2, 1, 40, 40, 40)
    target = torch.ones(2, 1, 40, 40, 40)
    assert bce_loss(logits, target).item() == pytest.approx(64000 * np.log(2), rel=1e-5)


def test_soft_jaccard_loss_weighs_a_thin_shell_as_much_as_a_large_solid():
    big, thin = torch.zeros(1, 1, 40, 40, 40), torch.zeros(1, 1, 40, 40, 40)
    big[..., 5:35, 5:35, 5:35] = 1
    thin[..., 10:30, 10:30, 10] = 1
    sure = lambda t: (t * 2 - 1) * 20  # noqa: E731  logits of a confident, exact answer
    assert soft_jaccard_loss(sure(big), big).item() == pytest.approx(0.0, abs=1e-6)
    # Missing half of each object costs both the same: half their Jaccard.
    half_big, half_thin = big.clone(), thin.clone()
    half_big[..., 5:20, :, :] = 0
    half_thin[..., 10:20, :, :] = 0
    assert soft_jaccard_loss(sure(half_big), big).item() == pytest.approx(0.5, abs=1e-3)
    assert soft_jaccard_loss(sure(half_thin), thin).item() == pytest.approx(0.5, abs=1e-3)
    # The summed cross-entropy charges the large solid 67 times as much for the same share missed.
    assert bce_loss(sure(half_big), big).item() > 60 * bce_loss(sure(half_thin), thin).item()


def test_jaccard_of_grids():
    a = np.zeros((1, 40, 40, 40), bool)
    b = a.copy()
    a[0, :10] = True
    b[0, 5:15] = True
    assert jaccard_grids(a, b)[0] == pytest.approx(5 / 15)


def test_a_network_keeps_the_grid_placement_of_its_data(tiny_data, tmp_path, capsys):
    other = 4.0 if load_completer().depth_shift == 0 else 0.0
    moved = tmp_path / "moved"
    generate(
        moved, GenerationConfig(views=4, seed=1, depth_shift=other), objects=["ycb/025_mug"], workers=1, progress=False
    )
    cfg = TrainConfig(steps=2, batch_size=2, eval_every=2, eval_views=2)
    with pytest.raises(ValueError, match="different grid placements"):
        train([tiny_data, moved], tmp_path / "mixed", cfg, progress=False)
    train(moved, tmp_path / "run", cfg, progress=False)
    c = load_completer(tmp_path / "run" / "best_loss.pt")
    assert c.depth_shift == other
    # Scoring it on views in another placement is refused with the command that fixes it.
    from shapeviewer.cli import main

    assert main(["evaluate-grids", "--data", str(tiny_data), "--weights", str(tmp_path / "run" / "best_loss.pt")]) != 0
    assert f"generate --depth-shift {other:g}" in capsys.readouterr().err


def test_shipped_weights_beat_the_input_alone(tiny_data):
    c = load_completer()
    if not c.trained:
        pytest.fail("static_assets/weights/unet3d.pt is missing: the app would run untrained")
    r = evaluate_grids(c, load_grid_sets(tiny_data), max_views=20)
    assert r["holdout_model"]["views"] >= 4  # the mustard bottle is a holdout model
    for s, v in r.items():
        assert v["jaccard"] > v["input_jaccard"] + 0.2, s


def test_the_output_grid_is_the_best_estimate_of_the_papers_y(tiny_data):
    """Scored as the paper scores it (against Y, every voxel the object touches), the output grid at
    the network's grid level beats the same answers cut at 0.5, where the soft label puts the surface."""
    c = load_completer()
    sets = load_grid_sets(tiny_data)

    def pooled(level: float) -> float:  # over the 24 views of the three sets
        r = evaluate_grids(c, sets, max_views=30, level=level)
        return sum(v["jaccard"] * v["views"] for v in r.values()) / sum(v["views"] for v in r.values())

    assert pooled(c.grid_level) > pooled(0.5) + 0.03


def test_evaluate_grids_by_shape_kind(tiny_data, capsys):
    from shapeviewer.cli import main

    r = evaluate_grids(load_completer(), load_grid_sets(tiny_data), max_views=50)
    for v in r.values():  # every view counted once, under its object's kind
        assert sum(k["views"] for k in v["by_kind"].values()) == v["views"]
        assert (
            min(k["jaccard"] for k in v["by_kind"].values())
            <= v["jaccard"]
            <= max(k["jaccard"] for k in v["by_kind"].values())
        )
    assert set(r["training_view"]["by_kind"]) == {"mug", "random"}  # the mustard bottle is a holdout model
    # The command line keeps the kinds asked for and prints a row per kind.
    assert main(["evaluate-grids", "--data", str(tiny_data), "--views", "50", "--kinds", "mug", "--by-kind"]) == 0
    out = capsys.readouterr().out
    rows = {line.split()[0] for line in out.splitlines()[1:] if line.strip()}
    assert "mug" in rows and not rows & {"bottle", "random"}
    assert main(["evaluate-grids", "--data", str(tiny_data), "--kinds", "teapot"]) != 0
    assert "no views of kinds teapot" in capsys.readouterr().err


@pytest.mark.slow
def test_evaluate_grids_scores_the_mean_of_the_mirrored_answers(tiny_data, capsys):
    """``samples=8`` scores the occupancy the detailed mesh meshes (the mean of the 8 mirrored
    answers), view by view, and it completes these views at least as well as the single answer."""
    from shapeviewer.cli import main

    c = load_completer()
    sets = load_grid_sets(tiny_data)
    gs = sets["training_view"]
    x, _, ctx = gs.grids(np.arange(len(gs)))
    mean = c.predict_samples(x, 8, context=ctx).mean(axis=0)
    expected = jaccard_grids(mean > c.grid_level, gs.truth(np.arange(len(gs)), "solid")).mean()
    r8 = evaluate_grids(c, sets, max_views=50, level=c.grid_level, samples=8)
    r1 = evaluate_grids(c, sets, max_views=50, level=c.grid_level)
    assert r8["training_view"]["jaccard"] == pytest.approx(expected)
    assert r8["training_view"]["jaccard"] != r1["training_view"]["jaccard"]
    views = sum(v["views"] for v in r1.values())
    assert (
        sum(v["jaccard"] * v["views"] for v in r8.values()) / views
        >= sum(v["jaccard"] * v["views"] for v in r1.values()) / views - 0.01
    )
    assert main(["evaluate-grids", "--data", str(tiny_data), "--samples", "8"]) == 0
    assert "mean of 8 mirrored answers" in capsys.readouterr().out


def test_averaged_weights_are_the_mean_of_the_networks_and_load(tmp_path, capsys):
    from shapeviewer.cli import main
    from shapeviewer.completion.model import build, save_weights
    from shapeviewer.training.averaging import average_weights

    nets = []
    for seed in (0, 1):
        torch.manual_seed(seed)
        nets.append(build("unet3d"))
        save_weights(tmp_path / f"{seed}.pt", nets[-1], "unet3d", {"label": "fraction", "steps": seed + 1, "eval": {}})
    assert main(["average", str(tmp_path / "0.pt"), str(tmp_path / "1.pt"), "--out", str(tmp_path / "m.pt")]) == 0
    c = load_completer(tmp_path / "m.pt")
    assert c.meta["averaged_from"] == ["0.pt", "1.pt"] and c.meta["label"] == "fraction" and "eval" not in c.meta
    mean = torch.load(tmp_path / "m.pt", weights_only=True)["state_dict"]
    for k, v in nets[0].state_dict().items():
        if v.is_floating_point():
            torch.testing.assert_close(mean[k], (v + nets[1].state_dict()[k]) / 2)
    # A network of another width cannot be averaged with these, and one file is not an average.
    save_weights(tmp_path / "wide.pt", build("unet3d", width=24), "unet3d", {})
    with pytest.raises(ValueError, match="not the same network"):
        average_weights([tmp_path / "0.pt", tmp_path / "wide.pt"], tmp_path / "x.pt")
    # Nor can a network trained in another grid placement (generate --depth-shift).
    save_weights(tmp_path / "moved.pt", nets[1], "unet3d", {"label": "fraction", "depth_shift": 4.0})
    with pytest.raises(ValueError, match="voxels forward"):
        average_weights([tmp_path / "0.pt", tmp_path / "moved.pt"], tmp_path / "x.pt")
    assert main(["average", str(tmp_path / "0.pt"), "--out", str(tmp_path / "x.pt")]) != 0
    assert "at least two" in capsys.readouterr().err and not (tmp_path / "x.pt").exists()
