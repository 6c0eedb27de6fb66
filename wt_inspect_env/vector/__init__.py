"""Many drones per process: the batched simulator and the native Gymnasium vector environment.

``gym.make_vec(env_id, num_envs=N, vectorization_mode="vector_entry_point", **options)`` reaches
:class:`WindTurbineInspectionVectorEnv` for every registered task.
"""
from ..world.batched_sim import BatchedQuadrotorSim
from .env import WindTurbineInspectionVectorEnv

__all__ = ["WindTurbineInspectionVectorEnv", "BatchedQuadrotorSim"]
