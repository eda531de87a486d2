"""The simulators in tandem equal one RNEA per payload."""

import numpy as np
import pytest

from iem.errors import InvalidInputError
from sim.family import training_payloads
from sim.robot import ArmModel
from sim.tandem import TandemSimulators


@pytest.fixture(scope="module")
def tandem():
    return TandemSimulators(training_payloads())


def test_samples_equal_per_payload_rnea(tandem):
    model = ArmModel()
    rng = np.random.default_rng(11)
    payloads = training_payloads()
    for _ in range(5):
        q, dq, ddq = model.random_state(rng)
        x, y = tandem.samples(q, dq, ddq)
        assert x.shape == (77, 21) and y.shape == (77, 10)
        for k, p in enumerate(payloads):
            expected = model.rnea_with_payload(q, dq, ddq, p.to_phi())
            np.testing.assert_allclose(x[k, 14:], expected, atol=1e-9)
            np.testing.assert_array_equal(x[k, :7], q)
            np.testing.assert_array_equal(x[k, 7:14], dq)
            np.testing.assert_allclose(y[k], p.to_phi(), atol=1e-15)


def test_targets_are_read_only(tandem):
    _, y = tandem.samples(np.zeros(7), np.zeros(7), np.zeros(7))
    with pytest.raises(ValueError):
        y[0, 0] = 1.0


def test_bad_family_shape_is_an_error():
    with pytest.raises(InvalidInputError, match=r"\(K, 10\)"):
        TandemSimulators(np.zeros((3, 9)))
