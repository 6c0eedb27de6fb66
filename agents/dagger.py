"""DAgger (Ross et al. 2011): behaviour cloning, then rounds of flying the learner and labelling
what it visits with the expert.

Why: a clone of VT-NMPC+ fits the demonstrations closely and still leaves them within seconds -
its small errors take it to states the expert never visited, where nothing taught it what to do.
DAgger asks the expert there. Each round flies the current policy (with probability ``beta`` a
decision window is flown by the expert instead, ``beta`` decaying per round), records the
learner's features at every decision with the expert's action for that state, adds them to
everything gathered so far and refits the policy on the aggregate (each mini-batch half
demonstrations, half learner-visited states by default: the visited states are few beside the
demonstrations but they are the ones that matter).

The expert flies in *shadow* (:class:`ShadowExpert`): it is run on every control step's
observation, so its warm start and disturbance observer advance at their own 100 Hz rate, but its
command is applied only when the mixture picks it; it is told the command that was applied
(``note_applied_action`` of the MPC base, :class:`controllers.rti_policy.RTIPolicy`), so its
observer keeps estimating the unmodelled acceleration and not the learner's deviation from its
plan. The learner decides every ``action_repeat`` control steps; its label is the expert's action
at the decision step, inverted to the agent's residual-hover action at that attitude (the same
inverse as behaviour cloning uses).

Outputs in ``--out`` (a run directory like a training run's): ``model.*`` (the last round's
policy, saved like a trained model: ``--controllers ppo:OUT/model.zip`` flies it, ``wt-inspect
train --algo ppo --resume OUT/model.zip`` fine-tunes it), ``best_model.*``, ``rounds/round_<k>/model.*``,
``evaluations.json`` (round 0 is behaviour cloning alone; one entry per round on the recipe's
evaluation mission, so the seeds report and the learning-curve figure read it), ``episodes.csv``
(the rollouts), ``dagger_data.npz`` (the aggregated learner-visited features and labels),
``dagger_state.json`` (the last finished round: a rerun with the same arguments resumes after it),
``summary.json``, ``learning_curve.png``.

The ``imitation`` library's DAgger is not used for the reason given in :mod:`agents.imitation`.
"""
from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import sys
import time
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from wt_inspect_env.policy import ENTRY_POINT_GROUP, PolicyEntry, check_observation
from wt_inspect_env.util.atomic_io import atomic_path, write_text_atomic
from wt_inspect_env.util.validation import check_positive, check_unknown_options, json_object_option

from .imitation import (
    actor_parameters,
    check_dataset_matches,
    dataset_arrays,
    invert_action,
    label_weights,
    load_demonstrations,
    new_clone_model,
    normalize_features,
    policy_mean_action,
)

STATE_FORMAT = 1


def _pos_int(name: str, v: Any) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
        raise ValueError(f"dagger {name} must be a positive integer, got {v!r}")
    return int(v)


