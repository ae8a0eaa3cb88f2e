"""The servo model on servo forms it was not written from: the fit, its verdict, and what
compensation does to the horn error, side by side in one run.

For each servo truth of tests/oracles/servo.py (test oracles written from each servo's physics:
a first-order lag, BAM's MX-64, the same motor behind a gear with 0.5° of backlash, and a
slew-limited servo that the form does not describe), a loop oracle renders a virtual joint
under a multi-sine hand (0.3–3 Hz; or a push-pull one) through the daemon's own Recorder:

1. a session without compensation → `admittance fidelity`'s analysis (fit, verdict, notes);
2. a session with the fitted model's lead (``_rtcore.servo_lead``, the function the RT loop's
   compensation calls) at full weight, whatever the verdict ("forced"), and with the weight the
   verdict gives (``servo_compensation`` of the parameter file `fidelity --params-out` writes);
3. the horn error (RMS present − model angle) off, forced and as gated, and their ratios.

All data are synthetic (oracles in Python, not the simulated bench's dxlsim servo, and not the
RT loop's `Compensation` filter). Usage::

    .venv/bin/python bench/servo_forms.py [--seconds 12] [--forms lag,bam,geared,slew] [--hand multisine]
        [--json FILE]

(``--forms`` also takes geared-0.25, geared-1 and geared-2, the same motor behind a play of 0.25°, 1° and 2°;
``--hand pushpull`` is a hand that pushes and pulls at 0.7 Hz with 60 ms reversals instead of
the multi-sine.)

takes about 2 minutes per form on a quiet machine.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from oracles.servo import HANDS, RATE, BamOracle, GearedOracle, LagOracle, SlewOracle, session  # noqa: E402

FORMS = {"lag": ("first-order lag 25 ms", LagOracle), "bam": ("BAM MX-64", BamOracle),
         "geared": ("MX-64 geared, 0.5° backlash", GearedOracle), "slew": ("slew-limited 0.6 rad/s", SlewOracle),
         # Other plays, so that the play's inverse is not judged on one servo only (not in the default run).
         "geared-0.25": ("MX-64 geared, 0.25° backlash", lambda: GearedOracle(backlash=math.radians(0.25))),
         "geared-1": ("MX-64 geared, 1° backlash", lambda: GearedOracle(backlash=math.radians(1.0))),
         "geared-2": ("MX-64 geared, 2° backlash", lambda: GearedOracle(backlash=math.radians(2.0)))}
DEFAULT_FORMS = ("lag", "bam", "geared", "slew")


def lead_of(params):
    from admittance import _rtcore

    return lambda w, a, q: _rtcore.servo_lead(params, w, a, q, h=1.0 / RATE)


def play_phases(cols: dict, free: float) -> list[tuple[str, float, float]]:
    """Where a geared servo's horn error is: the reads while the hand's torque leaves the horn free
    (|τ| ≤ the horn's friction, the truth's), then, outside that band, by the time since the
    torque last entered or left it and until it next does (the only moments the horn can change
    sides); (phase, share of the mean square, RMS)."""
    import numpy as np

    tau, read = cols["tau"], ~np.isnan(cols["theta_present"])
    error = np.where(read, cols["theta_present"] - cols["theta_model"], 0.0)
    state = np.sign(np.where(np.abs(tau) > free, tau, 0.0))
    idx = np.arange(len(tau))
    event = np.r_[False, state[1:] != state[:-1]]
    since = idx - np.maximum.accumulate(np.where(event, idx, -10**9))
    until = np.minimum.accumulate(np.where(event, idx, 10**9)[::-1])[::-1] - idx
    band = state == 0
    total = float(np.sum(error ** 2))
    out = []
    for name, mask in (("hand within the horn's friction", band),
                       ("0–30 ms after the torque left or entered that band", ~band & (since < 30)),
                       ("30–60 ms after", ~band & (since >= 30) & (since < 60)),
                       ("0–30 ms before it next does", ~band & (since >= 60) & (until < 30)),
                       ("elsewhere", ~band & (since >= 60) & (until >= 30))):
        sel = mask & read
        out.append((name, float(np.sum(error[sel] ** 2)) / total, float(np.sqrt(np.mean(error[sel] ** 2)))))
    return out


def measure(work: Path, key: str, seconds: float, hand: str) -> dict:
    from admittance.fidelity.recording import load_recording
    from admittance.fidelity.report import analyse

    label, truth = FORMS[key]
    off = session(work / f"{key}-off", truth(), seconds=seconds, hand=HANDS[hand])
    result = analyse(load_recording(work / f"{key}-off"))
    fit = result.pop("_servo_fit")
    trace: dict = {}
    forced = session(work / f"{key}-forced", truth(), seconds=seconds, lead=lead_of(fit.params.copy()), hand=HANDS[hand],
                     trace=trace)
    phases = play_phases(trace, truth().free) if isinstance(truth(), GearedOracle) else None
    gated = forced if result["servo_verdict"]["passed"] else off
    row = {"form": label, "hand": hand, "off": off, "forced": forced, "gated": gated, "servo": result["servo"],
           "verdict": result["servo_verdict"], "phases": phases}
    print(f"| {label} | {1e3 * off:.3f} | {1e3 * forced:.3f} ({off / forced:.1f}×) | "
          f"{'on' if row['verdict']['passed'] else 'off'}: {1e3 * gated:.3f} ({off / gated:.1f}×) | "
          f"{1e3 * fit.rmse_heldout:.3f} | {row['verdict']['heldout_gain']:.1f} | "
          f"{fit.residual['rmse_over_noise']:.2f} | {fit.residual['ljung_box_p']:.2g} |", flush=True)
    for name, share, rms in phases or []:
        print(f"    forced, {name}: {100 * share:.0f} % of the mean square, RMS {1e3 * rms:.2f} mrad", flush=True)
    for reason in row["verdict"]["reasons"]:
        print(f"    refused: {reason}", flush=True)
    for note in fit.notes:
        print(f"    note: {note}", flush=True)
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=12.0, help="length of each session")
    parser.add_argument("--forms", default=",".join(DEFAULT_FORMS), help=f"comma-separated, of {', '.join(FORMS)}")
    parser.add_argument("--hand", default="multisine", choices=sorted(HANDS), help="the hand's torque profile")
    parser.add_argument("--json", type=Path, help="also write every figure here")
    args = parser.parse_args()
    forms = [f for f in args.forms.split(",") if f]
    unknown = [f for f in forms if f not in FORMS]
    if unknown:
        parser.error(f"unknown form {unknown[0]!r} (known: {', '.join(FORMS)})")
    header = ("| servo form | horn error off (mrad) | forced on | as the verdict says | held-out (mrad) | "
              "held-out gain | residual/noise | Ljung–Box p |")

    def run():
        with tempfile.TemporaryDirectory(prefix="servo-forms-") as tmp:
            return [measure(Path(tmp), key, args.seconds, args.hand) for key in forms]

    return table(f"hand: {args.hand}", header, run, args.json)


def table(title: str, header: str, run, json_path: Path | None) -> int:
    """The machine's load, the table's header, its rows (``run()`` prints them and returns them),
    the load after; the rows also to ``json_path`` if given."""
    print(f"load before: {os.getloadavg()}, {title}", flush=True)
    print(header)
    print("|---" * (header.count("|") - 1) + "|")
    rows = run()
    print(f"load after: {os.getloadavg()}", flush=True)
    if json_path:
        json_path.write_text(json.dumps(rows, indent=1, default=str) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
