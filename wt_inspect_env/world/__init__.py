"""The simulators and the inspection world: the single and the batched PyBullet simulator
(:mod:`.sim`, :mod:`.batched_sim`), their shared stepping loop (:mod:`.integration`) and the
:class:`~wt_inspect_env.world.world.InspectionWorld` that ties flight, task and scene together.
Everything below may be imported here; only the environments (``env.py``, ``vector/``) sit above.
"""
