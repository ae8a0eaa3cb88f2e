"""Every subcommand explains itself: a description, help on every argument, the default of
every option that takes a value, a unit for every number with one, and one metavar per kind."""

from __future__ import annotations

import argparse
import re

import pytest

from admittance.cli import build_parser

# A float option's help names its unit (or says it is a fraction or a count).
UNIT = re.compile(r"\b(s|Hz|N|m|rad|seconds|fraction|dimensionless)\b|N·m|kg·m²|bit/s|count/N")
SECONDS = {"duration", "timeout", "settle", "dry_run"}
FOLDERS = {"out_dir", "report", "params_dir", "record"}
SKIP = (argparse._HelpAction, argparse._VersionAction, argparse._SubParsersAction)


def subcommands():
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sorted(action.choices.items())


def arguments(parser):
    return [a for a in parser._actions if not isinstance(a, SKIP)]


@pytest.mark.parametrize("name, parser", subcommands())
def test_every_subcommand_explains_itself(name, parser):
    assert parser.description, f"{name}: no description"
    for action in arguments(parser):
        flag = "/".join(action.option_strings) or action.dest
        assert action.help, f"{name} {flag}: no help"
        takes_value = action.option_strings and action.nargs != 0
        if takes_value and not action.required:
            assert "default" in action.help, f"{name} {flag}: the help does not say the default"
        if takes_value and action.type is float:
            assert UNIT.search(action.help), f"{name} {flag}: a number without its unit: {action.help!r}"
        if action.dest in SECONDS and takes_value:
            assert action.metavar == "S", f"{name} {flag}: seconds are metavar S, not {action.metavar}"
        if action.dest in FOLDERS:
            assert action.metavar == "DIR", f"{name} {flag}: a folder is metavar DIR, not {action.metavar}"
        if action.dest in ("json", "json_out", "stats_json"):
            assert action.metavar == "FILE.json", f"{name} {flag}: JSON output is metavar FILE.json"
        if action.dest == "dataset":
            assert action.metavar == "DATASET_DIR", f"{name}: the dataset is metavar DATASET_DIR"


def test_the_walk_covers_every_subcommand():
    names = {name for name, _ in subcommands()}
    assert {"run", "monitor", "set", "tare", "mock-bench", "setup", "identify", "synth", "thesis", "breakaway",
            "predict", "ladder", "convert", "fidelity"} <= names
