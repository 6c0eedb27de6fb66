"""A whole ``wt-inspect evaluate`` sweep as one TOML file (``--config FILE``).

A sweep worth keeping (the paper's table, a robustness study) is a dozen options; typed into a
shell they get lost or mistyped. A config file holds every option of the command, one key each,
and lives in version control next to its results. The command-line flags still win over the
file, so one file serves variations (``--config paper.toml --winds 4 --out out/w4``).

Keys are the long options' names with ``_`` for ``-`` (``--wind-type`` -> ``wind_type``); the two
switches that turn something off are booleans that say what is on (``--no-figures`` ->
``figures = false``, ``--no-progress`` -> ``progress = false``). Lists are TOML arrays
(``winds = [0, 4, 7]``, ``controllers = ["vtnmpc", "ppo:ppo_surface"]``), the JSON options are
TOML tables (``[turbine]``, ``[wind_options]``, ``[env]``). Relative paths (``out``, a model
file) are relative to the working directory, as on the command line. See
``examples/paper.toml`` for every key.

Everything is checked before anything runs: an unknown key or a value of the wrong type is a
one-line ``ValueError`` naming the file and the key (the CLI prints it and exits with 2).
"""
from __future__ import annotations

import dataclasses
import json
import math
import shlex
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from wt_inspect_env.util.figure_io import DEFAULT_FIGURE_FORMAT

# key -> kind; the kinds are checked by _check below.
KINDS: dict[str, str] = {
    "scenario": "str", "controllers": "str_list", "winds": "number_list", "seeds": "int_list", "out": "str",
    "backend": "str", "address": "str", "jobs": "int", "max_time": "number", "wind_type": "str",
    "wind_options": "table", "turbine": "table", "drone": "str", "env": "table", "record_every": "int",
    "figures": "bool", "figure_format": "str", "progress": "bool", "rerun": "bool", "trust_model": "bool",
}
_KIND_TEXT = {"str": "a string", "str_list": "an array of strings", "number_list": "an array of numbers",
              "int_list": "an array of integers", "int": "an integer", "number": "a number",
              "table": "a table", "bool": "true or false"}


