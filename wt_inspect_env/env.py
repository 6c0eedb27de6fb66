"""The Gymnasium environment: a PyBullet quadrotor inspecting a wind turbine under wind.

One :class:`WindTurbineInspectionEnv` owns the physics (:class:`~wt_inspect_env.sim.QuadrotorSim`,
its own PyBullet client), the turbine and its inspection plan, the moving inspection reference, the
camera-coverage tracker and the metric accumulator. Small hooks (``_observation``, ``_reward``,
``_termination``) can be overridden, after gym-pybullet-drones, without touching the physics.

Step: the normalised action (see :mod:`~wt_inspect_env.spaces`) becomes a ``[p, q, r, T]`` command
held for ``1 / ctrl_hz``; the inspection point advances (closed loop: it waits for a lagging
drone); at ``camera_hz`` the gimbal camera takes a frame and the newly seen blade triangles count.
At the end of phase 1 the reference holds, the rotor turns by ``rotor_turn_deg`` (the collision
mesh and the coverage geometry swap to the rotated turbine, triangle identities kept) and the
phase-2 path follows.

``terminated``: collision with the turbine or the ground, leaving the working volume, a
non-finite state or, with ``pose_error_limit``, straying too far from the stand-off pose (then
``info["termination"]`` says which). ``truncated``: the mission is complete
(``info["mission_complete"]``) or the time limit is reached. ``info["metrics"]`` holds the
:class:`~wt_inspect_env.metrics.InspectionMetrics` so far (as a dict).

``reset(seed=..., options={...})`` changes one episode: its wind, start (``start_offset``,
``start_noise``, ``start_progress``) and domain randomisation (:mod:`~wt_inspect_env.randomization`),
validated as the constructor's keywords (:meth:`EnvConfig.for_episode`); the next reset without
options is the constructor's configuration again. ``obs_mode`` ``rgb``/``depth``/``rgbd`` adds the
gimbal camera's images (:func:`~wt_inspect_env.render.camera_images`) to the state Dict.
"""
from __future__ import annotations

import json
import math
from collections import deque
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from .camera import GimbalCamera
from .coverage import CoverageTracker, PyBulletOccluder, TriangleVisibility
from .dynamics import yaw_to_quat
from .env_config import EnvConfig
from .metrics import MetricAccumulator, MetricsConfig
from .mission import Mission, build_mission
from .randomization import RandomizationDraw, noisy_state
from .randomization import draw as draw_randomization
from .reference import InspectionReference, ReferenceConfig, ReferenceSample
from .sim import RAY_MASK_WITHOUT_DRONE, QuadrotorSim, SimConfig
from .spaces import OBS_SHAPES, ActionScaling
from .step_terms import observations, reward_terms
from .texture import SpanTexture
from .validation import check_actions, check_array
from .wind import WindField, make_wind


def _box(shape: tuple[int, ...], lo: float = -np.inf, hi: float = np.inf) -> spaces.Box:
    return spaces.Box(low=lo, high=hi, shape=shape, dtype=np.float32)


def _display_available() -> bool:
    import os
    import sys
    return not sys.platform.startswith("linux") or bool(os.environ.get("DISPLAY"))


# Image entries each observation mode adds to the state Dict.
IMAGE_KEYS = {"state": (), "rgb": ("rgb",), "depth": ("depth",), "rgbd": ("rgb", "depth")}


def observation_space(obs_mode: str = "state", resolution: tuple[int, int] = (84, 84),
                      depth_far: float = 50.0) -> spaces.Dict:
    """The Dict observation space of one drone (see :mod:`~wt_inspect_env.spaces`); the image
    modes add ``rgb`` (uint8 (h, w, 3), the layout stable-baselines3's CNN policies expect) and/or
    ``depth`` (float32 (h, w, 1) [m]) to the state entries, which every policy still reads."""
    bounds = {"quaternion": (-1.0, 1.0), "normal": (-1.0, 1.0), "coverage": (0.0, 1.0),
              "progress": (0.0, 1.0)}
    entries = {k: _box(shape, *bounds.get(k, (-np.inf, np.inf))) for k, shape in OBS_SHAPES.items()}
    w, h = resolution
    if "rgb" in IMAGE_KEYS[obs_mode]:
        entries["rgb"] = spaces.Box(0, 255, shape=(h, w, 3), dtype=np.uint8)
    if "depth" in IMAGE_KEYS[obs_mode]:
        entries["depth"] = spaces.Box(0.0, float(depth_far), shape=(h, w, 1), dtype=np.float32)
    return spaces.Dict(entries)


