//! Rendering cost at the event simulator's working point: a textured box at Z = 0.6 m covering
//! about a quarter of the 1280×720 view, and the one-off point-set extraction.

mod common;

use common::{pose, textured_box};
use criterion::{criterion_group, criterion_main, Criterion};
use evcore::pointset::{extract_point_set, PointSetParams};
use evcore::render::{RenderOptions, Renderer};
use evcore::Camera;
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let cam = Camera::imx636().rectified();
    let opts = RenderOptions::default();
    for (name, n) in [
        ("render_box_12tri_1280x720", 1),
        ("render_box_3072tri_1280x720", 16),
    ] {
        let mesh = textured_box([0.22, 0.28, 0.08], n);
        let mut renderer = Renderer::new();
        let covered = renderer
            .render_into(&mesh, &cam, &pose(), None, &opts)
            .expect("renders");
        let frac =
            covered.depth_m.iter().filter(|d| d.is_finite()).count() as f64 / cam.n_pixels() as f64;
        eprintln!("{name}: object covers {:.1} % of the view", 100.0 * frac);
        c.bench_function(name, |b| {
            b.iter(|| {
                renderer
                    .render_into(black_box(&mesh), &cam, &pose(), None, &opts)
                    .expect("renders");
            })
        });
    }
    let mesh = textured_box([0.22, 0.28, 0.08], 1);
    let params = PointSetParams::default();
    c.bench_function("extract_point_set_box_1280x720", |b| {
        b.iter(|| extract_point_set(black_box(&mesh), &cam, &pose(), &params).expect("points"))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
