"""Where a geared servo's compensated horn error comes from: the play's inverse against variants
of it, on the same fitted models, side by side in one run.

bench/servo_forms.py fits each geared form and compensates with the Rust lead
(``_rtcore.servo_lead``: ``plant::servo::lead`` plus ``PlaySide``). This bench takes those fits
(``--fits``, the JSON that bench writes) and runs the forced session again with the play's inverse
replaced by ORACLES of it written here in Python, so that what limits it can be tried without
rebuilding the extension:

- ``now``: this tree's ``PlaySide`` (the oracle is checked against ``_rtcore.servo_lead`` on every
  session, to 1e-9 rad, so its figures are the Rust's);
- ``before``: the ``PlaySide`` of commit e15122c (h21g's two horizons: the held one dead time⁺ +
  (2 − x)·crossing/2, at most a whole crossing; the present torque extrapolated to both; the
  travel rule at the edge of the horn's friction);
- ``now, held horizon of before`` and ``now, no noise margin``: ``now`` with one of its changes
  undone (the held horizon of ``before``; the travel rule at the friction's edge): what each adds;
- ``now, forecast``: ``now`` with the hand's *true* torque at each horizon (the bench's hand is a
  known function): what a perfect torque forecast would add;
- ``now, true servo``: ``now`` with the oracle servo's own T, m, s, b, play and horn friction
  instead of the fitted ones: what a perfect fit would add.

Each row also gives the horn error around the moments the hand's torque leaves the horn's
friction band (it takes hold of the horn) and enters it (it lets go), in ms bins from that moment:
where a crossing of the play costs.

``--torque-noise SIGMA`` adds white noise (N·m, seeded) to the torque the compensation sees (the
recording and the fit are unchanged): a force sensor's noise. ``--rest-noise SIGMA`` instead counts
how often ``before`` and ``now`` flip the side (the goal crossing the play) with the joint at rest
under that much white torque noise for 60 s. All data are synthetic (test oracles).
Usage::

    .venv/bin/python bench/servo_forms.py --forms geared-0.25,geared,geared-1,geared-2 --json FITS.json
    .venv/bin/python bench/servo_play_variants.py --fits FITS.json [--torque-noise 0.005] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from oracles.servo import HANDS, RATE, GearedOracle, session  # noqa: E402
from servo_forms import play_phases, table  # noqa: E402

H = 1.0 / RATE
NAMES = ("time_constant", "inertial_time", "dead_time", "compliance", "deadband", "backlash", "backlash_torque")
TORQUE_MIN, VELOCITY_MIN = 0.01, 0.02  # plant::servo::PLAY_TORQUE_MIN, PLAY_VELOCITY_MIN
NOISE_WINDOW = 1.0  # plant::servo::PLAY_NOISE_WINDOW


def lead_oracle(p, w, a, q):
    """plant::servo::lead, vectorised (an oracle: the play's variants need it without the play)."""
    T, m, d, s, b = p[:5]
    ahead = w + a * d
    return w * d + 0.5 * a * d * d + T * (m * a + ahead) + b * ahead / np.sqrt(ahead ** 2 + 0.02 ** 2) - s * q


def crossing_of(p, speed=1.0):
    return max(math.sqrt(p[1] * p[0]), p[0]) * speed


class PlayOracle:
    """The play's inverse: the side, and the shaped crossing with the servo's inverse of it. The
    ``decide`` variants differ; the crossing is plant::servo::PlaySide's."""

    def __init__(self, p, speed=1.0):
        self.p, self.crossing = p, crossing_of(p, speed)
        self.side, self.stages = 0.0, [0.0, 0.0, 0.0]

    def cross(self):
        T, m, beta = self.p[0], self.p[1], self.p[5]
        stage = self.crossing / 3.0
        share, value = H / (stage + H), -0.5 * beta * self.side
        for j in range(3):
            self.stages[j] += (value - self.stages[j]) * share
            value = self.stages[j]
        a, b, c = self.stages
        return c + T * (m * (a - 2 * b + c) / stage ** 2 + (b - c) / stage)


class TwoHorizons(PlayOracle):
    """Commit e15122c's PlaySide (h21g): a free and a held horizon, the held one dead time⁺ +
    (2 − x)·crossing/2, the torque's rate from two low-passes in cascade, the present torque
    extrapolated to both; ``forecast`` (the hand's true torque) replaces the extrapolation."""

    def __init__(self, p, speed=1.0, forecast=None):
        super().__init__(p, speed)
        self.filters, self.forecast = [0.0, 0.0], forecast
        self.smoothing = 0.5 * (max(p[2], 0.0) + 0.5 * self.crossing)

    def horizons(self, omega):
        share = min(2 * abs(omega) * self.crossing / self.p[5], 1.0)
        dead = max(self.p[2], 0.0)
        return dead + 0.5 * self.crossing * share, dead + 0.5 * self.crossing * (2 - share)

    def rate(self, q):
        share = H / (self.smoothing + H)
        self.filters[0] += (q - self.filters[0]) * share
        self.filters[1] += (self.filters[0] - self.filters[1]) * share
        return (self.filters[0] - self.filters[1]) / self.smoothing

    def predict(self, t, q, rate, free, held):
        if self.forecast is not None:
            return self.forecast(t + free), self.forecast(t + held)
        if abs(q) > TORQUE_MIN or abs(rate * held) > TORQUE_MIN:
            return q + rate * free, q + rate * held
        return q, q

    def choose(self, tau_free, tau_held, omega, free_below, held_margin=0.0):
        push = max(self.p[6], TORQUE_MIN)
        if abs(tau_held) > push + held_margin:
            self.side = math.copysign(1.0, tau_held)
        elif abs(tau_free) > push:
            self.side = math.copysign(1.0, tau_free)
        elif abs(tau_free) <= free_below and abs(omega) > VELOCITY_MIN:
            self.side = -math.copysign(1.0, omega)

    def decide(self, t, w, a, q):
        rate = self.rate(q)
        free, held = self.horizons(w + a * max(self.p[2], 0.0))
        tau_free, tau_held = self.predict(t, q, rate, free, held)
        self.choose(tau_free, tau_held, w + a * free, self.p[6])


def crossing_left(u):
    """plant::servo::crossing_left: the three stages' Erlang survival."""
    return math.exp(-u) * (1 + u + 0.5 * u * u)


def held_lead(r):
    """plant::servo::held_lead: the root of crossing_left(u) = r·u, by the same bisection."""
    low, high = 0.0, 40.0
    for _ in range(48):
        mid = 0.5 * (low + high)
        if crossing_left(mid) > r * mid:
            low = mid
        else:
            high = mid
    return 0.5 * (low + high)


def held_torque_noise(share, c):
    """plant::servo::held_torque_noise: the held torque's variance per unit of white noise's."""
    x = (1 - share) ** 2
    return ((1 + c) ** 2 * share ** 2 / (1 - x) - 2 * c * (1 + c) * share ** 3 / (1 - x) ** 2
            + c * c * share ** 4 * (1 + x) / (1 - x) ** 3)


class Now(TwoHorizons):
    """This tree's PlaySide: the held horizon where the error before and after the hand takes hold
    is least (``held_lead``), the held torque from the first low-pass, the rest gate over a
    crossing, the travel rule only one measured noise σ within q_b, and at rest the held torque
    beyond the push by twice its own noise. ``held_of_before`` and ``margin`` switch the first
    and the travel rule's margin off (ablations)."""

    def __init__(self, p, speed=1.0, forecast=None, held_of_before=False, margin=True):
        super().__init__(p, speed, forecast)
        self.held_of_before, self.margin = held_of_before, margin
        self.last, self.noise = None, 0.0

    def horizons(self, omega):
        free, held = super().horizons(omega)
        if self.held_of_before:
            return free, held
        stage = self.crossing / 3
        runaway = max(abs(omega), VELOCITY_MIN) * stage / self.p[5]
        return free, max(max(self.p[2], 0.0) + stage * held_lead(runaway), held)

    def predict(self, t, q, rate, free, held):
        if self.forecast is not None:
            return self.forecast(t + free), self.forecast(t + held)
        if abs(q) > TORQUE_MIN or abs(rate * (max(self.p[2], 0.0) + self.crossing)) > TORQUE_MIN:
            return q + rate * free, self.filters[0] + rate * (held + self.smoothing)
        return q, q

    def decide(self, t, w, a, q):
        one, two = self.last if self.last is not None else (q, q)
        self.noise += ((q - 2 * one + two) ** 2 / 6 - self.noise) * H / (NOISE_WINDOW + H)
        self.last = (q, one)
        rate = self.rate(q)
        ahead = w + a * max(self.p[2], 0.0)
        free, held = self.horizons(ahead)
        tau_free, tau_held = self.predict(t, q, rate, free, held)
        below = self.p[6] - (math.sqrt(self.noise) if self.margin else 0.0)
        beyond = 0.0
        if abs(ahead) <= VELOCITY_MIN and self.noise > 0:  # at rest: beyond twice the held torque's noise
            share = H / (self.smoothing + H)
            beyond = 2 * math.sqrt(self.noise * held_torque_noise(share, (held + self.smoothing) / self.smoothing))
        self.choose(tau_free, tau_held, w + a * free, below, beyond)


def offsets(play: PlayOracle, w, a, q):
    out = np.zeros(len(w))
    for i in range(len(w)):
        play.decide(i * H, w[i], a[i], q[i])
        out[i] = play.cross()
    return out


BINS = ((-30, 0), (0, 10), (10, 20), (20, 30), (30, 60))  # ms from the moment the torque crosses ±q_b


def around_switches(cols: dict, free: float) -> dict:
    """The horn error's RMS (mrad) in ``BINS`` around the moments the hand's torque leaves the
    horn's friction band (it takes hold: "take-hold") and enters it (it lets go: "let-go"), over
    all such moments of the session, and the take-hold's share of the session's mean square in
    the 30 ms after."""
    tau, error = cols["tau"], cols["theta_present"] - cols["theta_model"]
    state = np.sign(np.where(np.abs(tau) > free, tau, 0.0))
    switches = np.nonzero(np.r_[False, state[1:] != state[:-1]])[0]
    switches = switches[(switches > 60) & (switches < len(tau) - 60)]
    out = {}
    for kind, mask in (("take-hold", state[switches] != 0), ("let-go", state[switches] == 0)):
        window = np.array([error[k - 30:k + 60] for k in switches[mask]])
        out[kind] = [float(1e3 * np.sqrt(np.nanmean(window[:, a + 30:b + 30] ** 2))) for a, b in BINS]
        if kind == "take-hold":
            out["take-hold share"] = float(np.nansum(window[:, 30:60] ** 2) / np.nansum(error ** 2))
    return out


def true_params(truth: GearedOracle) -> list[float]:
    """The oracle servo's own values in the servo form (docs/fidelity.md: T = D/K, m = I/D, s = 1/K,
    b = F/K); the horn is read 0.3 ms after the goal is written (a dead time of −0.3 ms)."""
    damping = truth.damping + truth.kt ** 2 / truth.r
    k = truth.stiffness
    return [damping / k, truth.inertia / damping, -3e-4, 1 / k, truth.coulomb / k, truth.play, truth.free]


def variants(hand):
    return {"now": (Now, {}), "before": (TwoHorizons, {}), "now, held horizon of before": (Now, {"held_of_before": True}),
            "now, no noise margin": (Now, {"margin": False}), "now, forecast": (Now, {"forecast": hand}),
            "now, true servo": (Now, {"true": True})}


def measure(row: dict, hand: str, noise: float, seed: int) -> dict:
    from admittance import _rtcore

    fitted = [row["servo"][k] for k in NAMES]
    play = play_of(row)
    out = {"form": row["form"], "off": row["off"]}
    for name, (kind, opts) in variants(HANDS[hand]).items():
        opts = dict(opts)
        p = true_params(GearedOracle(backlash=play)) if opts.pop("true", False) else fitted

        def lead(w, a, q, p=p, kind=kind, opts=opts, name=name):
            seen = q + np.random.default_rng(seed).normal(0.0, noise, len(q)) if noise else q
            played = lead_oracle(p, w, a, seen) + offsets(kind(p, **opts), w, a, seen)
            if name == "now":  # the oracle is the Rust
                rust = _rtcore.servo_lead(np.array(p), w, a, seen, h=H)
                assert np.max(np.abs(rust - played)) < 1e-9, np.max(np.abs(rust - played))
            return played

        trace: dict = {}
        with tempfile.TemporaryDirectory(prefix="servo-play-") as tmp:
            error = session(Path(tmp) / "on", GearedOracle(backlash=play), lead=lead, hand=HANDS[hand], trace=trace)
        phases = play_phases(trace, GearedOracle(backlash=play).free)
        switches = around_switches(trace, GearedOracle(backlash=play).free)
        out[name] = {"error": error, "ratio": row["off"] / error, "phases": phases, "switches": switches}
        print(f"| {row['form']} | {name} | {1e3 * error:.3f} | {row['off'] / error:.2f}× | "
              + " / ".join(f"{100 * share:.0f} %" for _, share, _ in phases) + " | "
              + "; ".join(f"{kind} " + " / ".join(f"{rms:.2f}" for rms in switches[kind]) for kind in ("take-hold", "let-go"))
              + f" ({100 * switches['take-hold share']:.0f} % of the mean square 0–30 ms after a take-hold) |", flush=True)
    return out


def rest_flips(row: dict, sigma: float, seconds: float = 60.0, seed: int = 3) -> dict:
    """Side flips of ``before`` and ``now`` on the form's fit with the joint at rest under white
    torque noise of ``sigma`` N·m (and speed noise of 5 mrad/s): each flip moves the goal across the
    play (a chatter of the goal)."""
    rng = np.random.default_rng(seed)
    n = int(seconds * RATE)
    q, w = rng.normal(0.0, sigma, n), rng.normal(0.0, 0.005, n)
    p = [row["servo"][k] for k in NAMES]
    out = {}
    for name, kind in (("before", TwoHorizons), ("now", Now)):
        play, flips, side = kind(p), 0, 0.0
        for i in range(n):
            play.decide(i * H, w[i], 0.0, q[i])
            flips, side = flips + (play.side != side), play.side
        out[name] = flips
    print(f"| {row['form']} | at rest, torque noise {sigma} N·m | side flips in {seconds:g} s: before "
          f"{out['before']}, now {out['now']} |", flush=True)
    return out


def play_of(row: dict) -> float:
    """The form's true play, from its label ("MX-64 geared, 1° backlash")."""
    return math.radians(float(row["form"].split(", ")[1].split("°")[0]))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fits", type=Path, required=True, help="bench/servo_forms.py --json output (geared forms)")
    parser.add_argument("--hand", default="multisine", choices=sorted(HANDS))
    parser.add_argument("--torque-noise", type=float, default=0.0, help="N·m, white, on the torque the compensation sees")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--rest-noise", type=float, default=0.0,
                        help="N·m: instead, count the side's flips with the joint at rest under this torque noise")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    rows = [r for r in json.loads(args.fits.read_text()) if "geared" in r["form"] and r["hand"] == args.hand]
    if not rows:
        parser.error(f"no geared form with the {args.hand} hand in {args.fits}")
    header = ("| servo form | play's inverse | horn error (mrad) | gain | share of the mean square: hand within the "
              "horn's friction / 0–30 ms after the torque left or entered that band / 30–60 ms after / 0–30 ms "
              "before it next does / elsewhere | horn error RMS (mrad) around the hand taking hold and letting go, "
              "ms from the switch: −30–0 / 0–10 / 10–20 / 20–30 / 30–60 |")
    if args.rest_noise:
        return table("at rest", "| servo form | session | flips |",
                     lambda: [rest_flips(row, args.rest_noise) for row in rows], args.json)
    return table(f"hand: {args.hand}, torque noise {args.torque_noise} N·m", header,
                 lambda: [measure(row, args.hand, args.torque_noise, args.seed) for row in rows], args.json)


if __name__ == "__main__":
    raise SystemExit(main())
