"""``--arm-model`` on the command line: a description the plug-in cannot use ends in one line
``iem: error: ...`` naming what is wrong, status 2, and nothing written; one whose meshes do
not resolve is used; an arm file of another arm model is refused, naming both."""

from __future__ import annotations

import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from deploy.cli import main
from sim.arm import ArmParams, save_arm
from sim.description import arm_description

REPO = Path(__file__).resolve().parents[2]


def fr3_text(edit=None) -> str:
    """The FR3's description (its ``fr3_`` names), changed by ``edit`` on its XML tree."""
    root = ET.fromstring(arm_description("fr3").text)
    if edit is not None:
        edit(root)
    return ET.tostring(root, encoding="unicode")


def element(root: ET.Element, tag: str, name: str) -> ET.Element:
    return next(el for el in root.findall(tag) if el.get("name") == name)


def branch_below_link7(root):
    """A second fixed child of the last arm link: two leaves, no flange named."""
    ET.SubElement(root, "link", name="fr3_camera")
    joint = ET.SubElement(root, "joint", name="fr3_camera_joint", type="fixed")
    ET.SubElement(joint, "parent", link="fr3_link7")
    ET.SubElement(joint, "child", link="fr3_camera")


def joint_off_link3(root):
    """A movable joint hanging off link 3, before the flange: a tree, not a chain."""
    extra = ET.SubElement(root, "link", name="fr3_extra")
    inertial = ET.SubElement(extra, "inertial")
    ET.SubElement(inertial, "mass", value="0.5")
    ET.SubElement(inertial, "inertia", ixx="1e-3", ixy="0", ixz="0", iyy="1e-3", iyz="0",
                  izz="1e-3")
    joint = ET.SubElement(root, "joint", name="fr3_extra_joint", type="revolute")
    ET.SubElement(joint, "parent", link="fr3_link3")
    ET.SubElement(joint, "child", link="fr3_extra")
    ET.SubElement(joint, "axis", xyz="0 0 1")
    ET.SubElement(joint, "limit", lower="-1", upper="1", velocity="1", effort="10")


def no_inertial_on_link4(root):
    link = element(root, "link", "fr3_link4")
    link.remove(link.find("inertial"))


def joint7_fixed(root):
    element(root, "joint", "fr3_joint7").set("type", "fixed")


BAD_FILES = {
    # name: (file contents, --arm-flange, what the message must name)
    "branching": (lambda: fr3_text(branch_below_link7), None,
                  ("no flange", "'fr3_link7'", "fr3_camera", "--arm-flange")),
    "not-a-chain": (lambda: fr3_text(joint_off_link3), "fr3_link8",
                    ("not a chain", "'fr3_extra_joint'", "'fr3_link3'", "'fr3_link8'")),
    "two-ends": (lambda: fr3_text(joint_off_link3), None,
                 ("no flange", "end in 2 places", "fr3_extra_joint", "--arm-flange")),
    "no-inertial": (lambda: fr3_text(no_inertial_on_link4), None,
                    ("'fr3_link4'", "'fr3_joint4'", "<inertial>")),
    "six-joints": (lambda: fr3_text(joint7_fixed), None,
                   ("moves 6 joints", "7 revolute joints")),
    "not-xml": (lambda: "this is <not xml", None, ("not readable XML",)),
    "empty": (lambda: "", None, ("not readable XML",)),
    "not-urdf": (lambda: "<sdf version='1.7'/>", None, ("root element is <robot>", "<sdf>")),
    "no-such-flange": (lambda: fr3_text(), "nosuchlink", ("no flange", "'nosuchlink'")),
}


