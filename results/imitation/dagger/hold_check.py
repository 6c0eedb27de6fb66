"""Can VT-NMPC+ itself fly when its decisions are taken at 25 Hz and held like the DAgger learner's
(decoded through the agent's residual-hover action at every control step)? Run from the repository root:
``python results/imitation/dagger/hold_check.py 12`` (seconds of flight from the mission start, 4 m/s gust)."""
import sys, json, numpy as np, gymnasium as gym, wt_inspect_env
from agents.dagger import expert_factory, ShadowExpert
from agents.imitation import invert_action
from agents.recipe import load_recipe
from agents.wrappers import ResidualHoverAction
rec = load_recipe("agents/recipes/dagger_full.json")
T = float(sys.argv[1]) if len(sys.argv) > 1 else 30.0
env = gym.make("WindTurbineInspection-v0", wind={"type": "gust", "mean_speed": 4.0}, time_limit_s=T)
u = env.unwrapped
expert = ShadowExpert(expert_factory("vtnmpc-plus")(u))
dec = ResidualHoverAction(rec.spec.action, u.scaling)
out = {}
for k in (4, 1):
    obs, info = env.reset(seed=0); expert.reset(0)
    held = None
    for t in range(10**7):
        a = expert.label(obs)
        q = np.asarray(obs["quaternion"], float)
        if t % k == 0:
            held = invert_action(rec.spec, u.scaling, a[None], q[None])[0]
        applied = dec(held, q)
        expert.applied(applied)
        obs, r, term, trunc, info = env.step(applied)
        if term or trunc:
            break
    m = info["metrics"]
    out[k] = {"flight_s": round(float(info["time"]), 2), "termination": info["termination"],
              **{x: round(float(m[x]), 4) for x in ("coverage", "safety_sm", "centering_cm", "rms_distance_error_m")}}
    print(k, out[k], flush=True)
print(json.dumps(out))
