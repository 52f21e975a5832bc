"""The low-level readers of capture files: header checks of ``.pcd`` / ``.ply`` point clouds and the
pixels of ``.png`` / ``.npy`` depth images.

:mod:`shapeviewer.perception.capture` turns what these return into a
:class:`~shapeviewer.perception.capture.Capture`. Everything here checks a file before the
expensive read (Open3D, PIL, numpy) so that a corrupt, truncated or oversized file is refused with a
:class:`CaptureError` that names the file and what is wrong with it, rather than read as zeros.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import BinaryIO

import numpy as np

from ..errors import ShapeviewerError

# PCD and PLY headers are a few hundred bytes; this many lines without the end of the header means
# the file is not what its suffix says.
MAX_HEADER_LINES = 200


class CaptureError(ShapeviewerError, ValueError):
    """A capture file that cannot be read; the message names the file and what is wrong with it."""


def check_file(path: str | os.PathLike) -> Path:
    """``path`` as a Path, or CaptureError when it is missing, not a regular file or empty.

    Only the file's metadata is read (``os.stat``), never its contents: a named pipe (FIFO) or a
    device called ``x.npy`` would block the first ``open`` or read forever, so it is refused here,
    before any reader opens it.
    """
    path = Path(path)
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise CaptureError(f"{path}: file not found") from None
    except OSError as e:  # permission denied, a name too long, a loop of links...
        raise CaptureError(f"{path}: cannot be read ({e.strerror or e})") from None
    if stat.S_ISDIR(info.st_mode):
        raise CaptureError(f"{path}: not a file (a folder)")
    if not stat.S_ISREG(info.st_mode):
        raise CaptureError(f"{path}: not a regular file (a pipe, socket or device cannot be a capture)")
    if info.st_size == 0:
        raise CaptureError(f"{path}: the file is empty")
    return path


def open_regular(path: Path) -> BinaryIO:
    """``path`` opened for binary reading, or CaptureError when it is not a regular file.

    Opened without blocking (a FIFO put in the file's place after :func:`check_file` would
    otherwise block the open until a writer came), then checked on the open descriptor itself.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0))
    except OSError as e:
        raise CaptureError(f"{path}: cannot be read ({e.strerror or e})") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise CaptureError(f"{path}: not a regular file (a pipe, socket or device cannot be a capture)")
    os.set_blocking(fd, True)
    return os.fdopen(fd, "rb")


def npy_header(path: Path) -> tuple[tuple[int, ...], np.dtype]:
    """``(shape, dtype)`` of a ``.npy`` file from its header alone; CaptureError when the file is
    not a ``.npy`` array or holds Python objects (which only unpickling, i.e. running code the file
    names, could read: never done here)."""
    with open_regular(path) as f:
        try:
            version = np.lib.format.read_magic(f)
            read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, _, dtype = read(f)
        except Exception as e:  # ValueError, EOFError... for a broken or foreign file
            raise CaptureError(f"{path}: not a readable .npy array ({_one_line(e)})") from None
    if dtype.hasobject:
        raise CaptureError(f"{path}: {NPY_OBJECTS}")
    return tuple(shape), dtype


# What a .npy of pickled Python objects is said to be (numpy's own message advises allow_pickle=True,
# i.e. running whatever code the file names: never passed on).
NPY_OBJECTS = "a .npy of Python objects is not a capture (expected a numeric array)"


def load_npy(path: Path) -> np.ndarray:
    """A numeric ``.npy`` array, memory-mapped (nothing is read until used, so sizes can be checked
    first); CaptureError for a broken file or one of Python objects."""
    npy_header(path)
    try:
        return np.load(path, mmap_mode="r", allow_pickle=False)
    except Exception as e:  # ValueError, OSError, EOFError... for broken files
        if "pickle" in str(e) or "Python objects" in str(e):
            raise CaptureError(f"{path}: {NPY_OBJECTS}") from None
        raise CaptureError(f"{path}: not a readable .npy array ({_one_line(e)})") from None


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split())[:300] or type(e).__name__


def _header_lines(path: Path, f, last_key: str) -> tuple[dict[str, list[str]], list[list[str]]]:
    """Keyword lines of a text header up to and including ``last_key`` (read from open file ``f``).

    Returns ``(last value of each key, every line in order)``; raises when ``last_key`` never comes.
    """
    keys: dict[str, list[str]] = {}
    lines: list[list[str]] = []
    for _ in range(MAX_HEADER_LINES):
        raw = f.readline(4096)
        if not raw:
            break
        words = raw.decode("ascii", errors="replace").split()
        if not words or words[0].startswith("#"):
            continue
        lines.append(words)
        keys[words[0]] = words[1:]
        if words[0] == last_key:
            return keys, lines
    raise CaptureError(
        f"{path}: corrupt or not a {path.suffix[1:].upper()} file: the header never reaches its {last_key!r} line"
    )


