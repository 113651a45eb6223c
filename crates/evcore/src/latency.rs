//! Event-to-pose latency, booked where it happens: which pushed batches a pose is the first to
//! contain, and a histogram of latencies a solver thread writes and any thread reads.
//!
//! [`PendingBatches`] is the hand-over between the two halves of a tracker. Ingest marks every
//! batch it has fully inserted (its push stamp); the solver claims them all at the start of a
//! step. Because the mark follows the insert, every claimed batch is in the active set the step
//! reads, so `published − push` is the latency of every event of a claimed batch (the events of
//! one batch are handed over together), and `published − oldest claimed push` bounds them all.
//! A batch marked just after a claim is booked by the next pose, never by an earlier one.
//!
//! The stamps of the last [`STAMP_RING`] batches are kept by mark order so that each claimed
//! batch is booked with its own latency. Only a solver that has claimed nothing for that many
//! batches loses stamps; those batches are booked at the claim's bound instead.

use std::sync::atomic::{AtomicU64, Ordering};

/// Bits of [`PendingBatches`]' words holding the push stamp (ns): 2^52 ns is 52 days of uptime.
const STAMP_BITS: u32 = 52;
const STAMP_MASK: u64 = (1 << STAMP_BITS) - 1;
/// The count saturates here (the top 12 bits).
const MAX_COUNT: u64 = (1 << (64 - STAMP_BITS)) - 1;
/// Push stamps kept by mark order: 4096 batches, 2 s of 0.5 ms batches. A slot's top 12 bits hold
/// the lap (mark number / ring size) it was written in, so a reader tells a stamp overwritten by a
/// later lap from its own without a lock.
const STAMP_RING: u64 = 1 << (64 - STAMP_BITS);

/// Batches ingested but not yet claimed by a step: the push stamp of the oldest and how many, in
/// one word so that a claim takes both at once, and the stamps of the last [`STAMP_RING`] batches
/// by mark order. One producer marks, one solver claims.
#[derive(Debug)]
pub struct PendingBatches {
    word: AtomicU64,
    /// Slot `k % STAMP_RING` holds the stamp of the `k`-th batch marked and its lap.
    stamps: Box<[AtomicU64]>,
    /// Batches marked so far (stored after their slot).
    marked: AtomicU64,
    /// Batches claimed so far (the claimant's own count, shared so that a rebuilt solver goes on
    /// where the last one stopped).
    claimed: AtomicU64,
}

impl Default for PendingBatches {
    fn default() -> Self {
        Self {
            word: AtomicU64::new(0),
            stamps: (0..STAMP_RING).map(|_| AtomicU64::new(0)).collect(),
            marked: AtomicU64::new(0),
            claimed: AtomicU64::new(0),
        }
    }
}

/// What one claim took: how many batches (saturating at 4095) and the oldest one's push stamp
/// ([`crate::clock::now_ns`], ns); `count == 0` when none were pending. `first..end` are the mark
/// numbers of the batches whose own stamps it books (see [`PendingBatches::claimed_stamps`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Claim {
    pub count: u64,
    pub oldest_pushed_ns: u64,
    pub first: u64,
    pub end: u64,
}

impl PendingBatches {
    /// Mark one batch pushed at `pushed_ns` (non-zero) as ingested. Release: whoever claims it
    /// also sees its events. Called by one producer at a time.
    pub fn mark(&self, pushed_ns: u64) {
        let stamp = pushed_ns & STAMP_MASK;
        let k = self.marked.load(Ordering::Relaxed);
        let lap = (k / STAMP_RING) & MAX_COUNT;
        self.stamps[(k % STAMP_RING) as usize]
            .store((lap << STAMP_BITS) | stamp, Ordering::Relaxed);
        self.marked.store(k + 1, Ordering::Release);
        let _ = self
            .word
            .fetch_update(Ordering::Release, Ordering::Relaxed, |word| {
                let (count, oldest) = (word >> STAMP_BITS, word & STAMP_MASK);
                let oldest = if count == 0 { stamp } else { oldest };
                Some(((count + 1).min(MAX_COUNT) << STAMP_BITS) | oldest)
            });
    }

