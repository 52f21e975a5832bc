"""Training the completion CNN (paper Sec. IV-A): Adam, binary cross-entropy, batch 32
drawn with replacement, Jaccard on Training Views, Holdout Views and Holdout Models (paper Fig. 4).

Data: the shards written by :mod:`shapeviewer.training.generate`. Views of training models are split into
training views and holdout views by :func:`shapeviewer.sim.catalogue.view_split`; only training views
are trained on.

Outputs in the run directory: ``last.pt`` (resumable: model, optimiser, step, RNG state),
``best_loss.pt`` (best training error), ``best_holdout_model.pt`` (best Holdout Models Jaccard),
``log.csv`` and ``jaccard.png`` (the three curves); with ``snapshot_every``, ``step_NNNNNN.pt`` at every
multiple of it, whose mean (:func:`shapeviewer.training.averaging.average_weights`) averages the run's
trajectory (stochastic weight averaging: a network at the centre of the region Adam wanders in at a
constant rate).
"""

from __future__ import annotations

import csv
import io
import json
import logging
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from ..completion.model import build, default_device, network_input, save_weights
from ..completion.voxel import GRID_DIM
from ..fileio import atomic_write
from ..sim import catalogue
from .generate import folder_depth_shift, shard_files

log = logging.getLogger(__name__)

SETS = ("training_view", "holdout_view", "holdout_model")
PROB_CLIP = 1e-6  # predictions clipped to [1e-6, 1 - 1e-6] in the loss, as the paper's code did
LOGIT_CLIP = float(np.log((1 - PROB_CLIP) / PROB_CLIP))


PLANE_DROPOUT = 0.2  # share of training examples whose support plane is hidden (callers may not know it)


LABELS = ("solid", "fraction")  # Y (every voxel the object touches, the paper's) or voxel.solid_fraction
_FIELDS = ("x", "y", "yfrac", "free", "below", "objects", "views", "source")


