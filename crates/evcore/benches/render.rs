//! Rendering cost at the event simulator's working point: a textured box at Z = 0.6 m covering
//! about a quarter of the 1280×720 view, and the one-off point-set extraction.

use criterion::{criterion_group, criterion_main, Criterion};
use evcore::mesh::{Mesh, Shading, Texture};
use evcore::pointset::{extract_point_set, PointSetParams};
use evcore::render::{RenderOptions, Renderer};
use evcore::{Camera, Pose};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::hint::black_box;

/// Box of `size_m` centred on the origin, each face split into `n`×`n` quads, with a UV that
/// wraps a 1024² print of bands and blocks around it.
fn textured_box(size_m: [f32; 3], n: u32) -> Mesh {
    let (mut vertices, mut faces, mut uv) = (Vec::new(), Vec::new(), Vec::new());
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            let base = vertices.len() as u32;
            for j in 0..=n {
                for i in 0..=n {
                    let (s, t) = (i as f32 / n as f32, j as f32 / n as f32);
                    let mut p = [0.0; 3];
                    p[axis] = sign * size_m[axis] / 2.0;
                    p[a] = (s - 0.5) * size_m[a];
                    p[b] = (t - 0.5) * size_m[b];
                    vertices.push(p);
                    uv.push([(axis as f32 * 2.0 + (sign + 1.0) / 2.0 + s) / 6.0, t]);
                }
            }
            for j in 0..n {
                for i in 0..n {
                    let k = base + j * (n + 1) + i;
                    faces.push([k, k + 1, k + n + 2]);
                    faces.push([k, k + n + 2, k + n + 1]);
                }
            }
        }
    }
    let data = (0..1024 * 1024)
        .map(|k| {
            let (x, y) = (k % 1024, k / 1024);
            let band = (y / 96) % 2 == 0;
            let block = (x / 40 + y / 56) % 3 == 0;
            if band ^ block {
                0.08
            } else {
                0.85
            }
        })
        .collect();
    let texture = Texture {
        width: 1024,
        height: 1024,
        data,
    };
    Mesh::new(vertices, faces, Shading::Textured { uv, texture }).expect("valid box")
}

fn pose() -> Pose {
    Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 0.6),
        UnitQuaternion::from_euler_angles(0.15, 0.35, 0.05),
    )
}

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
