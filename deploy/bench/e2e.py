"""``iem bench e2e``: the plug-in against the simulated controller at 1 kHz, end to end.

The simulated controller (the arm model's MuJoCo plant, the Panda by default; the default
test payload) plays the excitation path back
and forth in real time on python-can's virtual bus, in a thread of this process; the plug-in
service (the best available model, trained on the excitation path first) runs against it
for ``--seconds`` (default 60) and writes loads back through the safety gate.

The service reads every 1 kHz frame and estimates once per block point (the means of 10
frames, :mod:`iem.signals.blocks`). Printed: block points estimated and cycles lost (gaps in the
cycle counter), the block-to-estimate latency (from the arrival of a block's last frame to
its estimate, p50/p99) and the age of the block's frames (their mean arrival) when its
estimate is out, the CPU share of the plug-in (the CPU time of its threads over the wall
time: 1.0 is one whole core; ``cpu_share_parts`` splits it into the estimating loop, the
link reader, the learning worker and the checkpoints; the simulated controller's thread is
not counted), peak resident memory of the process (controller and plug-in together), the
controller's missed deadlines, and the estimator's step (its part of the loop's CPU) a point
live beside the same steps again back to back: once the run is over and the controller
stopped, a copy of the model as it was before the run steps through the run's own block
points in this thread without a pause. The back-to-back figure is the code's own cost; what
the live one adds is the price of each point starting after the thread slept (the caches it
finds cold, :mod:`deploy.service.host`) and of what runs beside it. Targets: no lost cycles,
block-to-estimate p99 ≤ 2 ms, at most 0.10 of one core (0.12 with ``--link slcan-pty``).
``--json FILE`` writes ``{"cycles", "lost", "latency_us": {"p50", "p99"}, "age_us": {"p50",
"p99"}, "cpu_share", "cpu_share_parts", "peak_rss_mb", "cpu_dma_latency_us", "step_cpu_us": {"live",
"back_to_back", "points"}, ...}`` (``cycles``: block points; ``step_cpu_us``: µs of CPU a
point; ``machine_us``: :func:`deploy.bench.timing.machine_speed` just before and just after
the run, ``{"before": {"cpu_us", "wall_us"}, "after": ...}``, µs a round of a fixed work:
the host's own speed, printed beside the share; ``cpu_share_rounds``: the share in such
rounds a second, which a slower host leaves as it was and slower code raises).
``--cpu-dma-latency-us US`` holds a CPU wake-up latency limit during the run, as ``[host]
cpu_dma_latency_us`` does for the service (:mod:`deploy.service.host`; the JSON's
``cpu_dma_latency_us`` is the limit held, null for none): the idle cores then poll, and
their CPU is not in ``cpu_share``.

The controller shares the interpreter (:mod:`deploy.simcell.inprocess`), so each frame also
waits for the controller thread's own work.
``--link slcan-pty`` runs the controller in its own process instead, as a cell has it, as
an slcan adapter on a pty that the plug-in opens with python-can's slcan interface (fd
profile); there the latency starts when python-can parses the frame in the plug-in's
process (the emulated adapter sends no time stamps).
"""

from __future__ import annotations

import copy
import json
import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path as FsPath

from iem.model_kinds import DEFAULT_MODEL

REPO = FsPath(__file__).resolve().parents[2]


def measure(seconds: float = 60.0, kind: str | None = None, seed: int = 0, log=print,
            link: str = "virtual", cpu_dma_latency_us: int = -1, description=None,
            rated_mass_kg: float | None = None, model=None) -> dict:
    """The figures on the arm model ``description`` (None: the default), the gate rated for
    ``rated_mass_kg`` (None: the arm model's rated payload), from ``model`` (a trained
    model of that arm; None: trained first, as the service does)."""
    from deploy.config import cell_config

    from .timing import machine_speed

    kind = model.name if model is not None else kind or DEFAULT_MODEL
    cell = {"description": description, "rated_mass_kg": rated_mass_kg, "where": "bench e2e",
            "host": {"cpu_dma_latency_us": cpu_dma_latency_us}}
    # a bad limit or an end effector beyond the rated payload fails before training
    cell_config(**cell)
    if link == "slcan-pty":
        return _measure_slcan_pty(seconds, kind, seed, log, cell, model)
    from deploy.simcell.inprocess import simulated_cell, virtual_link

    with tempfile.TemporaryDirectory() as tmp:
        config = cell_config(**cell, link=virtual_link("bench-e2e"),
                             model={"path": str(FsPath(tmp) / "model.msgpack"), "kind": kind,
                                    "seed": seed, "checkpoint_period_s": 30.0})
        # the controller plays the excitation path back and forth
        with simulated_cell(config, seed=seed, description=description,
                            model=model) as (controller, service):
            log(f"bench e2e: {kind} with {service.model.n_bags} bags; {seconds:g} s at 1 kHz "
                "on the virtual bus")
            states, before = _recorded(service)
            speed = [machine_speed()]  # the host, just before and just after the run
            controller.start()
            summary = service.run(duration=seconds)
            speed.append(machine_speed())
    # the controller stopped: the same points again, nothing beside them
    return _figures(summary, controller.stats(), link="virtual",
                    again=_back_to_back(service, before, states), machine=speed)


