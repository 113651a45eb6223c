//! Sensor-model throughput: one 1280×720 step with a striped patch moving half a pixel per
//! step over a static textured background (imx636 preset), and the same motion through a
//! 640×360 ROI step. Per-step µs × 1500 steps gives the compute time per simulated second at
//! ESIM's half-pixel rate for 0.4 m/s at Z = 0.6 m. `step_tiles_1280x720_moving_texture`: the
//! rendered camera's sensor step (`step_tiles`), a smooth texture sliding half a pixel per step
//! over the patch, so every pixel of its flagged tiles changes at every step and a few per cent
//! fire, as on a moving textured object in a 1 ms tick of the closed loop.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};
use evcore::sim::{EventSimulator, SimParams, SEGMENT_PX};
use evcore::{EventBatch, Roi};
use std::hint::black_box;

const W: u32 = 1280;
const H: u32 = 720;
const PATCH: Roi = Roi {
    x0: 440,
    y0: 210,
    width: 400,
    height: 300,
};
const ROI: Roi = Roi {
    x0: 320,
    y0: 180,
    width: 640,
    height: 360,
};
const DT_US: i64 = 667;

fn background() -> Vec<f32> {
    (0..H)
        .flat_map(|y| {
            (0..W).map(move |x| 0.2 + 0.1 * ((x as f32 * 0.05).sin() * (y as f32 * 0.03).cos()))
        })
        .collect()
}

/// The background with the patch's stripes (period 40 px, 1 px soft edges) shifted by k/2 px.
fn frame(bg: &[f32], k: u64) -> Vec<f32> {
    let mut f = bg.to_vec();
    let shift = k as f32 * 0.5;
    for y in PATCH.y0..PATCH.y0 + PATCH.height {
        for x in PATCH.x0..PATCH.x0 + PATCH.width {
            let phase = (x as f32 - shift).rem_euclid(40.0);
            let bright = (phase - 19.5).clamp(0.0, 1.0) - (phase - 39.5).clamp(0.0, 1.0);
            f[(y * W + x) as usize] = 0.1 + 0.7 * bright;
        }
    }
    f
}

fn crop(f: &[f32], r: Roi) -> Vec<f32> {
    (r.y0..r.y0 + r.height)
        .flat_map(|y| {
            f[(y * W + r.x0) as usize..(y * W + r.x0 + r.width) as usize]
                .iter()
                .copied()
        })
        .collect()
}

/// Warm a simulator over `n` steps and return it with the mean number of events per step.
fn warmed(bg: &[f32], n: u64, roi: bool) -> (EventSimulator, u64) {
    let mut sim = EventSimulator::new(W, H, SimParams::preset("imx636").unwrap()).unwrap();
    sim.reset(&frame(bg, 0), 0).unwrap();
    let mut out = EventBatch::default();
    let mut total = 0;
    for k in 1..=n {
        let f = frame(bg, k);
        if roi {
            sim.step_roi(&crop(&f, ROI), ROI, k as i64 * DT_US, &mut out)
                .unwrap();
        } else {
            sim.step(&f, k as i64 * DT_US, &mut out).unwrap();
        }
        total += out.len() as u64;
    }
    (sim, total / n)
}

fn bench(c: &mut Criterion) {
    let bg = background();
    let warm = 20;
    for (name, roi) in [
        ("step_1280x720_moving_stripes", false),
        ("step_roi_640x360_moving_stripes", true),
    ] {
        let (mut sim, per_step) = warmed(&bg, warm, roi);
        eprintln!("{name}: {per_step} events per step");
        let mut group = c.benchmark_group("sim");
        group.throughput(Throughput::Elements(per_step));
        let mut k = warm;
        let mut out = EventBatch::default();
        group.bench_function(name, |b| {
            b.iter_batched(
                || {
                    k += 1;
                    let f = frame(&bg, k);
                    (if roi { crop(&f, ROI) } else { f }, k as i64 * DT_US)
                },
                |(f, t)| {
                    if roi {
                        sim.step_roi(&f, ROI, t, &mut out).unwrap();
                    } else {
                        sim.step(&f, t, &mut out).unwrap();
                    }
                    black_box(out.len())
                },
                BatchSize::PerIteration,
            )
        });
        group.finish();
    }
}

/// The background with a smooth texture over the patch, slid by k/2 px: every patch pixel
/// changes at every step.
fn textured(bg: &[f32], k: u64) -> Vec<f32> {
    let mut f = bg.to_vec();
    let shift = k as f32 * 0.5;
    for y in PATCH.y0..PATCH.y0 + PATCH.height {
        for x in PATCH.x0..PATCH.x0 + PATCH.width {
            let u = (x as f32 - shift) * 0.04;
            f[(y * W + x) as usize] = 0.25 + 0.1 * u.sin() * (y as f32 * 0.2).cos();
        }
    }
    f
}

fn bench_tiles(c: &mut Criterion) {
    let bg = background();
    let mut sim = EventSimulator::new(W, H, SimParams::preset("imx636").unwrap()).unwrap();
    sim.reset(&textured(&bg, 0), 0).unwrap();
    let (tx, ty) = sim.tiles();
    let t = SEGMENT_PX as u32;
    // The tiles meeting the patch, as a render flags the tiles it redrew.
    let changed: Vec<bool> = (0..tx * ty)
        .map(|k| {
            let (x, y) = ((k % tx) as u32 * t, (k / tx) as u32 * t);
            x + t > PATCH.x0
                && x < PATCH.x0 + PATCH.width
                && y + t > PATCH.y0
                && y < PATCH.y0 + PATCH.height
        })
        .collect();
    let mut out = EventBatch::default();
    let mut k = 0;
    let mut step = |sim: &mut EventSimulator, out: &mut EventBatch| {
        k += 1;
        let f = textured(&bg, k);
        sim.step_tiles(&f, &changed, k as i64 * 1000, out).unwrap();
    };
    // Warmed until the pixels' references have spread over the band (a steady event rate).
    let mut total = 0;
    for n in 0..200 {
        step(&mut sim, &mut out);
        total += if n >= 100 { out.len() as u64 } else { 0 };
    }
    eprintln!(
        "step_tiles_1280x720_moving_texture: {} events per step",
        total / 100
    );
    let mut group = c.benchmark_group("sim");
    group.throughput(Throughput::Elements(total / 100));
    group.bench_function("step_tiles_1280x720_moving_texture", |b| {
        b.iter_batched(
            || {
                k += 1;
                (textured(&bg, k), k as i64 * 1000)
            },
            |(f, t_us)| {
                sim.step_tiles(&f, &changed, t_us, &mut out).unwrap();
                black_box(out.len())
            },
            BatchSize::PerIteration,
        )
    });
    group.finish();
}

criterion_group!(benches, bench, bench_tiles);
criterion_main!(benches);
