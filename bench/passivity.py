"""The passivity guard on the simulated bench: a gripping hand, virtual inertias down to a quarter
of the smallest stable one, guard off and on, side by side.

For each servo the bench simulates (the embedded BAM-style MX-64, and a first-order lag of 25 ms),
through the real daemon (`admittance run --record`, one process per session), with the servo
compensation on (a servo model identified from a session with the same gripping hand, as
bench/fidelity.py does: the compensation is what makes light virtual joints oscillate):

1. **under a gripping hand** (bench/fidelity.py's: its inertia rides on the horn, its arm's
   damping and stiffness pull it back; on the lag servo, a position source, without inertia)
   that pushes 0.3 N·m for 0.3 s and lets go every 3 s, at virtual inertias of 2, 1, 1/2 and 1/4
   of the smallest stable one (docs/fidelity.md: 0.063 of the servo's own inertia on the MX-64,
   0.017 on the lag servo; never below the daemon's floor of 1e-4 kg·m², 0.0068 of it), and with a stiff hand (10× the arm's stiffness) at 1 and 1/4 of it,
   guard off and on: the horn's wobble (angle minus its 0.25 s moving mean, RMS) 1–1.75 s and
   2–2.75 s after each push (sustained: the later over half the earlier and over a tick), the
   energy the joint gave the hand (the guard's balance at its lowest; it is recorded with the
   guard off too), the port's net energy over the session, the guard's episodes and its largest
   damping;
2. **in passive use**: the rendering error (RMS horn − model) of bench/fidelity.py's linear joint
   (the MX-64's own inertia) under a 1 Hz sine and the 0.3–3 Hz multi-sine, guard off and on
   (target: within 5 %).

By default (``--clock lockstep``) every session runs the real loop cycle and the simulated bench
in model time (`lockstep_session`: no wall clock, so the figures are the same on every run whatever
the load; ``--stalls P CYCLES`` adds the loop's seeded stalls); ``--clock wall`` runs each session
through the daemon (`admittance run`) on the wall clock, the end-to-end check.

All data are synthetic (the simulated bench on a shared 2-core machine; the load is printed).
Usage::

    .venv/bin/python bench/passivity.py [--clock lockstep|wall] [--stalls P CYCLES]
                                        [--servos "BAM MX-64" "lag 25 ms"] [--factors 2 1 0.5 0.25]
                                        [--seconds 10.5] [--skip-fidelity] [--json FILE]

takes about 12 minutes with every part.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import tempfile
import tomllib
from pathlib import Path

import numpy as np
import tomli_w

from admittance.errors import DataError

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fidelity as fb  # noqa: E402  (the sessions, the hands, the wobble: one source with that bench)

# The smallest stable virtual inertia with compensation, over the servo's own (docs/fidelity.md).
SMALLEST_STABLE = {"BAM MX-64": 0.063, "lag 25 ms": 0.017}
# kg·m²: the daemon's floor on virtual_inertia ([joints] schema); a quarter of the lag servo's
# smallest stable inertia is below it, so that servo goes down to the floor (0.40 of it).
INERTIA_FLOOR = 1e-4
STIFF = 10.0  # the stiff hand's arm stiffness, × the gripping hand's
PUSHES = f"push-release:amplitude=0.3,period={fb.PERIOD_S},rise=0.05,hold=0.3,fall=0.02"


def own_inertia() -> float:
    return float(tomllib.loads(fb.MX64.read_text())["params"]["motor_inertia"])


def lockstep_session(work: Path, name: str, *, params: Path, profile: str, seconds: float, joint: dict | None = None,
                     bench: dict | None = None, seed: int = 1, stalls: tuple[float, int] = (0.0, 0)) -> tuple[Path, dict]:
    """bench/fidelity.py's `session` in model time: the same configuration (`fb.config_doc`), the
    loop built from it as the daemon builds it, the embedded bench's servos and hand, stepped
    together by `_rtcore.run_lockstep` (no wall clock: the same records on every run, whatever
    the load), and the records written by the daemon's own recorder, so the same analysis reads
    them; ``stalls``: (probability per cycle, longest in cycles) of the loop's seeded stalls (a loaded
    machine's overruns, made repeatable). (recording folder, stats: the guard's figures as the
    daemon's --stats-json has them)."""
    from types import SimpleNamespace

    from admittance import _rtcore
    from admittance.daemon.config import load_config
    from admittance.daemon.loopconfig import loop_config
    from admittance.daemon.recording import Recorder
    from admittance.daemon.supervisor import Supervisor
    from admittance.daemon.telemetry import columns_by_joint
    from admittance.mockbench.bench import BenchConfig, MockBench
    from admittance.mockbench.hand import tabulate

    config = work / f"{name}.toml"
    config.write_text(tomli_w.dumps(fb.config_doc(work, name, params=params, profile=profile, joint=joint, bench=bench)))
    cfg = load_config(config)
    s, b = cfg.sensor, cfg.bench
    hand = (b.hand_inertia, b.hand_damping, b.hand_stiffness)
    # The daemon's set-up leaves Return Delay Time at 0 (drivers/dynamixel.py `prepare`).
    servos = [{"id": j.id, "model": j.model, "protocol": cfg.bus.protocol, "params_file": j.params,
               "registers": {"Return Delay Time": 0}} for j in cfg.joints]
    sim = MockBench(BenchConfig(servos=servos, baudrate=cfg.bus.baudrate, profile=b.profile, lever_arm=cfg.joints[0].lever_arm,
                                axis=s.axis, counts_per_newton=list(s.counts_per_newton), noise_std_n=b.noise_std_n,
                                hand=hand if any(hand) else None, first_order_lag=b.servo_lag_s or None))
    table = tabulate(sim.profile, 1.0 / cfg.loop.rate_hz)
    if table is None:
        raise SystemExit(f"{name}: the lockstep bench takes the built-in or CSV hand profiles")
    model = sim.force_model
    loop = loop_config(cfg, "lockstep")
    records = _rtcore.run_lockstep(loop, sim.bus, *table, seconds + b.hand_delay_s, hand_servo=sim.hand_servo_id,
                                   lever_arm=model.lever_arm, axis=model.axis_index,
                                   counts_per_newton=list(model.counts_per_newton), noise_std_n=model.noise_std_n,
                                   seed=seed, hand_delay_s=b.hand_delay_s, stall_probability=stalls[0],
                                   stall_max_cycles=stalls[1])
    folder = work / name
    lp = cfg.loop
    recorder = Recorder(folder, [(j.id, j.model) for j in cfg.joints], measured_theta=True,
                        t0=float(records["deadline_ns"][0]) * 1e-9, segment_s=cfg.record.segment_s,
                        joint_info=Supervisor.joint_info(SimpleNamespace(cfg=cfg)), period_s=1.0 / lp.rate_hz)
    recorder.set_targets(_rtcore.AdmittanceLoop(loop).params())
    recorder.append_all(columns_by_joint(records, cfg))
    recorder.close()
    rows = records[records["id"] == cfg.joints[0].id]
    damping = rows["passivity_damping"]
    episodes = int(np.sum((damping[1:] > 0) & (damping[:-1] == 0)) + (damping[0] > 0))
    guard = {"port_energy": None, "episodes": episodes}  # the guard's port sum is not in the records
    stalled = int(np.sum(np.diff(rows["cycle"]) == 0))  # not a count of stalls: rows are per cycle run
    return folder, {"passivity": [guard], "overruns": stalled, "bus_errors": int(np.sum(rows["fault"] != 0))}


