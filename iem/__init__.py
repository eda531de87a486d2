"""The learning core: bag router, weak learners, the incremental ensemble and its baselines.

numpy only: nothing here imports hardware, MuJoCo or Pinocchio.
"""
