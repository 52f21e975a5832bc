"""The ``shapeviewer`` command's jobs (``cmd_*``, one per subcommand) and :func:`main`, which runs one.

The arguments and the usage text are in :mod:`.cli_parser`.
"""

from __future__ import annotations

import json
import logging
import shutil
import sys
import time
import traceback
from pathlib import Path

import numpy as np

from ..errors import ShapeviewerError
from .parser import build_parser


def _intrinsics(args, shape=None):
    from ..perception.camera import Intrinsics

    if all(getattr(args, k) is None for k in ("fx", "fy", "cx", "cy")):
        return None
    base = Intrinsics.kinect()
    return Intrinsics(
        base.width,
        base.height,
        args.fx or base.fx,
        args.fy or args.fx or base.fy,
        base.cx if args.cx is None else args.cx,
        base.cy if args.cy is None else args.cy,
    )


def load_input(spec: str, seed: int = 0, intrinsics=None):
    """A :class:`~shapeviewer.perception.capture.Capture` from ``default`` (the generated scene) or a file path."""
    if spec == "default":
        from ..sim.demo_scene import default_scene

        return default_scene(seed)
    from ..perception.capture import load_capture

    return load_capture(spec, intrinsics=intrinsics)


class CLIError(ShapeviewerError, ValueError):
    """A problem with the command's arguments or input, said in one line."""


# Commands whose option names a folder they create: removed again if the command fails and leaves it empty.
OUT_FOLDERS = {"complete": "out", "generate": "out", "evaluate": "out", "train": "run", "clutter": "out"}


def _new_folders(path: Path, option: str) -> list[Path]:
    """The folders of ``path`` (itself, then its parents) that do not exist yet; raises when
    ``path`` exists as something other than a folder (``option`` names it in the message)."""
    if path.exists() and not path.is_dir():
        raise CLIError(f"--{option} {path}: exists and is not a folder")
    missing = []
    while not path.exists() and path != path.parent:
        missing.append(path)
        path = path.parent
    return missing


def _remove_empty(folders: list[Path]) -> None:
    """Remove ``folders`` (deepest first) that hold no file, e.g. after a failed command created them."""
    for folder in folders:
        if folder.is_dir() and not any(p.is_file() or p.is_symlink() for p in folder.rglob("*")):
            shutil.rmtree(folder, ignore_errors=True)


def cmd_serve(args) -> int:
    from ..viewer import serve

    try:
        serve(
            host=args.host,
            port=args.port,
            seed=args.seed,
            cloud=args.cloud,
            weights=args.weights,
            intrinsics=_intrinsics(args),
            results=args.results,
            allow_hosts=tuple(args.allow_host),
            data_dir=args.data_dir,
        )
    except OSError as e:  # e.g. a bad --cloud path: say so instead of a traceback
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


