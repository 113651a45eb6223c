//! Event-to-pose latency, booked where it happens: which pushed batches a pose is the first to
//! contain, and a histogram of latencies a solver thread writes and any thread reads.
//!
//! [`PendingBatches`] is the hand-over between the two halves of a tracker. Ingest marks every
//! batch it has fully inserted (its push stamp and a count); the solver claims them all at the
//! start of a step with one swap. Because the mark follows the insert, every claimed batch is in
//! the active set the step reads, so `published − oldest claimed push` bounds the latency of every
//! event the pose is the first to use; a batch marked just after a claim only makes the next pose's
//! bound larger, never smaller.

use std::sync::atomic::{AtomicU64, Ordering};

/// Bits of [`PendingBatches`]' word holding the push stamp (ns): 2^52 ns is 52 days of uptime.
const STAMP_BITS: u32 = 52;
const STAMP_MASK: u64 = (1 << STAMP_BITS) - 1;
/// The count saturates here (the top 12 bits).
const MAX_COUNT: u64 = (1 << (64 - STAMP_BITS)) - 1;

/// Batches ingested but not yet claimed by a step: the push stamp of the oldest and how many, in
/// one word so that a claim takes both at once.
#[derive(Debug, Default)]
pub struct PendingBatches(AtomicU64);

/// What one claim took: how many batches (saturating at 4095) and the oldest one's push stamp
/// ([`crate::clock::now_ns`], ns); `count == 0` when none were pending.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Claim {
    pub count: u64,
    pub oldest_pushed_ns: u64,
}

impl PendingBatches {
    /// Mark one batch pushed at `pushed_ns` (non-zero) as ingested. Release: whoever claims it
    /// also sees its events.
    pub fn mark(&self, pushed_ns: u64) {
        let stamp = pushed_ns & STAMP_MASK;
        let _ = self
            .0
            .fetch_update(Ordering::Release, Ordering::Relaxed, |word| {
                let (count, oldest) = (word >> STAMP_BITS, word & STAMP_MASK);
                let oldest = if count == 0 { stamp } else { oldest };
                Some(((count + 1).min(MAX_COUNT) << STAMP_BITS) | oldest)
            });
    }

    /// Take every pending batch.
    pub fn claim(&self) -> Claim {
        let word = self.0.swap(0, Ordering::Acquire);
        Claim {
            count: word >> STAMP_BITS,
            oldest_pushed_ns: word & STAMP_MASK,
        }
    }
}

/// Width of a histogram bucket (ns).
const BUCKET_NS: u64 = 10_000;
/// Buckets: 10 µs each up to 100 ms; longer latencies go to an overflow count.
const BUCKETS: usize = 10_000;

/// Latencies (ns) in 10 µs buckets up to 100 ms, plus the exact maximum. One writer (the solver);
/// readers on any thread see counts that are at worst a few samples behind.
#[derive(Debug)]
pub struct LatencyHistogram {
    counts: Box<[AtomicU64]>,
    overflow: AtomicU64,
    total: AtomicU64,
    max_ns: AtomicU64,
}

impl Default for LatencyHistogram {
    fn default() -> Self {
        Self {
            counts: (0..BUCKETS).map(|_| AtomicU64::new(0)).collect(),
            overflow: AtomicU64::new(0),
            total: AtomicU64::new(0),
            max_ns: AtomicU64::new(0),
        }
    }
}

impl LatencyHistogram {
    /// Count `weight` samples of `ns`.
    pub fn record(&self, ns: u64, weight: u64) {
        if weight == 0 {
            return;
        }
        match self.counts.get((ns / BUCKET_NS) as usize) {
            Some(c) => c.fetch_add(weight, Ordering::Relaxed),
            None => self.overflow.fetch_add(weight, Ordering::Relaxed),
        };
        self.total.fetch_add(weight, Ordering::Relaxed);
        self.max_ns.fetch_max(ns, Ordering::Relaxed);
    }

    /// Samples counted.
    pub fn count(&self) -> u64 {
        self.total.load(Ordering::Relaxed)
    }

