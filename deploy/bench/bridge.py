"""``iem bench bridge``: how fast the bridge decodes, how late states arrive, bus loads.

For the virtual bus (in-process) and for slcan over a pty (an emulated adapter owning the
master in a forked process, python-can's ``slcan`` on the slave in this one):

- **throughput**: ``cycles`` cycles of joint-state frames are queued (virtual) or fed as
  fast as the pty takes them (slcan; the feeder waits for the pty rather than drop), and
  the link's ``read`` is timed until all are delivered: complete cycles per second,
  including python-can's receive path, the E2E check, reassembly and the ``JointState``.
  Target on the virtual bus: >= 20,000 cycles/s.
- **latency**: a sender (a thread, or the adapter's process) publishes at the profile's
  rate; for each cycle the time from just before its last frame is sent to the moment
  ``read`` returns its state, p50 and p99 in µs. Target on the virtual bus: p99 <= 200 µs.
  This includes waking the reader thread, which on a shared virtual machine is most of it;
  so for the virtual bus the benchmark also reports ``pipeline_us``: the same interval with
  sender and reader in one thread (send, then read), the bridge's own cost.

It also prints the bus load of both profiles (:mod:`firmware_bridge.busload`) and, with the
``ros2`` extra, the ros2 row: JointStates from a reliable writer in another process to the
``ros2`` link over loopback DDS (:func:`firmware_bridge.ros2_peers.measure_loopback`:
messages/s of a burst; latency p50/p99, lost and CPU share at 1 kHz; JSON key ``"ros2"``).
``--json FILE`` writes ``{"virtual": {"cycles_per_s", "latency_us": {"p50", "p99"},
"pipeline_us": {"p50", "p99"}}, "slcan_pty": {"cycles_per_s", "latency_us"}, "bus_load":
{"fd": {...}, "classic": {...}}}``. The figures depend on the machine and its load: this
is a command that prints them, never a timed test.
"""

from __future__ import annotations

import itertools
import json
import threading
import time
from pathlib import Path as FsPath

import can
import numpy as np

from firmware_bridge.protocol import PROFILES
from iem.types import JointState

_ids = itertools.count()


def _states(n: int) -> list[JointState]:
    k = np.arange(n)[:, None]
    phase = np.arange(7)[None, :]
    q = 0.8 * np.sin(2e-3 * k + phase)
    dq = 1.6e-3 * np.cos(2e-3 * k + phase)
    tau = 20.0 * np.sin(1e-3 * k + phase)
    return [JointState(t=i * 1e-3, q=q[i], dq=dq[i], tau_J=tau[i], cycle=i) for i in range(n)]


def _frames(profile: str, n: int) -> list[tuple[int, list[can.Message]]]:
    """``(cycle, messages)`` of ``n`` published cycles (cycle numbers step by the stride)."""
    from firmware_bridge.can_link import can_message
    from firmware_bridge.protocol import profile as get_profile

    js = get_profile(profile).joint_state
    out = []
    for i, s in enumerate(_states(n)):
        state = JointState(t=s.t * js.stride, q=s.q, dq=s.dq, tau_J=s.tau_J,
                           cycle=s.cycle * js.stride)
        frames, _ = js.encode(state, i & 0x0F)
        out.append((state.cycle, [can_message(codec, data) for codec, data in frames]))
    return out


def _percentiles(lat: list[float]) -> dict:
    a = np.asarray(lat) * 1e6
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99))}


def _paced(send, cycles, period: float, sent: dict) -> None:
    """Send each cycle's frames at ``period``; ``sent[cycle]`` = when its last frame went."""
    perf = time.perf_counter
    t0 = perf() + 0.02
    for i, (cycle, msgs) in enumerate(cycles):
        due = t0 + i * period
        while (left := due - perf()) > 0:
            time.sleep(left * 0.5 if left > 3e-4 else 0)
        for m in msgs[:-1]:
            send(m)
        sent[cycle] = perf()
        send(msgs[-1])


def _latency(send, link, cycles: list[tuple[int, list[can.Message]]], period: float,
             finish=None) -> dict:
    """Sender thread at ``period``; reader here. Latency from the last frame's send.
    ``finish`` runs in the sender thread after the last cycle."""
    sent: dict[int, float] = {}
    perf = time.perf_counter

    def sender():
        _paced(send, cycles, period, sent)
        if finish is not None:
            finish()

    th = threading.Thread(target=sender, daemon=True)
    th.start()
    lat = []
    try:
        for _ in range(len(cycles)):
            state = link.read(1.0)
            lat.append(perf() - sent[state.cycle])
    finally:
        th.join(5.0)
    return _percentiles(lat)


