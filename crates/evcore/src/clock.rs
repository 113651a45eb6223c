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
}
