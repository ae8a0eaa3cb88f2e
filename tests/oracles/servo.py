"""Servo truths for the fidelity tests and bench/servo_forms.py: test ORACLES, plain Python written
from each servo's physics, not from the project's code (the fit's model, plant::servo, is none
of them), and the loop oracle that records a session through the daemon's own Recorder.

- ``LagOracle``: a horn that lags its goal (exact exponential), read 0.3 ms after the write;
- ``BamOracle``: BAM's MX model: P-controlled PWM with the duty cap, DC motor with back-EMF,
  horn inertia, viscous and smooth (tanh) Coulomb friction, and the hand's torque on the horn;
- ``GearedOracle``: the BAM motor behind a gear train with backlash (play): the horn sits on
  the side of the motor the hand pushes it to, and stays where it is while the hand's torque
  is within the horn's own friction (a play operator; the horn's inertia is negligible
  against the motor's reflected one, as on any geared Dynamixel);
- ``SlewOracle``: a servo whose firmware moves the horn toward its goal at a fixed speed and
  stops within a tolerance (a bang-bang profile, as a position servo with a low profile
  velocity): a form the servo model does not describe.
"""

from __future__ import annotations

import math

import numpy as np

from admittance.daemon.mcap_recording import McapRecorder
from admittance.daemon.recording import Recorder

from oracles import virtual_joint

RATE = 1000.0
H = 1.0 / RATE
SUBSTEPS = 10  # the truths run at 0.1 ms
TICK = 2 * math.pi / 4096
READ_AFTER = 3  # substeps: the present position is read 0.3 ms after the goal is written
VIRTUAL = (0.02, 0.1, 0.02)  # I, B, F of the joint the loop renders


def multisine(t: float) -> float:
    """A hand from 0.3 to 3 Hz (N·m)."""
    return 0.06 * math.sin(2 * math.pi * 0.3 * t) + 0.05 * math.sin(2 * math.pi * 0.9 * t + 1.0) \
        + 0.05 * math.sin(2 * math.pi * 1.7 * t + 2.0) + 0.06 * math.sin(2 * math.pi * 3.0 * t + 0.5)


def pushpull(t: float) -> float:
    """A hand that pushes and pulls (N·m): ±0.15 at 0.7 Hz, reversing over 60 ms, with a 2.3 Hz
    tremor of 0.03 on top: reversals faster and rarer than the multi-sine's."""
    phase = (t * 0.7) % 1.0
    ramp = 0.06 * 0.7
    if phase < ramp:
        level = -1 + 2 * phase / ramp
    elif phase < 0.5:
        level = 1.0
    elif phase < 0.5 + ramp:
        level = 1 - 2 * (phase - 0.5) / ramp
    else:
        level = -1.0
    return 0.15 * level + 0.03 * math.sin(2 * math.pi * 2.3 * t)


HANDS = {"multisine": multisine, "pushpull": pushpull}


class LagOracle:
    def __init__(self, time_constant=0.025):
        self.tc, self.theta = time_constant, 0.0

    def step(self, goal, tau, h):
        self.theta = goal + (self.theta - goal) * math.exp(-h / self.tc)


class BamOracle:
    """MX-64 at 12 V, P gain 850 (P2), kt 1.62, R 3.95; horn 0.0147 kg·m², B 0.035, F 0.084."""

    def __init__(self):
        self.theta = self.omega = 0.0
        self.kp_duty = 0.158 * 850 / 128 * 8
        self.inertia, self.damping, self.coulomb = 0.0147, 0.035, 0.084
        self.kt, self.r, self.vin = 1.62, 3.95, 12.0

    def step(self, goal, tau, h):
        duty = max(-0.9625, min(0.9625, self.kp_duty * (goal - self.theta)))
        motor = self.kt / self.r * (self.vin * duty - self.kt * self.omega)
        net = motor + tau - self.damping * self.omega - self.coulomb * math.tanh(self.omega / 0.01)
        self.omega += h * net / self.inertia
        self.theta += h * self.omega

    @property
    def stiffness(self):  # K: N·m per rad of error below the duty cap
        return self.kt / self.r * self.vin * self.kp_duty