@dataclass(frozen=True)
class DAggerConfig:
    """DAgger settings (``--dagger-options`` JSON; unknown keys are an error).

    rounds: DAgger rounds after the initial behaviour cloning. episodes_per_round: rollouts per
    round, each on the recipe's training env (its variants drawn by their weights). beta0,
    beta_decay: the expert's share of the decision windows in round k is ``beta0 * beta_decay**(k-1)``.
    bc_epochs: passes over the demonstrations for the initial clone. refit_steps: gradient steps per
    round on the aggregate (continuing from the current policy), mini-batches of ``batch_size``
    with ``dagger_share`` of each from the learner-visited states. expert: a registered controller
    name, with its optional argument if it has one (``vtnmpc-plus:backoff=0.5``, see
    :func:`expert_factory`). seed: rollouts, mixture draws, network initialisation and batch order.
    """

    rounds: int = 8
    episodes_per_round: int = 4
    beta0: float = 0.5
    beta_decay: float = 0.5
    bc_epochs: int = 10
    refit_steps: int = 300
    batch_size: int = 4096
    learning_rate: float = 3e-3
    refit_learning_rate: float = 1e-3
    dagger_share: float = 0.5
    expert: str = "vtnmpc-plus"
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("rounds", "episodes_per_round", "bc_epochs", "refit_steps", "batch_size"):
            _pos_int(name, getattr(self, name))
        for name in ("beta0", "beta_decay", "dagger_share"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= float(v) <= 1.0:
                raise ValueError(f"dagger {name} must be a number in [0, 1], got {v!r}")
        check_positive("dagger learning_rate", self.learning_rate)
        check_positive("dagger refit_learning_rate", self.refit_learning_rate)
        if not isinstance(self.expert, str) or not self.expert or self.expert.startswith(":"):
            raise ValueError(f"dagger expert must be a registered controller name (NAME or NAME:ARGUMENT), "
                             f"got {self.expert!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ValueError(f"dagger seed must be a non-negative integer, got {self.seed!r}")

    @classmethod
    def from_mapping(cls, data: Any, **defaults: Any) -> "DAggerConfig":
        """The config from its JSON object over ``defaults`` (unknown keys are an error)."""
        if not isinstance(data, Mapping):
            raise ValueError(f"dagger options must be a JSON object, got {data!r}")
        check_unknown_options("dagger", data.keys(), [f.name for f in dataclasses.fields(cls)])
        return cls(**{**defaults, **dict(data)})

    def beta(self, round_: int) -> float:
        """The expert's share of decision windows in round ``round_`` (1-based)."""
        return float(self.beta0) * float(self.beta_decay) ** (round_ - 1)

    def to_dict(self) -> dict[str, Any]:
        """The config as plain JSON-able data (for the run's summary)."""
        return dataclasses.asdict(self)


def expert_factory(name: str) -> Callable[[Any], Any]:
    """The factory ``env -> policy`` of a registered controller, read from the entry points as the
    evaluation harness reads them (``agents`` may not import the harness or ``controllers``):
    ``NAME`` or, for an entry with an optional argument, ``NAME:ARGUMENT`` (e.g. a tightened
    expert, ``vtnmpc-plus:backoff=0.5``), the argument checked here."""
    found = {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}
    key, sep, arg = str(name).partition(":")
    if key not in found:
        raise ValueError(f"dagger expert {name!r} is not a registered controller; valid: {', '.join(sorted(found))}")
    entry = found[key].load()
    if not isinstance(entry, PolicyEntry) or entry.takes_argument:
        raise ValueError(f"dagger expert {name!r} must be a controller that needs no argument (not a model file)")
    if not sep:
        return entry.factory
    if not entry.optional_argument:
        raise ValueError(f"dagger expert {name!r}: {key!r} takes no argument")
    if entry.check is not None:
        entry.check(arg)
    return entry.with_argument(arg)


class ShadowExpert:
    """An expert policy run beside the learner (see the module docstring): :meth:`label` on every
    control step's observation, :meth:`applied` with the action the env was then given. An expert
    without ``note_applied_action`` is taken to keep no state that assumes its own command was
    applied (a stateless feedback law); the MPCs on :class:`controllers.rti_policy.RTIPolicy` have it."""

    def __init__(self, policy: Any) -> None:
        self.policy = policy
        self._note = getattr(policy, "note_applied_action", None)

    def reset(self, seed: int | None = None) -> None:
        """Reset the expert for a new episode."""
        self.policy.reset(seed)

    def label(self, obs: Mapping[str, Any]) -> np.ndarray:
        """The expert's normalised env action for ``obs`` (it advances the expert by one step)."""
        return np.asarray(self.policy.act(obs))

    def applied(self, action: np.ndarray) -> None:
        """The action actually executed after the last :meth:`label` (a stateless expert ignores it)."""
        if self._note is not None:
            self._note(action)


def rollout(student, expert: ShadowExpert, env, *, seed: int, beta: float, rng: np.random.Generator,
            spec, max_steps: int | None = None) -> dict[str, Any]:
    """One episode of the beta-mixture of ``student`` (an :class:`~agents.policy.SB3Policy`) and
    ``expert`` on the raw ``env``; returns the learner's raw features and the expert's agent-action
    labels at every decision step, the env steps, the return and the final metrics."""
    scaling = env.unwrapped.scaling
    obs, info = env.reset(seed=seed)
    student.reset(seed)
    expert.reset(seed)
    feats, labels, by_expert = [], [], []
    k, total, steps = spec.action_repeat, 0.0, 0
    held, use_expert = None, False
    while True:
        o = check_observation(obs)
        a_exp = expert.label(obs)                       # every control step: observer, warm start
        student.encoder.update(o)
        if steps % k == 0:
            x = student.encoder.features()
            u_exp = invert_action(spec, scaling, a_exp[None, :], o["quaternion"][None, :])[0]
            feats.append(np.array(x, dtype=np.float32))
            labels.append(u_exp.astype(np.float32))
            use_expert = bool(rng.random() < beta)
            by_expert.append(use_expert)
            if use_expert:
                held = u_exp
            else:
                u, _ = student.model.predict(student.normalize(x), deterministic=True)
                held = np.asarray(u, dtype=np.float64).reshape(4)
            student.encoder.note_action(held)
        action = a_exp if use_expert else student.decoder(held, o["quaternion"])
        expert.applied(action)
        obs, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        steps += 1
        if terminated or truncated or (max_steps is not None and steps >= max_steps):
            break
    m = info["metrics"]
    return {"features": np.asarray(feats, np.float32), "labels": np.asarray(labels, np.float32),
            "expert_share": float(np.mean(by_expert)) if by_expert else 0.0, "steps": steps,
            "return": total, "time_s": float(info.get("time", steps * env.unwrapped.dt)),
            "termination": info.get("termination") or ("complete" if info.get("mission_complete") else "time"),
            "metrics": {k_: float(m[k_]) for k_ in ("coverage", "safety_sm", "centering_cm", "rms_distance_error_m")}}


def _fit(policy, Xd: np.ndarray, Yd: np.ndarray, Xa: np.ndarray | None, Ya: np.ndarray | None, w, *,
         steps: int, batch_size: int, lr: float, share: float, rng: np.random.Generator) -> float:
    """``steps`` Adam steps of the variance-weighted MSE on mini-batches drawn from the
    demonstrations (``Xd``, ``Yd``) and the aggregated learner-visited states (``Xa``, ``Ya``,
    ``share`` of each batch); cosine learning-rate decay. Returns the mean loss of the last tenth."""
    import torch
    opt = torch.optim.Adam(actor_parameters(policy), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    n_a = 0 if Xa is None or len(Xa) == 0 else int(round(share * batch_size))
    n_d = batch_size - n_a
    losses = []
    for _ in range(steps):
        xs, ys = [], []
        if n_d:
            i = rng.integers(0, len(Xd), n_d)
            xs.append(Xd[i])
            ys.append(Yd[i])
        if n_a:
            j = rng.integers(0, len(Xa), n_a)
            xs.append(Xa[j])
            ys.append(Ya[j])
        xb, yb = torch.as_tensor(np.concatenate(xs)), torch.as_tensor(np.concatenate(ys))
        loss = torch.mean(w * (policy_mean_action(policy, xb) - yb) ** 2)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        losses.append(loss.item())
    return float(np.mean(losses[-max(1, steps // 10):]))


def _append_rows(path: Path, rows: list[dict[str, Any]]) -> None:
    if not rows:
        return
    new = not path.exists()
    with open(path, "a", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        if new:
            w.writeheader()
        w.writerows(rows)


def _save_npz(path: Path, **arrays: np.ndarray) -> None:
    with atomic_path(path, suffix=".npz") as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)


def dagger(dataset_path: str | Path, out: str | Path, *, recipe, task: str = "full",
           config: DAggerConfig | None = None, progress: bool = True, max_minutes: float | None = None,
           figure_format: str = "png") -> dict[str, Any]:
    """Behaviour cloning of the dataset, then ``config.rounds`` DAgger rounds (module docstring);
    resumes after the last finished round of an earlier call with the same ``out``. ``max_minutes``:
    once this much wall time has passed in this call no round and no rollout after a round's first
    starts (the round in progress is refitted and evaluated on what it has, so the overrun is one
    rollout, one refit and one evaluation). Returns the summary (also ``out/summary.json``)."""
    import torch
    from tqdm import tqdm

    from .policy import algo_class, env_interface, load_sidecar, save_agent, sidecar_paths
    from .safe_load import load_sb3_model, load_vecnormalize
    from .training import (
        EVAL_SEED_BASE,
        _policy_from_model,
        evaluate_on_envs,
        make_raw_env,
    )

    cfg = config if config is not None else DAggerConfig()
    if recipe.algo != "ppo":
        raise ValueError(f"dagger trains a PPO policy; recipe algo is {recipe.algo!r}")
    if recipe.spec.action.mode != "rates":
        raise ValueError(f"dagger needs agent action mode 'rates', got {recipe.spec.action.mode!r}")
    if max_minutes is not None and not (isinstance(max_minutes, (int, float)) and max_minutes > 0):
        raise ValueError(f"max_minutes must be positive, got {max_minutes!r}")
    factory = expert_factory(cfg.expert)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {str(out)!r} exists and is not a directory")
    state_path = out / "dagger_state.json"
    state = json.loads(state_path.read_text()) if state_path.is_file() else None
    if state is not None:
        same = {k: v for k, v in state["config"].items() if k != "rounds"} == \
            {k: v for k, v in cfg.to_dict().items() if k != "rounds"}
        if not same or state["recipe"] != recipe.to_dict() or state["dataset"] != str(dataset_path):
            raise ValueError(f"--out {str(out)!r} holds a DAgger run with other settings (dagger_state.json); "
                             "use another --out or the same arguments (only rounds may grow)")
    dataset, meta = load_demonstrations(dataset_path)
    eval_envs = [make_raw_env(task, options) for options in recipe.eval_options_list()]
    eval_env = eval_envs[0]
    t_start = time.perf_counter()
    wall_before = float(state["wall_time_s"]) if state else 0.0
    deadline = None if max_minutes is None else 60.0 * max_minutes
    envs: dict[int, Any] = {}
    try:
        for env in eval_envs:
            check_dataset_matches(meta, env)
        spec = recipe.spec
        u = eval_env.unwrapped
        out.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out / "recipe.json", json.dumps(recipe.to_dict(), indent=1))
        demo_cache = out / "demo_features.npz"
        t0 = time.perf_counter()
        if demo_cache.is_file():
            with np.load(demo_cache) as z:
                X, Y = z["X"], z["Y"]
        else:
            X, Y = dataset_arrays(dataset, spec, u.scaling, standoff=u.config.standoff, dt=u.dt)
            _save_npz(demo_cache, X=X, Y=Y)
        prep_s = time.perf_counter() - t0
        model, vecnorm, venv = new_clone_model(recipe, task, X, cfg.seed)
        cls = algo_class("ppo")
        Xd = normalize_features(vecnorm, X)
        w = label_weights(Y)
        evaluations: list[dict[str, Any]] = json.loads((out / "evaluations.json").read_text()) \
            if state and (out / "evaluations.json").is_file() else []
        done = int(state["round"]) if state else -1
        env_steps = int(state["env_steps"]) if state else 0
        Xa = Ya = None
        if state:
            ckpt = out / "rounds" / f"round_{done}" / "model.zip"
            model = load_sb3_model(cls, ckpt, load_sidecar(ckpt), env=vecnorm, device="cpu")
            vecnorm = load_vecnormalize(sidecar_paths(ckpt)[2], venv)
            if (out / "dagger_data.npz").is_file():
                with np.load(out / "dagger_data.npz") as z:
                    Xa, Ya = z["X"], z["Y"]

        def wall() -> float:
            return wall_before + time.perf_counter() - t_start

        def save(path: Path, round_: int, entry: Mapping[str, Any] | None) -> Path:
            extra = {"training": {"algo": "ppo", "task": task, "env_steps": env_steps, "wall_time_s": round(wall(), 1),
                                  "method": "dagger", "dagger_round": round_, "dataset": str(dataset_path),
                                  "seed": cfg.seed, "dagger": cfg.to_dict()},
                     "recipe": recipe.to_dict()}
            if entry is not None:
                extra["evaluation"] = entry
            return save_agent(model, path, algo="ppo", spec=spec, vecnormalize=vecnorm,
                              interface=env_interface(eval_env), extra=extra)

        def evaluate(round_: int, beta: float, extra: Mapping[str, Any]) -> dict[str, Any]:
            t = time.perf_counter()
            seeds = [EVAL_SEED_BASE + i for i in range(recipe.eval_episodes)]
            result = evaluate_on_envs(lambda env: _policy_from_model(model, spec, vecnorm, env), eval_envs, seeds)
            entry = {"round": round_, "beta": beta, "env_steps": env_steps, "wall_time_s": round(wall(), 2),
                     "eval_time_s": round(time.perf_counter() - t, 2), **dict(extra), **result}
            evaluations.append(entry)
            write_text_atomic(out / "evaluations.json", json.dumps(evaluations, indent=1))
            mm = result["mean"]
            ep0 = result["episodes"][0]
            print(f"[dagger] round {round_} beta={beta:.3f} env_steps={env_steps} wall={wall():.0f}s "
                  f"coverage={mm['coverage']:.3f} SM={mm['safety_sm']:.3f} CM={mm['centering_cm']:.3f} "
                  f"flight={mm['flight_time_s']:.1f}s ({ep0['termination'] or 'complete'}) "
                  f"score={result['score']:.3f}",
                  file=sys.stderr, flush=True)
            return entry

        def finish_round(round_: int, entry: Mapping[str, Any]) -> None:
            save(out / "rounds" / f"round_{round_}" / "model", round_, entry)
            if Xa is not None:
                _save_npz(out / "dagger_data.npz", X=Xa, Y=Ya)
            best = max(evaluations, key=lambda e: e["score"])
            if best is entry:
                save(out / "best_model", round_, entry)
            save(out / "model", round_, entry)
            write_text_atomic(state_path, json.dumps({"format": STATE_FORMAT, "round": round_, "env_steps": env_steps,
                                                      "wall_time_s": round(wall(), 1), "config": cfg.to_dict(),
                                                      "recipe": recipe.to_dict(), "dataset": str(dataset_path)},
                                                     indent=1))

        bar = tqdm(total=cfg.rounds + 1, initial=done + 1, desc="dagger", unit="round", disable=not progress,
                   file=sys.stderr)
        stopped = False
        if done < 0:                                    # round 0: behaviour cloning of the demonstrations
            torch.manual_seed(cfg.seed)
            rng = np.random.default_rng([cfg.seed, 0])
            steps = max(1, cfg.bc_epochs * math.ceil(len(Xd) / cfg.batch_size))
            t1 = time.perf_counter()
            loss = _fit(model.policy, Xd, Y, None, None, w, steps=steps, batch_size=cfg.batch_size,
                        lr=cfg.learning_rate, share=0.0, rng=rng)
            entry = evaluate(0, 1.0, {"fit_loss": loss, "fit_s": round(time.perf_counter() - t1, 1),
                                      "feature_prep_s": round(prep_s, 1), "samples_dagger": 0})
            done = 0
            finish_round(0, entry)
            bar.update(1)
        variants = recipe.env_variants or [{}]
        weights = np.asarray(recipe.env_variant_weights or [1.0] * len(variants), float)
        for r in range(done + 1, cfg.rounds + 1):
            if deadline is not None and time.perf_counter() - t_start >= deadline:
                stopped = True
                break
            rng = np.random.default_rng([cfg.seed, r])
            beta = cfg.beta(r)
            student = _policy_from_model(model, spec, vecnorm, eval_env)
            rows, new_x, new_y = [], [], []
            for e in range(cfg.episodes_per_round):
                if e and deadline is not None and time.perf_counter() - t_start >= deadline:
                    stopped = True       # past the wall budget: refit and evaluate on what this round has
                    break
                v = int(rng.choice(len(variants), p=weights / weights.sum()))
                if v not in envs:
                    env = make_raw_env(task, {**dict(recipe.env), **dict(variants[v])})
                    check_dataset_matches(meta, env)
                    envs[v] = (env, ShadowExpert(factory(env.unwrapped)))
                env, expert = envs[v]
                seed = int(cfg.seed * 100_000 + r * 1000 + e)
                ro = rollout(student, expert, env, seed=seed, beta=beta, rng=rng, spec=spec)
                env_steps += ro["steps"]
                new_x.append(ro["features"])
                new_y.append(ro["labels"])
                rows.append({"env_steps": env_steps, "wall_time_s": round(wall(), 2), "return": ro["return"],
                             "time_s": ro["time_s"], **ro["metrics"], "termination": ro["termination"],
                             "variant": v, "round": r, "beta": beta, "expert_share": round(ro["expert_share"], 3)})
            _append_rows(out / "episodes.csv", rows)
            Xn_new = normalize_features(vecnorm, np.concatenate(new_x))
            Y_new = np.concatenate(new_y)
            Xa = Xn_new if Xa is None else np.concatenate([Xa, Xn_new])
            Ya = Y_new if Ya is None else np.concatenate([Ya, Y_new])
            t1 = time.perf_counter()
            loss = _fit(model.policy, Xd, Y, Xa, Ya, w, steps=cfg.refit_steps, batch_size=cfg.batch_size,
                        lr=cfg.refit_learning_rate, share=cfg.dagger_share, rng=rng)
            entry = evaluate(r, beta, {"fit_loss": loss, "fit_s": round(time.perf_counter() - t1, 1),
                                       "samples_dagger": int(len(Xa)),
                                       "rollout_flight_s": [round(x["time_s"], 2) for x in rows],
                                       "rollout_termination": [x["termination"] for x in rows]})
            done = r
            finish_round(r, entry)
            bar.update(1)
            if stopped:
                break
        bar.close()
        venv.close()
    finally:
        for env in eval_envs:
            env.close()
        for env, _ in envs.values():
            env.close()
    best = max(evaluations, key=lambda e: e["score"])
    summary = {"algo": "dagger", "task": task, "env_steps": env_steps, "wall_time_s": round(wall(), 1),
               "rounds_done": done, "stopped_by_wall_clock": stopped, "dataset": str(dataset_path),
               "samples_demonstrations": int(len(Xd)), "samples_dagger": 0 if Xa is None else int(len(Xa)),
               "config": cfg.to_dict(), "final_model": str(sidecar_paths(out / "model")[0]),
               "final_evaluation": {"mean": evaluations[-1]["mean"], "score": evaluations[-1]["score"]},
               "best_evaluation": {"round": best["round"], "mean": best["mean"], "score": best["score"]},
               "per_round": [{"round": e["round"], "beta": e["beta"], "env_steps": e["env_steps"],
                              "wall_time_s": e["wall_time_s"], "samples_dagger": e.get("samples_dagger"),
                              **{k: e["mean"][k] for k in ("coverage", "safety_sm", "centering_cm", "flight_time_s",
                                                           "collisions")},
                              "termination": e["episodes"][0]["termination"]} for e in evaluations],
               "machine": {"cpus": os.cpu_count(), "torch_threads": recipe.torch_threads}}
    from .curves import write_run_summary
    write_run_summary(out, summary, figure_format)
    return summary


def cli(args, prog: str) -> int:
    """``wt-inspect train --algo dagger --dataset DIR [--dagger-options JSON] [--recipe R] ...``."""
    from .recipe import load_recipe
    if args.dataset is None:
        print(f"{prog}: error: --algo dagger needs --dataset (a folder written by wt-inspect demos)", file=sys.stderr)
        return 2
    for flag, given in (("--seeds", args.seeds), ("--resume", args.resume), ("--timesteps", args.timesteps)):
        if given is not None:
            print(f"{prog}: error: {flag} is not supported with --algo dagger (a rerun with the same --out resumes "
                  "after its last round; the budget is --dagger-options rounds and --max-minutes)", file=sys.stderr)
            return 2
    try:
        cfg = DAggerConfig.from_mapping(json_object_option("--dagger-options", args.dagger_options), seed=args.seed)
        rec = load_recipe(args.recipe or str(Path(__file__).parent / "recipes" / "dagger_full.json"))
        summary = dagger(args.dataset, args.out, recipe=rec, task=args.task or "full", config=cfg,
                         progress=not args.no_progress, max_minutes=args.max_minutes,
                         figure_format=args.figure_format)
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    for row in summary["per_round"]:
        print(f"round {row['round']} (beta {row['beta']:.3f}): coverage {row['coverage']:.3f}, "
              f"SM {row['safety_sm']:.3f}, "
              f"CM {row['centering_cm']:.3f}, flight {row['flight_time_s']:.1f} s ({row['termination'] or 'complete'})")
    print(json.dumps({"model": summary["final_model"], "summary": str(args.out) + "/summary.json"}))
    return 0
