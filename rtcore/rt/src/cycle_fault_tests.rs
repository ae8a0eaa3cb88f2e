//! Servo and bus faults through whole cycles on the fake clock: the in-memory wire's servos shut
//! down, lose their torque, reboot and go silent; its adapter is unplugged and plugged back.
//! Each test checks what the cycle did on the wire (REBOOT, goal = present before torque on, no
//! writes while the port is gone) and what it marked (fault bits, mode, the stop request).
use super::tests::{counting, free_joint, rig, Rig, PERIOD};
use super::*;
use crate::recovery::{FaultPolicy, StopCause, HW_ELECTRICAL_SHOCK, HW_OVERLOAD};
use dxl::protocol2;

/// A loop that drives its servos (torque on at start), reading them every cycle.
fn driving(present: &[(u8, i64)], policy: FaultPolicy) -> Rig {
    let mut r = rig(free_joint_for(present.len()), present);
    r.ctl.set_fault_policy(policy, true);
    r.ctl.sync_read_divisor = 1;
    let mut bus = r.bus.clone();
    r.ctl.start_at_present(&mut bus, &r.clock, 0, true).unwrap();
    r.ctl.begin(r.clock.now_ns());
    r
}

fn free_joint_for(n: usize) -> LoopParams {
    let one = free_joint();
    let mut p = crate::params::tests::params(n);
    for j in &mut p.joints {
        *j = one.joints[0];
    }
    p
}

/// Runs cycles (a still hand) until `done` or `max` cycles; every record, in order.
fn run_until(r: &mut Rig, max: usize, mut done: impl FnMut(&Rig) -> bool) -> Vec<Record> {
    let mut records = Vec::new();
    for _ in 0..max {
        records.push(r.cycle_with(Some(0.0))); // the first joint's record
        while let Ok(rec) = r.telemetry.pop() {
            records.push(rec);
        }
        if done(r) {
            break;
        }
    }
    records
}

/// The packets written, decoded: (instruction, id, params).
fn packets(r: &Rig) -> Vec<(u8, u8, Vec<u8>)> {
    r.bus.written().iter().map(|p| (p[7], p[4], p[8..p.len() - 2].to_vec())).collect()
}

/// The goal of joint `id` in a SYNC_WRITE's params (P2: address, size, then id + 4 bytes each).
fn goal_in(params: &[u8], id: u8) -> Option<i64> {
    params[4..].chunks(5).find(|c| c[0] == id).map(|c| i32::from_le_bytes([c[1], c[2], c[3], c[4]]) as i64)
}

fn events(r: &Rig, kind: FaultKind) -> u64 {
    r.shared.stats.faults.events(kind)
}

#[test]
fn an_overload_shutdown_reboots_then_torque_comes_back_on_at_the_present_position() {
    let mut r = driving(&[(1, 2048), (2, 2048)], FaultPolicy::default());
    run_until(&mut r, 20, |_| false);
    {
        let mut wire = r.bus.wire();
        wire.set_hardware(1, HW_OVERLOAD); // the firmware's Shutdown: torque off, alert set
        wire.set_torque(1, false);
        wire.present[0].1 = 2100; // the limp horn sagged meanwhile
        wire.reboot_silence = 5;
    }
    let before = r.bus.written().len();
    let records = run_until(&mut r, 2_000, |r| r.bus.wire().torque_of(1) && r.ctl.recovery.view(0).unwrap().phase == crate::recovery::Phase::Ok);
    assert!(r.bus.wire().torque_of(1), "torque is back on");
    assert_eq!(r.bus.wire().reboots, vec![1], "one REBOOT, of the servo that shut down");
    let sent = &packets(&r)[before..];
    let enable = sent.iter().position(|(ins, id, p)| *ins == 0x03 && *id == 1 && p[..3] == [64, 0, 1]).expect("torque on");
    let last_goal = sent[..enable].iter().rev().find(|(ins, ..)| *ins == 0x83).and_then(|(_, _, p)| goal_in(p, 1));
    assert_eq!(last_goal, Some(2100), "the goal was the present position before torque went on");
    let reboot = sent.iter().position(|(ins, ..)| *ins == 0x08).unwrap();
    assert!(reboot < enable);
    let joint1: Vec<&Record> = records.iter().filter(|rec| rec.id == 1).collect();
    assert!(joint1.iter().any(|rec| rec.fault & FaultKind::ServoError.bit() != 0 && rec.mode == LoopMode::Faulted as i64));
    assert!(records.iter().filter(|rec| rec.id == 2).all(|rec| rec.fault == 0), "the other joint ran on unmarked");
    assert_eq!(events(&r, FaultKind::ServoError), 1);
    // Held while it recovered, then from the present position on: no jump afterwards.
    let after: Vec<i64> = run_until(&mut r, 50, |_| false).iter().filter(|rec| rec.id == 1).map(|rec| rec.goal_tick).collect();
    assert!(after.iter().all(|g| (g - 2100).abs() <= 1), "{after:?}");
    let v = r.ctl.recovery.view(0).unwrap();
    assert_eq!((v.counts.reboots, v.counts.reenables, v.counts.recoveries), (1, 1, 1));
    assert!(r.ctl.stop_request().is_none());
}

