"""``[ros2]`` in cell.toml: defaults, the opener's options, and clear errors."""

from __future__ import annotations

import pytest

from deploy.config import ConfigError, config_from_dict, load_config
from deploy.model.setup import link_rate


def test_defaults_and_the_options_the_opener_gets():
    cfg = config_from_dict({"link": {"kind": "ros2"}})
    assert cfg.link.channel == "/franka/joint_states"  # the default topic
    assert link_rate(cfg) == 1000.0
    opts = cfg.link_options()
    # "auto": the arm model's joint names and flange (the Panda's by default)
    panda = tuple(f"panda_joint{i}" for i in range(1, 8))
    assert opts == {"domain_id": None, "joints": list(panda), "estimate_topic": "/iem/payload",
                    "estimate_std_topic": "", "estimate_rate_hz": 10.0,
                    "set_load_service": "/service_server/set_load",
                    "set_load_timeout_s": 2.0, "flange_frame": "panda_link8", "interface": "",
                    "robot_state_topic": "/franka_robot_state_broadcaster/robot_state",
                    "diagnostics_topic": "/diagnostics", "peers": []}
    fr3 = config_from_dict({"link": {"kind": "ros2"}, "ros2": {"joints": "fr3"}})
    assert fr3.arm.model == "fr3" and fr3.link_options()["flange_frame"] == "fr3_link8"
    assert config_from_dict({"link": {"kind": "socketcan", "channel": "can0"},
                             "ros2": {"domain_id": 3}}).link_options() == {}
    cfg = config_from_dict({"link": {"kind": "ros2", "channel": "/left/franka/joint_states"},
                            "ros2": {"domain_id": 7, "joints": [f"l_j{i}" for i in range(7)],
                                     "interface": "eth1", "peers": ["10.0.0.2"]}})
    opts = cfg.link_options()
    assert opts["domain_id"] == 7 and opts["joints"] == [f"l_j{i}" for i in range(7)]
    assert opts["interface"] == "eth1" and opts["peers"] == ["10.0.0.2"]


def test_the_example_cell_toml_documents_every_ros2_key():
    from dataclasses import fields
    from pathlib import Path

    from deploy.config import Ros2Config

    text = (Path(__file__).resolve().parents[3] / "deploy" / "cell.toml").read_text()
    assert "[ros2]" in text
    for f in fields(Ros2Config):
        assert f"# {f.name}:" in text, f.name
    cfg = load_config(Path(__file__).resolve().parents[3] / "deploy" / "cell.toml")
    assert cfg.ros2 == Ros2Config()  # the example sets every key to its default


@pytest.mark.parametrize(("doc", "message"), [
    ({"ros2": {"domain_id": 233}}, r"domain_id = 233 is out of range; valid is an integer "
                                   r"from -1 to 232"),
    ({"ros2": {"domain_id": "0"}}, "must be an integer"),
    ({"ros2": {"estimate_topic": "iem/payload"}}, "not a fully qualified ROS 2 name"),
    ({"ros2": {"set_load_service": "/service_server/"}}, "not a fully qualified ROS 2 name"),
    ({"ros2": {"estimate_std_topic": "/1x"}}, "not a fully qualified ROS 2 name"),
    ({"ros2": {"estimate_rate_hz": 0}}, r"estimate_rate_hz = 0.0 is out of range"),
    ({"ros2": {"set_load_timeout_s": 5.0}}, r"valid is \[0.05, 4\]"),
    ({"ros2": {"joints": "ur5"}}, "valid values are 'auto', 'fr3', 'panda'"),
    ({"ros2": {"joints": ["a", "b"]}}, "list of 7 distinct non-empty strings"),
    ({"ros2": {"joints": ["a"] * 7}}, "list of 7 distinct non-empty strings"),
    ({"ros2": {"set_load_service": ""}}, "must be a non-empty string"),
    ({"ros2": {"peers": "127.0.0.1"}}, "must be a list of non-empty strings"),
    ({"ros2": {"topic": "/x"}}, r"unknown key\(s\) \['topic'\] in \[ros2\]"),
    ({"link": {"kind": "ros2", "channel": "can0"}},
     r"\[link\] channel = 'can0' is not a fully qualified ROS 2 name.*JointState topic"),
])
def test_bad_ros2_keys_are_clear_errors(doc, message):
    with pytest.raises(ConfigError, match=message):
        config_from_dict(doc)
