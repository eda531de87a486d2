"""A motion that determines a payload (sim.excite): within the arm model's limits, from and
back to the start pose at rest, better conditioned than the paths it is meant to help, read
back from its CSV, and enough for the offline identification; bad inputs are refused."""

import numpy as np
import pytest

from iem.errors import PathError
from sim.excite import DESIGN_RATE_HZ, LIMIT_FRACTION, condition_number, excite_path
from sim.paths import Q0, excitation_path, load_path_csv, new_task_path, save_path_csv
from sim.robot import ArmModel

START = np.array(Q0) + np.array([0.3, 0.1, -0.2, 0.2, 0.0, -0.1, 0.3])


@pytest.fixture(scope="module")
def designed():
    return excite_path(6.0, START, restarts=1, iterations=15)


def test_the_motion_keeps_the_limits_and_starts_and_ends_at_rest_at_the_start(designed):
    path, design = designed
    m = ArmModel()
    assert path.duration == pytest.approx(6.0)
    path.check_limits(m)
    np.testing.assert_allclose(path.q[[0, -1]], [START, START], atol=1e-9)
    assert np.abs(path.dq[[0, -1]]).max() < 1e-9 and np.abs(path.ddq[[0, -1]]).max() < 1e-9
    assert np.all(np.abs(path.dq).max(axis=0) <= LIMIT_FRACTION * m.dq_max + 1e-9)
    assert np.all(np.abs(path.ddq).max(axis=0) <= LIMIT_FRACTION * m.ddq_max + 1e-9)
    assert np.all(np.array(design.q_peak) <= np.array(design.q_room))
    np.testing.assert_allclose(design.dq_peak, np.abs(path.dq).max(axis=0), rtol=1e-12)


def test_it_is_better_conditioned_than_the_excitation_and_the_task_path(designed):
    """The excitation path's scaled regressor (measured: condition 5,500) and the new task
    path's (380,000); the designed motion's under 500 even lightly optimised."""
    _, design = designed
    m = ArmModel()
    every = round(1000 / DESIGN_RATE_HZ)
    conds = [condition_number(m, p.q[::every], p.dq[::every], p.ddq[::every])
             for p in (excitation_path(), new_task_path())]
    assert design.condition < 500 and design.condition < 0.1 * min(conds), (design, conds)


def test_its_csv_is_the_motion(designed, tmp_path):
    path, _ = designed
    f = tmp_path / "excite.csv"
    save_path_csv(path, f)
    back = load_path_csv(f)
    assert back.duration == pytest.approx(path.duration)
    np.testing.assert_allclose(back.q, path.q, atol=1e-6)
    back.check_limits(ArmModel())


def test_its_data_alone_identify_a_payload(designed):
    """Loaded and bare along the motion, the offline identification (simulated arm equal to
    its model) finds the payload's mass and CoM."""
    from sim.family import test_payloads
    from sim.identify import identify
    from sim.plant import ArmPlant

    path, _ = designed
    payload = test_payloads()["test-3w"]
    loaded = ArmPlant(payload=payload, seed=1, controller_load=payload).follow(path)
    bare = ArmPlant(payload=None, seed=2).follow(path)
    cut = lambda r: (r.t, r.q, r.dq, r.tau)  # noqa: E731
    got = identify(cut(loaded), bare=cut(bare)).phi
    truth = payload.to_phi()
    assert abs(got[0] - truth[0]) < 0.002
    assert np.linalg.norm(got[1:4] / got[0] - truth[1:4] / truth[0]) < 0.001


def test_bad_inputs_are_refused_naming_what_is_valid():
    m = ArmModel()
    outside = np.array(Q0)
    outside[3] = m.q_max[3] + 0.1
    with pytest.raises(PathError, match=r"joint 4 .*strictly between"):
        excite_path(5.0, outside)
    with pytest.raises(PathError, match="seconds must be from 2 to 120"):
        excite_path(1.0)
    with pytest.raises(PathError, match=r"start must have shape \(7,\)"):
        excite_path(5.0, [0.0, 1.0])
    with pytest.raises(PathError, match="harmonics must be an integer from 3 to 10"):
        excite_path(5.0, harmonics=2)
