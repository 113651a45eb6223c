//! The clock criterion reads: wall time (criterion's own) or the calling thread's CPU time.
//!
//! Set `EVCORE_BENCH_CLOCK=cpu` to time the benches that use [`config`] (surface, field, tracker)
//! by `CLOCK_THREAD_CPUTIME_ID` instead of wall time. On a shared, loaded machine a benchmark's
//! wall time mostly measures how long the scheduler kept it off a core; the thread's CPU time
//! counts only the time it ran, which for single-threaded code is close to its wall time on an
//! idle machine (cache pollution by the other tenants still shows). Everything timed by these
//! benches runs on the calling thread; a bench that fans work out to other threads (rayon) must
//! not use this clock, as their CPU time would not be counted.
//!
//! Results land in `target/criterion` in nanoseconds either way; the clock in use is printed to
//! stderr at start so a saved figure can be traced to its clock.

use criterion::measurement::{Measurement, ValueFormatter, WallTime};
use criterion::Criterion;
use std::time::{Duration, Instant};

/// Environment variable selecting the clock: `cpu` or `wall` (the default).
pub const CLOCK_ENV: &str = "EVCORE_BENCH_CLOCK";

/// A criterion measurement reading wall time or the calling thread's CPU time.
pub struct BenchClock {
    cpu: bool,
}

/// A reading of the selected clock.
pub enum Mark {
    Wall(Instant),
    Cpu(Duration),
}

impl BenchClock {
    /// The clock `EVCORE_BENCH_CLOCK` asks for; any value other than `cpu` or `wall` is refused so
    /// a typo cannot silently produce wall-clock figures.
    pub fn from_env() -> Self {
        let cpu = match std::env::var(CLOCK_ENV).as_deref() {
            Ok("cpu") => true,
            Ok("wall") | Err(std::env::VarError::NotPresent) => false,
            Ok(other) => panic!("{CLOCK_ENV}={other}: expected `cpu` or `wall`"),
            Err(e) => panic!("{CLOCK_ENV}: {e}"),
        };
        eprintln!(
            "bench clock: {}",
            if cpu { "thread CPU time" } else { "wall time" }
        );
        Self { cpu }
    }
}

/// CPU time consumed so far by the calling thread (the clock ingest sizes its share by).
fn thread_cpu_time() -> Duration {
    Duration::from_nanos(evcore::clock::thread_cpu_ns())
}

impl Measurement for BenchClock {
    type Intermediate = Mark;
    type Value = Duration;

    fn start(&self) -> Mark {
        if self.cpu {
            Mark::Cpu(thread_cpu_time())
        } else {
            Mark::Wall(Instant::now())
        }
    }

    fn end(&self, mark: Mark) -> Duration {
        match mark {
            Mark::Wall(t0) => t0.elapsed(),
            Mark::Cpu(t0) => thread_cpu_time().saturating_sub(t0),
        }
    }

    fn add(&self, a: &Duration, b: &Duration) -> Duration {
        *a + *b
    }

    fn zero(&self) -> Duration {
        Duration::ZERO
    }

    fn to_f64(&self, value: &Duration) -> f64 {
        value.as_nanos() as f64
    }

    fn formatter(&self) -> &dyn ValueFormatter {
        // Both clocks yield nanoseconds, so criterion's duration formatting applies unchanged.
        static WALL: WallTime = WallTime;
        WALL.formatter()
    }
}

/// Criterion configured with the clock `EVCORE_BENCH_CLOCK` selects.
pub fn config() -> Criterion<BenchClock> {
    Criterion::default().with_measurement(BenchClock::from_env())
}
