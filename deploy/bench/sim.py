"""``iem bench sim``: how fast the simulation parts are.

Prints medians over many calls: Pinocchio RNEA and payload regressor in µs per call, the
tandem simulators in µs per path point for the 77 training payloads, and the plant's
real-time factor at 1 kHz (simulated time / wall time, tracking the new task path with the
default test payload and the default sensor model). Targets: tandem <= 100 µs per point,
plant >= 10x real time. ``--json FILE`` writes the same figures.
"""

from __future__ import annotations

import json
import time
from pathlib import Path as FsPath

import numpy as np


def _median_us(fn, calls: int, repeats: int) -> float:
    """Median over ``repeats`` batches of the mean time per call, in µs."""
    per_call = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        per_call.append((time.perf_counter() - t0) / calls * 1e6)
    return float(np.median(per_call))


def measure(calls: int = 2000, repeats: int = 15, plant_seconds: float = 2.0,
            plant_repeats: int = 5, description=None) -> dict:
    """The figures on the arm model ``description`` (None: the default)."""
    from iem.extras import require
    from sim.family import default_test_payload, training_payloads
    from sim.paths import new_task_path

    require("mujoco", "iem bench sim (the plant's real-time factor)")
    from sim.plant import ArmPlant
    from sim.robot import ArmModel
    from sim.tandem import TandemSimulators

    model = ArmModel(description=description)
    rng = np.random.default_rng(0)
    states = [model.random_state(rng) for _ in range(64)]
    it = iter(range(1 << 62))

    def state():
        return states[next(it) % len(states)]

    rnea_us = _median_us(lambda: model.rnea(*state()), calls, repeats)
    regressor_us = _median_us(lambda: model.payload_regressor(*state()), calls, repeats)
    tandem = TandemSimulators(training_payloads(), model=ArmModel(description=description))
    tandem_us = _median_us(lambda: tandem.samples(*state()), calls, repeats)

    path = new_task_path(model=model)
    n = min(len(path), int(plant_seconds * 1000))
    factors = []
    plant = ArmPlant(payload=default_test_payload(), seed=0, description=description)
    for _ in range(plant_repeats):
        plant.reset(path.q[0], path.dq[0])
        t0 = time.perf_counter()
        for k in range(n):
            plant.step(path.q[k], path.dq[k], path.ddq[k])
        factors.append(n * 1e-3 / (time.perf_counter() - t0))
    return {
        "rnea_us": rnea_us,
        "regressor_us": regressor_us,
        "tandem_us_per_point": tandem_us,
        "tandem_payloads": len(tandem),
        "plant_realtime_factor": float(np.median(factors)),
    }


def configure(parser) -> None:
    from deploy.options import add_arm_model

    parser.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    parser.add_argument("--calls", type=int, default=2000, help="calls per timing batch")
    add_arm_model(parser)


def run(args) -> int:
    from deploy.options import arm_description_of

    figures = measure(calls=args.calls, description=arm_description_of(args))
    print(f"RNEA                 {figures['rnea_us']:8.2f} µs/call")
    print(f"payload regressor    {figures['regressor_us']:8.2f} µs/call")
    print(f"tandem ({figures['tandem_payloads']} payloads) {figures['tandem_us_per_point']:8.2f} "
          "µs/point   (target <= 100)")
    print(f"plant at 1 kHz       {figures['plant_realtime_factor']:8.1f} x real time "
          "(target >= 10)")
    if args.json:
        FsPath(args.json).write_text(json.dumps(figures, indent=2) + "\n")
    return 0
