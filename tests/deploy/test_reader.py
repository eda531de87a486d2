"""The service's link reader (deploy.reader): the bus is drained while the estimator is busy,
what overflows is counted, silences and the end of a stream come through in order."""

from __future__ import annotations

import itertools
import time

from deploy.reader import LinkReader
from firmware_bridge.can_link import CanControllerPort, CanLink, open_bus
from tests.firmware_bridge.conftest import synthetic_states

_names = itertools.count()


def _pair():
    channel = f"test-reader-{next(_names)}"
    port = CanControllerPort(open_bus("virtual", channel, "fd"), "fd")
    link = CanLink(open_bus("virtual", channel, "fd"), "fd", silence_timeout=0.05)
    return port, link


def _publish(port, states):
    for s in states:
        port.tick(s.cycle, s.t)
        port.publish(s)


def _drain(reader, timeout=0.5):
    items = []
    while (item := reader.get(timeout)) is not None:
        items.append(item)
        if item.kind == "silent":
            break
    return items


def test_a_busy_estimator_loses_only_the_oldest_cycles_and_counts_them():
    port, link = _pair()
    reader = LinkReader(link, timeout=0.05, capacity=100).start()
    try:
        states = synthetic_states(1000)
        _publish(port, states)  # the consumer is busy: it reads nothing meanwhile
        deadline = time.monotonic() + 10
        while link.counters.delivered < 1000 and time.monotonic() < deadline:
            time.sleep(0.01)
        items = _drain(reader)
    finally:
        reader.stop()
        link.close()
        port.close()
    cycles = [i.value.cycle for i in items if i.kind == "state"]
    assert cycles == [s.cycle for s in states[-100:]]  # the newest, in order
    # (a silence reported before the first cycle may have been dropped as old news too)
    assert reader.skipped == 900 and items[-1].kind == "silent"
    assert all(i.frame_time > 0 for i in items if i.kind == "state")


def test_a_silence_is_reported_and_the_reader_goes_on():
    port, link = _pair()
    reader = LinkReader(link, timeout=0.05).start()
    try:
        states = synthetic_states(200)
        _publish(port, states[:100])
        first = _drain(reader)
        _publish(port, states[100:])
        second = _drain(reader)
    finally:
        reader.stop()
        link.close()
        port.close()
    assert [i.kind for i in first] == ["state"] * 100 + ["silent"]
    assert [i.value.cycle for i in second if i.kind == "state"] == list(range(100, 200))
    assert reader.skipped == 0


def test_a_link_failure_reaches_the_consumer():
    port, link = _pair()
    reader = LinkReader(link, timeout=0.05)
    link.close()  # reading a closed link fails
    reader.start()
    try:
        item = reader.get(2.0)
    finally:
        reader.stop()
        port.close()
    assert item is not None and item.kind == "error"
