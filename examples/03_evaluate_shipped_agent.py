"""Tutorial 3: score a shipped PPO agent with the evaluation harness, then drive its bare
stable-baselines3 model yourself.

Run: python examples/03_evaluate_shipped_agent.py   (about 15 s on an idle machine; needs the rl extra:
pip install "wt-inspect[rl]")

``evaluate_policy`` flies one run exactly as ``wt-inspect evaluate`` does (here capped at a few
simulated seconds); ``agent_env`` wraps the env so that ``model.predict(obs)`` takes its
observation - the model's own 27 normalised features - and its action goes straight to ``step``.
"""
import gymnasium as gym

import wt_inspect_env  # noqa: F401 - registers the environment ids
from agents.policy import agent_env, load_sb3_policy
from agents.safe_load import resolve_model_path, shipped_models
from wt_inspect.evaluation import evaluate_policy

print("shipped agents:", ", ".join(shipped_models()))

# 1. the harness: a registered name, scored like every other controller
run = evaluate_policy("ppo:ppo_surface_wind_mix", scenario="surface", wind=4.0, max_time=3.0)
row = run.row()
print(f"harness, 3 s of the surface task at 4 m/s: coverage {row['coverage']:.3f}, SM {row['safety']:.3f}, "
      f"CM {row['centering']:.3f}")

# 2. plain stable-baselines3: model.predict on the wrapped env's observation
path = resolve_model_path("ppo_surface_wind_mix")
model = load_sb3_policy("ppo", path).model          # a stable_baselines3.PPO (loaded without unpickling)
env = agent_env(gym.make("WindTurbineInspection-Surface-v0", wind={"type": "gust", "mean_speed": 4.0}), path)
obs, info = env.reset(seed=0)
print("model input:", obs.shape, "- the env's own observation is a Dict of", len(env.unwrapped.observation_space))
for _ in range(75):                                  # each step holds the action for 4 control steps: 3 s
    action, _ = model.predict(obs, deterministic=True)
    obs, reward, terminated, truncated, info = env.step(action)
    if terminated or truncated:
        break
m = info["metrics"]
print(f"bare model, {m['flight_time_s']:.1f} s: coverage {m['coverage']:.3f}, SM {m['safety_sm']:.3f}, "
      f"CM {m['centering_cm']:.3f}")
env.close()
