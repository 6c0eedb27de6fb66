"""Camera observations (obs_mode rgb / depth / rgbd) and the turbine's span texture."""
from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import wt_inspect_env  # noqa: F401 - registers the ids
from wt_inspect_env.scene.texture import SpanTexture, vertex_normals

SURFACE = "WindTurbineInspection-Surface-v0"


@pytest.mark.parametrize("mode", [pytest.param("rgb", marks=pytest.mark.slow),
                                  pytest.param("depth", marks=pytest.mark.slow), "rgbd"])
def test_check_env_passes_on_the_image_modes_headless(mode, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    env = gym.make(SURFACE, obs_mode=mode, camera_resolution=(32, 24))
    check_env(env.unwrapped)
    env.close()


@pytest.fixture(scope="module")
def rgbd_env():
    env = gym.make(SURFACE, obs_mode="rgbd", camera_resolution=(64, 48), wind="none").unwrapped
    yield env
    env.close()


def test_image_entries_follow_gymnasium_and_leave_the_state_entries_unchanged(rgbd_env):
    env = rgbd_env
    space = env.observation_space
    assert space["rgb"].shape == (48, 64, 3) and space["rgb"].dtype == np.uint8
    assert space["depth"].shape == (48, 64, 1) and space["depth"].dtype == np.float32
    assert space["depth"].high.max() == env.config.depth_far
    state_env = gym.make(SURFACE, wind="none").unwrapped
    try:
        assert set(space.spaces) == set(state_env.observation_space.spaces) | {"rgb", "depth"}
        hover = env.scaling.hover_action()
        for e in (env, state_env):
            e.reset(seed=0)
        for _ in range(15):
            o, *_ = env.step(hover)
            s, *_ = state_env.step(hover)
            assert space.contains(o)
            for k in s:
                np.testing.assert_array_equal(o[k], s[k])
    finally:
        state_env.close()


def test_depth_at_the_image_centre_is_the_standoff(rgbd_env):
    """At the start the camera looks along the surface normal from d_ref = 7 m (minus the 0.1 m
    the lens sits ahead of the centre of mass): the centre pixel's depth is that distance."""
    env = rgbd_env
    obs, _ = env.reset(seed=0)
    d = obs["depth"][:, :, 0]
    h, w = d.shape
    assert d[h // 2, w // 2] == pytest.approx(env.config.standoff - 0.1, abs=0.3)
    assert d.max() == pytest.approx(env.config.depth_far, rel=1e-3)   # sky: nothing hit, saturated
    assert (d > 0).all()


def test_images_carry_the_span_markings(rgbd_env):
    """The bands along the span make the image depend on where along the blade the camera is:
    1.5 m higher (a band and a half) the same surface at the same distance looks different,
    though the depth image (a flat face) is the same."""
    env = rgbd_env
    a, _ = env.reset(seed=0)
    b, _ = env.reset(seed=0, options={"start_offset": [0.0, 0.0, 1.5]})
    blade = (a["depth"][:, :, 0] < 10.0) & (b["depth"][:, :, 0] < 10.0)
    assert blade.mean() > 0.15
    assert np.median(a["depth"][blade]) == pytest.approx(np.median(b["depth"][blade]), abs=0.01)
    colours = np.unique(a["rgb"][blade], axis=0)
    assert len(colours) >= 3
    diff = np.abs(a["rgb"].astype(int) - b["rgb"].astype(int)).sum(axis=2)
    assert (diff[blade] > 60).mean() > 0.3


def test_frustum_culling_draws_the_same_image_as_the_whole_turbine():
    """Only the drawn chunks in the camera's frustum are handed to the renderer; the image must be
    exactly the one of the whole turbine (culling is conservative), along a flight past the blade
    and across the rotor turn of the full mission."""
    import pybullet as p

    from wt_inspect_env.scene.render import _render, camera_images, metric_depth

    env = gym.make("WindTurbineInspection-v0", obs_mode="rgbd", camera_resolution=(40, 30), wind="none",
                   start_offset=(0.0, 0.0, 0.0)).unwrapped
    try:
        env.reset(seed=0)
        hover = env.scaling.hover_action()
        a = hover.copy()
        a[2] = 0.4                                    # yaw round: the view sweeps over the turbine
        checked = 0
        for k in range(60):
            env.step(a if k % 2 else hover)
            if k % 6:
                continue
            rgb, depth = camera_images(env.sim, env.camera, env.sim.state[0], (40, 30), env.config.depth_far)
            shown = env.sim._chunks[env.sim.geometry[0]]["shown"]
            assert 0 < shown.sum() < len(shown)
            env.sim.show_obstacle_chunks(True)
            origin, R = env.camera.pose(env.sim.state[0, 0:3], env.sim.state[0, 6:10])
            rgba, buf = _render(env.sim.client, origin, origin + R[:, 2], -R[:, 1], env.camera.config.fov_deg[1],
                                env.config.depth_far, 40, 30, flags=p.ER_NO_SEGMENTATION_MASK)
            np.testing.assert_array_equal(rgb, rgba[:, :, :3])
            np.testing.assert_array_equal(depth, metric_depth(buf, env.config.depth_far))
            checked += 1
        assert checked == 10
        # the phase-2 (turned) turbine is drawn, the parked phase-1 one is not
        env.world.set_phase(0, 1)
        assert env.sim._chunks[1]["shown"].all() and not env.sim._chunks[0]["shown"].any()
        assert env.sim.obstacle_chunks is not None
    finally:
        env.close()


def test_state_mode_builds_no_drawn_chunks():
    env = gym.make(SURFACE).unwrapped
    try:
        assert env.sim.obstacle_texture is None and env.sim.obstacle_chunks is None
    finally:
        env.close()


def test_span_texture_bands_follow_the_distance_from_the_rotor_centre():
    tex = SpanTexture(center=(0.0, 0.0, 100.0), radius=12.0, band_m=1.0, major_every=5)
    img = tex.image()
    assert img.dtype == np.uint8 and img.shape[2] == 3 and img.shape[1] == tex.n_bands * (img.shape[1] // tex.n_bands)
    v = np.array([[0.0, 0.0, 100.0], [0.0, 0.0, 106.0], [0.0, 6.0, 100.0], [0.0, 0.0, 88.0]])
    uv = tex.uvs(v)
    assert uv[0, 0] == 0.0 and uv[1, 0] == uv[2, 0] == pytest.approx(0.5) and uv[3, 0] == 1.0
    px = img.shape[1] // tex.n_bands
    bands = img[0, ::px]
    assert all((bands[k] != bands[k + 1]).any() for k in range(len(bands) - 1))   # neighbours differ
    assert (bands[::5] == bands[0]).all()                                      # the major lines
    with pytest.raises(ValueError, match="texture radius must be positive"):
        SpanTexture(center=(0, 0, 0), radius=0.0)
    n = vertex_normals(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), np.array([[0, 1, 2]]))
    np.testing.assert_allclose(n, [[0, 0, 1]] * 3)


@pytest.mark.parametrize("kw, match", [
    (dict(obs_mode="thermal"), "unknown obs_mode 'thermal'"),
    (dict(obs_mode="rgb", camera_resolution=(84,)), "camera_resolution must be"),
    (dict(obs_mode="rgb", camera_resolution=(0, 84)), "camera_resolution must be"),
    (dict(obs_mode="rgb", camera_resolution=(84.0, 84)), "camera_resolution must be"),
    (dict(obs_mode="depth", depth_far=0.05), "depth_far must exceed"),
])
def test_bad_camera_options_are_one_line_errors_naming_the_field(kw, match):
    with pytest.raises(ValueError, match=match) as e:
        gym.make(SURFACE, **kw)
    assert "\n" not in str(e.value)


def test_vector_env_refuses_image_modes_in_one_line():
    with pytest.raises(ValueError, match="obs_mode is not supported by the vector env") as e:
        gym.make_vec(SURFACE, num_envs=2, vectorization_mode="vector_entry_point", obs_mode="rgb")
    assert "\n" not in str(e.value)


@pytest.mark.slow
def test_bench_env_measures_the_image_modes(capsys):
    from wt_inspect.commands.bench_env import main

    assert main(["--task", "surface", "--steps", "30", "--repeats", "1", "--obs-mode", "rgbd",
                 "--camera-resolution", "32x24", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["obs_mode"] == "rgbd" and out["camera_resolution"] == [32, 24]
    assert out["steps_per_s"] > 0 and 0 < out["ratio_to_raw_pybullet"] < 1
    assert main(["--obs-mode", "rgb", "--camera-resolution", "84"]) == 2
    assert "--camera-resolution" in capsys.readouterr().err
