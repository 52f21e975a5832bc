"""Where a browser's captures come from: files it uploads, and (only when the server was started
with ``--data-dir``) capture files of one server folder. Plain functions, no viser: they check and
read bytes and paths; the app shows what they say.

Points of the captures they return are camera optical frame, metres (:mod:`shapeviewer.perception.capture`).
"""

from __future__ import annotations

import logging
import re
import shutil
import tempfile
from pathlib import Path

from ..perception.camera import Intrinsics
from ..perception.capture import CLOUD_SUFFIXES, DEPTH_SUFFIXES, Capture, CaptureError, load_capture, npy_holds_points

log = logging.getLogger(__name__)

UPLOAD_SUFFIXES = (*CLOUD_SUFFIXES, *DEPTH_SUFFIXES)
# The "Server file" dropdown lists at most this many capture files of the data folder.
MAX_DATA_FILES = 200


# Longest upload name shown (characters, after escaping): a name is a label, not a message.
MAX_NAME_CHARS = 120
# ASCII punctuation left as it is in markdown: these never start markup inside a line.
_MARKDOWN_PLAIN = frozenset(".,-/'\"=%;?")
_WORD = re.compile(r"\w")
_JOINER = "\u2060"  # WORD JOINER: invisible, no line break; splits what markdown would make a link


def one_line(text: str) -> str:
    """``text`` as one printable line: each character that is not printable escaped the way
    ``repr`` escapes it (``\\n``, ``\\x1b``, ``\\u202e``). Safe in a log line, where a newline
    in a name would forge a line of its own; a text already on one line comes back as it was."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def upload_name(name: str) -> str:
    """The name an upload is shown and logged by: the base name of the browser's file name (never a
    client path; Windows separators too), on one line (:func:`one_line`), at most
    :data:`MAX_NAME_CHARS` long."""
    base = Path(str(name).replace("\\", "/")).name or "upload"
    shown = one_line(base)
    if len(shown) > MAX_NAME_CHARS:
        keep = MAX_NAME_CHARS - 1 - len(Path(shown).suffix)
        shown = shown[: max(keep, 1)] + "…" + Path(shown).suffix
    return shown


def markdown_text(text: str) -> str:
    """``text`` (a name from a browser or a file) as literal markdown: on one line, every character
    that could start markup or raw HTML backslash-escaped, so that ``<img src=x>``, ``[a](x)`` or
    ``**`` show as typed. Underscores inside a word and plain punctuation stay as they are
    (``ycb/025_mug.pcd`` reads the same in the source and on screen).

    GitHub-flavoured markdown also turns ``www.``, ``http://`` and ``a@b.c`` in plain text into
    links, after the escapes are gone: an invisible word joiner (U+2060) before ``:``, ``@`` and a
    ``.`` after ``www`` keeps them text."""
    line = one_line(text)
    out = []
    for i, c in enumerate(line):
        if c == "_":
            inside = 0 < i < len(line) - 1 and _WORD.match(line[i - 1]) and _WORD.match(line[i + 1])
            out.append(c if inside else "\\_")
        elif c == "." and line[max(i - 3, 0) : i].lower() == "www":
            out.append(_JOINER + c)
        elif c in ":@":
            out.append(_JOINER + "\\" + c)
        elif c.isascii() and not c.isalnum() and not c.isspace() and c not in _MARKDOWN_PLAIN:
            out.append("\\" + c)
        else:
            out.append(c)
    return "".join(out)


def upload_problem(shown: str, size: int, max_bytes: int) -> str | None:
    """Why an upload named ``shown`` of ``size`` bytes is refused before it is read; None if not."""
    suffix = Path(shown).suffix.lower()
    if suffix not in UPLOAD_SUFFIXES:
        return f"unsupported file type {suffix or '(no suffix)'!r}; upload one of {', '.join(UPLOAD_SUFFIXES)}"
    if not size:
        return "the file is empty"
    if size > max_bytes:
        return (
            f"{size / 2**20:,.0f} MB; uploads may be at most {max_bytes / 2**20:,.0f} MB "
            "(start the server with --cloud or --data-dir for larger captures)"
        )
    return None


def read_upload(shown: str, content: bytes, intrinsics: Intrinsics | None) -> tuple[Capture, str | None]:
    """Parse an upload's bytes from a private temporary file (removed afterwards), as
    :func:`~shapeviewer.perception.capture.load_capture` reads files. Messages name ``shown``, never the
    server's file. Returns the capture and, for a depth image read without ``intrinsics``, a note
    saying which intrinsics were assumed."""
    suffix = Path(shown).suffix.lower()
    folder = Path(tempfile.mkdtemp(prefix="shapeviewer-upload-"))
    path = folder / f"capture{suffix}"
    try:
        path.write_bytes(content)
        try:
            capture = load_capture(path, intrinsics=intrinsics)
            is_depth = suffix == ".png" or (suffix == ".npy" and not npy_holds_points(path))
        except (ValueError, OSError) as e:
            raise CaptureError(str(e).replace(str(path), shown)) from None
        except Exception as e:  # an unexpected reader failure: still not a word about the server's paths
            raise RuntimeError(str(e).replace(str(path), shown)) from e
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    capture.source = shown
    note = None
    if is_depth and intrinsics is None and capture.intrinsics is not None:
        k = capture.intrinsics
        note = (
            f"{shown} is a depth image and the server was started without --fx --fy --cx --cy: "
            f"back-projected with the Kinect's intrinsics for {k.width}x{k.height} "
            f"(fx {k.fx:.1f}, fy {k.fy:.1f}, cx {k.cx:.1f}, cy {k.cy:.1f})."
        )
    return capture, note


def data_files(root: Path | None) -> tuple[str, ...]:
    """Names of the capture files in the data folder ``root`` (not its subfolders; sorted, at most
    :data:`MAX_DATA_FILES`, no hidden files, no links out of it); empty without a folder."""
    if root is None:
        return ()
    try:
        names = sorted(
            e.name
            for e in root.iterdir()
            if e.suffix.lower() in UPLOAD_SUFFIXES
            and not e.name.startswith(".")
            and e.is_file()
            and e.resolve().is_relative_to(root)
        )
    except OSError as e:
        log.warning("listing %s failed: %s", root, e)
        return ()
    return tuple(names[:MAX_DATA_FILES])


def data_file(root: Path, name: str) -> Path:
    """The path of ``name`` in the data folder ``root`` (resolved); CaptureError for anything that
    resolves outside it (``..``, an absolute path, a symbolic link out of it)."""
    path = (root / name).resolve()
    if not path.is_relative_to(root):
        raise CaptureError(f"{name}: outside the server's data folder")
    return path
