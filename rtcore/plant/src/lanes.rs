//! Simulations of different trials stepped side by side: what `batch::Batch` runs.
//!
//! Why side by side: a substep is a chain of dependent operations (a sine of the angle, then
//! the velocity, then the angle again) that leaves most of a core idle while it waits; the
//! independent chains of a few simulations fill that wait. Why each lane on its own trial:
//! identification also makes many calls with a single parameter set (a damped trial of its
//! Levenberg–Marquardt fit) over its ~30 trials; with lanes bound to one trial such a call
//! had one lane per work item and nothing to overlap. So every lane walks its own trial's
//! sample times (its own substep count per interval, its own torque cursor, its own rest and
//! end), and the lanes are interleaved substep by substep.
use crate::friction::FrictionLaw;
use crate::model::{rests_for_good, Load, State, Substep};
use crate::params::Params;
use crate::trial::{substep_count, TorqueCursor, Trial};

/// One simulation for `simulate_lanes`: a trial, a validated parameter set, the initial state.
#[derive(Clone, Copy)]
pub struct Run<'a> {
    pub trial: &'a Trial,
    pub params: &'a Params,
    pub x0: State,
}

impl Run<'_> {
    /// The parameters the plant steps with: gain, bias and drift correct a *measured* torque,
    /// so on a trial without one bias and drift are left out (the gain multiplies a zero).
    fn stepped_params(&self) -> Params {
        match self.trial.tau() {
            Some(_) => *self.params,
            None => Params { torque_bias: 0.0, torque_drift: 0.0, ..*self.params },
        }
    }
}

/// `trial::simulate_into` for `L` simulations at once, each on its own trial: lane `l` runs
/// `runs[l]` and hands its states to `record(l, i, &state)`, the numbers `simulate_into`
/// gives for it alone, to the bit (tests/lanes.rs). A lane whose trial ends, or whose drop
/// rests for good (`model::rests_for_good`), is no longer stepped; the call ends when all are.
/// Expects a validated `max_step`.
pub fn simulate_lanes<const L: usize, F: FnMut(usize, usize, &State)>(
    runs: [Run; L],
    law: FrictionLaw,
    max_step: f64,
    mut record: F,
) {
    let params: [Params; L] = runs.map(|run| run.stepped_params());
    let mut lanes: [Lane; L] = std::array::from_fn(|l| Lane::new(&runs[l], &params[l], law));
    for (l, lane) in lanes.iter_mut().enumerate() {
        lane.arrive(l, max_step, &mut record);
    }
    loop {
        let mut stepping = false;
        for (l, lane) in lanes.iter_mut().enumerate() {
            if lane.done {
                continue;
            }
            stepping = true;
            lane.advance();
            if lane.k == lane.n {
                lane.arrive(l, max_step, &mut record);
            }
        }
        if !stepping {
            return;
        }
    }
}

/// One simulation in flight: where it is in its own trial's walk (`trial::walk`'s
/// scheme: n equal substeps of h between consecutive samples, the k-th at t[i−1] + k·h).
struct Lane<'a> {
    t: &'a [f64],
    t0: f64,
    load: &'a Load,
    params: &'a Params,
    law: FrictionLaw,
    substep: Substep<'a>,
    /// The applied torque and its delay; `None` on a trial without one (a drop), which is the
    /// only kind that can rest for good.
    torque: Option<(TorqueCursor<'a>, f64)>,
    state: State,
    /// The sample walked towards, the start of its interval, the substeps taken and to take.
    next: usize,
    start: f64,
    k: usize,
    n: usize,
    /// The substep's length and h / inertia, recomputed only when the length changes.
    h: f64,
    gain: f64,
    done: bool,
}

impl<'a> Lane<'a> {
    fn new(run: &Run<'a>, params: &'a Params, law: FrictionLaw) -> Self {
        let trial = run.trial;
        let torque = trial.tau().map(|tau| (TorqueCursor::new(trial.t(), tau), params.time_delay));
        Lane {
            t: trial.t(),
            t0: trial.t()[0],
            load: trial.load_ref(),
            params,
            law,
            substep: Substep::new(params, trial.load_ref(), law),
            torque,
            state: run.x0,
            next: 0,
            start: 0.0,
            k: 0,
            n: 0,
            h: f64::NAN,
            gain: f64::NAN,
            done: false,
        }
    }

    /// The next substep of the interval.
    #[inline(always)]
    fn advance(&mut self) {
        let t = self.start + self.k as f64 * self.h;
        let applied = match &mut self.torque {
            Some((cursor, delay)) => cursor.at(t - *delay),
            None => 0.0,
        };
        self.substep.advance(&mut self.state, applied, t - self.t0, self.gain, self.h);
        self.k += 1;
    }

    /// Sample `next` is reached (0 before any substep): hand it over, then end the lane if its
    /// trial ends or its drop rests for good (its remaining samples filled with the rest
    /// state), else set up the next interval.
    fn arrive<F: FnMut(usize, usize, &State)>(&mut self, l: usize, max_step: f64, record: &mut F) {
        let i = self.next;
        record(l, i, &self.state);
        // ω == 0 first: the test costs a sine or two, and a moving joint skips it.
        if self.torque.is_none()
            && self.state.omega == 0.0
            && rests_for_good(&self.state, self.params, self.load, self.law, 0.0)
        {
            // What every later substep would leave: ω set to 0, θ + h·0.
            self.state = State { theta: self.state.theta + 0.0, omega: 0.0 };
            for j in i + 1..self.t.len() {
                record(l, j, &self.state);
            }
            self.done = true;
            return;
        }
        if i + 1 == self.t.len() {
            self.done = true;
            return;
        }
        let dt = self.t[i + 1] - self.t[i];
        self.n = substep_count(dt, max_step);
        let h = dt / self.n as f64;
        if h != self.h {
            self.h = h;
            self.gain = h / self.substep.inertia;
        }
        self.next = i + 1;
        self.start = self.t[i];
        self.k = 0;
    }
}
