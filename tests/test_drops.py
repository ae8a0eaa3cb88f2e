"""``admittance drops`` on the simulated bench: the thesis's procedure through the bus (torque on
to the start angle, release, Present Position read back to back), a dataset identify takes, and
identify recovering the simulated servo's own plant; the safety gates (start angle inside the
limits, a swing that leaves them is caught)."""

from __future__ import annotations

import json
import math
import tomllib

import pytest
import tomli_w

from admittance.cli import main
from admittance.drops.procedure import Joint
from admittance.drops.simulated import simulated_session
from admittance.errors import DeviceError
from admittance.formats import paramfile
from admittance.mockbench.bench import params_path

ROD = {"mass": 0.0402, "length": 0.456}
BOB = {"mass": 0.1034}
TOLERANCE = {"motor_inertia": 0.05, "damping": 0.10, "coulomb": 0.15}  # identify's (README, "Measured")


@pytest.fixture(scope="module")
def drops(tmp_path_factory):
    out = tmp_path_factory.mktemp("drops") / "ds"
    assert main(["drops", str(out), "--distances", "0.2,0.3,0.4", "--repeats", "1", "--duration", "4",
                 "--start-angle", "1.2", "--move-speed", "1.5"]) == 0
    return out


def test_drops_write_a_dataset_of_every_distance_and_direction(drops):
    manifest = tomllib.loads((drops / "manifest.toml").read_text())
    assert manifest["rod"] == ROD and manifest["bob"] == BOB
    trials = manifest["trials"]
    assert sorted((t["bob_distance"], t["direction"]) for t in trials) == [
        (d, s) for d in (0.2, 0.3, 0.4) for s in ("ccw", "cw")]
    for t in trials:
        assert t["read_rate_hz"] > 100  # back-to-back reads, not a timer's
        rows = (drops / t["file"]).read_text().splitlines()
        first = [float(v) for v in rows[1].split(",")]
        assert rows[0] == "t,theta" and len(rows) > 400
        assert math.copysign(1, first[1]) == (1 if t["direction"] == "cw" else -1)
        assert abs(abs(first[1]) - 1.2) < 0.06  # released from the start angle


def test_identify_on_the_drops_recovers_the_simulated_servos_plant(drops, tmp_path):
    truth = paramfile.load(params_path("MX-64"))
    assert main(["identify", str(drops), "--json", str(tmp_path / "out.json"), "--friction",
                 truth["model"]["friction"], "--max-effects", "0", "--quiet"]) == 0
    fitted = json.loads((tmp_path / "out.json").read_text())["params"]
    errors = {name: fitted[name] / truth["params"][name] - 1.0 for name in TOLERANCE}
    print("relative errors:", {n: f"{100 * e:+.1f} %" for n, e in errors.items()})
    assert all(abs(errors[n]) < TOLERANCE[n] for n in TOLERANCE), errors


def test_a_start_angle_outside_the_limits_is_refused_before_anything_moves(tmp_path, capsys):
    config = tmp_path / "bench.toml"
    config.write_text(tomli_w.dumps({"bus": {"port": "/dev/does-not-exist"},
                                     "joints": [{"id": 1, "model": "MX-64",
                                                 "limits": {"position_min": -1.0, "position_max": 1.0}}],
                                     "sensor": {"kind": "optoforce", "port": "/dev/null", "lever_arm": 0.1}}))
    assert main(["drops", str(tmp_path / "out"), "--config", str(config), "--start-angle", "0.95"]) != 0
    assert "must lie inside the joint's position limits" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_swing_that_leaves_the_limits_is_caught(tmp_path):
    """A zero 500 ticks off: the pendulum's true bottom is at −0.77 rad, so from +0.5 rad (1.27 rad
    from the bottom) it swings past −1.0 rad, the limit (Coulomb friction takes about 0.35 rad of
    the half swing); the servo catches it there (torque on) and the drop stops."""
    joint = Joint(1, zero_tick=2048 + 500, position_min=-1.0, position_max=1.0, margin=0.1)
    with simulated_session(ROD, BOB, 0.4, joint, say=lambda _: None) as session:
        session.move_to(0.5, 1.5)
        with pytest.raises(DeviceError, match="caught"):
            session.drop(4.0)
        assert session.bus.read_raw(1, "Torque Enable") == 1