def recorded_rows(folder: Path) -> dict[str, np.ndarray]:
    """Every column of joint 1's recorded rows, its CSV segments joined (the passivity columns
    included, which `fidelity`'s reader leaves out)."""
    parts = [np.genfromtxt(path, delimiter=",", names=True) for path in sorted(folder.glob("joint1_*.csv"))]
    return {name: np.concatenate([np.atleast_1d(p[name]) for p in parts]) for name in parts[0].dtype.names}


def energy_figures(rows: dict[str, np.ndarray], stats: dict) -> dict:
    """The guard's balance at its lowest and its largest damping (the recorded rows), the port's net
    energy and the guard's episodes (the session's stats)."""
    balance, damping = rows["passivity_energy"], rows["passivity_damping"]
    guard = stats["passivity"][0]
    return {"generated_j": float(max(-balance.min(), 0.0)), "port_energy_j": guard["port_energy"],
            "episodes": guard["episodes"], "damping_max": float(damping.max())}


def gripped(run, work: Path, servo: str, lag: float, params: Path, inertia: float, guard: int, hand: dict,
            seconds: float, label: str) -> dict:
    name = f"{fb.slug(servo)}-{label}-{'on' if guard else 'off'}"
    folder, stats = run(work, name, params=params, profile=PUSHES, seconds=seconds,
                               joint={"virtual_inertia": inertia, "virtual_damping": 0.0347, "virtual_coulomb": 0.0,
                                      "servo_compensation": 1.0, "passivity_guard": guard},
                               bench={"servo_lag_s": lag, **hand})
    early, late = fb.wobble(folder)
    return {"early_mrad": 1e3 * early, "late_mrad": 1e3 * late, "sustained": fb.sustained(early, late),
            **energy_figures(recorded_rows(folder), stats), "overruns": stats["overruns"], "bus_errors": stats["bus_errors"]}


