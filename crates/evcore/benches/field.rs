//! Distance-field build and sampling on a realistic 400×400 ROI of a 1280×720 sensor: edge-like
//! segments (2 px thick, 10 % of their pixels missing) plus sparse noise, 15 % of pixels active.

mod clock;

use clock::BenchClock;
use criterion::{criterion_group, criterion_main, Criterion};
use evcore::field::{DistanceField, FieldParams};
use evcore::rng::Rng;
use evcore::Roi;
use std::hint::black_box;

const ROI: Roi = Roi {
    x0: 437,
    y0: 161,
    width: 400,
    height: 400,
};

fn edge_mask(rng: &mut Rng) -> Vec<u8> {
    let (w, h) = (ROI.width as usize, ROI.height as usize);
    let mut mask = vec![0u8; w * h];
    let target = w * h * 15 / 100;
    let mut active = 0;
    let mut set = |mask: &mut [u8], i: usize| {
        active += usize::from(mask[i] == 0);
        mask[i] = 1;
        active
    };
    let mut count = 0;
    while count < target {
        let (x0, y0) = (rng.uniform() * w as f64, rng.uniform() * h as f64);
        let angle = rng.uniform() * std::f64::consts::TAU;
        let (c, s) = (angle.cos(), angle.sin());
        let len = 40.0 + 160.0 * rng.uniform();
        for step in 0..(len as usize) {
            for t in 0..2 {
                let x = x0 + step as f64 * c - t as f64 * s;
                let y = y0 + step as f64 * s + t as f64 * c;
                if x >= 0.0
                    && y >= 0.0
                    && (x as usize) < w
                    && (y as usize) < h
                    && rng.uniform() > 0.1
                {
                    count = set(&mut mask, y as usize * w + x as usize);
                }
            }
        }
        for _ in 0..20 {
            count = set(&mut mask, rng.below((w * h) as u64) as usize);
        }
    }
    mask
}

fn bench_field(c: &mut Criterion<BenchClock>) {
    let mut rng = Rng::new(42);
    let mask = edge_mask(&mut rng);
    let mut field = DistanceField::new(FieldParams::default()).unwrap();

    c.bench_function("field/build_level0_values_400x400", |b| {
        b.iter(|| field.build(black_box(&mask), ROI, 1).unwrap())
    });
    c.bench_function("field/build_3levels_400x400", |b| {
        b.iter(|| field.build(black_box(&mask), ROI, 3).unwrap())
    });

    // 3000 model points (the registration budget) scattered over the ROI.
    let points: Vec<(f32, f32)> = (0..3000)
        .map(|_| {
            let u = ROI.x0 as f32 + rng.uniform() as f32 * ROI.width as f32;
            let v = ROI.y0 as f32 + rng.uniform() as f32 * ROI.height as f32;
            (u, v)
        })
        .collect();
    let level = field.level(0);
    c.bench_function("field/sample_3000pts", |b| {
        b.iter(|| {
            black_box(&points)
                .iter()
                .map(|&(u, v)| level.sample(u, v))
                .sum::<f32>()
        })
    });
    c.bench_function("field/sample_slope_3000pts", |b| {
        b.iter(|| {
            black_box(&points).iter().fold([0.0f32; 3], |acc, &(u, v)| {
                let s = level.sample_slope(u, v);
                [acc[0] + s[0], acc[1] + s[1], acc[2] + s[2]]
            })
        })
    });
}

criterion_group! {
    name = benches;
    config = clock::config();
    targets = bench_field
}
criterion_main!(benches);
