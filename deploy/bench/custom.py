"""``iem bench custom``: the paper benchmark's models on any payload file and path file.

The models are trained as in ``iem bench paper`` (offline on the excitation path, the 77
training payloads); then the plant carries the given payload along the given path (CSV,
see :func:`sim.paths.load_path_csv`) and every model runs it learning as it goes, as in the
``new_path`` scenario. ``DIR/results.json`` has the paper benchmark's schema with the
scenario ``custom``: ``{MODEL: {"mae", "mae_groups", "convergence_s", "mae_groups_raw",
"coverage_2sigma", ...}}`` (as ``new_path``; IEM+phys included).
"""

from __future__ import annotations

import json
import time
from pathlib import Path as FsPath

from deploy.options import add_arm_model, arm_description_of
from iem.types import PARAMS

from .harness import Bench


def run_custom(payload_file, path_file, out_dir, quick: bool = False, seed: int = 0,
               log=print, extra_models: dict | None = None, description=None) -> dict:
    """The paper benchmark's models on the arm model ``description`` (None: the default),
    trained on its excitation path, then along the path of ``path_file`` (checked against
    the arm model's limits) with the payload of ``payload_file``."""
    from sim.paths import load_path_csv
    from sim.payload import load_payload

    started = time.perf_counter()
    payload = load_payload(payload_file)
    bench = Bench(quick=quick, seed=seed, log=log, description=description)
    path = load_path_csv(path_file).check_limits(bench.kin)
    out_dir = FsPath(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    models = bench.trained_models(extra_models)
    bags_before = models["IEM"].n_bags
    rollout = bench.rollout(path, payload, seed + 2)
    phi = payload.to_phi()
    scen = {}
    for name, model in models.items():
        scen[name] = bench.scores(bench.run(model, rollout, learn=True), phi, convergence=True,
                                  model=model)
        g = scen[name]["mae_groups"]
        log(f"custom {name:8s} mass {g['mass']:.4g}  com {g['com']:.4g}  "
            f"inertia {g['inertia']:.4g}  converged {scen[name]['convergence_s']}")
    results = {
        "params": list(PARAMS), "models": list(models), "scenarios": {"custom": scen},
        "bags": {"after_excitation": bags_before, "after_custom": models["IEM"].n_bags},
        "setup": {"quick": quick, "seed": seed, "arm_model": bench.description.record(),
                  "payload": payload.name,
                  "payload_file": str(payload_file), "path_file": str(path_file),
                  "path_s": path.duration, "phi": phi.tolist(),
                  "wall_s": time.perf_counter() - started},
    }
    (out_dir / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    log(f"wrote {out_dir / 'results.json'}")
    return results


def configure(parser) -> None:
    parser.add_argument("--payload", required=True, metavar="FILE", help="payload TOML file")
    parser.add_argument("--path", required=True, metavar="FILE",
                        help="path CSV: t,q1..q7 (s, rad), at least 100 Hz")
    parser.add_argument("--out", required=True, metavar="DIR", help="folder for the results")
    parser.add_argument("--quick", action="store_true", help="smaller training")
    parser.add_argument("--seed", type=int, default=0, help="seed of noise and learners")
    add_arm_model(parser)


def run(args) -> int:
    run_custom(args.payload, args.path, args.out, quick=args.quick, seed=args.seed,
               description=arm_description_of(args))
    return 0
