"""Objects a user brings as a folder of URDF files: scanned and modelled household objects for the catalogue.

The layout is the one of pybullet's ``random_urdfs`` and of the VGN/GIGA clutter-removal object sets:
every object is a single-link ``NAME.urdf`` whose ``<visual>`` names a mesh beside it (``NAME_visual.obj``),
in metres, with a ``<mesh scale="sx sy sz">`` and an ``<origin xyz rpy>`` when the file's frame is not the
link's, and the link's ``<inertial><mass>`` in kilograms. URDFs directly in the folder and one level
below it (``random_urdfs/000/000.urdf``) are read.

Every object is named ``urdf/<set>/<NAME>``: ``<set>`` is the folder's name, or ``<parent>-<name>`` when
the folder is named like a split (``pile/train`` -> ``pile-train``), so the two sets' ``train`` folders
get distinct names; ``<NAME>`` is the URDF file's stem. This module reads files only: the catalogue
(:mod:`shapeviewer.sim.catalogue`) makes the meshes watertight solids, measures and splits them.
"""

from __future__ import annotations

import hashlib
import logging
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import trimesh

log = logging.getLogger(__name__)

SOURCE = "urdf"  # the catalogue source of these objects, and their names' prefix
# Folder names that say which split a folder holds rather than what it holds: such a set is named
# after its parent too.
SPLIT_FOLDER_NAMES = frozenset({"train", "training", "test", "testing", "val", "valid", "validation", "eval"})

Geometry = Literal["mesh", "box", "cylinder", "sphere"]


@dataclass(frozen=True)
class Visual:
    """One ``<visual>`` of the link.

    Attributes:
        geometry: ``mesh``, ``box``, ``cylinder`` or ``sphere``.
        path: the mesh file (``mesh`` only).
        scale: per-axis scale of the mesh file's coordinates to metres (``mesh`` only).
        size: ``box``: (x, y, z) sides; ``cylinder``: (radius, length); ``sphere``: (radius,); metres.
        origin: 4x4 ``T_link_visual`` as nested tuples (URDF ``xyz`` metres, ``rpy`` radians, fixed axes).
    """

    geometry: Geometry
    path: Path | None
    scale: tuple[float, float, float]
    size: tuple[float, ...]
    origin: tuple[tuple[float, ...], ...]


@dataclass(frozen=True)
class UrdfObject:
    """One object of a URDF folder.

    Attributes:
        name: ``urdf/<set>/<NAME>``, the catalogue name.
        set: the set name (from the folder, see the module docstring).
        urdf: the URDF file (absolute).
        visuals: the link's visual geometry, in the link frame.
        mass: the link's mass (kg), or None when the URDF gives none.
    """

    name: str
    set: str
    urdf: Path
    visuals: tuple[Visual, ...]
    mass: float | None

    @property
    def stem(self) -> str:
        """``NAME``: the URDF file's stem."""
        return self.urdf.stem

    def files(self) -> tuple[Path, ...]:
        """The URDF and every mesh file it names."""
        return (self.urdf, *(v.path for v in self.visuals if v.path is not None))


def set_name(folder: Path) -> str:
    """The set name of a folder: its name, or ``<parent>-<name>`` for a split's name (``pile/train``
    -> ``pile-train``); characters other than letters, digits, ``-`` and ``.`` become ``-``."""
    folder = Path(folder).resolve()
    name = folder.name
    if name.lower() in SPLIT_FOLDER_NAMES and folder.parent.name:
        name = f"{folder.parent.name}-{name}"
    return re.sub(r"[^A-Za-z0-9.\-]+", "-", name).strip("-") or "objects"


def _floats(text: str | None, n: int, what: str, default: tuple[float, ...]) -> tuple[float, ...]:
    if text is None:
        return default
    try:
        values = tuple(float(v) for v in text.split())
    except ValueError:
        raise ValueError(f"{what} {text!r} is not numbers") from None
    if len(values) != n or not all(np.isfinite(values)):
        raise ValueError(f"{what} {text!r} is not {n} finite numbers")
    return values


def _origin(element: ET.Element | None) -> tuple[tuple[float, ...], ...]:
    """``T_link_visual`` of a URDF ``<origin xyz rpy>`` (rpy: roll, pitch, yaw about fixed x, y, z)."""
    T = np.eye(4)
    if element is not None:
        xyz = _floats(element.get("xyz"), 3, "origin xyz", (0.0, 0.0, 0.0))
        rpy = _floats(element.get("rpy"), 3, "origin rpy", (0.0, 0.0, 0.0))
        T = trimesh.transformations.euler_matrix(rpy[0], rpy[1], rpy[2], axes="sxyz")
        T[:3, 3] = xyz
    return tuple(tuple(float(x) for x in row) for row in T)


def _mesh_file(urdf: Path, filename: str) -> Path:
    """The mesh file a ``<mesh filename>`` names: relative to the URDF's folder; a ``package://PKG/REST``
    or ``file://`` name is looked for beside the URDF and in the folders above it."""
    if filename.startswith("file://"):
        filename = filename.removeprefix("file://")
    rests = [filename]
    if filename.startswith("package://"):
        rest = filename.removeprefix("package://")
        rests = [rest.partition("/")[2], rest]
    for base in (urdf.parent, *list(urdf.parent.parents)[:3]):
        for rest in rests:
            candidate = base / rest
            if rest and candidate.is_file():
                return candidate
    raise ValueError(f"mesh file {filename!r} not found beside {urdf.name}")


