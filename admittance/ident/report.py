"""``identify --report DIR``: a report (``report.html``, self-contained, and ``report.md`` with
PNG figures; report_html.py renders the one from the other), in the spirit of the thesis's
appendix A (recorded against simulated angle, trial by trial) plus what the thesis lacked: the
held-out comparison, the evidence for and against each effect, and the residual verdict.

Matplotlib runs on the Agg backend (no display needed); figures are written and closed one by
one so a 30-trial report does not hold 30 figures in memory. Legends sit above the plots, outside
every axes (the saved image grows to hold them), so they never cover a bar or a line; every
figure has a caption (its Markdown alt text, the HTML's figcaption).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from admittance.errors import DataError
from admittance.ident.identify import IdentifyResult

TRIALS_PER_FIGURE = 6
HELDOUT_CAPTIONS = (
    "Held-out trials: simulated minus recorded angle over time, base model in red, final model in blue",
    "Held-out trials: RMS simulation error per trial, base model in red, final model in blue",
)
UNITS = {
    "motor_inertia": "kg·m²", "damping": "N·m·s/rad", "coulomb": "N·m", "coulomb_asym": "N·m",
    "stribeck_torque": "N·m", "stribeck_velocity": "rad/s", "load_coulomb": "–", "angle_offset": "rad",
    "quadratic_drag": "N·m·s²/rad²", "cogging_amplitude": "N·m", "cogging_period": "1/rev",
    "cogging_phase": "rad", "time_delay": "s", "torque_bias": "N·m", "torque_drift": "N·m/s", "tanh_k": "s/rad",
    "torque_gain": "–",
}


def write_report(result: IdentifyResult, out_dir: str | Path) -> Path:
    """Write ``report.md``, its figures and ``report.html`` into ``out_dir``; returns the HTML path."""
    import matplotlib

    matplotlib.use("Agg")
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataError(f"--report {out}: cannot create the folder ({exc.strerror})") from None
    figures = {
        "training": _trace_figures(out, result, "training"),
        "heldout": _heldout_figures(out, result),
        "residual": _residual_figure(out, result),
        "evidence": _evidence_figure(out, result),
        "signatures": _signature_figure(out, result),
    }
    from admittance.ident.report_html import write_html

    markdown = _markdown(result, figures)
    (out / "report.md").write_text(markdown)
    return write_html(markdown, out, out / "report.html")


def _save(fig, path: Path) -> str:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")  # "tight" keeps the legends above the axes
    plt.close(fig)
    return path.name


def _legend_above(fig, ax) -> None:
    """The figure's legend in one row above all its axes: it covers no data."""
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=max(len(labels), 1),
               fontsize=8, frameon=False)


def _grid(n: int):
    import matplotlib.pyplot as plt

    cols = 2 if n > 1 else 1
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(6 * cols, 2.6 * rows), squeeze=False)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    return fig, axes.ravel()


def _trace_figures(out: Path, result: IdentifyResult, label: str) -> list[str]:
    """Recorded vs simulated angle for the training trials (final model)."""
    trials = [result.dataset.trials[i] for i in result.training]
    names = []
    for start in range(0, len(trials), TRIALS_PER_FIGURE):
        chunk = list(range(start, min(start + TRIALS_PER_FIGURE, len(trials))))
        fig, axes = _grid(len(chunk))
        for ax, k in zip(axes, chunk):
            tr = trials[k]
            ax.plot(tr.t, tr.theta, ".", ms=2, color="0.5", label="recorded")
            ax.plot(tr.t, tr.theta + result.final.residuals[k], "-", lw=1.0, color="C0", alpha=0.8, label="simulated")
            ax.set_title(tr.name, fontsize=9)
            ax.set_xlabel("t [s]")
            ax.set_ylabel("θ [rad]")
        _legend_above(fig, axes[0])
        names.append(_save(fig, out / f"{label}_{start // TRIALS_PER_FIGURE + 1}.png"))
    return names


