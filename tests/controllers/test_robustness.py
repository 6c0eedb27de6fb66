"""Robustness cases of issue 17: a NaN warm start falls back instead of raising, complex actions
are refused (single and vector env), wind speeds beyond the physical bound are refused."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import wt_inspect_env  # noqa: F401 - registers the environment ids
from controllers.rti import RTIOptions
from controllers.vtnmpc import VTNMPCPolicy
from wt_inspect.evaluation.scenarios import wind_spec
from wt_inspect_env.physics.wind import MAX_WIND_SPEED, make_wind
from wt_inspect_env.vector.env import WindTurbineInspectionVectorEnv

ENV = "WindTurbineInspection-Surface-v0"


@pytest.mark.parametrize("qp_solver", ["casadi", "hpipm"])
def test_nan_warm_start_falls_back_to_hover_then_recovers(qp_solver) -> None:
    env = gym.make(ENV)
    pol = VTNMPCPolicy(params=env.unwrapped.params, d_ref=env.unwrapped.config.standoff,
                       solver=RTIOptions(qp_solver=qp_solver))
    obs, _ = env.reset(seed=0)
    for _ in range(2):
        obs, *_ = env.step(pol.act(obs))
    pol.solver._w[:] = np.nan          # a corrupted plan (what a diverged iteration leaves)
    a = pol.act(obs)
    st = pol.last_stats
    assert st.fallback and st.fallback_source == "hover" and st.status == "NONFINITE_ITERATE"
    assert np.all(np.isfinite(a)) and np.allclose(a, env.unwrapped.scaling.hover_action())
    obs, *_ = env.step(a)
    pol.act(obs)                       # the plan was rebuilt from the measured state
    assert not pol.last_stats.fallback and np.all(np.isfinite(pol.solver.iterate))
    env.close()


@pytest.mark.parametrize("action", [np.array([0, 0, 0, 0.1 + 0.5j]), np.array([0, 0, 0, 0.1 + 0j]),
                                    [0.0, 0.0, 0.0, 1j], ["0", "0", "0", "0"], np.zeros(4, bool)])
def test_single_env_refuses_complex_and_text_actions(action) -> None:
    env = gym.make(ENV)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action must be a real numeric array"):
        env.step(action)
    env.step(np.zeros(4))   # still usable
    env.close()


def test_vector_env_refuses_complex_actions() -> None:
    venv = WindTurbineInspectionVectorEnv(num_envs=2, task="surface")
    venv.reset(seed=0)
    bad = np.zeros((2, 4), dtype=complex)
    bad[1, 3] = 0.1j
    with pytest.raises(ValueError, match="actions must be a real numeric array.*complex"):
        venv.step(bad)
    with pytest.raises(ValueError, match="actions must be a real numeric array"):
        venv.step(np.zeros((2, 4), dtype=complex))   # zero imaginary part: still complex
    venv.step(np.zeros((2, 4)))
    venv.close()


@pytest.mark.parametrize("spec", [{"type": "gust", "mean_speed": 1e9}, {"type": "gust", "mean_speed": 50.5},
                                  {"type": "dryden", "mean_speed": 60.0},
                                  {"type": "gust", "mean_speed": 4.0, "std": 80.0},
                                  {"type": "shear", "ref_speed": 51.0},
                                  {"type": "constant", "velocity": [40.0, 40.0, 0.0]}])
def test_wind_beyond_the_physical_bound_refused(spec) -> None:
    with pytest.raises(ValueError, match=f"at most {MAX_WIND_SPEED:g} m/s"):
        make_wind(spec)


def test_wind_at_the_bound_accepted_and_sweep_speeds_checked() -> None:
    assert make_wind({"type": "gust", "mean_speed": MAX_WIND_SPEED}) is not None
    with pytest.raises(ValueError, match="wind speed must be at most 50 m/s"):
        wind_spec(1e9)
    with pytest.raises(ValueError, match="wind speed must be a finite number, got '4'"):
        wind_spec("4")
