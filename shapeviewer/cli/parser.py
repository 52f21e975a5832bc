"""The ``shapeviewer`` command: the viewer's jobs, headless.

shapeviewer serve [--port 8080] [--cloud PATH] [--seed N] [--weights PATH] [--results DIR] [--data-dir DIR]
shapeviewer complete INPUT --segment K|all --mode fast|detailed --out DIR
shapeviewer grasp MESH --hand barrett|panda --out grasps.json|scene.zip
shapeviewer objects [--objects-dir DIR ...]
shapeviewer generate --out DIR [--views N] [--backend process|ray] [--objects-dir DIR ...]
shapeviewer train --data DIR --run DIR [--steps N]
shapeviewer average A.pt B.pt --out C.pt
shapeviewer evaluate-grids --data DIR [--weights PATH] [--by-kind] [--kinds mug bowl ...] [--samples 1]
shapeviewer evaluate --out DIR [--views paper|tabletop] [--views-per-set 50] [--seed 0] [--weights PATH]
                     [--workers N] [--backend process|ray] [--objects-dir DIR ...]
                     [--grasps [--hand barrett|panda] [--n-grasps 20] [--grasp-budget S] [--grasp-methods M ...]
                               [--robust]]
shapeviewer clutter --scene pile|packed --objects DIR [--setup DIR] --rounds N --seeds S ... --methods M ... --out DIR
"""

from __future__ import annotations

import argparse

from ..runtime.backends import BACKENDS


