"""Coverage samples: the training family at a bag's poses with other velocities, checked
against Pinocchio's RNEA with each payload; the reversed samples, checked against the tandem
simulators at the reversed state (with an arm's friction too); an ensemble trained with them
reads a reversed motion its plain twin does not."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

from iem.ensemble import IncrementalEnsemble
from iem.errors import InvalidInputError
from iem.factories import build
from sim.coverage import OtherVelocities, reversal_spec, reversed_velocities
from sim.family import default_test_payload, training_payloads
from sim.paths import excitation_path
from sim.plant import RealityGap
from sim.robot import ArmModel
from sim.tandem import TandemSimulators


def training_phi() -> np.ndarray:
    """The 77 training payloads' phi, ``(77, 10)``, paper order."""
    return np.array([p.to_phi() for p in training_payloads()])


def test_samples_are_the_family_torques_at_a_state_within_the_limits():
    model = ArmModel()
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
    Xc, Yc = covered._augment(np.vstack([X[:2], X[2:]]), np.vstack([Y, Y]), 2, [0])
    assert Xc.shape == (4 + 2 * 2 * 2, 21) and Yc.shape == (12, 10)
    np.testing.assert_array_equal(Xc[:4], np.vstack([X[:2], X[2:]]))
    assert plain._augment(X, np.vstack([Y, Y]), 2, [0])[0] is X


@pytest.mark.parametrize("gap", [None, 3])
def test_reversed_samples_are_the_tandem_at_the_reversed_state(gap):
    """Against the tandem simulators (Pinocchio's RNEA, the arm's friction and offsets) at
    (q, -dq, ddq): on the nominal arm and on a calibrated-style arm with friction."""
    arm = None if gap is None else RealityGap(seed=gap).realise()
    model = ArmModel(arm=arm)
    phi = training_phi()[:6]
    tandem = TandemSimulators(phi, model=model)
    reverse = reversed_velocities() if arm is None else build(reversal_spec(arm), "reversal")
    rng = np.random.default_rng(1)
    for _ in range(3):
        q, dq, ddq = model.random_state(rng)
        X, _ = tandem.samples(q, dq, ddq)
        back, _ = tandem.samples(q, -dq, ddq)
        np.testing.assert_allclose(reverse(X), back, rtol=0, atol=1e-9)
        if arm is not None:  # friction is odd: the torques do change
            assert np.abs(back[:, 14:] - X[:, 14:]).max() > 0.05


def test_samples_of_one_state_are_reversed_as_each_alone():
    """The samples of one state share their velocities and take one row's friction: the same
    numbers to the bit as each sample reversed on its own; samples of several states too."""
    arm = RealityGap(seed=3).realise()
    model = ArmModel(arm=arm)
    tandem = TandemSimulators(training_phi()[:6], model=model)
    reverse = build(reversal_spec(arm), "reversal")
    rng = np.random.default_rng(2)
    X = np.vstack([tandem.samples(*model.random_state(rng))[0] for _ in range(2)])
    one = X[:6]  # one state
    np.testing.assert_array_equal(reverse(one), np.vstack([reverse(row[None]) for row in one]))
    np.testing.assert_array_equal(reverse(X), np.vstack([reverse(row[None]) for row in X]))


def test_reversal_is_a_hyper_parameter_that_doubles_the_training():
    spec = "sim.coverage:reversed_velocities"
    ens = IncrementalEnsemble(seed=0, reversal=spec)
    assert ens.params()["reversal"] == spec
    assert type(ens)(**ens.params()).params() == ens.params()
    assert IncrementalEnsemble.from_state(ens.to_state()).reversal == spec
    assert copy.deepcopy(ens)._augment.reverse is ens._augment.reverse  # immutable, shared
    assert pickle.loads(pickle.dumps(ens)).reversal == spec  # the spec, built again
    X = np.arange(2 * 21, dtype=float).reshape(2, 21)
    Y = training_phi()[:2]
    Xr, Yr = ens._augment(X, Y, 2, [0])
    assert Xr.shape == (4, 21)
    np.testing.assert_array_equal(Xr[:2], X)
    np.testing.assert_array_equal(Xr[2:, 7:14], -X[:, 7:14])
    np.testing.assert_array_equal(Xr[2:, [*range(7), *range(14, 21)]],
                                  X[:, [*range(7), *range(14, 21)]])
    np.testing.assert_array_equal(Yr, np.vstack([Y, Y]))
    with pytest.raises(InvalidInputError, match=r"reversal 'sim\.coverage:nothing'"):
        IncrementalEnsemble(reversal="sim.coverage:nothing")
    with pytest.raises(InvalidInputError, match=r"reversal .*arm:00000000'.*was not given"):
        IncrementalEnsemble(reversal="sim.coverage:reversed_velocities@arm:00000000")
    with pytest.raises(InvalidInputError, match=r"never by path"):
        IncrementalEnsemble(reversal="sim.coverage:reversed_velocities@/an/arm.msgpack")


def test_a_bag_trained_with_the_reversal_reads_the_motion_driven_backwards():
    """Bags fitted on the excitation path; the test payload's samples along it read with
    every velocity reversed (the torques of the frictionless arm are the same): the plain
    twin is far off, the reversal reads them as it reads the path forwards."""
    path = excitation_path().slice(0, 6.0)
    kin = ArmModel()
    tandem = TandemSimulators(training_phi(), model=kin)
    flange = kin.flange_positions(path.q)
    test = TandemSimulators(default_test_payload().to_phi()[None, :], model=kin)
    idx = np.arange(0, len(path.q), 5)
    X = np.vstack([test.samples(path.q[i], path.dq[i], path.ddq[i])[0] for i in idx])
    back = X.copy()
    back[:, 7:14] *= -1.0
    truth = default_test_payload().mass
    err = {}
    for name, reversal in (("plain", None), ("reversal", "sim.coverage:reversed_velocities")):
        ens = IncrementalEnsemble(seed=0, reversal=reversal).fit(
            path.q, flange, lambda i: tandem.samples(path.q[i], path.dq[i], path.ddq[i]))
        err[name] = [np.abs(ens.predict_many(Z, flange[idx])[:, 0] - truth).mean()
                     for Z in (X, back)]
    forward, backward = err["reversal"]
    assert backward < 1.5 * forward + 0.01, err
    assert err["plain"][1] > 5 * backward, err
