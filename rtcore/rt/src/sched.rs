//! Real-time setup of the loop thread: SCHED_FIFO, locked memory, CPU affinity, timer slack.
//!
//! Each request may be refused (no CAP_SYS_NICE / RLIMIT_RTPRIO = 0 → EPERM, a finite
//! RLIMIT_MEMLOCK → ENOMEM). The loop then runs anyway, like ros2_control and dora: every refusal
//! becomes one warning naming the errno and the fix, and the report says what was obtained, so
//! the supervisor can log it and `stats()` can show it.
//!
//! Memory locking in a Python process: `MCL_FUTURE` with a finite RLIMIT_MEMLOCK makes every
//! later allocation of the interpreter fail once the locked total reaches the limit, so it is only
//! asked for when the limit is infinite; otherwise `MCL_CURRENT` locks what exists now (the loop's
//! buffers are all allocated before this call). The lock is process-wide: a count of the loops
//! holding it lets the last one to stop undo it.
//!
//! Timer slack: a SCHED_OTHER thread's absolute-deadline sleeps may end up to its timer slack
//! late (50 µs by default), the kernel's way to batch wake-ups. The loop sets its own slack to
//! 1 ns, so that when SCHED_FIFO is refused its wake-ups are not 50 µs late by design.
//! (SCHED_FIFO threads get zero slack from the kernel anyway.)
use std::sync::atomic::{AtomicUsize, Ordering};

/// The scheduling policy asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Policy {
    Fifo,
    Other,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RtRequest {
    pub policy: Policy,
    pub priority: i32,
    pub lock_memory: bool,
    pub cpu: Option<usize>,
}

/// The SCHED_FIFO priority a loop asks for unless told otherwise (the simulated bus's too).
pub const DEFAULT_PRIORITY: i32 = 50;

impl Default for RtRequest {
    fn default() -> Self {
        RtRequest { policy: Policy::Fifo, priority: DEFAULT_PRIORITY, lock_memory: true, cpu: None }
    }
}

/// What the thread actually runs with.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RtReport {
    /// "SCHED_FIFO" or "SCHED_OTHER" (or another name read back from the kernel).
    pub policy: &'static str,
    pub priority: i32,
    pub memory_locked: bool,
    pub cpu: Option<usize>,
}

impl Default for RtReport {
    fn default() -> Self {
        RtReport { policy: "SCHED_OTHER", priority: 0, memory_locked: false, cpu: None }
    }
}

static MEMORY_LOCK_HOLDERS: AtomicUsize = AtomicUsize::new(0);

fn errno_text(code: i32) -> String {
    format!("{} (errno {code})", std::io::Error::from_raw_os_error(code))
}

/// Applies the request to the calling thread; returns what it obtained and one warning per refusal.
pub fn apply_to_current_thread(req: &RtRequest) -> (RtReport, Vec<String>) {
    let mut warnings = Vec::new();
    let mut report = RtReport::default();
    if let Some(cpu) = req.cpu {
        match pin_to_cpu(cpu) {
            Ok(()) => report.cpu = Some(cpu),
            Err(e) => warnings.push(format!("CPU affinity to cpu {cpu} refused: {}", errno_text(e))),
        }
    }
    if req.policy == Policy::Fifo {
        if let Err(e) = set_fifo(req.priority) {
            warnings.push(format!(
                "SCHED_FIFO priority {} refused: {}; running at SCHED_OTHER. Fix: run as root, or \
                 give the service LimitRTPRIO={} or AmbientCapabilities=CAP_SYS_NICE",
                req.priority,
                errno_text(e),
                req.priority
            ));
        }
    }
    (report.policy, report.priority) = current_policy();
    set_minimal_timer_slack();
    if req.lock_memory {
        match lock_memory() {
            Ok(()) => report.memory_locked = true,
            Err(e) => warnings.push(format!(
                "mlockall refused: {}; memory is not locked and page faults may delay cycles. \
                 Fix: LimitMEMLOCK=infinity or AmbientCapabilities=CAP_IPC_LOCK",
                errno_text(e)
            )),
        }
    }
    (report, warnings)
}

/// The smallest timer slack the kernel accepts (1 ns) for the calling thread; failure only
/// leaves the default slack, so it is not reported.
fn set_minimal_timer_slack() {
    // SAFETY: PR_SET_TIMERSLACK only changes the calling thread's timer slack.
    unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong) };
}

/// Undoes `lock_memory` once the last loop that locked it has stopped.
pub fn release_memory_lock() {
    if MEMORY_LOCK_HOLDERS.fetch_sub(1, Ordering::SeqCst) == 1 {
        // SAFETY: munlockall has no memory-safety preconditions.
        unsafe { libc::munlockall() };
    }
}

fn pin_to_cpu(cpu: usize) -> Result<(), i32> {
    if cpu >= libc::CPU_SETSIZE as usize {
        return Err(libc::EINVAL);
    }
    // SAFETY: a zeroed cpu_set_t is the empty set; CPU_SET stays within it (checked above);
    // pid 0 is the calling thread.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) != 0 {
            return Err(std::io::Error::last_os_error().raw_os_error().unwrap_or(0));
        }
    }
    Ok(())
}