def cmd_complete(args) -> int:
    from .. import export
    from ..completion.model import load_completer
    from ..completion.pipeline import SegmentTooSmallError, check_segment, complete_points, completion_detailed_mesh
    from ..perception.segment import segment_scene, world_frame

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    capture = load_input(args.input, args.seed, _intrinsics(args))
    t_load = time.perf_counter() - t0
    seg = segment_scene(capture)
    T_world_cam, _ = world_frame(capture, seg)
    if not seg.segments:
        raise CLIError(
            f"{capture.source}: no segments found (nothing stands on a support plane among its "
            f"{int(capture.valid_mask().sum()):,} valid points); nothing to complete"
        )
    wanted = seg.segments if args.segment == "all" else [s for s in seg.segments if str(s.id) == args.segment]
    if not wanted:
        raise CLIError(
            f"no segment {args.segment!r}; the capture has segments {', '.join(str(s.id) for s in seg.segments)}"
        )
    completer = load_completer(args.weights)
    report = {
        "input": capture.source,
        "load_seconds": t_load,
        "segmentation": seg.timings,
        "model": {"arch": completer.arch, "trained": completer.trained, "weights": completer.source},
        "T_world_cam": np.asarray(T_world_cam).tolist(),
        "segments": [],
    }
    usable = []
    for s in wanted:
        entry = {"id": s.id, "label": s.label, "points": int(len(s.points_cam))}
        try:
            check_segment(s.points_cam)
            usable.append(s)
        except SegmentTooSmallError as exc:
            entry["error"] = str(exc)
        report["segments"].append(entry)
    completions = complete_points(
        [s.points_cam for s in usable],
        completer,
        [s.id for s in usable],
        support_plane=seg.plane_cam,
        revolve_answers=args.revolve,
        fit_boxes=args.boxes,
    )
    by_id = {e["id"]: e for e in report["segments"]}
    for s, c in zip(usable, completions):
        e = by_id[s.id]
        e.update(
            {
                "grid_frame": c.frame.to_dict(),
                "timings": c.timings,
                "input_voxels": int(c.grid_in.sum()),
                "output_voxels": int(c.grid_out.sum()),
                "revolved": c.revolved,
                "boxed": c.boxed,
            }
        )
        if c.cuboid is not None:
            e["box"] = {
                "extents_m": c.cuboid.extents.tolist(),
                "residual_m": c.cuboid.residual,
                "fill": c.cuboid.fill,
                "aligned": c.cuboid.aligned,
            }
        if c.axis is not None:
            e["revolution_axis"] = {
                "residual_m": c.axis.residual,
                "radius_m": c.axis.radius,
                "coverage_deg": c.axis.coverage_deg,
            }
        (out / f"segment_{s.id}_points.ply").write_bytes(
            export.points_ply_bytes(s.points_cam, frame=args.frame, T_world_cam=T_world_cam)
        )
        samples = c.samples[: args.samples] if args.samples else None
        (out / f"segment_{s.id}_grids.npz").write_bytes(
            export.grids_npz_bytes(
                c.grid_in, c.probabilities, c.frame, T_world_cam, grid_out=c.grid_out, samples=samples
            )
        )
        if samples is not None:
            e["samples"] = _write_sample_meshes(
                c, samples, out / f"segment_{s.id}", args.format, args.frame, T_world_cam
            )
        if c.fast_mesh is None:
            e["error"] = c.error
            continue
        path = out / f"segment_{s.id}_fast.{args.format}"
        path.write_bytes(export.mesh_bytes(c.fast_mesh, args.format, args.frame, T_world_cam))
        e["mesh"] = {
            "fast": path.name,
            "frame": args.frame,
            "watertight": bool(c.fast_mesh.is_watertight),
            "volume_m3": float(c.fast_mesh.volume),
        }
        if args.mode == "detailed":
            steps: dict[str, float] = {}
            t0 = time.perf_counter()
            mesh = completion_detailed_mesh(c, s.points_cam, timings=steps)
            c.timings["detailed_mesh"] = time.perf_counter() - t0
            e["detailed_steps"] = steps
            path = out / f"segment_{s.id}_detailed.{args.format}"
            path.write_bytes(export.mesh_bytes(mesh, args.format, args.frame, T_world_cam))
            e["mesh"].update(
                {
                    "detailed": path.name,
                    "detailed_watertight": bool(mesh.is_watertight),
                    "detailed_volume_m3": float(mesh.volume),
                }
            )
    (out / "report.json").write_text(json.dumps(report, indent=1))
    done = sum("mesh" in e for e in report["segments"])
    print(f"{done}/{len(report['segments'])} segments completed -> {out}/report.json")
    return 0


