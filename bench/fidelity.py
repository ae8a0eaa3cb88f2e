"""Rendering fidelity on the simulated bench, before and after servo compensation, side by side.

For each servo the bench can simulate (the embedded default, a BAM-style MX-64: P-controlled
PWM with the duty cap, DC motor with back-EMF; and a first-order lag of 25 ms that the servo
model's simulator never made), through the real daemon (`admittance run --record`, one process
per session):

1. **identify** the servo: a session with a multi-sine hand (0.3–3 Hz), no compensation,
   then `admittance fidelity --params-out` (the servo model comes only from that recording);
2. **sweep**: one session per hand profile (sines at 0.3, 0.5, 1, 2 and 3 Hz, and the
   multi-sine), without and with compensation: the rendering error (RMS present − model where
   the hand acts), the admittance the horn rendered (`identify` on the measured angle) against
   the target, and the rendered θ/τ at the sine's frequency against the target's (a Bode plot);
   the virtual joint is the MX-64's own inertia, a damping of 0.1 N·m·s/rad and no Coulomb
   friction, so that one sine pins I and B;
3. **smallest stable inertia** (Keemink et al., IJRR 2018): a hand that grips the horn (its
   inertia rides on it, its arm's damping and stiffness pull it back; the sensor reads what it
   transmits; on the lag servo, a position source, without inertia) pushes and lets go every
   3 s; the virtual inertia is halved until the horn's wobble a second after the push no longer
   dies out (the RMS in 2.0–2.75 s is over half that in 1.0–1.75 s and over a tick), then
   bisected; the figure is the smallest stable virtual inertia over the servo's own (the plant
   file's motor_inertia; the load is 0).

All data are synthetic: the simulated bench, on a shared 2-core machine (the load is printed;
under load the mock bus's thread starves, reads fail and the fidelity tool cuts the recording
at the gaps, see docs/fidelity.md). Usage::

    .venv/bin/python bench/fidelity.py [--seconds 12] [--quick] [--plots DIR]

Plots are written only with ``--plots``: docs/fidelity/ holds the full run's, which a quick run
must not replace unasked.

takes about 15 minutes (``--quick``: 3 frequencies, a coarser search, about 8).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

import numpy as np
import tomli_w

from admittance import data
from admittance.extras import require

BENCH = data.bench_config()
MX64 = data.params_file("MX-64")
ADMITTANCE = Path(sys.executable).with_name("admittance")
SERVOS = {"BAM MX-64": 0.0, "lag 25 ms": 0.025}  # [bench].servo_lag_s
FREQUENCIES = (0.3, 0.5, 1.0, 2.0, 3.0)
# The MX-64's own inertia, no Coulomb friction (one sine then pins I and B), and a damping that
# lets a drift (a stalled sensor thread holding a torque) die out in 0.15 s.
LINEAR = {"virtual_inertia": 0.01467, "virtual_damping": 0.1, "virtual_coulomb": 0.0}
MOTION_RAD = 0.15  # the model's sine amplitude each hand profile aims at
# A hand gripping the handle at 0.105 m: 0.5 kg, 14 N·s/m, 180 N/m (illustrative, not measured).
# With the MX-64's own inertia as the virtual one the coupled joint is damped at ζ ≈ 0.45: after
# a push it settles within half a second, so what still moves a second later is the loop's doing.
HAND = {"hand_inertia": 0.0055, "hand_damping": 0.15, "hand_stiffness": 2.0}
# The lag servo's horn is a position source (it follows its goal whatever pushes it): a mass on it
# would only feel an impulse at each goal tick, so there the hand has its damping and stiffness.
HANDS = {"BAM MX-64": HAND, "lag 25 ms": {**HAND, "hand_inertia": 0.0}}
PERIOD_S = 3.0  # the push-release profile's period
WINDOWS_S = ((1.0, 1.75), (2.0, 2.75))  # after each push: the wobble in the second must not persist
SUSTAINED = 0.5  # late/early wobble ratio above which the oscillation does not die out
MIN_WOBBLE_RAD = 0.0015  # below this (one tick) the horn is at rest


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def config_doc(work: Path, name: str, *, params: Path, profile: str, joint: dict | None = None,
               bench: dict | None = None) -> dict:
    """The embedded bench's configuration of one recorded session (bench/passivity.py's lockstep
    sessions take it too)."""
    doc = tomllib.loads(BENCH.read_text())
    doc["joints"][0].update({"params": str(params), **(joint or {})})
    doc["loop"]["stale_timeout_ms"] = 500.0  # the schema's most: a starved reader must not hold the joint (not under test)
    doc["loop"]["sync_read_divisor"] = 2  # rows every 2 ms: the 3 Hz hand's torque between rows is a line
    doc["bench"].update({"profile": profile, **(bench or {})})
    doc["record"] = {"path": str(work / name), "segment_s": 6.0}
    return doc


def session(work: Path, name: str, *, params: Path, profile: str, seconds: float, joint: dict | None = None,
            bench: dict | None = None) -> tuple[Path, dict]:
    """One `admittance run` of the embedded bench, recorded; (recording folder, stats)."""
    doc = config_doc(work, name, params=params, profile=profile, joint=joint, bench=bench)
    doc["zenoh"] = {"prefix": f"bench/{name}", "listen": [f"tcp/127.0.0.1:{free_port()}"]}
    config = work / f"{name}.toml"
    config.write_text(tomli_w.dumps(doc))
    stats = work / f"{name}.json"
    for attempt in range(3):  # a starved mock bus can miss a setup reply on a loaded machine: start again
        result = subprocess.run([str(ADMITTANCE), "run", "--config", str(config), "--duration", str(seconds),
                                 "--stats-json", str(stats)], capture_output=True, text=True)
        if result.returncode == 0:
            return work / name, json.loads(stats.read_text())
        print(f"  {name}: attempt {attempt + 1} failed: {result.stderr.strip()[-200:]}", flush=True)
    raise SystemExit(f"{name}: admittance run failed three times")


def analyse(folder: Path) -> dict:
    from admittance.fidelity.recording import load_recording
    from admittance.fidelity.report import analyse as fidelity

    return fidelity(load_recording(folder))


def sine_amplitude(f: float, v: dict) -> float:
    """The hand torque that moves the linear virtual joint by MOTION_RAD at ``f``."""
    w = 2 * math.pi * f
    return MOTION_RAD * w * math.hypot(v["virtual_damping"], v["virtual_inertia"] * w)


def multisine(path: Path, seconds: float, v: dict) -> Path:
    """A hand of five sines from 0.3 to 3 Hz (fixed phases), each moving the joint ~MOTION_RAD/3."""
    t = np.arange(0.0, seconds + 5.0, 0.002)
    tau = sum(sine_amplitude(f, v) / 3 * np.sin(2 * math.pi * f * t + k) for k, f in enumerate((0.3, 0.7, 1.3, 2.1, 3.0)))
    np.savetxt(path, np.column_stack([t, tau]), delimiter=",", header="t,tau", comments="")
    return path


def phasor(t: np.ndarray, x: np.ndarray, f: float) -> complex:
    """x's component at f (least squares with an offset and a trend), as a complex amplitude."""
    w = 2 * math.pi * f
    basis = np.column_stack([np.ones_like(t), t - t.mean(), np.cos(w * t), np.sin(w * t)])
    c = np.linalg.lstsq(basis, x, rcond=None)[0]
    return complex(c[2], -c[3])


