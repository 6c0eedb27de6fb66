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


@contextlib.contextmanager
def atomic_paths(*paths: str | os.PathLike) -> Iterator[list[Path]]:
    """Like :func:`atomic_path` for a set of files that belong together (a plan's mesh and path):
    yield one temporary path per target and rename them all only after the block succeeded, so
    a failure while writing any of them (a full or read-only disk) leaves none of them - never
    the mesh without its path. The renames themselves (metadata only, one directory) are not
    one atomic step, but nothing is renamed before every file was written."""
    with contextlib.ExitStack() as stack:
        tmps = [stack.enter_context(_deferred(p)) for p in paths]
        yield [t for t, _ in tmps]
        for tmp, target in tmps:
            os.replace(tmp, target)


@contextlib.contextmanager
def _deferred(path: str | os.PathLike) -> Iterator[tuple[Path, Path]]:
    """A temporary file next to ``path`` (removed on exit unless renamed onto it)."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.parent / f".{target.name}.{secrets.token_hex(6)}.tmp{target.suffix}"
    os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
    try:
        yield tmp, target
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def check_out_dir(path: str | os.PathLike, option: str = "--out") -> Path:
    """Refuse, before any work, an output directory that cannot be created or written: an
    existing non-directory, a parent that is a file, or (for a non-root user) a missing write
    permission on the directory or its nearest existing ancestor. Creates nothing. A ValueError
    names the option and the path; a read-only or full file system that permissions do not show
    is still caught when writing (callers turn that OSError into the same one-line error)."""
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise ValueError(f"{option} {str(target)!r} exists and is not a directory")
    anc = target
    while not anc.exists():
        if anc.parent == anc:
            break
        anc = anc.parent
    if not anc.is_dir():
        raise ValueError(f"{option} {str(target)!r} cannot be created: {str(anc)!r} is not a directory")
    if not os.access(anc, os.W_OK | os.X_OK):
        what = "is not writable" if anc == target else f"cannot be created: {str(anc)!r} is not writable"
        raise ValueError(f"{option} {str(target)!r} {what}")
    return target
