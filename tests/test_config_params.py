"""The shipped parameter files (admittance/data/params/*.toml) hold the thesis's fitted averages."""

from __future__ import annotations

import csv
import importlib.util
import statistics
import tomllib

import pytest

from admittance import data

MOTORS = {"MX-28": "mx28.toml", "MX-64": "mx64.toml", "MX-106": "mx106.toml"}
# (bob distance cm, direction, repeat) of the friction typo in table 3.2, and its correction
TYPO = ("MX-28", "20", "ccw", "3")
TYPO_FIXED = 0.0044


def _table_means(thesis_data, motor):
    with open(thesis_data / "optimized_parameters.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["motor"] == motor]
    friction = []
    for r in rows:
        key = (r["motor"], r["bob_distance_cm"], r["direction"], r["repeat"])
        friction.append(TYPO_FIXED if key == TYPO else float(r["friction_Nm"]))
    return len(rows), {
        "motor_inertia": statistics.mean(float(r["inertia_motor_kgm2"]) for r in rows),
        "damping": statistics.mean(float(r["damping_Nms_per_rad"]) for r in rows),
        "coulomb": statistics.mean(friction),
    }


def _load(repo_root, name):
    with open(data.path("params", name), "rb") as fh:
        return tomllib.load(fh)


@pytest.mark.parametrize("motor", sorted(MOTORS))
def test_params_are_the_thesis_means(repo_root, thesis_data, motor):
    n, means = _table_means(thesis_data, motor)
    assert n == 30
    doc = _load(repo_root, MOTORS[motor])
    for name, value in means.items():
        assert doc["params"][name] == pytest.approx(value, rel=2e-3), name


@pytest.mark.parametrize("motor", sorted(MOTORS))
def test_model_table_is_contract_2(repo_root, motor):
    doc = _load(repo_root, MOTORS[motor])
    assert doc["model"]["motor"] == motor
    assert doc["model"]["friction"] == "tanh"
    assert doc["model"]["mode"] == "geometry"
    assert "thesis" in doc["model"]["source"]
    assert doc["params"]["tanh_k"] == 100.0


def test_mx28_friction_typo_is_corrected(repo_root, thesis_data):
    """With the 0.0440 typo the mean would be the thesis's printed 0.0078."""
    with open(thesis_data / "optimized_parameters.csv", newline="") as fh:
        raw = [float(r["friction_Nm"]) for r in csv.DictReader(fh) if r["motor"] == "MX-28"]
    assert statistics.mean(raw) == pytest.approx(0.0078, abs=5e-5)
    assert _load(repo_root, "mx28.toml")["params"]["coulomb"] == pytest.approx(0.0064, abs=1e-4)


@pytest.mark.skipif(importlib.util.find_spec("admittance.formats.paramfile") is None,
                    reason="admittance.formats.paramfile not written yet")
@pytest.mark.parametrize("name", sorted(MOTORS.values()))
def test_paramfile_reader_accepts_them(repo_root, name):
    from admittance.formats import paramfile

    loaded = paramfile.load(data.path("params", name))
    assert loaded["model"]["friction"] == "tanh"
    vector = paramfile.full_vector(loaded["params"])
    assert vector[0] == _load(repo_root, name)["params"]["motor_inertia"]
    assert vector[paramfile.PARAM_NAMES.index("tanh_k")] == 100.0
