"""A guarded on-disk cache of native libraries this project compiles with the machine's C compiler.

Both the simulator's compiled flight core and the MPCs' generated C (CasADi code generation, the
HPIPM shim) are built once and loaded with ``ctypes``/``casadi.external``. A cached library is
native code that runs in this process the moment it is loaded, so the cache is guarded
(:class:`LibraryCache`):

* the directory is created private (0700) and refused - a one-line :class:`CacheDirError`
  naming it - if it is owned by another user or is group- or world-writable (anyone who can
  write there could plant a library);
* each library's SHA-256 is recorded at compile time beside it (``NAME.so.sha256``) and checked
  before every load; a library without a digest, with another digest (replaced, truncated,
  corrupted) is rebuilt, with a warning, and so is one that fails to load (a garbage file that
  passes no digest check can never make every later construction fail);
* a library is built in a private temporary directory inside the cache and renamed into place
  (atomic: two processes compiling the same source cannot load a half-written file);
  temporary directories left by a killed compile are removed the next time the cache is used.

Callers key each library by a digest of everything that determines it (source, compiler, flags),
so a stale library can never be loaded.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import stat
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, TypeVar

CACHE_ENV = "WT_INSPECT_CACHE"
CACHE_DIR_MODE = 0o700
BUILD_PREFIX = "tmp"                  # tempfile's default prefix, so older leftovers are found too
STALE_BUILD_AGE_S = 3600.0            # a build directory this old belongs to no running compile
DIGEST_SUFFIX = ".sha256"

T = TypeVar("T")


def default_cache_dir() -> Path:
    """``$WT_INSPECT_CACHE`` if set, else ``~/.cache/wt-inspect`` (the XDG convention)."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "wt-inspect"


class CacheDirError(ValueError):
    """The compiled-solver cache directory cannot be trusted (or used)."""


class CompileError(RuntimeError):
    """The compiler failed (its message is in the exception)."""


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


