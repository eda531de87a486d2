"""The pick-and-place of ``iem bench fci``: where the arm goes and what it carries.

The arm starts at the FR3's home, moves to the pick pose bare, and then for each payload:
grasps it (the scene mounts it on the flange), carries it to the place pose, releases it (the
scene removes it) and goes back to pick bare. Every payload change (a grasp, a release) is
followed by one motion, the one that *carries the change*, of at least :data:`MOTION_S` s.

The poses are the FR3's task path's ends (:attr:`sim.description.ArmDescription.task`), which
the calibration motion and the excitation path never reach: every motion is new to the
model. The payloads are files of ``sim/payloads``: test-3w (1.615 kg, the paper's container
with three weights), light-tool (0.6 kg off the flange axis) and test-2w (1.34 kg); with the
Franka Hand (0.73 kg) each stays within the FR3's 3 kg.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path as FsPath

import numpy as np

MOTION_S = 3.0
"""Each motion of the robot's own program lasts this long, s (minimum-jerk, at rest at both
ends)."""
SETTLE_S = 1.0
"""Rest after a motion before the hand grasps or releases, s of the robot's time."""
HOLD_S = 0.5
"""Rest after a grasp or a release before the next motion, s."""
START_S = 2.0
END_S = 3.0
"""Rest before the first motion and after the last, s."""
PAYLOADS = ("test-3w", "light-tool", "test-2w")


@dataclass(frozen=True)
class Step:
    """One step of the program: ``"move"`` to ``target`` (rad), ``"grasp"`` the next payload,
    ``"release"`` it, or ``"rest"`` for ``seconds``."""

    kind: str
    target: tuple[float, ...] | None = None
    seconds: float = 0.0


def poses(description=None) -> dict[str, np.ndarray]:
    """``home``, ``pick`` and ``place`` of the arm model (the FR3's by default)."""
    from sim.description import arm_description

    desc = arm_description(description or "fr3")
    return {"home": np.array(desc.home), "pick": np.array(desc.task[0]),
            "place": np.array(desc.task[1])}


def payload_files(names=PAYLOADS) -> list[FsPath]:
    """The payload files of ``names`` in ``sim/payloads``."""
    import sim

    folder = FsPath(sim.__file__).parent / "payloads"
    return [folder / f"{n}.toml" for n in names]


def steps(n_payloads: int = len(PAYLOADS), description=None) -> list[Step]:
    """The program (see the module docstring)."""
    p = poses(description)
    pick, place = tuple(p["pick"]), tuple(p["place"])
    out = [Step("rest", seconds=START_S), Step("move", pick)]
    for _ in range(n_payloads):
        out += [Step("rest", seconds=SETTLE_S), Step("grasp"), Step("rest", seconds=HOLD_S),
                Step("move", place), Step("rest", seconds=SETTLE_S), Step("release"),
                Step("rest", seconds=HOLD_S), Step("move", pick)]
    out.append(Step("rest", seconds=END_S))
    return out
