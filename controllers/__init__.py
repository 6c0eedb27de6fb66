"""Policy classes: a generic real-time-iteration NMPC core, VT-NMPC and the NMPC / PAMPC baselines.

* :mod:`controllers.rti` - the RTI solver for least-squares OCPs (and the IPOPT reference);
* :mod:`controllers.rti_policy` - :class:`~controllers.rti_policy.RTIPolicy`, the one policy base:
  an MPC is its OCP, weights (:class:`~controllers.rti_policy.LSQWeights`) and parameters;
* :mod:`controllers.vtnmpc`, :mod:`controllers.nmpc`, :mod:`controllers.pampc` (with the
  baselines' shared tracking pieces in :mod:`controllers.tracking`);
* :mod:`controllers.registration` - the names the evaluation harness finds them by (entry points).

All policies share the interface of :class:`wt_inspect_env.policy.Policy`: ``reset(seed=None)``,
``act(obs) -> action`` and stable-baselines3's ``predict(obs, state=None, episode_start=None,
deterministic=True)``.
"""
