"""Averaging weights files of one network: the mean of a fine-tune and its start (WiSE-FT), or of a
run's snapshots (stochastic weight averaging). ``shapeviewer average`` calls :func:`average_weights`.

The shipped model is such a mean: the snapshots ``step_NNNNNN.pt`` that ``train --snapshot-every``
writes over the second half of a fine-tune, averaged parameter by parameter. The network has no batch
normalisation, so the mean needs no statistics recomputed.
"""

from __future__ import annotations

from pathlib import Path

import torch

from ..completion.model import build, save_weights


def average_weights(paths: list[str | Path], out: str | Path, *, note: str | None = None) -> dict:
    """Write to ``out`` the parameter-wise mean of weights files of one architecture; returns its meta.

    Averaging a fine-tuned network with the one it started from (Wortsman et al., "Robust
    fine-tuning of zero-shot models", 2022) keeps much of what the fine-tune learnt while staying
    close to what the start already did well. The meta is the last file's without its evaluation,
    with ``averaged_from`` (the files' names) and ``note`` as its ``schedule`` when given.

    Raises:
        ValueError: fewer than two files, or files of different architectures, shapes or grid
            placements (``meta["depth_shift"]``: the mean of two placements' networks answers neither).
    """
    if len(paths) < 2:
        raise ValueError("average at least two weights files")
    states = [torch.load(p, map_location="cpu", weights_only=True) for p in paths]
    first = states[0]
    for p, st in zip(paths[1:], states[1:], strict=True):
        same = st["arch"] == first["arch"] and st["state_dict"].keys() == first["state_dict"].keys()
        if not same or any(v.shape != first["state_dict"][k].shape for k, v in st["state_dict"].items()):
            raise ValueError(f"{p} is not the same network as {paths[0]} (architecture or shapes differ)")
        shifts = [s.get("meta", {}).get("depth_shift", 0.0) for s in (first, st)]
        if shifts[0] != shifts[1]:
            raise ValueError(
                f"{p} was trained with the object {shifts[1]:g} voxels forward in the grid, {paths[0]} with "
                f"{shifts[0]:g} (generate --depth-shift): their mean would answer neither placement"
            )
    avg = {}
    for k, v in first["state_dict"].items():
        if v.is_floating_point():
            avg[k] = torch.stack([st["state_dict"][k].float() for st in states]).mean(0).to(v.dtype)
        else:  # counters such as BatchNorm's batches seen: the last file's
            avg[k] = states[-1]["state_dict"][k]
    # The last file's evaluation was of that network, not of the mean: it is left out.
    meta = {k: v for k, v in states[-1].get("meta", {}).items() if k != "eval"}
    meta["averaged_from"] = [Path(p).name for p in paths]
    if note:
        meta["schedule"] = note
    net = build(first["arch"], **meta.get("arch_kwargs", {}))
    net.load_state_dict(avg)
    save_weights(out, net, first["arch"], meta)
    return meta
