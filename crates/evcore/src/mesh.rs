//! Triangle meshes of tracked objects, with grayscale appearance for rendering.
//!
//! Vertices are in metres in the object frame. Appearance is linear intensity (0 = black, 1 = white):
//! a constant, one value per vertex, or a texture addressed by per-vertex UVs.

use crate::error::{ensure, Result};
use nalgebra::Vector3;

/// A grayscale texture of linear intensity in 0..1, row-major. Row 0 is the top of the image
/// (v = 1), the convention of image files and of trimesh/OBJ UVs.
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    pub width: u32,
    pub height: u32,
    pub data: Vec<f32>,
}

impl Texture {
    /// Bilinear sample at texture coordinates (u, v), u to the right, v up, texel centres at
    /// ((i + 0.5) / width, 1 − (j + 0.5) / height). Coordinates outside 0..1 clamp to the border,
    /// because UV atlases put unrelated content next to each island.
    #[inline]
    pub fn sample(&self, u: f32, v: f32) -> f32 {
        let (w, h) = (self.width as usize, self.height as usize);
        let x = (u.clamp(0.0, 1.0) * w as f32 - 0.5).clamp(0.0, (w - 1) as f32);
        let y = ((1.0 - v.clamp(0.0, 1.0)) * h as f32 - 0.5).clamp(0.0, (h - 1) as f32);
        let (x0, y0) = (x as usize, y as usize);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let row0 = &self.data[y0 * w..];
        let row1 = &self.data[y1 * w..];
        let top = row0[x0] + (row0[x1] - row0[x0]) * fx;
        let bottom = row1[x0] + (row1[x1] - row1[x0]) * fx;
        top + (bottom - top) * fy
    }
}

/// How a mesh's surface albedo (linear intensity) is defined.
#[derive(Debug, Clone, PartialEq)]
pub enum Shading {
    /// One albedo for the whole surface.
    Constant(f32),
    /// One albedo per vertex, interpolated across faces.
    VertexIntensity(Vec<f32>),
    /// One UV per vertex into a texture.
    Textured { uv: Vec<[f32; 2]>, texture: Texture },
}

#[derive(Debug, Clone, PartialEq)]
pub struct Mesh {
    /// Vertex positions in metres, object frame.
    pub vertices: Vec<[f32; 3]>,
    /// Triangles as vertex indices. Winding is free: the renderer shades both sides.
    pub faces: Vec<[u32; 3]>,
    pub shading: Shading,
}

fn vec3(p: &[f32; 3]) -> Vector3<f64> {
    Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
}

impl Mesh {
    /// A sphere holding every vertex: (centre in the object frame, radius), both metres: the
    /// sphere around the vertices' bounding box (one pass, cheap enough to take per frame).
    pub fn bounding_sphere(&self) -> (Vector3<f64>, f64) {
        let (mut lo, mut hi) = (self.vertices[0], self.vertices[0]);
        for v in &self.vertices {
            for k in 0..3 {
                lo[k] = lo[k].min(v[k]);
                hi[k] = hi[k].max(v[k]);
            }
        }
        let (lo, hi) = (vec3(&lo), vec3(&hi));
        // Grown by a relative 1e-6 so that f32 vertices on the box corners stay inside.
        (
            0.5 * (lo + hi),
            0.5 * (hi - lo).norm() * (1.0 + 1e-6) + 1e-9,
        )
    }

    /// Validates everything the renderer relies on, so that rendering never has to check again:
    /// at least one vertex and face, finite coordinates, indices in range, per-vertex arrays as
    /// long as `vertices`, albedos finite and non-negative, and a total area above 1e-10 m².
    pub fn new(vertices: Vec<[f32; 3]>, faces: Vec<[u32; 3]>, shading: Shading) -> Result<Self> {
        ensure(!vertices.is_empty(), || "mesh has no vertices".into())?;
        ensure(!faces.is_empty(), || "mesh has no faces".into())?;
        if let Some(i) = vertices
            .iter()
            .position(|v| v.iter().any(|c| !c.is_finite()))
        {
            return Err(crate::Error::InvalidArgument(format!(
                "mesh vertex {i} is not finite: {:?}",
                vertices[i]
            )));
        }
        let n = vertices.len();
        if let Some(f) = faces
            .iter()
            .position(|f| f.iter().any(|&k| k as usize >= n))
        {
            return Err(crate::Error::InvalidArgument(format!(
                "mesh face {f} {:?} indexes past the {n} vertices",
                faces[f]
            )));
        }
        let albedo_ok = |a: f32| a.is_finite() && a >= 0.0;
        match &shading {
            Shading::Constant(a) => ensure(albedo_ok(*a), || {
                format!("constant intensity {a} must be finite and >= 0")
            })?,
            Shading::VertexIntensity(vals) => {
                ensure(vals.len() == n, || {
                    format!("{} vertex intensities for {n} vertices", vals.len())
                })?;
                ensure(vals.iter().all(|&a| albedo_ok(a)), || {
                    "vertex intensities must be finite and >= 0".into()
                })?;
            }
            Shading::Textured { uv, texture } => {
                ensure(uv.len() == n, || {
                    format!("{} UVs for {n} vertices", uv.len())
                })?;
                ensure(uv.iter().flatten().all(|c| c.is_finite()), || {
                    "UVs must be finite".into()
                })?;
                let (w, h) = (texture.width as usize, texture.height as usize);
                ensure(w > 0 && h > 0 && texture.data.len() == w * h, || {
                    format!(
                        "texture {w}x{h} needs {} values, got {}",
                        w * h,
                        texture.data.len()
                    )
                })?;
                ensure(texture.data.iter().all(|&a| albedo_ok(a)), || {
                    "texture values must be finite and >= 0".into()
                })?;
            }
        }
        let mesh = Self {
            vertices,
            faces,
            shading,
        };
        let area = mesh.area_m2();
        ensure(area > 1e-10, || {
            format!("mesh is degenerate: total area {area:.3e} m² (all faces collapsed)")
        })?;
        Ok(mesh)
    }

