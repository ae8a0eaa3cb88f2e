"""What one tick of the daemon's main thread costs, and the payload encodings side by side.

The supervisor's main thread wakes at ``[zenoh].state_rate_hz`` (100 Hz by default), drains the
loop's telemetry (rate/tick rows per joint), converts it for the recorder and the state
message, and encodes that message. Two design choices are measured here, in one run:

- ``vectorised`` (admittance.daemon.telemetry: whole NumPy columns per joint) against a
  ``per-row`` Python loop over the structured array doing the same conversion;
- the state payload in ``json`` against ``msgpack`` (msgspec structs both): time and bytes.

Prints absolute figures for this machine and the ratios, which are what carries over.
Usage: ``.venv/bin/python bench/daemon_tick.py [--joints 3] [--rows 10]``
"""

from __future__ import annotations

import argparse
import math
import time
from types import SimpleNamespace

import numpy as np

from admittance.daemon import telemetry
from admittance.daemon.messages import Codec, JointState, State, decode

FIELDS = [("cycle", "<u8"), ("t_ns", "<u8"), ("deadline_ns", "<u8"), ("id", "<i8"), ("force", "<f8"), ("torque", "<f8"),
          ("theta", "<f8"), ("omega", "<f8"), ("goal_tick", "<i8"), ("present_tick", "<i8"),
          ("period_error_ns", "<i8"), ("latency_ns", "<i8"), ("fault", "<u8"), ("mode", "<i8")]


def records(joints: int, rows: int) -> np.ndarray:
    rec = np.zeros(joints * rows, np.dtype(FIELDS))
    rec["cycle"] = np.repeat(np.arange(rows), joints)
    rec["deadline_ns"] = rec["cycle"] * 1_000_000
    rec["t_ns"] = rec["deadline_ns"] + 20_000  # woke 20 µs late
    rec["id"] = np.tile(np.arange(1, joints + 1), rows)
    rec["torque"] = np.sin(rec["cycle"] * 0.01)
    rec["theta"] = np.cos(rec["cycle"] * 0.01)
    rec["goal_tick"] = 2048 + rec["cycle"]
    rec["present_tick"] = np.where(rec["cycle"] % 10 == 0, 2048 + rec["cycle"], -1)
    return rec


def per_row(rec: np.ndarray, cfg) -> tuple[dict, State]:
    """The same conversion as telemetry.columns_by_joint + latest_state, one row at a time."""
    columns: dict[int, dict[str, list]] = {}
    latest: dict[int, JointState] = {}
    zero = {j.id: j for j in cfg.joints}
    for row in rec.tolist():
        cycle, t_ns, deadline_ns, jid, force, torque, theta, omega, goal, present, _, _, fault, mode = row
        joint = zero[jid]
        col = columns.setdefault(jid, {k: [] for k in ("t", "t_wake", "tau", "force", "theta_model", "omega_model",
                                                       "theta_goal", "theta_present", "cycle", "fault", "mode")})
        col["t"].append(deadline_ns * 1e-9)
        col["t_wake"].append(t_ns * 1e-9)
        col["tau"].append(torque)
        col["force"].append(force)
        col["theta_model"].append(theta)
        col["omega_model"].append(omega)
        col["theta_goal"].append((goal - joint.zero_tick) * telemetry.RAD_PER_TICK * joint.direction)
        col["theta_present"].append(math.nan if present == -1 else
                                    (present - joint.zero_tick) * telemetry.RAD_PER_TICK * joint.direction)
        col["cycle"].append(float(cycle))
        col["fault"].append(float(fault))
        col["mode"].append(float(mode))
        latest[jid] = JointState(id=jid, t=t_ns * 1e-9, force=force, tau=torque, theta=theta, omega=omega,
                                 goal_tick=goal, present_tick=None if present == -1 else present, fault=fault)
    return columns, State(cycle=int(rec["cycle"][-1]), joints=list(latest.values()),
                          mode=telemetry.mode_name(int(rec["mode"][-1])))


def vectorised(rec: np.ndarray, cfg) -> tuple[dict, State]:
    return telemetry.columns_by_joint(rec, cfg), telemetry.latest_state(rec, cfg)


def per_call_us(fn, *args, repeat: int) -> float:
    start = time.perf_counter()
    for _ in range(repeat):
        fn(*args)
    return (time.perf_counter() - start) / repeat * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--joints", type=int, default=3)
    parser.add_argument("--rows", type=int, default=10, help="cycles per tick (1 kHz loop / 100 Hz tick = 10)")
    parser.add_argument("--repeat", type=int, default=2000)
    args = parser.parse_args()
    cfg = SimpleNamespace(joints=[SimpleNamespace(id=i, zero_tick=2048, direction=1)
                                  for i in range(1, args.joints + 1)])

    print(f"== telemetry conversion per tick: {args.joints} joints × {args.rows} cycles")
    for n_rows in (args.rows, args.rows * 10):
        rec = records(args.joints, n_rows)
        row_us = per_call_us(per_row, rec, cfg, repeat=max(args.repeat // 10, 50))
        vec_us = per_call_us(vectorised, rec, cfg, repeat=max(args.repeat // 10, 50))
        print(f"{n_rows:5d} cycles  per-row {row_us:9.1f} µs  vectorised {vec_us:9.1f} µs  "
              f"per-row/vectorised = {row_us / vec_us:5.2f}")

    print(f"== state payload ({args.joints} joints)")
    state = vectorised(records(args.joints, args.rows), cfg)[1]
    sizes = {}
    for encoding in ("json", "msgpack"):
        codec = Codec(encoding)
        payload = codec.encode(state)
        sizes[encoding] = len(payload)
        enc_us = per_call_us(codec.encode, state, repeat=args.repeat)
        dec_us = per_call_us(decode, payload, State, repeat=args.repeat)
        print(f"{encoding:8s} {len(payload):5d} bytes  encode {enc_us:6.2f} µs  decode {dec_us:6.2f} µs")
    print(f"json/msgpack size ratio = {sizes['json'] / sizes['msgpack']:.2f}")


if __name__ == "__main__":
    main()
