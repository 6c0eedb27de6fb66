"""The quadrotor's physics without PyBullet: parameters (:mod:`.quadrotor`), the CasADi model
(:mod:`.dynamics`), the PX4-like rate loop and mixer (:mod:`.rate_control`), wind fields
(:mod:`.wind`), the simulator options (:mod:`.sim_config`) and the compiled flight core
(:mod:`.flight_core`, ``flight_core.c``). Depends on :mod:`wt_inspect_env.util` and
:mod:`wt_inspect_env.native` only.
"""
