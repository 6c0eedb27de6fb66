"""The task's hooks: what a drone observes, what it earns and when its episode ends.

One :class:`TaskHooks` serves every environment: the single
:class:`~wt_inspect_env.env.WindTurbineInspectionEnv` (a world of one drone) and the native vector
environment (a world of N) both call the same three methods on the same
:class:`~wt_inspect_env.world.world.InspectionWorld`, with arrays over its drones. Subclass it to change the
reward, the observation or the termination, and pass an instance as ``hooks=`` to either
environment (or to ``gym.make`` / ``gym.make_vec``); both then train and evaluate on the changed task,
so the single and the vector backends cannot drift apart.

A termination is an integer code per drone into :attr:`TaskHooks.termination_names` (0 = the
episode goes on); a subclass that adds a reason appends its name (see :meth:`code_for`).
"""
from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from .step_terms import clearance_reward, observations, reward_terms, termination_codes, too_close


class WorldView(Protocol):
    """What the hooks read of the world they are called with (the
    :class:`~wt_inspect_env.world.world.InspectionWorld` is the one that calls them). Named structurally so
    that the world, which holds and calls the hooks, is not imported back by them."""

    config: Any
    sim: Any
    reference: Any
    dt: float
    n_triangles: int
    hover_action: np.ndarray
    volume_lo: np.ndarray
    volume_hi: np.ndarray

    @property
    def coverage(self) -> np.ndarray:
        """(N,) share of the mission's inspected triangles each drone has seen this episode."""

    def structure(self) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) vectors to the nearest structure point and (N,) distances (inf: non-finite state)."""

TERMINATIONS = (None, "non_finite_state", "collision", "left_working_volume", "lost_pose")


class TaskHooks:
    """The default inspection task (the reward of :class:`~wt_inspect_env.task.env_config.RewardConfig`).

    Every method receives the world and returns one row per drone; the arrays the world passes in
    are for all its drones.
    """

    def __init__(self) -> None:
        self.termination_names: list[str | None] = list(TERMINATIONS)

    def code_for(self, name: str) -> int:
        """The code of termination ``name``, added to :attr:`termination_names` on first use."""
        if name not in self.termination_names:
            self.termination_names.append(name)
        return self.termination_names.index(name)

    def observations(self, world: WorldView, safe: np.ndarray) -> dict[str, np.ndarray]:
        """The Dict observation of every drone, ``(N, k)`` float32 entries (see :mod:`.spaces`);
        rows flagged in ``safe`` (non-finite states) must still lie inside the observation space."""
        s = world.reference.sample
        return observations(world.sim.state, world.sim.body_rates, s.point, s.normal, s.velocity,
                            world.coverage, s.progress, safe=safe)

    def rewards(self, world: WorldView, actions: np.ndarray, n_new: np.ndarray,
                terminated: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Reward per drone and its named terms (``info["reward_terms"]``) for the normalised
        ``actions`` (N, 4), the triangles each drone saw for the first time and who terminated
        (with a ``reward.clearance`` weight, the term ``clearance`` too)."""
        s = world.reference.sample
        w = world.config.reward
        reward, terms = reward_terms(w, world.dt, world.n_triangles, actions, world.hover_action,
                                     world.sim.state, s.ideal_position, s.point, n_new, terminated)
        if w.clearance > 0.0:
            terms["clearance"] = clearance_reward(w, world.dt, world.config.d_min, world.structure()[1])
            reward = reward + terms["clearance"]
        return reward, terms

    def terminations(self, world: WorldView, state: np.ndarray, finite: np.ndarray,
                     collision: np.ndarray) -> np.ndarray:
        """Termination code per drone (0: goes on): a non-finite state, a collision, leaving the
        working volume or, with ``pose_error_limit``, straying from the stand-off pose (not while
        the reference waits for the rotor turn), or, with ``clearance_limit``, coming closer than
        that to the structure (``"too_close"``)."""
        s = world.reference.sample
        code = termination_codes(state, collision, world.volume_lo, world.volume_hi, s.ideal_position,
                                 s.waiting_for_phase_change, world.config.pose_error_limit)
        limit = world.config.clearance_limit
        if limit is not None:
            code[too_close(code, world.structure()[1], limit)] = self.code_for("too_close")
        return code
