"""Making the initial model: bags and learners from the excitation path (``iem train``).

The tandem simulators of the configured training family (``paper``: the 77 payloads) give
the samples at every state of the planned excitation path (the built-in one, or a path CSV);
the model's ``fit`` forms the initial bags and trains their learners. The model kinds are
those of :data:`iem.persistence.MODELS` that can learn online (``IEM``, ``IEM+phys``).
"""

from __future__ import annotations

import time

from iem.errors import InvalidInputError
from iem.persistence import DEFAULT_MODEL, MODELS, new_model, save_model

TRAINABLE = ("IEM", "IEM+phys")


def best_model_kind() -> str:
    """The most capable model this build has (:data:`iem.persistence.DEFAULT_MODEL`)."""
    return DEFAULT_MODEL if DEFAULT_MODEL in TRAINABLE else "IEM"


def make_model(kind: str, seed: int = 0, rate_hz: float = 1000.0, **params):
    """A fresh model of ``kind`` for joint states at ``rate_hz``; ``params`` go to its IEM."""
    if kind not in TRAINABLE or kind not in MODELS:
        valid = [k for k in TRAINABLE if k in MODELS]
        raise InvalidInputError(f"model kind {kind!r} cannot be trained here; valid kinds are "
                                f"{', '.join(valid)}")
    if kind == "IEM+phys":  # the physics part filters at the link's rate; it holds an IEM
        return new_model(kind, ensemble={"seed": seed, **params}, rate_hz=rate_hz)
    return new_model(kind, seed=seed, **params)


def excitation(spec: str = "builtin"):
    """The excitation path: ``builtin`` (:func:`sim.paths.excitation_path`) or a CSV file."""
    from sim.paths import excitation_path, load_path_csv

    return excitation_path() if spec == "builtin" else load_path_csv(spec)


def tandem_for(family: str):
    from sim.family import family as family_payloads
    from sim.tandem import TandemSimulators

    return TandemSimulators(family_payloads(family))


def train_initial_model(kind: str = "IEM", family: str = "paper", excitation_spec="builtin",
                        seed: int = 0, log=print, rate_hz: float = 1000.0, **params):
    """A new model of ``kind`` trained on the excitation path with ``family``'s payloads,
    for joint states arriving at ``rate_hz`` (1000 on the fd profile, 500 on classic)."""
    from sim.robot import PandaModel

    model = make_model(kind, seed, rate_hz, **params)
    path = excitation(excitation_spec)
    tandem = tandem_for(family)
    t0 = time.perf_counter()
    model.fit(path.q, PandaModel().flange_positions(path.q),
              lambda i: tandem.samples(path.q[i], path.dq[i], path.ddq[i]))
    log(f"trained {kind} on {path.name!r} ({path.duration:.0f} s, {len(tandem)} training "
        f"payloads): {model.n_bags} bags in {time.perf_counter() - t0:.1f} s")
    return model


def configure(parser) -> None:
    parser.add_argument("--out", required=True, metavar="FILE", help="model file to write")
    parser.add_argument("--kind", default=None, choices=list(TRAINABLE),
                        help="model kind (default: the best available)")
    parser.add_argument("--family", default="paper", help="training payload family")
    parser.add_argument("--excitation", default="builtin", metavar="CSV",
                        help="excitation path CSV (default: the built-in 20 s path)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the learners")
    parser.add_argument("--rate", type=float, default=1000.0, metavar="HZ",
                        help="joint states per second the link delivers (fd 1000, classic 500)")


def run(args) -> int:
    kind = args.kind or best_model_kind()
    model = train_initial_model(kind, args.family, args.excitation, args.seed,
                                rate_hz=args.rate)
    save_model(model, args.out)
    print(f"wrote {args.out}")
    return 0
