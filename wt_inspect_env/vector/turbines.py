"""The vector env's many-turbine options: their validation from plain data (a training recipe's
``turbines`` entry) and the seeding of a world's turbine stream, kept apart from the env's stepping."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ..task.turbine_draws import TurbineDistribution
from ..util.validation import check_positive, check_positive_int, check_unknown_options

REDRAW = "redraw"             # termination name of a drone cut short by its world's new turbine
_TURBINE_STREAM = 0x7B1E      # mixed into a world's seed: its turbines' stream, apart from its drones'


def turbine_stream(seed: int | None) -> np.random.Generator:
    """A world's turbine stream, from the seed of its first drone (fresh entropy without): its own
    stream, so the turbines drawn do not move the drone's start, wind or randomisation draws."""
    return np.random.default_rng([int(seed), _TURBINE_STREAM]) if seed is not None else np.random.default_rng()


#: the keys of a recipe's (or any plain-data caller's) many-turbine options
MANY_TURBINE_KEYS: tuple[str, ...] = ("distribution", "n_turbines", "redraw_every", "redraw_after_s")


def many_turbine_kwargs(options: Any) -> dict[str, Any]:
    """The vector env's keyword options of plain-data many-turbine options (a training recipe's
    ``turbines`` entry): ``{"distribution": {...TurbineDistribution fields}, "n_turbines": G,
    "redraw_every": K}`` or ``"redraw_after_s": T`` instead of K, all optional but ``n_turbines``.
    Validated here, so a recipe fails when it is read; that ``n_turbines`` divides the number of
    drones is checked when the env is built."""
    if not isinstance(options, Mapping):
        raise ValueError(f"turbines must be a dict with keys {', '.join(MANY_TURBINE_KEYS)}, got {options!r}")
    check_unknown_options("turbines", options.keys(), MANY_TURBINE_KEYS)
    if "n_turbines" not in options:
        raise ValueError("turbines.n_turbines is required (the number of worlds, dividing the number of drones)")
    out = {"turbines": TurbineDistribution.coerce(options.get("distribution", {})),
           "n_turbines": check_positive_int("turbines.n_turbines", options["n_turbines"]),
           "redraw_every": check_positive_int("turbines.redraw_every", options.get("redraw_every", 1))}
    if "redraw_after_s" in options:
        if "redraw_every" in options:
            raise ValueError("turbines: give either redraw_every (episodes) or redraw_after_s (simulated seconds), "
                             "not both")
        out["redraw_after_s"] = check_positive("turbines.redraw_after_s", options["redraw_after_s"])
    return out


