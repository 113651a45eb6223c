//! Rendered event camera, one `SimCamera::advance` (render + composite + remap + sensor step) at
//! 1280×720 with the IMX636 model's distortion, a 3072-triangle textured box (the render bench's pose) and
//! the textured background plane 0.6 m behind it, the camera moving 0.2 mm per frame against the
//! world (≈ 0.15 px of background motion: the closed loop's 1 kHz regime at 0.2 m/s). Sparse
//! frames against the full-frame reference path; both give the same events (tested). And
//! `render_fast`: the `render-fast` source's regime, one sparse render per 4 ticks (≈ 0.6 px of
//! background motion) with the sensor stepped at the 3 ticks in between on interpolated
//! intensities (`SimCamera::advance_ticks`); one iteration is one render and 4 sensor steps.

mod common;

use common::{pose, textured_box};
use criterion::{criterion_group, criterion_main, Criterion};
use evcore::render::RenderOptions;
use evcore::se3::Pose;
use evcore::sim::camera::{Background, BackgroundPlane, SimCamera};
use evcore::sim::SimParams;
use evcore::{Camera, EventBatch};
use nalgebra::Isometry3;
use std::sync::Arc;

/// The shared bench pose, drifting 0.1 mm per frame.
fn object(k: f64) -> Pose {
    let mut p = pose();
    p.translation.vector.x += 1e-4 * k;
    p
}

fn background(k: f64) -> Pose {
    Isometry3::translation(2e-4 * k, -1e-4 * k, 1.5)
}

fn camera(sparse: bool) -> SimCamera {
    let plane = Background::Plane(BackgroundPlane {
        t_c_bg: background(0.0),
        cell_m: 0.04,
        seed: 1,
    });
    let mesh = Arc::new(textured_box([0.22, 0.28, 0.08], 16));
    let params = SimParams::preset("imx636").unwrap();
    let mut c = SimCamera::new(
        Camera::imx636(),
        mesh,
        RenderOptions::default(),
        plane,
        params,
        4,
    )
    .unwrap();
    c.set_sparse(sparse);
    c
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("simcamera_moving_camera_1280x720");
    g.sample_size(20);
    for (name, sparse) in [("sparse", true), ("reference", false)] {
        let mut cam = camera(sparse);
        let mut out = EventBatch::default();
        let mut k = 0_i64;
        cam.advance(&object(0.0), 0, Some(&background(0.0)), &mut out)
            .unwrap();
        g.bench_function(name, |b| {
            b.iter(|| {
                k += 1;
                let kf = k as f64;
                cam.advance(&object(kf), 1000 * k, Some(&background(kf)), &mut out)
                    .unwrap();
                out.len()
            })
        });
    }
    let mut cam = camera(true);
    let mut out = EventBatch::default();
    let mut k = 0_i64;
    cam.advance(&object(0.0), 0, Some(&background(0.0)), &mut out)
        .unwrap();
    g.bench_function("render_fast", |b| {
        b.iter(|| {
            let ticks = [1000 * k + 1000, 1000 * k + 2000, 1000 * k + 3000];
            k += 4;
            let kf = k as f64;
            cam.advance_ticks(
                &object(kf),
                &[],
                (&ticks, 1000 * k),
                Some(&background(kf)),
                &mut out,
            )
            .unwrap();
            out.len()
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
