"""Controller names -> policy factories, found through Python entry points.

Every package that provides policies registers them under the entry-point group
``wt_inspect.controllers`` (:data:`wt_inspect_env.policy.ENTRY_POINT_GROUP`), each name pointing at
a :class:`~wt_inspect_env.policy.PolicyEntry`::

    [project.entry-points."wt_inspect.controllers"]
    vtnmpc = "controllers.registration:vtnmpc"
    ppo = "agents.registration:ppo"

so this harness never imports ``controllers`` or ``agents`` by name, and a third-party controller
plugs in exactly as ours do (as Gymnasium finds environments). Names are plain (``vtnmpc``,
``nmpc``, ...) or, for entries that take an argument, ``NAME:ARG`` (``ppo:PATH.zip``; the MPCs take
an optional one, ``vtnmpc:weights=FILE.json``). Any name may end in ``+filter``
(:data:`~wt_inspect_env.policy.FILTER_SUFFIX`): the policy then flies through the safety filter
registered as ``filter`` in the group ``wt_inspect.safety_filters``
(:mod:`controllers.safety_filter`), which keeps d_min from the turbine whatever it commands.
A factory takes the (unwrapped) environment and returns a policy with the common interface
(``reset(seed=None)``, ``act(obs)``; see :mod:`wt_inspect_env.policy`).

Entry points are read from the installed package metadata: after editing ``pyproject.toml``,
reinstall (``pip install -e .``) for a new name to appear.
"""
from __future__ import annotations

import functools
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from typing import Any, Callable, Mapping

from wt_inspect_env.policy import ENTRY_POINT_GROUP, FILTER_ENTRY_POINT_GROUP, FILTER_SUFFIX, PolicyEntry

from ..extras import missing_extra

PolicyFactory = Callable[[Any], Any]


@functools.cache
def _entry_points() -> dict[str, EntryPoint]:
    """Registered names; the same name from two packages with different targets is an error
    (the same target seen twice - an editable install's two metadata copies - is not)."""
    found: dict[str, EntryPoint] = {}
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        other = found.setdefault(ep.name, ep)
        if other.value != ep.value:
            raise ValueError(f"controller name {ep.name!r} is registered twice in entry-point group "
                             f"{ENTRY_POINT_GROUP!r}: {other.value} and {ep.value}")
    return found


@functools.cache
def _load(name: str) -> PolicyEntry:
    ep = _entry_points()[name]
    entry = ep.load()
    if not isinstance(entry, PolicyEntry):
        raise ValueError(f"entry point {name!r} of group {ENTRY_POINT_GROUP!r} ({ep.value}) must be a "
                         f"wt_inspect_env.policy.PolicyEntry, got {type(entry).__name__}")
    return entry


def entries() -> Mapping[str, PolicyEntry]:
    """Every registered entry, by name (loads each entry point's module)."""
    return {name: _load(name) for name in _entry_points()}


def source_roots() -> list[Path]:
    """The package directories that provide registered policies (for the run files' code
    fingerprint: every source that can change a result)."""
    roots = []
    for ep in _entry_points().values():
        module = __import__(ep.module.split(".")[0])
        root = Path(module.__file__).parent
        if root not in roots:
            roots.append(root)
    return roots


def valid_names() -> str:
    """The names accepted by :func:`resolve`, for error messages and ``--help``."""
    names = _entry_points()
    if not names:
        return ("(none registered: the package metadata has no entry points of group "
                f"{ENTRY_POINT_GROUP!r}; reinstall with pip install -e .)")
    # plain names (and optional arguments) first, then the names that need an argument
    return ", ".join(argument_form(n) for n in sorted(names, key=lambda n: _load(n).takes_argument))


def argument_form(name: str) -> str:
    """How a registered name is written: ``vtnmpc[:weights=FILE]``, ``ppo:PATH``, ``nmpc``."""
    entry = _load(name)
    if entry.takes_argument:
        return f"{name}:PATH"
    return f"{name}[:{entry.optional_argument}]" if entry.optional_argument else name