def _measure_slcan_pty(seconds: float, kind: str, seed: int, log, cell: dict,
                       model=None) -> dict:
    """The controller in its own process, an slcan adapter on a pty; the plug-in here, in
    the cell of :func:`deploy.config.cell_config`'s arguments ``cell``."""
    from deploy.config import cell_config
    from deploy.model.training import train_initial_model
    from deploy.options import arm_model_options
    from deploy.service.loop import Service
    from deploy.service.status import StatusLine

    from .timing import machine_speed

    if model is None:
        model = train_initial_model(kind, seed=seed, log=lambda *a: None,
                                    noise="sensor",  # the simulated arm is its model
                                    description=cell["description"])
    cmd = [sys.executable, "-m", "deploy.cli", "sim-controller", "--interface", "slcan-pty",
           "--profile", "fd", "--seed", str(seed), "--duration", str(seconds + 30),
           *arm_model_options(cell["description"])]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        pty = proc.stdout.readline().strip()
        if not pty.startswith("/dev/"):
            raise RuntimeError(f"sim-controller did not announce its pty: {pty!r}")
        with tempfile.TemporaryDirectory() as tmp:
            config = cell_config(**cell, link={"kind": "slcan", "channel": pty, "profile": "fd"},
                                 model={"path": str(FsPath(tmp) / "model.msgpack"),
                                        "kind": kind, "checkpoint_period_s": 30.0})
            service = Service(config, model=model, status=StatusLine(False))
            try:
                service.open()
                log(f"bench e2e: {kind} with {model.n_bags} bags; {seconds:g} s at 1 kHz, "
                    f"the controller in process {proc.pid} behind slcan on {pty}")
                states, before = _recorded(service)
                speed = [machine_speed()]
                summary = service.run(duration=seconds)
                speed.append(machine_speed())
            finally:
                service.close()
    finally:
        if proc.poll() is None:
            proc.terminate()
        _, err = proc.communicate(timeout=20)
    again = _back_to_back(service, before, states)  # the controller's process has ended
    stats = {}
    for line in err.splitlines():  # "sim-controller: cycles N, overruns N, ..."
        if line.startswith("sim-controller: cycles"):
            for part in line.split(": ", 1)[1].split(", "):
                key, _, value = part.partition(" ")
                stats[key] = int(value) if value.isdigit() else value
    return _figures(summary, {"cycles": stats.get("cycles"), "overruns": stats.get("overruns")},
                    link="slcan-pty", again=again, machine=speed)


def _recorded(service) -> tuple[list, object]:
    """The block points ``service`` will estimate (filled as it runs) and a copy of its
    model as it is before the run."""
    states: list = []
    service.on_cycle.append(lambda record: states.append(record.state))
    return states, copy.deepcopy(service.model)


def _back_to_back(service, model, states: list) -> dict:
    """``model`` (the service's before its run) stepped through the run's own block points
    again, back to back in this thread, set up as the service runs it: the estimator's own
    CPU a point, beside what the same steps took live (:func:`deploy.bench.timing.
    step_timing`)."""
    from .timing import step_timing

    if not states:  # nothing was estimated: nothing to step again
        return {"cpu_mean": None, "points": 0}
    model.go_live(True, background=service.config.estimate.background_learning)
    try:
        return step_timing(service.identifier(model), states)
    finally:
        model.stop()


