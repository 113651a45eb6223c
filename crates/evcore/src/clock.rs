//! One monotonic clock for the whole process, in nanoseconds, so that stamps taken on different
//! threads (a batch pushed on the producer's, a pose published on the solver's) can be subtracted.

use std::sync::OnceLock;
use std::time::Instant;

static EPOCH: OnceLock<Instant> = OnceLock::new();

/// Nanoseconds on the process's monotonic clock since its first use, plus one: never 0, which the
/// stamps use for "none".
pub fn now_ns() -> u64 {
    let epoch = *EPOCH.get_or_init(Instant::now);
    u64::try_from(epoch.elapsed().as_nanos()).unwrap_or(u64::MAX) + 1
}

/// Nanoseconds of CPU time the calling thread has used: what a piece of work cost its core, without
/// the time the thread was preempted (which a wall clock counts, and which on a loaded machine says
/// nothing about the work). A system call (≈ 0.1–0.5 µs): for timing batches, not single events.
#[cfg(unix)]
pub fn thread_cpu_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; the call only writes into it.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    debug_assert_eq!(rc, 0, "clock_gettime(CLOCK_THREAD_CPUTIME_ID) failed");
    (ts.tv_sec as u64) * 1_000_000_000 + ts.tv_nsec as u64
}

/// Without a thread CPU clock, the wall clock (it also counts preemption).
#[cfg(not(unix))]
pub fn thread_cpu_ns() -> u64 {
    now_ns()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn never_zero_and_never_backwards_across_threads() {
        let a = now_ns();
        let b = std::thread::spawn(now_ns).join().unwrap();
        std::thread::sleep(std::time::Duration::from_millis(2));
        let c = now_ns();
        assert!(a > 0 && b >= a && c >= b + 2_000_000);
    }

    #[test]
    fn thread_cpu_time_counts_work_not_sleep() {
        let t0 = thread_cpu_ns();
        std::thread::sleep(std::time::Duration::from_millis(20));
        let slept = thread_cpu_ns() - t0;
        let t1 = thread_cpu_ns();
        let started = std::time::Instant::now();
        let mut x = 0u64;
        while started.elapsed() < std::time::Duration::from_millis(20) {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
        }
        let worked = thread_cpu_ns() - t1;
        assert!(slept < 5_000_000, "sleeping 20 ms used {slept} ns of CPU");
        assert!(
            worked > slept,
            "spinning used {worked} ns of CPU, sleeping {slept} ns"
        );
    }
}
