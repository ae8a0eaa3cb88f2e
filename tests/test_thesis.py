"""The thesis's alternating LM procedure (Rust-backed) and its pure-Python baseline."""

from __future__ import annotations

import csv
import io
import math

import numpy as np
import pytest

from admittance import sim
from admittance.cli import main
from admittance.errors import DataError
from admittance.thesis import alternating as thesis
from oracles import thesis_ode3 as baseline_thesis
from admittance.formats.dataset import load_dataset, load_geometry
from admittance.formats.converters import ConvertedTrial, write_dataset

ROD = {"mass": 0.0402, "length": 0.456}
BOB = {"mass": 0.1034}
TRUTH = {"motor_inertia": 0.0147, "damping": 0.035, "coulomb": 0.084}


def tanh_dataset(folder, distances=(0.3,), duration=4.0, noise=0.0, motor="MX-64"):
    """Drops simulated with the thesis's own model (tanh friction), released at rest."""
    rng = np.random.default_rng(3)
    trials = []
    for k, d in enumerate(distances):
        t = np.arange(0.0, duration, 1 / 120)
        inertia, gravity = load_geometry(ROD, BOB, d)
        rt = sim.make_trial(t, None, inertia, gravity)
        sign = 1 if k % 2 == 0 else -1
        theta = sim.simulate(rt, TRUTH, sign * 1.5, 0.0, max_step=1e-4, friction="tanh")
        direction = "cw" if sign > 0 else "ccw"
        theta = theta + rng.normal(0, noise, t.size) if noise else theta
        trials.append(ConvertedTrial(f"d{round(d * 100)}_{direction}_{k}", t, theta, None,
                                     {"bob_distance": d, "direction": direction}))
    return write_dataset(folder, trials, {"motor": motor, "rod": ROD, "bob": BOB})


def test_alternating_scheme_reaches_the_optimum_of_a_separable_problem():
    """With orthogonal sensitivities the (I, B) and F steps do not interact: exact in one cycle."""
    x = np.linspace(0, 1, 200)
    basis = np.array([np.sin(2 * np.pi * x), np.cos(2 * np.pi * x), np.sin(4 * np.pi * x)])
    truth = np.array([0.02, 0.03, 0.09])

    def simulate(rows):
        return rows @ basis

    fit = thesis.alternating_fit(simulate, truth @ basis, (0.04, 0.01, 0.12), cycles=1, tol=1e-10)
    np.testing.assert_allclose([fit.inertia_total, fit.damping, fit.friction], truth, rtol=1e-6)
    assert fit.rmse < 1e-9
    assert fit.n_simulations > 3


def test_alternating_scheme_rejects_zero_cycles():
    with pytest.raises(ValueError):
        thesis.alternating_fit(lambda rows: rows, np.zeros(3), (1, 1, 1), cycles=0)


def test_rust_and_python_ode3_simulators_agree(tmp_path):
    trial = load_dataset(tanh_dataset(tmp_path / "ds", duration=3.0)).trials[0]
    rows = np.array([[0.03, 0.03, 0.09], [0.025, 0.04, 0.05]])
    rust = thesis.rust_simulator(trial, (trial.theta[0], 0.0))(rows)
    python = baseline_thesis.ode3_simulator(trial, (trial.theta[0], 0.0))(rows)
    assert rust.shape == python.shape == (2, trial.n_samples)
    # different integrators (semi-implicit Euler vs Bogacki–Shampine) at the same 1 ms step
    assert np.max(np.abs(rust - python)) < 5e-3


def test_thesis_fit_on_its_own_model_finds_the_inertia(tmp_path):
    dataset = load_dataset(tanh_dataset(tmp_path / "ds", distances=(0.3, 0.4), noise=0.002))
    rows = thesis.fit_dataset(dataset)
    for row, trial in zip(rows, dataset.trials):
        total = TRUTH["motor_inertia"] + trial.load_inertia
        assert row.inertia_total == pytest.approx(total, rel=0.03)
        # the fit explains the swing far better than the initial guess does
        guess = thesis.rust_simulator(trial, (trial.theta[0], 0.0))(
            np.array([[thesis.INITIAL_INERTIA, thesis.INITIAL_DAMPING, 0.1061]]))[0]
        assert row.rmse < 0.5 * math.sqrt(np.mean((guess - trial.theta) ** 2))


def test_baseline_matches_the_rust_thesis_fit(tmp_path):
    dataset = load_dataset(tanh_dataset(tmp_path / "ds", duration=2.5))
    rust = thesis.fit_dataset(dataset, cycles=2)[0]
    python = baseline_thesis.fit_dataset(dataset, cycles=2)[0]
    assert python.inertia_total == pytest.approx(rust.inertia_total, rel=0.02)
    assert python.damping == pytest.approx(rust.damping, rel=0.1, abs=2e-3)
    assert python.friction == pytest.approx(rust.friction, rel=0.05)