#[test]
fn an_electrical_shock_is_never_rebooted_and_asks_for_a_stop() {
    let mut r = driving(&[(1, 2048)], FaultPolicy::default());
    r.bus.wire().set_hardware(1, HW_ELECTRICAL_SHOCK);
    r.bus.wire().set_torque(1, false);
    let records = run_until(&mut r, 200, |r| r.ctl.stop_request().is_some());
    let stop = r.ctl.stop_request().unwrap();
    assert_eq!((stop.cause, stop.joint, stop.hardware_error), (StopCause::UnsafeError, Some(0), HW_ELECTRICAL_SHOCK));
    assert!(r.bus.wire().reboots.is_empty() && !r.bus.wire().torque_of(1));
    assert_eq!(r.shared.stop_request(), Some(stop), "published for the supervisor");
    assert_eq!(records.last().unwrap().mode, LoopMode::Faulted as i64);
}

#[test]
fn torque_found_off_after_a_silence_is_held_then_re_enabled() {
    let policy = FaultPolicy { silent_after_ns: 20 * PERIOD, ..FaultPolicy::default() };
    let mut r = driving(&[(1, 2048)], policy);
    run_until(&mut r, 10, |_| false);
    r.bus.wire().silent = vec![1]; // browned out: nothing answers...
    let silent = run_until(&mut r, 60, |_| false);
    assert!(silent.last().unwrap().fault & FaultKind::ServoSilent.bit() != 0, "silent after 20 ms");
    let held = silent.last().unwrap();
    assert_eq!(held.omega, 0.0);
    {
        let mut wire = r.bus.wire(); // ...then back, reset: torque off, horn elsewhere
        wire.silent.clear();
        wire.set_torque(1, false);
        wire.present[0].1 = 1990;
    }
    run_until(&mut r, 100, |r| r.bus.wire().torque_of(1));
    assert!(r.bus.wire().torque_of(1), "re-enabled");
    assert!(r.bus.wire().reboots.is_empty(), "no error: no reboot");
    let rec = run_until(&mut r, 5, |_| false).pop().unwrap();
    assert_eq!((rec.goal_tick, rec.fault), (1990, 0));
    assert_eq!((events(&r, FaultKind::ServoSilent), events(&r, FaultKind::TorqueOff)), (1, 1));
}

