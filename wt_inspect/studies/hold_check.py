"""Can VT-NMPC+ itself fly when its decisions are taken at 25 Hz and held like the DAgger learner's?

The expert's action is converted to the learner's action space (``agents.imitation.invert_action``
with the ``dagger_full`` recipe's spec), held for ``k`` control steps and decoded through the
agent's residual-hover action at every step, on the full mission in the paper's 4 m/s gust, for
``k`` = 4 (25 Hz, the learner's rate) and 1 (every step). Prints one line per ``k`` and the JSON of
both (quoted in ``results/imitation/dagger``)::

    wt-inspect study hold-check --seconds 12
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

HOLDS = (4, 1)


def run(seconds: float, holds: tuple[int, ...] = HOLDS) -> dict[int, dict]:
    """Per hold ``k``: flight time, termination, coverage, SM, CM and RMS distance error."""
    import gymnasium as gym

    import wt_inspect_env  # noqa: F401 - registers the env ids
    from agents.dagger import ShadowExpert, expert_factory
    from agents.imitation import invert_action
    from agents.recipe import RECIPE_DIR, load_recipe
    from agents.wrappers import ResidualHoverAction

    rec = load_recipe(RECIPE_DIR / "dagger_full.json")
    env = gym.make("WindTurbineInspection-v0", wind={"type": "gust", "mean_speed": 4.0}, time_limit_s=seconds)
    out: dict[int, dict] = {}
    try:
        u = env.unwrapped
        expert = ShadowExpert(expert_factory("vtnmpc-plus")(u))
        dec = ResidualHoverAction(rec.spec.action, u.scaling)
        for k in holds:
            obs, info = env.reset(seed=0)
            expert.reset(0)
            held = None
            t = 0
            while True:
                a = expert.label(obs)
                q = np.asarray(obs["quaternion"], float)
                if t % k == 0:
                    held = invert_action(rec.spec, u.scaling, a[None], q[None])[0]
                applied = dec(held, q)
                expert.applied(applied)
                obs, _, term, trunc, info = env.step(applied)
                t += 1
                if term or trunc:
                    break
            m = info["metrics"]
            out[k] = {"flight_s": round(float(info["time"]), 2), "termination": info["termination"],
                      **{x: round(float(m[x]), 4)
                         for x in ("coverage", "safety_sm", "centering_cm", "rms_distance_error_m")}}
    finally:
        env.close()
    return out


def main(argv: list[str] | None = None, prog: str = "wt-inspect study hold-check") -> int:
    """``wt-inspect study hold-check``: run the check given by ``argv``; returns the exit code."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="seconds of flight from the mission start")
    args = ap.parse_args(argv)
    if not args.seconds > 0:
        ap.error(f"--seconds must be positive, got {args.seconds!r}")
    out = run(args.seconds)
    for k, row in out.items():
        print(k, row, flush=True)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