def run_iem(capsys, *argv: str) -> tuple[int, str]:
    status = main(list(argv))
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return status, err


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_train_refuses_a_bad_description_before_training(case, tmp_path, capsys):
    make, flange, names = BAD_FILES[case]
    arm = tmp_path / f"{case}.urdf"
    arm.write_text(make(), encoding="utf-8")
    out = tmp_path / "model.msgpack"
    status, err = run_iem(capsys, "train", "--arm-model", str(arm), "--out", str(out),
                          *(["--arm-flange", flange] if flange else []))
    assert status == 2
    assert err.startswith(f"iem: error: arm model {arm}: "), err
    assert err.count("\n") == 1, err
    for name in names:
        assert name in err, (name, err)
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [arm.name]


@pytest.mark.parametrize("argv, names", [
    (["--arm-model", "{tmp}/missing.urdf"], ("missing.urdf", "cannot read the URDF file: it "
                                              "does not exist")),
    (["--arm-model", "{tmp}/latin1.urdf"], ("latin1.urdf", "not UTF-8 text")),
    (["--arm-model", "ur5"], ("'ur5' is not valid", "'panda', 'fr3'", ".urdf")),
])
def test_train_refuses_an_arm_model_it_cannot_read(argv, names, tmp_path, capsys):
    (tmp_path / "latin1.urdf").write_bytes(b"<robot name='b\xe9cher'/>")
    out = tmp_path / "model.msgpack"
    status, err = run_iem(capsys, "train", *(a.format(tmp=tmp_path) for a in argv),
                          "--out", str(out))
    assert status == 2
    assert err.startswith("iem: error: arm model "), err
    for name in names:
        assert name in err, (name, err)
    assert not out.exists()


def test_the_installed_command_exits_2_on_a_bad_description(tmp_path):
    arm = tmp_path / "six.urdf"
    arm.write_text(fr3_text(joint7_fixed), encoding="utf-8")
    out = tmp_path / "model.msgpack"
    done = subprocess.run([sys.executable, "-m", "deploy.cli", "train", "--arm-model", str(arm),
                           "--out", str(out)], cwd=REPO, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 2
    assert done.stderr.startswith(f"iem: error: arm model {arm}: the way from")
    assert "moves 6 joints" in done.stderr
    assert not out.exists()


def test_a_mesh_path_that_does_not_resolve_is_no_error(tmp_path, capsys):
    def add_visual(root):
        visual = ET.SubElement(element(root, "link", "fr3_link2"), "visual")
        ET.SubElement(ET.SubElement(visual, "geometry"), "mesh",
                      filename="package://nowhere/x.stl")

    arm = tmp_path / "meshes.urdf"
    arm.write_text(fr3_text(add_visual), encoding="utf-8")
    out = tmp_path / "model.msgpack"
    # the description is read first; the missing excitation CSV then stops the training
    status, err = run_iem(capsys, "train", "--arm-model", str(arm), "--excitation",
                          str(tmp_path / "none.csv"), "--out", str(out))
    assert status == 2
    assert err.startswith("iem: error: ") and "none.csv" in err, err
    assert "arm model" not in err and "nowhere" not in err
    assert arm_description(str(arm)).digest == arm_description("fr3").digest


def test_an_arm_file_of_another_arm_model_is_refused_naming_both(tmp_path, capsys):
    arm = tmp_path / "fr3-arm.msgpack"
    save_arm(ArmParams.nominal(None, "fr3"), arm)
    out = tmp_path / "model.msgpack"
    status, err = run_iem(capsys, "train", "--arm", str(arm), "--out", str(out))
    assert status == 2
    assert err.startswith("iem: error: arm model mismatch: the arm file fr3-arm.msgpack"), err
    assert "'fr3'" in err and "'panda'" in err
    assert not out.exists()
    # given its own arm model, the arm file passes (the missing excitation CSV stops it)
    status, err = run_iem(capsys, "train", "--arm", str(arm), "--arm-model", "fr3",
                          "--excitation", str(tmp_path / "none.csv"), "--out", str(out))
    assert status == 2 and "none.csv" in err and "mismatch" not in err, err
    assert not out.exists()
