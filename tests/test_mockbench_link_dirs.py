"""The simulated bench's folder of stable links (``<tmp>/admittance-bench-<pid>-*``) is removed on
every way out of a bench, and one left by a process that died without stopping its bench (SIGKILL)
is removed by the next bench made, never a folder that might not be a dead bench's."""

from __future__ import annotations

import gc
import os
import signal
import subprocess
import sys
import tempfile

import pytest

from admittance.mockbench import link_dirs as link_dirs_module
from admittance.mockbench.bench import BenchConfig, MockBench
from admittance.mockbench.link_dirs import remove_orphan_link_dirs


@pytest.fixture
def tmp(tmp_path, monkeypatch):
    """tempfile's folder (where benches put their links) is this test's own."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    return tmp_path


def link_dirs(tmp) -> list[str]:
    return sorted(p.name for p in tmp.glob("admittance-bench-*"))


def still() -> MockBench:
    return MockBench(BenchConfig(profile="still", sensor_stream="rust"))


def test_a_bench_stopped_leaves_no_folder(tmp):
    with still() as bench:
        assert link_dirs(tmp) == [os.path.basename(bench._link_dir)]
        assert bench._link_dir.startswith(str(tmp / f"admittance-bench-{os.getpid()}-"))
    assert link_dirs(tmp) == []


class FailingSensor:
    def __init__(self, sensor, fail_on):
        self.sensor, self.fail_on = sensor, fail_on

    def start(self):
        if self.fail_on == "start":
            raise OSError("the sensor would not start")
        self.sensor.start()

    def stop(self):
        self.sensor.stop()
        if self.fail_on == "stop":
            raise OSError("the sensor would not stop")


def test_a_bench_whose_start_fails_in_a_with_block_leaves_no_folder(tmp):
    bench = still()
    bench.sensor = FailingSensor(bench.sensor, "start")
    with pytest.raises(OSError, match="would not start"), bench:
        pass
    assert link_dirs(tmp) == []


def test_a_stop_that_raises_still_removes_the_folder(tmp):
    bench = still()
    bench.start()
    bench.sensor = FailingSensor(bench.sensor, "stop")
    with pytest.raises(OSError, match="would not stop"):
        bench.stop()
    assert link_dirs(tmp) == []


KILLED_BENCH = """
import os, signal
from admittance.mockbench.bench import BenchConfig, MockBench
bench = MockBench(BenchConfig(profile="still"))
bench.start()
print(bench._link_dir, flush=True)
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_the_folder_of_a_killed_bench_is_removed_by_the_next_bench(tmp):
    proc = subprocess.run([sys.executable, "-c", KILLED_BENCH], env={**os.environ, "TMPDIR": str(tmp)},
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    left = proc.stdout.strip()
    assert sorted(os.listdir(left)) == ["dxl", "sensor"], "the killed bench left its links behind"
    with still() as bench:
        assert link_dirs(tmp) == [os.path.basename(bench._link_dir)], "the dead process's folder is still there"


def dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait(timeout=60)
    return proc.pid


def test_only_folders_of_dead_benches_holding_only_their_links_are_removed(tmp):
    gone = dead_pid()

    def folder(name: str, *links: str):
        path = tmp / name
        path.mkdir()
        for link in links:
            (path / link).symlink_to("/dev/null")
        return path

    orphan = folder(f"admittance-bench-{gone}-abc123", "dxl", "sensor", f"dxl.{gone}.new")
    empty_orphan = folder(f"admittance-bench-{gone}-def456")
    live = folder(f"admittance-bench-{os.getpid()}-ghi789", "dxl")  # this process runs
    legacy = folder("admittance-bench-k2j4h5g6", "dxl")  # no pid in its name: whose, unknown
    other_file = folder(f"admittance-bench-{gone}-jkl012", "dxl")
    (other_file / "notes.txt").write_text("not a bench's link")
    real_file = folder(f"admittance-bench-{gone}-mno345")
    (real_file / "sensor").write_text("a regular file named like a link")
    not_a_dir = tmp / f"admittance-bench-{gone}-pqr678"
    not_a_dir.write_text("")
    kept = [live, legacy, other_file, real_file, not_a_dir]
    if os.getuid() == 0:  # root can make a folder of another user's
        foreign = folder(f"admittance-bench-{gone}-stu901", "dxl")
        os.chown(foreign, 12345, 12345)
        kept.append(foreign)

    removed = remove_orphan_link_dirs(str(tmp))
    assert sorted(removed) == sorted([str(orphan), str(empty_orphan)])
    assert all(path.exists() for path in kept)
    assert not orphan.exists() and not empty_orphan.exists()


def test_a_bench_folder_is_named_after_its_process():
    assert link_dirs_module._LINK_DIR_NAME.fullmatch(f"admittance-bench-{os.getpid()}-x_y1")


def test_a_bench_never_stopped_leaves_no_folder_once_collected_or_at_exit(tmp):
    """A lockstep bench (bench/passivity.py) only lends its bus and is never started or stopped."""
    bench = still()
    folder = bench._link_dir
    del bench
    gc.collect()
    assert not os.path.exists(folder)
    at_exit = "from admittance.mockbench.bench import MockBench; keep = MockBench(profile='still'); print(keep._link_dir)"
    proc = subprocess.run([sys.executable, "-c", at_exit], env={**os.environ, "TMPDIR": str(tmp)},
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip(), proc.stderr
    assert link_dirs(tmp) == []
