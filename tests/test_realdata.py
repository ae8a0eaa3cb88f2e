"""The pipeline on measured data (../shared/data/real): converted, identified, sane, and judged
by the admission rules of issue 9.

Skipped when the shared data is absent. The XL330 tests cut their logs short (a window and every
other sample) to stay fast; the full analyses are in docs/real-data.md.
"""

from __future__ import annotations

import math

import pytest

from admittance.formats.dataset import load_dataset
from admittance.ident.identify import IdentifySettings, identify_dataset
from admittance.ident.ladder import effect_ladder
from admittance.formats.converters import convert_files, load_trial

pytestmark = pytest.mark.realdata

XL330_SWINGS = ("10h28m17", "10h28m49", "10h29m21", "10h29m54")
# the hardware's gravity torque over total inertia: 0.546 kg at 0.5 m plus a 0.13 kg, 0.5 m rod
DFKI_GRAVITY = (0.546 * 0.5 + 0.13 * 0.25) * 9.80665
DFKI_INERTIA = 0.546 * 0.25 + 0.13 * 0.25 / 3 + 0.0022


def _xl330_files(real_data):
    raw = real_data / "bam_xl330" / "bam" / "data.bak" / "raw"
    return [raw / f"2026-01-15_{stamp}.json" for stamp in XL330_SWINGS]


def _dfki_files(real_data):
    root = real_data / "dfki_simple_pendulum" / "results"
    return [root / "control_method_pd" / "system_identification" / "data_measured.csv",
            root / "control_method_ddp" / "data_measured.csv",
            root / "control_method_energy_shaping" / "data_measured.csv"]


def test_bam_free_swings_load(real_data):
    for path in _xl330_files(real_data):
        t, theta, tau = load_trial(path, "dynamixel")
        assert tau is None and t[0] == 0.0
        assert 3.9 < t[-1] < 4.1 and 1100 < t.size < 1200
        assert -1.0 < theta[0] < -0.3  # released from below −π/2 (the servo cannot lift it)
        assert abs(theta[-1] + 0.03) < 0.01  # comes to rest near −0.03 rad


def test_xl330_lumped_gravity_over_inertia(real_data, tmp_path):
    folder = convert_files(_xl330_files(real_data), "dynamixel", tmp_path / "xl330", header={"motor": "XL330"},
                           t_stop=2.0, every=2)
    result = identify_dataset(load_dataset(folder), IdentifySettings(max_effects=1)).to_json()
    assert result["mode"] == "lumped"
    assert 66.0 < result["base"]["gravity_per_inertia"] < 75.0  # SOURCE.md: 68–73 s⁻²
    assert 0.0 < result["base"]["damping_per_inertia"] < 3.0
    assert 0.0 < result["base"]["coulomb_per_inertia"] < 5.0
    assert result["rmse_after"] <= result["rmse_before"] < 0.05


def test_xl330_angle_offset_halves_the_heldout_error(real_data, tmp_path):
    """Geometry mode (bob 0.49 kg at 0.1 m, arm assumed 9.4 g): the armature matches BAM's
    (0.0016–0.0018 kg·m²), and the offset found equals the rest angle of the logs."""
    folder = convert_files(_xl330_files(real_data), "dynamixel", tmp_path / "xl330",
                           header={"motor": "XL330", "rod": {"mass": 0.0094, "length": 0.1}, "bob": {"mass": 0.49}},
                           extra={"bob_distance": 0.1}, t_stop=2.0, every=2)
    base, offset, cogging = effect_ladder(load_dataset(folder), [(), ("angle_offset",), ("angle_offset", "cogging")])
    assert 0.0012 < base.params["motor_inertia"] < 0.0026
    assert -0.045 < offset.params["angle_offset"] < -0.015
    assert offset.pooled_rmse < 0.7 * base.pooled_rmse
    assert offset.verdict in ("claimed", "stand-in") and offset.support["folds_supporting"] == 4
    # Issue 9: cogging at a free period (6.8, 1.55, 1.51, 2.92/rev across folds) was the catch-all;
    # on a whole-number period it may help prediction, but it is not claimed with structure left.
    assert cogging.verdict in ("refused", "stand-in")


