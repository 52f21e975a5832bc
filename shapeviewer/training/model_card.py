"""The markdown model card ``shapeviewer evaluate-grids --card`` writes for a weights file: its
architecture, grid placement, data, split, training and the measured Jaccard at 40^3 (paper Sec. IV-A)."""

from __future__ import annotations

from pathlib import Path

from ..completion.model import build
from ..completion.voxel import FRONT_MARGIN
from .train import PLANE_DROPOUT


def model_card(completer, evaluation: dict, data_dir: str | Path | list) -> str:
    """A markdown model card: architecture, data, split, training, and measured Jaccard at 40^3.

    The reproduction commands and the figures on test views (``evaluate``) are the caller's to add.
    """
    meta = completer.meta
    # Counted on a fresh module: the loaded one's convolutions are pre-packed for oneDNN.
    n_params = sum(p.numel() for p in build(completer.arch, **meta.get("arch_kwargs", {})).parameters())
    names = {"training_view": "Training Views", "holdout_view": "Holdout Views", "holdout_model": "Holdout Models"}
    rows = "\n".join(
        f"| {names[s]} | {v['views']} | {v['jaccard']:.3f} | {v['input_jaccard']:.3f} |" for s, v in evaluation.items()
    )
    ex = meta.get("examples", {})
    data = meta.get("data", data_dir)
    data = ", ".join(f"`{d}`" for d in (data if isinstance(data, (list, tuple)) else [data]))
    inputs = (
        "occupancy, plus two context channels: space the camera saw through and space under the support "
        "plane (`voxel.context_grids`), both zeroed in the output"
        if completer.in_channels == 3
        else "occupancy only (the paper's input)"
    )
    placement = (
        "the paper's placement (bounding-box centre at voxel (20, 20, 18), largest side 32 voxels)"
        if completer.depth_shift == 0
        else f"the paper's placement moved up to {completer.depth_shift:g} voxels towards the camera "
        f"(bounding-box centre at voxel (20, 20, 18 - up to {completer.depth_shift:g}), front at least "
        f"{FRONT_MARGIN:g} voxels inside, largest side 32 voxels)"
    )
    return f"""# Model card: `{completer.arch}` shape completion CNN

- **Architecture**: `{completer.arch}` ({n_params:,} parameters), input and output 40^3 grids in
  {placement}. Input: {inputs}.
- **Data**: folders {data}; examples: {ex.get("training_view", "?")} training views,
  {ex.get("holdout_view", "?")} holdout views, {ex.get("holdout_model", "?")} holdout-model views.
- **Split**: holdout models are YCB 003_cracker_box, 006_mustard_bottle, 024_bowl, 035_power_drill and 15% of
  the random pybullet and the procedural household objects (hash of the name); 20% of each training model's
  views are holdout views.
- **Training**: Adam (betas 0.9/0.999, eps 1e-8), learning rate {meta.get("lr", "?")},
  batch {meta.get("batch_size", "?")} drawn with replacement, binary cross-entropy summed over voxels,
  random image-plane mirror/transpose augmentation, the support plane hidden in {PLANE_DROPOUT:.0%} of the
  examples; {meta.get("steps", "?")} steps,
  {meta.get("wall_seconds", 0) / 3600:.1f} h of CPU time (2 cores, shared). Checkpoint chosen by the best Holdout
  Models Jaccard on a 200-view sample (as the paper kept its best holdout-model checkpoint).

## Jaccard at 40^3 (`shapeviewer evaluate-grids`, 500 views per set)

| set | views | CNN | input only |
|---|---|---|---|
{rows}

The output grid (p > {completer.grid_level:g}, the network's `grid_level`) against the paper's ground truth Y.
"Input only" scores the visible-surface grid X itself against Y.
"""