def _pipeline(send, link, cycles) -> dict:
    """Send a cycle's frames and read its state in this thread: the bridge's own latency."""
    perf = time.perf_counter
    lat = []
    for _, msgs in cycles:
        for m in msgs[:-1]:
            send(m)
        t0 = perf()
        send(msgs[-1])
        link.read(1.0)
        lat.append(perf() - t0)
    return _percentiles(lat)


def measure_virtual(profile: str = "fd", cycles: int = 20000, latency_cycles: int = 2000
                    ) -> dict:
    from firmware_bridge.can_link import CanLink, open_bus

    channel = f"bench-{next(_ids)}"
    tx = open_bus("virtual", channel, profile)
    link = CanLink(open_bus("virtual", channel, profile), profile)
    try:
        batch = _frames(profile, cycles)
        for _, msgs in batch:
            for m in msgs:
                tx.send(m)
        t0 = time.perf_counter()
        for _ in range(cycles):
            link.read(1.0)
        rate = cycles / (time.perf_counter() - t0)
        link.decoder.resync()  # the latency runs start again at cycle 0
        latency = _latency(tx.send, link, _frames(profile, latency_cycles),
                           link.profile.joint_state.cycle_ms * 1e-3)
        link.decoder.resync()
        pipeline = _pipeline(tx.send, link, _frames(profile, latency_cycles))
    finally:
        link.close()
        tx.shutdown()
    return {"cycles_per_s": rate, "latency_us": latency, "pipeline_us": pipeline}


def _slcan_feeder(adapter, profile: str, n_rate: int, n_latency: int, conn) -> None:
    """The adapter's process: serves the client's commands, then feeds the frames."""
    pty = adapter.pty
    deadline = time.perf_counter() + 10.0
    while not adapter.is_open and time.perf_counter() < deadline:
        adapter.recv(0.01)
    conn.send("open" if adapter.is_open else "the slcan client never opened the channel")

    def send(m):  # wait for the pty rather than drop frames
        while pty.backlog > 16384:
            pty.flush()
            time.sleep(2e-4)
        adapter.send(m)

    def drain():
        while pty.backlog:
            pty.flush()
            time.sleep(1e-3)

    for _, msgs in _frames(profile, n_rate):
        for m in msgs:
            send(m)
    drain()
    conn.recv()  # the reader is ready for the latency run
    sent: dict[int, float] = {}
    _paced(send, _frames(profile, n_latency), get_period(profile), sent)
    drain()
    conn.send(sent)
    conn.recv()


def get_period(profile: str) -> float:
    from firmware_bridge.protocol import profile as get_profile

    return get_profile(profile).joint_state.cycle_ms * 1e-3


def measure_slcan_pty(profile: str = "fd", cycles: int = 3000, latency_cycles: int = 1000
                      ) -> dict:
    """The adapter runs in a forked process (as a USB adapter would be another device), the
    reader here opens the pty with python-can's ``slcan``. ``time.perf_counter`` is the
    system's monotonic clock, so send and receive times of the two processes compare."""
    import multiprocessing

    from firmware_bridge.can_link import CanLink
    from firmware_bridge.errors import LinkError
    from firmware_bridge.slcan_adapter import SlcanPtyAdapter

    ctx = multiprocessing.get_context("fork")
    here, there = ctx.Pipe()
    adapter = SlcanPtyAdapter()
    feeder = ctx.Process(target=_slcan_feeder, daemon=True,
                         args=(adapter, profile, cycles, latency_cycles, there))
    feeder.start()
    link = CanLink.open("slcan", adapter.slave_path, profile)
    try:
        if not here.poll(15.0) or (status := here.recv()) != "open":
            raise LinkError(f"slcan bench: the adapter process did not start ({status!r})")
        t0 = time.perf_counter()
        for _ in range(cycles):
            link.read(5.0)
        rate = cycles / (time.perf_counter() - t0)
        link.decoder.resync()
        here.send("latency")
        got = {}
        for _ in range(latency_cycles):
            state = link.read(5.0)
            got[state.cycle] = time.perf_counter()
        sent = here.recv()
        here.send("stop")
        latency = _percentiles([got[c] - sent[c] for c in got])
    finally:
        link.close()
        feeder.join(10.0)
        if feeder.is_alive():
            feeder.kill()
            feeder.join()
        adapter.shutdown()
    return {"cycles_per_s": rate, "latency_us": latency}