def _dfki_geometry(real_data, tmp_path):
    """The three runs as docs/real-data.md converts them: full rate, first 3.3 s."""
    return load_dataset(convert_files(
        _dfki_files(real_data), "dfki", tmp_path / "dfki",
        header={"motor": "AK80-6", "rod": {"mass": 0.13, "length": 0.5}, "bob": {"mass": 0.546}},
        extra={"bob_distance": 0.5}, t_stop=3.3))


def test_dfki_identify_weighs_the_torque_gain_on_two_runs(real_data, tmp_path):
    """identify holds out the energy-shaping run and cross-validates on the other two (one fold
    each). The torque gain is refitted from its own starts whatever the linear ranking says, and
    found at 0.87, about 3 σ from 1: on two 3.3 s runs that is the edge of the significance the
    rule asks (the ladder, on all three runs, claims it: next test). The delay collapses the
    inertia and the bias is not significant. (Before issue 9 the gain was refitted only when its
    linearised share of the residual passed 0.2 %; a base fit that ended elsewhere after a 1e-9
    change of its start put it at 0.06 %, and the verdict flipped without the gain being tried.)"""
    result = identify_dataset(_dfki_geometry(real_data, tmp_path)).to_json()
    assert result["mode"] == "geometry"
    assert result["base"]["motor_inertia"] < 0.01  # the reflected rotor is ~0.0022 kg·m²
    assert 0.05 < result["base"]["coulomb"] < 0.4  # the source's own fits: 0.11–0.18 N·m
    assert result["rmse_after"] <= result["rmse_before"] < 0.2
    tried = {e["effect"]: e for e in result["evidence"][0]}
    gain = tried["torque_gain"]
    assert 0.82 < gain["params"]["torque_gain"]["value"] < 0.92 and gain["significance_sigma"] > 2.5
    if gain["accepted"]:
        assert result["effects"] == ["torque_gain"] and gain["crossval"]["folds_supporting"] == 2
    else:
        # At the edge either rule may be the one that declines: the significance asked of a
        # parameter, or the cross-validated gain against its spread over the two folds (1 of 2
        # improves). Which one moved between numpy/scipy releases without the data changing.
        assert result["effects"] == []
        assert "σ from its off value" in gain["reason"] or "within its uncertainty" in gain["reason"], gain["reason"]
    assert tried["time_delay"]["reason"].startswith("not physical") and "motor_inertia" in tried["time_delay"]["reason"]
    assert "σ from its off value" in tried["torque_bias"]["reason"]


def test_dfki_torque_gain_lowers_the_leave_one_out_error(real_data, tmp_path):
    """Fitted on two runs and scored on the third, the gain (the plant's torque_gain, geometry
    mode) lowers every fold's error at one value (0.85–0.87 in each fold). The ladder admits it
    but only as a stand-in: fitted apart, the large swings and the small ones still want models
    far apart (inertia ~5× apart, tens of noise variances gained), so something the library does
    not name is left in these runs, and the gain may be covering part of it."""
    base, gain = effect_ladder(_dfki_geometry(real_data, tmp_path), [(), ("torque_gain",)])
    assert gain.pooled_rmse < 0.85 * base.pooled_rmse
    assert all(g <= b for g, b in zip(gain.heldout_rmse, base.heldout_rmse))
    assert all(0.82 < fold["torque_gain"][0] < 0.92 for fold in gain.fold_values)
    assert gain.verdict == "stand-in" and gain.support["folds_supporting"] == 3
    assert "not one model on the large-swing and the small-swing data" in gain.reason
    assert 0.82 < gain.params["torque_gain"] < 0.92
    assert gain.params["motor_inertia"] < 0.01


def test_dfki_lumped_finds_the_torque_gain(real_data, tmp_path):
    """Γ = G/I matches the hardware; the measured torque acts at ~0.86 of its value."""
    folder = convert_files(_dfki_files(real_data), "dfki", tmp_path / "dfki", t_stop=3.3, every=2)
    (base,) = effect_ladder(load_dataset(folder), [()])
    gamma = base.params["gravity_per_inertia"]
    assert gamma == pytest.approx(DFKI_GRAVITY / DFKI_INERTIA, rel=0.05)
    gain = base.params["inverse_inertia"] * DFKI_GRAVITY / gamma  # κ·I with I = G/Γ
    assert 0.75 < gain < 0.95
    assert math.isfinite(base.pooled_rmse)
