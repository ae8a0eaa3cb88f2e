"""The format pages ship inside the package, are reachable from --help, and name every key and
column the code reads or writes (a key added to the code without its line in the page fails here)."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

from admittance import cli, docs
from admittance.daemon import mcap_recording, recording
from admittance.formats import converters as loaders

REPO = Path(__file__).resolve().parents[1]
DATASET_COMMANDS = ("identify", "thesis", "predict", "ladder", "breakaway", "convert")


def documented(topic: str) -> set[str]:
    """Every `name` in backticks on the page (`[bob]` and `[[trials]]` count as bob and trials)."""
    return {name.strip("[]") for name in re.findall(r"`([^`\s]+)`", docs.page(topic))}


@pytest.mark.parametrize("topic", sorted(docs.TOPICS))
def test_docs_command_prints_the_packaged_page(topic, capsys):
    assert cli.main(["docs", topic]) == 0
    text = capsys.readouterr().out
    assert text.startswith("# ") and f"admittance docs {topic}" in text
    # the repository's docs/ holds the same page (a link), so the two cannot drift apart
    assert (REPO / "docs" / f"{topic}.md").read_text(encoding="utf-8") == text


@pytest.mark.parametrize("command", DATASET_COMMANDS)
def test_dataset_commands_help_points_at_the_shipped_page(command, capsys):
    with pytest.raises(SystemExit):
        cli.main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "admittance docs datasets" in text
    assert "shared/" not in text and "contracts" not in text


def test_every_manifest_key_the_dataset_reader_reads_is_documented():
    source = (REPO / "admittance" / "formats" / "dataset.py").read_text()
    read = set(re.findall(r"""\.get\(["'](\w+)["']""", source)) | {"mass", "length"}
    assert read >= {"trials", "motor", "file", "bob_distance", "format", "encoder_ticks"}
    assert read - documented("datasets") == set()


def test_every_trial_format_is_documented():
    page = documented("datasets")
    assert set(loaders.LOADERS) | {"csv"} <= page


def test_every_recorded_column_and_manifest_key_is_documented(tmp_path):
    rec = recording.Recorder(tmp_path, [(1, "MX-64")], measured_theta=True, t0=0.0,
                             joint_info={1: {"model": "MX-64"}})
    rec.set_targets({f"1.{k}": 0.1 for k in recording.TARGET_KEYS})
    rec.set_targets({f"1.{k}": 0.2 for k in recording.TARGET_KEYS})  # a live change: params_changed

    manifest = tomllib.loads((tmp_path / "manifest.toml").read_text())
    keys = set(manifest) | {k for trial in manifest["trials"] for k in trial} | set(recording.TARGET_KEYS)
    page = documented("recordings")
    assert set(recording.COLUMNS) - page == set()
    assert keys - page == set()
    for schema in (mcap_recording.CYCLE_SCHEMA, mcap_recording.SESSION_SCHEMA, mcap_recording.PARAMS_SCHEMA,
                   mcap_recording.EVENT_SCHEMA):
        assert schema["title"] in page
        assert set(schema["properties"]) - page == set(), schema["title"]


def test_the_servo_page_is_the_key_declaration_that_validates_them():
    from admittance.formats import paramfile

    assert docs.page("servo") == docs.servo_page()
    assert set(paramfile.SERVO_KEYS) <= documented("servo")
