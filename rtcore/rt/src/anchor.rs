//! No single position read moves the joint: every read is checked against what the horn could
//! physically have done before it is trusted.
//!
//! Two uses, one record per joint ([`ReadCheck`]):
//!
//! - **Anchoring** (the loop's start, a recovery's re-anchor): the model and the goal are put
//!   where the horn is, and torque may then go on. A read anchors only when *confirmed*
//!   ([`ReadCheck::anchor`]): it agrees with the anchoring read before it or with the last
//!   trusted running read, either taken within [`PAIR_WINDOW_NS`] (within
//!   [`READ_TOLERANCE_RAD`] plus what the joint's own `velocity_max` allows in the time between
//!   them), it lies inside the servo's tick range and the joint's position limits, and it is
//!   consistent with the last trusted read and the time since (at `horn_speed_max`). One glitched
//!   read (an encoder's +2000 ticks) so never becomes a goal: the next read disagrees with it.
//! - **Running reads** ([`ReadCheck::running`]): a read that jumps from the last trusted one
//!   faster than any horn can turn (`horn_speed_max`) is not trusted: the cycle marks it
//!   (`FaultKind::PositionGlitch`), counts it, and keeps it out of the record's present
//!   position and the compensation's horn error. A second read that agrees with the jumped one
//!   confirms it (the horn really is there: a stretch without reads, a hand during a silence),
//!   so a real move is never locked out.
//!
//! Pure logic on times and ticks passed in: no bus, no clock, no allocation.
use crate::joint::TickMap;
use crate::params::Limits;

/// Two reads of a horn at rest differ by encoder noise (a tick or two); this much more than the
/// motion allowed between them is still "the same place" (0.01 rad ≈ 6.5 ticks at 4096/rev).
pub const READ_TOLERANCE_RAD: f64 = 0.01;

/// Two anchoring reads confirm each other only when taken this close together (the start reads
/// back to back, a recovery every 10 ms): an old read says nothing about where the horn is now.
pub const PAIR_WINDOW_NS: u64 = 100_000_000;

/// A trusted or pending read: its tick and when it was taken (CLOCK_MONOTONIC ns).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Read {
    tick: i64,
    t_ns: u64,
}

/// Why an anchoring read was not taken.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AnchorRefusal {
    /// The read has nothing recent to agree with yet: read again.
    Unconfirmed,
    /// It disagrees with the read just before it (one of them glitched): read again.
    Disagrees,
    /// Outside the servo's tick range (`tick_min..=tick_max`): no servo reports that.
    OutOfRange { tick: i64 },
    /// Confirmed, but outside the joint's position limits: torque must not go on there.
    OutsideLimits { theta: f64 },
    /// Confirmed, but farther from the last trusted read than the horn could have turned since.
    Jump { tick: i64, last_tick: i64 },
}

/// One joint's position reads: the last trusted one, and the reads awaiting confirmation (an
/// anchoring's first read, a running read that jumped), each kept apart so the running reads
/// between two anchoring reads do not undo the pair.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReadCheck {
    trusted: Option<Read>,
    anchoring: Option<Read>,
    jumped: Option<Read>,
}

impl ReadCheck {
    /// The last trusted tick.
    pub fn trusted_tick(&self) -> Option<i64> {
        self.trusted.map(|r| r.tick)
    }

    /// An anchoring read at `t_ns`: `Ok(tick)` when it is confirmed and may anchor the model
    /// (it then becomes the trusted read); otherwise why not. An unconfirmed read is kept to be
    /// confirmed by the next one.
    pub fn anchor(&mut self, tick: i64, t_ns: u64, ticks: &TickMap, limits: &Limits, horn_speed_max: f64) -> Result<i64, AnchorRefusal> {
        let read = Read { tick, t_ns };
        if tick < ticks.tick_min || tick > ticks.tick_max {
            self.anchoring = None;
            return Err(AnchorRefusal::OutOfRange { tick });
        }
        // Its partner: the anchoring read before it, or the last trusted running read (the
        // SyncRead's, every cycle: a recovery's own reads may come seconds apart on a busy bus,
        // each too old for the one before; the HIL glitch test stayed in `reanchoring` so).
        let recent = |p: &Read| t_ns.saturating_sub(p.t_ns) <= PAIR_WINDOW_NS;
        let partners = [self.anchoring.filter(recent), self.trusted.filter(recent)];
        self.anchoring = Some(read);
        if partners.iter().all(Option::is_none) {
            return Err(AnchorRefusal::Unconfirmed);
        }
        if !partners.iter().flatten().any(|p| within(ticks, *p, read, limits.velocity_max)) {
            return Err(AnchorRefusal::Disagrees);
        }
        let theta = ticks.theta_of(tick);
        let (lo, hi) = (limits.position_min - READ_TOLERANCE_RAD, limits.position_max + READ_TOLERANCE_RAD);
        if !(lo..=hi).contains(&theta) {
            return Err(AnchorRefusal::OutsideLimits { theta });
        }
        if let Some(last) = self.trusted.filter(|last| !within(ticks, *last, read, horn_speed_max)) {
            return Err(AnchorRefusal::Jump { tick, last_tick: last.tick });
        }
        self.trust(read);
        Ok(tick)
    }

