"""Many drones per process: the batched simulator and the native Gymnasium vector environment.

``gym.make_vec(env_id, num_envs=N, vectorization_mode="vector_entry_point", **options)`` reaches
:class:`WindTurbineInspectionVectorEnv` for every registered task.
"""
from .env import WindTurbineInspectionVectorEnv
from .sim import BatchedQuadrotorSim

__all__ = ["WindTurbineInspectionVectorEnv", "BatchedQuadrotorSim"]