#[test]
fn an_unplugged_bus_holds_sends_nothing_and_comes_back_on_replug() {
    let mut r = driving(&[(1, 2048)], FaultPolicy::default());
    run_until(&mut r, 10, |_| false);
    r.bus.wire().unplugged = true;
    let lost = run_until(&mut r, 200, |_| false);
    assert_eq!(r.bus.wire().disconnects, 1, "the port was handed back once, to be reopened");
    assert!(lost[1..].iter().all(|rec| rec.fault & FaultKind::BusLost.bit() != 0 && rec.omega == 0.0));
    let written = r.bus.written().len();
    let errors = r.shared.stats.bus_errors.load(Ordering::Relaxed);
    run_until(&mut r, 100, |_| false);
    assert_eq!(r.bus.written().len(), written, "nothing is sent to a port that is gone");
    assert_eq!(r.shared.stats.bus_errors.load(Ordering::Relaxed), errors, "nor counted again each cycle");
    assert!(r.shared.link.lost_since_ns.load(Ordering::Relaxed) > 0);
    r.bus.wire().unplugged = false;
    let back = run_until(&mut r, 20, |_| false);
    assert_eq!(back.last().unwrap().fault, 0);
    assert_eq!(r.shared.link.reconnects.load(Ordering::Relaxed), 1);
    let sent = packets(&r);
    assert!(sent[written..].iter().any(|(ins, id, p)| *ins == 0x02 && *id == 1 && p[..2] == [64, 0]), "torque checked after the replug");
    assert_eq!(events(&r, FaultKind::BusLost), 1);
    assert!(r.ctl.stop_request().is_none());
}

#[test]
fn a_bus_not_back_within_the_timeout_asks_for_a_stop() {
    let policy = FaultPolicy { lost_timeout_ns: 300 * PERIOD, silent_after_ns: 50 * PERIOD, ..FaultPolicy::default() };
    let mut r = driving(&[(1, 2048)], policy);
    r.bus.wire().unplugged = true;
    run_until(&mut r, 299, |_| false);
    assert!(r.ctl.stop_request().is_none());
    run_until(&mut r, 3, |_| false);
    assert_eq!(r.ctl.stop_request().unwrap().cause, StopCause::BusLost);
    r.bus.wire().unplugged = false; // too late: the request stays, the joint keeps holding
    let rec = run_until(&mut r, 5, |_| false).pop().unwrap();
    assert_eq!(rec.omega, 0.0);
    assert_eq!(r.ctl.stop_request().unwrap().cause, StopCause::BusLost);
}

#[test]
fn a_silent_servo_costs_the_others_nothing_and_is_left_out_while_it_reboots() {
    let mut r = driving(&[(1, 2048), (2, 3000)], FaultPolicy::default());
    r.bus.wire().silent = vec![1];
    let records = run_until(&mut r, 5, |_| false);
    assert!(records.iter().filter(|rec| rec.id == 2).all(|rec| rec.present_tick == 3000), "joint 2 still read");
    assert!(records.iter().filter(|rec| rec.id == 1).all(|rec| rec.present_tick == -1));
}

#[test]
fn the_sensor_faults_raised_outside_mark_every_joint() {
    let mut r = driving(&[(1, 2048), (2, 2048)], FaultPolicy::default());
    r.shared.external_faults.set(FaultKind::SensorLost.into());
    let records = run_until(&mut r, 2, |_| false);
    assert!(records.iter().all(|rec| rec.fault == FaultKind::SensorLost.bit() && rec.mode == LoopMode::Faulted as i64));
    r.shared.external_faults.set(Faults::NONE);
    assert!(run_until(&mut r, 1, |_| false).iter().all(|rec| rec.fault == 0));
}

/// A Protocol 2.0 servo (id 1) that allocates nothing: replies are encoded into a fixed buffer.
/// It shuts down with an overload, takes a REBOOT, answers Torque Enable, Hardware Error Status
/// and its present position.
struct FixedServo {
    reply: [u8; 64],
    len: usize,
    hardware: u8,
    torque: bool,
    quiet: u32,
}