    /// A running read at `t_ns`: true when it may be used (consistent with the last trusted read
    /// at `horn_speed_max`, or confirmed by the read before it); false for a glitch.
    pub fn running(&mut self, tick: i64, t_ns: u64, ticks: &TickMap, horn_speed_max: f64) -> bool {
        let read = Read { tick, t_ns };
        let in_range = (ticks.tick_min..=ticks.tick_max).contains(&tick);
        let consistent = match self.trusted {
            None => true, // nothing to hold it against (never anchored: the loop does not run so)
            Some(last) => within(ticks, last, read, horn_speed_max),
        };
        let confirmed = self.jumped.is_some_and(|p| within(ticks, p, read, horn_speed_max));
        if in_range && (consistent || confirmed) {
            self.trusted = Some(read);
            self.jumped = None;
            return true;
        }
        self.jumped = in_range.then_some(read);
        false
    }

    fn trust(&mut self, read: Read) {
        self.trusted = Some(read);
        self.anchoring = None;
        self.jumped = None;
    }
}

/// Whether `b` is where the horn could be, `a` having been read before it, at `speed` rad/s.
fn within(ticks: &TickMap, a: Read, b: Read, speed: f64) -> bool {
    let dt = b.t_ns.saturating_sub(a.t_ns) as f64 * 1e-9;
    let moved = (ticks.theta_of(b.tick) - ticks.theta_of(a.tick)).abs();
    // A NaN speed (never from a validated configuration) allows nothing: `<=` is then false.
    moved <= READ_TOLERANCE_RAD + speed.max(0.0) * dt
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;
    const TICKS: TickMap = TickMap { zero_tick: 2048, direction: 1, ticks_per_rev: 4096.0, tick_min: 0, tick_max: 4095 };
    const LIMITS: Limits = Limits { position_min: -3.1, position_max: 3.1, velocity_max: 6.0, acceleration_max: 1e3 };
    const SPEED: f64 = 50.0;

    #[test]
    fn one_read_never_anchors() {
        let mut c = ReadCheck::default();
        assert_eq!(c.anchor(2048, 0, &TICKS, &LIMITS, SPEED), Err(AnchorRefusal::Unconfirmed));
        assert_eq!(c.anchor(2049, MS, &TICKS, &LIMITS, SPEED), Ok(2049));
        assert_eq!(c.trusted_tick(), Some(2049));
    }

    #[test]
    fn a_glitched_first_read_is_outvoted_by_the_two_after_it() {
        let mut c = ReadCheck::default();
        assert_eq!(c.anchor(4048, 0, &TICKS, &LIMITS, SPEED), Err(AnchorRefusal::Unconfirmed));
        assert_eq!(c.anchor(2048, MS, &TICKS, &LIMITS, SPEED), Err(AnchorRefusal::Disagrees));
        assert_eq!(c.anchor(2047, 2 * MS, &TICKS, &LIMITS, SPEED), Ok(2047));
    }

    #[test]
    fn a_glitched_second_read_is_not_taken() {
        let mut c = ReadCheck::default();
        c.anchor(2048, 0, &TICKS, &LIMITS, SPEED).unwrap_err();
        assert_eq!(c.anchor(4048, MS, &TICKS, &LIMITS, SPEED), Err(AnchorRefusal::Disagrees));
    }

    #[test]
    fn an_old_read_confirms_nothing() {
        let mut c = ReadCheck::default();
        c.anchor(2048, 0, &TICKS, &LIMITS, SPEED).unwrap_err();
        // 200 ms later velocity_max would allow 1.2 rad: the old read is not a partner.
        assert_eq!(c.anchor(2600, 200 * MS, &TICKS, &LIMITS, SPEED), Err(AnchorRefusal::Unconfirmed));
        assert_eq!(c.anchor(2600, 210 * MS, &TICKS, &LIMITS, SPEED), Ok(2600));
    }

    #[test]
    fn agreement_allows_the_joints_own_speed_between_reads_and_no_more() {
        // 10 ms apart at velocity_max 6 rad/s: 0.06 rad + the tolerance ≈ 45.6 ticks.
        let mut c = ReadCheck::default();
        c.anchor(2048, 0, &TICKS, &LIMITS, SPEED).unwrap_err();
        assert_eq!(c.anchor(2093, 10 * MS, &TICKS, &LIMITS, SPEED), Ok(2093));
        let mut c = ReadCheck::default();
        c.anchor(2048, 0, &TICKS, &LIMITS, SPEED).unwrap_err();
        assert_eq!(c.anchor(2095, 10 * MS, &TICKS, &LIMITS, SPEED), Err(AnchorRefusal::Disagrees));
    }

    #[test]
    fn a_confirmed_read_outside_the_limits_or_the_range_does_not_anchor() {
        let mut c = ReadCheck::default();
        let beyond = TICKS.goal_tick(3.3);
        c.anchor(beyond, 0, &TICKS, &LIMITS, SPEED).unwrap_err();
        assert!(matches!(c.anchor(beyond, MS, &TICKS, &LIMITS, SPEED), Err(AnchorRefusal::OutsideLimits { .. })));
        assert_eq!(c.trusted_tick(), None);
        assert_eq!(c.anchor(5000, 2 * MS, &TICKS, &LIMITS, SPEED), Err(AnchorRefusal::OutOfRange { tick: 5000 }));
        // At a limit, within the tolerance: taken.
        let at = TICKS.goal_tick(3.1 + 0.005);
        c.anchor(at, 3 * MS, &TICKS, &LIMITS, SPEED).unwrap_err();
        assert_eq!(c.anchor(at, 4 * MS, &TICKS, &LIMITS, SPEED), Ok(at));
    }

    #[test]
    fn a_re_anchor_far_from_the_last_trusted_read_waits_for_the_time_that_makes_it_possible() {
        let mut c = ReadCheck::default();
        c.anchor(2048, 0, &TICKS, &LIMITS, SPEED).unwrap_err();
        c.anchor(2048, MS, &TICKS, &LIMITS, SPEED).unwrap();
        // Two agreeing reads 2 rad away only 10 ms later: no horn turns that fast.
        let far = TICKS.goal_tick(2.0);
        c.anchor(far, 10 * MS, &TICKS, &LIMITS, SPEED).unwrap_err();
        assert!(matches!(c.anchor(far, 11 * MS, &TICKS, &LIMITS, SPEED), Err(AnchorRefusal::Jump { .. })));
        // 200 ms later 50 rad/s allows 10 rad: the horn may really be there (moved by hand).
        c.anchor(far, 200 * MS, &TICKS, &LIMITS, SPEED).unwrap_err();
        assert_eq!(c.anchor(far, 201 * MS, &TICKS, &LIMITS, SPEED), Ok(far));
    }

    #[test]
    fn a_running_jump_is_a_glitch_until_a_second_read_confirms_it() {
        let mut c = ReadCheck::default();
        c.anchor(2048, 0, &TICKS, &LIMITS, SPEED).unwrap_err();
        c.anchor(2048, MS, &TICKS, &LIMITS, SPEED).unwrap();
        assert!(c.running(2060, 11 * MS, &TICKS, SPEED));
        assert!(!c.running(4060, 21 * MS, &TICKS, SPEED), "+2000 ticks in 10 ms");
        assert!(c.running(2062, 31 * MS, &TICKS, SPEED), "back where it was: trusted");
        assert!(!c.running(4000, 41 * MS, &TICKS, SPEED));
        assert!(c.running(4001, 51 * MS, &TICKS, SPEED), "the same place twice: the horn is there");
        assert_eq!(c.trusted_tick(), Some(4001));
        assert!(!c.running(-5, 61 * MS, &TICKS, SPEED), "outside the tick range");
        assert!(!c.running(-5, 71 * MS, &TICKS, SPEED), "never confirmed");
    }

    #[test]
    fn running_reads_between_two_anchoring_reads_do_not_undo_the_pair() {
        let mut c = ReadCheck::default();
        assert!(c.running(2048, 0, &TICKS, SPEED));
        c.anchor(2100, 5 * MS, &TICKS, &LIMITS, SPEED).unwrap_err();
        assert!(c.running(2100, 6 * MS, &TICKS, SPEED));
        assert_eq!(c.anchor(2100, 15 * MS, &TICKS, &LIMITS, SPEED), Ok(2100));
    }

    #[test]
    fn a_recent_trusted_running_read_confirms_an_anchoring_read() {
        let mut c = ReadCheck::default();
        assert!(c.running(2700, 0, &TICKS, SPEED));
        assert_eq!(c.anchor(2701, 2 * MS, &TICKS, &LIMITS, SPEED), Ok(2701));
        // A glitched anchoring read disagrees with it; an old one confirms nothing.
        let mut c = ReadCheck::default();
        assert!(c.running(2700, 0, &TICKS, SPEED));
        assert_eq!(c.anchor(4700, 2 * MS, &TICKS, &LIMITS, SPEED), Err(AnchorRefusal::OutOfRange { tick: 4700 }));
        assert_eq!(c.anchor(3700, 3 * MS, &TICKS, &LIMITS, SPEED), Err(AnchorRefusal::Disagrees));
        assert_eq!(c.anchor(2700, 500 * MS, &TICKS, &LIMITS, SPEED), Err(AnchorRefusal::Unconfirmed));
    }

    #[test]
    fn a_long_silence_allows_a_long_move() {
        let mut c = ReadCheck::default();
        assert!(c.running(2048, 0, &TICKS, SPEED));
        assert!(c.running(TICKS.goal_tick(2.5), 200 * MS, &TICKS, SPEED));
    }
}
