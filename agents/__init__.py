"""stable-baselines3 agents: training, observation wrappers, saved models, RL-vs-MPC comparison.

Needs the optional ``rl`` extra (``pip install 'wt-inspect[rl]'``).

* :mod:`agents.wrappers` - body-frame relative features, residual-to-hover actions, action repeat,
  training-only reward shaping, per-episode environment variants (no torch needed);
* :mod:`agents.recipe` - training recipes (``agents/recipes/*.json``);
* :mod:`agents.training` - ``train(...)``: vectorised envs, VecNormalize, evaluation with the shared
  metrics, checkpoints, resume, TensorBoard, learning curve (``wt-inspect train``);
* :mod:`agents.policy` - ``load_sb3_policy(algo, path, env)``: a saved model as a controller with the
  shared ``reset / act / predict`` interface (used by the evaluation harness for ``ppo:PATH``);
* :mod:`agents.bench` - training throughput (``wt-inspect bench train``);
* ``agents/models`` - the shipped agents with their learning curves (see its README).
"""
