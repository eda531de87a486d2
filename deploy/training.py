"""Making the initial model: bags and learners from the excitation path (``iem train``).

The tandem simulators of the configured training family (``paper``: the 77 payloads) give
the samples at every state of the planned excitation path (the built-in one, or a path CSV);
the model's ``fit`` forms the initial bags and trains their learners. The model kinds are
those of :data:`iem.persistence.MODELS` that can learn online (``IEM``, ``IEM+phys``).
"""

from __future__ import annotations

import importlib
import time

from iem.errors import InvalidInputError
from iem.persistence import MODELS, save_model

TRAINABLE = ("IEM", "IEM+phys")


def model_class(kind: str):
    if kind not in TRAINABLE or kind not in MODELS:
        valid = [k for k in TRAINABLE if k in MODELS]
        raise InvalidInputError(f"model kind {kind!r} cannot be trained here; valid kinds are "
                                f"{', '.join(valid)}")
    module, _, name = MODELS[kind].partition(":")
    return getattr(importlib.import_module(module), name)


def best_model_kind() -> str:
    """The most capable model this build has (``IEM+phys`` if present, else ``IEM``)."""
    return "IEM+phys" if "IEM+phys" in MODELS else "IEM"


def excitation(spec: str = "builtin"):
    """The excitation path: ``builtin`` (:func:`sim.paths.excitation_path`) or a CSV file."""
    from sim.paths import excitation_path, load_path_csv

    return excitation_path() if spec == "builtin" else load_path_csv(spec)


def tandem_for(family: str):
    from sim.family import family as family_payloads
    from sim.tandem import TandemSimulators

    return TandemSimulators(family_payloads(family))


def train_initial_model(kind: str = "IEM", family: str = "paper", excitation_spec="builtin",
                        seed: int = 0, log=print, **params):
    """A new model of ``kind`` trained on the excitation path with ``family``'s payloads."""
    from sim.robot import PandaModel

    cls = model_class(kind)
    path = excitation(excitation_spec)
    tandem = tandem_for(family)
    t0 = time.perf_counter()
    model = cls(seed=seed, **params)
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


def run(args) -> int:
    kind = args.kind or best_model_kind()
    model = train_initial_model(kind, args.family, args.excitation, args.seed)
    save_model(model, args.out)
    print(f"wrote {args.out}")
    return 0
