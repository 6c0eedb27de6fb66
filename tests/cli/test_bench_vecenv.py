"""`wt-inspect bench vecenv`: its figures are computed from what it measures (not timed here)."""
from __future__ import annotations

import math

import pytest

from wt_inspect.commands import bench_vecenv


def test_memory_readings_cover_the_requested_steps_and_give_a_finite_slope():
    out = bench_vecenv.measure_memory("surface", 4, 4000, {}, samples=4)
    assert out["num_envs"] == 4 and out["steps"] == 4000
    assert len(out["rss_mb"]) == 5 and out["at_steps"] == [0, 1000, 2000, 3000, 4000]
    assert all(r > 0 for r in out["rss_mb"])
    assert math.isfinite(out["growth_mb_per_million_steps_second_half"])
    assert out["growth_mb_total"] == out["rss_mb"][-1] - out["rss_mb"][0]


@pytest.mark.slow
def test_cli_prints_every_n_the_single_env_row_and_the_memory_line(capsys):
    code = bench_vecenv.main(["--num-envs", "1,2", "--steps", "200", "--repeats", "1", "--task", "surface",
                              "--memory-steps", "400"])
    text = capsys.readouterr().out
    assert code == 0
    rows = [line.split()[0] for line in text.splitlines() if line.strip()[:2] in ("1*", "2 ")]
    assert rows == ["1*", "2"]
    assert "memory, N = 2, 400 aggregate steps" in text


def test_bad_memory_steps_is_one_line_naming_the_option(capsys):
    assert bench_vecenv.main(["--memory-steps", "-1"]) == 2
    err = capsys.readouterr().err
    assert "--memory-steps" in err and len(err.strip().splitlines()) == 1
