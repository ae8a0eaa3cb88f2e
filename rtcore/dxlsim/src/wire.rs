//! The servos' end of the wire, shared by the pty thread (`server`) and the in-process link
//! (`direct`): it decodes instructions, lets the bus answer them, and times each reply as a
//! real wire would; and the physics clock both keep up with.
//!
//! Timing (with `wire_delay`): a reply's first byte may start when the instruction's last byte
//! would have arrived (instruction length × 10 bits / baud after it was read, or after the
//! host's previous instruction has left) plus the servo's Return Delay Time; the reply is due
//! when its own last byte would have arrived, and not before the replies ahead of it. Chained
//! replies (broadcast PING, Sync/Bulk Read) follow each other the same way, each after its
//! servo's Return Delay Time; a Fast Sync Read's one combined reply waits one Return Delay Time
//! (its first servo's) for all. Without `wire_delay` replies are due at once.
//!
//! Times are CLOCK_MONOTONIC nanoseconds (`rt::clock::monotonic_ns`), the loop's own clock,
//! so the in-process link compares a reply's due time with the loop's read deadline directly.
use std::collections::VecDeque;

use dxl::{protocol1, protocol2, DecodeError, Kind, Packet, Protocol};

use crate::bus::Reply;
use crate::server::{BusConfig, Shared};

/// A partial packet older than this is dropped: the e-manual's 1.5 ms inter-byte timeout,
/// after which a servo waits for a new header. Clients write a packet in one call, so only a
/// truncated packet ever waits this long.
const INTER_BYTE_TIMEOUT_NS: u64 = 1_500_000;
/// The most simulated time one catch-up may run; beyond it time is skipped.
const MAX_CATCH_UP_NS: u64 = 250_000_000;

/// The physics' fixed substep and how far it has run; in `Shared`, so whoever answers a packet
/// first brings the servos up to the wall clock.
#[derive(Debug)]
pub struct PhysicsClock {
    step_ns: u64,
    /// When `start` ran (None: the servos stay still).
    epoch_ns: Option<u64>,
    steps_done: u64,
}

impl PhysicsClock {
    pub fn new(rate_hz: f64) -> PhysicsClock {
        PhysicsClock { step_ns: ((1e9 / rate_hz) as u64).max(1), epoch_ns: None, steps_done: 0 }
    }

    /// Time runs from now (a no-op when it runs already).
    pub fn start(&mut self, now_ns: u64) {
        if self.epoch_ns.is_none() {
            self.epoch_ns = Some(now_ns);
            self.steps_done = 0;
        }
    }

    /// The servos stand still until the next `start`, which does not catch up the pause.
    pub fn pause(&mut self) {
        self.epoch_ns = None;
    }
}

impl Shared {
    /// Steps every servo up to `now_ns`. After a starvation longer than `MAX_CATCH_UP_NS` the
    /// lost time is skipped (and counted) rather than simulated in one burst that would starve
    /// the caller again.
    pub fn advance_physics(&mut self, now_ns: u64) {
        let clock = &mut self.physics;
        let Some(epoch) = clock.epoch_ns else { return };
        let due = now_ns.saturating_sub(epoch) / clock.step_ns;
        let max_burst = MAX_CATCH_UP_NS / clock.step_ns;
        let mut n = due.saturating_sub(clock.steps_done);
        if n > max_burst {
            self.io.skipped_steps += n - max_burst;
            clock.steps_done += n - max_burst;
            n = max_burst;
        }
        let h = clock.step_ns as f64 * 1e-9;
        for _ in 0..n {
            self.bus.step(h);
        }
        clock.steps_done += n;
        self.io.physics_steps += n;
        self.bus.publish();
    }
}

/// A packet decoder for the bus's protocol (the two decoders are different types).
enum Decoder {
    V1(protocol1::Decoder),
    V2(protocol2::Decoder),
}

impl Decoder {
    fn new(protocol: Protocol) -> Decoder {
        match protocol {
            Protocol::V1 => Decoder::V1(protocol1::Decoder::new(protocol1::Expect::Instruction)),
            Protocol::V2 => Decoder::V2(protocol2::Decoder::new()),
        }
    }

    fn push(&mut self, bytes: &[u8]) -> usize {
        match self {
            Decoder::V1(d) => d.push(bytes),
            Decoder::V2(d) => d.push(bytes),
        }
    }

    fn next(&mut self) -> Option<Result<Packet<'_>, DecodeError>> {
        match self {
            Decoder::V1(d) => d.next(),
            Decoder::V2(d) => d.next(),
        }
    }

    fn skipped_bytes(&self) -> u64 {
        match self {
            Decoder::V1(d) => d.skipped_bytes(),
            Decoder::V2(d) => d.skipped_bytes(),
        }
    }

    fn buffered(&self) -> usize {
        match self {
            Decoder::V1(d) => d.buffered(),
            Decoder::V2(d) => d.buffered(),
        }
    }

    fn clear(&mut self) {
        match self {
            Decoder::V1(d) => d.clear(),
            Decoder::V2(d) => d.clear(),
        }
    }
}

