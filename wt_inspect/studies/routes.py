"""The route comparison of issue 14: every way tried to a full-mission policy, on one time axis.

The training runs live outside the repository (their checkpoints are hundreds of MB); this script
reads their ``evaluations.json`` (each a periodic evaluation on the full mission at 4 m/s,
deterministic policy), writes the extracted points to ``OUT/routes.json`` and draws ``OUT/routes.png``
(``--out`` default ``routes`` in the current directory). ``wt-inspect study routes RUNS_ROOT`` with
RUNS_ROOT holding the run directories named below; ``--from-json`` redraws the figure from an existing
``OUT/routes.json``; ``--add RUNS_ROOT LABEL...`` extracts only the named routes from RUNS_ROOT into
``OUT/routes.json`` (routes whose runs are on another machine keep their points) and redraws.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from agents.curves import plot_routes, route_points
from agents.seeds import TARGET
from wt_inspect_env.util.atomic_io import write_text_atomic

DEFAULT_OUT = Path("routes")
ROUTES = {
    "PPO from scratch, full task": ["ppo_scratch"],
    "behaviour cloning (VT-NMPC+ demos) + PPO": ["bc/seed_0", "bc_ppo"],
    "behaviour cloning at 25 Hz + DAgger": ["dagger"],
    "PPO curriculum: surface -> blade -> full -> fine centering": [
        "ppo_blade_to_full", "ppo_full_2", "ppo_centering", "ppo_centering2", "ppo_centering3"],
    "PPO on 128 drones: blade agent -> full with fine centering (ppo_full_vec128)": ["full128_from_blade/seed_0"],
    "PPO from scratch on 128 drones, 3 m pose limit (pilot)": ["pilotF_s0"],
}


def main(argv: list[str], prog: str = "wt-inspect study routes") -> int:
    """``wt-inspect study routes``: extract and draw the routes' evaluations (see the module); returns the exit code."""
    argv = list(argv)
    if argv and argv[0] in {"-h", "--help"}:
        print(f"usage: {prog} [--out DIR] (RUNS_ROOT | --from-json | --add RUNS_ROOT LABEL...)\n\n{__doc__}")
        return 0
    here = DEFAULT_OUT
    if "--out" in argv:
        i = argv.index("--out")
        if i + 1 >= len(argv):
            print(f"{prog}: error: --out needs a directory", file=sys.stderr)
            return 2
        here = Path(argv[i + 1])
        del argv[i:i + 2]
    if argv and argv[0] == "--from-json":
        routes = json.loads((here / "routes.json").read_text())["routes"]
    elif argv and argv[0] == "--add":
        root, labels = Path(argv[1]), argv[2:]
        unknown = [lab for lab in labels if lab not in ROUTES]
        if unknown:
            print(f"{prog}: error: unknown route {unknown[0]!r}; known: {', '.join(ROUTES)}", file=sys.stderr)
            return 2
        routes = json.loads((here / "routes.json").read_text())["routes"]
        routes.update({lab: route_points([root / d for d in ROUTES[lab]]) for lab in labels})
    else:
        root = Path(argv[0]) if argv else Path(".")
        routes = {label: route_points([root / d for d in dirs]) for label, dirs in ROUTES.items()}
    if not (argv and argv[0] == "--from-json"):
        write_text_atomic(here / "routes.json", json.dumps({"runs": ROUTES, "target": TARGET, "routes": routes},
                                                          indent=1) + "\n")
    print(plot_routes(routes, here / "routes.png", target=TARGET))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
