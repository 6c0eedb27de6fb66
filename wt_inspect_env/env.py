"""The Gymnasium environment: a PyBullet quadrotor inspecting a wind turbine under wind.

One :class:`WindTurbineInspectionEnv` is a world of one drone: an
:class:`~wt_inspect_env.world.world.InspectionWorld` with ``n = 1`` (its own PyBullet client, the turbine
and its inspection plan, the moving inspection reference, camera coverage and metrics) - the same
code the vector environment runs for N drones. To change the reward, the observation or the
termination, subclass :class:`~wt_inspect_env.task.hooks.TaskHooks` and pass ``hooks=`` (both
environments honour it).

Step: the normalised action (see :mod:`~wt_inspect_env.task.spaces`) becomes a ``[p, q, r, T]`` command
held for ``1 / ctrl_hz``; the inspection point advances (closed loop: it waits for a lagging
drone); at ``camera_hz`` the gimbal camera takes a frame and the newly seen blade triangles count.
At the end of phase 1 the reference holds, the rotor turns by ``rotor_turn_deg`` (the collision
mesh and the coverage geometry swap to the rotated turbine, triangle identities kept) and the
phase-2 path follows.

``terminated``: collision with the turbine or the ground, leaving the working volume, a
non-finite state or, with ``pose_error_limit``, straying too far from the stand-off pose (then
``info["termination"]`` says which). ``truncated``: the mission is complete
(``info["mission_complete"]``) or the time limit is reached. ``info["metrics"]`` holds the
:class:`~wt_inspect_env.task.metrics.InspectionMetrics` so far (as a dict).

``reset(seed=..., options={...})`` changes one episode: its wind, start (``start_offset``,
``start_noise``, ``start_progress``) and domain randomisation (:mod:`~wt_inspect_env.task.randomization`),
validated as the constructor's keywords (:meth:`EnvConfig.for_episode`); the next reset without
options is the constructor's configuration again. ``obs_mode`` ``rgb``/``depth``/``rgbd`` adds the
gimbal camera's images (:func:`~wt_inspect_env.scene.render.camera_images`) to the state Dict.
"""
from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from .scene.texture import SpanTexture
from .task.coverage import CoverageTracker
from .task.env_config import EnvConfig
from .task.hooks import TaskHooks
from .task.spaces import OBS_SHAPES, OPTIONAL_OBS_SHAPES
from .util.validation import check_actions, check_array
from .world.world import InspectionWorld, grow_to_start, start_state

__all__ = ["WindTurbineInspectionEnv", "observation_space", "grow_to_start", "start_state", "IMAGE_KEYS"]


def _box(shape: tuple[int, ...], lo: float = -np.inf, hi: float = np.inf) -> spaces.Box:
    return spaces.Box(low=lo, high=hi, shape=shape, dtype=np.float32)


def _display_available() -> bool:
    import os
    import sys
    return not sys.platform.startswith("linux") or bool(os.environ.get("DISPLAY"))


# Image entries each observation mode adds to the state Dict.
IMAGE_KEYS = {"state": (), "rgb": ("rgb",), "depth": ("depth",), "rgbd": ("rgb", "depth")}


def observation_space(obs_mode: str = "state", resolution: tuple[int, int] = (84, 84),
                      depth_far: float = 50.0, structure: bool = False) -> spaces.Dict:
    """The Dict observation space of one drone (see :mod:`~wt_inspect_env.task.spaces`); the image
    modes add ``rgb`` (uint8 (h, w, 3), the layout stable-baselines3's CNN policies expect) and/or
    ``depth`` (float32 (h, w, 1) [m]) to the state entries, which every policy still reads;
    ``structure`` adds the nearest structure point (``EnvConfig.structure_observation``)."""
    bounds = {"quaternion": (-1.0, 1.0), "normal": (-1.0, 1.0), "coverage": (0.0, 1.0),
              "progress": (0.0, 1.0)}
    entries = {k: _box(shape, *bounds.get(k, (-np.inf, np.inf))) for k, shape in OBS_SHAPES.items()}
    if structure:
        entries["structure"] = _box(OPTIONAL_OBS_SHAPES["structure"], -np.inf, np.inf)
    w, h = resolution
    if "rgb" in IMAGE_KEYS[obs_mode]:
        entries["rgb"] = spaces.Box(0, 255, shape=(h, w, 3), dtype=np.uint8)
    if "depth" in IMAGE_KEYS[obs_mode]:
        entries["depth"] = spaces.Box(0.0, float(depth_far), shape=(h, w, 1), dtype=np.float32)
    return spaces.Dict(entries)