def _heldout_figures(out: Path, result: IdentifyResult) -> list[str]:
    import matplotlib.pyplot as plt

    trials = [result.dataset.trials[i] for i in result.heldout]
    fig, axes = _grid(len(trials))
    for ax, tr, rb, ra in zip(axes, trials, result.before.residuals, result.after.residuals):
        ax.plot(tr.t, rb * 1e3, lw=1, color="C3", label="base model")
        ax.plot(tr.t, ra * 1e3, lw=1, color="C0", alpha=0.8, label="final model")
        ax.set_title(f"{tr.name}: error", fontsize=9)
        ax.set_xlabel("t [s]")
        ax.set_ylabel("sim − rec [mrad]")
    _legend_above(fig, axes[0])
    names = [_save(fig, out / "heldout_error.png")]
    fig, ax = plt.subplots(figsize=(max(4, 0.8 * len(trials) + 2), 3))
    x = np.arange(len(trials))
    ax.bar(x - 0.2, [1e3 * np.sqrt(np.mean(r**2)) for r in result.before.residuals], 0.4, color="C3", label="base")
    ax.bar(x + 0.2, [1e3 * np.sqrt(np.mean(r**2)) for r in result.after.residuals], 0.4, color="C0", label="final")
    ax.set_xticks(x, [tr.name for tr in trials], rotation=30, ha="right", fontsize=7)
    ax.set_ylabel("RMSE [mrad]")
    _legend_above(fig, ax)
    names.append(_save(fig, out / "heldout_rmse.png"))
    return names


def _residual_figure(out: Path, result: IdentifyResult) -> str:
    """The residual binned by each effect's signature variable: speed, angle, time."""
    import matplotlib.pyplot as plt

    bins = result.residual["bins"]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3))
    for ax, (by, unit) in zip(axes, (("speed", "|ω| [rad/s]"), ("angle", "θ [rad]"), ("time", "t − t₀ [s]"))):
        rows = bins[by]
        centres = [(r["low"] + r["high"]) / 2 for r in rows]
        widths = [max(r["high"] - r["low"], 1e-9) * 0.9 for r in rows]
        ax.bar(centres, [1e3 * r["rms"] for r in rows], widths, color="C2")
        ax.axhline(1e3 * result.residual["noise_estimate"], color="k", ls="--", lw=1, label="noise estimate")
        ax.set_xlabel(unit)
        ax.set_ylabel("residual RMS [mrad]")
    _legend_above(fig, axes[0])
    return _save(fig, out / "residual_bins.png")


def _signature_figure(out: Path, result: IdentifyResult) -> str | None:
    """The final residual of the worst training trial against the signature of each remaining
    candidate: the part of the residual that candidate, linearised, would take away."""
    import matplotlib.pyplot as plt

    candidates = [e for e in result.remaining if e.signature][:4]
    if not candidates:
        return None
    worst = int(np.argmax([np.sqrt(np.mean(r**2)) for r in result.final.residuals]))
    trial = result.dataset.trials[result.training[worst]]
    fig, axes = plt.subplots(len(candidates), 1, figsize=(8, 1.9 * len(candidates)), sharex=True, squeeze=False)
    for ax, evidence in zip(axes.ravel(), candidates):
        ax.plot(trial.t, 1e3 * result.final.residuals[worst], color="0.6", lw=1, label="residual")
        ax.plot(trial.t, 1e3 * evidence.signature[worst], color="C1", lw=1.2,
                label=f"{evidence.effect} ({100 * evidence.explained:.1f} % overall)")
        ax.set_ylabel("mrad")
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    axes.ravel()[0].set_title(f"{trial.name}: residual and candidate signatures", fontsize=9)
    axes.ravel()[-1].set_xlabel("t [s]")
    return _save(fig, out / "signatures.png")


def _evidence_figure(out: Path, result: IdentifyResult) -> str | None:
    """Explained fraction of each candidate, per search round and on the final residual."""
    import matplotlib.pyplot as plt

    rounds = list(result.search.rounds) if result.search else []
    rounds.append(result.remaining)
    rounds = [r for r in rounds if r]
    if not rounds:
        return None
    fig, axes = plt.subplots(1, len(rounds), figsize=(4.5 * len(rounds), 3), squeeze=False)
    for i, (ax, ranking) in enumerate(zip(axes.ravel(), rounds)):
        names = [e.effect for e in ranking]
        colors = ["C0" if e.accepted else "0.6" for e in ranking]
        ax.barh(names, [100 * e.explained for e in ranking], color=colors)
        ax.invert_yaxis()
        ax.set_xlabel("explained [% of residual SS]")
        ax.set_title("final residual" if i == len(rounds) - 1 else f"search round {i + 1}", fontsize=9)
    return _save(fig, out / "evidence.png")


