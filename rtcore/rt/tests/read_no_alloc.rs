//! A single-servo read (Torque Enable, Hardware Error Status) allocates nothing, so the loop
//! may poll them from its cycle. Own test binary: its global allocator counts this thread only.
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::collections::VecDeque;
use std::io;

use dxl::{protocol2, Protocol};
use rt::bus::{JointBus, Registers, Transport};

thread_local! {
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

struct Counting;

// SAFETY: forwards to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Answers every READ of one byte with `value` and an alert, from a queue made once.
struct OneByteServo {
    replies: VecDeque<u8>,
    value: u8,
}

impl Transport for OneByteServo {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        let mut buf = [0u8; 16];
        let n = protocol2::encode_status(&mut buf, bytes[4], 0x80, &[self.value]).unwrap();
        self.replies.extend(&buf[..n]);
        Ok(())
    }
    fn read_until(&mut self, buf: &mut [u8], _deadline_ns: u64) -> io::Result<usize> {
        let n = buf.len().min(self.replies.len());
        for (slot, byte) in buf.iter_mut().zip(self.replies.drain(..n)) {
            *slot = byte;
        }
        Ok(n)
    }
}

#[test]
fn reads_of_one_item_allocate_nothing() {
    let regs = Registers { goal_address: 116, goal_size: 4, present_address: 132, present_size: 4, torque_enable_address: 64 };
    let mut bus = JointBus::new(Protocol::V2, regs, &[1, 2]);
    let mut servo = OneByteServo { replies: VecDeque::with_capacity(256), value: 0x20 };
    bus.read_hardware_error(&mut servo, 0, 0).unwrap(); // warm-up: first-use initialisation
    let probe = ALLOCATIONS.with(Cell::get);
    std::hint::black_box(Box::new(1u8));
    assert_eq!(ALLOCATIONS.with(Cell::get), probe + 1, "the counter sees this thread's allocations");
    let before = ALLOCATIONS.with(Cell::get);
    for k in 0..100 {
        assert_eq!(bus.read_hardware_error(&mut servo, k % 2, 0).unwrap(), 0x20);
        assert!(bus.read_torque_enable(&mut servo, k % 2, 0).unwrap());
    }
    assert_eq!(ALLOCATIONS.with(Cell::get) - before, 0, "a read allocated");
    assert_eq!(bus.health()[1].alerts, 100);
}