def _figures(summary: dict, stats: dict, link: str, again: dict, machine: list) -> dict:
    cycles = summary["cycles"]
    return {
        "cycles": cycles,
        "lost": summary["frames"]["lost"],
        "skipped": summary["frames"]["skipped"],
        "unlearnt": summary["unlearnt"],
        "latency_us": summary["latency_us"],
        "age_us": summary["age_us"],
        "block_frames": summary["block_frames"],
        "cpu_share": summary["cpu_s"] / summary["wall_s"] if summary["wall_s"] else None,
        "cpu_share_parts": {k: v / summary["wall_s"] if summary["wall_s"] else None
                            for k, v in summary["cpu_parts"].items()},
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "seconds": summary["wall_s"],
        "controller_cycles": stats["cycles"],
        "controller_overruns": stats["overruns"],
        "dropped": summary["frames"]["dropped"],
        "writes": summary["writes"],
        "bags": summary["bags"],
        "model": summary["model"],
        "link": link,
        "cpu_dma_latency_us": summary["cpu_dma_latency_us"],
        "step_cpu_us": {"live": summary["step_cpu_s"] / cycles * 1e6 if cycles else None,
                        "back_to_back": again["cpu_mean"], "points": again["points"]},
        "machine_us": {"before": machine[0], "after": machine[1]},
        "cpu_share_rounds": (summary["cpu_s"] / summary["wall_s"] / _round_s(machine)
                             if summary["wall_s"] else None),
    }


def _round_s(machine: list) -> float:
    """CPU s of one round of :func:`~deploy.bench.timing.machine_speed`'s work on the host as
    it was around the run (the mean of before and after)."""
    return (machine[0]["cpu_us"] + machine[1]["cpu_us"]) / 2.0 * 1e-6


def configure(parser) -> None:
    parser.add_argument("--seconds", type=float, default=60.0, help="length of the run, s")
    parser.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    parser.add_argument("--model", choices=["IEM", "IEM+phys"], default=None,
                        help="model kind (default: the best available)")
    parser.add_argument("--link", choices=["virtual", "slcan-pty"], default="virtual",
                        help="virtual: the controller in this process (default); slcan-pty: "
                             "the controller in its own process behind slcan on a pty")
    from deploy.service.host import add_cpu_latency_option

    add_cpu_latency_option(parser)
    from deploy.options import add_arm_model, add_rated_mass

    add_arm_model(parser)
    add_rated_mass(parser)


def run(args) -> int:
    from deploy.options import arm_description_of

    f = measure(args.seconds, kind=args.model, link=args.link,
                cpu_dma_latency_us=args.cpu_dma_latency_us,
                description=arm_description_of(args), rated_mass_kg=args.rated_mass_kg)
    lat = f["latency_us"]
    age = f["age_us"]
    print(f"block points estimated {f['cycles']} ({f['block_frames']} frames each), cycles "
          f"lost {f['lost']}, points skipped {f['skipped']}, estimated without learning "
          f"{f['unlearnt']} (controller published {f['controller_cycles']} cycles, missed "
          f"{f['controller_overruns']} deadlines)")
    print(f"block to estimate p50 {lat['p50']:.0f} µs, p99 {lat['p99']:.0f} µs (target p99 "
          f"<= 2000); age of the frames at the estimate p50 {age['p50']:.0f} µs, p99 "
          f"{age['p99']:.0f} µs")
    share_target = 0.12 if f["link"] == "slcan-pty" else 0.10
    parts = ", ".join(f"{k} {v:.3f}" for k, v in f["cpu_share_parts"].items())
    print(f"CPU share of the plug-in {f['cpu_share']:.2f} of one core, all its threads "
          f"({parts}; target <= {share_target:g}); peak RSS {f['peak_rss_mb']:.0f} MB")
    step = f["step_cpu_us"]
    if step["points"]:
        print(f"the estimator's step (its part of the loop): {step['live']:.0f} µs of CPU a "
              f"point live, {step['back_to_back']:.0f} µs on the same {step['points']} points "
              f"again back to back ({step['live'] / step['back_to_back']:.2f} times): what the "
              "live step adds is each point starting after a sleep, with cold caches, and what "
              "runs beside it")
    print(f"writes {f['writes']}; bags {f['bags']} ({f['model']})")
    m = f["machine_us"]
    print(f"the machine's own speed beside it: a fixed round of small NumPy calls and Python "
          f"arithmetic took {m['before']['cpu_us']:.1f} µs of CPU ({m['before']['wall_us']:.1f} "
          f"wall) just before the run, {m['after']['cpu_us']:.1f} ({m['after']['wall_us']:.1f}) "
          f"just after; the share {f['cpu_share']:.3f} is the CPU of "
          f"{f['cpu_share_rounds']:.0f} such rounds a second (a host twice as slow doubles "
          "the share and the round, not their ratio)")
    if f["cpu_dma_latency_us"] is not None:
        print(f"held a CPU wake-up latency limit of {f['cpu_dma_latency_us']} µs: idle cores "
              "polled instead of sleeping; their CPU is not in the share above")
    if args.json:
        FsPath(args.json).write_text(json.dumps(f, indent=2) + "\n")
    return 0
