"""``iem train --learner``: the learner a model's bags are trained with, recorded in its file."""

from __future__ import annotations

import pytest

from deploy.cli import main
from iem.persistence import load_model


def test_train_learner_is_recorded(tmp_path, capsys):
    """Without ``--learner`` the kind says it: test_excite_cli.py's ``iem train --path``
    trains IEM+phys so and checks its learner ("expected"), which a second training here
    would repeat."""
    sgd = tmp_path / "sgd.msgpack"
    assert main(["train", "--learner", "sgd", "--noise", "sensor", "--out", str(sgd)]) == 0
    model = load_model(sgd)
    assert model.params()["ensemble"]["learner"] == "sgd"
    assert model._ens.learner_kind == "sgd"


def test_train_refuses_a_learner_it_does_not_know(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["train", "--learner", "adam", "--out", str(tmp_path / "m.msgpack")])
    assert exit_.value.code == 2
    assert "invalid choice: 'adam' (choose from 'sgd', 'expected')" in capsys.readouterr().err
