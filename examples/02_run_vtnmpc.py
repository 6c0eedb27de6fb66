"""Tutorial 2: fly the paper's controller (and VT-NMPC+) on the surface task for a few seconds.

Run: python examples/02_run_vtnmpc.py   (about 10 s; the first run also compiles the QP code, ~1 s)

Any policy with ``reset(seed)`` / ``act(obs)`` drives the env the same way; ``last_stats`` reports
the MPC's solve time and QP iterations of the last step.
"""
import gymnasium as gym

import wt_inspect_env  # noqa: F401 - registers the environment ids
from controllers.vtnmpc import VTNMPC_PLUS, VTNMPCPolicy

SECONDS = 3.0
for name, options in (("VT-NMPC (the paper's form)", {}), ("VT-NMPC+", VTNMPC_PLUS)):
    env = gym.make("WindTurbineInspection-Surface-v0", wind={"type": "gust", "mean_speed": 4.0})
    u = env.unwrapped
    policy = VTNMPCPolicy(params=u.params, d_ref=u.config.standoff, **options)
    obs, info = env.reset(seed=0)
    policy.reset(seed=0)
    for _ in range(int(SECONDS / u.dt)):
        obs, reward, terminated, truncated, info = env.step(policy.act(obs))
        if terminated or truncated:
            break
    m = info["metrics"]
    print(f"{name:<27} {m['flight_time_s']:.1f} s: coverage {m['coverage']:.3f}, SM {m['safety_sm']:.3f}, "
          f"CM {m['centering_cm']:.4f}, RMS distance error {m['rms_distance_error_m']:.2f} m; "
          f"last solve {policy.last_stats.solve_ms:.2f} ms")
    env.close()
