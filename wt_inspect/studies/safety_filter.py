"""The safety filter against policies that fly at the structure (``results/safety_filter``).

Adversaries (:data:`ADVERSARIES`), each a policy on the env's action space: full acceleration at
the tower, at the nearest blade point, at the hub, at the ground; uniform random actions; and a
policy that holds a pose 1.5 m from the mesh, inside d_min. Each flies from seeded *recoverable*
starts - at rest, farther than d_min + :data:`START_MARGIN` from the turbine and above the ground
(at rest the braking distance is zero) - for :data:`SECONDS` simulated seconds in one of the
winds of :data:`WINDS` (none, the paper's gust at 4 and 7 m/s, Dryden turbulence at 5 and 10 m/s),
once unfiltered and once through :class:`controllers.safety_filter.SafetyFilter`. Per flight:
the least clearance to the collision mesh of the rotor position in force, the time below
d_min - 0.1 m, whether it collided, and the filter's counts. Resumable per chunk of starts::

    wt-inspect study safety-filter --starts 1000 --out results/safety_filter
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

#: simulated seconds of each adversarial flight
SECONDS = 6.0
#: a start is this much [m] farther than d_min from the turbine, at rest
START_MARGIN = 1.0
#: the winds the starts cycle through (env ``wind`` options)
WINDS: tuple[Mapping[str, Any] | str, ...] = (
    "none", {"type": "gust", "mean_speed": 4.0}, {"type": "gust", "mean_speed": 7.0},
    {"type": "dryden", "mean_speed": 5.0, "direction": [1.0, 0.4, 0.0]},
    {"type": "dryden", "mean_speed": 10.0, "direction": [-0.3, 1.0, 0.0]})
#: the filter's promise, with the margin the issue states: never below d_min - this [m]
TOLERANCE = 0.1
CHUNK = 50
FIELDS = ("start", "adversary", "wind", "filtered", "min_clearance_m", "steps_below", "collided", "termination",
          "interventions", "fallbacks", "passed", "filter_median_ms", "filter_p99_ms")


class Scene:
    """One environment of the study and its turbine geometry, built once and reused by every
    flight in it: the exact distance field of each rotor position's collision mesh (the clearance
    measured) and, on first use, its nearest-point structure (the adversaries' targets)."""

    def __init__(self, env: Any) -> None:
        from wt_inspect_env.planner.clearance import DistanceField
        self.env = env
        self.u = env.unwrapped
        self.fields = [DistanceField(t.mesh.triangles) for t in self.u.mission.turbines]
        self._near: dict[int, Any] = {}

    def nearest(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest point of the active rotor position's collision mesh and the outward direction."""
        from wt_inspect_env.planner.proximity import MeshProximity
        i = self.u.phase_index
        if i not in self._near:
            self._near[i] = MeshProximity(self.u.mission.turbines[i].mesh.triangles)
        c, _, n = self._near[i].closest(p[None])
        return c[0], n[0]


class FlyAt:
    """Accelerate at a target as hard as the airframe allows (a geometric attitude controller on
    the env's body-rate and thrust commands); ``target(obs, scene) -> (3,)``."""

    def __init__(self, scene: Scene, target: Callable[[Mapping[str, Any], Scene], np.ndarray], gain: float = 4.0,
                 damping: float = 1.0, a_max: float = 9.0) -> None:
        self.scene, self.u = scene, scene.u
        self.target, self.gain, self.damping, self.a_max = target, gain, damping, a_max

    def reset(self, seed: int | None = None) -> None:
        """Nothing to reset: the policy has no state."""
        pass

    def act(self, obs: Mapping[str, Any]) -> np.ndarray:
        """The normalised action that accelerates the drone at the target."""
        from wt_inspect_env.physics.dynamics import quat_to_rotmat_np
        u = self.u
        p, q = np.asarray(obs["position"], float), np.asarray(obs["quaternion"], float)
        R = quat_to_rotmat_np(q)
        v = R @ np.asarray(obs["velocity_body"], float)
        a = self.gain * (self.target(obs, self.scene) - p) - self.damping * v
        n = float(np.linalg.norm(a))
        if n > self.a_max:
            a *= self.a_max / n
        m, g = u.params.mass, 9.81
        f = m * (a + np.array([0.0, 0.0, g]))
        z_des = f / max(float(np.linalg.norm(f)), 1e-9)
        thrust = float(f @ R[:, 2])
        err = np.cross(R[:, 2], z_des)                # rotate body z onto z_des
        rates = 6.0 * (R.T @ err)
        lo, hi = u.scaling.lower, u.scaling.upper
        cmd = np.clip(np.array([rates[0], rates[1], 0.0, thrust]), lo, hi)
        return u.scaling.to_action(cmd).astype(np.float32)


class RandomActions:
    """Uniform random actions (seeded at reset)."""

    def __init__(self, scene: Scene) -> None:
        self.rng = np.random.default_rng(0)

    def reset(self, seed: int | None = None) -> None:
        """Reseed the random actions."""
        self.rng = np.random.default_rng(seed)

    def act(self, obs: Mapping[str, Any]) -> np.ndarray:
        """Uniformly random normalised actions."""
        return self.rng.uniform(-1.0, 1.0, 4).astype(np.float32)


def _tower(obs: Mapping[str, Any], scene: Scene) -> np.ndarray:
    spec = scene.u.mission.turbines[0].spec
    x, y = spec.position if spec is not None else (0.0, 0.0)
    return np.array([x, y, float(obs["position"][2])])


def _blade(obs: Mapping[str, Any], scene: Scene) -> np.ndarray:
    c, n = scene.nearest(np.asarray(obs["position"], float))
    return c - 2.0 * n                              # aim through the surface


def _hub(obs: Mapping[str, Any], scene: Scene) -> np.ndarray:
    return np.asarray(scene.u.mission.turbines[scene.u.phase_index].rotor_center, float)


def _ground(obs: Mapping[str, Any], scene: Scene) -> np.ndarray:
    p = np.asarray(obs["position"], float)
    return np.array([p[0], p[1], -10.0])


def _inside(obs: Mapping[str, Any], scene: Scene) -> np.ndarray:
    c, n = scene.nearest(np.asarray(obs["position"], float))
    return c + 1.5 * n                              # a pose 1.5 m off the surface: inside d_min


ADVERSARIES: dict[str, Callable[[Scene], Any]] = {
    "tower": lambda scene: FlyAt(scene, _tower),
    "blade": lambda scene: FlyAt(scene, _blade),
    "hub": lambda scene: FlyAt(scene, _hub),
    "ground": lambda scene: FlyAt(scene, _ground),
    "random": RandomActions,
    "hold-inside": lambda scene: FlyAt(scene, _inside, gain=1.5, damping=1.5, a_max=4.0),
}


def draw_start(scene: Scene, rng: np.random.Generator, low: bool = False) -> np.ndarray:
    """A start position at rest, at least d_min + START_MARGIN from the turbine (and above the
    ground by as much), at most 12 m from it, within the turbine's box grown by 12 m; ``low``:
    at most 15 m above the ground (for the ground adversary)."""
    field = scene.fields[0]
    lo, hi = scene.u.mission.turbines[0].mesh.bounds
    lo, hi = lo - 12.0, hi + 12.0
    need = float(scene.u.config.d_min) + START_MARGIN
    for _ in range(10_000):
        p = rng.uniform(lo, hi)
        if low:
            p[2] = rng.uniform(need, 15.0)
        if p[2] < need:
            continue
        d = float(field.distance(p[None], 12.0)[0])
        if need <= d < 12.0:
            return p
    raise RuntimeError("no recoverable start found")


def fly(scene: Scene, policy: Any, start: np.ndarray, seed: int, seconds: float = SECONDS,
        track: list | None = None) -> dict[str, Any]:
    """One adversarial flight from ``start`` (at rest): least clearance, steps below
    d_min - TOLERANCE, collision, and the filter's counts if ``policy`` is a SafetyFilter;
    ``track``: a list that gets (t, x, y, z, vx, vy, vz) of every step."""
    env, u, fields = scene.env, scene.u, scene.fields
    obs, info = env.reset(seed=seed)
    offset = (np.asarray(start, float) - np.asarray(obs["position"], float)).tolist()
    obs, info = env.reset(seed=seed, options={"start_offset": offset})
    policy.reset(seed=seed)
    d_min = float(u.config.d_min)
    least, below, term, steps = math.inf, 0, None, 0
    while True:
        obs, _, terminated, truncated, info = env.step(policy.act(obs))
        steps += 1
        if track is not None:
            track.append((float(info["time"]), *u.sim.state[0, 0:6]))
        x = u.sim.state[0, 0:3]
        d = float(min(fields[u.phase_index].distance(x[None], 20.0)[0], x[2]))
        least = min(least, d)
        below += d < d_min - TOLERANCE
        if terminated or truncated or info["time"] >= seconds - 1e-9:
            term = info["termination"] or ("time" if not terminated else "terminated")
            break
    out = {"min_clearance_m": round(least, 4), "steps_below": below, "collided": term == "collision",
           "termination": term}
    stats = getattr(policy, "stats", None)
    if stats is not None:
        s = stats.as_dict()
        out.update(interventions=s["filter_interventions"], fallbacks=s["filter_fallbacks"],
                   passed=int(round(s["filter_passed_fraction"] * s["filter_steps"])),
                   filter_median_ms=round(s["filter_median_ms"], 4), filter_p99_ms=round(s["filter_p99_ms"], 4))
    return out


def flight_setup(k: int) -> tuple[str, int]:
    """The adversary and the wind (index into :data:`WINDS`) of start ``k``."""
    names = list(ADVERSARIES)
    return names[k % len(names)], k % len(WINDS)


def planned_flights(argv: list[str]) -> list[dict[str, Any]]:
    """Every flight the command ``wt-inspect study safety-filter ARGV`` flies, in order (for the
    behaviour digests of :mod:`wt_inspect.behaviour`)."""
    args = build_parser().parse_args(argv)
    return [{"start": k, "filtered": f, "seed": args.seed} for k in range(args.starts) for f in (False, True)]


def _start(scene: Scene, k: int, seed: int) -> np.ndarray:
    """Start ``k``'s position (low for the ground adversary)."""
    return draw_start(scene, np.random.default_rng([seed, k]), low=flight_setup(k)[0] == "ground")


def _policy(scene: Scene, k: int, filtered: bool) -> Any:
    """Start ``k``'s adversary, through the safety filter if ``filtered``."""
    from controllers.safety_filter import SafetyFilter
    pol = ADVERSARIES[flight_setup(k)[0]](scene)
    return SafetyFilter(pol, scene.env) if filtered else pol


def trajectory(flight: Mapping[str, Any], seconds: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first ``seconds`` of one planned flight: time, position and world velocity. A flight's
    ``start_offset_m`` (optional) moves its start in x, y and z (the behaviour digests' noise twin)."""
    import gymnasium as gym

    import wt_inspect_env  # noqa: F401 - registers the env ids
    k = int(flight["start"])
    env = gym.make("WindTurbineInspection-v0", wind=WINDS[flight_setup(k)[1]], time_limit_s=SECONDS + 5.0)
    try:
        scene = Scene(env)
        track: list = []
        start = _start(scene, k, int(flight.get("seed", 0))) + float(flight.get("start_offset_m", 0.0))
        fly(scene, _policy(scene, k, bool(flight["filtered"])), start, seed=k, seconds=min(seconds, SECONDS),
            track=track)
    finally:
        env.close()
    a = np.asarray(track)
    return a[:, 0], a[:, 1:4], a[:, 4:7]


def read_chunk(path: Path) -> list[dict[str, Any]] | None:
    """The rows of a finished chunk file, or None when there is none. A chunk records the code
    that flew it (``{"code": ..., "rows": [...]}``, like the run files' metadata) so that
    ``wt-inspect reproduce`` discards the chunks of other code; an older bare list is read too."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    rows = doc.get("rows") if isinstance(doc, dict) else doc
    return rows if isinstance(rows, list) else None


def run(starts: int, out: Path, *, seed: int = 0, progress: bool = True) -> list[dict[str, Any]]:
    """Fly every adversary from ``starts`` starts, unfiltered and filtered (resumes from the
    chunk files in ``out/chunks``); returns every row."""
    import gymnasium as gym
    from tqdm import tqdm

    import wt_inspect_env  # noqa: F401 - registers the env ids
    from wt_inspect.evaluation.runner import code_fingerprint
    from wt_inspect_env.util.atomic_io import write_text_atomic
    code = code_fingerprint()
    chunks = out / "chunks"
    chunks.mkdir(parents=True, exist_ok=True)
    scenes: dict[int, Scene] = {}
    rows: list[dict[str, Any]] = []
    bar = tqdm(total=starts, desc="safety-filter starts", disable=not progress)
    try:
        for c0 in range(0, starts, CHUNK):
            path = chunks / f"starts_{c0:05d}.json"
            n = min(CHUNK, starts - c0)
            done = read_chunk(path)
            if done is not None:
                rows += done
                bar.update(n)
                continue
            got = []
            for k in range(c0, c0 + n):
                name, w = flight_setup(k)
                if w not in scenes:
                    scenes[w] = Scene(gym.make("WindTurbineInspection-v0", wind=WINDS[w],
                                               time_limit_s=SECONDS + 5.0))
                scene = scenes[w]
                start = _start(scene, k, seed)
                for filtered in (False, True):
                    got.append({"start": k, "adversary": name, "wind": json.dumps(WINDS[w]), "filtered": filtered,
                                **fly(scene, _policy(scene, k, filtered), start, seed=k)})
                bar.update(1)
            write_text_atomic(path, json.dumps({"code": code, "rows": got}) + "\n")
            rows += got
    finally:
        bar.close()
        for scene in scenes.values():
            scene.env.close()
    return rows


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per adversary and filtered/unfiltered: flights, collisions, flights and steps below
    d_min - TOLERANCE, the worst clearance; over all: the filter's time."""
    out: dict[str, Any] = {}
    for name in ADVERSARIES:
        for filtered in (False, True):
            sel = [r for r in rows if r["adversary"] == name and r["filtered"] == filtered]
            if not sel:
                continue
            out[f"{name}/{'filtered' if filtered else 'unfiltered'}"] = {
                "flights": len(sel), "collisions": sum(r["collided"] for r in sel),
                "flights_below": sum(r["steps_below"] > 0 for r in sel),
                "steps_below": sum(r["steps_below"] for r in sel),
                "worst_clearance_m": min(r["min_clearance_m"] for r in sel)}
    f = [r for r in rows if r["filtered"]]
    if f:
        out["filter_median_ms"] = float(np.median([r["filter_median_ms"] for r in f]))
        out["filter_p99_ms_median"] = float(np.median([r["filter_p99_ms"] for r in f]))
        out["fallbacks"] = float(sum(r["fallbacks"] for r in f))
    return out


def markdown(s: Mapping[str, Any], starts: int, command: str) -> str:
    """results.md of the study from its summary ``s`` (``starts`` seeded starts, the command)."""
    from wt_inspect.evaluation.report import hardware
    lines = ["# The safety filter against adversarial policies", "",
             f"`{command}`", "",
             f"{starts} seeded starts at rest, each at least d_min + {START_MARGIN:g} m from the turbine and the "
             f"ground; {SECONDS:g} s per flight; the winds cycle through none, the paper's gust at 4 and 7 m/s and "
             "Dryden turbulence at 5 and 10 m/s. Each start is flown by one adversary, unfiltered and filtered. "
             f"\"Below\" counts control steps closer than d_min - {TOLERANCE:g} m to the structure or the ground.", "",
             "| adversary | flights | collisions | flights below | steps below | worst clearance |",
             "|---|---:|---:|---:|---:|---:|"]
    for k, v in s.items():
        if isinstance(v, dict):
            lines.append(f"| {k} | {v['flights']} | {v['collisions']} | {v['flights_below']} | {v['steps_below']} | "
                         f"{v['worst_clearance_m']:.2f} m |")
    if "filter_median_ms" in s:
        lines += ["", f"Filter time per step: median {s['filter_median_ms']:.3f} ms (median over flights of each "
                      f"flight's median), p99 {s['filter_p99_ms_median']:.3f} ms (median of the flights' p99); "
                      f"QP fallbacks: {s['fallbacks']:.0f}.", ""]
    lines += [f"Machine: {hardware()}."]
    return "\n".join(lines) + "\n"


def build_parser(prog: str = "wt-inspect study safety-filter") -> argparse.ArgumentParser:
    """The argument parser of ``wt-inspect study safety-filter``."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--starts", type=int, default=1000, help="seeded recoverable starts (default 1000)")
    ap.add_argument("--out", default="results/safety_filter", help="output folder")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-progress", action="store_true")
    return ap


def main(argv: list[str], prog: str = "wt-inspect study safety-filter") -> int:
    """``wt-inspect study safety-filter``: run the study given by ``argv``; returns the exit code."""
    ap = build_parser(prog)
    args = ap.parse_args(argv)
    if args.starts < 1:
        ap.error(f"--starts must be >= 1, got {args.starts}")
    from wt_inspect_env.util.atomic_io import write_text_atomic
    out = Path(args.out)
    rows = run(args.starts, out, seed=args.seed, progress=not args.no_progress)
    s = summary(rows)
    with open(out / "flights.csv.tmp", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=FIELDS, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    (out / "flights.csv.tmp").replace(out / "flights.csv")
    write_text_atomic(out / "summary.json", json.dumps(s, indent=1) + "\n")
    command = f"wt-inspect study safety-filter --starts {args.starts} --out {args.out}"
    write_text_atomic(out / "results.md", markdown(s, args.starts, command))
    print(markdown(s, args.starts, command))
    return 0


if __name__ == "__main__":   # pragma: no cover
    sys.exit(main(sys.argv[1:]))