impl Transport for FixedServo {
    fn write_all(&mut self, p: &[u8]) -> std::io::Result<()> {
        let (instruction, address) = (p[7], u16::from_le_bytes([p[8], p[9]]));
        let alert = if self.hardware != 0 { 0x80 } else { 0 };
        if self.quiet > 0 && instruction != 0x83 {
            self.quiet -= 1;
            return Ok(());
        }
        let data: ([u8; 4], usize) = match (instruction, address) {
            (0x82, _) | (0x02, 132) => (2048i32.to_le_bytes(), 4),
            (0x02, 64) => ([u8::from(self.torque), 0, 0, 0], 1),
            (0x02, 70) => ([self.hardware, 0, 0, 0], 1),
            (0x03, 64) => {
                self.torque = p[10] != 0 && self.hardware == 0;
                ([0; 4], 0)
            }
            (0x08, _) => {
                (self.hardware, self.torque, self.quiet) = (0, false, 3);
                ([0; 4], 0)
            }
            _ => return Ok(()),
        };
        self.len = protocol2::encode_status(&mut self.reply, 1, alert, &data.0[..data.1]).unwrap();
        Ok(())
    }

    fn read_until(&mut self, buf: &mut [u8], _deadline_ns: u64) -> std::io::Result<usize> {
        let n = std::mem::take(&mut self.len);
        buf[..n].copy_from_slice(&self.reply[..n]);
        Ok(n)
    }
}

#[test]
fn a_whole_recovery_allocates_nothing() {
    let mut r = driving(&[(1, 2048)], FaultPolicy::default());
    let mut servo = FixedServo { reply: [0; 64], len: 0, hardware: 0, torque: true, quiet: 0 };
    let cycle = |r: &mut Rig, servo: &mut FixedServo| {
        let deadline = r.clock.now_ns() + PERIOD;
        r.clock.clone().sleep_until(deadline);
        let before = counting::count();
        r.ctl.run_cycle(servo, &r.clock, deadline, deadline);
        while r.telemetry.pop().is_ok() {}
        counting::count() - before
    };
    for _ in 0..5 {
        cycle(&mut r, &mut servo); // warm-up
    }
    servo.hardware = HW_OVERLOAD;
    servo.torque = false;
    let mut allocations = 0;
    for _ in 0..600 {
        allocations += cycle(&mut r, &mut servo);
    }
    let v = r.ctl.recovery.view(0).unwrap();
    assert_eq!((v.counts.reboots, v.counts.recoveries), (1, 1), "the recovery ran through");
    assert!(servo.torque);
    assert_eq!(allocations, 0, "a cycle allocated");
}

/// Every goal joint `id` was sent, in order (SYNC_WRITEs to Goal Position, 116).
fn goals_sent(r: &Rig, id: u8) -> Vec<i64> {
    packets(r).iter().filter(|(ins, _, p)| *ins == 0x83 && p[0] == 116).filter_map(|(_, _, p)| goal_in(p, id)).collect()
}

#[test]
fn a_glitched_first_read_at_start_never_becomes_a_goal() {
    for glitch in [2000, -2000, 5000] {
        let mut r = rig(free_joint_for(1), &[(1, 2048)]);
        r.ctl.set_fault_policy(FaultPolicy::default(), true);
        r.bus.wire().glitches.push((1, glitch));
        let mut bus = r.bus.clone();
        r.ctl.start_at_present(&mut bus, &r.clock, 0, true).unwrap();
        assert_eq!(goals_sent(&r, 1), vec![2048], "glitch {glitch}: the first goal is where the horn is");
        assert_eq!(r.ctl.states().next().unwrap().theta, 0.0);
    }
}

#[test]
fn a_start_whose_reads_never_agree_or_rest_outside_the_limits_is_refused_with_torque_off() {
    let mut r = rig(free_joint_for(1), &[(1, 2048)]);
    r.ctl.set_fault_policy(FaultPolicy::default(), true);
    r.bus.wire().glitches.extend((0..START_READS as i64).map(|i| (1, if i % 2 == 0 { 1500 } else { 0 })));
    let mut bus = r.bus.clone();
    let refused = r.ctl.start_at_present(&mut bus, &r.clock, 0, true);
    assert!(matches!(&refused, Err(StartRefusal::Position(m)) if m.contains("did not agree")), "{refused:?}");
    assert!(goals_sent(&r, 1).is_empty() && r.bus.written().iter().all(|p| p[7] != 0x03), "no goal, no torque");

    let beyond = TickMap { zero_tick: 2048, direction: 1, ticks_per_rev: 4096.0, tick_min: 0, tick_max: 4095 }.goal_tick(3.0);
    let mut limited = free_joint_for(1);
    limited.joints[0].limits.position_max = 2.5;
    let mut r = rig(limited, &[(1, beyond)]);
    r.ctl.set_fault_policy(FaultPolicy::default(), true);
    let mut bus = r.bus.clone();
    let refused = r.ctl.start_at_present(&mut bus, &r.clock, 0, true);
    assert!(matches!(&refused, Err(StartRefusal::Position(m)) if m.contains("outside its position limits")), "{refused:?}");
    assert!(r.bus.written().iter().all(|p| p[7] != 0x03 && p[7] != 0x83));
}

