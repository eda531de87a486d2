"""What the plug-in asks of the cell PC while it runs: a CPU wake-up latency limit.

A 1 kHz loop sleeps between frames. When a core has nothing to run, the kernel puts it in an
idle state (a C-state, or a halted vCPU on a virtual machine); leaving it takes time, and
the caches come back cold. Python's estimate cycle touches a large working set (the
interpreter, numpy, the model), so a cycle that starts from an idle core costs more CPU
than the same cycle run back to back. Measured on this project's 2-vCPU machine (cpuidle
driver ``haltpoll``), the estimator alone on 11,000 recorded 1 kHz frames:

- back to back: 56 µs of CPU per cycle on average;
- paced at 1 kHz, sleeping between cycles: 95-110 µs;
- paced, sleeping, with a latency limit of 0 µs held: 76-79 µs.

The limit is Linux's PM QoS CPU latency request (``Documentation/power/pm_qos_interface``):
a process writes the largest wake-up latency it accepts, in µs, as a 32-bit integer to
``/dev/cpu_dma_latency`` and holds the file open; the kernel then uses no idle state slower
than that, on every core, until the last such file is closed. 0 keeps idle cores polling.
It is what ``cyclictest`` does by default, and what a real-time cell's tuning (``tuned``'s
``latency-performance`` profile, or C-states off in the BIOS) already provides.

The cost: idle cores poll instead of sleeping, which draws power (and, on a virtual machine,
takes the host's CPU). That CPU shows as idle, not as the plug-in's: the plug-in's CPU share
falls, the machine's power does not. So it is off unless configured (``[host]
cpu_dma_latency_us`` in ``cell.toml``).

The device belongs to root (mode 0600). For the service's own user, a udev rule gives its
group access::

    # /etc/udev/rules.d/60-iem-cpu-latency.rules
    KERNEL=="cpu_dma_latency", GROUP="iem", MODE="0660"
"""

from __future__ import annotations

import os
import struct

from deploy.config import INT_RANGES, ConfigError

DEVICE = "/dev/cpu_dma_latency"
MAX_LATENCY_US = INT_RANGES[("host", "cpu_dma_latency_us")][1]
"""Largest limit the configuration takes, µs (the kernel's default is 2,000 s: no limit)."""
_S32 = struct.Struct("=i")


class CpuLatencyRequest:
    """A held PM QoS CPU latency limit (:meth:`close`, or the process's exit, releases it).

    Args:
        latency_us: the largest wake-up latency accepted, µs (0 to :data:`MAX_LATENCY_US`).
        device: the PM QoS device (another path only in tests).

    Raises:
        ConfigError: a limit out of range, a kernel without the device, no permission to
            write it, or a limit the kernel did not apply (each message names the key, the
            device and what would be valid).
    """

    def __init__(self, latency_us: int, device: str = DEVICE) -> None:
        where = f"[host] cpu_dma_latency_us = {latency_us!r}"
        if isinstance(latency_us, bool) or not isinstance(latency_us, int) \
                or not 0 <= latency_us <= MAX_LATENCY_US:
            raise ConfigError(f"{where}: valid are integers 0 to {MAX_LATENCY_US} µs, or -1 "
                              "for no limit")
        self.latency_us = latency_us
        self.device = device
        try:
            self._fd = os.open(device, os.O_RDWR | os.O_CLOEXEC)
        except FileNotFoundError:
            raise ConfigError(f"{where}: {device} does not exist (a kernel without PM QoS); "
                              "set -1, or limit the idle states another way (tuned's "
                              "latency-performance profile, the BIOS)") from None
        except PermissionError:
            raise ConfigError(f"{where}: no permission to write {device} (it belongs to "
                              "root); give the service's group access with a udev rule, "
                              "KERNEL==\"cpu_dma_latency\", GROUP=\"iem\", MODE=\"0660\", "
                              "or set -1") from None
        try:
            os.write(self._fd, _S32.pack(latency_us))
            held = self.current()
        except OSError as exc:
            self.close()
            raise ConfigError(f"{where}: {device} did not take the request ({exc}); it must "
                              "be the kernel's PM QoS device") from exc
        if held > latency_us:
            self.close()
            raise ConfigError(f"{where}: the kernel's limit is {held} µs after the request, "
                              f"not at most {latency_us}: {device} is not a PM QoS device")
        self.effective_us = held

    def current(self) -> int:
        """The limit in force on the machine, µs (the smallest of every held request)."""
        fd = os.open(self.device, os.O_RDONLY | os.O_CLOEXEC)
        try:
            data = os.read(fd, _S32.size)
        finally:
            os.close(fd)
        if len(data) != _S32.size:
            raise OSError(f"{self.device} gave {len(data)} bytes, not {_S32.size}")
        return _S32.unpack(data)[0]

    @property
    def held(self) -> bool:
        return self._fd is not None

    def close(self) -> None:
        """Release the limit (closing the file withdraws the request)."""
        fd, self._fd = getattr(self, "_fd", None), None
        if fd is not None:
            os.close(fd)

    def __enter__(self) -> CpuLatencyRequest:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def add_cpu_latency_option(parser) -> None:
    """``--cpu-dma-latency-us US`` of the commands that run the service for a measurement
    (``iem demo``, ``iem bench e2e``): what ``[host] cpu_dma_latency_us`` sets for it."""
    parser.add_argument("--cpu-dma-latency-us", type=int, default=-1, metavar="US",
                        help="hold this CPU wake-up latency limit during the run, as [host] "
                             f"cpu_dma_latency_us does for the service (0 to {MAX_LATENCY_US} "
                             f"µs; needs write access to {DEVICE}; default -1: none)")


def hold_cpu_latency(latency_us: int, device: str = DEVICE) -> CpuLatencyRequest | None:
    """The configured limit, held; None for -1 (no limit asked)."""
    if latency_us == -1:
        return None
    return CpuLatencyRequest(latency_us, device)