class WindTurbineInspectionEnv(gym.Env):
    """Quadrotor wind-turbine inspection (see the module docstring and :class:`EnvConfig`).

    ``hooks``: a :class:`~wt_inspect_env.task.hooks.TaskHooks` (subclass) that gives the observation,
    reward and termination (default: the inspection task's).
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 100}

    def __init__(self, render_mode: str | None = None, hooks: TaskHooks | None = None, **options: Any) -> None:
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
        # The turbine's span markings where images are made; otherwise none (saves drawing them).
        images = cfg.obs_mode != "state" or render_mode is not None
        self.world = world = InspectionWorld(cfg, 1, hooks=hooks, texture=_span_texture if images else None)
        self.sim = world.sim
        self.mission = world.mission
        self.params = world.params
        self.scaling = world.scaling
        self.dt = world.dt
        self.camera = world.camera
        self.n_triangles = world.n_triangles
        self.time_limit = world.time_limit
        if render_mode == "human":
            self.sim.enable_gui()  # pragma: no cover - needs a display
        self.action_space = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self.observation_space = observation_space(cfg.obs_mode, cfg.camera_resolution, cfg.depth_far,
                                                   cfg.structure_observation)
        self.episode_config = cfg
        self._constructor_wind = world.winds[0]
        self._started = False
        self._seeded = False
        self._closed = False

    # ------------------------------------------------------------------ views of drone 0
    @property
    def hooks(self) -> TaskHooks:
        """The task's observation, reward and termination rules (shared with the world)."""
        return self.world.hooks

    @property
    def randomization(self):
        """This episode's domain-randomisation draw (None without randomisation)."""
        return self.world.randomization[0]

    @property
    def wind(self):
        """The wind field of the current episode."""
        return self.world.winds[0]

    @property
    def coverage(self) -> float:
        """Share of the mission's inspected triangles seen this episode."""
        return float(self.world.coverage[0])

    @property
    def coverage_counts(self) -> np.ndarray:
        """(M,) how often each inspected triangle was seen this episode."""
        return self.world.counts[0]

    @property
    def phase_index(self) -> int:
        """Index of the turbine geometry the drone flies in (0: phase 1; 1: the turned rotor)."""
        return int(self.world.phase_index[0])

    def metrics(self) -> dict[str, float]:
        """The :class:`~wt_inspect_env.task.metrics.InspectionMetrics` (as a dict) of the episode so far."""
        return self.world.metrics(0).to_dict()

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode; ``options`` (wind, start offset, ...) hold for this episode only."""
        # Options first, so bad ones are refused before anything changes; they hold for this
        # episode only (the next reset without them is the constructor's configuration again).
        w = self.world
        ep = self.config.for_episode(options)
        wind = w.episode_wind(0, ep.wind) if options and "wind" in options else self._constructor_wind
        self.episode_config = ep
        if seed is None and not self._seeded:
            seed = self.config.seed
        self._seeded = True
        super().reset(seed=seed)
        w.rngs[0] = self.np_random
        w.episode[0] = ep
        if w.winds[0] is not wind:
            w.set_wind(0, wind)
        w.reset([0])
        self._started = True
        return self._observation(np.zeros(1, dtype=bool)), self._info(None, None)

    def step(self, action):
        """Hold ``action`` for one control step; returns the Gymnasium step tuple."""
        if not self._started:
            raise RuntimeError("call reset() before step()")
        a = check_actions(action)    # shared with the vector env: the same input is refused alike
        r = self.world.step(a[None])
        info = self._info(r, int(r.code[0]))
        obs = self._observation(~r.finite, r.observations)
        return obs, float(r.reward[0]), bool(r.terminated[0]), bool(r.truncated[0]), info

    def render(self):
        """The camera and overview images (``render_mode="rgb_array"``; None otherwise)."""
        if self.render_mode != "rgb_array":
            return None
        from .scene.render import render_views
        return render_views(self)

    def close(self) -> None:
        """Close the world's simulator (idempotent)."""
        if not self._closed:
            self.world.close()
            self._closed = True
        super().close()

    # ------------------------------------------------------------------ internals
    def _observation(self, safe: np.ndarray, batch: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
        obs = self.world.observations(safe) if batch is None else batch
        out = {k: v[0] for k, v in obs.items()}
        if self.config.obs_mode != "state":
            out.update(self._camera_images())
        return out

    def _camera_images(self) -> dict[str, np.ndarray]:
        """The gimbal camera's images for the image observation modes (see :mod:`.render`)."""
        from .scene.render import camera_images
        cfg = self.config
        rgb, depth = camera_images(self.sim, self.camera, self.sim.state[0], cfg.camera_resolution,
                                   far=cfg.depth_far, rgb="rgb" in IMAGE_KEYS[cfg.obs_mode],
                                   depth="depth" in IMAGE_KEYS[cfg.obs_mode])
        out = {}
        if rgb is not None:
            out["rgb"] = rgb
        if depth is not None:
            out["depth"] = depth[:, :, None]
        return out

    def _info(self, r, code: int | None) -> dict[str, Any]:
        w = self.world
        s = w.reference.sample
        info = {
            "reward_terms": {} if r is None else {k: float(v[0]) for k, v in r.terms.items()},
            "metrics": w.metrics(0).to_dict(),
            "coverage": float(w.coverage[0]),
            "phase": int(s.phase[0]),
            "time": float(w.sim.time[0]),
            "waiting_for_phase_change": bool(s.waiting_for_phase_change[0]),
            "ideal_position": s.ideal_position[0].copy(),
            "wind": w.sim.last_wind[0].copy(),
            "stalls": int(w.reference.stalls[0]),
            "skipped_m": float(w.reference.skipped[0]),
            "approaching": bool(w.reference.approaching[0]),
        }
        rz = w.randomization[0]
        if rz is not None:
            info["randomization"] = rz.to_info()
        if r is not None:
            info["termination"] = w.hooks.termination_names[code]
            info["mission_complete"] = bool(r.complete[0])
        return info

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
        the env used there: the next phase's (turned rotor) from the start of a phase-change hold.
        Call after :meth:`reset` with the flight's seed (for randomised turbines); the env's own
        coverage is not touched, the frames go into a new tracker, which is returned.
        """
        w = self.world
        if not w.camera_every:
            raise ValueError("camera_hz is 0: this env takes no coverage frames to re-score")
        pos = check_array("position", position, (None, 3))
        quat = check_array("quaternion", quaternion, (len(pos), 4))
        ph, wait = np.asarray(phase), np.asarray(waiting)
        for name, arr in (("phase", ph), ("waiting", wait)):
            if arr.shape != (len(pos),):
                raise ValueError(f"{name} must have one entry per row ({len(pos)}), got shape {arr.shape}")
        geometry = ph.astype(np.int64) - 1 + wait.astype(bool)     # as step(): the turn starts with the hold
        geometry = np.minimum(geometry, len(self.mission.turbines) - 1)
        tracker = CoverageTracker(self.n_triangles, areas=self.mission.turbines[0].blade_areas[self.mission.inspected])
        rows = [k for k in [0] + list(range(w.camera_every, len(pos), w.camera_every))
                if np.isfinite(pos[k]).all() and np.isfinite(quat[k]).all()]
        if rows:
            origins, Rs = self.camera.poses(pos[rows], quat[rows])
            for tri in w.visible(geometry[rows], origins, Rs):
                tracker.update_indices(tri)
        return tracker


def _span_texture(mission) -> SpanTexture:
    return SpanTexture.for_meshes(mission.turbines[0].rotor_center, [t.mesh for t in mission.turbines])