def response(folder: Path, f: float) -> dict:
    """θ/τ at f for the measured (horn) and the model angle, pooled over the recording's stretches."""
    from admittance.fidelity.recording import load_recording

    out = {}
    for column in ("theta", "theta_model"):
        ratios = [phasor(s["t"], s[column], f) / phasor(s["t"], s["tau"], f)
                  for s in load_recording(folder).of_joint(1) if s["t"][-1] - s["t"][0] > 1.0 / f]
        out[column] = complex(np.mean(ratios)) if ratios else complex("nan")
    return out


def target_response(f: float, v: dict) -> complex:
    w = 2 * math.pi * f
    return 1.0 / complex(-v["virtual_inertia"] * w * w, v["virtual_damping"] * w)


def identify_servo(work: Path, servo: str, lag: float, seconds: float, hand: dict | None, run=None) -> tuple[Path, dict]:
    """The servo model, from a session without compensation (only what the recording shows);
    ``run`` makes the session (default: `session`, the daemon on the wall clock)."""
    name = f"{slug(servo)}-identify{'-hand' if hand else ''}"
    profile = str(multisine(work / f"{name}.csv", seconds, LINEAR))
    folder, _ = (run or session)(work, name, params=MX64, profile=profile, seconds=seconds, joint=dict(LINEAR),
                        bench={"servo_lag_s": lag, **(hand or {})})
    params = work / f"{name}.toml"
    subprocess.run([str(ADMITTANCE), "fidelity", str(folder), "--json", str(work / f"{name}-fidelity.json"),
                    "--params-out", str(params), "--quiet"], check=True)
    return params, json.loads((work / f"{name}-fidelity.json").read_text())["servo"]


