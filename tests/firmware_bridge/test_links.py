"""The link table, bus errors and silence diagnostics. The protocols at the seam, for every
link kind: test_link_conformance.py (firmware_bridge.checks)."""

import can
import pytest

from firmware_bridge.can_link import CanControllerPort, CanLink, open_bus
from firmware_bridge.errors import (
    AckTimeout,
    BridgeConfigError,
    ControllerSilent,
    EndOfStream,
    LinkError,
)
from firmware_bridge.links import LINKS, RecordedSource, open_link
from iem.errors import IemError, PayloadError
from sim.payload import Payload

from .conftest import synthetic_states


def test_unknown_kinds_name_the_valid_ones():
    with pytest.raises(BridgeConfigError, match="valid kinds are virtual, socketcan, slcan"):
        open_link("carrier-pigeon", "x")
    with pytest.raises(BridgeConfigError, match="valid kinds are virtual, socketcan, slcan"):
        open_bus("pcan", "x")
    with pytest.raises(BridgeConfigError, match="slcan needs a channel"):
        open_bus("slcan", "")
    assert set(LINKS) == {"virtual", "socketcan", "slcan", "serial", "franka", "program", "ros2",
                          "replay", "recording"}


def test_socketcan_failure_is_a_link_error_with_a_hint():
    with pytest.raises(LinkError, match="cannot open socketcan bus on channel 'iemnone0'"):
        open_bus("socketcan", "iemnone0")


class BrokenBus(can.BusABC):
    def __init__(self, **kwargs):
        super().__init__(channel="broken", **kwargs)

    def _recv_internal(self, timeout):
        raise can.CanOperationError("bus-off")

    def send(self, msg, timeout=None):
        raise can.CanOperationError("transmit buffer full")


def test_bus_errors_are_surfaced_not_swallowed():
    link = CanLink(BrokenBus(), "fd")
    with pytest.raises(LinkError, match="receiving failed: bus-off") as info:
        link.read(0.1)
    assert isinstance(info.value.__cause__, can.CanOperationError)
    assert isinstance(info.value, IemError)
    with pytest.raises(LinkError, match="sending the payload command failed"):
        link.send(None)
    link.close()


def test_silence_names_what_was_seen(channel):
    """A classic controller talking to an fd link: the message says so."""
    port = CanControllerPort(open_bus("virtual", channel, "classic"), "classic")
    link = CanLink.open("virtual", channel, "fd", silence_timeout=0.05)
    for s in synthetic_states(20, 2):
        port.publish(s)
    with pytest.raises(ControllerSilent) as info:
        link.read()
    message = str(info.value)
    assert "no complete joint state for 50 ms" in message
    assert "is the controller running --profile classic?" in message
    assert "no heartbeat yet" in message
    assert isinstance(info.value, TimeoutError)
    with pytest.raises(AckTimeout, match="no acknowledgement of payload command 1"):
        link.wait_ack(link.send(None), 0.05)
    link.close()
    port.close()


def test_the_sink_refuses_impossible_payloads_before_sending(channel):
    link = CanLink.open("virtual", channel, "fd")
    with pytest.raises(PayloadError, match="not physically consistent"):
        link.send(Payload("bad", -1.0, (0, 0, 0), (1, 0, 0, 1, 0, 1)))
    link.close()


def test_one_opener_signature_and_unknown_options_name_the_valid_ones(channel):
    import inspect

    from firmware_bridge.links import bus_kinds, controller_interfaces, link_kind

    for kind, spec in LINKS.items():  # every opener: (kind, channel, *, profile, silence_timeout)
        module = __import__(spec.module, fromlist=[spec.opener])
        params = inspect.signature(getattr(module, spec.opener)).parameters
        assert list(params)[:2] == ["kind", "channel"], kind
        for name in ("profile", "silence_timeout"):
            assert params[name].kind is inspect.Parameter.KEYWORD_ONLY, (kind, name)
    with pytest.raises(BridgeConfigError, match=r"unexpected keyword argument 'baudrate'.*"
                                                r"its options are window, bus_options"):
        open_link("virtual", channel, baudrate=9600)
    link = open_link("virtual", channel, profile="classic", silence_timeout=0.2, window=8)
    assert (link.silence_timeout, link.rate_hz) == (0.2, 500.0)
    link.close()
    assert bus_kinds() == ("virtual", "socketcan", "slcan")
    assert set(controller_interfaces()) == {"virtual", "socketcan", "slcan", "slcan-pty",
                                            "serial", "serial-pty"}
    with pytest.raises(BridgeConfigError, match="is not a CAN bus"):
        open_bus("serial", "loop://")
    assert link_kind("replay").sink is False and link_kind("recording").sink is False


# -- a recording's source: one base ------------------------------------------------------------
class _ThreeStates(RecordedSource):
    def __init__(self) -> None:
        self.states = iter(synthetic_states(3, 1))
        self.closed = 0

    def read(self, timeout=None):
        try:
            return next(self.states)
        except StopIteration:
            raise EndOfStream("after 3 joint states") from None

    def close(self) -> None:
        self.closed += 1


def test_a_recorded_source_iterates_to_its_end_and_closes_on_leaving_with():
    with _ThreeStates() as src:
        assert [s.cycle for s in src] == [0, 1, 2]
        assert list(src) == [] and src.closed == 0  # the end stays the end
    assert src.closed == 1
    with pytest.raises(RuntimeError), _ThreeStates() as failing:
        raise RuntimeError("a failure inside")
    assert failing.closed == 1
    RecordedSource().close()  # nothing to release by default


def test_the_recordings_sources_write_none_of_it_again():
    from firmware_bridge.recordings import RecordingSource
    from firmware_bridge.replay import ReplaySource

    for source in (ReplaySource, RecordingSource):
        assert issubclass(source, RecordedSource)
        assert not {"__iter__", "__enter__", "__exit__"} & set(vars(source)), source
