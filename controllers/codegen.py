"""C code generation for CasADi functions, compiled once and cached on disk.

The real-time iteration spends most of its preparation phase evaluating Jacobians of the
residuals and the RK4 dynamics. CasADi's virtual machine evaluates them several times slower than
straight-line C, so the QP-data function is generated as C, compiled with the machine's compiler
(``gcc -O2 -shared -fPIC``) and loaded with :func:`casadi.external`.

The cache key is a SHA-256 of the *generated source* plus the compiler, its flags and the CasADi
version. The source is the problem (horizon, model parameters, residuals and constraints are all
in it), so any change to the problem gives a new key and a stale library can never be loaded.

A cached library is native code that runs in this process the moment it is loaded, so it goes
through the guarded library cache of :mod:`wt_inspect_env.util.native_cache` (private directory,
digest checked before every load, atomic builds), which the HPIPM shim and the simulator's flight
core use too.

Only pure numerical functions go through this path; the HPIPM call itself is never generated
(calling HPIPM from generated code has crashed; the QP is solved through CasADi's plugin or
:mod:`controllers.hpipm_direct`).
"""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import casadi as ca

# The guarded library cache lives with the simulator, which compiles its flight core through it too.
from wt_inspect_env.util.native_cache import (  # noqa: F401
    CACHE_DIR_MODE,
    CACHE_ENV,
    DIGEST_SUFFIX,
    CacheDirError,
    CompileError,
    LibraryCache,
    default_cache_dir,
)

DEFAULT_FLAGS: tuple[str, ...] = ("-O2", "-shared", "-fPIC")


@dataclass(frozen=True)
class CompiledFunction:
    """A callable CasADi function and how it was obtained.

    ``compiled`` is False when no compiler was available (or compilation failed) and ``function``
    is the uncompiled (SX-expanded) original. ``compile_seconds`` is the time spent generating and
    compiling in this call (0 on a cache hit); ``load_seconds`` the time to load the library.
    """

    function: ca.Function
    compiled: bool
    path: Path | None
    cache_hit: bool
    compile_seconds: float
    load_seconds: float


def _expanded(fun: ca.Function) -> ca.Function:
    """SX version of ``fun`` when it can be expanded: the SX virtual machine is several times
    faster than the MX one for scalar-heavy code like ours."""
    try:
        return fun.expand()
    except Exception:  # functions with non-expandable nodes stay MX
        return fun


def generate_source(fun: ca.Function) -> str:
    """C source of ``fun`` (no header, no main), deterministic for identical functions."""
    cg = ca.CodeGenerator(f"{fun.name()}.c", {"with_header": False})
    cg.add(fun)
    return cg.dump()


def _compiler_id(compiler: str) -> str:
    try:
        out = subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=30)
        return out.stdout.splitlines()[0] if out.stdout else compiler
    except (OSError, subprocess.SubprocessError):
        return compiler


def compile_function(fun: ca.Function, *, cache_dir: str | os.PathLike | None = None,
                     compiler: str | None = None, flags: tuple[str, ...] = DEFAULT_FLAGS,
                     use_cache: bool = True) -> CompiledFunction:
    """Generate C for ``fun``, compile it (or reuse the cached library) and load it.

    Without a usable compiler (or when compiling fails) this warns and returns the uncompiled
    function, so the controller still works, only slower. ``compiler`` defaults to ``$CC`` or
    ``gcc``. CacheDirError if the cache directory cannot be trusted (see the module docstring).
    """
    compiler = compiler or os.environ.get("CC") or "gcc"
    exe = shutil.which(compiler)
    if exe is None:
        warnings.warn(f"no C compiler {compiler!r} found: running {fun.name()!r} uncompiled "
                      "(several times slower)", RuntimeWarning, stacklevel=2)
        return CompiledFunction(_expanded(fun), False, None, False, 0.0, 0.0)

    t0 = time.perf_counter()
    src = generate_source(fun)
    key_material = "\n".join([src, _compiler_id(exe), " ".join(flags), ca.__version__])
    key = hashlib.sha256(key_material.encode()).hexdigest()[:20]
    cache = LibraryCache.open(cache_dir)
    name = f"{fun.name()}_{key}.so"
    built_at: list[float] = []

    def build(tmp: Path) -> Path:
        c_file = tmp / f"{fun.name()}.c"
        c_file.write_text(src)
        out = tmp / name
        cmd = [exe, *flags, str(c_file), "-o", str(out), "-lm"]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise CompileError(f"compiling {fun.name()!r} failed ({' '.join(cmd)}): {proc.stderr.strip()[:500]}")
        built_at.append(time.perf_counter())
        return out

    loaded_at: list[float] = []

    def load(lib: Path) -> ca.Function:
        t = time.perf_counter()
        f = ca.external(fun.name(), str(lib))
        loaded_at.append(time.perf_counter() - t)
        return f

    try:
        loaded, lib, cache_hit = cache.load(name, build, load, use_cache=use_cache)
    except (CompileError, OSError, RuntimeError) as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        warnings.warn(f"{first}; running {fun.name()!r} uncompiled", RuntimeWarning, stacklevel=2)
        return CompiledFunction(_expanded(fun), False, None, False, 0.0, 0.0)
    compile_seconds = 0.0 if cache_hit else (built_at[-1] - t0 if built_at else 0.0)
    return CompiledFunction(loaded, True, lib, cache_hit, compile_seconds, loaded_at[-1] if loaded_at else 0.0)


def uncompiled(fun: ca.Function) -> CompiledFunction:
    """The uncompiled (SX-expanded where possible) function, wrapped like a compiled one."""
    return CompiledFunction(_expanded(fun), False, None, False, 0.0, 0.0)
