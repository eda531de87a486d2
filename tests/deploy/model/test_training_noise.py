"""The equations' error a cell trains IEM+phys with when nothing says otherwise: the arm's own
noise when it was calibrated (an arm file), the sensor's without one (the error the model's
data test can then judge)."""

import pytest

from deploy.config import ConfigError, config_from_dict
from deploy.model.training import NOISE_CHOICES, noise_for
from iem.errors import InvalidInputError


def test_auto_is_the_arm_files_noise_with_one_and_the_sensors_without():
    assert noise_for("auto", None) == noise_for("auto", "") == "sensor"
    assert noise_for("auto", "/var/lib/iem/arm.msgpack") == "arm"
    assert noise_for("arm", None) == "arm" and noise_for("sensor", "arm.msgpack") == "sensor"
    with pytest.raises(InvalidInputError, match="valid are auto, arm, sensor"):
        noise_for("white", None)


def test_the_default_configuration_and_iem_train_choose_auto():
    import argparse

    from deploy.commands import train

    assert config_from_dict({}).arm.noise == "auto" and "auto" in NOISE_CHOICES
    parser = argparse.ArgumentParser()
    train.configure(parser)
    assert parser.parse_args(["--out", "m.msgpack"]).noise is None  # auto, as run() reads it
    assert parser.parse_args(["--out", "m.msgpack", "--noise", "auto"]).noise == "auto"
    with pytest.raises(ConfigError, match="noise"):
        config_from_dict({"arm": {"noise": "white"}})