# Guard off, on, off, on: interleaved, so that a drift of the machine's load over the four
# sessions shows as off ≠ off again rather than as an effect of the guard.
PASSIVE_ORDER = (("off", 0), ("on", 1), ("off_again", 0), ("on_again", 1))


def rows_rendering_rmse(rows: dict[str, np.ndarray]) -> float:
    """RMS(horn − model) over every recorded row: the rendering error of a stalled session, which
    `fidelity` refuses to analyse (no 1 s stretch without a 30 ms gap between reads)."""
    return float(np.sqrt(np.mean((rows["theta"] - rows["theta_model"]) ** 2)))


def fidelity_rmse(folder: Path) -> float | None:
    """`fidelity`'s rendering error, None where it refuses the session (no clean 1 s stretch)."""
    try:
        return fb.analyse(folder)["rendering_rmse"]
    except DataError as exc:
        print(f"  {folder.name}: {exc}", flush=True)
        return None


def passive(run, work: Path, servo: str, lag: float, params: Path, seconds: float, stalled: bool) -> list[dict]:
    """The rendering error of the linear joint, guard off and on, interleaved: `fidelity`'s, or,
    with seeded stalls or where `fidelity` refuses one of the four sessions, RMS(horn − model)
    over the rows (:func:`rows_rendering_rmse`) for all four, so the pairs compare like with like."""
    rows = []
    profiles = [("sine 1 Hz", f"sine:amplitude={fb.sine_amplitude(1.0, fb.LINEAR):.5f},frequency=1.0"),
                ("multi-sine 0.3–3 Hz", str(fb.multisine(work / "multisine.csv", seconds, fb.LINEAR)))]
    for label, profile in profiles:
        row = {"servo": servo, "hand": label}
        for key, guard in PASSIVE_ORDER:
            name = f"{fb.slug(servo)}-passive-{fb.slug(label)}-{key}"
            folder, stats = run(work, name, params=params, profile=profile, seconds=seconds,
                                joint={**fb.LINEAR, "servo_compensation": 1.0, "passivity_guard": guard},
                                bench={"servo_lag_s": lag})
            recorded = recorded_rows(folder)
            row[key] = {"rendering_rmse": None if stalled else fidelity_rmse(folder),
                        "rows_rmse": rows_rendering_rmse(recorded), **energy_figures(recorded, stats)}
        measure = "rendering_rmse" if all(row[k]["rendering_rmse"] is not None for k, _ in PASSIVE_ORDER) else "rows_rmse"
        row["measure"] = measure
        off, on, again, on_again = (row[k][measure] for k, _ in PASSIVE_ORDER)
        star = "" if measure == "rendering_rmse" else " *"
        print(f"| {servo} | {label}{star} | {1e3 * off:.4f} | {1e3 * on:.4f} | {100 * (on / off - 1):+.2f} % | "
              f"{1e3 * again:.4f} | {1e3 * on_again:.4f} | {100 * ((on + on_again) / (off + again) - 1):+.2f} % | "
              f"{row['on']['episodes'] + row['on_again']['episodes']} | {1e3 * row['on']['generated_j']:.2f} |", flush=True)
        rows.append(row)
    return rows


def port_mj(r: dict) -> str:
    """The port's net energy (the daemon's stats; not recorded in a lockstep run)."""
    return "–" if r["port_energy_j"] is None else f"{1e3 * r['port_energy_j']:+.1f}"


def default_margin() -> float:
    """J: the loop's default `passivity_margin` (the bench leaves it at its default)."""
    from admittance._rtcore import LOOP_DEFAULTS

    return float(LOOP_DEFAULTS["passivity_margin"])


