"""Training data generation (paper Sec. IV-A): (X, Y) pairs of 40^3 grids per rendered view.

For each object and orientation on the paper's roll x pitch x yaw grid (11 x 6 x 11 = 726), the
object alone is rendered by the live pipeline's simulated Kinect (same intrinsics, optional sensor
noise), 0.6-1.2 m away. X is the visible points voxelized with :func:`voxel.partial_to_grid`;
Y is every voxel the solid object touches, in the same grid frame, and Y_frac the share of each
voxel the object fills (:func:`voxel.solid_fraction`, the soft label). Pairs with fewer than 100
occupied X voxels, or with under 80% of X inside Y, are rejected (the paper's rule).

With ``scenes="tabletop"`` the views are :mod:`shapeviewer.sim.tabletop` views instead: the object
resting on a table among neighbours, a robot's camera (Kinect or RealSense noise), the segment cut
by the app's own segmentation and the support plane it found; the 80% rule then allows one voxel
of slack (segments carry flying pixels and a little of their neighbours).

Every example also stores the context channels of :func:`voxel.context_grids` (seen free space,
under the support plane), which a context-aware network reads.

Output: one shard per object, ``<out>/shards/<name>.npz`` with bit-packed X, Y and context and
per-view metadata, and ``<out>/manifest.json``. Generation is resumable (finished shards are skipped;
a shard written before the soft label existed gains it from its stored poses).
"""

from __future__ import annotations

import io
import json
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..completion.voxel import (
    GRID_DIM,
    GridFrame,
    context_grids,
    partial_to_grid,
    points_to_grid,
    solid_fraction,
    solid_grid,
    surface_samples,
)
from ..fileio import atomic_write
from ..geometry import raycasting_scene
from ..perception.camera import Intrinsics, backproject_valid
from ..sim import catalogue
from ..sim.sensor import DepthNoise, KinectNoise, RaycastRenderer

log = logging.getLogger(__name__)

ORIENTATION_GRID = (11, 6, 11)  # roll x pitch x yaw, as in the paper
MIN_X_VOXELS = 100
MIN_X_INSIDE_Y = 0.8
DISTANCE_RANGE = (0.6, 1.2)  # metres from the camera


@dataclass(frozen=True)
class GenerationConfig:
    views: int | None = None  # views per object (a seeded subset of the 726); None = all
    noise: bool = True
    seed: int = 0
    scenes: str = "sphere"  # "sphere": the paper's floating views; "tabletop": robot views of a table
    # Each view's depth error is the sensor model's times a factor drawn from this range
    # (DepthNoise.scaled): training on a range of sensors and surfaces, not on one model's.
    noise_scale: tuple[float, float] = (1.0, 1.0)
    # Voxels the grid placement moves the object towards the camera (voxel.frame_for_points);
    # 0 is the paper's placement.
    depth_shift: float = 0.0

    def __post_init__(self) -> None:
        lo, hi = self.noise_scale
        if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo <= hi):
            raise ValueError(f"noise_scale must be a range 0 <= LO <= HI, got LO={lo:g} HI={hi:g}")


def orientation(view: int) -> np.ndarray:
    """3x3 rotation of view number ``view`` on the 11 x 6 x 11 roll-pitch-yaw grid (about 0.57 rad steps)."""
    nr, np_, ny = ORIENTATION_GRID
    r, rest = divmod(view, np_ * ny)
    p, y = divmod(rest, ny)
    roll, yaw = 2 * np.pi * r / nr, 2 * np.pi * y / ny
    pitch = -np.pi / 2 + np.pi * (p + 0.5) / np_
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def view_indices(name: str, config: GenerationConfig) -> np.ndarray:
    """The views rendered for one object: all 726, or a subset fixed by the seed and the name."""
    total = int(np.prod(ORIENTATION_GRID))
    if config.views is None or config.views >= total:
        return np.arange(total)
    rng = np.random.default_rng(catalogue.object_seed(name, config.seed))
    return np.sort(rng.choice(total, size=config.views, replace=False))


def view_pose(name: str, view: int, seed: int) -> np.ndarray:
    """T_cam_obj (4x4): the object's pose in the camera frame for one view (metres)."""
    rng = np.random.default_rng(catalogue.object_seed(name, seed, view))
    d = rng.uniform(*DISTANCE_RANGE)
    T = np.eye(4)
    T[:3, :3] = orientation(view)
    # A small offset from the optical axis varies the perspective as in a real scene.
    T[:3, 3] = [rng.uniform(-0.12, 0.12) * d, rng.uniform(-0.1, 0.1) * d, d]
    return T


