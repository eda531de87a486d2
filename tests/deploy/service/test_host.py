"""``[host] cpu_dma_latency_us``: the PM QoS CPU latency limit the service holds while it runs.

On the real ``/dev/cpu_dma_latency`` where it is writable (the kernel reports the limit in
force, so the request is checked against the kernel itself), else on a file standing in for
it; the configuration's errors as for every other key.
"""

from __future__ import annotations

import os
import struct

import pytest

from deploy.config import ConfigError, config_from_dict
from deploy.service.host import DEVICE, CpuLatencyRequest, hold_cpu_latency

from ..conftest import cell_config

WRITABLE = os.access(DEVICE, os.W_OK)
real_device = pytest.mark.skipif(not WRITABLE, reason=f"{DEVICE} is not writable here "
                                 "(it belongs to root); the file stand-in tests still run")


def current_limit() -> int:
    with open(DEVICE, "rb", buffering=0) as f:
        return struct.unpack("=i", f.read(4))[0]


def test_the_default_is_no_limit_and_holds_nothing():
    assert config_from_dict({}).host.cpu_dma_latency_us == -1
    assert hold_cpu_latency(-1) is None


@pytest.mark.parametrize(("value", "part"), [
    (2_000_000, "out of range; valid is an integer from -1 to 1000000"),
    (-2, "out of range"),
    (1.5, "must be an integer"),
    (True, "must be an integer"),
])
def test_a_bad_limit_names_the_key_and_what_is_valid(value, part):
    with pytest.raises(ConfigError) as info:
        config_from_dict({"host": {"cpu_dma_latency_us": value}}, where="cell.toml")
    assert "[host] cpu_dma_latency_us" in str(info.value) and part in str(info.value)


def test_the_request_writes_a_native_32_bit_integer_and_reads_the_limit_back(tmp_path):
    device = tmp_path / "cpu_dma_latency"
    device.write_bytes(b"")
    with CpuLatencyRequest(25, device=str(device)) as request:
        assert request.held and request.effective_us == 25
        assert device.read_bytes() == struct.pack("=i", 25)
    assert not request.held
    request.close()  # a second close is harmless


@pytest.mark.parametrize("value", [-1, 1_000_001, 2.0])
def test_the_request_refuses_a_value_out_of_range(tmp_path, value):
    with pytest.raises(ConfigError) as info:
        CpuLatencyRequest(value, device=str(tmp_path / "unused"))
    assert "0 to 1000000" in str(info.value)


def test_a_kernel_without_the_device_is_named(tmp_path):
    missing = tmp_path / "cpu_dma_latency"
    with pytest.raises(ConfigError) as info:
        CpuLatencyRequest(0, device=str(missing))
    message = str(info.value)
    assert str(missing) in message and "does not exist" in message and "set -1" in message


def test_a_device_that_does_not_report_the_limit_is_refused():
    with pytest.raises(ConfigError) as info:  # /dev/null takes the write, reads nothing
        CpuLatencyRequest(0, device="/dev/null")
    assert "/dev/null" in str(info.value)


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs fork")
def test_no_permission_names_the_udev_rule(tmp_path):
    """As a user who may not write the device (root drops to nobody in a forked child)."""
    device = tmp_path / "cpu_dma_latency"
    device.write_bytes(b"")
    device.chmod(0o600)
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: never returns into pytest
        try:
            os.close(read)
            if os.geteuid() == 0:
                os.setgid(65534)
                os.setuid(65534)
            try:
                CpuLatencyRequest(0, device=str(device))
                message = "held"
            except ConfigError as exc:
                message = str(exc)
            os.write(write, message.encode())
        finally:
            os._exit(0)
    os.close(write)
    with os.fdopen(read, "rb") as f:
        message = f.read().decode()
    os.waitpid(pid, 0)
    assert "no permission to write" in message and 'GROUP="iem"' in message, message


@real_device
def test_the_kernel_applies_the_limit_while_held_and_drops_it_at_close():
    before = current_limit()
    with CpuLatencyRequest(55) as request:
        assert current_limit() <= 55
        assert request.effective_us == current_limit()
    assert current_limit() == before


@real_device
@pytest.mark.hil
def test_the_service_holds_the_limit_while_it_runs(model_file):
    from deploy.simcell.inprocess import simulated_cell, virtual_channel
    from sim.family import default_test_payload
    from sim.paths import new_task_path

    before = current_limit()
    doc = cell_config(model_file, {"kind": "virtual", "channel": virtual_channel("host"),
                                   "profile": "fd"}, host={"cpu_dma_latency_us": 44})
    seen = []
    with simulated_cell(config_from_dict(doc, where="test"), path=new_task_path(),
                        payload=default_test_payload(), once=True, seed=1) as (controller,
                                                                               service):
        service.on_cycle.append(lambda r: seen.append(current_limit())
                                if len(seen) < 3 else None)
        controller.start()
        summary = service.run(until=lambda: controller.cycles >= 500)
    assert summary["cpu_dma_latency_us"] == 44
    assert seen and max(seen) <= 44
    assert current_limit() == before  # released when the service closed
