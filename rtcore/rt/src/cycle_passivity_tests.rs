//! The passivity guard in the loop: a hand gripping the horn of a servo that follows its goal
//! late, at a virtual inertia far below the hand's. Without the guard the horn oscillates and
//! feeds the hand energy; with it the oscillation dies out, and a joint that stays passive is
//! left exactly as it was. Deterministic: the fake clock, the in-memory bus, and a test oracle of
//! the servo and the hand (a lagging position source, the hand's inertia, damping and stiffness).
use super::tests::{free_joint, started, Rig, RATE};
use super::*;
use std::f64::consts::TAU;

/// The hand: kg·m², N·m·s/rad, N·m/rad (bench/fidelity.py's gripping hand).
const HAND: (f64, f64, f64) = (0.0055, 0.15, 2.0);
/// The servo: a position source following its goal with this lag (s) after this many cycles.
const LAG_S: f64 = 0.01;
const DELAY: usize = 2;
/// J: the guard's margin here (the oracle's lagging horn dips a passive joint's balance to
/// −0.005 J at a push's start).
const MARGIN: f64 = 0.01;
const LEVER: f64 = 0.1;

/// The test oracle of the horn and the hand around the loop.
struct Bench {
    rig: Rig,
    goals: Vec<f64>,
    horn: [f64; 3],
}

impl Bench {
    fn new(inertia: f64, guard: bool) -> Bench {
        let mut p = free_joint();
        p.joints[0].gains = JointGains { inertia, damping: 0.0347, coulomb: 0.0, lever_arm: LEVER };
        p.joints[0].passivity.guard = if guard { 1.0 } else { 0.0 };
        p.joints[0].passivity.margin = MARGIN;
        let mut rig = started(p, &[(1, 2048)]);
        rig.ctl.sync_read_divisor = 1;
        Bench { rig, goals: vec![0.0; DELAY + 1], horn: [0.0; 3] }
    }

    /// One cycle with the hand's `push` (N·m) besides its grip; the record.
    fn cycle(&mut self, push: f64) -> Record {
        let h = 1.0 / RATE;
        let [a, b, c] = self.horn;
        let (inertia, damping, stiffness) = HAND;
        let tau = push - inertia * (c - 2.0 * b + a) / (h * h) - damping * (c - b) / h - stiffness * c;
        let rec = self.rig.cycle_with(Some(tau / LEVER));
        self.goals.push((rec.goal_tick - 2048) as f64 * TAU / 4096.0);
        let goal = self.goals.remove(0);
        let next = c + (goal - c) * h / (LAG_S + h);
        self.horn = [b, c, next];
        let tick = 2048 + (next * 4096.0 / TAU).round() as i64;
        self.rig.bus.wire().present = vec![(1, tick)];
        rec
    }

    /// A push of 0.3 N·m for 0.3 s, then `seconds` of the grip alone: the horn's peak-to-peak
    /// swing in the last second, and the records.
    fn push_and_release(&mut self, seconds: f64) -> (f64, Vec<Record>) {
        let n = (seconds * RATE) as usize;
        let records: Vec<Record> = (0..n).map(|k| self.cycle(if k < 300 { 0.3 } else { 0.0 })).collect();
        let last: Vec<f64> = self.goals.iter().copied().chain([self.horn[2]]).collect();
        let tail = records[n - 1000..].iter().map(|r| r.present_tick as f64 * TAU / 4096.0);
        let (lo, hi) = tail.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| (lo.min(x), hi.max(x)));
        assert!(last.iter().all(|x| x.is_finite()));
        (hi - lo, records)
    }
}

#[test]
fn without_the_guard_a_light_joint_oscillates_under_the_hand() {
    let (swing, records) = Bench::new(0.001, false).push_and_release(4.0);
    assert!(swing > 0.05, "the oracle's loop must be unstable here, swing {swing} rad");
    assert!(records.iter().all(|r| r.passivity_damping == 0.0), "the guard is off");
    let generated = records.iter().map(|r| r.passivity_energy).fold(0.0, f64::min);
    assert!(generated < -0.01, "and the observer sees the energy it feeds the hand: {generated} J");
}

#[test]
fn the_guard_damps_the_oscillation_out_and_keeps_the_energy_within_its_margin() {
    let (swing, records) = Bench::new(0.001, true).push_and_release(4.0);
    assert!(swing < 2.0 * TAU / 4096.0, "the horn settles within two ticks, swing {swing} rad");
    assert!(records.iter().any(|r| r.passivity_damping > 0.0), "the guard acted");
    let generated = records.iter().map(|r| r.passivity_energy).fold(0.0, f64::min);
    // The guard starts at half the margin with a damping that grows with the depth: the energy
    // that still arrives after it starts (the lagging horn, a tick's worth of work at a time)
    // stays within the other half (acting at the margin with the damping of the excess alone
    // let this joint give the hand 3 margins).
    assert!(generated > -MARGIN, "the joint gave the hand no more than the margin: {generated} J");
    // Added and removed without a jump: the damping moves by at most its growth per cycle.
    for pair in records.windows(2) {
        let (a, b) = (pair[0].passivity_damping, pair[1].passivity_damping);
        let h = 1.0 / RATE;
        let rise = (1.0 - a) * h / (crate::passivity::RISE_S + h) + crate::passivity::START_FRACTION;
        assert!(b - a <= rise + 1e-12 && a - b <= a * h / crate::passivity::RELEASE_S + 1e-3, "{a} → {b}");
    }
    let goal_steps = records.windows(2).map(|p| (p[1].goal_tick - p[0].goal_tick).abs()).max().unwrap();
    assert!(goal_steps <= 3, "no goal jumps more than 3 ticks in a cycle: {goal_steps}");
}

#[test]
fn a_stable_joint_under_the_same_hand_is_left_exactly_as_it_was() {
    let (_, on) = Bench::new(0.02, true).push_and_release(3.0);
    let (_, off) = Bench::new(0.02, false).push_and_release(3.0);
    assert!(on.iter().all(|r| r.passivity_damping == 0.0), "a passive joint never gets damping");
    let same = on.iter().zip(&off).all(|(a, b)| a.theta == b.theta && a.goal_tick == b.goal_tick);
    assert!(same, "so its model and goals are the guard-off ones, bit for bit");
    assert!(on.iter().map(|r| r.passivity_energy).fold(f64::INFINITY, f64::min) > -MARGIN);
}

