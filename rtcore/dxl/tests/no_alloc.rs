//! The RT paths allocate nothing per cycle: SYNC_WRITE and SYNC_READ through a `Client`,
//! counted by a global allocator wrapper. Only the test's own thread is counted: the harness's
//! main thread does its bookkeeping (allocating) whenever the scheduler lets it, which on a
//! loaded machine can be in the middle of the measured cycles. (Its own test binary, too, so
//! no other test thread runs beside it.)
#[allow(dead_code)] // the shared fake also serves client.rs, which uses more of it
mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use common::FakeBus;
use dxl::client::{Client, Slot};
use dxl::packet::Protocol;

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    // A const-initialised Cell has no destructor, so reading it never allocates itself.
    static COUNTED: Cell<bool> = const { Cell::new(false) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTED.try_with(Cell::get).unwrap_or(false) {
            ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        }
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn sync_cycles_do_not_allocate() {
    let ids = [1, 2, 3, 4, 5, 6];
    let mut c = Client::new(FakeBus::new(Protocol::V2, &ids, 311), Protocol::V2, Duration::from_millis(1));
    let mut data = [0u8; 24];
    let mut out = [0u8; 24];
    let mut slots = [Slot::Missing; 6];
    // One warm-up cycle: first-use initialisation (e.g. of the clock) is not per-cycle cost.
    c.sync_write(116, 4, &ids, &data).unwrap();
    c.sync_read(116, 4, &ids, &mut out, &mut slots).unwrap();
    COUNTED.with(|c| c.set(true));
    let before = ALLOCATIONS.load(Ordering::SeqCst);
    for cycle in 0..100u8 {
        data.fill(cycle);
        c.sync_write(116, 4, &ids, &data).unwrap();
        assert_eq!(c.sync_read(116, 4, &ids, &mut out, &mut slots).unwrap(), 6);
    }
    let allocated = ALLOCATIONS.load(Ordering::SeqCst) - before;
    COUNTED.with(|c| c.set(false));
    assert_eq!(allocated, 0);
    assert_eq!(out, data);
}
