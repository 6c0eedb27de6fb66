"""The world's compiled per-step arithmetic (``world_core.c`` and its ctypes driver).

Below the physics and the task on purpose: the wind's gusts, the batched simulator's body frames,
the reference, the metrics, the coverage and the default task's terms all call into this one
library, so it may depend on nothing but :mod:`wt_inspect_env.util`.
"""