    /// Total surface area in m².
    pub fn area_m2(&self) -> f64 {
        self.faces.iter().map(|f| self.face_area_m2(f)).sum()
    }

    fn face_area_m2(&self, f: &[u32; 3]) -> f64 {
        let [a, b, c] = f.map(|k| vec3(&self.vertices[k as usize]));
        0.5 * (b - a).cross(&(c - a)).norm()
    }

    /// Radius in metres of the smallest sphere centred on the object-frame origin that holds
    /// every vertex (the tracker's bound on the object's image extent).
    pub fn bounding_radius(&self) -> f64 {
        self.vertices
            .iter()
            .map(|v| vec3(v).norm())
            .fold(0.0, f64::max)
    }

    /// Area-weighted centroid of the surface in the object frame (metres); weighting by area keeps
    /// it independent of how finely each part is tessellated.
    pub fn centroid(&self) -> Vector3<f64> {
        let (mut sum, mut total) = (Vector3::zeros(), 0.0);
        for f in &self.faces {
            let area = self.face_area_m2(f);
            let c = f
                .iter()
                .map(|&k| vec3(&self.vertices[k as usize]))
                .sum::<Vector3<f64>>()
                / 3.0;
            sum += c * area;
            total += area;
        }
        sum / total
    }
}

/// Cube of edge `edge_m` centred on the object origin, outward-wound, for tests across modules.
#[cfg(test)]
pub(crate) fn test_cube(edge_m: f32, shading: Shading) -> Mesh {
    let h = edge_m / 2.0;
    let v: Vec<[f32; 3]> = (0..8)
        .map(|i| {
            [
                if i & 1 == 0 { -h } else { h },
                if i & 2 == 0 { -h } else { h },
                if i & 4 == 0 { -h } else { h },
            ]
        })
        .collect();
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let f = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    Mesh::new(v, f, shading).expect("a cube is a valid mesh")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad() -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        (
            vec![
                [0.0, 0.0, 0.0],
                [0.2, 0.0, 0.0],
                [0.2, 0.1, 0.0],
                [0.0, 0.1, 0.0],
            ],
            vec![[0, 1, 2], [0, 2, 3]],
        )
    }

    #[test]
    fn area_centroid_radius_of_a_rectangle() {
        let (v, f) = quad();
        let m = Mesh::new(v, f, Shading::Constant(0.5)).unwrap();
        assert!((m.area_m2() - 0.02).abs() < 1e-9);
        let c = m.centroid();
        assert!((c - Vector3::new(0.1, 0.05, 0.0)).norm() < 1e-7, "{c}");
        assert!((m.bounding_radius() - (0.2f64.powi(2) + 0.1f64.powi(2)).sqrt()).abs() < 1e-7);
    }

    #[test]
    fn rejects_bad_meshes() {
        let (v, f) = quad();
        assert!(Mesh::new(vec![], f.clone(), Shading::Constant(0.5)).is_err());
        assert!(Mesh::new(v.clone(), vec![], Shading::Constant(0.5)).is_err());
        let mut nan = v.clone();
        nan[2][1] = f32::NAN;
        assert!(Mesh::new(nan, f.clone(), Shading::Constant(0.5)).is_err());
        assert!(Mesh::new(v.clone(), vec![[0, 1, 4]], Shading::Constant(0.5)).is_err());
        assert!(Mesh::new(v.clone(), f.clone(), Shading::VertexIntensity(vec![0.5; 3])).is_err());
        assert!(Mesh::new(v.clone(), f.clone(), Shading::Constant(f32::NAN)).is_err());
        let tex = Texture {
            width: 2,
            height: 2,
            data: vec![0.0; 3],
        };
        assert!(Mesh::new(
            v.clone(),
            f.clone(),
            Shading::Textured {
                uv: vec![[0.0; 2]; 4],
                texture: tex
            }
        )
        .is_err());
        let collinear = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]];
        let err = Mesh::new(collinear, vec![[0, 1, 2]], Shading::Constant(0.5)).unwrap_err();
        assert!(err.to_string().contains("degenerate"), "{err}");
    }

    #[test]
    fn texture_samples_rows_top_down_and_clamps() {
        // Top row dark, bottom row bright: v = 1 is the top.
        let t = Texture {
            width: 2,
            height: 2,
            data: vec![0.0, 0.0, 1.0, 1.0],
        };
        assert_eq!(t.sample(0.25, 0.75), 0.0);
        assert_eq!(t.sample(0.25, 0.25), 1.0);
        assert!((t.sample(0.5, 0.5) - 0.5).abs() < 1e-6);
        assert_eq!(t.sample(-3.0, 7.0), 0.0);
    }
}