def _write_sample_meshes(c, samples: np.ndarray, stem: Path, fmt: str, frame: str, T_world_cam: np.ndarray) -> dict:
    """Write the fast mesh of each of ``samples``, the first of completion ``c``'s sample
    completions (``<stem>_sample_<k>.<fmt>``); returns the report entry: the files (None for an
    empty sample) and the viewer's confidence figures over them
    (:func:`~shapeviewer.completion.pipeline.confidence_figures`): the mean spread on the seen and the unseen
    side, and the share of completed voxels that are a guess."""
    from .. import export
    from ..completion.model import sample_spread
    from ..completion.pipeline import confidence_figures
    from ..completion.reconstruct import fast_mesh

    files: list[str | None] = []
    for k, probabilities in enumerate(samples):
        try:
            mesh = fast_mesh(probabilities, c.frame, level=c.mesh_level)
        except ValueError:  # an empty sample: nothing to mesh
            files.append(None)
            continue
        path = stem.with_name(f"{stem.name}_sample_{k}.{fmt}")
        path.write_bytes(export.mesh_bytes(mesh, fmt, frame, T_world_cam))
        files.append(path.name)
    sides, guessed = confidence_figures(c.grid_in, c.solid, sample_spread(samples))
    return {"n": len(samples), "meshes": files, "mean_spread": dict(sides), "guessed_share": guessed}


def cmd_grasp(args) -> int:
    out = Path(args.out)
    if out.is_dir():
        raise CLIError(f"--out {out} is a folder; give a file name (grasps.json or scene.zip)")
    if not out.parent.is_dir():
        raise CLIError(f"--out {out}: the folder {out.parent} does not exist")
    if args.budget is not None and not args.budget > 0:
        raise CLIError(f"--budget must be a positive number of seconds, got {args.budget}")
    from ..grasp.serialize import plan_mesh_file

    grasps = plan_mesh_file(
        args.mesh,
        args.out,
        hand=args.hand,
        n_grasps=args.n,
        seed=args.seed,
        on_table=not args.no_table,
        budget_seconds=args.budget,
    )
    best = max((g.epsilon for g in grasps), default=float("nan"))
    lifted = sum(g.lifted for g in grasps)
    print(f"{len(grasps)} grasps (best epsilon {best:.3f}; {lifted} lift the mesh in simulation, first) -> {args.out}")
    return 0


def cmd_objects(args) -> int:
    from ..sim import catalogue

    if args.write_index:
        catalogue.clear_caches()
        for p in (catalogue.cache_dir() / f"catalogue_v{catalogue.CATALOGUE_VERSION}.json", catalogue.SHIPPED_INDEX):
            p.unlink(missing_ok=True)  # rebuild from the meshes themselves
        # The shipped index holds the package's own objects only, never a user's folders.
        catalogue.write_index(catalogue.catalogue(objects_dirs=()), Path(args.write_index))
        print(f"catalogue index -> {args.write_index}")
    with catalogue.objects_from(args.objects_dir) as folders:
        rows = catalogue.catalogue()
        skipped = {folder: catalogue.urdf_skipped(folder) for folder in folders}
    if args.json:
        print(
            json.dumps(
                [
                    {
                        "name": e.name,
                        "split": e.split,
                        "source": e.source,
                        "kind": catalogue.shape_kind(e.name),
                        "size_m": [round(x, 4) for x in e.extents],
                    }
                    for e in rows
                ],
                indent=1,
            )
        )
        return 0
    width = max([34, *(len(e.name) for e in rows)])
    print(f"{'name':{width}s} {'split':14s} {'source':9s} {'kind':13s} size (cm)")
    for e in rows:
        size = " x ".join(f"{x * 100:.1f}" for x in e.extents)
        print(f"{e.name:{width}s} {e.split:14s} {e.source:9s} {catalogue.shape_kind(e.name):13s} {size}")
    counts = {s: sum(e.split == s for e in rows) for s in ("train", "holdout_model")}
    print(f"{len(rows)} objects: {counts['train']} train, {counts['holdout_model']} holdout models")
    for folder, missed in skipped.items():
        listed = [e for e in rows if e.source == "urdf" and Path(e.path).is_relative_to(folder)]
        held = sum(e.split == "holdout_model" for e in listed)
        print(f"{folder}: {len(listed)} objects ({len(listed) - held} train, {held} holdout), {len(missed)} skipped")
        for what, why in missed:
            print(f"  skipped {what}: {why}")
    return 0


