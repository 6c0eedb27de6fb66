import numpy as np
import pytest

from wt_inspect_env.physics.quadrotor import GRAVITY, get_preset
from wt_inspect_env.task.spaces import ActionScaling


def test_action_round_trip_and_bounds():
    s = ActionScaling.from_params(get_preset("matrice100"))
    m = s.mass
    np.testing.assert_allclose(s.to_command([-1, -1, -1, -1]), [-np.deg2rad(100)] * 3 + [0.3 * m * GRAVITY])
    np.testing.assert_allclose(s.to_command([1, 1, 1, 1]), [np.deg2rad(100)] * 3 + [2 * m * GRAVITY])
    hover = s.hover_action()
    np.testing.assert_allclose(s.to_command(hover), [0, 0, 0, m * GRAVITY], rtol=1e-6)
    rng = np.random.default_rng(1)
    for _ in range(10):
        a = rng.uniform(-1, 1, 4)
        np.testing.assert_allclose(s.to_action(s.to_command(a)), a, atol=1e-6)


@pytest.mark.parametrize("bad", [[0, 0, 0], [np.nan, 0, 0, 0], [0, 0, 0, 1.5]])
def test_bad_actions_raise(bad):
    s = ActionScaling(mass=1.0)
    with pytest.raises(ValueError, match="action"):
        s.to_command(bad)