def _markdown(result: IdentifyResult, figures: dict) -> str:
    j = result.to_json()
    lines = [
        f"# Identification report: {result.dataset.motor or result.dataset.folder}",
        "",
        f"- dataset: `{result.dataset.folder}` ({len(result.dataset.trials)} trials, mode **{result.mode}**, "
        f"friction law **{result.settings.friction}**)",
        f"- effects claimed: **{', '.join(result.effects) or 'none'}**"
        + (f"; kept as stand-ins (in the model, not claimed): {', '.join(result.stand_ins)}" if result.stand_ins else ""),
        f"- held-out RMSE: base {1e3 * result.before.rmse:.3f} mrad → final {1e3 * result.after.rmse:.3f} mrad "
        f"({len(result.heldout)} trials: {', '.join(j['heldout'])})",
        f"- time: {result.timings.get('total', 0.0):.2f} s",
        "",
        "## Parameters",
        "",
        "| parameter | base | final | σ (final) | unit |",
        "|---|---|---|---|---|",
    ]
    sigma = result.sigma(result.final)
    base = result.base_params
    for name, value in result.params.items():
        if name not in sigma and value == base[name]:
            continue
        s = f"{sigma[name]:.3g}" if name in sigma else "fixed"
        lines.append(f"| {name} | {base[name]:.5g} | {value:.5g} | {s} | {UNITS.get(name, '')} |")
    if result.mode == "lumped":
        lines += ["", "Lumped mode: torques are per unit of total inertia; "
                  + ", ".join(f"{k} = {v:.5g}" for k, v in j["lumped"].items()) + "."]
    lines += ["", "## Effects", ""]
    lines += _evidence_table(result)
    if figures["evidence"]:
        lines += ["", f"![Explained share of the residual per candidate effect, per search round and on the "
                  f"final residual; blue: added to the model, grey: not]({figures['evidence']})"]
    lines += ["", "## Residual", "", result.residual["summary"] + ".", "", f"![The final model's residual RMS binned by speed, angle and time; the dashed line is the "
              f"noise estimate]({figures['residual']})", ""]
    if figures["signatures"]:
        lines += ["What each remaining candidate would explain, on the worst training trial:", "",
                  f"![The worst training trial's residual in grey and what each remaining candidate, "
                  f"linearised, would take away from it]({figures['signatures']})", ""]
    else:
        lines += ["The residual is what the sensor alone leaves: no candidate has anything to explain.", ""]
    if result.unexplained:
        lines += ["## What the library does not explain", "", result.unexplained["summary"] + ".", ""]
        lines += [f"- refused: {t['effect']} ({t['reason']})" for t in result.unexplained["tried"]]
        lines += [f"- stand-in: {t['effect']} ({t['reason']})" for t in result.unexplained["stand_ins"]]
        lines += [""]
    lines += ["## Held-out trials", ""]
    lines += [f"![{caption}]({name})" for caption, name in zip(HELDOUT_CAPTIONS, figures["heldout"])]
    lines += ["", "## Training trials (final model)", ""]
    lines += [f"![Training trials, part {i} of {len(figures['training'])}: recorded angle as grey dots, the "
              f"final model's simulation as a blue line]({name})" for i, name in enumerate(figures["training"], start=1)]
    return "\n".join(lines) + "\n"


def _evidence_table(result: IdentifyResult) -> list[str]:
    rows = ["| round | effect | variant | explained | cross-validated gain | significance | decision |",
            "|---|---|---|---|---|---|---|"]
    rounds = result.search.rounds if result.search else []
    for i, ranking in enumerate(rounds, start=1):
        for e in ranking:
            gain = "–" if e.validation_gain is None else f"{100 * e.validation_gain:.1f} %"
            sig = "–" if e.significance is None else f"{e.significance:.1f} σ"
            decision = ("**stand-in**: " + e.reason if e.stand_in else "**claimed**") if e.accepted else e.reason
            rows.append(f"| {i} | {e.effect} | {e.variant} | {100 * e.explained:.2f} % | {gain} | {sig} | {decision} |")
    if not rounds:
        stopped = result.search.stopped if result.search else "--max-effects 0"
        rows.append(f"| – | – | – | – | – | – | no search: {stopped} |")
    return rows
