"""Named turbines for ``TurbineSpec(preset=...)`` / ``turbine={"preset": "nrel-5mw"}``.

``nrel-5mw``: the NREL offshore 5-MW baseline wind turbine, from J. Jonkman, S. Butterfield,
W. Musial and G. Scott, *Definition of a 5-MW Reference Wind Turbine for Offshore System
Development*, NREL/TP-500-38060, National Renewable Energy Laboratory, February 2009:

* Table 1-1 (gross properties): 3 blades, rotor diameter 126 m, hub diameter 3 m, hub height
  90 m, overhang 5 m (shaft tilt 5 deg and precone 2.5 deg are *not* modelled: this project's
  rotor plane is vertical).
* Table 2-1 (distributed blade aerodynamic properties): the 17 analysis nodes' radius RNodes [m]
  from the rotor centre, aerodynamic twist [deg] and chord [m], and the aerofoil at each node
  (Cylinder1/2, DU40, DU35, DU30, DU25, DU21, NACA64; the number in a DU name is the relative
  thickness in percent, NACA64_A17 is the 18 % NACA 64-618, the cylinders are 100 %). The blade
  runs from the hub radius 1.5 m to the tip radius 63 m (61.5 m long); the table's first and last
  node are element mid-points (2.87 m, 61.63 m), so the root and tip stations repeat their values.
* Section 6 (tower): base diameter 6 m, top diameter 3.87 m (the 87.6 m tower; here the tower
  reaches the rotor centre at the 90 m hub height, the model's convention).

Not in the report, assumed here and marked so: the nacelle, an obstacle only, is modelled as a
cylinder of 1.75 m radius running 12 m back from the tower axis; the hub is the usual cylinder of
the hub radius. The 3.54 m root cylinders, starting 1.5 m from the rotor centre, stay 0.83 m
apart from their neighbours (measured on the mesh).
"""
from __future__ import annotations

from typing import Any

# Table 2-1 of NREL/TP-500-38060: (RNodes [m], AeroTwst [deg], Chord [m], relative thickness)
NREL_5MW_NODES: tuple[tuple[float, float, float, float], ...] = (
    (2.8667, 13.308, 3.542, 1.00),    # Cylinder1
    (5.6000, 13.308, 3.854, 1.00),    # Cylinder1
    (8.3333, 13.308, 4.167, 1.00),    # Cylinder2
    (11.7500, 13.308, 4.557, 0.405),  # DU40_A17
    (15.8500, 11.480, 4.652, 0.35),   # DU35_A17
    (19.9500, 10.162, 4.458, 0.35),   # DU35_A17
    (24.0500, 9.011, 4.249, 0.30),    # DU30_A17
    (28.1500, 7.795, 4.007, 0.25),    # DU25_A17
    (32.2500, 6.544, 3.748, 0.25),    # DU25_A17
    (36.3500, 5.361, 3.502, 0.21),    # DU21_A17
    (40.4500, 4.188, 3.256, 0.21),    # DU21_A17
    (44.5500, 3.125, 3.010, 0.18),    # NACA64_A17
    (48.6500, 2.319, 2.764, 0.18),    # NACA64_A17
    (52.7500, 1.526, 2.518, 0.18),    # NACA64_A17
    (56.1667, 0.863, 2.313, 0.18),    # NACA64_A17
    (58.9000, 0.370, 2.086, 0.18),    # NACA64_A17
    (61.6333, 0.106, 1.419, 0.18),    # NACA64_A17
)
NREL_5MW_HUB_RADIUS = 1.5     # Table 1-1: hub diameter 3 m
NREL_5MW_TIP_RADIUS = 63.0    # Table 1-1: rotor diameter 126 m


def _nrel_5mw() -> dict[str, Any]:
    nodes = ((NREL_5MW_HUB_RADIUS, *NREL_5MW_NODES[0][1:]), *NREL_5MW_NODES,
             (NREL_5MW_TIP_RADIUS, *NREL_5MW_NODES[-1][1:]))
    return {
        "tower_height": 90.0,                       # hub height
        "tower_radius": 3.0,                        # base diameter 6 m
        "tower_top_radius": 1.935,                  # top diameter 3.87 m
        "hub_radius": NREL_5MW_HUB_RADIUS,
        "overhang": 5.0,
        "nacelle_radius": 1.75,                     # assumed (not in the report)
        "nacelle_length": 12.0,                     # assumed (not in the report)
        "blade": {
            "span": [n[0] for n in nodes],
            "twist_deg": [n[1] for n in nodes],
            "chord": [n[2] for n in nodes],
            "thickness": [n[3] for n in nodes],
            "pitch_axis": 0.25,
        },
    }


PRESETS = {"nrel-5mw": _nrel_5mw}


def get_turbine_preset(name: Any) -> dict[str, Any]:
    """The TurbineSpec fields of a named turbine (a fresh dict)."""
    if not isinstance(name, str) or name not in PRESETS:
        raise ValueError(f"preset must be one of {', '.join(sorted(PRESETS))}, got {name!r}")
    return PRESETS[name]()