def read_urdf(urdf: Path, set_name: str) -> UrdfObject:
    """Read one single-link URDF; raises ValueError saying why it is not a usable object (not XML, no
    visual geometry, an articulated robot, a missing mesh file, a bad scale or origin)."""
    urdf = Path(urdf).resolve()
    try:
        root = ET.parse(urdf).getroot()
    except ET.ParseError as e:
        raise ValueError(f"not a URDF: {e}") from None
    links = [link for link in root.iter("link") if link.find("visual") is not None]
    if not links:
        raise ValueError("no <visual> geometry")
    if len(links) > 1:
        raise ValueError(f"{len(links)} links with visual geometry: an articulated model, not one object")
    link = links[0]
    visuals = []
    for visual in link.findall("visual"):
        geometry = visual.find("geometry")
        shape = next(iter(geometry), None) if geometry is not None else None
        if shape is None:
            raise ValueError("a <visual> without geometry")
        origin = _origin(visual.find("origin"))
        if shape.tag == "mesh":
            filename = shape.get("filename")
            if not filename:
                raise ValueError("a <mesh> without a filename")
            scale = _floats(shape.get("scale"), 3, "mesh scale", (1.0, 1.0, 1.0))
            visuals.append(Visual("mesh", _mesh_file(urdf, filename), scale, (), origin))  # type: ignore[arg-type]
        elif shape.tag == "box":
            size = _floats(shape.get("size"), 3, "box size", ())
            visuals.append(Visual("box", None, (1.0, 1.0, 1.0), size, origin))
        elif shape.tag == "cylinder":
            size = (float(shape.get("radius", "nan")), float(shape.get("length", "nan")))
            visuals.append(Visual("cylinder", None, (1.0, 1.0, 1.0), size, origin))
        elif shape.tag == "sphere":
            visuals.append(Visual("sphere", None, (1.0, 1.0, 1.0), (float(shape.get("radius", "nan")),), origin))
        else:
            raise ValueError(f"unsupported visual geometry <{shape.tag}>")
    mass_element = link.find("inertial/mass")
    mass = None
    if mass_element is not None and mass_element.get("value") is not None:
        mass = _floats(mass_element.get("value"), 1, "mass", ())[0]
    return UrdfObject(f"{SOURCE}/{set_name}/{urdf.stem}", set_name, urdf, tuple(visuals), mass)


def urdf_files(folder: Path) -> list[Path]:
    """The ``*.urdf`` files of a folder and of its direct subfolders, sorted."""
    folder = Path(folder)
    return sorted({*folder.glob("*.urdf"), *folder.glob("*/*.urdf")})


def scan(folder: Path) -> tuple[list[UrdfObject], list[tuple[str, str]]]:
    """Every object of a URDF folder and the URDFs that are not one: ``(objects, [(file, reason)])``.

    Raises:
        ValueError: ``folder`` is not a folder, or holds no URDF.
    """
    folder = Path(folder).resolve()
    if not folder.is_dir():
        raise ValueError(f"{folder}: not a folder")
    files = urdf_files(folder)
    if not files:
        raise ValueError(f"{folder}: no *.urdf files in it or in its subfolders")
    name = set_name(folder)
    objects: list[UrdfObject] = []
    skipped: list[tuple[str, str]] = []
    seen: set[str] = set()
    for urdf in files:
        rel = str(urdf.relative_to(folder))
        if "__" in urdf.stem:  # shard files name objects with "/" written as "__"
            skipped.append((rel, "'__' in the file name (object names may not hold it)"))
            continue
        if urdf.stem in seen:
            skipped.append((rel, f"another URDF of the folder is also named {urdf.stem!r}"))
            continue
        try:
            objects.append(read_urdf(urdf, name))
        except (OSError, ValueError) as e:
            skipped.append((rel, str(e)))
            continue
        seen.add(urdf.stem)
    return objects, skipped


def visual_mesh(obj: UrdfObject) -> trimesh.Trimesh:
    """The link's visual geometry as one mesh in the link frame, metres (each part scaled, then placed
    by its origin); not yet repaired (the catalogue makes it a watertight solid).

    Raises:
        ValueError: a mesh file without triangles or with non-finite vertices, or a bad primitive size.
    """
    parts = []
    for v in obj.visuals:
        if v.geometry == "mesh":
            assert v.path is not None
            mesh = trimesh.load(v.path, force="mesh", process=False)
            if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
                raise ValueError(f"{v.path.name}: no triangles")
            vertices = np.asarray(mesh.vertices, np.float64) * np.asarray(v.scale)
            mesh = trimesh.Trimesh(vertices, mesh.faces, process=False)
        elif not (all(np.isfinite(v.size)) and all(s > 0 for s in v.size)):
            raise ValueError(f"{v.geometry} size {v.size} is not positive")
        elif v.geometry == "box":
            mesh = trimesh.creation.box(extents=v.size)
        elif v.geometry == "cylinder":
            mesh = trimesh.creation.cylinder(radius=v.size[0], height=v.size[1], sections=48)
        else:
            mesh = trimesh.creation.icosphere(subdivisions=3, radius=v.size[0])
        if not np.all(np.isfinite(mesh.vertices)):
            raise ValueError("non-finite vertices")
        mesh.apply_transform(np.asarray(v.origin))
        parts.append(mesh)
    joined = parts[0] if len(parts) == 1 else trimesh.util.concatenate(parts)
    if not isinstance(joined, trimesh.Trimesh):
        raise ValueError("the visual parts do not join into one mesh")
    return joined


def fingerprint(objects: list[UrdfObject] | tuple[UrdfObject, ...]) -> str:
    """A key that changes when any object's URDF or mesh file changes (path, size, modification time)."""
    h = hashlib.sha1()
    for obj in objects:
        h.update(obj.name.encode())
        for f in obj.files():
            st = f.stat()
            h.update(f"|{f}|{st.st_size}|{st.st_mtime_ns}".encode())
        h.update(b"\n")
    return h.hexdigest()
