"""``iem demo``: the simulated Panda follows the new task path with the default test payload.

The controller starts without knowing the payload, so the tracking error shows what an
unidentified load does; halfway the true load is set (libfranka ``setLoad``), as the plug-in
will do once it has identified it, and the error drops.
"""

from __future__ import annotations

import time

import numpy as np


def configure(parser) -> None:
    parser.add_argument("--seed", type=int, default=0, help="sensor-noise seed")


def run(args) -> int:
    from sim.family import default_test_payload
    from sim.paths import new_task_path
    from sim.plant import PandaPlant

    payload = default_test_payload()
    path = new_task_path()
    plant = PandaPlant(payload=payload, seed=args.seed)
    plant.reset(path.q[0], path.dq[0])
    half = len(path) // 2
    print(f"payload {payload.name}: {payload.mass:.3f} kg, CoM {np.round(payload.com, 4)} m")
    print(f"path {path.name}: {path.duration:.1f} s at 1 kHz; controller load: none")
    window: list[float] = []
    t0 = time.perf_counter()
    for k in range(len(path)):
        if k == half:
            plant.set_controller_load(payload)
            print(f"t={k / 1000:5.2f} s  controller load set to the true payload")
        plant.step(path.q[k], path.dq[k], path.ddq[k])
        window.append(float(np.abs(path.q[k] - plant.last_q).max()))
        if (k + 1) % 500 == 0:
            print(f"t={(k + 1) / 1000:5.2f} s  tracking error max {max(window) * 1e3:7.3f} mrad "
                  f"(last 0.5 s)")
            window.clear()
    wall = time.perf_counter() - t0
    print(f"done: {path.duration:.1f} s simulated in {wall:.2f} s "
          f"({path.duration / wall:.1f}x real time)")
    return 0
