"""Every script in bench/ run end to end with its smallest arguments, so that none rots unseen.

A bench is not a test: nothing here checks a figure or a time (the machine is shared, and the
benches print ratios for a reader). What is checked is that the script still runs against the
current API (bench/loop_timing.py's daemon load once broke silently when the supervisor's
RunOptions and backends changed): exit 0, no traceback, and one line of its real output, which
a script that stopped early or measured nothing would not print.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# A guard against a hung bench, not a timing assertion: each case takes a few seconds.
HANG_S = 180

# (script, arguments, a regular expression one line of the output must match)
CASES = [
    ("daemon_tick.py", ["--joints", "1", "--rows", "2", "--repeat", "50"], r"^json/msgpack size ratio = \d+\.\d+$"),
    ("ecosystem_tick.py", ["--ticks", "20"], r"^\s+ROS 2 bridge\s+\d+\.\d+ µs"),
    ("identify_coverage.py", ["--seeds", "1", "--kinds", "clean", "--trials", "4", "--duration", "3"], r"^\| all \| \d+ \| \d+ \| \d+ % \|"),
    ("identify_families.py", ["--only", "clean", "--match", "mocap"], r"^passed [01] of 1 synthetic rows"),
    # --shared-extension: building the baseline's own extension takes minutes (run by hand).
    ("identify_speed.py", ["--sets", "stribeck=0.04", "--trials", "4", "--duration", "3", "--shared-extension"],
     r"^median CPU ratio baseline / this: \d+\.\d+× over 1 sets"),
    ("identify_jacobian.py", ["--trials", "2", "--duration", "2"], r"^scipy 2-point\s+\d+\.\d+\s+\d+"),
    ("identify_vs_thesis.py", ["--trials", "2", "--duration", "2"],
     r"^ratio baseline / identify:\s+\d+\.\d+×"),
    ("query_starvation.py", ["--seconds", "3", "--busy", "0"], r'^\{"gets": \d+, "answered": \d+, "timed_out": \d+'),
    ("optoforce_parse.py", [], r"^\s+CAN reader, virtual bus \(CAN frames/s\)\s+[\d,]+"),
    ("sensor_recovery.py", ["--outages", "0.1", "--repeats", "1"], r"^\s+0\.10 \|\s+\d+\.\d+ \|\s+0\.050$"),
    ("servo_forms.py", ["--forms", "lag", "--seconds", "4"], r"^\| first-order lag 25 ms \| \d+\.\d+ \| "),
    # The play's inverse against its variants, on the geared fits servo_forms.py wrote for the docs.
    ("servo_play_variants.py", ["--fits", "docs/fidelity/servo_forms_two_horizons.json"],
     r"^\| MX-64 geared, 1° backlash \| now \| \d+\.\d+ \| \d+\.\d+× \|"),
    ("servo_scan.py", ["--baud", "1000000"], r"^\s+ServoBus\.scan\(ids\) ping per ID .*found 1\)$"),
    ("plant_lanes.py", ["--sets", "1", "2", "--repeats", "1"], r"^\| 2 \| \d+\.\d+ ms \| \d+\.\d+ ms \| \d+\.\d+× \|"),
    ("sim_step.py", [], r"^\s+rayon \(\d+ cpus\)\s+\d+\.\d+ M substeps/s"),
    ("wire_limit.py", ["--servos", "2", "--bauds", "4000000", "--rdt", "0", "--cycles", "20", "--rates", "250",
                       "--point-s", "0.3"], r"^\| 0 \| 2 \| 4 \| \d+ \| \d+ \(\d+.*\| (none|250) \(\d/1\) \|$"),
    # One daemon run, then one mock-bus test under pytest (the bench's two tables).
    ("simulated_bench.py", ["--burners", "0", "--runs", "1", "--duration", "1", "--test-burners", "0", "--tests",
                            "tests/test_mockbus_sdk.py::test_ping_answers_model_311_and_absent_ids_stay_silent"],
     r"^\| this \| 1 \| [1-9]\d* \| \d+ \| \d+ \|"),
    # One short daemon run per simulated DAQ stream, no burners.
    ("sensor_stream.py", ["--duration", "2", "--burners", "0"], r"^stale holds per stream: python \d+ in 1 runs, rust \d+ in 1 runs$"),
    # One short run per transport, no burners: the hand-over's split is printed for both.
    ("pty_handoff.py", ["--seconds", "0.5", "--runs", "1", "--burners", "0"],
     r"^median p99 latency: pty \d+ µs, pipe \d+ µs \(pty / pipe \d+\.\dx\)$"),
    ("slcan_reader_cpu.py", ["--window", "1"], r"^slcan / serial CPU: \d+\.\d+x$"),
    ("reader_stalls.py", ["--window", "0.5", "--burners", "0"], r"^switch\+freeze / default: p99 \d+\.\d+, p99\.9 \d+\.\d+"),
    # A fault a second: torque off, brown-out, hardware error, then the bus unplugged and back.
    ("soak.py", ["--seconds", "6", "--fault-every", "1"], r"^fault_events\s+[1-9]"),
    ("syncwrite_cycle.py", [], r"^\s+12\s+4M \|"),
    # One run of the HIL glitch test, its recovery holds read from its MCAP.
    ("recovery_holds.py", ["--runs", "1"], r"^recovery holds: median \d+\.\d+ s, longest \d+\.\d+ s, \d+ of \d+ over 0\.5 s; \d+ of 1 runs failed"),
    # One servo, one inertia, guard off and on (after a short identification of the servo model).
    ("passivity.py", ["--servos", "lag 25 ms", "--factors", "1", "--seconds", "4", "--identify-seconds", "8",
                      "--skip-fidelity", "--skip-stiff"], r"^guard on: [0-9] of 1 gripped sessions"),
    # The same through the daemon on the wall clock (the default runs the loop in model time).
    ("passivity.py", ["--clock", "wall", "--servos", "lag 25 ms", "--factors", "1", "--seconds", "4",
                      "--identify-seconds", "8", "--skip-fidelity", "--skip-stiff"], r"^guard on: [0-9] of 1 gripped sessions"),
    ("loop_timing.py", ["--load", "daemon", "--rates", "250", "--joints", "1", "--point-s", "0.3", "--min-cycles", "1",
                        "--no-phase-lock-section"], r"^median Python/Rust at SCHED_OTHER: p99 period error"),
    # The daemon load with the Rust reader on a pty DAQ process (Rust loops only).
    # Its reader's longest gap is split into the source's share and the reader's, beside the source's own gaps.
    ("loop_timing.py", ["--load", "daemon", "--sensor", "rust", "--rates", "250", "--joints", "1", "--point-s", "0.3",
                        "--min-cycles", "1", "--no-phase-lock-section"],
     r"rust_fifo .* reader rust-serial SCHED_FIFO: longest gap \d+ µs = source \d+ µs between its writes, then read "
     r"-?\d+ µs after the write, stale \d+; source's longest write gap [1-9]\d* µs \| p99 tail: \d+ of \d+ cycles"),
]
# Benches no case runs, each with the reason (test_every_bench_has_a_case makes it explicit).
SKIPPED = {
    "fidelity.py": "its smallest run (--quick --skip-inertia --seconds 2) is 18 `admittance run` sessions "
                   "(two servos: an identification, then 3 sines and a multi-sine, each without and with "
                   "compensation), about 50 s on a 2-core VM; no option runs fewer sessions",
    "fit_numerics.py": "whole identify runs of 30-drop sets, this tree's fit.py against a commit's, several rounds "
                       "(minutes); what it times is held bit for bit per function by tests/test_ident_fit_numerics.py",
    "fit_numerics_replay.py": "replays every call of a whole identify run through a commit's fit.py (minutes); "
                              "the per-function bit-for-bit claim is tests/test_ident_fit_numerics.py's",
    "identify_perturbed.py": "builds this tree's extension a second time with another plant feature (minutes on a "
                             "fresh machine) and runs the families bench under both (4-5 min); its comparison of "
                             "the two runs is tested below (test_the_perturbed_bench_reports_what_changed)",
}


def test_every_bench_has_a_case():
    listed = {script for script, _, _ in CASES} | set(SKIPPED)
    # A leading underscore marks a module the benches share (bench/_rt_sleep.py), not a bench.
    assert listed == {p.name for p in (ROOT / "bench").glob("*.py") if not p.name.startswith("_")}


@pytest.mark.slow  # subprocesses of a few seconds each: not for `make test-thorough`'s bug hunt
@pytest.mark.parametrize(("script", "args", "expected"), CASES, ids=[c[0] for c in CASES])
def test_bench_runs_end_to_end(script, args, expected, tmp_path):
    if script == "soak.py":
        args = [*args, "--out", str(tmp_path / "soak")]  # its default is a new folder it leaves behind
    done = subprocess.run([sys.executable, str(ROOT / "bench" / script), *args], cwd=ROOT,
                          env={**os.environ, "MPLBACKEND": "Agg"}, capture_output=True, text=True, timeout=HANG_S)
    output = done.stdout + done.stderr
    assert done.returncode == 0, f"bench/{script} exited {done.returncode}:\n{output[-3000:]}"
    assert "Traceback" not in output, output[-3000:]
    assert re.search(expected, done.stdout, re.M), f"no line matching {expected!r} in:\n{done.stdout[-3000:]}"


def test_the_perturbed_bench_reports_what_changed():
    """bench/identify_perturbed.py's comparison: a verdict or a name that changed, or a held-out
    error more than 10 % apart, is reported; a held-out error 0.5 % apart is not."""
    sys.path.insert(0, str(ROOT / "bench"))
    try:
        import identify_perturbed as bench
    finally:
        sys.path.remove(str(ROOT / "bench"))

    def row(ok=True, effects=("stribeck",), after=2.0e-3, label="stribeck, 30 trials"):
        return {"family": "regime", "label": label, "seed": 1, "ok": ok, "effects": list(effects), "after": after}

    default = [row(), row(label="spring"), row(label="cogging"), row(label="drag")]
    perturbed = [row(ok=False, effects=()), row(label="spring", after=2.01e-3), row(label="cogging", after=4.0e-3),
                 row(label="drag", effects=("quadratic_drag",))]
    changed = [a["label"] for a, _ in bench.differences(default, perturbed)]
    assert changed == ["stribeck, 30 trials", "cogging", "drag"]