def _header_ints(path: Path, keys: dict[str, list[str]], key: str, n: int | None = None) -> list[int]:
    values = keys.get(key)
    if values is None:
        raise CaptureError(f"{path}: corrupt header: no {key} line")
    try:
        ints = [int(x) for x in values]
    except ValueError:
        raise CaptureError(f"{path}: corrupt header: {key} {' '.join(values)!r} is not a list of integers") from None
    if (n is not None and len(ints) != n) or any(i < 0 for i in ints):
        raise CaptureError(
            f"{path}: corrupt header: {key} {' '.join(values)!r} (expected {n or 'some'} non-negative integers)"
        )
    return ints


def pcd_layout(path: Path) -> tuple[int, int, int]:
    """``(points, width, height)`` of a PCD after checking its header and that its data is complete."""
    with open_regular(path) as f:
        keys, _ = _header_lines(path, f, "DATA")
        data_offset = f.tell()
        fields = keys.get("FIELDS", [])
        if not {"x", "y", "z"} <= set(fields):
            raise CaptureError(f"{path}: corrupt header or not a point cloud: FIELDS {' '.join(fields)!r} lacks x y z")
        sizes = _header_ints(path, keys, "SIZE", len(fields))
        counts = _header_ints(path, keys, "COUNT", len(fields)) if "COUNT" in keys else [1] * len(fields)
        if len(keys.get("TYPE", [])) != len(fields):
            raise CaptureError(f"{path}: corrupt header: TYPE does not list a type per field")
        (width,), (height,) = _header_ints(path, keys, "WIDTH", 1), _header_ints(path, keys, "HEIGHT", 1)
        (n_points,) = _header_ints(path, keys, "POINTS", 1) if "POINTS" in keys else (width * height,)
        if n_points != width * height:
            raise CaptureError(f"{path}: corrupt header: POINTS {n_points} is not WIDTH x HEIGHT ({width} x {height})")
        if n_points == 0:
            raise CaptureError(f"{path}: the cloud has no points")
        kind = (keys["DATA"] or ["?"])[0]
        needed = n_points * sum(s * c for s, c in zip(sizes, counts))
        available = os.fstat(f.fileno()).st_size - data_offset
        if kind == "ascii":
            body = f.read().strip()
            rows = body.count(b"\n") + 1 if body else 0
            if rows < n_points:
                raise CaptureError(f"{path}: truncated: {rows} of {n_points} point rows are present")
        elif kind == "binary":
            if available < needed:
                raise CaptureError(
                    f"{path}: truncated: {available} bytes of binary data, {n_points} points need {needed}"
                )
        elif kind == "binary_compressed":
            sizes_raw = f.read(8)
            if len(sizes_raw) < 8:
                raise CaptureError(f"{path}: truncated: the compressed data block is missing")
            packed, unpacked = np.frombuffer(sizes_raw, dtype="<u4")
            if unpacked != needed:
                raise CaptureError(
                    f"{path}: corrupt: the compressed block unpacks to {unpacked} bytes, "
                    f"{n_points} points need {needed}"
                )
            if available - 8 < packed:
                raise CaptureError(f"{path}: truncated: {available - 8} of {packed} compressed bytes are present")
        else:
            raise CaptureError(f"{path}: unsupported DATA {kind!r} (expected ascii, binary or binary_compressed)")
    return n_points, width, height


_PLY_SIZES = {
    "char": 1,
    "uchar": 1,
    "int8": 1,
    "uint8": 1,
    "short": 2,
    "ushort": 2,
    "int16": 2,
    "uint16": 2,
    "int": 4,
    "uint": 4,
    "int32": 4,
    "uint32": 4,
    "float": 4,
    "float32": 4,
    "double": 8,
    "float64": 8,
}


