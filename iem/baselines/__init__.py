"""The baselines the IEM is measured against (numpy only at import).

- :mod:`~iem.baselines.old_iem`: the old IEM (2024), the same learners updated in place,
  never added to (:class:`InPlaceEnsemble`, ``"old_IEM"``).
- :mod:`~iem.baselines.bem`: the BEM (2023), bagged networks and CART trees trained once
  (:class:`BatchEnsemble`, ``"BEM"``), with its tree :mod:`~iem.baselines.tree`
  (:class:`RegressionTree`).
- :mod:`~iem.baselines.least_squares`: LS, recursive least squares on the payload regressor,
  the physics anchor (:class:`RecursiveLeastSquares`, ``"LS"``).
"""

from .bem import BatchEnsemble
from .least_squares import RecursiveLeastSquares
from .old_iem import FROZEN, RUNNING_CENTRE, STRICT, UPDATES, InPlaceEnsemble
from .tree import RegressionTree

__all__ = ["FROZEN", "RUNNING_CENTRE", "STRICT", "UPDATES", "BatchEnsemble", "InPlaceEnsemble",
           "RecursiveLeastSquares", "RegressionTree"]
