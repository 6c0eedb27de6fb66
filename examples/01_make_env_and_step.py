"""Tutorial 1: make the environment, read its observation, step it, read the reward and metrics.

Run: python examples/01_make_env_and_step.py   (a few seconds)

The drone starts at the stand-off pose of the first inspection point (7 m from the blade) and is
commanded to hover for two simulated seconds while the wind pushes it; every reward term and
the inspection metrics so far are in ``info``.
"""
import gymnasium as gym
import numpy as np

import wt_inspect_env  # noqa: F401 - registers WindTurbineInspection-v0, -Blade-v0, -Surface-v0

env = gym.make("WindTurbineInspection-Surface-v0", wind={"type": "gust", "mean_speed": 4.0}, standoff=7.0)
obs, info = env.reset(seed=0)
print("observation keys:", ", ".join(f"{k}{tuple(v.shape)}" for k, v in obs.items()))
print("action space:", env.action_space, "(normalised body rates p, q, r and collective thrust)")

# a = 0 is not hover (thrust maps [-1, 1] to [0.3, 2] m g): ask the action scaling for it
hover = env.unwrapped.scaling.hover_action()
start = obs["position"].copy()
for _ in range(200):                      # 100 Hz control: 2 s
    obs, reward, terminated, truncated, info = env.step(hover)
    if terminated or truncated:
        break

print(f"after {info['metrics']['flight_time_s']:.2f} s: drifted {np.linalg.norm(obs['position'] - start):.2f} m "
      f"in the 4 m/s gust (hovering is not holding the pose)")
print("reward terms of the last step:", {k: round(float(v), 4) for k, v in info["reward_terms"].items()})
m = info["metrics"]
print(f"metrics so far: coverage {m['coverage']:.3f}, SM {m['safety_sm']:.3f}, CM {m['centering_cm']:.3f}")
env.close()
