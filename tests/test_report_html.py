"""``identify --report`` without ``--json``: a self-contained HTML page (every figure embedded,
each with a caption), legends that cover no axes, and a real browser that shows every figure;
``synth --ramps`` makes torque ramps on which ``breakaway`` finds the simulated friction."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

from admittance.cli import main

pytest.importorskip("matplotlib")

CHROMIUM = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome", "chrome")
                 if shutil.which(n)), None)


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """A report of a synthetic dataset with an effect, written without --json; every figure's
    legends are checked against every axes of that figure as it is saved."""
    import matplotlib

    matplotlib.use("Agg")
    from admittance.ident import report as report_module

    root = tmp_path_factory.mktemp("report")
    assert main(["synth", str(root / "ds"), "--trials", "4", "--duration", "4", "--seed", "3",
                 "--effect", "angle_offset=0.03"]) == 0
    overlaps: list[str] = []
    original = report_module._save

    def checked_save(fig, path):
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        legends = list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
        for legend in legends:
            box = legend.get_window_extent(renderer)
            for ax in fig.axes:
                if ax.get_visible() and box.overlaps(ax.get_window_extent(renderer)):
                    overlaps.append(f"{path.name}: a legend covers {ax.get_title() or 'an axes'}")
        return original(fig, path)

    report_module._save = checked_save
    try:
        assert main(["identify", str(root / "ds"), "--report", str(root / "rep"), "--quiet"]) == 0
    finally:
        report_module._save = original
    return root / "rep", overlaps


def test_the_report_is_one_self_contained_page_with_captioned_figures(report):
    folder, overlaps = report
    assert not overlaps, overlaps
    page = (folder / "report.html").read_text()
    images = re.findall(r'<img src="([^"]+)"', page)
    pngs = sorted(folder.glob("*.png"))
    assert len(images) == len(pngs) >= 4
    assert all(src.startswith("data:image/png;base64,") for src in images)
    assert not re.search(r'(?:src|href)="(?!data:)', page), "the page refers to something outside itself"
    captions = re.findall(r"<figcaption>(.+?)</figcaption>", page)
    assert len(captions) == len(images) and all(len(c) > 20 for c in captions)
    assert "<table>" in page and "angle_offset" in page and "<script" not in page


@pytest.mark.skipif(CHROMIUM is None, reason="no headless Chromium on this machine (apt-get install chromium)")
def test_a_headless_browser_shows_every_figure(report, tmp_path):
    """Chromium loads the page and decodes every embedded image: a probe script (added to a copy,
    the report itself has none) writes each image's natural size into the DOM it dumps."""
    folder, _ = report
    probe = ("<script>window.addEventListener('load', () => { document.body.setAttribute('data-sizes', "
             "JSON.stringify([...document.images].map(i => [i.naturalWidth, i.naturalHeight]))); });</script>")
    page = (folder / "report.html").read_text().replace("</body>", probe + "</body>")
    copy = tmp_path / "probe.html"
    copy.write_text(page)
    proc = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=5000",
                           "--dump-dom", copy.as_uri()], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    match = re.search(r"data-sizes=\"([^\"]+)\"", proc.stdout)
    assert match, proc.stdout[:500]
    sizes = json.loads(match.group(1).replace("&quot;", '"'))
    assert len(sizes) == len(list(folder.glob("*.png"))) and all(w > 100 and h > 100 for w, h in sizes)


def test_synth_ramps_give_breakaway_the_simulated_friction(tmp_path):
    assert main(["synth", str(tmp_path / "ramps"), "--ramps", "--trials", "4", "--duration", "6",
                 "--noise", "0.0005", "--seed", "2"]) == 0
    truth = json.loads((tmp_path / "ramps" / "truth.json").read_text())["params"]
    proc = subprocess.run([sys.executable, "-m", "admittance", "breakaway", str(tmp_path / "ramps"), "--json",
                           str(tmp_path / "b.json")], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "b.json").read_text())
    assert sorted(summary["average_by_direction"]) == ["ccw", "cw"]
    torques = np.array([t["torque"] for t in summary["trials"]])
    assert np.all(np.abs(torques / truth["coulomb"] - 1.0) < 0.05), torques


def test_ramps_and_a_hand_are_refused_together(tmp_path):
    assert main(["synth", str(tmp_path / "x"), "--ramps", "--with-torque"]) != 0
