"""What motion would settle an uncertain payload: while the data do not determine the CoM,
the estimate names the joint move that would (iem.physics.advice), the gate's reason says
it, and making that move determines the CoM."""

import numpy as np
import pytest

from deploy.bench.realistic import tools
from iem.online import OnlineIdentifier
from iem.persistence import load_model
from iem.signals.blocks import BlockFormer
from sim.paths import Q0, linear_path
from sim.plant import ArmPlant
from sim.robot import ArmModel
from sim.tandem import TandemSimulators

pytest.importorskip("mujoco")

TOOL = tools()["light_tool"]  # 0.4 kg, its CoM 1 cm off the flange axis


def _estimates(model, path):
    """The model's estimates along ``path`` with the light tool on the ideal plant."""
    from sim.family import family

    kin = ArmModel()
    r = ArmPlant(payload=TOOL, seed=3, controller_load=TOOL).follow(path)
    online = OnlineIdentifier(model, kin.flange_position,
                              TandemSimulators(family("cell"), model=kin).samples)
    blocks = BlockFormer().push_many(r.t, r.features, np.arange(len(r)))
    return [online.step_block(blocks.state(k))[0] for k in range(len(blocks))]


def _about_joint_1():
    """Joint 1 alone, slowly there and back: the gravity's direction in the flange frame
    never changes, so the CoM along it is never seen."""
    q1 = np.array(Q0)
    q1[0] += 0.4
    return linear_path(Q0, q1, 4.0).then(linear_path(q1, Q0, 4.0))


def test_the_estimate_and_the_gate_say_what_move_settles_the_com(trained_phys_model_file):
    from deploy.writeback.checks import model_doubt
    from deploy.writeback.settings import GateConfig

    model = load_model(trained_phys_model_file)
    path = _about_joint_1()
    est = _estimates(model, path)[-1]
    assert "com" not in est.determined
    advice = est.extra["settle"]
    assert advice.startswith("the CoM along") and "move joint" in advice, advice
    reason, detail = model_doubt(est, GateConfig())
    assert reason == "uncertain" and advice in detail
    # the advised move, made after the same motion, determines the CoM
    j = int(advice.split("move joint ")[1].split()[0]) - 1
    amount = float(advice.split(" by ")[1].split()[0])
    q = np.array(path.q[-1])
    q2 = q.copy()
    q2[j] += amount
    more = path.then(linear_path(q, q2, 2.0)).then(linear_path(q2, q, 2.0))
    model = load_model(trained_phys_model_file)
    after = _estimates(model, more)[-1]
    assert "com" in after.determined and "settle" not in after.extra
