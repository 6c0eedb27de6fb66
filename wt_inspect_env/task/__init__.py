"""The inspection task: the environments' options (:mod:`.env_config`), action scaling and
observation layout (:mod:`.spaces`), missions, the moving reference, coverage, metrics, inspection
geometry, domain randomisation and the hooks with their per-step terms. Depends on the layers
below it (util, native, turbine, planner, physics, scene), never on the simulators or the world.
"""
