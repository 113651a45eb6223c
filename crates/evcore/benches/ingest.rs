//! The producer's cost of `Ingest::push` (through `TrackerCore::ingest_thinned`) on a cluttered
//! 1280×720 stream: 32 Mev/s of events scattered uniformly over a 960 × 600 px region, pushed in
//! 1 ms batches, kept whole and thinned to 1/8 (an `EventsPerSecond` cap, so the kept fraction
//! is exact rather than sized on measured costs). Thinned, the kept events are far apart in the
//! stream, so their undistortion-table entries (a 3.7 MB table) are not in cache: the per-kept-event
//! cost is what the overload policy trades against freshness.
//!
//! One iteration is one batch; `Throughput::Elements` is the events kept per batch, so the
//! figure to compare is ns per kept event = time / kept (printed at start). Timed on the thread's
//! CPU clock (`EVCORE_BENCH_CLOCK=cpu`), push only: shifting the batches' times is not counted.

mod clock;
mod common;

use clock::BenchClock;
use common::{pose, textured_box};
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use evcore::clock::thread_cpu_ns;
use evcore::pointset::{extract_point_set, PointSetParams};
use evcore::rng::Rng;
use evcore::tracker::{IngestLimit, TrackerConfig, TrackerCore};
use evcore::{Camera, EventBatch};
use std::time::Duration;

/// Offered rate (events per µs) and batch length (µs): the rendered drill's peaks.
const RATE_EV_PER_US: usize = 32;
const BATCH_US: i64 = 1000;
/// Distinct batches cycled through (32 ms of stream, 16 MB): more than the caches hold.
const N_BATCHES: usize = 32;
/// The cluttered region: x in [160, 1120), y in [60, 660).
const ROI_X0: u64 = 160;
const ROI_W: u64 = 960;
const ROI_Y0: u64 = 60;
const ROI_H: u64 = 600;

fn stream(seed: u64) -> Vec<EventBatch> {
    let mut rng = Rng::new(seed);
    let n = RATE_EV_PER_US * BATCH_US as usize;
    (0..N_BATCHES)
        .map(|b| {
            let mut batch = EventBatch::with_capacity(n);
            for i in 0..n {
                let (x, y) = (ROI_X0 + rng.below(ROI_W), ROI_Y0 + rng.below(ROI_H));
                let t_us = b as i64 * BATCH_US + (i / RATE_EV_PER_US) as i64;
                batch.push(x as u16, y as u16, (i % 2) as i16, t_us);
            }
            batch
        })
        .collect()
}

fn core(cam: &Camera, limit: IngestLimit) -> TrackerCore {
    let mesh = textured_box([0.16, 0.21, 0.06], 1);
    let points = extract_point_set(&mesh, &cam.rectified(), &pose(), &PointSetParams::default())
        .expect("S*")
        .points_o;
    let config = TrackerConfig {
        ingest_limit: limit,
        ..TrackerConfig::default()
    };
    TrackerCore::new(cam, points, pose(), config).expect("core")
}

fn bench(c: &mut Criterion<BenchClock>) {
    let cam = Camera::imx636();
    let offered_per_s = (RATE_EV_PER_US * 1_000_000) as f64;
    let cases = [
        ("ingest_push_32mevs_whole", IngestLimit::Off),
        (
            "ingest_push_32mevs_thinned_1_8",
            IngestLimit::EventsPerSecond(offered_per_s / 8.0),
        ),
    ];
    let mut group = c.benchmark_group("ingest");
    for (name, limit) in cases {
        let mut batches = stream(11);
        let mut tracker = core(&cam, limit);
        // One pass to settle the rate estimate and fill SCARF, then count what a batch keeps.
        for b in &batches {
            tracker.ingest_thinned(b).expect("ingest");
        }
        let shift = |batches: &mut [EventBatch]| {
            for b in batches.iter_mut() {
                b.t_us
                    .iter_mut()
                    .for_each(|t| *t += N_BATCHES as i64 * BATCH_US);
            }
        };
        shift(&mut batches);
        let before = tracker.stats().events_ingested;
        tracker.ingest_thinned(&batches[0]).expect("ingest");
        let kept = tracker.stats().events_ingested - before;
        eprintln!(
            "{name}: {kept} of {} events kept per batch",
            batches[0].len()
        );
        let mut next = 1;
        group.throughput(Throughput::Elements(kept));
        group.bench_function(name, |b| {
            b.iter_custom(|iters| {
                let mut cpu_ns = 0;
                for _ in 0..iters {
                    if next == N_BATCHES {
                        shift(&mut batches);
                        next = 0;
                    }
                    let t0 = thread_cpu_ns();
                    tracker.ingest_thinned(&batches[next]).expect("ingest");
                    cpu_ns += thread_cpu_ns() - t0;
                    next += 1;
                }
                Duration::from_nanos(cpu_ns)
            })
        });
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = clock::config().sample_size(20);
    targets = bench
}
criterion_main!(benches);
