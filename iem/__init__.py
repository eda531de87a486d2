"""The learning core: the incremental ensemble, IEM+phys, their baselines and their signals.

- :mod:`iem.ensemble`: the paper's IEM (bag router, weak learners, the learning scheduler);
- :mod:`iem.physics`: IEM+phys, the ensemble as a prior for Bayesian least squares on the
  robot's physics;
- :mod:`iem.baselines`: the old IEM, BEM and LS;
- :mod:`iem.signals`: block points, the gap rule, filters, smoothing, recordings.

At the top, what everything imports: the value types and errors (:mod:`iem.types`,
:mod:`iem.payload`, :mod:`iem.errors`), the estimator protocol (:mod:`iem.base`), the sensor
model, the online loop, model files (:mod:`iem.persistence`, :mod:`iem.migrations`,
:mod:`iem.atomic_file`, and the table of factories they may name, :mod:`iem.factories`),
metrics and the shared check suite.

numpy, scipy (LAPACK for the small solves, the offline chain's filters) and msgpack (model
files); nothing here imports hardware, MuJoCo or Pinocchio.
"""
