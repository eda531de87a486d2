"""``iem demo``: the simulated Panda identifies its payload online and writes it back.

The best model available (:data:`iem.persistence.DEFAULT_MODEL`, IEM+phys, or the one named
with ``--model``) is trained on the excitation path with the tandem simulators, as the
plug-in would be before its first task. Then the arm follows the new task path with the
default test payload; the controller starts without knowing it. Every half second the demo
prints the estimate with its standard deviation and the tracking error; at 2 s it writes the
estimate to the controller (libfranka ``setLoad`` semantics) and the error drops. At 3.5 s
the payload is swapped for a heavier one without telling anyone; a model with a change
detector reports it, and at 5 s the demo writes the new estimate.
"""

from __future__ import annotations

import time

import numpy as np

SWAP_TO = "test-4w"
WRITE_AT = (2000, 5000)
"""Samples at which the current estimate is written to the controller."""
SWAP_AT = 3500
"""Sample at which the payload is swapped."""


def configure(parser) -> None:
    from iem.persistence import DEFAULT_MODEL, MODELS

    parser.add_argument("--seed", type=int, default=0, help="sensor-noise and model seed")
    parser.add_argument("--model", default=DEFAULT_MODEL, choices=sorted(MODELS),
                        help=f"the estimator to run (default {DEFAULT_MODEL}, the best one)")


def _make(kind: str, seed: int):
    from iem.persistence import new_model

    small = {"seed": seed, "fit_epochs": 4, "fit_stride": 20}
    if kind == "IEM+phys":
        return new_model(kind, ensemble=small)
    if kind in ("IEM", "old_IEM"):
        return new_model(kind, **small)
    if kind == "BEM":
        return new_model(kind, seed=seed, fit_epochs=4, fit_stride=40)
    return new_model(kind)


def run(args) -> int:
    from iem.online import OnlineIdentifier
    from sim.family import default_test_payload, test_payloads, training_payloads
    from sim.paths import excitation_path, new_task_path
    from sim.payload import Payload
    from sim.plant import PandaPlant
    from sim.robot import PandaModel
    from sim.tandem import TandemSimulators

    t0 = time.perf_counter()
    kin = PandaModel()
    tandem = TandemSimulators(training_payloads(), model=PandaModel())
    model = _make(args.model, args.seed)
    if hasattr(model, "fit"):
        exc = excitation_path()
        model.fit(exc.q, kin.flange_positions(exc.q),
                  lambda i: tandem.samples(exc.q[i], exc.dq[i], exc.ddq[i]))
    print(f"model {model.name}: trained on the excitation path, {model.n_bags} bags "
          f"({time.perf_counter() - t0:.1f} s)")

    payload, swapped = default_test_payload(), test_payloads()[SWAP_TO]
    path = new_task_path()
    plant = PandaPlant(payload=payload, seed=args.seed)
    plant.reset(path.q[0], path.dq[0])
    online = OnlineIdentifier(model, kin.flange_position, tandem.samples)
    print(f"payload {payload.name}: {payload.mass:.3f} kg; path {path.name}: "
          f"{path.duration:.1f} s at 1 kHz; controller load: none")
    window: list[float] = []
    t1 = time.perf_counter()
    for k in range(len(path)):
        if k == SWAP_AT:
            plant.set_payload(swapped)
            payload = swapped
            print(f"t={k / 1000:5.2f} s  payload swapped for {swapped.name} "
                  f"({swapped.mass:.3f} kg); nobody is told")
        state = plant.step(path.q[k], path.dq[k], path.ddq[k])
        est, smoothed = online.step(state)
        window.append(float(np.abs(path.q[k] - plant.last_q).max()))
        if est.extra.get("change"):
            print(f"t={k / 1000:5.2f} s  payload change detected")
        if k in WRITE_AT:
            phi = est.phi if est.std is not None else smoothed
            try:
                load = Payload.from_phi(phi, name="estimate").check()
            except Exception as exc:  # an inconsistent estimate must not reach the robot
                print(f"t={k / 1000:5.2f} s  estimate not written: {exc}")
            else:
                plant.set_controller_load(load)
                print(f"t={k / 1000:5.2f} s  setLoad({load.mass:.4f} kg, CoM "
                      f"{np.round(load.com, 4).tolist()} m)")
        if (k + 1) % 500 == 0:
            phi = est.phi if est.std is not None else smoothed
            sd = "" if est.std is None else f" ± {est.std[0]:.4f}"
            print(f"t={(k + 1) / 1000:5.2f} s  mass {phi[0]:.4f}{sd} kg (true "
                  f"{payload.mass:.4f})  tracking error max {max(window) * 1e3:7.3f} mrad")
            window.clear()
    wall = time.perf_counter() - t1
    print(f"done: {path.duration:.1f} s simulated and identified in {wall:.2f} s "
          f"({path.duration / wall:.1f}x real time)")
    return 0
