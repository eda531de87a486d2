"""The contract a PayloadEstimate checks where it is made, against the plain rule, on edge
values (NaN, infinities, values whose squares overflow, negative variances); and the states
a decoder makes of arrays it already holds as a state keeps them."""

import math

import numpy as np
import pytest

from iem.errors import InvalidInputError
from iem.types import JointState, PayloadEstimate

EDGES = (math.nan, math.inf, -math.inf, 1e200, -1e200, 1e-300, -1e-300, 0.0, -0.0, 3.0, -0.5)


def valid(phi, std, cov) -> bool:
    """The rule in words, entry by entry: phi 10 finite numbers or all NaN; std None or 10
    numbers >= 0 (inf allowed); cov None or a finite 10x10 with a diagonal >= 0."""
    if not (all(math.isfinite(v) for v in phi) or all(math.isnan(v) for v in phi)):
        return False
    if std is not None and not all(v >= 0 for v in std):
        return False
    return cov is None or (all(math.isfinite(v) for v in np.ravel(cov))
                           and all(cov[i][i] >= 0 for i in range(10)))


def accepted(phi, std, cov) -> bool:
    try:
        PayloadEstimate(t=0.0, phi=phi, std=std, cov=cov)
    except InvalidInputError:
        return False
    return True


def test_the_checks_follow_the_rule_on_edge_values():
    rng = np.random.default_rng(0)
    for _ in range(3000):
        phi = rng.normal(size=10)
        std = None if rng.random() < 0.2 else rng.uniform(0.0, 1.0, 10)
        cov = None if rng.random() < 0.3 else np.diag(rng.uniform(0.0, 1.0, 10))
        what = rng.integers(4)
        edge = EDGES[rng.integers(len(EDGES))]
        if what == 0:
            phi[rng.integers(10)] = edge
        elif what == 1 and std is not None:
            std[rng.integers(10)] = edge
        elif what == 2 and cov is not None:
            i, j = rng.integers(10, size=2)
            cov[i, j] = edge
        elif what == 3:
            phi[:] = math.nan
        assert accepted(phi, std, cov) == valid(phi, std, cov), (phi, std, cov)


def test_shapes_are_refused_with_their_field():
    with pytest.raises(InvalidInputError, match=r"phi has shape \(9,\)"):
        PayloadEstimate(t=0.0, phi=np.zeros(9))
    with pytest.raises(InvalidInputError, match="std has shape"):
        PayloadEstimate(t=0.0, phi=np.zeros(10), std=np.zeros(3))
    with pytest.raises(InvalidInputError, match="cov has shape"):
        PayloadEstimate(t=0.0, phi=np.zeros(10), cov=np.eye(3))


def test_a_state_of_kept_arrays_equals_the_checked_one():
    v = np.arange(21, dtype=float)
    v.flags.writeable = False
    q, dq, tau = v[:7], v[7:14], v[14:]
    kept = JointState.of_kept(1.5, q, dq, tau, 12)
    checked = JointState(t=1.5, q=q, dq=dq, tau_J=tau, cycle=12)
    for f in ("t", "q", "dq", "tau_J", "cycle"):
        assert np.array_equal(getattr(kept, f), getattr(checked, f)), f
    assert kept.q is checked.q  # the checked one keeps a read-only float64 array as it is
    with pytest.raises(AttributeError):
        kept.t = 2.0  # frozen like any state