/// One client's wire: the instructions read so far and the replies not yet due.
pub struct Answerer {
    decoder: Decoder,
    config: BusConfig,
    /// Replies waiting for their due time, in wire order.
    schedule: VecDeque<(u64, Vec<u8>)>,
    /// When the bus is free again (the last scheduled reply's end).
    bus_free_ns: u64,
    /// When the host's last instruction has left its adapter: the host's bytes go out one at a
    /// time, so an instruction written right after another follows it on the wire.
    host_free_ns: u64,
    /// When the last bytes arrived (for the inter-byte timeout).
    last_rx_ns: u64,
}

impl Answerer {
    pub fn new(protocol: Protocol, config: BusConfig, now_ns: u64) -> Answerer {
        let schedule = VecDeque::new();
        Answerer { decoder: Decoder::new(protocol), config, schedule, bus_free_ns: now_ns, host_free_ns: now_ns, last_rx_ns: now_ns }
    }

    /// A new wire (an unplug or replug): what was in flight on the old one is gone.
    pub fn clear(&mut self, now_ns: u64) {
        self.decoder.clear();
        self.schedule.clear();
        self.bus_free_ns = now_ns;
        self.host_free_ns = now_ns;
    }

    /// Forgets a partial packet once the inter-byte timeout has passed.
    pub fn drop_stale_partial(&mut self, now_ns: u64, shared: &mut Shared) {
        if self.decoder.buffered() > 0 && now_ns.saturating_sub(self.last_rx_ns) > INTER_BYTE_TIMEOUT_NS {
            self.decoder.clear();
            shared.io.truncated_packets += 1;
        }
    }

    /// Bytes that arrived at `arrival_ns`: every whole packet is answered (physics first brought
    /// up to then, so reads see current positions) and its replies scheduled.
    pub fn receive(&mut self, arrival_ns: u64, mut bytes: &[u8], shared: &mut Shared) {
        self.drop_stale_partial(arrival_ns, shared);
        self.last_rx_ns = arrival_ns;
        shared.io.bytes_in += bytes.len() as u64;
        shared.advance_physics(arrival_ns);
        while !bytes.is_empty() {
            let taken = self.decoder.push(bytes);
            bytes = &bytes[taken..];
            self.answer_packets(arrival_ns, shared);
        }
        shared.io.garbage_bytes = self.decoder.skipped_bytes();
    }

    /// When the next reply is due, if one is scheduled.
    pub fn next_due_ns(&self) -> Option<u64> {
        self.schedule.front().map(|(due, _)| *due)
    }

    /// The next reply if it is due at `now_ns`: (its due time, its bytes).
    pub fn pop_due(&mut self, now_ns: u64) -> Option<(u64, Vec<u8>)> {
        if self.next_due_ns()? <= now_ns {
            self.schedule.pop_front()
        } else {
            None
        }
    }

    fn answer_packets(&mut self, arrival_ns: u64, shared: &mut Shared) {
        let protocol = shared.bus.protocol();
        loop {
            let (replies, length) = match self.decoder.next() {
                None => return,
                Some(Ok(Packet { id, kind: Kind::Instruction(code), params })) => {
                    (shared.bus.handle(id, code, params), packet_len(protocol, params.len()))
                }
                Some(Ok(Packet { kind: Kind::Status(_), .. })) => {
                    shared.io.foreign_status_packets += 1;
                    continue;
                }
                Some(Err(DecodeError::Crc { id, .. } | DecodeError::Checksum { id, .. })) => {
                    (shared.bus.handle_corrupt(id), packet_len(protocol, 0))
                }
                Some(Err(DecodeError::Length { .. })) => {
                    shared.io.framing_errors += 1;
                    continue;
                }
            };
            // The instruction's bytes follow the host's earlier ones (a SyncWrite written just
            // before a Sync Read delays it by its own bytes), but not a servo's reply still on
            // the wire: a host that does not wait for it collides with it on a real bus, and
            // queueing behind replies made late by a late simulation thread (which a real
            // servo never is) put every later reply behind them, cycle after cycle.
            let sent_ns = arrival_ns.max(self.host_free_ns) + self.wire_time_ns(length);
            self.host_free_ns = sent_ns;
            self.schedule_replies(sent_ns, replies);
        }
    }

    /// Queues replies back to back after `start_ns`, each after its servo's Return Delay Time.
    fn schedule_replies(&mut self, start_ns: u64, replies: Vec<Reply>) {
        let mut t = start_ns.max(self.bus_free_ns);
        for reply in replies.into_iter().filter(|r| !r.bytes.is_empty()) {
            if self.config.wire_delay {
                t += reply.delay_us * 1000;
            }
            t += self.wire_time_ns(reply.bytes.len());
            self.schedule.push_back((t, reply.bytes));
        }
        self.bus_free_ns = t;
    }

    /// Time `n` bytes take on the wire: 10 bits per byte (start, 8 data, stop).
    fn wire_time_ns(&self, n: usize) -> u64 {
        if self.config.wire_delay && self.config.baudrate > 0 {
            n as u64 * 10 * 1_000_000_000 / u64::from(self.config.baudrate)
        } else {
            0
        }
    }
}

/// The size of an instruction packet with `n_params` parameter bytes (unstuffed; the
/// difference stuffing makes is a few bytes of wire time at most).
fn packet_len(protocol: Protocol, n_params: usize) -> usize {
    match protocol {
        Protocol::V1 => protocol1::PREFIX_LEN + 2 + n_params,
        Protocol::V2 => protocol2::PREFIX_LEN + 3 + n_params,
    }
}
