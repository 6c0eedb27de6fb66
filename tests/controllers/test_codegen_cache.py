"""The compiled-solver cache (issue 17): a replaced library is rebuilt, never loaded; 0-byte and
garbage entries are rebuilt; leftovers of killed compiles are removed; the directory is private
and refused when someone else could write to it; builds are atomic.

Every test uses its own temporary cache directory and its own function name: a process keeps a
library it has loaded once (dlopen matches by path), so each corrupted entry is loaded here for
the first time, as it would be by the next process.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import stat
import subprocess
import sys
import time
import warnings
from pathlib import Path

import casadi as ca
import pytest

from controllers.codegen import DIGEST_SUFFIX, CacheDirError, LibraryCache, compile_function

pytestmark = pytest.mark.skipif(shutil.which(os.environ.get("CC") or "gcc") is None, reason="no C compiler")

FUNCTION = """
import casadi as ca
def probe(name):
    x = ca.SX.sym("x", 2)
    return ca.Function(name, [x], [ca.sin(x) * x[0] + 1.0])
"""
_ns: dict = {}
exec(FUNCTION, _ns)
probe = _ns["probe"]


def _populate(cache: Path, name: str) -> Path:
    """Compile ``probe(name)`` into ``cache`` in another process; the library's path."""
    code = FUNCTION + (f"\nfrom controllers.codegen import compile_function\n"
                       f"print(compile_function(probe({name!r}), cache_dir={str(cache)!r}).path)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return Path(out.stdout.strip().splitlines()[-1])


def _replace(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".new")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def _compile_warned(name: str, cache: Path):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = compile_function(probe(name), cache_dir=cache)
    return res, [str(w.message) for w in caught]


def _check_values(res) -> None:
    out = res.function(ca.DM([0.5, 2.0]))
    assert res.compiled
    assert abs(float(out[1]) - (ca.sin(2.0) * 0.5 + 1.0)) < 1e-12


def test_cache_dir_is_private_and_builds_are_atomic(tmp_path):
    cache = tmp_path / "a" / "cache"
    res = compile_function(probe("cc_atomic"), cache_dir=cache)
    assert stat.S_IMODE(cache.stat().st_mode) == 0o700
    assert not res.cache_hit and res.path.parent == cache
    names = sorted(p.name for p in cache.iterdir())
    assert names == [res.path.name, res.path.name + DIGEST_SUFFIX]       # no temporary left behind
    recorded = (cache / (res.path.name + DIGEST_SUFFIX)).read_text().split()[0]
    assert recorded == hashlib.sha256(res.path.read_bytes()).hexdigest()
    again = compile_function(probe("cc_atomic"), cache_dir=cache)
    assert again.cache_hit
    _check_values(again)


def test_a_poisoned_library_is_rebuilt_not_loaded(tmp_path):
    cache = tmp_path / "cache"
    lib = _populate(cache, "cc_poison")
    marker = tmp_path / "constructor_ran"
    evil_src = tmp_path / "evil.c"
    evil_src.write_text('#include <stdio.h>\n__attribute__((constructor)) static void pwn(void) {\n'
                        f'  FILE *f = fopen("{marker}", "w"); if (f) {{ fputs("pwned", f); fclose(f); }}\n}}\n')
    evil = tmp_path / "evil.so"
    subprocess.run(["gcc", "-shared", "-fPIC", str(evil_src), "-o", str(evil)], check=True)
    # the payload is real: loading the library runs it
    subprocess.run([sys.executable, "-c", f"import ctypes; ctypes.CDLL({str(evil)!r})"], check=True)
    assert marker.read_text() == "pwned"
    marker.unlink()
    _replace(lib, evil.read_bytes())                     # same name, the digest file left as it was
    res, msgs = _compile_warned("cc_poison", cache)
    assert not marker.exists()
    assert not res.cache_hit and any("differs from" in m and "rebuilding" in m for m in msgs)
    _check_values(res)
    assert hashlib.sha256(lib.read_bytes()).hexdigest() != hashlib.sha256(evil.read_bytes()).hexdigest()


def test_a_library_without_its_digest_is_rebuilt(tmp_path):
    cache = tmp_path / "cache"
    lib = _populate(cache, "cc_nodigest")
    (cache / (lib.name + DIGEST_SUFFIX)).unlink()
    res, msgs = _compile_warned("cc_nodigest", cache)
    assert not res.cache_hit and any("no SHA-256 recorded" in m for m in msgs)
    _check_values(res)
    assert (cache / (lib.name + DIGEST_SUFFIX)).is_file()


def test_a_zero_byte_entry_is_rebuilt(tmp_path):
    cache = tmp_path / "cache"
    lib = _populate(cache, "cc_empty")
    _replace(lib, b"")
    res, msgs = _compile_warned("cc_empty", cache)
    assert not res.cache_hit and any("rebuilding" in m for m in msgs)
    assert lib.stat().st_size > 0
    _check_values(res)


def test_a_garbage_entry_that_fails_to_load_is_rebuilt(tmp_path):
    """Even with a matching digest (written by whoever wrote the garbage), a library that does not
    load is rebuilt instead of failing every later construction."""
    cache = tmp_path / "cache"
    lib = _populate(cache, "cc_garbage")
    _replace(lib, b"garbage, not an ELF file")
    (cache / (lib.name + DIGEST_SUFFIX)).write_text(hashlib.sha256(b"garbage, not an ELF file").hexdigest())
    res, msgs = _compile_warned("cc_garbage", cache)
    assert not res.cache_hit and any("failed to load" in m for m in msgs)
    _check_values(res)
    second = compile_function(probe("cc_garbage"), cache_dir=cache)
    assert second.cache_hit


def test_leftovers_of_killed_compiles_are_removed(tmp_path):
    cache = tmp_path / "cache"
    LibraryCache.open(cache)
    dead = subprocess.Popen(["true"])
    dead.wait()
    killed = cache / f"tmp-{dead.pid}-abc123"              # a compile whose process is gone
    old = cache / "tmpq1w2e3r4"                             # tempfile-style, two hours old
    fresh = cache / "tmpfresh99"                            # maybe a compile running right now
    mine = cache / f"tmp-{os.getpid()}-zzz"
    for d in (killed, old, fresh, mine):
        d.mkdir()
        (d / "probe.c").write_text("int x;")
    two_hours_ago = time.time() - 7200
    os.utime(old, (two_hours_ago, two_hours_ago))
    keep = cache / "tmp_not_a_dir.so"
    keep.write_text("")
    compile_function(probe("cc_leftover"), cache_dir=cache)
    assert not killed.exists() and not old.exists()
    assert fresh.exists() and mine.exists() and keep.exists()


def test_a_cache_dir_others_can_write_is_refused(tmp_path):
    cache = tmp_path / "cache"
    LibraryCache.open(cache)
    cache.chmod(0o777)
    with pytest.raises(CacheDirError, match="world-writable") as exc:
        compile_function(probe("cc_perm"), cache_dir=cache)
    assert str(cache) in str(exc.value) and "\n" not in str(exc.value)
    cache.chmod(0o770)
    with pytest.raises(CacheDirError, match="0770"):
        LibraryCache.open(cache)
    cache.chmod(0o755)                                       # readable by others is fine, writable is not
    LibraryCache.open(cache)
    assert not list(cache.glob("*.so"))                      # nothing was built while refused


@pytest.mark.skipif(os.geteuid() != 0, reason="changing a directory's owner needs root")
def test_a_cache_dir_owned_by_another_user_is_refused(tmp_path):
    cache = tmp_path / "cache"
    LibraryCache.open(cache)
    os.chown(cache, 12345, -1)
    with pytest.raises(CacheDirError, match="owned by uid 12345") as exc:
        compile_function(probe("cc_owner"), cache_dir=cache)
    assert "\n" not in str(exc.value)


@pytest.mark.slow
def test_the_hpipm_shim_goes_through_the_guarded_cache(tmp_path):
    from controllers import hpipm_direct
    if not (hpipm_direct._casadi_lib_dir() / "libhpipm.so").exists():
        pytest.skip("no libhpipm in this casadi")
    cache = tmp_path / "cache"
    code = ("import sys; from controllers.hpipm_direct import shim_library; "
            f"print(shim_library({str(cache)!r}))")
    lib = Path(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              check=True).stdout.strip().splitlines()[-1])
    assert (cache / (lib.name + DIGEST_SUFFIX)).is_file()
    _replace(lib, b"")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        loaded, path = hpipm_direct.load_shim(cache)
    assert path == lib and lib.stat().st_size > 0 and hasattr(loaded, "vtqp_create")
    assert any("rebuilding" in str(w.message) for w in caught)
