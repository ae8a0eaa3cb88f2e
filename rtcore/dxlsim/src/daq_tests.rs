//! The simulated DAQ: its profile and force model alone, then the stream over its pty read by
//! the project's own OptoForce parser (polls with deadlines; asserts what arrives, not when).
use std::io::{Read, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::time::{Duration, Instant};

use forceread::optoforce::{config_packet, Parser, Record, Sample};

use super::*;
use crate::{build_bus, BusConfig, MockBus, ServoConfig};

const PUSH: f64 = 0.21; // N·m: 2 N at 0.105 m, 903.78 counts at 451.89 counts/N
const CPN: f64 = 451.89;

fn model() -> ForceModel {
    ForceModel { lever_arm: 0.105, axis: 0, counts_per_unit: vec![CPN; 3], bias_n: 0.0, noise_std_n: 0.0 }
}

fn bus() -> MockBus {
    let bus = build_bus(vec![ServoConfig::new(1, plant::Params { motor_inertia: 0.0147, damping: 0.035, coulomb: 0.084, ..plant::Params::default() })], 1_000_000).unwrap();
    MockBus::new(bus, BusConfig { baudrate: 1_000_000, wire_delay: true, physics_rate_hz: 2000.0, rt_priority: 0 }).unwrap()
}

fn daq(bus: &MockBus, profile: HandProfile) -> SimulatedDaq {
    let config = DaqConfig { profile, model: model(), hand_servo: 1, rate_hz: 1000.0, seed: 7, rt_priority: 0 };
    SimulatedDaq::new(config, bus.servos()).unwrap()
}

fn constant(tau: f64) -> HandProfile {
    HandProfile::new(vec![0.0], vec![tau], None).unwrap()
}

/// The host's end of the DAQ's pty: what it reads, parsed.
struct Host {
    file: std::fs::File,
    parser: Parser,
}

impl Host {
    fn open(path: &str) -> Host {
        let file = std::fs::OpenOptions::new().read(true).write(true).custom_flags(libc::O_NONBLOCK).open(path).unwrap();
        Host { file, parser: Parser::default() }
    }

    /// Records until `enough` says so (or 2 s pass: the caller's assertion then fails).
    fn records_until(&mut self, mut enough: impl FnMut(&[Record]) -> bool) -> Vec<Record> {
        let mut got = Vec::new();
        let give_up = Instant::now() + Duration::from_secs(2);
        let mut buf = [0u8; 4096];
        while !enough(&got) && Instant::now() < give_up {
            match self.file.read(&mut buf) {
                Ok(n) => self.parser.feed(&buf[..n], |r| got.push(r)),
                Err(_) => std::thread::sleep(Duration::from_millis(1)),
            }
        }
        got
    }

    fn samples(&mut self, n: usize) -> Vec<Sample> {
        let records = self.records_until(|r| r.iter().filter(|r| matches!(r, Record::Sample(_))).count() >= n);
        records.into_iter().filter_map(|r| if let Record::Sample(s) = r { Some(s) } else { None }).collect()
    }

    fn send(&mut self, bytes: &[u8]) {
        self.file.write_all(bytes).unwrap();
    }
}

#[test]
fn a_profile_interpolates_repeats_and_holds() {
    let p = HandProfile::new(vec![0.0, 1.0, 2.0], vec![0.0, 1.0, 0.0], Some(2.0)).unwrap();
    assert_eq!(p.at(0.5), 0.5);
    assert_eq!(p.at(2.5), 0.5, "repeated every period");
    let held = HandProfile::new(vec![1.0, 2.0], vec![3.0, 5.0], None).unwrap();
    assert_eq!((held.at(0.0), held.at(1.5), held.at(9.0)), (3.0, 4.0, 5.0));
    for (t, tau, period) in [(vec![], vec![], None), (vec![0.0, 0.0], vec![1.0, 1.0], None), (vec![0.0], vec![f64::NAN], None),
        (vec![0.0, 3.0], vec![0.0, 0.0], Some(2.0)), (vec![0.0], vec![0.0], Some(0.0))]
    {
        assert!(HandProfile::new(t.clone(), tau, period).is_err(), "{t:?} {period:?}");
    }
}

#[test]
fn counts_clip_at_int16_with_the_axis_overload_bit() {
    let mut noise = Gaussian::new(1);
    let (counts, status) = model().counts(PUSH, &mut noise);
    assert_eq!((counts, status), (vec![904, 0, 0], 0));
    let (counts, status) = model().counts(-10.0, &mut noise);
    assert_eq!((counts[0], status), (-32767, 1 << 9), "fx's overload flag");
    let bad = ForceModel { counts_per_unit: vec![CPN; 4], ..model() };
    assert!(bad.validate().is_err());
}

#[test]
fn seeded_noise_is_repeatable_and_has_its_spread() {
    let draw = |seed| (0..20_000).map({ let mut g = Gaussian::new(seed); move |_| g.sample(2.0) }).collect::<Vec<f64>>();
    assert_eq!(draw(3), draw(3));
    let x = draw(4);
    let mean = x.iter().sum::<f64>() / x.len() as f64;
    let std = (x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / x.len() as f64).sqrt();
    assert!(mean.abs() < 0.05 && (std - 2.0).abs() < 0.05, "mean {mean}, std {std}");
}

#[test]
fn the_stream_pushes_the_hand_and_sends_its_force() {
    let bus = bus();
    let daq = daq(&bus, constant(PUSH));
    let mut host = Host::open(&daq.port_path());
    daq.start().unwrap();
    let samples = host.samples(20);
    assert!(samples.len() >= 20);
    assert!(samples.iter().all(|s| s.n == 3 && s.counts[0] == 904 && s.status == 0));
    assert!(samples.windows(2).all(|w| w[1].counter == w[0].counter.wrapping_add(1)), "counted");
    assert_eq!(bus.lock().bus.servo_mut(1).unwrap().snapshot().hand_torque, PUSH, "the horn is pushed too");
    assert_eq!(daq.state().last_torque(), PUSH);
}

#[test]
fn the_write_gap_counts_the_streams_own_pauses_not_a_silence() {
    let bus = bus();
    let daq = daq(&bus, constant(PUSH));
    let mut host = Host::open(&daq.port_path());
    daq.start().unwrap();
    host.samples(20);
    let gap = daq.state().max_write_gap_ns.load(Ordering::Relaxed);
    assert!(gap > 0, "consecutive frames were timed");
    daq.state().silent.store(true, Ordering::Relaxed);
    std::thread::sleep(Duration::from_millis(300));
    daq.state().silent.store(false, Ordering::Relaxed);
    host.samples(20);
    let gap = daq.state().max_write_gap_ns.load(Ordering::Relaxed);
    assert!(gap < 300_000_000, "a silence the host asked for is not the source's gap ({gap} ns)");
}

#[test]
fn a_config_packet_tares_stops_and_is_acknowledged() {
    let bus = bus();
    let daq = daq(&bus, constant(PUSH));
    let mut host = Host::open(&daq.port_path());
    daq.start().unwrap();
    host.samples(5);
    host.send(&config_packet(1000, 0.0, true).unwrap());
    let after = host.records_until(|r| {
        r.iter().skip_while(|r| !matches!(r, Record::Ack(0))).filter(|r| matches!(r, Record::Sample(_))).count() >= 5
    });
    let tared = after.iter().skip_while(|r| !matches!(r, Record::Ack(0))).find_map(|r| if let Record::Sample(s) = r { Some(*s) } else { None });
    assert_eq!(tared.map(|s| s.counts[0]), Some(0), "the tare took the load just sampled");
    assert_eq!(daq.state().configs_received.load(Ordering::Relaxed), 1);
    host.send(&config_packet(0, 0.0, false).unwrap());
    host.records_until(|r| r.iter().any(|r| matches!(r, Record::Ack(0))));
    assert!(!daq.state().streaming());
    let sent = daq.state().samples_sent.load(Ordering::Relaxed);
    std::thread::sleep(Duration::from_millis(30));
    assert_eq!(daq.state().samples_sent.load(Ordering::Relaxed), sent, "SPEED 0 stops the stream");
}

#[test]
fn fault_modes_reach_the_wire() {
    let bus = bus();
    let daq = daq(&bus, constant(PUSH));
    let mut host = Host::open(&daq.port_path());
    daq.start().unwrap();
    daq.state().saturated.store(true, Ordering::Relaxed);
    daq.state().fault_status.store(0x2000, Ordering::Relaxed);
    let s = *host.samples(30).last().unwrap();
    assert_eq!((s.counts[0], s.status), (32767, 0x2000 | 1 << 9));
    daq.state().saturated.store(false, Ordering::Relaxed);
    daq.state().fault_status.store(0, Ordering::Relaxed);
    host.samples(5);
    daq.state().corrupt(3);
    daq.state().inject_garbage(40);
    host.samples(10);
    assert_eq!(host.parser.stats.checksum_errors, 3);
    assert!(host.parser.stats.skipped_bytes >= 40);
    assert_eq!(daq.state().faulty_frames.load(Ordering::Relaxed), 3);
    daq.state().silent.store(true, Ordering::Relaxed);
    std::thread::sleep(Duration::from_millis(10));
    host.records_until(|_| true);
    let sent = daq.state().samples_sent.load(Ordering::Relaxed);
    std::thread::sleep(Duration::from_millis(30));
    assert!(daq.state().samples_sent.load(Ordering::Relaxed) <= sent + 1, "silent: nothing sent");
}

#[test]
fn unplug_hangs_up_and_replug_follows_the_link() {
    let bus = bus();
    let daq = daq(&bus, constant(PUSH));
    let dir = std::env::temp_dir().join(format!("daq-link-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let link = dir.join("sensor");
    daq.set_link(&link).unwrap();
    daq.start().unwrap();
    let mut host = Host::open(link.to_str().unwrap());
    host.samples(3);
    assert!(daq.unplug() && !daq.unplug());
    assert!(!link.exists(), "the link goes with the cable");
    let mut buf = [0u8; 64];
    let give_up = Instant::now() + Duration::from_secs(2);
    let hung_up = loop {
        match host.file.read(&mut buf) {
            Ok(0) => break true,
            Err(e) if e.kind() != std::io::ErrorKind::WouldBlock => break true,
            _ if Instant::now() > give_up => break false,
            _ => std::thread::sleep(Duration::from_millis(1)),
        }
    };
    assert!(hung_up, "the host's descriptor hangs up");
    assert!(daq.replug().unwrap() && !daq.replug().unwrap());
    let mut again = Host::open(link.to_str().unwrap());
    assert!(again.samples(3).len() >= 3, "samples flow on the new pty");
    assert_eq!(daq.plug_counts(), (1, 1));
    daq.close();
    assert!(!link.exists());
    let _ = std::fs::remove_dir(&dir);
}

#[test]
fn a_held_hand_keeps_off_until_started_and_a_new_profile_takes_over() {
    let bus = bus();
    let daq = daq(&bus, constant(PUSH));
    daq.state().hold_hand();
    let mut host = Host::open(&daq.port_path());
    daq.start().unwrap();
    assert!(host.samples(10).iter().all(|s| s.counts[0] == 0), "held: no push");
    daq.state().start_hand(0.0);
    assert!(host.samples(10).last().is_some_and(|s| s.counts[0] == 904), "started: the profile");
    daq.set_profile(constant(-PUSH));
    assert!(host.samples(10).last().is_some_and(|s| s.counts[0] == -904), "replaced");
}