def slug(text: str) -> str:
    return "".join(c if c.isalnum() else "-" for c in text.lower()).strip("-")


def sweep(work: Path, servo: str, lag: float, params: Path, seconds: float, frequencies) -> list[dict]:
    rows = []
    profiles = [(f"sine {f:g} Hz", f"sine:amplitude={sine_amplitude(f, LINEAR):.5f},frequency={f}", f)
                for f in frequencies]
    profiles.append(("multi-sine 0.3–3 Hz", str(multisine(work / "multisine.csv", seconds, LINEAR)), None))
    for label, profile, f in profiles:
        row = {"servo": servo, "hand": label, "frequency": f}
        for comp in (0.0, 1.0):
            name = f"{slug(servo)}-{slug(label)}-{'on' if comp else 'off'}"
            folder, stats = session(work, name, params=params, profile=profile, seconds=seconds,
                                    joint={**LINEAR, "servo_compensation": comp}, bench={"servo_lag_s": lag})
            result = analyse(folder)
            key = "on" if comp else "off"
            row[key] = {"rendering_rmse": result["rendering_rmse"], "rendered": result["rendered"],
                        "rendered_error": result["rendered_error"], "rows": result["rows"], "gaps": result["gaps"],
                        "bus_errors": stats["bus_errors"], "overruns": stats["overruns"], "cycles": stats["cycles"]}
            if f is not None:
                row[key]["response"] = {k: [v.real, v.imag] for k, v in response(folder, f).items()}
        if f is not None:
            t = target_response(f, LINEAR)
            row["target_response"] = [t.real, t.imag]
        rows.append(row)
        print(table_line(row), flush=True)
    return rows


def table_line(row: dict) -> str:
    off, on = row["off"], row["on"]
    errs = lambda r: " ".join(f"{k[8]}{100 * (v or 0):+5.1f}%" for k, v in r["rendered_error"].items())  # noqa: E731
    return (f"| {row['servo']} | {row['hand']} | {1e3 * off['rendering_rmse']:.2f} | {1e3 * on['rendering_rmse']:.2f} | "
            f"{off['rendering_rmse'] / on['rendering_rmse']:.1f}× | {errs(off)} | {errs(on)} |")