def measure(profile: str = "fd", cycles: int = 20000, slcan_cycles: int = 3000,
            ros2_cycles: int = 10000) -> dict:
    from firmware_bridge.busload import profile_load

    loads = {}
    for name in PROFILES:
        fig = profile_load(name)
        loads[name] = {k: fig[k] for k in ("bits_per_frame", "frames_per_s", "load_percent",
                                           "rate_hz")}
    return {
        "profile": profile,
        "virtual": measure_virtual(profile, cycles, min(2000, cycles)),
        "slcan_pty": measure_slcan_pty(profile, slcan_cycles, min(1000, slcan_cycles)),
        "bus_load": loads,
        "ros2": measure_ros2(ros2_cycles),
    }


def measure_ros2(cycles: int = 10000) -> dict:
    """The ros2 row (:func:`firmware_bridge.ros2_peers.measure_loopback`: ``cycles`` messages
    at 1 kHz for the latency, twice that for the rate), or why not."""
    try:
        import cyclonedds  # noqa: F401
    except ImportError:
        return {"skipped": "install the 'ros2' extra (cyclonedds)"}
    from firmware_bridge.ros2_peers import measure_loopback

    return measure_loopback(rate_cycles=2 * cycles, latency_cycles=cycles)


def configure(parser) -> None:
    parser.add_argument("--profile", default="fd", choices=PROFILES,
                        help="wire profile measured (default fd)")
    parser.add_argument("--cycles", type=int, default=20000,
                        help="cycles for the virtual-bus throughput (default 20000)")
    parser.add_argument("--slcan-cycles", type=int, default=3000,
                        help="cycles for the slcan throughput (default 3000)")
    parser.add_argument("--ros2-cycles", type=int, default=10000,
                        help="messages at 1 kHz for the ros2 row's latency, twice as many for "
                        "its rate (default 10000)")
    parser.add_argument("--json", metavar="FILE", help="also write the figures as JSON")


def _met(ok: bool) -> str:
    return "met" if ok else "MISSED"


def run(args) -> int:
    fig = measure(args.profile, args.cycles, args.slcan_cycles, args.ros2_cycles)
    print(f"bridge, {args.profile} profile")
    for key, label in (("virtual", "virtual bus"), ("slcan_pty", "slcan over a pty")):
        f = fig[key]
        lat = f["latency_us"]
        target = ""
        if key == "virtual":
            target = (f"   (targets >= 20000: {_met(f['cycles_per_s'] >= 20000)}, p99 <= 200: "
                      f"{_met(lat['p99'] <= 200)})")
        print(f"{label:17s} decode {f['cycles_per_s']:9.0f} cycles/s   latency p50 "
              f"{lat['p50']:7.1f} µs  p99 {lat['p99']:7.1f} µs{target}")
        if "pipeline_us" in f:
            p = f["pipeline_us"]
            print(f"{'':17s} in one thread (send, then read): p50 {p['p50']:7.1f} µs  "
                  f"p99 {p['p99']:7.1f} µs")
    r = fig["ros2"]
    if "skipped" in r:
        print(f"ros2 over loopback  skipped: {r['skipped']}")
    else:
        lat = r["latency_us"]
        print(f"ros2 over loopback  {r['cycles_per_s']:9.0f} msgs/s   latency p50 "
              f"{lat['p50']:7.1f} µs  p99 {lat['p99']:7.1f} µs at 1 kHz, {r['lost']} lost of "
              f"{r['lost'] + r['delivered']}, CPU share {r['cpu_share']:.2f}   (targets 0 lost, "
              "p99 <= 1000, CPU <= 0.3)")
    for name, load in fig["bus_load"].items():
        print(f"bus load {name:7s}  {load['bits_per_frame']} bits/frame, "
              f"{load['frames_per_s']:g} frames/s at {load['rate_hz']:g} Hz: "
              f"{load['load_percent']:.1f} %")
    if args.json:
        FsPath(args.json).write_text(json.dumps(fig, indent=2) + "\n")
    return 0