def grow_to_start(lo: np.ndarray, hi: np.ndarray, start: np.ndarray, margin: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The episode's working volume: the mission's box grown to hold the start position with
    ``margin`` round it, so that a start far off the path (``start_offset``) is not already a
    departure from the working volume (the mission's box is thin across the rotor plane)."""
    start = np.asarray(start, dtype=float)
    lo = np.minimum(lo, start - margin)
    return lo, np.maximum(hi, start + margin)


def start_state(ideal_position: np.ndarray, point: np.ndarray, start_offset: Any, start_noise: float,
                rng: np.random.Generator) -> np.ndarray:
    """The model state an episode starts from: the ideal stand-off pose plus the fixed
    ``start_offset`` plus ``N(0, start_noise)`` noise (drawn from ``rng`` only when positive, so
    the seeded stream is unchanged without it), at rest, level, facing the inspection point.
    One home for the single env and the vector env, which must start drone i identically."""
    start = ideal_position + np.asarray(start_offset, dtype=float)
    if start_noise > 0:
        start = start + rng.normal(0.0, start_noise, 3)
    a = point - start
    state = np.zeros(10)
    state[0:3] = start
    state[6:10] = yaw_to_quat(math.atan2(a[1], a[0]))
    return state


class WindTurbineInspectionEnv(gym.Env):
    """Quadrotor wind-turbine inspection (see the module docstring and :class:`EnvConfig`)."""

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 100}

    def __init__(self, render_mode: str | None = None, **options: Any) -> None:
        super().__init__()
        # Per instance: "human" only where a GUI can open (so headless checkers do not ask for it),
        # and render_fps = the control rate, since render() shows every control step - a video
        # recorder then plays 1 s of flight in 1 s.
        modes = ["rgb_array"] + (["human"] if _display_available() else [])
        if render_mode is not None and render_mode not in modes:
            raise ValueError(f"unknown render_mode {render_mode!r}; valid: {modes}"
                             + ("" if render_mode != "human" else " ('human' needs a display: DISPLAY is not set)"))
        self.render_mode = render_mode
        self.config = cfg = EnvConfig.from_kwargs(**options)
        self.metadata = {**type(self).metadata, "render_modes": modes, "render_fps": cfg.ctrl_hz}
        self.params = cfg.drone
        self.scaling = ActionScaling.from_params(self.params)
        self.dt = 1.0 / cfg.ctrl_hz
        self._camera_every = max(1, int(round(cfg.ctrl_hz / cfg.camera_hz)))

        self.mission: Mission = build_mission(cfg)
        self.wind = make_wind(cfg.wind)
        self.sim = QuadrotorSim(self.params, SimConfig(ctrl_hz=cfg.ctrl_hz, physics_hz=cfg.physics_hz,
                                                        integrator=cfg.integrator),
                                wind=self.wind, obstacles=self.mission.turbines[0].mesh,
                                obstacle_texture=self._texture(render_mode))
        if render_mode == "human":
            self.sim.enable_gui()  # pragma: no cover - needs a display
        self.camera = GimbalCamera(cfg.camera)
        occluder = (PyBulletOccluder(self.sim.client, collision_filter_mask=RAY_MASK_WITHOUT_DRONE)
                    if cfg.occlusion else None)
        t0 = self.mission.turbines[0]
        ins = self.mission.inspected
        self.visibility = TriangleVisibility(self.camera, t0.blade_vertices[ins], t0.blade_normals[ins], occluder)
        self.n_triangles = len(self.mission.inspected)
        self.coverage = self._coverage_tracker()
        self.metrics = MetricAccumulator(self.n_triangles, MetricsConfig(
            d_ref=cfg.standoff, safety_margin=cfg.safety_margin, pixel_ifov_rad=cfg.camera.ifov_rad))
        self.reference = InspectionReference(
            self.mission.points, self.mission.normals, self.mission.s, self.mission.phase,
            ReferenceConfig(speed=cfg.reference_speed, mode=cfg.reference_mode, standoff=cfg.standoff,
                            lag_threshold=cfg.reference_lag, stop_threshold=cfg.reference_stop))
        self.time_limit = cfg.time_limit_s or (1.5 * self.reference.nominal_duration + 30.0)
        lo, hi = self.mission.working_volume(cfg.working_margin)
        self._vol_base = (lo, hi)
        self._vol_lo, self._vol_hi = lo.copy(), hi.copy()

        self.action_space = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self.observation_space = observation_space(cfg.obs_mode, cfg.camera_resolution, cfg.depth_far)
        self._hover = self.scaling.hover_action()
        self.episode_config = cfg
        self._winds: dict[str, WindField] = {}     # per-episode wind fields by spec (_episode_wind)
        self.randomization: RandomizationDraw | None = None
        self._noise_rng: np.random.Generator | None = None
        self._commands: deque = deque()
        self._sample: ReferenceSample | None = None
        self._steps = 0
        self._phase_index = 0
        self._geometry_index = 0
        self._seeded = False
        self._closed = False

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        # Options first, so bad ones are refused before anything changes; they hold for this
        # episode only (the next reset without them is the constructor's configuration again).
        ep = self.config.for_episode(options)
        wind = self._episode_wind(ep.wind) if options and "wind" in options else self.wind
        self.episode_config = ep
        if seed is None and not self._seeded:
            seed = self.config.seed
        self._seeded = True
        super().reset(seed=seed)
        self.sim.wind = wind
        wind.reset(int(self.np_random.integers(2**63 - 1)))
        self._set_phase(0)
        frac = float(self.np_random.uniform(0.0, ep.start_progress)) if ep.start_progress > 0 else 0.0
        self._sample = self.reference.reset(frac)
        state = start_state(self._sample.ideal_position, self._sample.point, ep.start_offset,
                            ep.start_noise, self.np_random)
        # Drawn after the start (so without randomisation the seeded stream is today's).
        self.randomization = (None if ep.randomization is None
                              else draw_randomization(ep.randomization, self.params, self.np_random))
        r = self.randomization
        if r is not None:
            self.sim.set_plant(r.plant, r.thrust_scale)
            self._noise_rng = np.random.default_rng(r.noise_seed)
            self._commands = deque([self.scaling.to_command(self._hover)] * r.latency_steps)
        elif self.sim.plant is not self.params:
            self.sim.set_plant()
        self._vol_lo, self._vol_hi = grow_to_start(*self._vol_base, state[0:3], self.config.working_margin)
        self.sim.reset(state)
        self.coverage.reset()
        self.metrics.reset()
        self._steps = 0
        self._done_time: float | None = None
        self._last_new = 0
        self._frame()
        self.metrics.add(0.0, state[0:3], state[6:10], self._sample.point, self._sample.normal,
                         n_new=self._last_new, n_visible=self._last_visible)
        return self._observation(), self._info({})

    def step(self, action):
        if self._sample is None:
            raise RuntimeError("call reset() before step()")
        a = check_actions(action)    # shared with the vector env: the same input is refused alike
        command = self.scaling.to_command(a)
        if self.randomization is not None and self.randomization.latency_steps:
            self._commands.append(command)      # command latency: the one from latency_steps ago
            command = self._commands.popleft()
        self.sim.step(command)
        self._steps += 1
        state = self.sim.state
        finite = bool(np.isfinite(state).all())
        pos = state[0:3] if finite else np.zeros(3)
        self._sample = self.reference.step(self.dt, pos if finite else self._sample.ideal_position)
        if self._sample.hold_started:
            self._set_phase(self._phase_index + 1)
        new = 0
        self._last_visible = 0
        if finite and self._steps % self._camera_every == 0:
            new = self._frame()
        collision = self.sim.in_collision
        if finite:
            self.metrics.add(self.sim.time, pos, state[6:10], self._sample.point, self._sample.normal,
                             collision=collision, n_new=new, n_visible=self._last_visible,
                             inspecting=not self._sample.waiting_for_phase_change)
        termination = self._termination(state, finite, collision)
        reward, terms = self._reward(a, state, new, termination is not None)
        terminated = termination is not None
        if self._sample.done and self._done_time is None:
            self._done_time = self.sim.time
        complete = self._done_time is not None and self.sim.time >= self._done_time + self.config.end_hold_s - 1e-9
        truncated = not terminated and (complete or self.sim.time >= self.time_limit - 1e-9)
        info = self._info(terms)
        info["termination"] = termination
        info["mission_complete"] = complete
        obs = self._observation() if finite else self._observation(safe=True)
        return obs, float(reward), terminated, truncated, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        from .render import render_views
        return render_views(self)

    def close(self) -> None:
        if not self._closed:
            self.sim.close()
            self._closed = True
        super().close()

    # ------------------------------------------------------------------ hooks
    def _observation(self, safe: bool = False) -> dict[str, np.ndarray]:
        s = self._sample
        obs = observations(self.sim.state[None], self.sim.body_rates[None], s.point[None], s.normal[None],
                           s.velocity[None], np.array([self.coverage.coverage]), np.array([s.progress]),
                           safe=np.array([safe]))
        out = {k: v[0] for k, v in obs.items()}
        r = self.randomization
        if r is not None and r.has_noise and not safe:
            noisy_state(out, r, self._noise_rng)
        if self.config.obs_mode != "state":
            out.update(self._camera_images())
        return out

    def _camera_images(self) -> dict[str, np.ndarray]:
        """The gimbal camera's images for the image observation modes (see :mod:`.render`)."""
        from .render import camera_images
        cfg = self.config
        rgb, depth = camera_images(self.sim, self.camera, self.sim.state, cfg.camera_resolution,
                                   far=cfg.depth_far, rgb="rgb" in IMAGE_KEYS[cfg.obs_mode],
                                   depth="depth" in IMAGE_KEYS[cfg.obs_mode])
        out = {}
        if rgb is not None:
            out["rgb"] = rgb
        if depth is not None:
            out["depth"] = depth[:, :, None]
        return out

    def _reward(self, action: np.ndarray, state: np.ndarray, n_new: int, crashed: bool
                ) -> tuple[float, dict[str, float]]:
        reward, terms = reward_terms(self.config.reward, self.dt, self.n_triangles, action[None], self._hover,
                                     state[None], self._sample.ideal_position[None], self._sample.point[None],
                                     np.array([n_new]), np.array([crashed]))
        return float(reward[0]), {k: float(v[0]) for k, v in terms.items()}

    def _termination(self, state: np.ndarray, finite: bool, collision: bool) -> str | None:
        if not finite:
            return "non_finite_state"
        if collision:
            return "collision"
        p = state[0:3]
        if np.any(p < self._vol_lo) or np.any(p > self._vol_hi):
            return "left_working_volume"
        limit = self.config.pose_error_limit
        s = self._sample
        if (limit is not None and not s.waiting_for_phase_change
                and float(np.linalg.norm(p - s.ideal_position)) > limit):
            return "lost_pose"
        return None

    def _info(self, terms: dict[str, float]) -> dict[str, Any]:
        s = self._sample
        return {
            "reward_terms": terms,
            "metrics": self.metrics.result().to_dict(),
            "coverage": self.coverage.coverage,
            "phase": s.phase,
            "time": self.sim.time,
            "waiting_for_phase_change": s.waiting_for_phase_change,
            "ideal_position": s.ideal_position.copy(),
            "wind": self.sim.wind_velocity.copy(),
            **({} if self.randomization is None else {"randomization": self.randomization.to_info()}),
        }

    # ------------------------------------------------------------------ internals
    def _episode_wind(self, spec: Any) -> WindField:
        """The wind field of a ``reset(options={"wind": spec})``: built once per distinct spec (a
        Dryden field's shaping filters take far longer to build than a reset) and reseeded at every
        reset, so reusing it changes nothing; a few specs are kept."""
        try:
            key = json.dumps(spec, sort_keys=True)
        except (TypeError, ValueError):     # a callable or WindField: used as given
            return make_wind(spec)
        field = self._winds.pop(key, None) or make_wind(spec)
        self._winds[key] = field            # most recently used last
        while len(self._winds) > 8:
            self._winds.pop(next(iter(self._winds)))
        return field

    def _texture(self, render_mode: str | None) -> SpanTexture | None:
        """The turbine's span markings, where images are made (image observations, rgb_array or
        human rendering); otherwise none, which saves building the drawn chunks."""
        if self.config.obs_mode == "state" and render_mode is None:
            return None
        return SpanTexture.for_meshes(self.mission.turbines[0].rotor_center, [t.mesh for t in self.mission.turbines])

    def _set_phase(self, index: int) -> None:
        """Use turbine geometry of phase ``index`` for collisions and coverage (rotor turned)."""
        index = min(index, len(self.mission.turbines) - 1)
        if index == self._phase_index and self._steps > 0:
            return
        turb = self.mission.turbines[index]
        if index != self._geometry_index:
            self.sim.set_obstacles(turb.mesh)
            self.visibility.set_mesh(turb.blade_vertices[self.mission.inspected],
                                     turb.blade_normals[self.mission.inspected])
            self._geometry_index = index
        self._phase_index = index

    def _coverage_tracker(self) -> CoverageTracker:
        """An empty tracker of the mission's inspected triangles (their areas for area coverage)."""
        return CoverageTracker(self.n_triangles, areas=self.mission.turbines[0].blade_areas[self.mission.inspected])

    def replay_coverage(self, position: np.ndarray, quaternion: np.ndarray, phase: np.ndarray,
                        waiting: np.ndarray) -> CoverageTracker:
        """Coverage of a recorded flight under *this* env's camera and coverage rule, without flying.

        Why: the camera and the coverage rule do not act on the flight (no controller or reward
        term the flight depends on reads them), so a study of lens or rule changes can re-score
        the frames of one flight instead of flying it again. The arrays are one row per control
        step from the reset on (row 0 = the reset state, row k = after step k; as the evaluation
        harness records them with ``record_every=1``): positions ``(K, 3)``, quaternions
        ``(K, 4)``, the reference's phase label (1, 2) and whether it was waiting for the phase
        change (``info["phase"]``, ``info["waiting_for_phase_change"]``). Frames are taken where
        :meth:`step` takes them (row 0 and every ``ctrl_hz / camera_hz``-th row), with the geometry
        the env used there: the next phase's (turned rotor) from the start of a phase-change hold. Call after
        :meth:`reset` with the flight's seed (for randomised turbines); the env's own coverage is
        not touched, the frames go into a new tracker, which is returned.
        """
        pos = check_array("position", position, (None, 3))
        quat = check_array("quaternion", quaternion, (len(pos), 4))
        ph, wait = np.asarray(phase), np.asarray(waiting)
        for name, arr in (("phase", ph), ("waiting", wait)):
            if arr.shape != (len(pos),):
                raise ValueError(f"{name} must have one entry per row ({len(pos)}), got shape {arr.shape}")
        geometry = ph.astype(np.int64) - 1 + wait.astype(bool)     # as step(): the turn starts with the hold
        tracker = self._coverage_tracker()
        rows = [0] + list(range(self._camera_every, len(pos), self._camera_every))
        try:
            for k in rows:
                if not (np.isfinite(pos[k]).all() and np.isfinite(quat[k]).all()):
                    continue
                self._set_phase(int(geometry[k]))
                origin, R = self.camera.pose(pos[k], quat[k])
                tracker.update_indices(self.visibility.visible_indices(origin, R))
        finally:
            self._set_phase(0)
        return tracker

    def _frame(self) -> int:
        """Take one camera frame; returns how many triangles were seen for the first time."""
        state = self.sim.state
        origin, R = self.camera.pose(state[0:3], state[6:10])
        idx = self.visibility.visible_indices(origin, R)
        self._last_visible = len(idx)
        new = self.coverage.update_indices(idx)
        self._last_new = new
        return new
