"""``wt-inspect bench train``: training throughput (simulator steps per second), vector env vs subprocesses.

For each backend - the native vector env (``--n-envs`` drones in this process, the default of
``wt-inspect train``) and, as the reference timed in the same run, SB3's subprocess vector env
(``--ref-n-envs`` single envs, one per process, the path training used before) - two numbers,
each the median of several repeats after a warm-up:

* ``vecenv``: the agent envs alone (the recipe's features, actions, shaping, VecNormalize),
  driven by random policy actions - the ceiling set by simulation (and inter-process traffic);
* ``learn``: ``model.learn`` of the recipe's algorithm for the same number of steps - what a
  training run really gets, including network forward passes and gradient updates.

The vector figures are also printed as ratios to the subprocess ones, and ``model.learn``'s time
is split into where it goes (summed over the timed repeats): ``env`` - stepping the agent envs
(simulation, features, shaping, normalisation), ``policy`` - the rest of collecting the rollouts
(the network's forward passes, the rollout buffer), ``update`` - the gradient epochs. This is what
decides which part to make faster (the issue of a learner "as fast as the simulator allows").

Steps are simulator control steps (100 Hz), so an ``action_repeat`` of k counts k per decision.
The machine's other load is not controlled: run it on a quiet machine for comparable numbers.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time

import numpy as np

from wt_inspect_env.task.env_config import TASKS
from wt_inspect_env.util.validation import check_choice

from .policy import ALGOS


def _timed_vec_env(venv):
    """``venv`` behind a pass-through VecEnv wrapper that adds up the wall time of its steps."""
    from stable_baselines3.common.vec_env import VecEnvWrapper

    class TimedVecEnv(VecEnvWrapper):
        def __init__(self) -> None:
            super().__init__(venv)
            self.seconds = 0.0

        def reset(self):
            return self.venv.reset()

        def step_wait(self):
            t = time.perf_counter()
            out = self.venv.step_wait()
            self.seconds += time.perf_counter() - t
            return out

    return TimedVecEnv()


def _phase_callback():
    """A callback adding up the wall time ``model.learn`` spends collecting rollouts."""
    from stable_baselines3.common.callbacks import BaseCallback

    class Phases(BaseCallback):
        def __init__(self) -> None:
            super().__init__(verbose=0)
            self.rollout = 0.0
            self._t = 0.0

        def _on_rollout_start(self) -> None:
            self._t = time.perf_counter()

        def _on_rollout_end(self) -> None:
            self.rollout += time.perf_counter() - self._t

        def _on_step(self) -> bool:
            return True

    return Phases()


def run_bench(algo: str = "ppo", task: str = "surface", n_envs: int = 2, steps: int = 20_000,
              repeats: int = 3, recipe: str | None = None, seed: int = 0, backend: str = "vector") -> dict:
    """Run the benchmark and return its summary (see the module docstring)."""
    check_choice("algorithm", algo, ALGOS)
    check_choice("task", task, TASKS)
    for name, v in (("n_envs", n_envs), ("steps", steps), ("repeats", repeats)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ValueError(f"{name} must be a positive integer, got {v!r}")
    import torch
    from stable_baselines3.common.vec_env import VecNormalize

    from .policy import algo_class
    from .recipe import default_recipe_path, load_recipe
    from .training import _algo_kwargs, _policy_kwargs, recipe_vec_env

    rec = load_recipe(recipe or default_recipe_path(algo))
    if rec.algo != algo:
        raise ValueError(f"recipe is for algorithm {rec.algo!r}, not {algo!r}")
    torch.set_num_threads(rec.torch_threads)
    k = rec.spec.action_repeat
    decisions = math.ceil(steps / (k * n_envs))     # vector steps
    venv = VecNormalize(recipe_vec_env(rec, task, n_envs, backend=backend, seed=seed),
                        gamma=float(rec.algo_kwargs.get("gamma", 0.99)))
    rng = np.random.default_rng(seed)
    vec_rates, learn_rates = [], []
    try:
        venv.seed(seed)
        venv.reset()
        for rep in range(repeats + 1):            # repeat 0 warms up
            t0 = time.perf_counter()
            n = 0
            for _ in range(decisions):
                a = np.clip(rng.normal(0.0, 0.3, (n_envs, 4)), -1, 1).astype(np.float32)
                _, _, _, infos = venv.step(a)
                n += sum(i.get("env_steps", k) for i in infos)
            if rep > 0:
                vec_rates.append(n / (time.perf_counter() - t0))
        kw = _algo_kwargs(rec)
        if algo == "ppo":   # one update per repeat at least
            kw["n_steps"] = min(int(kw.get("n_steps", 2048)), decisions)
            kw["batch_size"] = min(int(kw.get("batch_size", 64)), kw["n_steps"] * n_envs)
        timed = _timed_vec_env(venv)
        model = algo_class(algo)("MlpPolicy", timed, seed=seed, device="cpu",
                                 policy_kwargs=_policy_kwargs(rec), **kw)
        split = {"env": 0.0, "rollout": 0.0, "total": 0.0}
        for rep in range(repeats + 1):
            phases = _phase_callback()
            env0 = timed.seconds
            t0 = time.perf_counter()
            model.learn(total_timesteps=decisions * n_envs, reset_num_timesteps=False, callback=phases)
            dt = time.perf_counter() - t0
            if rep > 0:
                learn_rates.append(decisions * n_envs * k / dt)
                split["env"] += timed.seconds - env0
                split["rollout"] += phases.rollout
                split["total"] += dt
    finally:
        venv.close()
    return {
        "benchmark": "train", "backend": backend,
        "algo": algo, "task": task, "n_envs": n_envs, "action_repeat": k,
        "steps_per_repeat": decisions * n_envs * k, "repeats": repeats,
        "vecenv_steps_per_s": statistics.median(vec_rates),
        "learn_steps_per_s": statistics.median(learn_rates),
        "learn_steps_per_s_min": min(learn_rates), "learn_steps_per_s_max": max(learn_rates),
        "minutes_per_2M_steps": 2e6 / statistics.median(learn_rates) / 60.0,
        "learn_time_split": {"env": split["env"] / split["total"],
                             "policy": (split["rollout"] - split["env"]) / split["total"],
                             "update": (split["total"] - split["rollout"]) / split["total"]},
        "cpus": os.cpu_count(), "torch_threads": rec.torch_threads,
        "load_average": os.getloadavg()[0],
    }


def main(argv: list[str], prog: str = "wt-inspect bench train") -> int:
    """``wt-inspect bench train``: parse ``argv``, run the benchmark and print it; returns the exit code."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--algo", default="ppo", help=f"algorithm: {', '.join(ALGOS)}")
    ap.add_argument("--task", default="surface", help=f"task: {', '.join(TASKS)}")
    ap.add_argument("--n-envs", type=int, default=16, help="drones of the vector env (default 16)")
    ap.add_argument("--ref-n-envs", type=int, default=2, help="subprocess envs of the reference (default 2)")
    ap.add_argument("--steps", type=int, default=20_000, help="simulator steps per repeat")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--recipe", default=None)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    try:
        vec = run_bench(args.algo, args.task, args.n_envs, args.steps, args.repeats, args.recipe, backend="vector")
        ref = run_bench(args.algo, args.task, args.ref_n_envs, args.steps, args.repeats, args.recipe,
                        backend="subprocess")
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    out = {"vector": vec, "subprocess": ref,
           "vecenv_ratio": vec["vecenv_steps_per_s"] / ref["vecenv_steps_per_s"],
           "learn_ratio": vec["learn_steps_per_s"] / ref["learn_steps_per_s"]}
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"training throughput, {vec['algo']} on {vec['task']}, action repeat {vec['action_repeat']} "
          f"(median of {vec['repeats']}, {vec['steps_per_repeat']} steps each), env steps/s:")
    print(f"  {'':22} {'vec env alone':>14} {'model.learn':>12} {'min/2M steps':>13}")
    for label, r in ((f"vector, {vec['n_envs']} drones", vec), (f"subprocess, {ref['n_envs']} envs", ref)):
        print(f"  {label:22} {r['vecenv_steps_per_s']:14.0f} {r['learn_steps_per_s']:12.0f} "
              f"{r['minutes_per_2M_steps']:13.1f}")
    print(f"  ratio vector / subprocess: vec env {out['vecenv_ratio']:.2f}x, learn {out['learn_ratio']:.2f}x")
    for label, r in (("vector", vec), ("subprocess", ref)):
        sp = r["learn_time_split"]
        print(f"  model.learn time, {label}: env {100 * sp['env']:.0f} %, policy (forward, buffer) "
              f"{100 * sp['policy']:.0f} %, update {100 * sp['update']:.0f} %")
    print(f"  (cpus {vec['cpus']}, load average {vec['load_average']:.2f})")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main(sys.argv[1:]))
