//! Scene fixtures shared by the benches: a printed box and the pose it is seen from.

use evcore::mesh::{Mesh, Shading, Texture};
use evcore::Pose;
use nalgebra::{Isometry3, Translation3, UnitQuaternion};

/// Box of `size_m` centred on the origin, each face split into `n`×`n` quads, with a UV that
/// wraps a 1024² print of bands and blocks around it.
pub fn textured_box(size_m: [f32; 3], n: u32) -> Mesh {
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

/// The box at Z = 0.6 m turned so that three faces show.
pub fn pose() -> Pose {
    Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 0.6),
        UnitQuaternion::from_euler_angles(0.15, 0.35, 0.05),
    )
}
