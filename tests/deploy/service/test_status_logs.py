"""The terminal status line and the structured (JSON) logs."""

import io
import json
import logging
from datetime import datetime

import pytest

from deploy.config import LogConfig
from deploy.service.logs import JsonFormatter, setup_logging
from deploy.service.status import StatusLine


class FakeTty(io.StringIO):
    def isatty(self) -> bool:
        return True


# -- status line ------------------------------------------------------------------------------
@pytest.mark.parametrize(("mode", "tty", "enabled"), [
    ("auto", True, True), ("auto", False, False), ("on", False, True), ("on", True, True),
    ("off", True, False), ("off", False, False)])
def test_enabled_by_mode_and_terminal(mode, tty, enabled):
    stream = FakeTty() if tty else io.StringIO()
    line = StatusLine.from_config(LogConfig(status_line=mode, status_period_s=0.5), stream)
    assert line.enabled is enabled and line.period_s == 0.5 and line.stream is stream


def test_a_stream_without_isatty_counts_as_no_terminal():
    class Bare:
        def write(self, text): ...
        def flush(self): ...

    assert not StatusLine.from_config(LogConfig(status_line="auto"), Bare()).enabled


def test_redraw_pads_over_the_longer_previous_text_and_clear_erases():
    out = FakeTty()
    line = StatusLine(True, out, period_s=0.25)
    assert line.due(0.0)
    line.show("m 1.615 kg  bags 4", now=0.0)
    assert out.getvalue() == "\rm 1.615 kg  bags 4"
    assert not line.due(0.1)
    line.show("too early", now=0.1)  # within the period: not drawn
    assert out.getvalue() == "\rm 1.615 kg  bags 4"
    line.show("short", now=0.3)
    assert out.getvalue().endswith("\rshort" + " " * (len("m 1.615 kg  bags 4") - 5))
    line.show("SILENT", force=True, now=0.31)  # forced: drawn at once
    assert out.getvalue().endswith("\rSILENT")
    line.clear()
    assert out.getvalue().endswith("\r" + " " * 6 + "\r")
    written = out.getvalue()
    line.clear()  # nothing shown since: nothing written
    assert out.getvalue() == written


def test_disabled_status_line_writes_nothing():
    out = io.StringIO()
    line = StatusLine(False, out)
    assert not line.due(0.0)
    line.show("anything", force=True, now=0.0)
    line.clear()
    assert out.getvalue() == ""


# -- JSON logs --------------------------------------------------------------------------------
@pytest.fixture
def restore_iem_logger():
    root = logging.getLogger("iem")
    saved = root.handlers[:], root.level, root.propagate
    yield
    root.handlers[:], root.level, root.propagate = saved[0], saved[1], saved[2]


def test_json_lines_parse_with_standard_and_extra_fields(restore_iem_logger):
    out = io.StringIO()
    setup_logging("info", "json", stream=out)
    log = logging.getLogger("iem.gate")
    log.info("gate %s: %s", "send", "mass 1.6 kg",
             extra={"event": "gate", "reason": "send", "seq": 7})
    log.debug("not shown at info")
    log.warning("controller silent", extra={"event": "controller_silent"})
    lines = out.getvalue().splitlines()
    assert len(lines) == 2
    first, second = (json.loads(x) for x in lines)
    assert first["level"] == "info" and first["logger"] == "iem.gate"
    assert first["msg"] == "gate send: mass 1.6 kg"
    assert (first["event"], first["reason"], first["seq"]) == ("gate", "send", 7)
    assert datetime.fromisoformat(first["ts"]).utcoffset().total_seconds() == 0
    assert second["level"] == "warning" and second["event"] == "controller_silent"
    for standard in ("args", "levelno", "pathname", "thread"):
        assert standard not in first


def test_json_carries_the_exception_and_odd_values(restore_iem_logger):
    out = io.StringIO()
    setup_logging("debug", "json", stream=out)
    log = logging.getLogger("iem.service")
    try:
        raise ValueError("bad frame")
    except ValueError:
        log.exception("checkpoint failed", extra={"path": object()})
    doc = json.loads(out.getvalue())
    assert doc["level"] == "error" and "ValueError: bad frame" in doc["exc"]
    assert doc["path"].startswith("<object object")  # not JSON: written as its str


