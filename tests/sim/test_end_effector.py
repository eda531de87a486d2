"""The end effector: part of the arm's body 7, declared, recorded and checked."""

import numpy as np
import pytest

from iem.errors import InvalidInputError, ModelFileError
from iem.persistence import check_arm
from sim.arm import ArmParams, arm_record, load_arm, save_arm
from sim.end_effector import check_same, end_effector, end_effector_of
from sim.nominal import link7_params
from sim.payload import Payload, save_payload
from sim.robot import ArmModel, nominal_link_params


def test_franka_hand_is_the_nominal_model_to_the_bit():
    assert np.array_equal(nominal_link_params("franka_hand"), nominal_link_params())
    assert np.array_equal(ArmParams.nominal().link_params, nominal_link_params())
    assert ArmParams.nominal().end_effector == "franka_hand"


def test_none_is_link7_alone_and_the_hand_is_its_0_76_kg():
    bare = nominal_link_params("none")
    assert bare[6, 0] == pytest.approx(0.735522)  # the URDF's panda_link7
    assert np.array_equal(bare[:6], nominal_link_params()[:6])
    hand = end_effector("franka_hand")
    assert hand.mass == pytest.approx(0.73 + 2 * 0.015, abs=1e-9)  # hand and two fingers
    assert np.allclose(link7_params() + hand.params(), nominal_link_params()[6])


def test_an_end_effector_is_resolved_on_its_arm_model(tmp_path):
    """One resolution (end_effector_of): an EndEffector as it is; a spec; None or "" the arm
    model's default, the hand on a named arm model and nothing on a URDF file."""
    from sim.description import arm_description

    fr3 = arm_description("fr3")
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(fr3.text, encoding="utf-8")
    own = arm_description(str(urdf), fr3.flange)
    tool = end_effector("none")
    assert end_effector_of(tool, fr3) is tool
    for declared in (None, ""):
        assert end_effector_of(declared).spec == "franka_hand"  # the default arm model's
        assert end_effector_of(declared, fr3).spec == "franka_hand"
        assert end_effector_of(declared, own).spec == "none"
    assert end_effector_of("none", fr3).label == "none"
    assert end_effector_of("franka_hand", own).mass == end_effector("franka_hand").mass
    assert own.end_effector_spec(None) == "none" and fr3.end_effector_spec("x.toml") == "x.toml"
    with pytest.raises(InvalidInputError, match="'gripper' is not valid"):
        end_effector_of("gripper", fr3)
    # and everything that builds the arm from a declaration takes it from there
    assert ArmParams.nominal(None, own).end_effector == "none"
    assert np.array_equal(nominal_link_params(None, own), nominal_link_params("none", own))


def test_a_tool_file_is_a_payload_fused_into_body_7(tmp_path):
    """Independent truth: Pinocchio's RNEA of the bare arm with the tool as a payload at the
    flange equals the RNEA of the arm whose body 7 carries the tool."""
    tool = Payload("gripper", 0.9, (0.01, -0.02, 0.07), (0.003, 0.0001, 0.0, 0.003, 0.0, 0.002))
    path = tmp_path / "gripper.toml"
    save_payload(tool, path)
    ee = end_effector(str(path))
    assert ee.label.startswith("gripper:") and ee.mass == pytest.approx(0.9)
    with_tool = ArmModel(arm=ArmParams.nominal(ee))
    bare = ArmModel(arm=ArmParams.nominal("none"))
    rng = np.random.default_rng(3)
    for _ in range(5):
        q, dq, ddq = bare.random_state(rng)
        assert np.allclose(with_tool.rnea(q, dq, ddq),
                           bare.rnea_with_payload(q, dq, ddq, tool.to_phi()), atol=1e-10)


def test_a_bad_end_effector_says_what_is_valid(tmp_path):
    with pytest.raises(InvalidInputError, match=r"franka_hand.*none.*toml"):
        end_effector("robotiq")
    with pytest.raises(InvalidInputError):
        end_effector(str(tmp_path / "missing.toml"))


def test_the_arm_file_and_the_model_record_it(tmp_path):
    arm = ArmParams.nominal("none")
    save_arm(arm, tmp_path / "arm.msgpack")
    back = load_arm(tmp_path / "arm.msgpack")
    assert back.end_effector == "none" and back.crc32 == arm.crc32
    record = arm_record(back, tmp_path / "arm.msgpack")
    assert record["end_effector"] == "none"
    # an arm without an end effector keeps the state (and CRC) of files from before it
    assert "end_effector" not in ArmParams.nominal().to_state()

    class Model:
        trained_arm = record

    with pytest.raises(ModelFileError, match=r"'none'.*'franka_hand'"):
        check_arm(Model(), None)


def test_a_mismatch_names_both():
    check_same("none", "none", "a", "b")
    check_same("", "franka_hand", "a", "b")  # files that record none: the hand
    with pytest.raises(InvalidInputError, match=r"the arm file .* 'none'.*declares 'franka_hand'"):
        check_same("none", "franka_hand", "the arm file x", "the configuration")
