"""The ``--settings`` of the robust ranking's benchmarks (``benchmarks/robust.py``,
``benchmarks/studies/ranking.py``): one setting of :func:`~shapeviewer.grasp.robust.robustness` per
command-line word."""

from __future__ import annotations


def setting_options(setting: str) -> dict:
    """``"3,2"`` or ``"3,2,0.2"`` as options of :func:`~shapeviewer.grasp.robust.robustness`:
    ``lift_top`` and ``recheck_top``, then optionally ``hedge`` (how far below the mesh level the
    sample meshes are made)."""
    values = setting.split(",")
    if len(values) not in (2, 3):
        raise SystemExit(f"--settings {setting}: expected lift_top,recheck_top[,hedge]")
    options = {"lift_top": int(values[0]), "recheck_top": int(values[1])}
    return options | ({"hedge": float(values[2])} if len(values) == 3 else {})
