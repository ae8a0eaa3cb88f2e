"""The daemon-side commands' logging: plain lines on a terminal, ``<N>`` priorities when stderr is
the journal, --verbose/--quiet, the rate limit, and no bare prints left in the daemon's code."""

from __future__ import annotations

import io
import logging
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from admittance import logs
from helpers import free_endpoint

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def restore_logging():
    root, ours = logging.getLogger(), logging.getLogger(logs.ROOT)
    levels, handlers = (root.level, ours.level), list(root.handlers)
    yield
    logs.reset()
    root.handlers[:] = handlers
    root.setLevel(levels[0])
    ours.setLevel(levels[1])


def emit(verbosity: int, journal: bool) -> str:
    out = io.StringIO()
    logs.configure("run", verbosity, stream=out, journal=journal)
    log = logging.getLogger("admittance.daemon.test")
    log.debug("step")
    log.info("running MX-64#1")
    log.warning("latency timer is 16 ms")
    log.error("two\nlines")
    logging.getLogger("can.interfaces").info("a library's info")
    return out.getvalue()


def test_plain_lines_name_the_command_and_the_level_and_verbosity_picks_the_levels(restore_logging):
    assert emit(0, journal=False).splitlines() == [
        "admittance run: running MX-64#1", "admittance run: warning: latency timer is 16 ms",
        "admittance run: error: two", "lines"]
    quiet = emit(-1, journal=False)
    assert "running" not in quiet and "warning: latency" in quiet
    verbose = emit(1, journal=False)
    assert "admittance run: debug: step" in verbose and "a library's info" in verbose


def test_journal_lines_carry_the_syslog_priority_on_every_line_and_no_prefix(restore_logging):
    assert emit(0, journal=True).splitlines() == ["<6>running MX-64#1", "<4>latency timer is 16 ms",
                                                  "<3>two", "<3>lines"]
    assert "<7>step" in emit(1, journal=True)


def test_the_journal_is_detected_by_the_stream_systemd_names(tmp_path, monkeypatch):
    with open(tmp_path / "stderr", "w") as stream, open(tmp_path / "other", "w") as other:
        st = os.fstat(stream.fileno())
        monkeypatch.setenv("JOURNAL_STREAM", f"{st.st_dev}:{st.st_ino}")
        assert logs.journal_stream(stream)
        assert not logs.journal_stream(other), "stderr redirected elsewhere: plain lines"
        assert not logs.journal_stream(io.StringIO())
        monkeypatch.delenv("JOURNAL_STREAM")
        assert not logs.journal_stream(stream)


def test_the_rate_limit_lets_a_burst_through_then_counts_what_it_held_back(caplog):
    now = [0.0]
    limit = logs.RateLimitedLog(logging.getLogger("admittance.test.limit"), period=10.0, burst=2,
                                clock=lambda: now[0])
    sent = [limit("k", f"line {i}") for i in range(5)]
    assert sent == [True, True, False, False, False]
    assert limit("other", "another key is not held back")
    now[0] = 10.0
    assert limit("k", "after the pause")
    assert caplog.messages[-1] == "after the pause (3 more like it held back)"


def test_a_daemon_side_command_under_systemd_writes_priorities_to_the_journal_stream(tmp_path):
    """The router, as a service would start it: stderr is the journal's stream (a pipe here)."""
    read, write = os.pipe()
    st = os.fstat(write)
    env = {**os.environ, "JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"}
    for flags, expect in (([], r"^<6>serving on tcp/127\.0\.0\.1:\d+ "), (["-q"], r"^$")):
        proc = subprocess.Popen([sys.executable, "-m", "admittance", "router", "--listen", free_endpoint(),
                                 "--duration", "0.3", *flags], stderr=write, stdout=subprocess.DEVNULL, env=env,
                                cwd=tmp_path)
        assert proc.wait(timeout=60) == 0
        text = os.read(read, 65536).decode() if _readable(read) else ""
        assert re.search(expect, text, re.M), (flags, text)
    os.close(read)
    os.close(write)


def _readable(fd: int) -> bool:
    import select

    return bool(select.select([fd], [], [], 0)[0])


def test_no_bare_prints_in_the_daemon_its_bench_and_its_drivers():
    """Everything the daemon says goes through logging; a command's *product* (``--check``,
    ``--print-ports``) is printed by its ``cli.py`` on stdout, never on stderr."""
    offenders = []
    for area in ("daemon", "mockbench", "drivers"):
        for path in sorted((REPO / "admittance" / area).glob("*.py")):
            for number, line in enumerate(path.read_text().splitlines(), 1):
                code = line.split("#", 1)[0]
                bare = "sys.stderr.write" in code or "file=sys.stderr" in code
                if bare or ("print(" in code and path.name != "cli.py"):
                    offenders.append(f"{path.relative_to(REPO)}:{number}: {line.strip()}")
    assert offenders == []


def test_forwarded_sends_the_packages_lines_to_a_callable_only_for_the_block(restore_logging):
    """The setup wizard shows a dry run's daemon lines in its own output, not twice."""
    out, said = io.StringIO(), []
    logs.configure("setup", 0, stream=out, journal=False)
    log = logging.getLogger("admittance.daemon.supervisor")
    with logs.forwarded(said.append):
        log.debug("a step")
        log.info("stopped (hold) after 10 cycles")
        log.warning("SCHED_FIFO refused")
    log.info("after the block")
    assert said == ["stopped (hold) after 10 cycles", "warning: SCHED_FIFO refused"]
    assert out.getvalue() == "admittance setup: after the block\n"


def test_a_command_run_in_process_leaves_no_handler_for_the_next(restore_logging, capsys):
    """Tests run many commands in one process: the next one's error is its own one line."""
    from admittance.cli import main

    before = list(logging.getLogger().handlers)
    assert main(["router", "--listen", free_endpoint(), "--duration", "0.1"]) == 0
    assert logging.getLogger().handlers == before, "the router's handler was left behind"
    capsys.readouterr()
    logs.configure("mock-bench", 0)  # a command called without main(), as some tests do
    assert main(["thesis", "/nonexistent/dataset"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("admittance thesis: error: "), err