def _number(kind: type, low: float | None = None, high: float | None = None, *, above: bool = False):
    """An argparse ``type`` that parses ``kind`` and refuses values outside [low, high] (``above``:
    strictly greater than ``low``), so a bad option stops the command before it runs, with a clear
    message, instead of a run whose results are wrong."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not a {'whole number' if kind is int else 'number'}"
            ) from None
        if kind is float and value != value:
            raise argparse.ArgumentTypeError("NaN is not a valid value")
        if low is not None and (value <= low if above else value < low):
            raise argparse.ArgumentTypeError(f"{text} must be {'>' if above else '>='} {low:g}")
        if high is not None and value > high:
            raise argparse.ArgumentTypeError(f"{text} must be <= {high:g}")
        return value

    parse.__name__ = kind.__name__  # argparse names the type in its messages
    return parse


COUNT = _number(int, 1)  # how many of something: at least one
SEED = _number(int, 0, 2**32 - 1)  # numpy's seed range
PORT = _number(int, 1, 65535)
SECONDS = _number(float, 0.0, above=True)
SHARE = _number(float, 0.0, 1.0)
PIXELS = _number(float, 0.0, above=True)


def _add_input_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seed", type=SEED, default=0, help="seed of the generated default scene")
    p.add_argument("--weights", default=None, help="CNN weights (.pt); default: the shipped model")
    for k in ("fx", "fy", "cx", "cy"):
        p.add_argument(f"--{k}", type=PIXELS, default=None, help=f"depth-image intrinsics {k} (pixels)")


def _add_objects_dir(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--objects-dir",
        action="append",
        default=[],
        metavar="DIR",
        help="also use the objects of this folder of URDF files (NAME.urdf beside its visual mesh, metres; "
        "named urdf/<set>/<NAME>); repeatable. Default: the folders in SHAPEVIEWER_OBJECTS, if any",
    )


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="shapeviewer", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("-v", "--verbose", action="store_true")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("serve", help="start the web viewer (same as python app.py)")
    s.add_argument("--host", default="127.0.0.1", help="interface to listen on (0.0.0.0 for all)")
    s.add_argument("--port", type=PORT, default=8080, help="port (the next free one is used if busy)")
    s.add_argument("--cloud", default=None, help="a .pcd/.ply cloud or a depth image (.png mm / .npy m)")
    s.add_argument(
        "--results",
        default=None,
        metavar="DIR",
        help="results folder of `shapeviewer evaluate` for the Dataset tab (default: a small sample "
        "store, built in the user cache on first run)",
    )
    s.add_argument(
        "--allow-host",
        action="append",
        default=[],
        metavar="NAME",
        help="another name browsers reach this server by (besides localhost and --host); repeatable",
    )
    s.add_argument(
        "--data-dir",
        default=None,
        metavar="DIR",
        help="a folder whose capture files browsers may load (default: none; browsers can upload their own)",
    )
    _add_input_args(s)

    s = sub.add_parser("complete", help="segment a capture and complete segments headless")
    s.add_argument("input", help="'default' (generated scene), a .pcd/.ply cloud, or a depth image")
    s.add_argument("--segment", default="all", help="segment id or 'all'")
    s.add_argument("--mode", default="fast", choices=["fast", "detailed"])
    s.add_argument("--out", required=True)
    s.add_argument("--format", default="ply", choices=["ply", "obj", "stl", "glb"])
    s.add_argument("--frame", default="world", choices=["world", "camera"])
    s.add_argument(
        "--samples",
        type=int,
        default=0,
        choices=range(9),
        metavar="N",
        help="also write N (1-8) sample completions: their per-voxel spread in the grids .npz and "
        "each sample's fast mesh (segment_<id>_sample_<k>)",
    )
    s.add_argument(
        "--revolve",
        action="store_true",
        help="revolve the network's answers about the table's normal for segments that look like a "
        "surface of revolution about it (bowls, cups, cans): closes an upside-down bowl's far side",
    )
    s.add_argument(
        "--no-boxes",
        dest="boxes",
        action="store_false",
        help="complete every segment as the network answers it, also those on the table whose points are a "
        "box's (by default completed as the box fitted to them)",
    )
    _add_input_args(s)

    s = sub.add_parser("grasp", help="plan grasps on a mesh file (metres, z up) and write JSON or a pybullet zip")
    s.add_argument("mesh")
    s.add_argument("--hand", default="barrett", choices=["barrett", "panda"])
    s.add_argument("--n", type=COUNT, default=20, help="number of distinct grasps")
    s.add_argument("--out", required=True, help="grasps.json, or a .zip for the pybullet-ready scene")
    s.add_argument("--seed", type=SEED, default=0)
    s.add_argument("--budget", type=SECONDS, default=None, help="planning time limit in seconds")
    s.add_argument("--no-table", action="store_true", help="plan without a table below the object")

    s = sub.add_parser("objects", help="list the object catalogue with split, source and size")
    s.add_argument("--json", action="store_true")
    s.add_argument(
        "--write-index",
        default=None,
        metavar="PATH",
        help="process every mesh again and write the index (static_assets/catalogue.json ships one)",
    )
    _add_objects_dir(s)

    s = sub.add_parser("generate", help="render training pairs (X, Y) for the catalogue objects")
    s.add_argument("--out", required=True)
    s.add_argument(
        "--views", type=COUNT, default=None, help="views per object (default: all 726 sphere views, 32 tabletop views)"
    )
    s.add_argument(
        "--scenes",
        default="sphere",
        choices=["sphere", "tabletop"],
        help="sphere: the paper's floating views; tabletop: the object on a table among neighbours, "
        "a robot's Kinect or RealSense, segmented by the app",
    )
    s.add_argument(
        "--objects",
        nargs="*",
        default=None,
        help="catalogue names (urdf/<set>/<NAME> of an --objects-dir folder), or generated ones it does not list "
        "(assembly/parts_000 ...); default: the catalogue",
    )
    s.add_argument("--no-noise", action="store_true", help="ideal depth instead of the Kinect sensor model")
    s.add_argument(
        "--noise-scale",
        type=_number(float, 0.0),
        nargs=2,
        default=(1.0, 1.0),
        metavar=("LO", "HI"),
        help="each view's depth error is the sensor model's times a factor drawn from LO-HI (default 1 1)",
    )
    s.add_argument(
        "--depth-shift",
        type=_number(float, 0.0),
        default=0.0,
        metavar="VOXELS",
        help="move each object up to this many voxels towards the camera in its grid, so deep objects "
        "stay inside it (default 0: the paper's placement; the shipped model uses 4)",
    )
    s.add_argument("--workers", type=COUNT, default=None)
    s.add_argument("--backend", default="process", choices=BACKENDS)
    s.add_argument("--seed", type=SEED, default=0)
    _add_objects_dir(s)

    s = sub.add_parser("train", help="train (or resume) a completion CNN")
    s.add_argument("--data", required=True, nargs="+", help="one or more `generate` folders, pooled")
    s.add_argument("--run", required=True)
    s.add_argument("--arch", default="unet3d", choices=["unet3d", "varley2017"])
    s.add_argument("--steps", type=COUNT, default=20000)
    s.add_argument("--batch-size", type=COUNT, default=32)
    s.add_argument("--lr", type=_number(float, 0.0, above=True), default=1e-4)
    s.add_argument("--eval-every", type=COUNT, default=500)
    s.add_argument("--eval-views", type=COUNT, default=200)
    s.add_argument(
        "--snapshot-every",
        type=_number(int, 0),
        default=0,
        help="keep the weights every this many steps as step_NNNNNN.pt, to average with `shapeviewer average`",
    )
    s.add_argument("--width", type=COUNT, default=None)
    s.add_argument(
        "--in-channels",
        type=int,
        default=3,
        choices=[1, 3],
        help="unet3d inputs: 1 = occupancy (the paper), 3 = + seen free space and support plane",
    )
    s.add_argument(
        "--init", default=None, help="weights to start from (a narrower unet3d, or one with fewer inputs, is widened)"
    )
    s.add_argument(
        "--jaccard-weight",
        type=_number(float, 0.0),
        default=0.0,
        help="add this many times (1 - soft Jaccard) per example to the summed cross-entropy "
        "(0 = the paper's loss; it weighs thin-walled objects as much as large ones)",
    )
    s.add_argument(
        "--label",
        default="solid",
        choices=["solid", "fraction"],
        help="the target: solid = every voxel the object touches (the paper's Y); fraction = how much of "
        "each voxel the object fills (voxel.solid_fraction), whose 0.5 contour lies on the surface",
    )
    s.add_argument("--seed", type=SEED, default=0)

    s = sub.add_parser("average", help="the parameter-wise mean of weights files of one network -> a weights file")
    s.add_argument("weights", nargs="+", help="two or more weights files (.pt) of the same architecture")
    s.add_argument("--out", required=True)
    s.add_argument("--note", default=None, help="how the weights were trained (kept in the file's meta)")

    s = sub.add_parser("evaluate-grids", help="Jaccard at 40^3 on the three evaluation sets")
    s.add_argument("--data", required=True, nargs="+")
    s.add_argument("--weights", default=None)
    s.add_argument("--views", type=COUNT, default=500)
    s.add_argument("--seed", type=SEED, default=0)
    s.add_argument("--json", default=None, help="also write the figures to this file")
    s.add_argument("--card", default=None, help="write a model card (markdown) with these figures")
    s.add_argument("--by-kind", action="store_true", help="also print the Jaccard per shape kind")
    s.add_argument("--kinds", nargs="+", default=None, help="only views of these shape kinds (mug bowl ...)")
    s.add_argument(
        "--samples",
        type=int,
        default=8,
        choices=range(1, 9),
        metavar="N",
        help="score the mean of the answers for N mirrored views (default 8: the app's output grid; "
        "1: one answer, as the paper's network gave)",
    )

    s = sub.add_parser("evaluate", help="the paper's completion Tables I-III (Partial, Mirror, Ours) -> results folder")
    s.add_argument("--out", required=True, help="results folder (resumable: finished views are skipped)")
    s.add_argument("--views-per-set", type=COUNT, default=50, help="views per evaluation set (the paper: 50)")
    s.add_argument(
        "--views",
        default="paper",
        choices=["paper", "tabletop"],
        help="paper: the paper's three view sets of floating objects; tabletop: objects on a table "
        "among neighbours, a robot's Kinect or RealSense, segmented by the app",
    )
    s.add_argument("--seed", type=SEED, default=0)
    s.add_argument("--weights", default=None, help="CNN weights (.pt); default: the shipped model")
    s.add_argument(
        "--workers",
        type=COUNT,
        default=None,
        help="processes, or with --backend ray the CPUs of a local Ray instance (default: all cores)",
    )
    s.add_argument(
        "--backend",
        default="process",
        choices=BACKENDS,
        help="process: local processes; ray: a Ray cluster (RAY_ADDRESS, else a local instance)",
    )
    s.add_argument("--no-progress", action="store_true", help="no progress bar")
    _add_objects_dir(s)
    s.add_argument(
        "--grasps",
        action="store_true",
        help="also Tables IV/V: plan grasps on each completion, execute them on the true mesh "
        "(saved completions are reused)",
    )
    s.add_argument("--hand", default="barrett", choices=["barrett", "panda"])
    s.add_argument("--n-grasps", type=COUNT, default=20, help="grasps planned per view and method (the paper: 20)")
    s.add_argument(
        "--grasp-budget",
        type=SECONDS,
        default=None,
        help="planning time limit per view and method, seconds (default: the full, deterministic search)",
    )
    s.add_argument(
        "--robust",
        action="store_true",
        help="with --grasps: also rank the grasps of Ours-fast, Ours-detailed and Ours-envelope by robustness "
        "over the CNN's 8 sample completions, grasped with the palm a few mm off and lifted (Table V's "
        "'(robust)' best grasp, the same grasps)",
    )
    s.add_argument(
        "--widen-below",
        type=SHARE,
        default=None,
        metavar="SHARE",
        help="with --robust: when the most robust grasp lifts fewer than this share of its sample tests, plan "
        "as many again on the grasp envelope and rank them with the first (default: 1.0, i.e. unless it lifted "
        "them all; 0: never)",
    )
    s.add_argument(
        "--grasp-methods",
        nargs="+",
        default=None,
        metavar="METHOD",
        help="meshes to grasp, of Partial Mirror Hull Ours-fast Ours-detailed and Ours-envelope (the grasp "
        "envelope of the CNN's sample completions; default: all six)",
    )

    s = sub.add_parser("clutter", help="VGN/GIGA's simulated clutter removal with a Panda hand -> results folder")
    s.add_argument("--scene", required=True, choices=["pile", "packed"])
    s.add_argument("--objects", required=True, metavar="DIR", help="object set: a folder of NAME.urdf files")
    s.add_argument("--setup", default=None, metavar="DIR", help="folder with plane.urdf / box.urdf (default: built in)")
    s.add_argument("--rounds", type=COUNT, default=10, help="rounds per seed and method")
    s.add_argument("--seeds", type=SEED, nargs="+", default=[0])
    s.add_argument("--methods", nargs="+", default=["Highest"], metavar="METHOD", help="methods to run (Highest)")
    s.add_argument("--objects-per-round", type=COUNT, default=5)
    s.add_argument("--attempt-seconds", type=SECONDS, default=120.0, help="a method's time per grasp attempt")
    s.add_argument("--out", required=True, help="results folder (resumable: finished rounds are skipped)")
    return p
