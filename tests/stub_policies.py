"""Stand-in policies for the harness and registry tests: the policy interface (``reset``/``act``),
nothing else. Imported by name (``pythonpath = ["tests"]``)."""
from __future__ import annotations


class Hover:
    """Holds the hover command: zero body rates and hover thrust (in still air it keeps every
    rotor at m g / 4)."""

    def __init__(self, env) -> None:
        self.action = env.scaling.hover_action()

    def reset(self, seed=None) -> None:
        pass

    def act(self, obs):
        return self.action


class Climb(Hover):
    """Zero body rates and 20 % more than hover thrust: a straight vertical climb."""

    def __init__(self, env) -> None:
        s = env.scaling
        self.action = s.to_action([0.0, 0.0, 0.0, 1.2 * s.hover_thrust])