def session(folder, servo, seconds=12.0, divisor=5, lead=None, hand=multisine, trace=None):
    """Run the loop oracle against ``servo`` and record it with the daemon's Recorder. ``lead``
    (ω, α, τ arrays of every cycle) -> the goal offsets (rad) is the compensation, given the whole
    session at once (the virtual joint does not depend on the servo), so that a compensation
    that carries a state from cycle to cycle (the gear play's side) sees the cycles in order.
    Returns the rendering error (RMS present − model); ``trace`` (a dict), if given, receives
    every recorded column."""
    n = int(seconds * RATE)
    cols = {k: np.full(n, np.nan) for k in ("t", "t_wake", "tau", "force", "theta_model", "omega_model",
                                            "theta_goal", "theta_present", "cycle", "mode", "fault")}
    alpha = np.zeros(n)
    theta = omega = 0.0
    for k in range(n):
        tau = hand(k * H)
        before = omega
        theta, omega = virtual_joint.step(theta, omega, tau, *VIRTUAL, H)
        cols["tau"][k], cols["theta_model"][k], cols["omega_model"][k] = tau, theta, omega
        alpha[k] = (omega - before) / H
    offsets = lead(cols["omega_model"], alpha, cols["tau"]) if lead else np.zeros(n)
    h = H / SUBSTEPS
    for k in range(n):
        t = k * H
        goal = round((cols["theta_model"][k] + offsets[k]) / TICK) * TICK
        read = None
        for j in range(SUBSTEPS):
            servo.step(goal, hand(t + j * h), h)
            if j == READ_AFTER - 1 and k % divisor == 0:
                read = round(servo.theta / TICK) * TICK
        for key, value in (("t", t), ("t_wake", t), ("force", cols["tau"][k] / 0.1), ("theta_goal", goal),
                           ("cycle", k), ("mode", 0.0), ("fault", 0.0)):
            cols[key][k] = value
        cols["theta_present"][k] = np.nan if read is None else read
    info = {"model": "MX-64", "params_file": "mx64.toml", "rate_hz": RATE, "friction": "stick",
            "plant": {"motor_inertia": 0.0147, "damping": 0.035, "coulomb": 0.084}}
    rec = Recorder(folder, [(1, "MX-64")], measured_theta=True, t0=0.0, segment_s=3.0, joint_info={1: info})
    params = {"1.virtual_inertia": VIRTUAL[0], "1.virtual_damping": VIRTUAL[1], "1.virtual_coulomb": VIRTUAL[2],
              "1.servo_compensation": 1.0 if lead else 0.0}
    rec.set_targets(params)
    mcap = McapRecorder(folder / "session.mcap", {"joints": [{**info, "id": 1, "name": "joint1"}], "t0": 0.0,
                                                  "segment_s": 3.0, "measured_theta": True, "rate_hz": RATE})
    mcap.params("start", params)
    for start in range(0, n, 97):  # drained in batches, as the supervisor does
        batch = {k: v[start:start + 97] for k, v in cols.items()}
        rec.append(1, batch)
        mcap.append(1, batch, wall_offset_ns=0)
    rec.close()
    mcap.close()
    if trace is not None:
        trace.update(cols)
    read = ~np.isnan(cols["theta_present"])
    return float(np.sqrt(np.mean((cols["theta_present"][read] - cols["theta_model"][read]) ** 2)))


class GearedOracle(BamOracle):
    """BamOracle behind a gear with ``backlash`` rad of play (MX datasheets: a few tenths of a degree)."""

    def __init__(self, backlash=math.radians(0.5), horn_friction=0.02):
        super().__init__()
        self.play, self.free = backlash, horn_friction
        self.motor = 0.0

    def step(self, goal, tau, h):
        self.theta = self.motor  # the motor's own loop reads its own shaft (the encoder is on the horn below)
        super().step(goal, tau, h)
        self.motor = self.theta
        if abs(tau) > self.free:  # the hand pushes the horn against one side of the play
            self.horn = self.motor + math.copysign(self.play / 2, tau)
        else:  # within the horn's friction it stays, but never beyond the play
            self.horn = min(max(self.horn, self.motor - self.play / 2), self.motor + self.play / 2)
        self.theta = self.horn

    horn = 0.0


class SlewOracle:
    """A horn driven toward its goal at ``speed`` rad/s, stopping within ``tolerance`` rad."""

    def __init__(self, speed=0.6, tolerance=0.004):
        self.speed, self.tol, self.theta = speed, tolerance, 0.0

    def step(self, goal, tau, h):
        error = goal - self.theta
        if abs(error) > self.tol:
            self.theta += math.copysign(min(self.speed * h, abs(error)), error)