@dataclass(frozen=True)
class EvaluateConfig:
    """Every option of ``wt-inspect evaluate`` with the command's defaults (``None``: the
    scenario's or the machine's choice, see the command's ``--help``)."""

    scenario: str = "paper"
    controllers: tuple[str, ...] = ("vtnmpc", "nmpc", "pampc")
    winds: tuple[float, ...] | None = None
    seeds: tuple[int, ...] = (0,)
    out: str | None = None
    backend: str = "local"
    address: str | None = None
    jobs: int | None = None
    max_time: float | None = None
    wind_type: str = "gust"
    wind_options: Mapping[str, Any] = field(default_factory=dict)
    turbine: Mapping[str, Any] = field(default_factory=dict)
    drone: str | None = None
    env: Mapping[str, Any] = field(default_factory=dict)
    record_every: int = 1
    figures: bool = True
    figure_format: str = DEFAULT_FIGURE_FORMAT
    progress: bool = True
    rerun: bool = False
    trust_model: bool = False

    def merged(self, overrides: Mapping[str, Any]) -> "EvaluateConfig":
        """This config with ``overrides`` (already-typed values, e.g. the flags given on the
        command line; ``None`` entries are ignored) on top."""
        check_values(overrides.keys(), source="overrides")
        given = {k: _freeze(k, v) for k, v in overrides.items() if v is not None}
        return dataclasses.replace(self, **given)

    def run_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :func:`wt_inspect.evaluation.run_evaluation` (``out`` must be set)."""
        if self.out is None:
            raise ValueError("out is required: give --out DIR or out = \"DIR\" in the config file")
        return {"scenario": self.scenario, "controllers": list(self.controllers),
                "winds": None if self.winds is None else list(self.winds), "seeds": list(self.seeds),
                "out": self.out, "backend": self.backend, "jobs": self.jobs, "address": self.address,
                "max_time": self.max_time, "wind_type": self.wind_type, "wind_options": dict(self.wind_options),
                "turbine": dict(self.turbine), "drone": self.drone, "env_overrides": dict(self.env),
                "record_every": self.record_every, "figures": self.figures, "figure_format": self.figure_format,
                "progress": self.progress, "rerun": self.rerun, "trust_model": self.trust_model}

    def command(self, prog: str = "wt-inspect evaluate") -> str:
        """The equivalent command line with flags only (every option that differs from the
        default), so a results file made from a config still says how to rerun it without it."""
        default = EvaluateConfig()
        parts = [prog]
        for f in dataclasses.fields(self):
            value, base = getattr(self, f.name), getattr(default, f.name)
            if value == base and f.name != "scenario":   # the scenario always: it says what the sweep is
                continue
            flag = "--" + f.name.replace("_", "-")
            if KINDS[f.name] == "bool":
                parts.append({"figures": "--no-figures", "progress": "--no-progress"}.get(f.name, flag))
            elif KINDS[f.name].endswith("_list"):
                parts += [flag, ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value)]
            elif KINDS[f.name] == "table":
                parts += [flag, json.dumps(dict(value))]
            else:
                parts += [flag, f"{value:g}" if isinstance(value, float) else str(value)]
        return " ".join(shlex.quote(p) if i else p for i, p in enumerate(parts))


def check_values(keys: Any, *, source: str) -> None:
    """ValueError naming ``source`` and the first key that is not an option."""
    for key in keys:
        if key not in KINDS:
            raise ValueError(f"{source}: unknown key {key!r}; valid keys: {', '.join(KINDS)}")


def _check(source: str, key: str, value: Any) -> Any:
    """``value`` if it has the kind of ``key`` (ints accepted as numbers), else ValueError naming
    the key, the kind it must have and what it got."""
    kind = KINDS[key]

    def is_int(v: Any) -> bool:
        return isinstance(v, int) and not isinstance(v, bool)

    def is_num(v: Any) -> bool:
        return (is_int(v) or isinstance(v, float)) and math.isfinite(v)

    ok = {"str": lambda v: isinstance(v, str),
          "bool": lambda v: isinstance(v, bool),
          "int": is_int,
          "number": is_num,
          "table": lambda v: isinstance(v, dict),
          "str_list": lambda v: isinstance(v, list) and bool(v) and all(isinstance(x, str) for x in v),
          "number_list": lambda v: isinstance(v, list) and bool(v) and all(is_num(x) for x in v),
          "int_list": lambda v: isinstance(v, list) and bool(v) and all(is_int(x) for x in v)}[kind](value)
    if not ok:
        empty = " (not empty)" if kind.endswith("_list") else ""
        raise ValueError(f"{source}: key {key!r} must be {_KIND_TEXT[kind]}{empty}, got {value!r}")
    return value


def _freeze(key: str, value: Any) -> Any:
    """Lists as tuples (the dataclass is frozen and comparable), numbers of number kinds as floats."""
    kind = KINDS[key]
    if kind == "number_list":
        return tuple(float(v) for v in value)
    if kind.endswith("_list"):
        return tuple(value)
    if kind == "number":
        return float(value)
    if kind == "table":
        return dict(value)
    return value


def parse_config(data: Mapping[str, Any], source: str = "config") -> EvaluateConfig:
    """An :class:`EvaluateConfig` from a parsed TOML document (unknown keys and wrong types are a
    ValueError naming ``source`` and the key)."""
    check_values(data.keys(), source=source)
    return EvaluateConfig(**{k: _freeze(k, _check(source, k, v)) for k, v in data.items()})


def load_config(path: str | Path) -> EvaluateConfig:
    """Read and check a TOML sweep file (see the module docstring); ValueError with one line
    naming the file (and the key) on any problem."""
    p = Path(path)
    try:
        text = p.read_bytes()
    except OSError as exc:
        raise ValueError(f"cannot read config file {str(p)!r}: {exc.strerror or exc}") from None
    try:
        data = tomllib.loads(text.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"config file {str(p)!r} is not valid TOML: {exc}") from None
    return parse_config(data, source=f"config file {str(p)!r}")


__all__ = ["EvaluateConfig", "KINDS", "load_config", "parse_config"]