    /// Largest sample (ns); None before any.
    pub fn max_ns(&self) -> Option<u64> {
        (self.count() > 0).then(|| self.max_ns.load(Ordering::Relaxed))
    }

    /// An upper bound (ns) of the `q`-quantile, 0 ≤ q ≤ 1: the upper edge of the bucket holding it
    /// (never above the maximum). None before any sample.
    pub fn quantile_ns(&self, q: f64) -> Option<u64> {
        let max = self.max_ns()?;
        let total = self.count();
        // The rank of the quantile among the samples, 1-based.
        let rank = ((q.clamp(0.0, 1.0) * total as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for (k, c) in self.counts.iter().enumerate() {
            seen += c.load(Ordering::Relaxed);
            if seen >= rank {
                return Some(((k as u64 + 1) * BUCKET_NS).min(max));
            }
        }
        Some(max)
    }

    /// Forget every sample.
    pub fn reset(&self) {
        for c in self.counts.iter() {
            c.store(0, Ordering::Relaxed);
        }
        self.overflow.store(0, Ordering::Relaxed);
        self.total.store(0, Ordering::Relaxed);
        self.max_ns.store(0, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn a_claim_takes_the_oldest_stamp_and_the_count_at_once() {
        let p = PendingBatches::default();
        assert_eq!(p.claim(), Claim::default());
        p.mark(500);
        p.mark(700);
        p.mark(900);
        assert_eq!(
            p.claim(),
            Claim {
                count: 3,
                oldest_pushed_ns: 500
            }
        );
        assert_eq!(p.claim().count, 0, "claimed batches are gone");
        p.mark(1000);
        assert_eq!(p.claim().oldest_pushed_ns, 1000);
        for k in 0..5000 {
            p.mark(2000 + k);
        }
        assert_eq!(
            p.claim(),
            Claim {
                count: MAX_COUNT,
                oldest_pushed_ns: 2000
            }
        );
    }

    #[test]
    fn claims_racing_marks_lose_and_double_no_batch() {
        // Fewer marks per round than the count holds, so that every claim is exact.
        let n = MAX_COUNT - 1;
        for _ in 0..20 {
            let p = Arc::new(PendingBatches::default());
            let marker = {
                let p = Arc::clone(&p);
                std::thread::spawn(move || (1..=n).for_each(|k| p.mark(k)))
            };
            let mut claimed = 0;
            while claimed < n {
                let c = p.claim();
                if c.count > 0 {
                    // Stamps grow with the push order: each claim starts right after the last.
                    assert_eq!(c.oldest_pushed_ns, claimed + 1);
                    claimed += c.count;
                }
            }
            marker.join().unwrap();
            assert_eq!((claimed, p.claim().count), (n, 0));
        }
    }

    #[test]
    fn quantiles_bound_the_samples_from_above_within_a_bucket() {
        let h = LatencyHistogram::default();
        assert_eq!(h.quantile_ns(0.5), None);
        // 1 ms ... 100 ms in 1 ms steps, plus one sample beyond the buckets.
        for ms in 1..=100u64 {
            h.record(ms * 1_000_000 - 1, 1);
        }
        h.record(250_000_000, 1);
        assert_eq!(h.count(), 101);
        assert_eq!(h.max_ns(), Some(250_000_000));
        let p50 = h.quantile_ns(0.5).unwrap();
        assert!(
            (51_000_000 - 1..=51_000_000 + BUCKET_NS).contains(&p50),
            "{p50}"
        );
        assert_eq!(h.quantile_ns(1.0), Some(250_000_000));
        assert_eq!(
            h.quantile_ns(0.0),
            Some(1_000_000),
            "the smallest sample's bucket edge"
        );
        h.record(3_000, 99);
        assert_eq!(
            h.quantile_ns(0.4),
            Some(10_000),
            "a weight counts that many samples"
        );
        h.reset();
        assert_eq!((h.count(), h.max_ns()), (0, None));
    }
}
