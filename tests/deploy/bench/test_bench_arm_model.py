"""The benches, the demo and the simulated controller on another arm model (``--arm-model``):
the paper benchmark's quick run on the FR3, each bench's set-up made of the arm model given,
and the Panda's own recording refused on any other."""

import json

import numpy as np
import pytest

from deploy.cli import main
from iem.errors import InvalidInputError
from iem.factories import build
from sim.description import arm_description
from sim.robot import ArmModel

pytest.importorskip("mujoco")

GROUPS = ("mass", "com", "inertia")


@pytest.fixture(scope="module")
def fr3_quick(tmp_path_factory):
    pytest.importorskip("matplotlib")
    out = tmp_path_factory.mktemp("paper-fr3")
    assert main(["bench", "paper", "--quick", "--arm-model", "fr3", "--out", str(out)]) == 0
    return json.loads((out / "results.json").read_text())


@pytest.mark.slow  # as the Kinova's (test_second_arm.py): bench paper --quick on another arm
# model runs with -m slow only; the default suite runs it on the Panda (test_bench_paper.py)
# and checks every bench's set-up is the arm model's (below)
def test_bench_paper_quick_runs_on_the_fr3_and_records_it(fr3_quick):
    r = fr3_quick
    assert r["setup"]["arm_model"] == arm_description("fr3").record()
    assert r["setup"]["arm_model"]["digest"] != arm_description("panda").digest
    new = r["scenarios"]["new_path"]
    assert new["IEM+phys"]["mae_groups"]["mass"] < 0.01  # kg, on a 1.6 kg payload
    forget = r["scenarios"]["forgetting"]
    assert forget["IEM"]["weights_identical"] is True
    assert forget["old_IEM"]["weights_identical"] is False
    for g in GROUPS:
        assert forget["IEM"]["after"][g] <= 1.05 * forget["IEM"]["before"][g]
    assert forget["old_IEM"]["after"]["mass"] >= 2 * forget["old_IEM"]["before"]["mass"]


def test_the_bench_is_made_of_the_arm_model_it_is_given():
    """Kinematics, paths, plant and the dynamics LS and IEM+phys compute with are the FR3's:
    the dynamics spec gives the FR3's torques (pinocchio on its own file), not the Panda's."""
    from deploy.bench.harness import Bench

    fr3 = arm_description("fr3")
    bench = Bench(quick=True, description="fr3")
    assert bench.kin.description is fr3
    assert bench._plant_cls().description is fr3
    assert np.allclose(bench.excitation.q[0], fr3.home)
    assert np.allclose(bench.new_path.q[0], fr3.task[0])
    assert np.allclose(bench.new_path.q[-1], fr3.task[1])
    assert bench.excitation.first_violation(ArmModel(description=fr3)) is None
    q, dq, ddq = ArmModel(description=fr3).random_state(np.random.default_rng(3))
    tau = build(bench.dynamics, "test")(q, dq, ddq)[0]
    from sim.arm import ArmParams

    own = ArmModel(arm=ArmParams.nominal(None, fr3)).rnea(q, dq, ddq)
    panda = ArmModel(arm=ArmParams.nominal(None, "panda")).rnea(q, dq, ddq)
    assert np.allclose(tau, own, atol=1e-9)
    assert not np.allclose(tau, panda, atol=1e-3)


def test_the_demo_paths_and_cell_are_the_arm_models(tmp_path):
    from deploy.commands.demo import _demo_config, demo_path

    fr3 = arm_description("fr3")
    path, phases = demo_path(fr3)
    assert np.allclose(path.q[0], fr3.home) and np.allclose(path.q[-1], fr3.task[1])
    assert [p[0] for p in phases] == ["excitation", "transfer", "new task"]
    cfg = _demo_config(tmp_path / "m.msgpack", "IEM+phys", 0, None, False, -1, fr3)
    assert cfg.arm.model == "fr3" and cfg.gate.rated_mass_kg == fr3.rated_payload_kg
    # an arm model from a file gives no rated payload: refused without one, used with it
    urdf = tmp_path / "fr3.urdf"
    urdf.write_text(fr3.text)
    own = arm_description(str(urdf), fr3.flange)
    with pytest.raises(InvalidInputError, match="--rated-mass-kg"):
        _demo_config(tmp_path / "m.msgpack", "IEM+phys", 0, None, False, -1, own)
    cfg = _demo_config(tmp_path / "m.msgpack", "IEM+phys", 0, None, False, -1, own, 2.5)
    assert cfg.arm.model == str(urdf) and cfg.gate.rated_mass_kg == 2.5


def test_the_real_panda_recording_refuses_another_arm_model(tmp_path, capsys):
    out = tmp_path / "real"
    assert main(["bench", "real", "--arm-model", "fr3", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "iem: error:" in err and "'fr3'" in err and "--arm-model panda" in err
    assert not out.exists()