def cmd_generate(args) -> int:
    from ..training.generate import GenerationConfig, generate

    r = generate(
        args.out,
        GenerationConfig(
            views=args.views,
            noise=not args.no_noise,
            seed=args.seed,
            scenes=args.scenes,
            noise_scale=tuple(args.noise_scale),
            depth_shift=args.depth_shift,
        ),
        objects=args.objects,
        workers=args.workers,
        backend=args.backend,
        objects_dirs=args.objects_dir,
    )
    print(json.dumps({k: v for k, v in r.items() if k != "errors"}, indent=1))
    for e in r["errors"]:
        print(f"error: {e['name']}: {e['error']}", file=sys.stderr)
    return 0


def cmd_train(args) -> int:
    from ..training.train import TrainConfig, train

    cfg = TrainConfig(
        arch=args.arch,
        steps=args.steps,
        batch_size=args.batch_size,
        lr=args.lr,
        eval_every=args.eval_every,
        eval_views=args.eval_views,
        snapshot_every=args.snapshot_every,
        seed=args.seed,
        width=args.width,
        in_channels=args.in_channels,
        init=args.init,
        jaccard_weight=args.jaccard_weight,
        label=args.label,
    )
    print(json.dumps(train(args.data, args.run, cfg), indent=1))
    return 0


def cmd_average(args) -> int:
    from ..training.averaging import average_weights

    average_weights(args.weights, args.out, note=args.note)
    print(f"mean of {len(args.weights)} weights files -> {args.out}")
    return 0


def cmd_evaluate_grids(args) -> int:
    from ..completion.model import load_completer
    from ..training.train import check_placement, evaluate_grids, load_grid_sets

    completer = load_completer(args.weights)
    check_placement(completer, args.data)
    sets = load_grid_sets(args.data)
    if args.kinds:
        import numpy as np

        from ..sim.catalogue import shape_kind

        sets = {
            s: gs.subset(np.flatnonzero([shape_kind(str(o)) in args.kinds for o in gs.objects]))
            for s, gs in sets.items()
        }
        if not any(len(gs) for gs in sets.values()):
            raise ValueError(f"no views of kinds {', '.join(args.kinds)} in {', '.join(args.data)}")
    # The paper's metric: the output grid against Y.
    r = evaluate_grids(
        completer, sets, max_views=args.views, seed=args.seed, level=completer.grid_level, samples=args.samples
    )
    answer = "one answer (the view as seen)" if args.samples == 1 else f"mean of {args.samples} mirrored answers"
    print(f"Jaccard at 40^3 against the paper's Y, {answer} p > {completer.grid_level:g}")
    print(f"{'set':15s} {'views':>6s} {'Jaccard':>8s} {'input only':>10s}")
    for s, v in r.items():
        print(f"{s:15s} {v['views']:6d} {v['jaccard']:8.3f} {v['input_jaccard']:10.3f}")
    if args.by_kind:
        names = list(r)
        print(f"\n{'kind':15s}" + "".join(f" {s:>15s}" for s in names) + "   (Jaccard, views)")
        for kind in sorted({k for v in r.values() for k in v["by_kind"]}):
            cells = [r[s]["by_kind"].get(kind) for s in names]
            print(
                f"{kind:15s}" + "".join(f" {c['jaccard']:9.3f} {c['views']:5d}" if c else f" {'-':>15s}" for c in cells)
            )
    if args.json:
        Path(args.json).write_text(json.dumps(r, indent=1))
    if args.card:
        from ..training.model_card import model_card

        Path(args.card).write_text(model_card(completer, r, args.data))
        print(f"model card -> {args.card}")
    return 0


