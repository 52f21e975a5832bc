"""Files: the cache folder (:func:`cache_dir`) and writes a reader never sees half of (:func:`atomic_write`)."""

from __future__ import annotations

import os
import secrets
from pathlib import Path


def atomic_write(path: str | Path, data: bytes | str) -> Path:
    """Write ``data`` (str as UTF-8) to ``path`` atomically: a temp file in the same folder, then
    :func:`os.replace`. The folder is created when missing.

    Readers (another process, a ``glob``) see the old file or the new one, never a partial one; a
    run killed mid-write leaves at most a hidden ``.<name>.<random>.tmp`` beside it, which matches no
    ``*.json`` / ``*.npz`` pattern. The temp name is unique, so concurrent writers of one path do
    not clobber each other's temp file (the last ``os.replace`` wins). Not fsynced: atomic against
    a crashing process, not against a power cut.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = data.encode() if isinstance(data, str) else data
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
    # 0o666 less the umask: the file gets the permissions a plain open() would give it.
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(payload)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def cache_dir() -> Path:
    """Where generated files live (``$SHAPEVIEWER_CACHE``, default ``~/.cache/shapeviewer``)."""
    d = Path(os.environ.get("SHAPEVIEWER_CACHE", Path.home() / ".cache" / "shapeviewer"))
    d.mkdir(parents=True, exist_ok=True)
    return d
