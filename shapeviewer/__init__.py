"""shapeviewer: Shape Completion Enabled Robotic Grasping (Varley et al., IROS 2017), runnable and visible."""

import os
from typing import Any

__version__ = "0.2.0"

# OpenMP threads that spin while they wait make a 2-thread CNN pass 10-20x slower (about 0.3 s
# instead of 20 ms) as soon as anything else runs on a 2-core machine. Sleeping waits keep clicks
# fast under load. Only effective before torch is first imported, hence here.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# The public API, imported on first use so that `import shapeviewer` stays light (no torch,
# open3d or pybullet until a function needs them).
_API: dict[str, str | tuple[str, str]] = {
    "complete": ".completion.pipeline",
    "load_capture": ".perception.capture",
    "segment_scene": ".perception.segment",
    "isolate": ".perception.segment",
    "table_band": ".perception.segment",
    "partial_to_grid": ".completion.voxel",
    "context_grids": ".completion.voxel",
    "GridFrame": ".completion.voxel",
    "load_completer": ".completion.model",
    "sample_spread": ".completion.model",
    "fast_mesh": ".completion.reconstruct",
    "detailed_mesh": ".completion.reconstruct",
    "partial_mesh": ".completion.baselines",
    "mirror_mesh": ".completion.baselines",
    "hull_mesh": ".completion.baselines",
    "completion_metrics": ".evaluation.metrics",
    "plan_grasps": (".grasp.plan", "plan"),
    "execute_grasps": (".grasp.execute", "execute_grasps"),
    "robust_grasps": (".grasp.pick", "robust_grasps"),
    "evaluate": (".evaluation.run", "evaluate"),
    "clear_table": (".clutter.run", "clear_table"),
    "ViewerApp": ".viewer.app",
}
__all__ = sorted(_API)


def __getattr__(name: str) -> Any:
    if name not in _API:
        raise AttributeError(f"module 'shapeviewer' has no attribute {name!r}")
    import importlib

    entry = _API[name]
    module, attr = entry if isinstance(entry, tuple) else (entry, name)
    value = getattr(importlib.import_module(module, __name__), attr)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
