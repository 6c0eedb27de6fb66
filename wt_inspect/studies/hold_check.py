"""Can VT-NMPC+ itself fly when its decisions are taken at 25 Hz and held like the DAgger learner's?

The expert's action is converted to the learner's action space (``agents.imitation.invert_action``
with the ``dagger_full`` recipe's spec), held for ``k`` control steps and decoded through the
agent's residual-hover action at every step, on the full mission in the paper's gust (4 m/s unless
``--wind``), for ``k`` = 4 (25 Hz, the learner's rate) and 1 (every step) unless ``--holds``. Prints
one line per ``k`` and the JSON of all (quoted in the imitation study's report)::

    wt-inspect study hold-check --seconds 12
    wt-inspect study hold-check --seconds 150 --wind 7 --holds 4,2,1 --expert vtnmpc-plus:backoff=0.5

Besides the mission metrics each ``k`` reports the least clearance to the structure and the share
of the held decisions at the action bounds per component [p, q, r, thrust]: a held loop that
oscillates shows as saturated labels, which a learner deciding at that rate has to copy.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

import numpy as np

HOLDS = (4, 1)
#: an action component at least this close to +-1 counts as saturated (the action bounds)
SATURATED = 0.999


def label_stats(Y: np.ndarray) -> dict[str, Any]:
    """Samples, per-component standard deviation and share at the bounds of agent actions ``Y``
    (n, 4) - the expert's labels in the imitation study, its held decisions here."""
    Y = np.asarray(Y, dtype=np.float64).reshape(-1, 4)
    if len(Y) == 0:
        return {"samples": 0, "label_std": [None] * 4, "saturated_share": [None] * 4}
    return {"samples": int(len(Y)), "label_std": [round(float(s), 4) for s in Y.std(axis=0)],
            "saturated_share": [round(float(s), 4) for s in (np.abs(Y) >= SATURATED).mean(axis=0)]}


def run(seconds: float, holds: tuple[int, ...] = HOLDS, *, wind: float = 4.0,
        expert: str = "vtnmpc-plus") -> dict[int, dict]:
    """Per hold ``k``: flight time, termination, coverage, SM, CM, RMS distance error, least
    clearance and the share of held decisions at the bounds, flown by ``expert`` (a registered
    controller, with its argument if any) in the paper's gust of mean ``wind`` [m/s]."""
    import gymnasium as gym

    import wt_inspect_env  # noqa: F401 - registers the env ids
    from agents.dagger import ShadowExpert, expert_factory
    from agents.imitation import invert_action
    from agents.recipe import RECIPE_DIR, load_recipe
    from agents.wrappers import ResidualHoverAction

    for k in holds:
        if isinstance(k, bool) or not isinstance(k, int) or k < 1:
            raise ValueError(f"--holds must be positive integers, got {k!r}")
    factory = expert_factory(expert)            # a bad expert fails here, before anything flies
    rec = load_recipe(RECIPE_DIR / "dagger_full.json")
    env = gym.make("WindTurbineInspection-v0", wind={"type": "gust", "mean_speed": float(wind)},
                   time_limit_s=seconds, structure_observation=True)
    out: dict[int, dict] = {}
    try:
        u = env.unwrapped
        shadow = ShadowExpert(factory(u))
        dec = ResidualHoverAction(rec.spec.action, u.scaling)
        for k in holds:
            obs, info = env.reset(seed=0)
            shadow.reset(0)
            held = None
            decisions: list[np.ndarray] = []
            least = float(obs["structure"][3])
            t = 0
            while True:
                a = shadow.label(obs)
                q = np.asarray(obs["quaternion"], float)
                if t % k == 0:
                    held = invert_action(rec.spec, u.scaling, a[None], q[None])[0]
                    decisions.append(held)
                applied = dec(held, q)
                shadow.applied(applied)
                obs, _, term, trunc, info = env.step(applied)
                least = min(least, float(obs["structure"][3]))
                t += 1
                if term or trunc:
                    break
            m = info["metrics"]
            out[k] = {"flight_s": round(float(info["time"]), 2), "termination": info["termination"],
                      **{x: round(float(m[x]), 4)
                         for x in ("coverage", "safety_sm", "centering_cm", "rms_distance_error_m")},
                      "least_clearance_m": round(least, 3),
                      "saturated_share": label_stats(np.asarray(decisions))["saturated_share"]}
    finally:
        env.close()
    return out


def main(argv: list[str] | None = None, prog: str = "wt-inspect study hold-check") -> int:
    """``wt-inspect study hold-check``: run the check given by ``argv``; returns the exit code."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="seconds of flight from the mission start")
    ap.add_argument("--wind", type=float, default=4.0, help="mean speed of the paper's gust [m/s] (default 4)")
    ap.add_argument("--holds", default=",".join(map(str, HOLDS)),
                    help="comma-separated hold lengths k in control steps (default 4,1)")
    ap.add_argument("--expert", default="vtnmpc-plus",
                    help="registered controller, with its argument if any (default vtnmpc-plus)")
    args = ap.parse_args(argv)
    if not args.seconds > 0:
        ap.error(f"--seconds must be positive, got {args.seconds!r}")
    if not (math.isfinite(args.wind) and args.wind >= 0):
        ap.error(f"--wind must be a non-negative speed, got {args.wind!r}")
    try:
        holds = tuple(int(x) for x in args.holds.split(","))
    except ValueError:
        ap.error(f"--holds must be comma-separated positive integers, got {args.holds!r}")
    try:
        out = run(args.seconds, holds, wind=args.wind, expert=args.expert)
    except ValueError as exc:                   # a bad hold or expert, named
        ap.error(str(exc))
    for k, row in out.items():
        print(k, row, flush=True)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