def test_rod_inertia_script_uses_half_length():
    script, correct = thesis.rod_inertias({"rod": ROD})
    assert script == pytest.approx((1 / 3) * 0.0402 * 0.228**2)
    assert correct == pytest.approx((1 / 3) * 0.0402 * 0.456**2)
    assert thesis.rod_inertias({"rod": None}) == (0.0, 0.0)


def _row(name, d, direction, i_total=0.03, friction=0.08, damping=0.03):
    return thesis.ThesisRow(name, d, direction, friction, i_total - 0.01, i_total - 0.012, i_total, damping, 0.01)


def test_table_layout_and_averages():
    rows = [_row("a", 20.0, "cw", 0.02), _row("b", 20.0, "ccw", 0.022, damping=0.05),
            _row("c", 40.0, "cw", 0.04), _row("d", 40.0, "ccw", 0.042)]
    labels = [label for label, _ in thesis.summary_rows(rows)]
    assert labels == ["c", "d", "Average at 40 cm", "a", "b", "Average at 20 cm", "Motor average"]
    summary = dict(thesis.summary_rows(rows))
    assert summary["Average at 20 cm"]["damping"] == pytest.approx(0.04)
    assert "inertia_total" not in summary["Motor average"]
    assert summary["Motor average"]["inertia_motor"] == pytest.approx(0.021)
    md = thesis.to_markdown(rows, "MX-64")
    assert "| **Average at 40 cm** | 0.0800 |" in md
    table = list(csv.DictReader(io.StringIO(thesis.to_csv(rows))))
    assert [r["trial"] for r in table][-1] == "Motor average"
    assert float(table[0]["inertia_total"]) == 0.02


def test_thesis_row_motor_inertias(tmp_path):
    dataset = load_dataset(tanh_dataset(tmp_path / "ds", duration=1.0))
    trial = dataset.trials[0]
    fit = thesis.AlternatingResult(0.03, 0.03, 0.08, 0.0, 1)
    row = thesis.thesis_row(trial, dataset.geometry, fit)
    script, correct = thesis.rod_inertias(dataset.geometry)
    assert row.inertia_motor_correct_rod == pytest.approx(0.03 - trial.load_inertia)
    assert row.inertia_motor - row.inertia_motor_correct_rod == pytest.approx(correct - script)
    assert row.bob_distance_cm == 30.0 and row.direction == "cw"


def test_initial_friction_from_table_3_1():
    assert thesis.initial_friction_for("MX-64 (synthetic)") == 0.1061
    assert thesis.initial_friction_for("mx-28") == 0.0176
    assert thesis.initial_friction_for("XL330") == 0.1234


def test_lumped_dataset_is_refused(tmp_path):
    t = np.linspace(0, 1, 50)
    folder = write_dataset(tmp_path / "ds", [ConvertedTrial("a", t, np.cos(t))])
    with pytest.raises(DataError, match="geometry"):
        thesis.fit_dataset(load_dataset(folder))


def test_initial_state_options(tmp_path):
    trial = load_dataset(tanh_dataset(tmp_path / "ds", duration=1.0)).trials[0]
    assert thesis.initial_state(trial, "rest") == (trial.theta[0], 0.0)
    theta0, omega0 = thesis.initial_state(trial, "data")
    assert theta0 == pytest.approx(trial.theta[0], abs=1e-3)
    assert omega0 == pytest.approx(0.0, abs=0.2)  # released at rest
    with pytest.raises(ValueError):
        thesis.initial_state(trial, "guess")


def test_cli_writes_markdown_and_csv(tmp_path, capsys):
    folder = tanh_dataset(tmp_path / "ds", duration=1.5)
    assert main(["thesis", str(folder), "--out", str(tmp_path / "out"), "--cycles", "1"]) == 0
    assert "Motor average" in capsys.readouterr().out
    assert (tmp_path / "out" / "thesis_table.md").is_file()
    assert (tmp_path / "out" / "thesis_table.csv").read_text().startswith("trial,")


def test_cli_missing_dataset_is_one_line_error(tmp_path, capsys):
    assert main(["thesis", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "not found" in err


@pytest.mark.parametrize("option", [["--cycles", "0"], ["--initial-inertia", "-1"], ["--initial-friction", "nan"],
                                    ["--initial-damping", "inf"]])
def test_cli_bad_starting_values_are_one_line_errors(tmp_path, capsys, option):
    assert main(["thesis", str(tmp_path / "nope"), *option]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and option[0] in err