def beyond(sessions: list[dict], margin: float) -> int:
    """How many sessions gave the hand more than ``margin`` J (the guard's balance at its lowest)."""
    return sum(r["generated_j"] > margin for r in sessions)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--servos", nargs="+", default=list(fb.SERVOS), choices=list(fb.SERVOS))
    parser.add_argument("--factors", nargs="+", type=float, default=[2.0, 1.0, 0.5, 0.25],
                        help="virtual inertias, × the servo's smallest stable one")
    parser.add_argument("--seconds", type=float, default=3 * fb.PERIOD_S + 1.5, help="each gripped session")
    parser.add_argument("--skip-fidelity", action="store_true", help="only the gripped sessions")
    parser.add_argument("--skip-stiff", action="store_true", help="no stiff-hand sessions")
    parser.add_argument("--skip-gripped", action="store_true", help="only the passive sessions")
    parser.add_argument("--identify-seconds", type=float, default=24.0,
                        help="the servo identification's session (bench/fidelity.py's: 24 s)")
    parser.add_argument("--clock", choices=("lockstep", "wall"), default="lockstep",
                        help="lockstep: the loop and the bench in model time (deterministic, load-independent); "
                             "wall: the daemon on the wall clock (`admittance run`, one process per session)")
    parser.add_argument("--stalls", nargs=2, type=float, default=(0.0, 0), metavar=("P", "CYCLES"),
                        help="lockstep: the loop stalls at a cycle with probability P for up to CYCLES cycles (seeded: "
                             "a loaded machine's overruns, repeatable); default none")
    parser.add_argument("--json", type=Path, help="also write every figure here")
    args = parser.parse_args()
    own = own_inertia()
    stalls = (args.stalls[0], int(args.stalls[1]))
    run = functools.partial(lockstep_session, stalls=stalls) if args.clock == "lockstep" else fb.session
    # The servo model is the servo's, not the stalls': identified from a session without them (with
    # them, `fidelity` finds no 1 s stretch without a 30 ms gap between reads and refuses it).
    identify_run = lockstep_session if args.clock == "lockstep" else fb.session
    print(f"clock: {args.clock}; stalls {stalls}; load before: {os.getloadavg()}", flush=True)
    results: dict = {"clock": args.clock, "stalls": stalls, "gripped": [], "passive": []}
    with tempfile.TemporaryDirectory(prefix="passivity-bench-") as tmp:
        work = Path(tmp)
        print("| servo | hand | I / servo's | guard | wobble 1–1.75 s (mrad) | wobble 2–2.75 s (mrad) | sustained | "
              "energy given the hand (mJ) | port net (mJ) | episodes | damping max |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for servo in args.servos if not args.skip_gripped else ():
            lag = fb.SERVOS[servo]
            hand = fb.HANDS[servo]
            params, _ = fb.identify_servo(work, servo, lag, args.identify_seconds, hand, identify_run)
            cases = [("gripping", hand, f) for f in args.factors]
            if not args.skip_stiff:
                stiff = {**hand, "hand_stiffness": STIFF * hand["hand_stiffness"]}
                cases += [("stiff", stiff, f) for f in (1.0, 0.25)]
            for label, hand_used, factor in cases:
                ratio = max(factor * SMALLEST_STABLE[servo], INERTIA_FLOOR / own)
                for guard in (0, 1):
                    r = gripped(run, work, servo, lag, params, ratio * own, guard, hand_used, args.seconds,
                                f"{label}-{factor:g}")
                    r.update(servo=servo, hand=label, ratio=ratio, guard=guard)
                    results["gripped"].append(r)
                    print(f"| {servo} | {label} | {ratio:.4f} | {'on' if guard else 'off'} | {r['early_mrad']:.2f} | "
                          f"{r['late_mrad']:.2f} | {'YES' if r['sustained'] else 'no'} | "
                          f"{1e3 * r['generated_j']:.1f} | {port_mj(r)} | {r['episodes']} | "
                          f"{r['damping_max']:.3g} |", flush=True)
        if not args.skip_fidelity:
            print("rendering error: fidelity's; * RMS(horn − model) over every row (fidelity refused a session of the four)")
            print("| servo | hand | rendering error guard off (mrad) | guard on (mrad) | change | off again (mrad) | "
                  "on again (mrad) | change, both pairs | guard episodes | lowest balance (mJ below 0) |")
            print("|---|---|---|---|---|---|---|---|---|---|")
            for servo in args.servos:
                params, _ = fb.identify_servo(work, servo, fb.SERVOS[servo], args.identify_seconds, None, identify_run)
                results["passive"] += passive(run, work, servo, fb.SERVOS[servo], params, 12.0, stalls[0] > 0)
    print(f"load after: {os.getloadavg()}", flush=True)
    on = [r for r in results["gripped"] if r["guard"]]
    off = [r for r in results["gripped"] if not r["guard"]]
    print(f"guard on: {sum(r['sustained'] for r in on)} of {len(on)} gripped sessions with a sustained oscillation; "
          f"guard off: {sum(r['sustained'] for r in off)} of {len(off)}")
    margin = results["margin_j"] = default_margin()
    print(f"energy given the hand beyond the margin ({1e3 * margin:g} mJ): guard on {beyond(on, margin)} of {len(on)} "
          f"gripped sessions; guard off {beyond(off, margin)} of {len(off)}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
