"""The wind turbine: its validated spec and triangle mesh (:mod:`.model`), parametric blades
(:mod:`.blade_geometry`) and named reference turbines (:mod:`.presets`). Depends on
:mod:`wt_inspect_env.util` only.
"""
