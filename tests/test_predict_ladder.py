"""The leave-one-trial-out effect ladder (admittance ladder)."""

from __future__ import annotations

import json

import pytest

from admittance.cli import main
from admittance.errors import ConfigError
from admittance.formats import paramfile
from admittance.ident import ladder, synthetic
from admittance.formats.dataset import load_dataset


@pytest.fixture(scope="module")
def offset_set(tmp_path_factory):
    """Four short drops with an undeclared 60 mrad angle offset."""
    folder = tmp_path_factory.mktemp("offset")
    spec = synthetic.SynthSpec(n_trials=4, duration=3.0, seed=4, effects={"angle_offset": 0.06})
    return synthetic.generate(folder, spec)


def test_the_true_effect_wins_leave_one_out(offset_set):
    base, offset = ladder.effect_ladder(load_dataset(offset_set), [(), ("angle_offset",)])
    assert offset.pooled_rmse < 0.5 * base.pooled_rmse
    assert offset.params["angle_offset"] == pytest.approx(0.06, abs=0.01)
    assert offset.params["motor_inertia"] == pytest.approx(synthetic.MX64["motor_inertia"], rel=0.05)
    assert len(base.heldout_rmse) == 4 and base.label == "base"
    assert offset.label == "base + angle_offset"
    assert len(offset.fold_values) == 4 and base.fold_values == [{}] * 4
    for fold in offset.fold_values:  # each fold finds it without its left-out trial
        value, sigma = fold["angle_offset"]
        assert value == pytest.approx(0.06, abs=0.01) and 0 < sigma < 0.01
    assert "- base + angle_offset: angle_offset 0.0" in ladder.to_markdown([base, offset], ["a", "b", "c", "d"])


def test_lumped_ladder_refuses_a_torque_gain(tmp_path):
    """Lumped mode already frees the scale of the torque (κ); a gain would be it twice."""
    spec = synthetic.SynthSpec(n_trials=2, duration=1.0, seed=1, with_torque=True, geometry=False)
    dataset = load_dataset(synthetic.generate(tmp_path, spec))
    with pytest.raises(ConfigError, match="torque_gain needs geometry"):
        ladder.effect_ladder(dataset, [("torque_gain",)])


def test_bad_rungs_are_config_errors(offset_set):
    dataset = load_dataset(offset_set)
    with pytest.raises(ConfigError, match="unknown effect"):
        ladder.effect_ladder(dataset, [("wobble",)])
    with pytest.raises(ConfigError, match="at least two"):
        ladder.effect_ladder(ladder_one_trial(dataset), [()])
    with pytest.raises(ConfigError, match="not a parameter"):
        ladder.effect_ladder(dataset, [()], start={"colour": 1.0})


def ladder_one_trial(dataset):
    from dataclasses import replace

    return replace(dataset, trials=dataset.trials[:1])


def test_cli_writes_table_json_and_parameter_files(offset_set, tmp_path, capsys):
    out = tmp_path / "ladder.json"
    params = tmp_path / "params"
    assert main(["ladder", str(offset_set), "--rung", "", "--rung", "angle_offset",
                 "--json", str(out), "--params-dir", str(params)]) == 0
    table = capsys.readouterr().out
    assert "| base + angle_offset |" in table and "pooled (mrad)" in table
    rungs = json.loads(out.read_text())
    assert [r["effects"] for r in rungs] == [[], ["angle_offset"]]
    doc = paramfile.load(params / "base_angle_offset.toml")
    assert doc["fit"]["effects"] == ["angle_offset"] and doc["model"]["mode"] == "geometry"
    assert (params / "base.toml").is_file()



@pytest.mark.parametrize("start", ["cogging_period=abc", "cogging_period=nan", "cogging_period=1,2", "cogging_period"])
def test_cli_start_value_that_is_not_a_number_is_one_line(offset_set, start, capsys):
    assert main(["ladder", str(offset_set), "--rung", "", "--start", start]) != 0
    err = capsys.readouterr().err.strip()
    assert "--start" in err and "\n" not in err


def test_start_values_apply_only_to_rungs_that_free_them(offset_set):
    dataset = load_dataset(offset_set)
    plain, with_start = ladder.effect_ladder(dataset, [()]), ladder.effect_ladder(
        dataset, [()], start={"cogging_amplitude": 0.05, "cogging_period": 3.0})
    assert with_start[0].params["cogging_amplitude"] == 0.0
    assert with_start[0].pooled_rmse == pytest.approx(plain[0].pooled_rmse)
