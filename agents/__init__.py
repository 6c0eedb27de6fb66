"""stable-baselines3 agents: training, observation wrappers, saved models, RL-vs-MPC comparison.

Needs the optional ``rl`` extra (``pip install 'wt-inspect[rl]'``).
"""