@dataclass(frozen=True)
class LibraryCache:
    """A guarded directory of compiled libraries (see the module docstring). :meth:`open`
    creates and checks it; :meth:`load` returns a loaded library, building it when needed."""

    directory: Path

    @classmethod
    def open(cls, cache_dir: str | os.PathLike | None = None) -> "LibraryCache":
        """The cache at ``cache_dir`` (default :func:`default_cache_dir`), created 0700 if
        missing, its owner and mode checked, leftovers of killed builds removed."""
        directory = Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()
        try:
            directory.parent.mkdir(parents=True, exist_ok=True)
            directory.mkdir(mode=CACHE_DIR_MODE, exist_ok=True)
        except OSError as exc:
            raise CacheDirError(f"compiled-solver cache {str(directory)!r} cannot be created: "
                                f"{exc.strerror or exc}") from None
        cache = cls(directory)
        cache.check()
        cache.remove_stale_builds()
        return cache

    def check(self) -> None:
        """CacheDirError unless the directory is a directory owned by this user and writable by
        no one else."""
        d = self.directory
        try:
            st = d.stat()
        except OSError as exc:
            raise CacheDirError(f"compiled-solver cache {str(d)!r} cannot be read: {exc.strerror or exc}") from None
        if not stat.S_ISDIR(st.st_mode):
            raise CacheDirError(f"compiled-solver cache {str(d)!r} is not a directory")
        if st.st_uid != os.geteuid():
            raise CacheDirError(f"compiled-solver cache {str(d)!r} is owned by uid {st.st_uid}, not the current "
                                f"user (uid {os.geteuid()}): refusing to load libraries from it; set "
                                f"{CACHE_ENV} to a private directory")
        if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
            raise CacheDirError(f"compiled-solver cache {str(d)!r} is group- or world-writable (mode "
                                f"{stat.S_IMODE(st.st_mode):04o}): refusing to load libraries from it; "
                                f"chmod 700 it or set {CACHE_ENV} to a private directory")

    def remove_stale_builds(self, max_age_s: float = STALE_BUILD_AGE_S) -> list[Path]:
        """Remove build directories of compiles that were killed: those whose process (named in
        the directory, ``tmp-PID-...``) is gone, and any ``tmp*`` directory older than
        ``max_age_s``. Returns what was removed."""
        removed = []
        now = time.time()
        try:
            children = list(self.directory.iterdir())
        except OSError:
            return removed
        for p in children:
            if not p.name.startswith(BUILD_PREFIX) or p.is_symlink() or not p.is_dir():
                continue
            parts = p.name.split("-")
            pid = int(parts[1]) if len(parts) >= 3 and parts[0] == BUILD_PREFIX and parts[1].isdigit() else None
            try:
                age = now - p.stat().st_mtime
            except OSError:
                continue
            if age > max_age_s or (pid is not None and pid != os.getpid() and not _pid_alive(pid)):
                shutil.rmtree(p, ignore_errors=True)
                removed.append(p)
        return removed

    def entry_problem(self, lib: Path) -> str | None:
        """Why the cached ``lib`` must not be loaded (None: its digest is the one recorded)."""
        try:
            recorded = (lib.parent / (lib.name + DIGEST_SUFFIX)).read_text().split()[0]
        except (OSError, IndexError, UnicodeDecodeError):
            return "no SHA-256 recorded at compile time"
        try:
            actual = _sha256(lib)
        except OSError as exc:
            return f"unreadable ({exc.strerror or exc})"
        if actual != recorded:
            return f"SHA-256 {actual[:16]}... differs from the {recorded[:16]}... recorded at compile time"
        return None

    def build(self, name: str, builder: Callable[[Path], Path]) -> Path:
        """Run ``builder(tmpdir) -> built file`` in a fresh private directory of the cache, record
        the file's digest and rename both into place."""
        lib = self.directory / name
        tmp = Path(tempfile.mkdtemp(prefix=f"{BUILD_PREFIX}-{os.getpid()}-", dir=self.directory))
        try:
            built = builder(tmp)
            digest = tmp / (name + DIGEST_SUFFIX)
            digest.write_text(f"{_sha256(built)}  {name}\n")
            os.replace(built, lib)
            os.replace(digest, self.directory / (name + DIGEST_SUFFIX))
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        return lib

    def load(self, name: str, builder: Callable[[Path], Path], loader: Callable[[Path], T], *,
             use_cache: bool = True) -> tuple[T, Path, bool]:
        """``(loader(lib), lib, cache_hit)`` for the library ``name``: the cached one if its digest
        checks out and it loads, else (warning why) a fresh build. ``use_cache=False`` always
        builds. CompileError if the build fails; the loader's error if a fresh build fails to load."""
        lib = self.directory / name
        if use_cache and lib.exists():
            problem = self.entry_problem(lib)
            if problem is None:
                try:
                    return loader(lib), lib, True
                except (OSError, RuntimeError) as exc:
                    first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
                    problem = f"failed to load ({first[:200]})"
            warnings.warn(f"compiled-solver cache entry {str(lib)!r}: {problem}; rebuilding it",
                          RuntimeWarning, stacklevel=3)
        self.build(name, builder)
        if self.entry_problem(lib) is not None:   # another process replaced it in between: build again
            self.build(name, builder)
        return loader(lib), lib, False


_C_FLAGS = ("-O2", "-shared", "-fPIC", "-ffp-contract=off", "-fno-fast-math")
_C_LIBS: dict[str, object] = {}


def load_c_source(source: str, stem: str, what: str, cache_dir: str | os.PathLike | None = None):
    """The C ``source`` compiled as a shared library and loaded with ``ctypes`` - built on first
    use per source, compiler and flags (``-O2 -ffp-contract=off``, no fast-math: the floating-point
    operations are the ones written), then loaded from the guarded cache; one library object per
    process. RuntimeError naming ``what`` when no compiler is there; CompileError when it fails."""
    import ctypes
    import subprocess
    import threading

    exe = shutil.which(os.environ.get("CC") or "gcc")
    if exe is None:
        raise RuntimeError(f"no C compiler (gcc or $CC) to build the {what}")
    key = hashlib.sha256("\n".join([source, exe, *_C_FLAGS]).encode()).hexdigest()[:20]
    name = f"{stem}_{key}.so"
    lock = _C_LIBS.setdefault("__lock__", threading.Lock())
    with lock:  # type: ignore[attr-defined]
        lib = _C_LIBS.get(name)
        if lib is not None:
            return lib

        def build(tmp: Path) -> Path:
            c = tmp / f"{stem}.c"
            c.write_text(source)
            out = tmp / name
            proc = subprocess.run([exe, *_C_FLAGS, str(c), "-o", str(out), "-lm"], capture_output=True, text=True)
            if proc.returncode != 0:
                raise CompileError(f"building the {what} failed: {proc.stderr.strip()[:300]}")
            return out

        lib, _, _ = LibraryCache.open(cache_dir).load(name, build, lambda p: ctypes.CDLL(str(p)))
        _C_LIBS[name] = lib
        return lib
