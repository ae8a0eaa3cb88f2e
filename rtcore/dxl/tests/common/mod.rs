//! A scripted in-memory bus for client tests: servos with a byte image of their control
//! table answer the instructions the client writes. It uses the crate's own decoder and
//! encoders and allocates nothing after construction (the no-allocation test relies on it).
use std::io;
use std::time::Instant;

use dxl::client::Transport;
use dxl::packet::{Kind, Protocol};
use dxl::protocol1::{self as p1, Expect};
use dxl::protocol2 as p2;
use dxl::{instruction as ins, AnyDecoder};

pub struct FakeServo {
    pub id: u8,
    pub memory: [u8; 256],
    /// Raw error byte put in every status.
    pub error: u8,
}

pub struct FakeBus {
    pub protocol: Protocol,
    pub servos: Vec<FakeServo>,
    decoder: AnyDecoder,
    out: Vec<u8>,
    out_len: usize,
    /// Bytes of garbage sent before every reply (line noise).
    pub noise: &'static [u8],
    pub written: usize,
}

impl FakeBus {
    pub fn new(protocol: Protocol, ids: &[u8], model_number: u16) -> FakeBus {
        let servos = ids
            .iter()
            .map(|&id| {
                let mut memory = [0u8; 256];
                memory[..2].copy_from_slice(&model_number.to_le_bytes());
                memory[6] = 45;
                FakeServo { id, memory, error: 0 }
            })
            .collect();
        FakeBus {
            protocol,
            servos,
            decoder: AnyDecoder::new(protocol, Expect::Instruction),
            out: vec![0; 8192],
            out_len: 0,
            noise: &[],
            written: 0,
        }
    }

    /// Queue bytes on the line as if they arrived late (e.g. an abandoned reply).
    pub fn inject(&mut self, bytes: &[u8]) {
        self.out[self.out_len..self.out_len + bytes.len()].copy_from_slice(bytes);
        self.out_len += bytes.len();
    }

    fn reply(&mut self, id: u8, params_of: impl Fn(&FakeServo, &mut [u8]) -> usize) {
        let Some(s) = self.servos.iter().find(|s| s.id == id) else { return };
        let mut params = [0u8; 256];
        let n = params_of(s, &mut params);
        let start = self.out_len;
        self.out[start..start + self.noise.len()].copy_from_slice(self.noise);
        let at = start + self.noise.len();
        let written = match self.protocol {
            Protocol::V1 => p1::encode_status(&mut self.out[at..], id, s.error, &params[..n]),
            Protocol::V2 => p2::encode_status(&mut self.out[at..], id, s.error, &params[..n]),
        };
        self.out_len = at + written.expect("fake reply fits");
    }

    fn answer(&mut self, id: u8, instr: u8, params: &[u8; 64], len: usize) {
        let p = &params[..len];
        let wide = self.protocol == Protocol::V2;
        // `params` is zero-padded, so the address of a parameterless instruction reads as 0.
        let (addr, rest) = if wide { (u16::from_le_bytes([params[0], params[1]]) as usize, 2) } else { (params[0] as usize, 1) };
        match instr {
            ins::PING if wide => self.reply(id, |s, o| {
                o[..3].copy_from_slice(&[s.memory[0], s.memory[1], s.memory[6]]);
                3
            }),
            ins::PING | ins::REBOOT => self.reply(id, |_, _| 0),
            ins::READ => {
                let n = if wide { u16::from_le_bytes([p[2], p[3]]) as usize } else { p[1] as usize };
                self.reply(id, |s, o| {
                    o[..n].copy_from_slice(&s.memory[addr..addr + n]);
                    n
                })
            }
            ins::WRITE => {
                let data = &p[rest..];
                if let Some(s) = self.servos.iter_mut().find(|s| s.id == id) {
                    s.memory[addr..addr + data.len()].copy_from_slice(data);
                }
                if id != 0xFE {
                    self.reply(id, |_, _| 0);
                }
            }
            ins::SYNC_READ => {
                let n = u16::from_le_bytes([p[2], p[3]]) as usize;
                for &target in &p[4..] {
                    self.reply(target, |s, o| {
                        o[..n].copy_from_slice(&s.memory[addr..addr + n]);
                        n
                    });
                }
            }
            ins::BULK_READ if wide => {
                for e in p.chunks_exact(5) {
                    let (a, n) = (u16::from_le_bytes([e[1], e[2]]) as usize, u16::from_le_bytes([e[3], e[4]]) as usize);
                    self.reply(e[0], |s, o| {
                        o[..n].copy_from_slice(&s.memory[a..a + n]);
                        n
                    });
                }
            }
            ins::BULK_READ => {
                for e in p[1..].chunks_exact(3) {
                    let (n, a) = (e[0] as usize, e[2] as usize);
                    self.reply(e[1], |s, o| {
                        o[..n].copy_from_slice(&s.memory[a..a + n]);
                        n
                    });
                }
            }
            ins::SYNC_WRITE => {
                let n = if wide { u16::from_le_bytes([p[2], p[3]]) as usize } else { p[1] as usize };
                let records = &p[if wide { 4 } else { 2 }..];
                for r in records.chunks_exact(n + 1) {
                    if let Some(s) = self.servos.iter_mut().find(|s| s.id == r[0]) {
                        s.memory[addr..addr + n].copy_from_slice(&r[1..]);
                    }
                }
            }
            _ => {}
        }
    }
}

impl Transport for FakeBus {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.written += bytes.len();
        self.decoder.push(bytes);
        while let Some(item) = self.decoder.next() {
            let Ok(p) = item else { continue };
            if let Kind::Instruction(instr) = p.kind {
                let mut params = [0u8; 64];
                params[..p.params.len()].copy_from_slice(p.params);
                let (id, len) = (p.id, p.params.len());
                self.answer(id, instr, &params, len);
            }
        }
        Ok(())
    }

    fn read(&mut self, buf: &mut [u8], _deadline: Instant) -> io::Result<usize> {
        let n = self.out_len.min(buf.len()).min(7); // small chunks: exercise reassembly
        buf[..n].copy_from_slice(&self.out[..n]);
        self.out.copy_within(n..self.out_len, 0);
        self.out_len -= n;
        Ok(n)
    }
}
