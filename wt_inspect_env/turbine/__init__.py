"""The wind turbine: its validated description (:mod:`.spec`), the triangle mesh built from it
(:mod:`.mesh`), turbines from mesh files (:mod:`.loading`), parametric blades
(:mod:`.blade_geometry`) and named reference turbines (:mod:`.presets`). Depends on
:mod:`wt_inspect_env.util` only.

The names a user needs are exported here: ``build_turbine(TurbineSpec(...))`` and
``load_turbine_mesh(path)`` give a :class:`~.mesh.TurbineMesh`.
"""
from __future__ import annotations

from .loading import MeshLoadOptions, load_turbine_mesh
from .mesh import TurbineMesh, build_turbine
from .spec import TurbineSpec

__all__ = ["MeshLoadOptions", "TurbineMesh", "TurbineSpec", "build_turbine", "load_turbine_mesh"]