def view_noise_scale(name: str, view: int, config: GenerationConfig) -> float:
    """The depth-error factor of one view, drawn from ``config.noise_scale`` (seeded by the view)."""
    lo, hi = config.noise_scale
    if hi == lo:
        return float(lo)
    rng = np.random.default_rng(catalogue.object_seed(name, config.seed, view, 29))
    return float(rng.uniform(lo, hi))


def noise_seed(seed: int, view: int) -> list[int]:
    """The sensor-noise seed of one view (shared by training data and evaluation renders)."""
    return [seed, int(view), 7]


def render_view(
    renderer: RaycastRenderer, T_cam_obj: np.ndarray, intr: Intrinsics, noise: DepthNoise | None, seed
) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points (N, 3) metres of an object at ``T_cam_obj``: ``(ideal, measured)``.

    ``measured`` has the sensor model applied (the same array as ``ideal`` without noise).
    """
    # The renderer holds the mesh in its own frame: the camera's pose there is inv(T_cam_obj).
    depth, _ = renderer.render(intr, np.linalg.inv(T_cam_obj))
    ideal = backproject_valid(depth, intr)
    return ideal, (backproject_valid(noise.apply(depth, seed), intr) if noise is not None else ideal)


def generate_object(name: str, out_dir: str | Path, config: GenerationConfig = GenerationConfig()) -> dict:
    """Render and voxelize every requested view of one object into ``out_dir/shards/<name>.npz``.

    Returns a summary dict (views tried, kept, rejected, seconds). Skips work if the shard exists.
    """
    shard = Path(out_dir) / "shards" / (name.replace("/", "__") + ".npz")
    if shard.exists():
        with np.load(shard) as z:
            arrays = dict(z)
        if "yfrac" not in arrays:
            arrays["yfrac"] = _fractions_of_shard(name, arrays)
            _write_shard(shard, arrays)
        return {"name": name, "kept": int(len(arrays["views"])), "skipped": True}
    if config.scenes not in ("sphere", "tabletop"):
        raise ValueError(f"unknown scenes {config.scenes!r} (use 'sphere' or 'tabletop')")
    t0 = time.perf_counter()
    views = _tabletop_examples(name, config) if config.scenes == "tabletop" else _sphere_examples(name, config)
    rows, rejected = [], {"few_voxels": 0, "outside": 0, "no_view": 0}
    for r in views:
        if isinstance(r, str):
            rejected[r] += 1
        else:
            rows.append(r)
    packed = GRID_DIM**3 // 8
    stack = lambda k, shape, dtype: np.array([r[k] for r in rows], dtype).reshape(shape)  # noqa: E731
    n = len(rows)
    arrays = {
        "x": stack("x", (n, packed), np.uint8),
        "y": stack("y", (n, packed), np.uint8),
        "yfrac": stack("yfrac", (n, GRID_DIM**3), np.uint8),
        "free": stack("free", (n, packed), np.uint8),
        "below": stack("below", (n, packed), np.uint8),
        "views": stack("view", (n,), np.int32),
        "center": stack("center", (n, 3), np.float64),
        "voxel_size": stack("voxel_size", (n,), np.float64),
        "T_cam_obj": stack("T", (n, 3, 4), np.float64),
        "plane": stack("plane", (n, 4), np.float64),
    }
    _write_shard(shard, arrays)
    return {"name": name, "kept": n, "rejected": rejected, "seconds": time.perf_counter() - t0, "skipped": False}


def _write_shard(path: Path, arrays: dict) -> None:
    # Compressed: the soft labels are 64 kB per view uncompressed, and almost all 0 or 255.
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    atomic_write(path, buf.getvalue())


def quantize_fraction(fraction: np.ndarray) -> np.ndarray:
    """A :func:`voxel.solid_fraction` grid as uint8 (255 = full), as shards store it."""
    return np.round(np.asarray(fraction) * 255).astype(np.uint8)


def _fractions_of_shard(name: str, arrays: dict) -> np.ndarray:
    """The soft labels (n, 64000) uint8 of a shard written before they existed, from its stored
    poses, grid frames and Y (the object's mesh in the same frame generation posed it in)."""
    mesh = catalogue.centred_mesh(name)
    scene = raycasting_scene(mesh)
    out = np.empty((len(arrays["views"]), GRID_DIM**3), np.uint8)
    for i in range(len(out)):
        frame = GridFrame(arrays["center"][i], float(arrays["voxel_size"][i]))
        T = np.vstack([arrays["T_cam_obj"][i], [0.0, 0.0, 0.0, 1.0]])
        y = np.unpackbits(arrays["y"][i]).reshape((GRID_DIM,) * 3).astype(bool)
        out[i] = quantize_fraction(solid_fraction(mesh, frame, y, T, scene=scene)).ravel()
    return out


def _example(
    view: int,
    x: np.ndarray,
    y: np.ndarray,
    yfrac: np.ndarray,
    context: np.ndarray,
    frame,
    T: np.ndarray,
    plane: np.ndarray | None,
) -> dict:
    return {
        "view": int(view),
        "x": np.packbits(x.ravel()),
        "y": np.packbits(y.ravel()),
        "yfrac": quantize_fraction(yfrac).ravel(),
        "free": np.packbits(context[0].ravel()),
        "below": np.packbits(context[1].ravel()),
        "center": frame.center,
        "voxel_size": frame.voxel_size,
        "T": T[:3, :],
        "plane": np.full(4, np.nan) if plane is None else np.asarray(plane, np.float64),
    }


def _sphere_examples(name: str, config: GenerationConfig):
    """The paper's views: the object floating alone on the roll-pitch-yaw grid (yields examples or
    the reason a view was rejected)."""
    mesh = catalogue.centred_mesh(name)
    renderer = RaycastRenderer([mesh])
    intr = Intrinsics.kinect()
    noise = KinectNoise() if config.noise else None
    surface = surface_samples(mesh, spacing=np.sort(mesh.extents)[1] / 32 / 2)
    for view in view_indices(name, config):
        T = view_pose(name, int(view), config.seed)
        scaled = noise.scaled(view_noise_scale(name, int(view), config)) if noise is not None else None
        ideal, measured = render_view(renderer, T, intr, scaled, noise_seed(config.seed, view))
        if len(measured) < 10 or len(ideal) < 10:
            yield "few_voxels"
            continue
        x, frame = partial_to_grid(measured, depth_shift=config.depth_shift)
        if x.sum() < MIN_X_VOXELS:
            yield "few_voxels"
            continue
        y = solid_grid(mesh, frame, T, surface_points=surface, scene=renderer.scene)
        # The paper's 80% rule judges the view's geometry, so it looks at the noise-free points:
        # sensor noise alone pushes some measured points into the voxels just outside Y.
        x_ideal = points_to_grid(ideal, frame)
        if (x_ideal & y).sum() < MIN_X_INSIDE_Y * x_ideal.sum():
            yield "outside"
            continue
        yfrac = solid_fraction(mesh, frame, y, T, scene=renderer.scene)
        yield _example(view, x, y, yfrac, context_grids(measured, frame), frame, T, None)


def _tabletop_examples(name: str, config: GenerationConfig):
    """Tabletop views (:func:`tabletop.render_tabletop_view`), ``config.views`` of them (default 32)."""
    from scipy import ndimage

    from ..sim.tabletop import render_tabletop_view

    mesh = catalogue.centred_mesh(name)
    scene = raycasting_scene(mesh)
    surface = surface_samples(mesh, spacing=np.sort(mesh.extents)[1] / 32 / 2)
    for view in range(config.views or 32):
        v = render_tabletop_view(name, view, seed=config.seed, noise_scale=view_noise_scale(name, view, config))
        if v is None:
            yield "no_view"
            continue
        x, frame = partial_to_grid(v.points_cam, depth_shift=config.depth_shift)
        if x.sum() < MIN_X_VOXELS:
            yield "few_voxels"
            continue
        y = solid_grid(mesh, frame, v.T_cam_obj, surface_points=surface, scene=scene)
        if (x & ndimage.binary_dilation(y)).sum() < MIN_X_INSIDE_Y * x.sum():
            yield "outside"
            continue
        yfrac = solid_fraction(mesh, frame, y, v.T_cam_obj, scene=scene)
        context = context_grids(v.points_cam, frame, support_plane=v.plane_cam)
        yield _example(view, x, y, yfrac, context, frame, v.T_cam_obj, v.plane_cam)


def _task(args):
    name, out_dir, config = args
    try:
        return generate_object(name, out_dir, config)
    except Exception as e:  # one broken object must not stop a day-long run
        log.exception("generation failed for %s", name)
        return {"name": name, "kept": 0, "error": repr(e), "skipped": False}


def generate(
    out_dir: str | Path,
    config: GenerationConfig = GenerationConfig(),
    objects: list[str] | None = None,
    workers: int | None = None,
    backend: str = "process",
    progress: bool = True,
    *,
    objects_dirs: list[str] | list[Path] | None = None,
) -> dict:
    """Generate shards for many objects (all catalogue objects by default) and write the manifest.

    ``backend`` is ``process`` (all cores of this machine) or ``ray`` (a Ray cluster, ``ray.init()``
    connects to ``RAY_ADDRESS`` or starts a local one). ``objects_dirs``: folders of URDF objects
    (:mod:`shapeviewer.sim.urdf_objects`) whose ``urdf/<set>/<NAME>`` objects join the catalogue for
    this run and its worker processes (:func:`catalogue.objects_from`; a Ray cluster's nodes read
    ``SHAPEVIEWER_OBJECTS`` of their own).
    """
    with catalogue.objects_from(objects_dirs):
        return _generate(out_dir, config, objects, workers, backend, progress)


def _generate(
    out_dir: str | Path,
    config: GenerationConfig,
    objects: list[str] | None,
    workers: int | None,
    backend: str,
    progress: bool,
) -> dict:
    from tqdm import tqdm

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    earlier = folder_depth_shift(out_dir)
    if earlier is None:  # record the placement before the first shard, so an interrupted run is guarded too
        write_manifest(out_dir, config)
    elif earlier != config.depth_shift:
        raise ValueError(
            f"{out_dir} holds views made with depth_shift={earlier:g}; adding views with "
            f"depth_shift={config.depth_shift:g} would mix two grid placements (use another folder)"
        )
    names = objects or [e.name for e in catalogue.catalogue()]
    tasks = [(n, str(out_dir), config) for n in names]
    t0 = time.perf_counter()
    results = []
    bar = tqdm(total=len(tasks), desc="objects", unit="obj", disable=not progress)
    if backend == "ray":
        import ray

        from ..runtime.backends import ray_init

        ray_init(workers)
        remote = ray.remote(_task)
        pending = [remote.remote(t) for t in tasks]
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            results.append(ray.get(done[0]))
            bar.update(1)
    elif backend == "process":
        import multiprocessing as mp

        workers = workers or os.cpu_count() or 1
        if workers == 1:
            for t in tasks:
                results.append(_task(t))
                bar.update(1)
        else:
            with mp.get_context("spawn").Pool(workers) as pool:
                for r in pool.imap_unordered(_task, tasks):
                    results.append(r)
                    bar.update(1)
    else:
        raise ValueError(f"unknown backend {backend!r} (use 'process' or 'ray')")
    bar.close()
    seconds = time.perf_counter() - t0
    manifest = write_manifest(out_dir, config)
    new_views = sum(r.get("kept", 0) for r in results if not r.get("skipped"))
    return {
        "objects": len(results),
        "errors": [r for r in results if "error" in r],
        "seconds": seconds,
        "new_views": new_views,
        "views_per_second": new_views / seconds if seconds > 0 else 0.0,
        "examples": manifest["examples"],
    }


def shard_files(out_dir: str | Path) -> list[Path]:
    """The finished shards of a ``generate`` folder, sorted (a folder still being filled gives the
    shards written so far; an older version's interrupted ``*.tmp.npz`` partials are skipped)."""
    return sorted(p for p in (Path(out_dir) / "shards").glob("*.npz") if not p.name.endswith(".tmp.npz"))


def folder_depth_shift(out_dir: str | Path) -> float | None:
    """The grid placement (voxels, :attr:`GenerationConfig.depth_shift`) a ``generate`` folder's
    manifest records: 0 for folders from before the option, None before a manifest is written."""
    manifest = Path(out_dir) / "manifest.json"
    if not manifest.exists():
        return None
    return float(json.loads(manifest.read_text())["config"].get("depth_shift", 0.0))


def write_manifest(out_dir: str | Path, config: GenerationConfig) -> dict:
    """Index every shard in ``out_dir``: object, split, view count and per-split example counts."""
    out_dir = Path(out_dir)
    shards = []
    examples = {"training_view": 0, "holdout_view": 0, "holdout_model": 0}
    for p in shard_files(out_dir):
        name = p.stem.replace("__", "/")
        with np.load(p) as z:
            views = z["views"].tolist()
        for v in views:
            examples[catalogue.view_split(name, v)] += 1
        shards.append(
            {"file": f"shards/{p.name}", "object": name, "split": catalogue.model_split(name), "views": len(views)}
        )
    manifest = {
        "version": 1,
        "grid": GRID_DIM,
        "orientation_grid": ORIENTATION_GRID,
        "config": {
            "views": config.views,
            "noise": config.noise,
            "seed": config.seed,
            "scenes": config.scenes,
            "noise_scale": list(config.noise_scale),
            "depth_shift": config.depth_shift,
        },
        "camera": Intrinsics.kinect().to_dict(),
        "examples": examples,
        "shards": shards,
    }
    atomic_write(out_dir / "manifest.json", json.dumps(manifest, indent=1))
    return manifest
