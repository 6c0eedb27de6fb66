"""The planner should choose between tours of equal cost the same way on every machine (known to fail).

At some rotor azimuths the tours either side of a blade or the tower are mirror images: equal in exact
arithmetic, so a plain ``argmin`` lets the last bits of a machine's floating point pick the mission
(the same turbine was flown from y = +8.5 m on one machine and y = -8.5 m on another). The test plays
another machine by putting relative noise of 1e-14 - the size of SIMD rounding differences - on every
distance the ordering computes, and asks for the same tour each time.
"""
from __future__ import annotations

import numpy as np
import pytest

import wt_inspect_env.planner.ordering as ordering
import wt_inspect_env.planner.plan as plan_module
from wt_inspect_env.task.env_config import EnvConfig
from wt_inspect_env.task.mission import build_mission


class _NoisyNumpy:
    """numpy whose ``linalg.norm`` carries last-bit noise (another machine's rounding)."""

    def __init__(self, seed: int) -> None:
        rng = np.random.default_rng(seed)

        class _Linalg:
            def __getattr__(self, name):
                return getattr(np.linalg, name)

            def norm(self, *args, **kwargs):
                r = np.linalg.norm(*args, **kwargs)
                return r * (1.0 + 1e-14 * rng.standard_normal(np.shape(r)))

        self.linalg = _Linalg()

    def __getattr__(self, name):
        return getattr(np, name)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="known: the planner's argmin lets floating point choose between mirror-image "
                   "tours; the tie-break that fixes it changes the plans several committed studies were made with, "
                   "so it lands with their regeneration (results/STALE.md, pose_sweep_paper_mpcs)")
def test_mirror_image_tours_are_chosen_the_same_way_under_last_bit_noise(monkeypatch):
    # the paper turbine at rotor azimuth 60 deg, the mission that flipped between machines
    cfg = EnvConfig(task="full", standoff=7.0, turbine={"rotor_azimuth_deg": 60.0, "facing_deg": 0.0})
    tours = set()
    for seed in range(8):
        noisy = _NoisyNumpy(seed)
        monkeypatch.setattr(ordering, "np", noisy)
        monkeypatch.setattr(plan_module, "np", noisy)
        plan = build_mission(cfg).plan
        tours.add(tuple((t.surface, t.phase, t.entry) for t in plan.tour))
    assert len(tours) == 1, tours