def ply_layout(path: Path) -> tuple[int, int, int]:
    """``(points, width, height)`` of a PLY after checking its header and that its vertices are complete.

    Organized when PCL's ``obj_info num_cols W`` / ``obj_info num_rows H`` lines say so.
    """
    with open_regular(path) as f:
        if f.readline(16).strip() != b"ply":
            raise CaptureError(f"{path}: not a PLY file (it does not start with 'ply')")
        keys, lines = _header_lines(path, f, "end_header")
        data_offset = f.tell()
        fmt = (keys.get("format") or ["?"])[0]
        if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
            raise CaptureError(f"{path}: corrupt header: unknown format {fmt!r}")
        # elements in file order: [name, count, record bytes (None when it has list properties), props]
        elements: list[list] = []
        info: dict[str, str] = {}
        for words in lines:
            if words[0] == "element" and len(words) == 3 and words[2].isdigit():
                elements.append([words[1], int(words[2]), 0, []])
            elif words[0] == "property" and elements and len(words) >= 3:
                el = elements[-1]
                el[3].append(words[-1])
                size = _PLY_SIZES.get(words[1]) if words[1] != "list" else None
                el[2] = None if size is None or el[2] is None else el[2] + size
            elif words[0] == "obj_info" and len(words) == 3:
                info[words[1]] = words[2]
            elif words[0] in ("element", "property"):
                raise CaptureError(f"{path}: corrupt header line {' '.join(words)!r}")
        names = [e[0] for e in elements]
        if "vertex" not in names:
            raise CaptureError(f"{path}: the PLY has no vertex element")
        at = names.index("vertex")
        _, n_points, record, props = elements[at]
        if not {"x", "y", "z"} <= set(props):
            raise CaptureError(f"{path}: the vertices have no x y z properties")
        if n_points == 0:
            raise CaptureError(f"{path}: the cloud has no points")
        if fmt == "ascii":
            rows_needed = sum(e[1] for e in elements[: at + 1])
            body = f.read().strip()
            rows = body.count(b"\n") + 1 if body else 0
            if rows < rows_needed:
                raise CaptureError(
                    f"{path}: truncated: {rows} of the {rows_needed} data rows up to the last vertex are present"
                )
        elif all(e[2] is not None for e in elements[: at + 1]):  # fixed-size records: sizes are known
            needed = sum(e[1] * e[2] for e in elements[: at + 1])
            available = os.fstat(f.fileno()).st_size - data_offset
            if available < needed:
                raise CaptureError(f"{path}: truncated: {available} bytes of binary data, the vertices need {needed}")
    try:
        width, height = int(info.get("num_cols", n_points)), int(info.get("num_rows", 1))
    except ValueError:
        width, height = n_points, 1
    if width * height != n_points:  # obj_info that does not describe this cloud: ignore it
        width, height = n_points, 1
    return n_points, width, height


def read_png_depth(path: Path, max_pixels: int) -> np.ndarray:
    """The pixels of a single-channel (16-bit) PNG depth image, as stored; CaptureError for a broken
    file, another kind of image or more than ``max_pixels`` pixels (checked before decoding)."""
    from PIL import Image

    try:
        with open_regular(path) as f, Image.open(f) as im:
            if im.width * im.height > max_pixels:  # checked before decoding the pixels
                raise CaptureError(f"{path}: {im.width}x{im.height} pixels; at most {max_pixels:,} can be loaded")
            im.load()
            mode, depth = im.mode, np.asarray(im)
    except CaptureError:
        raise
    except Exception as e:  # PIL raises OSError, SyntaxError, ValueError... for broken files
        raise CaptureError(f"{path}: not a readable PNG image ({e})") from None
    if not mode.startswith("I"):
        raise CaptureError(
            f"{path}: a {mode} image, not a depth image; expected a single-channel 16-bit PNG of millimetres"
        )
    return depth


def read_npy_depth(path: Path, max_pixels: int) -> np.ndarray:
    """A 2-D numeric ``.npy`` depth array, memory-mapped; CaptureError for a broken file, another
    shape or dtype, or more than ``max_pixels`` pixels (checked before reading)."""
    depth = load_npy(path)  # mapped: the size is checked before reading
    if not isinstance(depth, np.ndarray) or depth.ndim != 2:
        shape = getattr(depth, "shape", type(depth).__name__)
        raise CaptureError(f"{path}: expected a 2-D (H, W) depth array in metres, got {shape}")
    if depth.size > max_pixels:
        raise CaptureError(f"{path}: {depth.shape[1]}x{depth.shape[0]} pixels; at most {max_pixels:,} can be loaded")
    if not (np.issubdtype(depth.dtype, np.integer) or np.issubdtype(depth.dtype, np.floating)):
        raise CaptureError(f"{path}: expected a numeric depth array, got dtype {depth.dtype}")
    return depth