def split_name(name: str) -> tuple[str, str | None]:
    """``("ppo", "path.zip")`` for ``"ppo:path.zip"``, ``("vtnmpc", None)`` for ``"vtnmpc"``;
    ValueError naming the controller if it is not registered or its argument is missing/extra."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"controller must be a non-empty name; valid: {valid_names()}")
    base, sep, arg = name.partition(":")
    key = base.lower() if sep else base
    if key not in _entry_points():
        what = f"{base!r} is not a registered name taking an argument" if sep else "not registered"
        raise ValueError(f"unknown controller {name!r}: {what}; valid: {valid_names()}")
    entry = _load(key)
    if entry.takes_argument and not arg:
        raise ValueError(f"controller {name!r} needs an argument after '{key}:' (e.g. {key}:PATH.zip)")
    if entry.optional_argument and sep and not arg:
        raise ValueError(f"controller {name!r} needs an argument after '{key}:' (e.g. {key}:{entry.optional_argument})")
    if not entry.takes_argument and not entry.optional_argument and sep:
        raise ValueError(f"controller {base!r} takes no argument, got {name!r}")
    return key, (arg if sep else None)


def split_filter(name: str) -> tuple[str, bool]:
    """``("ppo:x.zip", True)`` for ``"ppo:x.zip+filter"``; ``(name, False)`` without the suffix."""
    if isinstance(name, str) and name.endswith(FILTER_SUFFIX):
        return name[:-len(FILTER_SUFFIX)], True
    return name, False


@functools.cache
def _safety_filter() -> Callable[[Any, Any], Any]:
    """The registered safety filter ``wrap(env, policy) -> policy``; ValueError if none is."""
    found = [ep for ep in entry_points(group=FILTER_ENTRY_POINT_GROUP) if ep.name == "filter"]
    if not found:
        raise ValueError(f"no safety filter is registered (entry point 'filter' of group "
                         f"{FILTER_ENTRY_POINT_GROUP!r}); reinstall with pip install -e .")
    wrap = found[0].load()
    if not callable(wrap):
        raise ValueError(f"safety filter {found[0].value} must be callable (env, policy) -> policy")
    return wrap


def _trust(entry: PolicyEntry, trust_model: bool) -> dict[str, bool]:
    """The ``trust_model`` keyword for an entry that takes it (see PolicyEntry.trust_option)."""
    return {"trust_model": bool(trust_model)} if entry.trust_option else {}


def check_controller(name: str, *, trust_model: bool = False) -> None:
    """ValueError listing the valid names unless ``name`` resolves (cheap: nothing is built;
    an entry's own ``check`` validates its argument, e.g. that a model file exists and loads
    without running code from it unless ``trust_model``). A missing optional dependency (``ppo:``
    without the ``rl`` extra) is a ValueError naming it and the extra, raised here - before any run."""
    name, filtered = split_filter(name)
    if filtered:
        _safety_filter()
    key, arg = split_name(name)
    try:
        entry = _load(key)
        if arg is not None and entry.check is not None:
            try:
                entry.check(arg, **_trust(entry, trust_model))
            except ValueError as exc:
                raise ValueError(f"controller {name!r}: {exc}") from None
    except ModuleNotFoundError as exc:
        msg = missing_extra(exc)
        if msg is None:
            raise
        raise ValueError(f"controller {name!r} {msg}") from None


def fingerprint(name: str) -> str:
    """What identifies the controller's behaviour for resuming: the name, plus what the entry
    says identifies its argument (a model file's content hash: a retrained ``ppo:model.zip``
    must not reuse the old results), and the filter suffix."""
    name, filtered = split_filter(name)
    key, arg = split_name(name)
    entry = _load(key)
    suffix = FILTER_SUFFIX if filtered else ""
    if arg is None:
        return key + suffix
    return (f"{key}:{entry.fingerprint(arg)}" if entry.fingerprint is not None else f"{key}:{arg}") + suffix


def env_options(name: str) -> dict[str, Any]:
    """The env options the controller ``name`` needs (its entry's ``env_options`` for its
    argument; none for a plain name or an entry without the hook)."""
    name, _ = split_filter(name)
    try:
        key, arg = split_name(name)
        entry = _load(key)
    except (KeyError, ValueError, ModuleNotFoundError):   # a bad name is reported where the run is planned
        return {}
    if arg is None or entry.env_options is None:
        return {}
    return dict(entry.env_options(arg))


def resolve(name: str, *, trust_model: bool = False) -> PolicyFactory:
    """The factory ``env -> policy`` of a controller name (see the module docstring);
    ``trust_model``: the user's explicit consent to run code from a model file that needs it."""
    check_controller(name, trust_model=trust_model)
    name, filtered = split_filter(name)
    key, arg = split_name(name)
    entry = _load(key)
    if arg is None:
        factory = entry.factory
    else:
        trust = _trust(entry, trust_model)
        factory = entry.with_argument(arg, **trust)
    return functools.partial(_filtered, factory) if filtered else factory


def _filtered(factory: PolicyFactory, env: Any) -> Any:
    """``factory``'s policy flown through the registered safety filter."""
    return _safety_filter()(env, factory(env))


def display_name(name: str) -> str:
    """Table name: the entry's display name (the paper's spelling for ours); for an entry with an
    argument, ``PPO (model stem)``, with `` + filter`` for a filtered one; a name that is not
    registered prints as it is."""
    name, filtered = split_filter(name)
    if filtered:
        return display_name(name) + " + filter"
    base, sep, arg = name.partition(":")
    key = base.lower() if sep else base
    if key not in _entry_points():
        return name
    entry = _load(key)
    shown = entry.display_name or key
    if not (sep and arg):
        return shown
    return f"{shown} ({entry.label(arg) if entry.label is not None else _argument_label(arg)})"


#: file stems every training run writes (``OUT/model.zip``, ``OUT/best_model.zip``): alone they
#: would give several runs' models one table name
GENERIC_STEMS = ("model", "best_model")


def _argument_label(arg: str) -> str:
    """A file argument's table name: its stem, with its folder for a generic stem
    (``seed_0/best_model``), so the seeds of one study get a column each."""
    path = Path(arg)
    if path.stem in GENERIC_STEMS and path.parent.name:
        return f"{path.parent.name}/{path.stem}"
    return path.stem
