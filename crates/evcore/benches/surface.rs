//! Front-end throughput on a 1280×720 grid (the IMX636 of the paper).
//!
//! Input: 1 M pre-generated events, 80 % on the outline of a 300×200 rectangle that drifts across
//! the sensor (about 1000 events per pixel of motion, rows and sides in random order) and 20 %
//! uniform noise, which defeats the caches the way real background activity does. SCARF is also
//! run on the edges alone and on noise alone to separate compute from cache misses.

mod clock;

use clock::BenchClock;
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use evcore::rng::Rng;
use evcore::surface::{Eros, EventSurface, FixedCount, Scarf};
use evcore::Roi;
use std::hint::black_box;

const W: u32 = 1280;
const H: u32 = 720;
const N_EVENTS: usize = 1_000_000;

fn moving_rectangle_with_noise(seed: u64, noise: f64) -> Vec<u32> {
    let mut rng = Rng::new(seed);
    let (rw, rh) = (300u32, 200u32);
    let perimeter = 2 * (rw + rh);
    (0..N_EVENTS)
        .map(|i| {
            if rng.uniform() < noise {
                return rng.below(u64::from(W * H)) as u32;
            }
            let step = (i / 1000) as u32;
            let (x0, y0) = (100 + step, 150 + step / 2);
            let k = rng.below(u64::from(perimeter)) as u32;
            let (x, y) = if k < rw {
                (x0 + k, y0)
            } else if k < 2 * rw {
                (x0 + k - rw, y0 + rh)
            } else if k < 2 * rw + rh {
                (x0, y0 + k - 2 * rw)
            } else {
                (x0 + rw, y0 + k - 2 * rw - rh)
            };
            y * W + x
        })
        .collect()
}

fn bench(c: &mut Criterion<BenchClock>) {
    let pixels = moving_rectangle_with_noise(1, 0.2);
    let clean = moving_rectangle_with_noise(1, 0.0);
    let noise = moving_rectangle_with_noise(1, 1.0);
    let polarity = vec![1i16; pixels.len()];

    let mut g = c.benchmark_group("surface_ingest_1280x720");
    g.throughput(Throughput::Elements(pixels.len() as u64));
    g.sample_size(10);
    let mut scarf = Scarf::new(W, H, 14, 1.0).expect("valid SCARF");
    g.bench_function("scarf_b14", |b| {
        b.iter(|| scarf.writer().ingest(black_box(&pixels)))
    });
    g.bench_function("scarf_b14_edges_only", |b| {
        b.iter(|| scarf.writer().ingest(black_box(&clean)))
    });
    g.bench_function("scarf_b14_noise_only", |b| {
        b.iter(|| scarf.writer().ingest(black_box(&noise)))
    });
    // The same stream in 1 ms batches at 20 Mev/s, as the tracker's producer hands it over: a
    // batch holds fewer than N events for most blocks, so little of it is evicted within itself.
    g.bench_function("scarf_b14_batches_20k", |b| {
        b.iter(|| {
            for batch in pixels.chunks(20_000) {
                scarf.writer().ingest(black_box(batch));
            }
        })
    });
    let mut fixed = FixedCount::new(W, H, 8000).expect("valid fixed-count");
    g.bench_function("fixed_count_8000", |b| {
        b.iter(|| fixed.ingest(black_box(&pixels), &polarity))
    });
    let mut eros = Eros::new(W, H, 7, 0.7).expect("valid EROS");
    g.bench_function("eros_k7", |b| {
        b.iter(|| eros.ingest(black_box(&pixels), &polarity))
    });
    g.finish();

    let roi = Roi {
        x0: 400,
        y0: 200,
        width: 400,
        height: 400,
    };
    let mut g = c.benchmark_group("surface_fill_mask_400x400");
    g.throughput(Throughput::Elements(roi.area() as u64));
    let mut out = vec![0u8; roi.area()];
    g.bench_function("scarf", |b| {
        b.iter(|| scarf.fill_mask(black_box(roi), &mut out))
    });
    g.bench_function("eros", |b| {
        b.iter(|| eros.fill_mask(black_box(roi), &mut out))
    });
    g.finish();

    // Reset cost matters when the tracker restarts after a loss.
    let mut g = c.benchmark_group("surface_reset_1280x720");
    g.bench_function("scarf", |b| b.iter(|| scarf.reset()));
    g.finish();
}

criterion_group! {
    name = benches;
    config = clock::config();
    targets = bench
}
criterion_main!(benches);
