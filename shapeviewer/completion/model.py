"""The shape completion CNN (paper Fig. 3) and a compact network that trains on a CPU.

Both map a (B, 1, 40, 40, 40) occupancy grid (indexed [x, y, z] in the camera frame, placement of
:mod:`shapeviewer.completion.voxel`) to per-voxel occupancy probabilities of the same shape.

* ``varley2017``: the paper's exact network, three 4^3 convolutions, two max-pools, dense 5,000,
  dense 64,000 with sigmoid; about 430 million parameters (1.7 GB of float32).
* ``unet3d``: the shipped default, a small 3D U-Net (encoder-decoder with skip connections) of
  about 0.4 million parameters, fast on CPU.

Weights files are ``torch.save`` dictionaries ``{"arch", "state_dict", "meta"}`` and are loaded with
``torch.load(weights_only=True)``.
"""

from __future__ import annotations

import io
import logging
import pickle
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ..errors import ShapeviewerError
from ..fileio import atomic_write
from .reconstruct import MESH_LEVEL
from .voxel import GRID_DIM

log = logging.getLogger(__name__)

DEFAULT_WEIGHTS = Path(__file__).resolve().parents[2] / "static_assets" / "weights" / "unet3d.pt"


class Varley2017(nn.Module):
    """The paper's CNN: conv(64, 4^3) x2, pool, conv(64, 4^3), pool, dense 5000, dense 64000."""

    def __init__(self) -> None:
        super().__init__()
        self.features = nn.Sequential(
            nn.Conv3d(1, 64, 4),
            nn.ReLU(inplace=True),  # 40 -> 37
            nn.Conv3d(64, 64, 4),
            nn.ReLU(inplace=True),  # 37 -> 34
            nn.MaxPool3d(2),  # 34 -> 17
            nn.Conv3d(64, 64, 4),
            nn.ReLU(inplace=True),  # 17 -> 14
            nn.MaxPool3d(2),  # 14 -> 7
        )
        self.dense1 = nn.Linear(64 * 7**3, 5000)
        self.dense2 = nn.Linear(5000, GRID_DIM**3)
        for m in self.modules():
            if isinstance(m, (nn.Conv3d, nn.Linear)):
                assert m.bias is not None  # every layer is built with a bias
                nn.init.zeros_(m.bias)
                if m is self.dense2:
                    nn.init.xavier_normal_(m.weight)  # Glorot-normal before the sigmoid
                else:
                    nn.init.kaiming_normal_(m.weight, nonlinearity="relu")  # He-normal before ReLUs

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits (B, 1, 40, 40, 40); apply a sigmoid for probabilities."""
        h = self.features(x).flatten(1)
        h = torch.relu(self.dense1(h))
        return self.dense2(h).view(-1, 1, GRID_DIM, GRID_DIM, GRID_DIM)


def _conv(cin: int, cout: int, k: int = 3) -> nn.Sequential:
    return nn.Sequential(nn.Conv3d(cin, cout, k, padding=k // 2), nn.ReLU(inplace=True))


def space_to_depth(x: torch.Tensor) -> torch.Tensor:
    """(B, C, 2D, 2H, 2W) -> (B, 8C, D, H, W): each 2^3 block of voxels becomes 8 channels."""
    b, c, d, h, w = x.shape
    x = x.view(b, c, d // 2, 2, h // 2, 2, w // 2, 2).permute(0, 1, 3, 5, 7, 2, 4, 6)
    return x.reshape(b, c * 8, d // 2, h // 2, w // 2)


def depth_to_space(x: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`space_to_depth`: (B, 8C, D, H, W) -> (B, C, 2D, 2H, 2W)."""
    b, c8, d, h, w = x.shape
    x = x.view(b, c8 // 8, 2, 2, 2, d, h, w).permute(0, 1, 5, 2, 6, 3, 7, 4)
    return x.reshape(b, c8 // 8, 2 * d, 2 * h, 2 * w)


class UNet3D(nn.Module):
    """A compact 3D U-Net working at 20^3 -> 10^3 -> 5^3 and back, with skip connections.

    Input channel 0 is the observed occupancy; with ``in_channels`` 3, channels 1-2 are the context
    of :func:`~shapeviewer.completion.voxel.context_grids` (seen free space, under the support plane).
    The 40^3 input is folded into 8 channels per input channel at 20^3 (space-to-depth) and the
    output unfolded the same way, so no convolution runs at full resolution: that is what makes it fast on a CPU.
    The skips carry the observed surface; the 5^3 bottleneck's receptive field covers the whole
    grid, so the network can reason about the object's overall shape.
    """

    def __init__(self, width: int = 16, in_channels: int = 1) -> None:
        super().__init__()
        w1, w2, w3 = width, 2 * width, 4 * width
        self.in_channels = in_channels
        self.enc1 = nn.Sequential(_conv(8 * in_channels, w1), _conv(w1, w1))
        self.down1 = nn.Sequential(nn.Conv3d(w1, w2, 2, stride=2), nn.ReLU(inplace=True))
        self.enc2 = nn.Sequential(_conv(w2, w2), _conv(w2, w2))
        self.down2 = nn.Sequential(nn.Conv3d(w2, w3, 2, stride=2), nn.ReLU(inplace=True))
        self.bottleneck = nn.Sequential(_conv(w3, w3), _conv(w3, w3))
        self.up2 = nn.Conv3d(w3, 8 * w2, 1)  # 1x1 conv + depth-to-space = a 2^3 stride-2 transposed conv
        self.dec2 = _conv(w2, w2)
        self.up1 = nn.Conv3d(w2, 8 * w1, 1)
        self.dec1 = _conv(w1, w1)
        self.head = nn.Conv3d(w1, 8, 1)
        for m in self.modules():
            if isinstance(m, nn.Conv3d):
                assert m.bias is not None  # every layer is built with a bias
                nn.init.zeros_(m.bias)
                if m is self.head:
                    nn.init.xavier_normal_(m.weight)  # Glorot before the sigmoid, as the paper
                else:
                    nn.init.kaiming_normal_(m.weight, nonlinearity="relu")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits (B, 1, 40, 40, 40); apply a sigmoid for probabilities."""
        e1 = self.enc1(space_to_depth(x))
        e2 = self.enc2(self.down1(e1))
        b = self.bottleneck(self.down2(e2))
        d2 = self.dec2(torch.relu(depth_to_space(self.up2(b))) + e2)
        d1 = self.dec1(torch.relu(depth_to_space(self.up1(d2))) + e1)
        return depth_to_space(self.head(d1))


class _MkldnnConv3d(nn.Module):
    """Inference-only Conv3d with weights pre-packed for oneDNN.

    Plain CPU Conv3d re-packs its weights on every call, which costs more than the convolution
    itself for one 40^3 grid (about 40 ms vs 9 ms for the whole network).
    """

    def __init__(self, conv: nn.Conv3d) -> None:
        super().__init__()
        from torch.utils.mkldnn import MkldnnConv3d

        self.conv = MkldnnConv3d(conv, torch.float32)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(x.to_mkldnn()).to_dense()


def _prepack_for_cpu(module: nn.Module) -> nn.Module:
    """Swap every Conv3d for its pre-packed oneDNN version (in place)."""
    for name, child in module.named_children():
        if isinstance(child, nn.Conv3d):
            setattr(module, name, _MkldnnConv3d(child))
        else:
            _prepack_for_cpu(child)
    return module


ARCHITECTURES = {"varley2017": Varley2017, "unet3d": UNet3D}


def build(arch: str, **kwargs) -> nn.Module:
    """A freshly initialised network by name (``varley2017`` or ``unet3d``)."""
    if arch not in ARCHITECTURES:
        raise ValueError(f"unknown architecture {arch!r}; choose one of {sorted(ARCHITECTURES)}")
    return ARCHITECTURES[arch](**kwargs)


def default_device() -> torch.device:
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


# Where a network's answers are meshed, by the label it was trained on (``train --label``): Y puts
# the 0.5 contour outside the object (reconstruct.MESH_LEVEL), the soft label on it.
LABEL_MESH_LEVELS = {"solid": MESH_LEVEL, "fraction": 0.5}
# The output grid is the network's estimate of the paper's Y: every voxel the object's surface
# passes through (as binvox marked it). A network trained on Y marks those above 0.5; one trained on the soft
# label answers how much of each voxel the object fills, and a voxel the surface only grazes is
# part of Y though it is mostly empty. On training views its Y Jaccard peaks at 0.2-0.25
# (docs/studies/grid-placement.md), so such a network's grid is p > 0.25.
LABEL_GRID_LEVELS = {"solid": 0.5, "fraction": 0.25}


@dataclass
class Completer:
    """A loaded network that completes 40^3 grids.

    Attributes:
        net: the torch module (in eval mode).
        arch: architecture name.
        meta: what the weights file says about itself (training steps, data, Jaccard...).
        trained: False when the weights are a fresh initialisation (the viewer says so).
        source: the weights path, or a description.
    """

    net: nn.Module
    arch: str
    meta: dict = field(default_factory=dict)
    trained: bool = True
    source: str = ""
    device: torch.device = field(default_factory=default_device)
    batch_size: int = 32

    @property
    def label(self) -> str:
        """The target it was trained on (``train --label``): ``solid`` (the paper's Y) or ``fraction``."""
        return str(self.meta.get("label", "solid"))

    @property
    def mesh_level(self) -> float:
        """The probability this network's answers are meshed at: the weights' ``meta["mesh_level"]``
        (chosen by a level scan, see the model card), else the level of the label it was trained on
        (:data:`LABEL_MESH_LEVELS`)."""
        return float(self.meta.get("mesh_level", LABEL_MESH_LEVELS[self.label]))

    @property
    def grid_level(self) -> float:
        """The probability above which a voxel is in this network's output grid (its estimate of
        the paper's Y): the weights' ``meta["grid_level"]``, else the level of the label it was
        trained on (:data:`LABEL_GRID_LEVELS`)."""
        return float(self.meta.get("grid_level", LABEL_GRID_LEVELS[self.label]))

    @property
    def depth_shift(self) -> float:
        """Voxels its grid placement moves the object towards the camera (``meta["depth_shift"]``,
        from the training data; 0, the paper's placement, for older weights). Inference must
        voxelize with it: ``voxel.partial_to_grid(points, depth_shift=completer.depth_shift)``."""
        return float(self.meta.get("depth_shift", 0.0))

    @property
    def in_channels(self) -> int:
        """1: occupancy only; 3: occupancy and the two context channels."""
        return int(getattr(self.net, "in_channels", 1))

    def predict(self, grids: np.ndarray, *, context: np.ndarray | None = None) -> np.ndarray:
        """Occupancy probabilities (float32) for a (40,40,40) or (B,40,40,40) bool occupancy array.

        Args:
            grids: the observed occupancy, [x, y, z] in the paper's placement.
            context: optional (2,40,40,40) or (B,2,40,40,40) bool grids of known-empty space
                (:func:`~shapeviewer.completion.voxel.context_grids`). A context-aware network reads them;
                either way those voxels are known to be empty, so their probability is set to 0.
        """
        grids = np.asarray(grids)
        single = grids.ndim == 3
        batch = grids[None] if single else grids
        if batch.ndim != 4 or batch.shape[1:] != (GRID_DIM,) * 3:
            raise ValueError(f"expected a (40,40,40) or (B,40,40,40) grid, got shape {grids.shape}")
        ctx = None
        if context is not None:
            ctx = np.asarray(context, dtype=bool)
            ctx = ctx[None] if single else ctx
            if ctx.shape != (len(batch), 2) + (GRID_DIM,) * 3:
                raise ValueError(f"context must be (B, 2, 40, 40, 40) for {len(batch)} grids, got {np.shape(context)}")
        out = np.empty(batch.shape, dtype=np.float32)
        with torch.inference_mode():
            for i in range(0, len(batch), self.batch_size):
                x = network_input(
                    batch[i : i + self.batch_size],
                    None if ctx is None else ctx[i : i + self.batch_size],
                    self.in_channels,
                )
                out[i : i + self.batch_size] = torch.sigmoid(self.net(x.to(self.device)))[:, 0].float().cpu().numpy()
        if ctx is not None:
            out[ctx.any(axis=1)] = 0.0
        return out[0] if single else out

    def predict_samples(self, grids: np.ndarray, n: int = 8, *, context: np.ndarray | None = None) -> np.ndarray:
        """``n`` plausible completions: (n, 40, 40, 40) or (n, B, 40, 40, 40) float32 probabilities.

        Sample k is the network's answer for the view mirrored by the k-th image-plane symmetry
        (flip x, flip y, swap x and y: mirrors of the scene with the camera in place, which the
        network was trained on), mapped back. Where the observation pins the shape down the answers
        agree; where the network guesses (the unseen back, a handle) they differ, so their spread
        (:func:`sample_spread`) is a per-voxel uncertainty. ``n`` is at most ``len(SYMMETRIES)``
        (8); sample 0 is :meth:`predict`.
        """
        if not 1 <= n <= len(SYMMETRIES):
            raise ValueError(f"n must be between 1 and {len(SYMMETRIES)}, got {n}")
        grids = np.asarray(grids)
        single = grids.ndim == 3
        batch = grids[None] if single else grids
        ctx = None if context is None else (np.asarray(context, bool)[None] if single else np.asarray(context, bool))
        syms = SYMMETRIES[:n]
        stacked = np.concatenate([_symmetry(batch, s) for s in syms])
        ctx_stacked = None if ctx is None else np.concatenate([_symmetry(ctx, s) for s in syms])
        p = self.predict(stacked, context=ctx_stacked).reshape((n,) + batch.shape)
        out = np.stack([_symmetry(p[k], s, inverse=True) for k, s in enumerate(syms)])
        return np.ascontiguousarray(out[:, 0] if single else out)


# The spread counts how much the samples disagree about *whether* a voxel is occupied: each
# probability is first pushed towards its decision at SPREAD_LEVEL,
# sigmoid(k (logit p - logit level)), so answers of 0.3 and 0.5, which decide differently, spread
# more than answers of 0.05 and 0.25, which agree. The plain std of the probabilities ranks voxels by
# error less well (docs/studies/uncertainty.md). The level sits a little below the soft label's surface (0.5): every
# voxel the visible surface passes through holds about half object, and a decision at exactly 0.5
# there flips on sub-voxel differences between samples that agree where the surface is; at 0.4 it
# asks whether the object reaches into the voxel, which the observed side settles and the unseen
# side does not.
SPREAD_SHARPNESS = 4.0
SPREAD_LEVEL = 0.4


def sample_spread(samples: np.ndarray, *, level: float = SPREAD_LEVEL) -> np.ndarray:
    """Per-voxel uncertainty of sample completions: the std over ``samples`` ((n, ...) occupancy
    probabilities, e.g. :meth:`Completer.predict_samples`) of their soft decisions at ``level``,
    ``sigmoid(SPREAD_SHARPNESS * (logit p - logit level))``; float32, the shape of one sample, 0 (all
    agree) to 0.5 (half say occupied, half empty)."""
    p = np.asarray(samples, dtype=np.float64)
    a, b = (p * (1.0 - level)) ** SPREAD_SHARPNESS, ((1.0 - p) * level) ** SPREAD_SHARPNESS
    return (a / (a + b)).std(axis=0).astype(np.float32)


# The image-plane symmetries the network was trained with (train.augment): flip x, flip y and
# swap x and y, as axes of a (B, 40, 40, 40) or (B, C, 40, 40, 40) array's last three dimensions.
SYMMETRIES = tuple((fx, fy, sw) for sw in (False, True) for fy in (False, True) for fx in (False, True))


def _symmetry(a: np.ndarray, sym: tuple[bool, bool, bool], inverse: bool = False) -> np.ndarray:
    """Apply one of :data:`SYMMETRIES` to the [x, y, z] axes (the last three) of ``a``."""
    fx, fy, sw = sym
    x, y = a.ndim - 3, a.ndim - 2
    if sw and inverse:
        a = np.swapaxes(a, x, y)
    if fx:
        a = np.flip(a, x)
    if fy:
        a = np.flip(a, y)
    if sw and not inverse:
        a = np.swapaxes(a, x, y)
    return a


def network_input(grids: np.ndarray, context: np.ndarray | None, in_channels: int) -> torch.Tensor:
    """(B, in_channels, 40, 40, 40) float32 tensor: occupancy, then the context channels (zeros,
    i.e. unknown, when ``context`` is None)."""
    x = torch.zeros((len(grids), in_channels) + grids.shape[1:], dtype=torch.float32)
    x[:, 0] = torch.from_numpy(np.ascontiguousarray(grids, dtype=np.float32))
    if in_channels > 1 and context is not None:
        x[:, 1:] = torch.from_numpy(np.ascontiguousarray(context, dtype=np.float32))
    return x


def save_weights(path: str | Path, net: nn.Module, arch: str, meta: dict | None = None) -> None:
    """Write ``{"arch", "state_dict", "meta"}`` to ``path`` (atomically)."""
    state = {k: v.detach().cpu() for k, v in net.state_dict().items()}
    buf = io.BytesIO()
    torch.save({"arch": arch, "state_dict": state, "meta": meta or {}}, buf)
    atomic_write(path, buf.getvalue())


def _for_inference(net: nn.Module, device: torch.device) -> nn.Module:
    net = net.to(device).eval()
    if device.type == "cpu" and torch.backends.mkldnn.is_available():
        import warnings

        with warnings.catch_warnings():  # torch.utils.mkldnn is built on the deprecated torch.jit.script
            warnings.simplefilter("ignore", DeprecationWarning)
            _prepack_for_cpu(net)
    return net


def training_curves(completer: Completer) -> Path | None:
    """The training-curve plot saved with a weights file, if any.

    ``<weights>_jaccard.png`` beside the file (shipped weights) or ``jaccard.png`` in its folder
    (a training run directory).
    """
    path = Path(completer.source)
    for png in (path.with_name(path.stem + "_jaccard.png"), path.parent / "jaccard.png"):
        if path.is_file() and png.is_file():
            return png
    return None


class WeightsError(ShapeviewerError, ValueError):
    """A weights file is missing, unreadable or does not match its architecture."""


def load_completer(weights: str | Path | None = None, device: str | torch.device | None = None) -> Completer:
    """Load a :class:`Completer` (``weights=None``: the model shipped in ``static_assets/weights``).

    When the shipped file is absent the network is freshly initialised and ``trained`` is False,
    so the pipeline still runs end to end and the viewer can say the model is untrained. An
    explicitly given path that is missing or corrupt raises :class:`WeightsError`.
    """
    device = torch.device(device) if device is not None else default_device()
    path = Path(weights) if weights is not None else DEFAULT_WEIGHTS
    if not path.exists():
        if weights is not None:
            raise WeightsError(f"weights file not found: {path}")
        log.warning("no trained weights at %s: using an untrained unet3d", path)
        torch.manual_seed(0)
        net = _for_inference(build("unet3d"), device)
        return Completer(net, "unet3d", {}, trained=False, source="untrained (random initialisation)", device=device)
    t0 = time.perf_counter()
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
        arch = blob["arch"]
        net = build(arch, **blob.get("meta", {}).get("arch_kwargs", {}))
        net.load_state_dict(blob["state_dict"])
    except Exception as e:  # corrupt zip, wrong keys, wrong shapes: one clear message
        # torch's own message on a file it refuses ends with advice to load it with weights_only=False,
        # i.e. to run whatever code the file holds: never pass that on; say what the file is not.
        reason = " ".join(str(e).split())[:300] or type(e).__name__
        if isinstance(e, pickle.UnpicklingError) or "weights_only" in str(e):
            reason = "not a weights file of tensors (torch.load with weights_only=True refused it)"
        raise WeightsError(f"cannot load weights {path}: {reason}") from None
    net = _for_inference(net, device)
    meta = dict(blob.get("meta", {}))
    log.info("loaded %s weights from %s in %.2f s", arch, path, time.perf_counter() - t0)
    return Completer(net, arch, meta, trained=bool(meta.get("steps", 0)), source=str(path), device=device)
