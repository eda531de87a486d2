"""``iem excite``: a path CSV within the arm model's limits that the path readers take, its
design's figures, and clear errors for a bad start pose."""

import json

import numpy as np

from deploy.cli import main
from sim.paths import load_path_csv
from sim.robot import ArmModel


def test_writes_a_motion_the_path_readers_take(tmp_path, capsys):
    out, figures = tmp_path / "excite.csv", tmp_path / "excite.json"
    assert main(["excite", "--seconds", "4", "--out", str(out), "--restarts", "1",
                 "--arm-model", "fr3", "--json", str(figures)]) == 0
    printed = capsys.readouterr().out
    assert "condition number" in printed and "of the limits" in printed
    model = ArmModel(description="fr3")
    path = load_path_csv(out, model=model)  # what sim-controller --arm-model fr3 --path reads
    assert path.duration == 4.0
    np.testing.assert_allclose(path.q[0], model.description.home, atol=1e-6)
    report = json.loads(figures.read_text())
    assert report["arm_model"] == "fr3" and 1.0 < report["condition"] < 1000.0
    assert max(np.array(report["dq_peak"]) / np.array(report["dq_max"])) <= 0.75 + 1e-9


def test_iem_train_path_trains_on_the_motion(tmp_path, capsys):
    """``iem train --path`` (also ``--excitation``) takes the CSV ``iem excite`` wrote; without
    ``--learner`` the kind's own learner trains the bags (IEM+phys's: "expected"; the learner
    given is recorded: test_train.py)."""
    from iem.persistence import load_model

    out, model = tmp_path / "excite.csv", tmp_path / "model.msgpack"
    assert main(["excite", "--seconds", "4", "--out", str(out), "--restarts", "1"]) == 0
    capsys.readouterr()
    assert main(["train", "--path", str(out), "--out", str(model), "--family", "paper"]) == 0
    assert "trained IEM+phys on 'excite' (4 s" in capsys.readouterr().out and model.exists()
    assert load_model(model)._ens.learner_kind == "expected"


def test_a_bad_start_pose_is_an_error_naming_the_joint(tmp_path, capsys):
    out = tmp_path / "x.csv"
    assert main(["excite", "--seconds", "4", "--out", str(out),
                 "--start", "0,0,0,9,0,0,0"]) == 2
    err = capsys.readouterr().err
    assert "joint 4 is 9 rad" in err and "strictly between" in err
    assert main(["excite", "--seconds", "4", "--out", str(out), "--start", "0,a"]) == 2
    assert "7 joint angles in rad" in capsys.readouterr().err
    assert not out.exists()
