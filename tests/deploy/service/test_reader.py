"""The service's readers (deploy.service.reader): the bus is drained while the estimator is busy,
block points are handed over once a block, what overflows is counted, silences and the end
of a stream come through in order (a silence first closes the open block), and a replay's
bulk reading gives the blocks the live reader gives."""

from __future__ import annotations

import itertools
import time

import numpy as np
import pytest

from deploy.service.reader import BatchReader, LinkReader
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


def test_a_busy_estimator_loses_only_the_oldest_blocks_and_counts_them():
    port, link = _pair()
    reader = LinkReader(link, timeout=0.05, capacity=10).start()
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
    assert cycles == [s.cycle for s in states[-91::10]]  # the newest blocks' last, in order
    # (a silence reported before the first cycle may have been dropped as old news too)
    assert reader.skipped == 90 and items[-1].kind == "silent"
    assert all(i.frame_time >= i.first_time > 0 for i in items if i.kind == "state")


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
    assert [i.kind for i in first] == ["state"] * 10 + ["silent"]
    assert [i.value.cycle for i in second if i.kind == "state"] == list(range(109, 200, 10))
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


def test_a_silence_closes_the_open_block_first():
    port, link = _pair()
    reader = LinkReader(link, timeout=0.05).start()
    try:
        states = synthetic_states(25)
        _publish(port, states)
        items = _drain(reader)
    finally:
        reader.stop()
        link.close()
        port.close()
    assert [i.kind for i in items] == ["state"] * 3 + ["silent"]
    last = items[2].value  # the last 5 frames' means, before the silence
    np.testing.assert_allclose(last.q, np.mean([s.q for s in states[20:]], axis=0),
                               rtol=0, atol=1e-5)  # the wire quantises q
    assert last.cycle == 24
    # the silence closed it: its age is the silence's, no lag of the service
    assert [i.flushed for i in items[:3]] == [False, False, True]
    # the silence on the controller's clock: the last frame's time plus the timeout
    assert items[3].t == pytest.approx(states[24].t + 0.05, abs=1e-5)  # the wire's 1 µs


class _Frames:
    """A replayed stream of given frames (a link without a bus)."""

    last_frame_time = 1.0

    def __init__(self, states):
        self.it = iter(states)

    def read(self, timeout):
        from firmware_bridge.errors import EndOfStream

        try:
            return next(self.it)
        except StopIteration:
            raise EndOfStream() from None


def test_a_replay_reads_in_bulk_the_blocks_the_live_reader_forms():
    states = synthetic_states(95)
    live = LinkReader(_Frames(states), timeout=0.05).start()
    try:
        items = []
        while (item := live.get(2.0)).kind == "state":
            items.append(item)
    finally:
        live.stop()
    batch = BatchReader(_Frames(states), 0.05, chunk=32)
    got = []
    while (item := batch.get()).kind == "state":
        got.append(item)
    assert item.kind == "end"
    assert len(got) == len(items) == 10  # the last 5 frames close a block at the end
    for a, b in zip(got, items, strict=True):
        assert a.value.t == b.value.t and a.value.cycle == b.value.cycle
        np.testing.assert_array_equal(a.value.features(), b.value.features())


class _Pausing(_Frames):
    """A replayed stream that is silent for ``reads`` reads after frame ``at``."""

    def __init__(self, states, at: int, reads: int) -> None:
        super().__init__(states)
        self.read_frames, self.at, self.quiet = 0, at, reads

    def read(self, timeout):
        from firmware_bridge.errors import ControllerSilent

        if self.read_frames == self.at and self.quiet:
            self.quiet -= 1
            raise ControllerSilent("quiet")
        self.read_frames += 1
        return super().read(timeout)


def test_a_replays_silence_is_on_the_recordings_clock_and_closes_the_open_block():
    states = synthetic_states(40)
    batch = BatchReader(_Pausing(states, at=25, reads=2), 0.05, chunk=32)
    items = []
    while (item := batch.get()).kind != "end":
        items.append(item)
    assert [i.kind for i in items] == ["state"] * 3 + ["silent"] * 2 + ["state"] * 2
    # the silence and the end each close the open block
    assert [i.flushed for i in items if i.kind == "state"] == [False, False, True, False, True]
    last = states[24].t  # the last frame before the silence; a read that finds none: 50 ms
    assert [i.t for i in items if i.kind == "silent"] == pytest.approx([last + 0.05,
                                                                        last + 0.10])
