"""The learning core: bag router, weak learners, the incremental ensemble and its baselines.

numpy only at import: nothing here imports hardware, MuJoCo or Pinocchio. The per-sample
kernels (:mod:`iem.kernels`) compile with numba when first run.
"""
