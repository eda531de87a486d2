"""One recording's replay as a job of its own: picklable, so that a child process runs it
(:mod:`deploy.replay.many`), with the ``iem replay`` options it was given.

:func:`replay_one` replays a file as ``iem replay`` would with the command's ``args``
(:func:`replay_inputs`: the model and payload files, read once per process; :func:`replay_options`:
how to read and estimate), and gives the recording's entry, with any error it met.
"""

from __future__ import annotations

import os
import sys
import traceback
from pathlib import Path as FsPath

from deploy.options import arm_description_of

THREAD_LIMITS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
"""The thread pools a child process limits to one thread before NumPy loads."""


INPUTS: dict = {}
"""This process's ``(truth, model)`` of ``--truth`` and ``--model``, read once for all its
recordings (:func:`deploy.replay.core.replay` copies the model it is given), under the options
they were read with."""


def inputs_of(args) -> tuple:
    """``(truth, model)`` of ``args`` (:func:`replay_inputs`), read once."""
    key = repr(sorted(vars(args).items()))
    if key not in INPUTS:
        INPUTS.clear()
        INPUTS[key] = replay_inputs(args)
    return INPUTS[key]


def child_init() -> None:
    """A child's set-up: one thread per pool, before NumPy loads; Ctrl-C is the parent's."""
    import signal

    for name in THREAD_LIMITS:
        os.environ[name] = "1"
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def replay_one(args, file: str, out_csv: str | None, save_model: str | None) -> dict:
    """Replay ``file`` as ``iem replay`` would with ``args``: the recording's entry of
    ``--json`` (``file``, ``error``, ``final_phi``, ``summary``); its estimates written to
    ``out_csv`` and its learnt model to ``save_model`` if given. Any error costs this
    recording only: it is the entry's ``error`` (a bug's traceback goes to stderr)."""
    from iem.errors import IemError

    from .core import replay

    name = FsPath(file).name

    def log(msg: str) -> None:
        print(f"{name}: {msg}", file=sys.stderr, flush=True)

    try:
        truth, model = inputs_of(args)
        summary, estimates = replay(file, truth=truth, model=model, save_model_to=save_model,
                                    log=log, **replay_options(args))
        if out_csv:
            estimates.write_csv(out_csv)
    except IemError as exc:
        return {"file": file, "error": str(exc), "final_phi": None, "summary": None}
    except Exception as exc:  # a bug: it keeps its traceback, the other recordings go on
        traceback.print_exc()
        return {"file": file, "error": f"{type(exc).__name__}: {exc}", "final_phi": None,
                "summary": None}
    return {"file": file, "error": None, "final_phi": estimates.smoothed[-1].tolist(),
            "summary": summary}


def replay_inputs(args) -> tuple:
    """``(truth, model)`` that ``iem replay``'s ``--truth`` and ``--model`` name (None where
    not given), the model loaded with the arm it runs on (``--arm``, ``--end-effector``): a
    model file references its arm by content."""
    from iem.persistence import load_model
    from sim.payload import load_payload

    truth = load_payload(args.truth) if args.truth else None  # fail early on a bad file
    model = None
    if args.model:
        from deploy.model.training import load_arm_file

        arm, _ = load_arm_file(args.arm, args.end_effector, arm_description_of(args))
        model = load_model(args.model, resources={"arm": arm})
    return truth, model


def replay_options(args) -> dict:
    """The keyword arguments of :func:`~deploy.replay.core.replay` that ``iem replay``'s options
    give about how to read and estimate a recording (not its model, truth or outputs)."""
    from deploy.options import recording_options

    return {**recording_options(args), "arm_file": args.arm, "end_effector": args.end_effector,
            "block_frames": args.block_frames, "rate_hz": args.rate,
            "description": arm_description_of(args), "rated_mass_kg": args.rated_mass_kg}
