"""What the PyBullet scene shows and how it is seen: the inspection camera (:mod:`.camera`), the
turbine's texture and visual chunks (:mod:`.texture`, :mod:`.scene_visuals`), PyBullet's mesh
reference leak contained (:mod:`.pybullet_refs`) and rendered images (:mod:`.render`). Depends on
:mod:`wt_inspect_env.util` only.
"""
