"""Atomic file output: write to a temporary file in the target directory, then rename.

A reader (or a crashed run) never sees a half-written file: ``os.replace`` within one directory is
atomic on POSIX and Windows, so the target either keeps its old content or gets the complete new
one. On failure the temporary file is removed.
"""
from __future__ import annotations

import contextlib
import os
import secrets
from pathlib import Path
from typing import Iterator


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success rename it onto ``path``.

    ``suffix`` defaults to the target's suffix so that libraries inferring the format from the file
    name (matplotlib, trimesh) still do so.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    # os.open with mode 0o666 (not mkstemp's 0o600) so the result gets the usual umask permissions
    for _ in range(100):
        tmp_path = target.parent / (f".{target.name}.{secrets.token_hex(6)}.tmp"
                                    + (target.suffix if suffix is None else suffix))
        try:
            os.close(os.open(tmp_path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
            break
        except FileExistsError:
            continue
    else:  # pragma: no cover - 100 collisions of 48 random bits
        raise FileExistsError(f"could not create a temporary file next to {target}")
    try:
        yield tmp_path
        os.replace(tmp_path, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
