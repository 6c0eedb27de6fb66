"""One policy base for every MPC on the RTI core: a controller is its OCP, weights and parameters.

:class:`RTIPolicy` owns everything that is the same for the VT-NMPC, the NMPC and the PAMPC - and
for the next MPC: building the solver (real-time iteration or IPOPT), reset, weights switched
without recompiling, the horizontal-normal fallback (:class:`~wt_inspect_env.task.geometry.HorizontalNormal`),
keyword overrides of the configuration, the quaternion sign alignment, the warm-start shift for the
control period, the preparation/feedback schedule and the statistics. A subclass provides only

* ``config_class`` - an :class:`MPCConfig` subclass (its extra fields, its weight class and sets);
* :meth:`RTIPolicy.build_ocp` - the least-squares OCP (residuals, dynamics, bounds);
* :meth:`RTIPolicy.parameters` - the OCP's online parameters for an observation;
* optionally :meth:`RTIPolicy.model_state` (an augmented state, e.g. the baselines' clock) and
  :meth:`RTIPolicy.on_measurement` (estimators fed by each measured state, e.g. VT-NMPC's
  disturbance observer).

The package's modules: :mod:`.weights` (weights and their scaling), :mod:`.config` (the shared
configuration and the OCP built from it), :mod:`.clearance` (the clearance constraint) and
:mod:`.policy` (the base class, its preparation/feedback schedule).
"""
from __future__ import annotations

from .clearance import N_CLEARANCE_PARAMS, SLACK_UPPER, clearance_ocp
from .config import (
                     BACKENDS,
                     MPCConfig,
                     check_positive_int,
                     config_ocp,
                     default_solver,
                     resolve_config,
                     warm_start_shifts,
)
from .policy import RTIPolicy
from .weights import REFERENCE_D_REF, REFERENCE_DRONE, WEIGHT_UNITS, LSQWeights, ResidualScales, weight_tuple

__all__ = ["BACKENDS", "N_CLEARANCE_PARAMS", "REFERENCE_DRONE", "REFERENCE_D_REF", "SLACK_UPPER", "WEIGHT_UNITS",
           "LSQWeights", "MPCConfig", "RTIPolicy", "ResidualScales", "check_positive_int", "clearance_ocp",
           "config_ocp", "default_solver", "resolve_config", "warm_start_shifts", "weight_tuple"]
