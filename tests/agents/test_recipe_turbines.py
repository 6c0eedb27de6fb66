"""A recipe's ``turbines`` entry: validated when the recipe is read, kept as plain JSON data."""
from __future__ import annotations

import pytest

from agents.recipe import Recipe


def test_a_recipe_keeps_its_turbines_entry_through_json():
    t = {"n_turbines": 4, "redraw_every": 2, "distribution": {"kinds": {"generated": 1.0}, "tower_height": [90, 100]}}
    rec = Recipe.from_dict({"turbines": t})
    assert rec.turbines == t and Recipe.from_dict(rec.to_dict()).turbines == t
    assert Recipe().turbines is None and "turbines" not in Recipe().to_dict()   # older recipes' dicts unchanged


@pytest.mark.parametrize("turbines, match", [
    ({"n_turbines": 0}, r"turbines.n_turbines must be a positive integer, got 0"),
    ({"redraw_every": 2}, r"turbines.n_turbines is required"),
    ({"n_turbines": 2, "distribution": {"kinds": {"nrel-15mw": 1}}}, r"unknown turbine kind or preset 'nrel-15mw'"),
    ({"n_turbines": 2, "every": 3}, r"turbines"),
    ([2], r"turbines must be a dict"),
])
def test_bad_recipe_turbines_are_one_line_errors(turbines, match):
    with pytest.raises(ValueError, match=match) as exc:
        Recipe.from_dict({"turbines": turbines})
    assert "\n" not in str(exc.value)


def test_recipe_turbines_exclude_a_fixed_turbine():
    with pytest.raises(ValueError, match="recipe turbines .* exclude"):
        Recipe.from_dict({"turbines": {"n_turbines": 1}, "env": {"turbine": {"preset": "nrel-5mw"}}})
