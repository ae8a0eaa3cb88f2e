"""Recordings are datasets: the contract's loader reads them, segments roll over, short tails are
dropped; and a real session goes record → identify → reload (the `hil` test at the end)."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest
import tomli_w

from admittance.daemon.recording import Recorder
from admittance.ident.dataset import load_dataset


def batch(t0: float, n: int, read_every: int = 1) -> dict[str, np.ndarray]:
    t = t0 + np.arange(n) * 1e-3
    present = np.sin(t)
    present[np.arange(n) % read_every != 0] = np.nan
    return {"t": t, "tau": 0.1 * np.cos(t), "force": np.cos(t), "theta_model": np.sin(t),
            "omega_model": np.cos(t), "theta_goal": np.sin(t), "theta_present": present,
            "cycle": np.round(t * 1e3), "fault": np.zeros(n)}


def test_a_recording_loads_as_a_geometry_dataset_with_measured_theta(tmp_path):
    rec = Recorder(tmp_path, [(1, "MX-64"), (3, "MX-28")], measured_theta=True, t0=100.0)
    for k in range(10):
        for joint in (1, 3):
            rec.append(joint, batch(100.0 + k * 0.05, 50, read_every=5))
    rec.close()
    dataset = load_dataset(tmp_path)
    assert dataset.mode == "geometry" and [tr.name for tr in dataset.trials] == ["joint1_000.csv", "joint3_000.csv"]
    trial = dataset.trials[0]
    assert trial.n_samples == 100 and trial.t[0] == pytest.approx(0.0)
    assert np.allclose(trial.theta, np.sin(trial.t + 100.0))
    assert trial.load_inertia < 1e-9 and trial.gravity_torque < 1e-6
    assert tomllib.loads((tmp_path / "manifest.toml").read_text())["theta_source"] == "present position"


def test_segments_roll_over_and_a_short_tail_is_dropped(tmp_path):
    rec = Recorder(tmp_path, [(1, "MX-64")], measured_theta=False, t0=0.0, segment_s=1.0)
    for k in range(25):  # 2.5 s in 0.1 s batches: segments [0, 1), [1, 2), [2, 2.5)
        rec.append(1, batch(k * 0.1, 100))
    rec.append(1, batch(3.0, 3))  # opens a fourth segment of 3 rows: too short, dropped at close
    rec.close()
    names = [tr.name for tr in load_dataset(tmp_path).trials]
    assert names == ["joint1_000.csv", "joint1_001.csv", "joint1_002.csv"]
    assert not (tmp_path / "joint1_003.csv").exists()
    assert rec.rows[1] == 2503


def test_an_unwritable_folder_is_a_config_error(tmp_path):
    from admittance.errors import ConfigError

    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(ConfigError, match="record: cannot create"):
        Recorder(blocker / "sub", [(1, "MX-64")], measured_theta=True, t0=0.0)


@pytest.mark.hil
@pytest.mark.slow
def test_record_identify_reload_round_trip(tmp_path):
    """A bench session recorded by the daemon is refitted by `identify`; the fit, reloaded as the
    joint's parameter file, gives back the felt (virtual) joint: inertia and damping within 30 %,
    Coulomb within 50 % + 5 mN·m (the servo's own following error shows in the measured angle)."""
    from daemon_process import running_daemon, wait_alive, wait_for_cycles, wait_for_state
    from helpers import free_endpoint

    from admittance.daemon import config
    from admittance.daemon.zenoh_iface import Client
    from admittance.ident.identify import IdentifySettings, identify_dataset

    inertia, damping, coulomb = 0.02, 0.1, 0.02
    endpoint, prefix = free_endpoint(), "hil/rec"
    cfg = {
        "bus": {"port": "mock"},
        "joints": [{"id": 1, "model": "MX-64", "virtual_inertia": inertia, "virtual_damping": damping,
                    "virtual_coulomb": coulomb}],
        "sensor": {"kind": "optoforce", "port": "mock", "lever_arm": 0.105},
        "loop": {"sync_read_divisor": 2, "stale_timeout_ms": 500.0},  # no hold when CI stalls the reader (the most allowed)
        "zenoh": {"prefix": prefix, "listen": [endpoint]},
        "record": {"path": "rec", "segment_s": 2.0},
        "bench": {"profile": "sine:amplitude=0.12,frequency=0.7", "hand_delay_s": 0.5},
    }
    path = tmp_path / "daemon.toml"
    path.write_text(tomli_w.dumps(cfg))
    with running_daemon(path) as daemon:
        wait_alive(endpoint, prefix)
        with Client([endpoint]) as client:
            pushed = wait_for_state(client, prefix, lambda m: abs(m["joints"][0]["tau"]) > 0.03, "the hand pushing")
            wait_for_cycles(client, prefix, 5500, after=pushed)  # ≥ 5.5 s: about 4 periods, 3 segments
    assert daemon.returncode == 0, daemon.stderr

    dataset = load_dataset(tmp_path / "rec")
    assert len(dataset.trials) >= 3 and dataset.has_torque
    fit = identify_dataset(dataset, IdentifySettings(max_effects=0))
    fitted = tmp_path / "felt.toml"
    fit.write_params(fitted, source="test round trip")

    cfg["joints"][0] = {"id": 1, "model": "MX-64", "params": str(fitted)}
    path.write_text(tomli_w.dumps(cfg))
    joint = config.load_config(path).joints[0]  # the reload: virtual_* default to the refit
    assert joint.virtual_inertia == pytest.approx(inertia, rel=0.3)
    assert joint.virtual_damping == pytest.approx(damping, rel=0.3)
    assert joint.virtual_coulomb == pytest.approx(coulomb, abs=0.5 * coulomb + 0.005)
    assert math.isfinite(fit.to_json()["rmse_after"])
