"""Dataset folders (shared/contracts/datasets.md): geometry, lumped mode, and every kind of bad
input failing with one line that names the file."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from admittance.errors import DataError
from admittance.formats.dataset import GRAVITY, load_dataset, read_csv_trial

from helpers import examples

MANIFEST = """motor = "MX-64"
[rod]
mass = 0.0402
length = 0.456
[bob]
mass = 0.1034
[[trials]]
file = "a.csv"
bob_distance = 0.40
direction = "cw"
"""


def _csv(n=20, dt=1 / 120, extra=""):
    rows = ["t,theta" + extra]
    for i in range(n):
        rows.append(f"{i * dt:.6f},{math.cos(i * 0.1):.6f}" + (",0.0" if extra else ""))
    return "\n".join(rows) + "\n"


def _folder(tmp_path, manifest=MANIFEST, files=None):
    (tmp_path / "manifest.toml").write_text(manifest)
    for name, body in (files if files is not None else {"a.csv": _csv()}).items():
        (tmp_path / name).write_text(body)
    return tmp_path


def test_geometry_gives_load_inertia_and_gravity(tmp_path):
    ds = load_dataset(_folder(tmp_path))
    assert ds.mode == "geometry" and ds.motor == "MX-64"
    tr = ds.trials[0]
    assert tr.load_inertia == pytest.approx(0.0402 * 0.456**2 / 3 + 0.1034 * 0.40**2)
    assert tr.gravity_torque == pytest.approx(0.0402 * GRAVITY * 0.456 / 2 + 0.1034 * GRAVITY * 0.40)
    assert tr.tau is None and tr.meta["direction"] == "cw"


def test_lumped_when_no_geometry_and_columns_in_any_order(tmp_path):
    manifest = '[[trials]]\nfile = "a.csv"\n'
    body = "theta,other,tau,t\n" + "".join(f"{0.1 * i},x,{0.5},{0.01 * i}\n" for i in range(12))
    ds = load_dataset(_folder(tmp_path, manifest, {"a.csv": body}))
    assert ds.mode == "lumped" and ds.has_torque
    np.testing.assert_allclose(ds.trials[0].t, 0.01 * np.arange(12))
    np.testing.assert_allclose(ds.trials[0].tau, 0.5)


def test_spreadsheet_csv_with_byte_order_mark_and_crlf(tmp_path):
    body = "\ufeff" + _csv().replace("\n", "\r\n")
    (tmp_path / "a.csv").write_text(body, encoding="utf-8", newline="")
    t, theta, tau = read_csv_trial(tmp_path / "a.csv")
    assert t.size == 20 and tau is None
    np.testing.assert_allclose(theta[:2], [1.0, math.cos(0.1)], atol=1e-6)


@pytest.mark.parametrize(
    "manifest, files, fragment",
    [
        (MANIFEST, {"a.csv": _csv().replace("theta", "angle")}, "missing column 'theta'"),
        (MANIFEST, {"a.csv": _csv().replace("0.016667,", "0.001,")}, "not strictly increasing"),
        (MANIFEST, {"a.csv": _csv().replace("0.008333,", "nan,")}, "NaN"),
        (MANIFEST, {"a.csv": _csv().replace("0.008333,", "abc,")}, "not a number"),
        (MANIFEST, {"a.csv": "t,theta\n"}, "empty trial"),
        (MANIFEST, {"a.csv": _csv().replace("t,theta", "t,theta,theta", 1)}, "appears 2 times"),
        (MANIFEST, {"a.csv": ""}, "empty file"),
        (MANIFEST, {"a.csv": _csv(n=5)}, "only 5 samples"),
        (MANIFEST, {}, "trial file not found"),
        (MANIFEST.replace("bob_distance = 0.40\n", ""), {"a.csv": _csv()}, "bob_distance: missing"),
        (MANIFEST.replace("bob_distance = 0.40", "bob_distance = -1"), {"a.csv": _csv()}, "positive"),
        (MANIFEST.replace("length = 0.456", 'length = "long"'), {"a.csv": _csv()}, "[rod] length"),
        ('motor = "x"\n', {"a.csv": _csv()}, "no [[trials]]"),
        ("[[trials]\n", {"a.csv": _csv()}, "not valid TOML"),
        (MANIFEST + '[[trials]]\nfile = "a.csv"\nbob_distance = 0.3\n', {"a.csv": _csv()}, "listed twice"),
        (MANIFEST.replace('file = "a.csv"', "file = 3"), {"a.csv": _csv()}, "missing 'file'"),
    ],
)
def test_bad_input_is_one_line_naming_the_file(tmp_path, manifest, files, fragment):
    folder = _folder(tmp_path, manifest, files)
    with pytest.raises(DataError) as err:
        load_dataset(folder)
    message = str(err.value)
    assert fragment in message
    assert "\n" not in message
    assert str(folder) in message


def test_missing_manifest_and_folder(tmp_path):
    with pytest.raises(DataError, match="manifest not found"):
        load_dataset(tmp_path)
    with pytest.raises(DataError, match="folder not found"):
        load_dataset(tmp_path / "nope")


def test_other_formats_go_to_the_loaders(tmp_path, monkeypatch):
    from admittance.formats import converters as loaders

    calls = []

    def fake_load_trial(path, fmt):
        calls.append((path.name, fmt))
        t = np.arange(15) * 0.01
        return t, np.sin(t), None

    monkeypatch.setattr(loaders, "load_trial", fake_load_trial)
    manifest = '[[trials]]\nfile = "rec.json"\nformat = "bam"\n'
    ds = load_dataset(_folder(tmp_path, manifest, {"rec.json": "{}"}))
    assert calls == [("rec.json", "bam")]
    assert ds.trials[0].n_samples == 15 and ds.trials[0].meta["format"] == "bam"


@settings(max_examples=examples(60))
@given(
    st.lists(st.floats(-10, 10, allow_nan=False), min_size=10, max_size=40),
    st.permutations(["t", "theta", "tau", "note"]),
)
def test_csv_reader_property(tmp_path_factory, thetas, header):
    """Any column order, any extra column: the values come back exactly as written."""
    path = tmp_path_factory.mktemp("csv") / "x.csv"
    cols = {"t": [0.01 * i for i in range(len(thetas))], "theta": thetas, "tau": [-v for v in thetas],
            "note": ["n"] * len(thetas)}
    lines = [",".join(header)] + [",".join(repr(cols[h][i]) if h != "note" else "n" for h in header)
                                  for i in range(len(thetas))]
    path.write_text("\n".join(lines) + "\n")
    t, theta, tau = read_csv_trial(path)
    np.testing.assert_array_equal(theta, thetas)
    np.testing.assert_array_equal(tau, [-v for v in thetas])
    np.testing.assert_array_equal(t, cols["t"])