    /// Take every pending batch.
    pub fn claim(&self) -> Claim {
        // The word first, then the mark count: every batch marked below `end` but one has updated
        // the word by then, so a batch whose stamp is lost is under this claim's bound.
        let word = self.word.swap(0, Ordering::Acquire);
        let end = self.marked.load(Ordering::Acquire);
        let first = self.claimed.swap(end, Ordering::Relaxed);
        Claim {
            count: word >> STAMP_BITS,
            oldest_pushed_ns: word & STAMP_MASK,
            first,
            end,
        }
    }

    /// The push stamp of each batch `claim` booked, oldest first; None for a batch whose stamp a
    /// later one overwrote (the solver claimed nothing for [`STAMP_RING`] batches).
    pub fn claimed_stamps(&self, claim: &Claim) -> impl Iterator<Item = Option<u64>> + '_ {
        let kept_from = claim.end.saturating_sub(STAMP_RING);
        let (first, end) = (claim.first.min(claim.end), claim.end);
        (first..end).map(move |k| {
            if k < kept_from {
                return None;
            }
            let slot = self.stamps[(k % STAMP_RING) as usize].load(Ordering::Relaxed);
            let lap = (k / STAMP_RING) & MAX_COUNT;
            (slot >> STAMP_BITS == lap).then_some(slot & STAMP_MASK)
        })
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
        let c = p.claim();
        assert_eq!((c.count, c.oldest_pushed_ns), (3, 500));
        let own: Vec<_> = p.claimed_stamps(&c).collect();
        assert_eq!(own, [Some(500), Some(700), Some(900)]);
        let none = p.claim();
        assert_eq!(none.count, 0, "claimed batches are gone");
        assert_eq!(p.claimed_stamps(&none).count(), 0);
        p.mark(1000);
        let c = p.claim();
        assert_eq!(c.oldest_pushed_ns, 1000);
        assert_eq!(p.claimed_stamps(&c).collect::<Vec<_>>(), [Some(1000)]);
        for k in 0..5000 {
            p.mark(2000 + k);
        }
        let c = p.claim();
        assert_eq!((c.count, c.oldest_pushed_ns), (MAX_COUNT, 2000));
        // The ring keeps the last 4096 stamps; the 904 before them are lost, not misread.
        let own: Vec<_> = p.claimed_stamps(&c).collect();
        assert_eq!(own.len(), 5000);
        let lost = 5000 - STAMP_RING as usize;
        assert!(own[..lost].iter().all(Option::is_none));
        assert!(own[lost..]
            .iter()
            .zip(2000 + lost as u64..)
            .all(|(s, want)| *s == Some(want)));
    }

    #[test]
    fn a_stamp_overwritten_while_read_is_not_taken_for_its_own() {
        let p = PendingBatches::default();
        p.mark(10);
        let c = p.claim();
        // The producer laps the ring before the solver reads the claimed stamp.
        for k in 0..STAMP_RING {
            p.mark(100 + k);
        }
        assert_eq!(p.claimed_stamps(&c).collect::<Vec<_>>(), [None]);
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
            let (mut claimed, mut booked) = (0, Vec::new());
            while claimed < n {
                let c = p.claim();
                if c.count > 0 {
                    // Stamps grow with the push order: each claim starts right after the last.
                    assert_eq!(c.oldest_pushed_ns, claimed + 1);
                    claimed += c.count;
                }
                // Each batch's own stamp once, in push order (its word may land a claim later).
                booked.extend(p.claimed_stamps(&c).map(Option::unwrap));
            }
            marker.join().unwrap();
            assert_eq!((claimed, p.claim().count), (n, 0));
            booked.extend(p.claimed_stamps(&p.claim()).map(Option::unwrap));
            assert_eq!(booked, (1..=n).collect::<Vec<_>>());
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
