"""Policy classes: a generic real-time-iteration NMPC core, VT-NMPC and the NMPC / PAMPC baselines.

All policies share one interface: ``reset(seed=None)``, ``act(obs) -> action`` and
stable-baselines3's ``predict(obs, state=None, episode_start=None, deterministic=True)``.
"""
