"""What the ecosystem outputs add to one tick of the daemon's main thread, side by side.

At 1 kHz and the default 100 Hz tick, each tick drains 10 cycles per joint. Measured in one run:

- the CSV recorder (rows where the servo was read: every 10th cycle here) against
  ``session.mcap`` (every cycle, JSON on JSON-Schema channels, zstd chunks of 32 KiB);
- the ROS 2 bridge (one JointState and one WrenchStamped, CDR, on a real loopback session);
- the Foxglove live view (one JSON message per joint on a local WebSocket server, no client).

Prints µs per tick and each output's share of the 10 ms tick budget; the ratios carry over.
Usage: ``.venv/bin/python bench/ecosystem_tick.py [--joints 1] [--ticks 2000]``
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from admittance.daemon.mcap_recording import McapRecorder
from admittance.daemon.messages import JointState, State
from admittance.daemon.recording import Recorder

CYCLES_PER_TICK = 10


def columns(tick: int) -> dict[str, np.ndarray]:
    t = 100.0 + (tick * CYCLES_PER_TICK + np.arange(CYCLES_PER_TICK)) * 1e-3
    present = np.sin(t)
    present[1:] = np.nan  # one read per 10 cycles (sync_read_divisor = 10)
    return {"t": t, "tau": 0.1 * np.cos(t), "force": np.cos(t), "theta_model": np.sin(t), "omega_model": np.cos(t),
            "theta_goal": np.sin(t), "theta_present": present, "cycle": np.round((t - 100.0) * 1e3)}


def per_tick_us(action, ticks: int) -> float:
    start = time.perf_counter()
    for tick in range(ticks):
        action(tick)
    return (time.perf_counter() - start) / ticks * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--joints", type=int, default=1)
    parser.add_argument("--ticks", type=int, default=2000)
    args = parser.parse_args()
    ids = list(range(1, args.joints + 1))
    batches = [columns(k) for k in range(args.ticks)]
    state = State(cycle=10, joints=[JointState(id=i, t=1.0, force=1.0, tau=0.1, theta=0.2, omega=0.0, goal_tick=2100,
                                               present_tick=2099, name=f"joint{i}", wall=1.7e9, position=0.19)
                                    for i in ids])
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        csv = Recorder(folder, [(i, "MX-64") for i in ids], measured_theta=True, t0=100.0, segment_s=3600)
        results["CSV recorder"] = per_tick_us(lambda k: [csv.append(i, batches[k]) for i in ids], args.ticks)
        csv.close()
        mcap = McapRecorder(folder / "session.mcap", {"joints": [], "t0": 100.0})

        def mcap_tick(k: int) -> None:
            for i in ids:
                mcap.append(i, batches[k], 0)
            mcap.flush()

        results["session.mcap"] = per_tick_us(mcap_tick, args.ticks)
        mcap.close()
        results.update(views(state, ids, args.ticks))
    budget_us = 1e6 / 100.0
    print(f"per tick of the supervisor ({CYCLES_PER_TICK} cycles x {args.joints} joint(s)), {args.ticks} ticks:")
    base = results["CSV recorder"]
    for name, us in results.items():
        print(f"  {name:<16} {us:8.1f} µs   {us / budget_us * 100:5.2f} % of a 10 ms tick   {us / base:5.2f}x CSV")


def views(state: State, ids: list[int], ticks: int) -> dict[str, float]:
    from admittance.daemon.zenoh_iface import make_config, open_session
    from admittance.ros2.rmw_zenoh import Ros2Bridge

    out = {}
    session = open_session(make_config(listen=["tcp/127.0.0.1:0"]), "bench")
    cfg = SimpleNamespace(ros2=SimpleNamespace(domain_id=0, namespace="", node="bench"),
                          sensor=SimpleNamespace(axis="x", frame_id="s"),
                          joints=[SimpleNamespace(id=i, zero_tick=2048, direction=1) for i in ids],
                          foxglove=SimpleNamespace(host="127.0.0.1", port=0, rate_hz=1000.0))
    bridge = Ros2Bridge(session, cfg)
    out["ROS 2 bridge"] = per_tick_us(lambda k: bridge.publish(state), ticks)
    bridge.close()
    session.close()
    try:
        from admittance.daemon.foxglove_view import FoxgloveView
    except ImportError:
        return out
    view = FoxgloveView(cfg)
    view._period_ns = 0  # every tick, as at rate_hz >= state_rate_hz
    out["Foxglove view"] = per_tick_us(lambda k: view.publish(state), ticks)
    view.close()
    return out


if __name__ == "__main__":
    main()