def cmd_evaluate(args) -> int:
    from ..evaluation.run import GRASP_METHODS, GraspOptions, evaluate

    grasps = None
    if args.grasps:
        grasps = GraspOptions(
            methods=tuple(args.grasp_methods or GRASP_METHODS),
            hand=args.hand,
            n_grasps=args.n_grasps,
            budget_seconds=args.grasp_budget,
            robust=args.robust,
            widen_below=args.widen_below,
        )
    from ..sim.catalogue import objects_from

    with objects_from(args.objects_dir):  # the test views are drawn from these objects too
        r = evaluate(
            args.out,
            n_per_set=args.views_per_set,
            seed=args.seed,
            weights=args.weights,
            workers=args.workers,
            backend=args.backend,
            progress=not args.no_progress,
            grasps=grasps,
            views=args.views,
        )
    print(r["tables_md"])
    print(f"{r['computed']} views computed, {r['skipped']} already done, {r['seconds']:.1f} s -> {args.out}")
    return 0


def cmd_clutter(args) -> int:
    from ..clutter.run import clear_table

    summary = clear_table(
        args.out,
        scene=args.scene,
        objects=args.objects,
        setup=args.setup,
        rounds=args.rounds,
        seeds=args.seeds,
        methods=args.methods,
        count=args.objects_per_round,
        attempt_seconds=args.attempt_seconds,
        report=lambda line: print(line, flush=True),
    )
    for name, m in summary["methods"].items():
        print(
            f"{name}: GSR {m['gsr']:.1f} +- {m['gsr_std']:.1f} %, DR {m['dr']:.1f} +- {m['dr_std']:.1f} % "
            f"({m['successes']}/{m['attempts']} attempts, {m['objects']} objects) -> {args.out}/summary.json"
        )
    return 0


COMMANDS = {
    "serve": cmd_serve,
    "complete": cmd_complete,
    "grasp": cmd_grasp,
    "objects": cmd_objects,
    "generate": cmd_generate,
    "train": cmd_train,
    "average": cmd_average,
    "evaluate-grids": cmd_evaluate_grids,
    "evaluate": cmd_evaluate,
    "clutter": cmd_clutter,
}


def _import_pybullet_quietly() -> None:
    """Import pybullet without its build banner (:mod:`..runtime.bullet`): the command's stderr is
    for its own messages (an error is one line)."""
    try:
        from ..runtime import bullet  # noqa: F401
    except ImportError:  # reported where it is needed
        pass


def main(argv: list[str] | None = None) -> int:
    """Run one command. Failures are one line on stderr and exit code 2 (1 for an unexpected error,
    with its traceback under ``-v``); Ctrl-C stops any command within seconds (exit code 130,
    no child process left: :mod:`.interrupt`). A folder the command created and left empty is removed."""
    from ..runtime.interrupt import interrupt_watch, interrupted, kill_descendants

    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s"
    )
    if args.command != "objects":
        _import_pybullet_quietly()
    created: list[Path] = []
    ok = False
    with interrupt_watch():
        try:
            if args.command in OUT_FOLDERS:
                created = _new_folders(Path(getattr(args, OUT_FOLDERS[args.command])), OUT_FOLDERS[args.command])
            code = COMMANDS[args.command](args)
            ok = code == 0
            return code
        except KeyboardInterrupt:
            kill_descendants()  # here too: the watcher thread dies with the process, maybe before it is done
            print("shapeviewer: interrupted", file=sys.stderr)
            return 130
        except Exception as e:
            if interrupted():  # Ctrl-C killed a child (V-HACD) and its failure surfaced first
                kill_descendants()
                print("shapeviewer: interrupted", file=sys.stderr)
                return 130
            if args.verbose:
                traceback.print_exc()
            if isinstance(e, (ValueError, OSError, KeyError, RuntimeError)):
                # CaptureError, MeshError, DecompositionError, a missing file...: the message says it all.
                print(f"error: {e}", file=sys.stderr)
                return 2
            # A bug: still one line, the traceback with -v.
            print(f"error: unexpected {type(e).__name__}: {e} (run with -v for the traceback)", file=sys.stderr)
            return 1
        finally:
            if not ok:
                _remove_empty(created)


if __name__ == "__main__":
    sys.exit(main())
