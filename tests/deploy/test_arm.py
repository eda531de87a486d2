"""The arm file wherever the arm model is used: training, the physics' dynamics spec,
replay and the service refuse a model trained for another arm."""

import numpy as np
import pytest

from deploy.cli import main
from deploy.config import config_from_dict, load_config
from deploy.replay.core import CSV_HEADER
from iem.errors import InvalidInputError, ModelFileError
from iem.persistence import check_arm, load_model
from iem.physics.regression import load_dynamics
from sim.arm import ArmParams, arm_record, arm_spec, load_arm, save_arm
from sim.family import default_test_payload
from sim.paths import new_task_path
from sim.plant import ArmPlant, RealityGap
from sim.robot import ArmModel
from tests.can_logs import write_log

GAP = RealityGap(seed=3).modelled_only()
"""The plant tests/conftest.py's arm file is calibrated from (``iem calibrate`` on its CAN
log, checked in tests/sim/test_calibration.py)."""


@pytest.fixture(scope="module")
def files(calibrated_from_a_can_log, tmp_path_factory):
    """A folder of this module's own: a copy of the arm file ``iem calibrate`` wrote from a
    CAN log (tests/conftest.py), IEM+phys trained for it by ``iem train --arm``, a loaded run
    on the same plant as a CAN log, and the nominal arm as ``other.msgpack``."""
    import shutil

    d = tmp_path_factory.mktemp("arm")
    assert calibrated_from_a_can_log["status"] == 0
    shutil.copyfile(calibrated_from_a_can_log["arm"], d / "arm.msgpack")
    p = default_test_payload()
    loaded = ArmPlant(gap=GAP, seed=22, payload=p, controller_load=p).follow(
        new_task_path().slice(0, 2.0))
    write_log(loaded, d / "loaded.blf")
    assert main(["train", "--kind", "IEM+phys", "--arm", str(d / "arm.msgpack"),
                 "--out", str(d / "model.msgpack")]) == 0
    save_arm(ArmParams.nominal(), d / "other.msgpack")
    return d


def test_model_records_its_arm_and_names_it_in_its_physics(files):
    arm = load_arm(files / "arm.msgpack")
    model = load_model(files / "model.msgpack", resources={"arm": arm})
    assert model.trained_arm == arm_record(arm, files / "arm.msgpack")
    assert model.dynamics == arm_spec(arm) == f"sim.arm:arm_dynamics@arm:{arm.crc32:08x}"
    check_arm(model, arm_record(arm, "anywhere/arm.msgpack"))  # same content: accepted
    with pytest.raises(ModelFileError, match="nominal arm"):
        check_arm(model, None)
    with pytest.raises(ModelFileError, match=r"other\.msgpack"):
        check_arm(model, arm_record(load_arm(files / "other.msgpack"), files / "other.msgpack"))


def test_dynamics_spec_carries_the_arm_file(files):
    arm = load_arm(files / "arm.msgpack")
    f = load_dynamics(arm_spec(arm))
    plain = load_dynamics("sim.arm:arm_dynamics")
    q, dq, ddq = ArmModel().random_state(np.random.default_rng(0))
    tau, Y, _ = f(q, dq, ddq)
    np.testing.assert_allclose(tau, ArmModel(arm=arm).rnea(q, dq, ddq), atol=1e-12)
    np.testing.assert_allclose(Y, plain(q, dq, ddq)[1], atol=1e-12)  # kinematics only
    assert not np.allclose(tau, plain(q, dq, ddq)[0], atol=1e-3)
    with pytest.raises(InvalidInputError, match="arm:00000000, which was not given"):
        load_dynamics("sim.arm:arm_dynamics@arm:00000000")


def test_replay_with_the_arm_and_refusal_with_another(files, capsys):
    csv, js = files / "e.csv", files / "s.json"
    args = ["replay", str(files / "loaded.blf"), "--model", str(files / "model.msgpack"),
            "--truth", "sim/payloads/test-3w.toml", "--json", str(js), "--out", str(csv),
            "--no-status"]
    assert main([*args, "--arm", str(files / "arm.msgpack")]) == 0
    assert csv.read_text().splitlines()[0] == ",".join(CSV_HEADER)
    capsys.readouterr()
    assert main(args) == 2
    assert "trained for arm file arm.msgpack" in capsys.readouterr().err
    assert main([*args, "--arm", str(files / "other.msgpack")]) == 2
    assert "other.msgpack" in capsys.readouterr().err


def test_config_arm_key(tmp_path):
    assert config_from_dict({}).model.arm == ""
    cfg = tmp_path / "cell.toml"
    cfg.write_text('[model]\narm = "arm.msgpack"\n')
    assert load_config(cfg).model.arm == str(tmp_path / "arm.msgpack")


def test_the_arm_record_is_covered_by_the_model_files_crc(tmp_path):
    from iem.ensemble import IncrementalEnsemble
    from iem.persistence import dumps, loads

    model = IncrementalEnsemble()
    model.trained_arm = {"crc32": 1234, "source": "arm.msgpack"}
    data = dumps(model)
    assert loads(data).trained_arm == model.trained_arm
    forged = data.replace(b"arm.msgpack", b"xrm.msgpack")
    with pytest.raises(ModelFileError, match="corrupt"):
        loads(forged)
    assert getattr(loads(dumps(IncrementalEnsemble())), "trained_arm", None) is None


def trained_on_a_copy_of_the_arm(files, tmp_path, kind: str):
    """``(model, arm_file, record)``: a model of ``kind`` trained by ``iem train --arm`` on a
    copy of the fixture's arm file in ``tmp_path``, accepted by ``check_model_arm``."""
    import shutil

    from deploy.model.training import check_model_arm

    arm_file = tmp_path / "arm.msgpack"
    shutil.copy(files / "arm.msgpack", arm_file)
    assert main(["train", "--kind", kind, "--arm", str(arm_file),
                 "--out", str(tmp_path / "model.msgpack")]) == 0
    model = load_model(tmp_path / "model.msgpack", resources={"arm": load_arm(arm_file)})
    record = arm_record(load_arm(arm_file), arm_file)
    check_model_arm(model, record)
    return model, arm_file, record


def test_the_learners_reversal_is_the_arms_and_a_changed_arm_file_is_refused(files, tmp_path):
    from deploy.model.training import check_model_arm
    from sim.coverage import reversal_spec

    model, arm_file, _ = trained_on_a_copy_of_the_arm(files, tmp_path, "IEM")
    arm = load_arm(arm_file)
    assert model.reversal == reversal_spec(arm)  # by content: the copy's is the original's
    assert load_model(files / "model.msgpack", resources={"arm": arm}).ensemble_model.reversal \
        == reversal_spec(load_arm(files / "arm.msgpack"))
    save_arm(ArmParams.nominal(), arm_file)  # same path, another arm
    other = load_arm(arm_file)
    with pytest.raises(ModelFileError, match=rf"trained for arm file arm\.msgpack \(CRC32 "
                                             rf"{arm.crc32:#010x}.* but is run with arm file "
                                             rf"arm\.msgpack \(CRC32 {other.crc32:#010x}"):
        load_model(tmp_path / "model.msgpack", resources={"arm": other})
    with pytest.raises(ModelFileError, match=r"trained for arm file arm\.msgpack"):
        check_model_arm(model, arm_record(other, arm_file))