#[test]
fn a_glitched_re_anchor_after_a_recovery_is_read_again_before_torque_goes_on() {
    let mut r = driving(&[(1, 2048)], FaultPolicy::default());
    run_until(&mut r, 20, |_| false);
    {
        let mut wire = r.bus.wire();
        wire.set_torque(1, false); // a brown-out: torque found off, no error
        wire.present[0].1 = 2375;
    }
    // The re-anchor's first READ of the present position glitches, +2000 (no SyncReads
    // meanwhile, so the glitch reaches that READ and no other).
    r.ctl.sync_read_divisor = 0;
    let before = r.bus.written().len();
    let mut glitched = 0;
    let records = run_until(&mut r, 3_000, |r| {
        let mut wire = r.bus.wire();
        let anchoring = r.ctl.recovery.view(0).unwrap().phase == crate::recovery::Phase::Reanchor;
        if anchoring && glitched == 0 && wire.glitches.is_empty() {
            wire.glitches.push((1, 2000));
            glitched += 1;
        }
        wire.torque_of(1) && r.ctl.recovery.view(0).unwrap().phase == crate::recovery::Phase::Ok
    });
    assert_eq!(glitched, 1, "the glitch was armed during the re-anchor");
    assert!(r.bus.wire().torque_of(1), "torque is back on");
    let sent = &packets(&r)[before..];
    let goals: Vec<i64> = sent.iter().filter(|(ins, _, p)| *ins == 0x83 && p[0] == 116).filter_map(|(_, _, p)| goal_in(p, 1)).collect();
    assert!(goals.iter().all(|g| (2040..=2380).contains(g)), "no goal near the glitch: {:?}", goals.iter().max());
    let enable = sent.iter().position(|(ins, id, p)| *ins == 0x03 && *id == 1 && p[..3] == [64, 0, 1]).unwrap();
    let last_goal = sent[..enable].iter().rev().find(|(ins, ..)| *ins == 0x83).and_then(|(_, _, p)| goal_in(p, 1));
    assert_eq!(last_goal, Some(2375), "torque on at the confirmed position");
    assert!(records.iter().any(|rec| Faults::from_bits(rec.fault as u64).contains(FaultKind::PositionGlitch)));
    assert!(records.iter().all(|rec| rec.theta < 1.0), "the model never went to the glitch");
}

#[test]
fn a_running_glitch_is_marked_and_kept_out_of_the_record_and_the_goal() {
    let mut r = driving(&[(1, 2048)], FaultPolicy::default());
    run_until(&mut r, 20, |_| false);
    let goals_before = goals_sent(&r, 1).len();
    r.bus.wire().glitches.push((1, 2000));
    let records = run_until(&mut r, 3, |_| false);
    let glitched = &records[0];
    assert!(Faults::from_bits(glitched.fault as u64).contains(FaultKind::PositionGlitch));
    assert_eq!(glitched.present_tick, -1, "the glitched read is not recorded as the horn's position");
    assert_eq!(glitched.mode, LoopMode::Running as i64, "a mark, not a hold");
    assert_eq!(records[1].present_tick, 2048, "the next read is trusted again");
    assert!(goals_sent(&r, 1)[goals_before..].iter().all(|g| (2040..=2056).contains(g)));
    assert_eq!(events(&r, FaultKind::PositionGlitch), 1);
}