@dataclass
class GridSet:
    """Bit-packed examples: ``x``, ``y``, ``free``, ``below`` are (N, 8000) uint8 (X, Y and the two
    context channels of :func:`voxel.context_grids`); ``yfrac`` is (N, 64000) uint8, the soft label
    (:func:`voxel.solid_fraction`, 255 = full; 0 everywhere for shards written before it existed);
    ``objects``/``views`` identify them; ``source`` is the data folder of each."""

    x: np.ndarray
    y: np.ndarray
    yfrac: np.ndarray
    free: np.ndarray
    below: np.ndarray
    objects: np.ndarray
    views: np.ndarray
    source: np.ndarray

    def __len__(self) -> int:
        return len(self.x)

    def grids(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Unpacked bool grids: X and Y (len(idx), 40, 40, 40) and the context (len(idx), 2, 40, 40, 40)."""
        unpack = lambda a: _unpack(a, idx)  # noqa: E731
        return unpack(self.x), unpack(self.y), np.stack([unpack(self.free), unpack(self.below)], axis=1)

    def targets(self, idx: np.ndarray, label: str) -> np.ndarray:
        """The training targets (len(idx), 40, 40, 40) float32: Y (``solid``) or the soft label (``fraction``).

        Raises:
            ValueError: ``fraction`` asked of examples whose shards predate the soft label.
        """
        if label == "solid":
            return _unpack(self.y, idx).astype(np.float32)
        if label != "fraction":
            raise ValueError(f"unknown label {label!r} (use one of {LABELS})")
        frac = self.yfrac[idx]
        missing = ~frac.any(axis=1)
        if missing.any():
            folders = sorted({str(d) for d in self.source[idx][missing]})
            raise ValueError(
                f"examples in {', '.join(folders)} have no soft label: run `shapeviewer generate` on those "
                "folders again (it adds the label to the shards it finds)"
            )
        return (frac.astype(np.float32) / 255.0).reshape((len(idx),) + (GRID_DIM,) * 3)

    def truth(self, idx: np.ndarray, label: str) -> np.ndarray:
        """The bool ground truth the 40^3 Jaccard compares with: Y, or the soft label above 0.5."""
        return _unpack(self.y, idx) if label == "solid" else self.targets(idx, label) > 0.5

    def subset(self, idx: np.ndarray) -> GridSet:
        return GridSet(*(getattr(self, f)[idx] for f in _FIELDS))


def _unpack(packed: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Rows ``idx`` of a bit-packed (N, 8000) array as bool grids (len(idx), 40, 40, 40)."""
    return np.unpackbits(packed[idx], axis=1).reshape((len(idx),) + (GRID_DIM,) * 3).astype(bool)


def load_grid_sets(data_dirs: str | Path | list) -> dict[str, GridSet]:
    """All examples of one or more generated data folders, split into the paper's three evaluation sets.

    Every finished shard counts, so a folder still being generated gives what it has so far.
    Shards written before the context channels existed load with empty (unknown) context.
    """
    parts: dict[str, list] = {s: [] for s in SETS}
    packed = GRID_DIM**3 // 8
    for data_dir, shard in _shard_files(data_dirs):
        with np.load(shard) as z:
            x, y, views = z["x"], z["y"], z["views"]
            yfrac = z["yfrac"] if "yfrac" in z else np.zeros((len(x), GRID_DIM**3), np.uint8)
            free = z["free"] if "free" in z else np.zeros_like(x)
            below = z["below"] if "below" in z else np.zeros_like(x)
        name = shard.stem.replace("__", "/")
        split = np.array([catalogue.view_split(name, int(v)) for v in views])
        for s in SETS:
            m = split == s
            if m.any():
                parts[s].append(
                    (
                        x[m],
                        y[m],
                        yfrac[m],
                        free[m],
                        below[m],
                        np.full(m.sum(), name, dtype=object),
                        views[m],
                        np.full(m.sum(), str(data_dir), dtype=object),
                    )
                )
    out = {}
    for s in SETS:
        if parts[s]:
            out[s] = GridSet(*(np.concatenate([p[i] for p in parts[s]]) for i in range(len(_FIELDS))))
        else:
            empty = np.zeros((0, packed), np.uint8)
            out[s] = GridSet(
                empty,
                empty.copy(),
                np.zeros((0, GRID_DIM**3), np.uint8),
                empty.copy(),
                empty.copy(),
                np.zeros(0, dtype=object),
                np.zeros(0, np.int32),
                np.zeros(0, dtype=object),
            )
    return out


def data_depth_shift(data_dirs: Sequence[str | Path]) -> float:
    """The grid placement (``generate --depth-shift``, voxels) shared by the data folders.

    A network learns its placement, so folders made with different ones cannot be pooled; a
    folder without a manifest yet (still being generated) is not checked.
    """
    recorded = {str(d): folder_depth_shift(d) for d in data_dirs}
    shifts = {d: s for d, s in recorded.items() if s is not None}
    if len(set(shifts.values())) > 1:
        raise ValueError(f"the data folders use different grid placements (depth_shift): {shifts}")
    return next(iter(shifts.values()), 0.0)


def check_placement(completer, data_dirs: Sequence[str | Path]) -> None:
    """Raise a ValueError that says what to run if the data folders' grid placement is not the
    network's (:attr:`~shapeviewer.completion.model.Completer.depth_shift`): its scores there would mean nothing."""
    shift = data_depth_shift(data_dirs)
    if shift != completer.depth_shift:
        raise ValueError(
            f"{', '.join(map(str, data_dirs))} place objects {shift:g} voxels forward in the grid but the "
            f"network ({completer.source}) was trained with {completer.depth_shift:g}: regenerate the views "
            f"with `generate --depth-shift {completer.depth_shift:g}`"
        )


def _shard_files(data_dirs: str | Path | list) -> list[tuple[Path, Path]]:
    """``(folder, shard)`` of every finished shard of the data folders (a folder that ``generate``
    is still filling gives the shards written so far)."""
    dirs = [Path(d) for d in (data_dirs if isinstance(data_dirs, (list, tuple)) else [data_dirs])]
    out = []
    for d in dirs:
        shards = shard_files(d)
        if not shards:
            raise FileNotFoundError(f"no shards in {d}: run `shapeviewer generate --out {d}` first")
        out += [(d, p) for p in shards]
    return out


def augment(
    x: np.ndarray, y: np.ndarray, ctx: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random symmetries of the image plane (flip x, flip y, swap x and y), applied to X, Y and the
    context alike, and the support plane hidden in ``PLANE_DROPOUT`` of the examples.

    Each symmetry is a mirror of the scene that keeps the camera at the origin looking along +z,
    and the grid placement is symmetric in x and y (centre at 20), so augmented pairs are valid views.
    """
    if rng.random() < 0.5:
        x, y, ctx = x[:, ::-1], y[:, ::-1], ctx[:, :, ::-1]
    if rng.random() < 0.5:
        x, y, ctx = x[:, :, ::-1], y[:, :, ::-1], ctx[:, :, :, ::-1]
    if rng.random() < 0.5:
        x, y, ctx = x.transpose(0, 2, 1, 3), y.transpose(0, 2, 1, 3), ctx.transpose(0, 1, 3, 2, 4)
    ctx = np.array(ctx)
    ctx[rng.random(len(ctx)) < PLANE_DROPOUT, 1] = False
    return np.ascontiguousarray(x), np.ascontiguousarray(y), ctx


def bce_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy summed over the 64,000 voxels and averaged over the batch (the paper's)."""
    logits = logits.clamp(-LOGIT_CLIP, LOGIT_CLIP)
    return F.binary_cross_entropy_with_logits(logits, target, reduction="sum") / logits.shape[0]


def soft_jaccard_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """1 - the soft Jaccard of the probabilities and the target, averaged over the batch.

    Unlike the summed cross-entropy it weighs every example alike, whatever its volume, so thin-walled
    vessels (a few thousand voxels) count as much as a large box: it is the evaluation's metric, made smooth."""
    p = torch.sigmoid(logits).flatten(1)
    t = target.flatten(1)
    inter = (p * t).sum(1)
    union = p.sum(1) + t.sum(1) - inter
    return (1 - inter / union.clamp_min(1.0)).mean()


def jaccard_grids(pred: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per-example Jaccard (IoU) of bool grids (B, 40, 40, 40)."""
    inter = (pred & truth).reshape(len(pred), -1).sum(1)
    union = (pred | truth).reshape(len(pred), -1).sum(1)
    return np.where(union > 0, inter / np.maximum(union, 1), 1.0)


def evaluate_grids(
    net_or_completer,
    sets: dict[str, GridSet],
    max_views: int = 500,
    seed: int = 0,
    batch: int = 32,
    label: str = "solid",
    level: float = 0.5,
    samples: int = 1,
) -> dict:
    """Mean Jaccard at 40^3 per set, of the voxels above ``level`` and of the input alone, against
    the ground truth of ``label`` (:meth:`GridSet.truth`: ``solid``, the paper's Y, or the label a
    network was trained on), and the network's per shape kind (``by_kind``: kind -> {"jaccard",
    "views"}, :func:`catalogue.shape_kind`). The paper's metric is ``label="solid"`` at the
    network's :attr:`~shapeviewer.completion.model.Completer.grid_level`; training scores its own label at 0.5.

    ``samples``: 1 scores the network's answer for the view as seen
    (:meth:`~shapeviewer.completion.model.Completer.predict`, what training watches); n > 1 the mean of its
    answers for the first n mirrored views (:meth:`~shapeviewer.completion.model.Completer.predict_samples`; 8
    is the app's output grid, :attr:`~shapeviewer.completion.pipeline.Completion.probabilities`).

    Uses a seeded sample of at most ``max_views`` views per set.
    """
    from ..completion.model import Completer

    completer = net_or_completer
    if not isinstance(completer, Completer):  # a network being trained: its own device, no pre-packing
        completer = Completer(completer, "", device=next(completer.parameters()).device)
    out = {}
    for s, gs in sets.items():
        if len(gs) == 0:
            continue
        rng = np.random.default_rng(seed)
        idx = np.sort(rng.choice(len(gs), size=min(max_views, len(gs)), replace=False))
        js, js_in = [], []
        for i in range(0, len(idx), batch):
            x, _, ctx = gs.grids(idx[i : i + batch])
            y = gs.truth(idx[i : i + batch], label)
            if samples > 1:
                p = completer.predict_samples(x, samples, context=ctx).mean(axis=0)
            else:
                p = completer.predict(x, context=ctx)
            js.append(jaccard_grids(p > level, y))
            js_in.append(jaccard_grids(x, y))
        jac = np.concatenate(js)
        kinds = np.array([catalogue.shape_kind(str(o)) for o in gs.objects[idx]])
        out[s] = {
            "jaccard": float(jac.mean()),
            "input_jaccard": float(np.concatenate(js_in).mean()),
            "views": int(len(idx)),
            "by_kind": {
                k: {"jaccard": float(jac[kinds == k].mean()), "views": int((kinds == k).sum())}
                for k in sorted(set(kinds.tolist()))
            },
        }
    return out


@dataclass
class TrainConfig:
    arch: str = "unet3d"
    steps: int = 20000
    batch_size: int = 32
    lr: float = 1e-4
    eval_every: int = 500
    eval_views: int = 200
    checkpoint_every: int = 100
    snapshot_every: int = 0  # keep the weights at every multiple of this step as step_NNNNNN.pt (0 = none)
    augment: bool = True
    seed: int = 0
    width: int | None = None  # unet3d width (None = the architecture's default)
    in_channels: int = 3  # unet3d: 1 = occupancy only (the paper), 3 = with the context channels
    init: str | None = None  # weights to start from (a narrower network is widened, see warm_start)
    jaccard_weight: float = 0.0  # weight of soft_jaccard_loss beside the summed cross-entropy (0 = the paper's loss)
    label: str = "solid"  # the target: "solid" (the paper's Y) or "fraction" (voxel.solid_fraction)


def _arch_kwargs(cfg: TrainConfig) -> dict:
    if cfg.arch != "unet3d":
        return {}
    return {**({"width": cfg.width} if cfg.width else {}), "in_channels": cfg.in_channels}


def warm_start(net: torch.nn.Module, weights: str | Path) -> None:
    """Load ``weights`` into ``net``, which may be wider than the network they were trained for
    (a 1-channel unet3d into a 3-channel one, or width 16 into width 24).

    Each weight keeps its old block; the old units' weights from new inputs are zero and the new
    units keep ``net``'s fresh random weights, so the widened network starts out computing exactly
    what the old one did, and its new units still receive gradients (their outputs are not zero)."""
    blob = torch.load(weights, map_location="cpu", weights_only=True)
    state = net.state_dict()
    for k, v in blob["state_dict"].items():
        if k in state and state[k].shape != v.shape:
            if v.ndim != state[k].ndim or any(o > n for o, n in zip(v.shape, state[k].shape)):
                raise ValueError(f"{weights}: {k} has shape {tuple(v.shape)}, larger than {tuple(state[k].shape)}")
            wide = state[k].clone() if v.ndim > 1 else torch.zeros_like(state[k])
            wide[: v.shape[0]] = 0
            wide[tuple(slice(0, n) for n in v.shape)] = v
            v = wide
        state[k] = v
    net.load_state_dict(state)


def train(data_dir: str | Path, run_dir: str | Path, cfg: TrainConfig | None = None, progress: bool = True) -> dict:
    """Train (or resume) a network on generated data (``cfg``: :class:`TrainConfig`'s defaults if None);
    returns the last evaluation."""
    cfg = cfg or TrainConfig()
    from tqdm import tqdm

    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    device = default_device()
    sets = load_grid_sets(data_dir)
    n_shards = len(_shard_files(data_dir))
    train_set = sets["training_view"]
    if len(train_set) == 0:
        raise ValueError(f"no training views in {data_dir}")
    if cfg.label not in LABELS:
        raise ValueError(f"unknown label {cfg.label!r} (use one of {LABELS})")
    if cfg.label == "fraction":  # fail now, not at the first batch that meets an old shard
        train_set.targets(np.flatnonzero(~train_set.yfrac.any(axis=1))[:1], cfg.label)
    torch.manual_seed(cfg.seed)
    net = build(cfg.arch, **_arch_kwargs(cfg))
    if cfg.init:
        warm_start(net, cfg.init)
    net = net.to(device)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, betas=(0.9, 0.999), eps=1e-8)
    rng = np.random.default_rng(cfg.seed)
    step, best_loss, best_jac, wall = 0, float("inf"), -1.0, 0.0
    last = run_dir / "last.pt"
    if last.exists():
        ck = torch.load(last, map_location=device, weights_only=True)
        net.load_state_dict(ck["state_dict"])
        opt.load_state_dict(ck["optimizer"])
        rng.bit_generator.state = ck["rng"]
        step, best_loss, best_jac, wall = ck["step"], ck["best_loss"], ck["best_jaccard"], ck.get("wall", 0.0)
        log.info("resumed %s at step %d", run_dir, step)
        _truncate_log(run_dir / "log.csv", step)
    data_names = [str(d) for d in (data_dir if isinstance(data_dir, (list, tuple)) else [data_dir])]
    depth_shift = data_depth_shift(data_names)
    (run_dir / "config.json").write_text(json.dumps({**asdict(cfg), "data": data_names}, indent=1))

    def meta() -> dict:
        return {
            "steps": step,
            "arch_kwargs": _arch_kwargs(cfg),
            "data": data_names,
            "lr": cfg.lr,
            "batch_size": cfg.batch_size,
            "jaccard_weight": cfg.jaccard_weight,
            "label": cfg.label,
            "depth_shift": depth_shift,
            "wall_seconds": wall,
            "examples": {s: len(v) for s, v in sets.items()},
        }

    log_path = run_dir / "log.csv"
    new_log = not log_path.exists()
    logf = open(log_path, "a", newline="")
    writer = csv.writer(logf)
    if new_log:
        writer.writerow(["step", "loss", *(f"jaccard_{s}" for s in SETS), "wall_seconds"])
    bar = tqdm(total=cfg.steps, initial=step, desc="train", disable=not progress)
    losses = []
    result = {}
    net.train()
    try:
        while step < cfg.steps:
            t0 = time.perf_counter()
            idx = rng.integers(0, len(train_set), cfg.batch_size)  # with replacement, as the paper
            x, _, ctx = train_set.grids(idx)
            y = train_set.targets(idx, cfg.label)
            if cfg.augment:
                x, y, ctx = augment(x, y, ctx, rng)
            xt = network_input(x, ctx, getattr(net, "in_channels", 1)).to(device)
            yt = torch.from_numpy(y[:, None]).to(device)
            logits = net(xt)
            loss = bce_loss(logits, yt)
            if cfg.jaccard_weight:
                loss = loss + cfg.jaccard_weight * soft_jaccard_loss(logits, yt)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            step += 1
            wall += time.perf_counter() - t0
            losses.append(loss.item())
            bar.update(1)
            bar.set_postfix(loss=f"{losses[-1]:.0f}")
            if step % cfg.eval_every == 0 or step == cfg.steps:
                if len(_shard_files(data_dir)) != n_shards:  # `generate` is still adding shards: use them
                    sets = load_grid_sets(data_dir)
                    n_shards, train_set = len(_shard_files(data_dir)), sets["training_view"]
                    log.info("reloaded data: %s", {s: len(v) for s, v in sets.items()})
                net.eval()
                result = evaluate_grids(net, sets, max_views=cfg.eval_views, seed=cfg.seed, label=cfg.label)
                net.train()
                mean_loss = float(np.mean(losses))
                losses.clear()
                writer.writerow(
                    [
                        step,
                        f"{mean_loss:.3f}",
                        *(f"{result.get(s, {}).get('jaccard', float('nan')):.4f}" for s in SETS),
                        f"{wall:.0f}",
                    ]
                )
                logf.flush()
                if mean_loss < best_loss:
                    best_loss = mean_loss
                    save_weights(run_dir / "best_loss.pt", net, cfg.arch, {**meta(), "eval": result})
                jac = result.get("holdout_model", {}).get("jaccard", -1.0)
                if jac > best_jac:
                    best_jac = jac
                    save_weights(run_dir / "best_holdout_model.pt", net, cfg.arch, {**meta(), "eval": result})
                plot_log(log_path, run_dir / "jaccard.png")
                log.info(
                    "step %d loss %.1f %s", step, mean_loss, {s: round(r["jaccard"], 3) for s, r in result.items()}
                )
            if cfg.snapshot_every and step % cfg.snapshot_every == 0:
                save_weights(run_dir / f"step_{step:06d}.pt", net, cfg.arch, meta())
            if step % cfg.checkpoint_every == 0 or step == cfg.steps:
                _save_checkpoint(last, net, opt, rng, step, best_loss, best_jac, wall)
    finally:
        _save_checkpoint(last, net, opt, rng, step, best_loss, best_jac, wall)
        logf.close()
        bar.close()
    return result


def _truncate_log(log_csv: Path, step: int) -> None:
    """Drop log rows written after the checkpoint a run resumes from (they will be redone)."""
    if not log_csv.exists():
        return
    rows = list(csv.reader(open(log_csv)))
    kept = rows[:1] + [r for r in rows[1:] if int(r[0]) <= step]
    if len(kept) != len(rows):
        with open(log_csv, "w", newline="") as f:
            csv.writer(f).writerows(kept)


def _save_checkpoint(path: Path, net, opt, rng, step, best_loss, best_jac, wall) -> None:
    buf = io.BytesIO()
    torch.save(
        {
            "state_dict": net.state_dict(),
            "optimizer": opt.state_dict(),
            "rng": rng.bit_generator.state,
            "step": step,
            "best_loss": best_loss,
            "best_jaccard": best_jac,
            "wall": wall,
        },
        buf,
    )
    atomic_write(path, buf.getvalue())


def plot_log(log_csv: str | Path, png: str | Path) -> None:
    """The paper's Fig. 4: Jaccard on the three sets against training steps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = list(csv.DictReader(open(log_csv)))
    if not rows:
        return
    steps = [int(r["step"]) for r in rows]
    fig, ax = plt.subplots(figsize=(6, 3.6), dpi=110)
    for s, label in zip(SETS, ("Training Views", "Holdout Views", "Holdout Models")):
        ax.plot(steps, [float(r[f"jaccard_{s}"]) for r in rows], label=label)
    ax.set_xlabel("training steps (batch 32)")
    ax.set_ylabel("Jaccard similarity (40^3)")
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(png)
    plt.close(fig)
