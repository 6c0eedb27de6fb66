"""C code generation for CasADi functions, compiled once and cached on disk.

The real-time iteration spends most of its preparation phase evaluating Jacobians of the
residuals and the RK4 dynamics. CasADi's virtual machine evaluates them several times slower than
straight-line C, so the QP-data function is generated as C, compiled with the machine's compiler
(``gcc -O2 -shared -fPIC``) and loaded with :func:`casadi.external`.

The cache key is a SHA-256 of the *generated source* plus the compiler, its flags and the CasADi
version. The source is the problem (horizon, model parameters, residuals and constraints are all
in it), so any change to the problem gives a new key and a stale library can never be loaded.
Libraries are written to a temporary name and renamed atomically, so two processes compiling the
same problem at once (parallel tests, subprocess environments) cannot load a half-written file.

Only pure numerical functions go through this path; the HPIPM call itself is never generated
(see ../shared/reference/anchors.md: embedding it has crashed).
"""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import casadi as ca

DEFAULT_FLAGS: tuple[str, ...] = ("-O2", "-shared", "-fPIC")
CACHE_ENV = "WT_INSPECT_CACHE"


def default_cache_dir() -> Path:
    """``$WT_INSPECT_CACHE`` if set, else ``~/.cache/wt-inspect`` (the XDG convention)."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "wt-inspect"


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

    Without a usable compiler this warns and returns the uncompiled function, so the controller
    still works, only slower. ``compiler`` defaults to ``$CC`` or ``gcc``.
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
    directory = Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()
    directory.mkdir(parents=True, exist_ok=True)
    lib = directory / f"{fun.name()}_{key}.so"

    cache_hit = use_cache and lib.exists()
    compile_seconds = 0.0
    if not cache_hit:
        with tempfile.TemporaryDirectory(dir=directory) as tmp:
            c_file = Path(tmp) / f"{fun.name()}.c"
            c_file.write_text(src)
            tmp_lib = Path(tmp) / lib.name
            cmd = [exe, *flags, str(c_file), "-o", str(tmp_lib), "-lm"]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                warnings.warn(f"compiling {fun.name()!r} failed ({' '.join(cmd)}): "
                              f"{proc.stderr.strip()[:500]}; running it uncompiled",
                              RuntimeWarning, stacklevel=2)
                return CompiledFunction(_expanded(fun), False, None, False, 0.0, 0.0)
            os.replace(tmp_lib, lib)
        compile_seconds = time.perf_counter() - t0

    t1 = time.perf_counter()
    loaded = ca.external(fun.name(), str(lib))
    load_seconds = time.perf_counter() - t1
    return CompiledFunction(loaded, True, lib, cache_hit, compile_seconds, load_seconds)


def uncompiled(fun: ca.Function) -> CompiledFunction:
    """The uncompiled (SX-expanded where possible) function, wrapped like a compiled one."""
    return CompiledFunction(_expanded(fun), False, None, False, 0.0, 0.0)
