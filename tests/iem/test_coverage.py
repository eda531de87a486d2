"""Coverage samples: the training family at a bag's poses with other velocities, checked
against Pinocchio's RNEA with each payload; an ensemble trained with them covers a reversed
motion its plain twin does not."""

from __future__ import annotations

import numpy as np

from iem.ensemble import IncrementalEnsemble
from sim.coverage import OtherVelocities
from sim.family import training_phi
from sim.robot import PandaModel


def test_samples_are_the_family_torques_at_a_state_within_the_limits():
    model = PandaModel()
    cover = OtherVelocities(fraction=0.9, model=model)
    phi = training_phi()[:5]
    q = np.array([0.1, -0.4, 0.2, -2.0, 0.1, 1.8, 0.6])
    X = cover(q, phi, np.random.default_rng(0))
    assert X.shape == (5, 21)
    np.testing.assert_array_equal(X[:, :7], np.tile(q, (5, 1)))
    dq = X[0, 7:14]
    assert np.all(np.abs(dq) <= 0.9 * model.dq_max) and np.any(dq != 0)
    # the torque of payload k is RNEA with that payload at (q, dq, ddq) for one ddq: recover
    # ddq from payload 0 and check every other payload against RNEA independently
    M = np.array([model.rnea_with_payload(q, np.zeros(7), e, phi[0])
                  - model.rnea_with_payload(q, np.zeros(7), np.zeros(7), phi[0])
                  for e in np.eye(7)]).T
    b = model.rnea_with_payload(q, dq, np.zeros(7), phi[0])
    ddq = np.linalg.solve(M, X[0, 14:] - b)
    assert np.all(np.abs(ddq) <= 0.9 * model.ddq_max + 1e-6)
    for k in range(5):
        np.testing.assert_allclose(X[k, 14:], model.rnea_with_payload(q, dq, ddq, phi[k]),
                                   atol=1e-8)


def test_coverage_is_a_hyper_parameter_and_changes_only_training():
    plain = IncrementalEnsemble(seed=0)
    covered = IncrementalEnsemble(seed=0, coverage="sim.coverage:other_velocities",
                                  coverage_draws=2)
    assert covered.params()["coverage"] == "sim.coverage:other_velocities"
    assert type(covered)(**covered.params()).params() == covered.params()
    X = np.zeros((4, 21))
    X[:, :7] = 0.3
    Y = training_phi()[:2]
    Xc, Yc = covered._covered(np.vstack([X[:2], X[2:]]), np.vstack([Y, Y]), 2, [0])
    assert Xc.shape == (4 + 2 * 2 * 2, 21) and Yc.shape == (12, 10)
    np.testing.assert_array_equal(Xc[:4], np.vstack([X[:2], X[2:]]))
    assert plain._covered(X, np.vstack([Y, Y]), 2, [0])[0] is X