fn set_fifo(priority: i32) -> Result<(), i32> {
    let param = libc::sched_param { sched_priority: priority };
    // SAFETY: pthread_self() is the calling thread; `param` is a valid sched_param.
    let rc = unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) };
    if rc == 0 {
        Ok(())
    } else {
        Err(rc)
    }
}

/// Reads the policy back from the kernel rather than trusting what was asked.
fn current_policy() -> (&'static str, i32) {
    let mut policy = 0;
    let mut param = libc::sched_param { sched_priority: 0 };
    // SAFETY: both out-pointers are valid for writes.
    let rc = unsafe { libc::pthread_getschedparam(libc::pthread_self(), &mut policy, &mut param) };
    if rc != 0 {
        return ("SCHED_OTHER", 0);
    }
    let name = match policy {
        libc::SCHED_FIFO => "SCHED_FIFO",
        libc::SCHED_RR => "SCHED_RR",
        libc::SCHED_BATCH => "SCHED_BATCH",
        libc::SCHED_IDLE => "SCHED_IDLE",
        _ => "SCHED_OTHER",
    };
    (name, param.sched_priority)
}

fn lock_memory() -> Result<(), i32> {
    let mut limit = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
    // SAFETY: `limit` is valid for writes.
    unsafe { libc::getrlimit(libc::RLIMIT_MEMLOCK, &mut limit) };
    let flags = if limit.rlim_cur == libc::RLIM_INFINITY {
        libc::MCL_CURRENT | libc::MCL_FUTURE
    } else {
        libc::MCL_CURRENT
    };
    // SAFETY: mlockall has no memory-safety preconditions.
    if unsafe { libc::mlockall(flags) } != 0 {
        return Err(std::io::Error::last_os_error().raw_os_error().unwrap_or(0));
    }
    MEMORY_LOCK_HOLDERS.fetch_add(1, Ordering::SeqCst);
    Ok(())
}

/// Touches `bytes` of stack so the pages the loop will use are resident before memory is locked
/// and before the first cycle (a first-touch page fault costs 100 µs and more).
#[inline(never)]
pub fn prefault_stack() {
    let mut area = [0u8; 128 * 1024];
    for chunk in area.chunks_mut(4096) {
        chunk[0] = 1;
    }
    std::hint::black_box(&area);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn asking_for_other_reports_other_without_warnings() {
        let req = RtRequest { policy: Policy::Other, priority: 0, lock_memory: false, cpu: None };
        let (report, warnings) = std::thread::spawn(move || apply_to_current_thread(&req)).join().unwrap();
        assert_eq!(report.policy, "SCHED_OTHER");
        assert!(!report.memory_locked);
        assert!(warnings.is_empty(), "{warnings:?}");
    }

    #[test]
    fn the_loop_thread_sleeps_with_the_minimal_timer_slack() {
        let req = RtRequest { policy: Policy::Other, priority: 0, lock_memory: false, cpu: None };
        let slack = std::thread::spawn(move || {
            apply_to_current_thread(&req);
            // SAFETY: PR_GET_TIMERSLACK reads the calling thread's slack (ns) as the return value.
            unsafe { libc::prctl(libc::PR_GET_TIMERSLACK) }
        })
        .join()
        .unwrap();
        assert_eq!(slack, 1);
    }

    #[test]
    fn fifo_is_either_obtained_or_refused_with_one_warning() {
        let req = RtRequest { policy: Policy::Fifo, priority: 10, lock_memory: false, cpu: None };
        let (report, warnings) = std::thread::spawn(move || apply_to_current_thread(&req)).join().unwrap();
        match report.policy {
            "SCHED_FIFO" => {
                assert_eq!(report.priority, 10);
                assert!(warnings.is_empty());
            }
            _ => {
                assert_eq!(warnings.len(), 1);
                assert!(warnings[0].contains("SCHED_FIFO"));
            }
        }
    }

    #[test]
    fn memory_is_either_locked_or_refused_with_one_warning() {
        let req = RtRequest { policy: Policy::Other, priority: 0, lock_memory: true, cpu: None };
        let (report, warnings) = std::thread::spawn(move || apply_to_current_thread(&req)).join().unwrap();
        if report.memory_locked {
            assert!(warnings.is_empty());
            release_memory_lock();
            assert_eq!(MEMORY_LOCK_HOLDERS.load(Ordering::SeqCst), 0);
        } else {
            assert_eq!(warnings.len(), 1);
            assert!(warnings[0].contains("mlockall"));
        }
    }

    #[test]
    fn an_impossible_cpu_is_a_warning_not_a_failure() {
        let req = RtRequest { policy: Policy::Other, priority: 0, lock_memory: false, cpu: Some(100_000) };
        let (report, warnings) = std::thread::spawn(move || apply_to_current_thread(&req)).join().unwrap();
        assert_eq!(report.cpu, None);
        assert_eq!(warnings.len(), 1);
        assert!(warnings[0].contains("cpu 100000"));
    }
}