def test_text_format_and_level(restore_iem_logger):
    out = io.StringIO()
    setup_logging("warning", "text", stream=out)
    logging.getLogger("iem.x").info("hidden")
    logging.getLogger("iem.x").warning("shown")
    text = out.getvalue()
    assert "hidden" not in text and "WARNING iem.x: shown" in text
    with pytest.raises(json.JSONDecodeError):
        json.loads(text)


def test_formatter_alone():
    record = logging.LogRecord("iem.t", logging.INFO, __file__, 1, "a %d", (1,), None)
    record.event = "x"
    doc = json.loads(JsonFormatter().format(record))
    assert {k: doc[k] for k in ("level", "logger", "msg", "event")} == {
        "level": "info", "logger": "iem.t", "msg": "a 1", "event": "x"}


# -- off a terminal, and log lines beside the status line ----------------------------------------
def test_off_a_terminal_plain_lines_at_the_plain_period_and_never_a_carriage_return():
    out = io.StringIO()  # a pipe or a file: not a terminal
    line = StatusLine(True, out, period_s=0.25, plain_period_s=10.0)
    assert line.enabled and not line.tty and line.interval_s == 10.0
    line.show("m 1.615 kg", now=0.0)
    assert not line.due(5.0)
    line.show("m 1.616 kg", now=5.0)  # not due: nothing
    line.show("m 1.617 kg", now=10.0)
    assert out.getvalue() == "status: m 1.615 kg\nstatus: m 1.617 kg\n"
    # a forced message is written once at once, not again while it stays the same
    for t in (10.1, 10.2, 10.3):
        line.show("controller silent: writes stopped", force=True, now=t)
    line.clear()  # nothing to erase: the lines are whole
    assert out.getvalue().count("controller silent") == 1
    assert "\r" not in out.getvalue()
    assert all(x.startswith("status: ") for x in out.getvalue().splitlines())


def test_off_a_terminal_a_plain_period_of_0_means_no_status_at_all():
    out = io.StringIO()
    line = StatusLine(True, out, plain_period_s=0.0)
    assert not line.enabled
    line.show("x", force=True, now=0.0)
    assert out.getvalue() == ""
    cfg = LogConfig(status_line="on", status_plain_period_s=0.0)
    assert not StatusLine.from_config(cfg, io.StringIO()).enabled
    assert StatusLine.from_config(cfg, FakeTty()).enabled  # on a terminal it still shows
    assert StatusLine.from_config(LogConfig(status_line="on"), io.StringIO()).interval_s == 10.0


@pytest.mark.parametrize("fmt", ["json", "text"])
def test_a_log_record_on_a_terminal_erases_the_status_line_first(restore_iem_logger, fmt):
    out = FakeTty()
    setup_logging("info", fmt, stream=out)
    line = StatusLine(True, out, period_s=0.25)
    line.show("m 1.615 kg  bags 4", now=0.0)
    logging.getLogger("iem.service").warning("controller silent: writes stopped")
    text = out.getvalue()
    # the status text, erased by blanks, then the record from the start of the line
    erased = "\rm 1.615 kg  bags 4" + "\r" + " " * 18 + "\r"
    assert text.startswith(erased)
    record = text[len(erased):]
    assert record.endswith("\n") and record.count("\n") == 1 and "\r" not in record
    assert "controller silent" in record and "bags 4" not in record
    # the next redraw starts a fresh line, and padding does not run over the record
    line.show("m 1.616 kg", now=0.3)
    assert out.getvalue() == text + "\rm 1.616 kg"


def test_off_a_terminal_logs_and_status_lines_stay_separate(restore_iem_logger):
    out = io.StringIO()
    setup_logging("info", "json", stream=out)
    line = StatusLine(True, out, period_s=0.25, plain_period_s=1.0)
    log = logging.getLogger("iem.gate")
    for k in range(5):
        line.show(f"tick {k}", now=k * 0.5)
        log.info("gate %d", k, extra={"event": "gate"})
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue()
    status = [x for x in lines if x.startswith("status: ")]
    logs = [json.loads(x) for x in lines if not x.startswith("status: ")]
    assert status == ["status: tick 0", "status: tick 2", "status: tick 4"]
    assert [d["msg"] for d in logs] == [f"gate {k}" for k in range(5)]