def wobble(folder: Path) -> tuple[float, float]:
    """The horn's wobble (angle minus its 0.25 s moving mean, RMS) in two windows after each push
    (WINDOWS_S, from the push's start: the first time the model moves 5 mrad, then every PERIOD_S;
    the sensor's torque is no clock: a gripping hand's spring cancels most of the push), the worst
    over the pushes: (early, late). Read from the raw rows (no cut at read
    gaps: an oscillation shows through them)."""
    from admittance.fidelity.recording import read_columns

    parts = [read_columns(path) for path in sorted(folder.glob("joint1_*.csv"))]
    t, theta, model = (np.concatenate([p[c] for p in parts]) for c in ("t", "theta", "theta_model"))
    pushed = np.flatnonzero(np.abs(model - model[0]) > 0.005)
    if pushed.size == 0:
        raise SystemExit(f"{folder}: the hand never pushed")
    since = t - t[pushed[0]]
    k = max(int(0.25 / np.median(np.diff(t))), 1)
    wob = theta - np.convolve(theta, np.ones(k) / k, mode="same")
    early = late = 0.0
    for push in range(int(since[-1] // PERIOD_S)):
        phase = since - push * PERIOD_S
        rms = [float(np.sqrt(np.mean(wob[(phase >= a) & (phase < b)] ** 2))) if ((phase >= a) & (phase < b)).sum() > 10
               else 0.0 for a, b in WINDOWS_S]
        early, late = max(early, rms[0]), max(late, rms[1])
    return early, late


def sustained(early: float, late: float) -> bool:
    return late > MIN_WOBBLE_RAD and late > SUSTAINED * early


def smallest_stable(work: Path, servo: str, lag: float, params: Path, comp: float, seconds: float,
                    steps: int) -> dict:
    """From the servo's own inertia, double until stable, halve until the horn keeps oscillating,
    then bisect (log scale). Stable = the wobble after each push dies out (late < half early)."""
    own = float(tomllib.loads(MX64.read_text())["params"]["motor_inertia"])
    profile = f"push-release:amplitude=0.3,period={PERIOD_S},rise=0.05,hold=0.3,fall=0.02"
    tried = {}

    def stable(inertia: float) -> bool:
        if inertia not in tried:
            name = f"{slug(servo)}-min-{'on' if comp else 'off'}-{inertia:.6f}"
            folder, stats = session(work, name, params=params, profile=profile, seconds=seconds,
                                    joint={"virtual_inertia": inertia, "virtual_damping": 0.0347,
                                           "virtual_coulomb": 0.0, "servo_compensation": comp},
                                    bench={"servo_lag_s": lag, **HANDS[servo]})
            early, late = wobble(folder)
            rendered = rendered_inertia(folder) if not sustained(early, late) else None
            tried[inertia] = {"early": early, "late": late, "stable": not sustained(early, late),
                              "rendered_inertia": rendered,
                              "overruns": stats["overruns"], "bus_errors": stats["bus_errors"]}
            print(f"  {servo}, compensation {comp:g}: I = {inertia:.5f} ({inertia / own:.3f} of the servo's) wobble "
                  f"{1e3 * early:.2f} → {1e3 * late:.2f} mrad: {'stable' if tried[inertia]['stable'] else 'SUSTAINED'}"
                  + (f", rendered I {rendered:.5f} ({rendered / own:.3f})" if rendered else ""), flush=True)
        return tried[inertia]["stable"]

    hi = own
    while not stable(hi):
        if hi >= 4 * own:
            return {"smallest_stable": None, "ratio": None, "note": "unstable up to 4× the servo's inertia",
                    "tried": tried}
        hi *= 2
    lo = hi / 2
    while stable(lo):
        hi, lo = lo, lo / 2
        if lo < own / 64:
            return {"smallest_stable": hi, "ratio": hi / own, "note": "search floor", "tried": tried,
                **smallest_rendered(tried, own)}
    for _ in range(steps):
        mid = math.sqrt(lo * hi)
        hi, lo = (mid, lo) if stable(mid) else (hi, mid)
    return {"smallest_stable": hi, "ratio": hi / own, "unstable_below": lo, "tried": tried,
            **smallest_rendered(tried, own)}


def rendered_inertia(folder: Path) -> float | None:
    """The inertia the horn really rendered (`identify` on the measured angle, the sensor's torque
    in), or None when the recording has no usable stretch."""
    from admittance.errors import DataError

    try:
        return float(analyse(folder)["rendered"]["virtual_inertia"])
    except DataError:
        return None


def smallest_rendered(tried: dict, own: float) -> dict:
    """Among the stable runs, the smallest inertia the horn rendered: what the hand felt, which a
    compliant servo without compensation adds its own horn to."""
    rendered = [v["rendered_inertia"] for v in tried.values() if v["stable"] and v["rendered_inertia"]]
    return {"smallest_rendered": min(rendered) / own if rendered else None}


def plot(rows: list[dict], out: Path) -> None:
    """Per servo: the rendered θ/τ against the target's (magnitude, phase), and their ratio."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    lagging = lambda z: np.degrees(np.angle(z)) - 360.0 * (np.angle(z) > 0)  # noqa: E731  (−360, 0]: no wrap
    for servo in SERVOS:
        pts = [r for r in rows if r["servo"] == servo and r["frequency"]]
        if not pts:
            continue
        f = np.array([r["frequency"] for r in pts])
        t_pts = np.array([complex(*r["target_response"]) for r in pts])
        fig, ((mag, ratio), (ph, dph)) = plt.subplots(2, 2, figsize=(10, 6), sharex=True)
        fine = np.geomspace(0.25, 3.5, 100)
        target = np.array([target_response(x, LINEAR) for x in fine])
        mag.loglog(fine, np.abs(target), "k-", label="target 1/(I·s² + B·s)")
        ph.semilogx(fine, lagging(target), "k-")
        ratio.semilogx(fine, np.ones_like(fine), "k-")
        dph.semilogx(fine, np.zeros_like(fine), "k-")
        for key, style, label in (("off", "o--", "horn, compensation off"), ("on", "s-", "horn, compensation on")):
            h = np.array([complex(*r[key]["response"]["theta"]) for r in pts])
            mag.loglog(f, np.abs(h), style, label=label)
            ph.semilogx(f, lagging(h), style)
            ratio.semilogx(f, np.abs(h / t_pts), style)
            dph.semilogx(f, np.degrees(np.angle(h / t_pts)), style)
        for axis in (mag, ph, ratio, dph):
            axis.set_xticks(list(FREQUENCIES), [f"{x:g}" for x in FREQUENCIES])
            axis.minorticks_off()
        mag.set_ylabel("|θ/τ| (rad/N·m)")
        ph.set_ylabel("phase of θ/τ (°)")
        ratio.set_ylabel("|rendered / target|")
        dph.set_ylabel("phase of rendered / target (°)")
        for axis in (ph, dph):
            axis.set_xlabel("hand frequency (Hz)")
        mag.legend(fontsize=8)
        fig.suptitle(f"rendered admittance, {servo} (simulated bench)")
        fig.tight_layout()
        fig.savefig(out / f"response_{slug(servo)}.png", dpi=80)
        plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=12.0, help="length of each sweep session")
    parser.add_argument("--quick", action="store_true", help="3 frequencies, a coarser inertia search")
    parser.add_argument("--plots", type=Path, help="write the Bode plots into this folder (default: none)")
    parser.add_argument("--json", type=Path, help="also write every figure here")
    parser.add_argument("--skip-inertia", action="store_true", help="only the identification and the sweep")
    parser.add_argument("--inertia-only", action="store_true", help="only the smallest stable inertia")
    args = parser.parse_args()
    if args.plots:  # now, not after the sessions
        require("matplotlib", "bench/fidelity.py --plots")
        try:
            args.plots.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            parser.error(f"--plots {args.plots}: {exc.strerror}")
        if not os.access(args.plots, os.W_OK):
            parser.error(f"--plots {args.plots}: not writable")
    frequencies = (0.3, 1.0, 3.0) if args.quick else FREQUENCIES
    print(f"load before: {os.getloadavg()}", flush=True)
    results = {"sweep": [], "servo_models": {}, "smallest_stable": {}}
    with tempfile.TemporaryDirectory(prefix="fidelity-bench-") as tmp:
        work = Path(tmp)
        print("| servo | hand | error off (mrad) | error on (mrad) | ratio | rendered I/B/F off | rendered I/B/F on |")
        print("|---|---|---|---|---|---|---|")
        for servo, lag in SERVOS.items() if not args.inertia_only else ():
            params, model = identify_servo(work, servo, lag, 2 * args.seconds, None)
            results["servo_models"][servo] = model
            results["sweep"] += sweep(work, servo, lag, params, args.seconds, frequencies)
        if not args.skip_inertia:
            for servo, lag in SERVOS.items():
                params, model = identify_servo(work, servo, lag, 2 * args.seconds, HANDS[servo])
                results["servo_models"][f"{servo}, gripping hand"] = model
                results["smallest_stable"][servo] = {
                    key: smallest_stable(work, servo, lag, params, comp, 3 * PERIOD_S + 1.5, 2 if args.quick else 3)
                    for key, comp in (("off", 0.0), ("on", 1.0))}
    print(f"load after: {os.getloadavg()}", flush=True)
    for servo, model in results["servo_models"].items():
        print(f"servo model, {servo}: " + ", ".join(f"{k} {model[k]:.4g}" for k in
              ("time_constant", "inertial_time", "dead_time", "compliance", "deadband", "rmse_heldout")))
    for servo, pair in results["smallest_stable"].items():
        off, on = pair["off"]["ratio"], pair["on"]["ratio"]
        print(f"smallest stable virtual inertia, {servo}: off {off}, on {on} of the servo's own"
              + (f" ({off / on:.2f}× lower with compensation)" if off and on else "")
              + f"; smallest rendered inertia when stable: off {pair['off'].get('smallest_rendered')}, "
              f"on {pair['on'].get('smallest_rendered')}")
    if args.json:  # the figures first: a plot that fails loses no measurement
        args.json.write_text(json.dumps(results, indent=1, default=str) + "\n")
    if args.plots:
        plot(results["sweep"], args.plots)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
