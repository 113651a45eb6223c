//! The model point set S* (paper §III-A): rendered once at the initial pose, its edge pixels
//! back-projected with the rendered depth and kept in the object frame, so that the tracker can
//! warp them by any later pose.
//!
//! An edge pixel is a foreground pixel with a 4-neighbour that is background or farther by more
//! than `depth_jump_m` (silhouette or occlusion boundary), whose normal differs from a neighbour's
//! by more than `crease_deg` (crease), or where the rendered intensity gradient exceeds
//! `texture_grad` (print and albedo edges). Silhouette and depth jumps take the nearer pixel, so
//! every point lies on the surface that is actually seen.

use crate::camera::Camera;
use crate::error::{ensure, Error, Result};
use crate::mesh::Mesh;
use crate::render::{render, RenderOptions, Rendered};
use crate::rng::Rng;
use crate::se3::Pose;
use nalgebra::Point3;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointSetParams {
    /// Upper bound on the number of points kept.
    pub max_points: usize,
    /// Depth step (metres) between 4-neighbours that counts as an occlusion boundary.
    pub depth_jump_m: f32,
    /// Angle (degrees) between neighbouring normals that counts as a crease. Above the facet
    /// angle of tessellated curved surfaces, so that spheres and cylinders give no false creases.
    pub crease_deg: f32,
    /// Rendered-intensity gradient magnitude (intensity units per pixel, central differences)
    /// that counts as a texture edge.
    pub texture_grad: f32,
    /// Seed of the subsampling.
    pub seed: u64,
}

impl Default for PointSetParams {
    fn default() -> Self {
        Self {
            max_points: 1000,
            depth_jump_m: 0.01,
            crease_deg: 30.0,
            texture_grad: 0.08,
            seed: 0,
        }
    }
}

/// Why a pixel is an edge; when several apply, the first in this order wins.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum EdgeKind {
    Silhouette = 0,
    Crease = 1,
    Texture = 2,
}

#[derive(Debug, Clone, PartialEq)]
pub struct PointSet {
    /// Points on the model surface in metres, object frame.
    pub points_o: Vec<[f32; 3]>,
    /// Kind of edge each point came from.
    pub kinds: Vec<EdgeKind>,
}

/// Edge pixels of a render as (x, y, kind), in image coordinates, row-major order.
fn edge_pixels(r: &Rendered, params: &PointSetParams) -> Vec<(u32, u32, EdgeKind)> {
    let (w, h) = (r.roi.width as usize, r.roi.height as usize);
    let cos_crease = params.crease_deg.to_radians().cos();
    let mut edges = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if !r.is_foreground(i) {
                continue;
            }
            let d = r.depth_m[i];
            let n = r.normal_c[i];
            let neighbours = [
                (x > 0).then(|| i - 1),
                (x + 1 < w).then(|| i + 1),
                (y > 0).then(|| i - w),
                (y + 1 < h).then(|| i + w),
            ];
            let mut kind = None;
            // A neighbour counts as "the same surface" if it is foreground without a depth jump;
            // the texture gradient is only trusted when all four are.
            let mut smooth = 0;
            for q in neighbours.into_iter().flatten() {
                let dq = r.depth_m[q];
                if dq - d > params.depth_jump_m {
                    kind = Some(EdgeKind::Silhouette);
                    break;
                }
                if (dq - d).abs() > params.depth_jump_m {
                    continue;
                }
                smooth += 1;
                let m = r.normal_c[q];
                if n[0] * m[0] + n[1] * m[1] + n[2] * m[2] < cos_crease {
                    kind = Some(EdgeKind::Crease);
                }
            }
            if kind.is_none() && smooth == 4 {
                let gx = 0.5 * (r.intensity[i + 1] - r.intensity[i - 1]);
                let gy = 0.5 * (r.intensity[i + w] - r.intensity[i - w]);
                if gx * gx + gy * gy > params.texture_grad * params.texture_grad {
                    kind = Some(EdgeKind::Texture);
                }
            }
            if let Some(k) = kind {
                edges.push((r.roi.x0 + x as u32, r.roi.y0 + y as u32, k));
            }
        }
    }
    edges
}

/// Deterministic, spatially even subset of at most `max` of `pixels`: shuffle by `seed`, then
/// greedily keep pixels at least `r` apart, shrinking `r` until `max` fit. Plain shuffle-and-cap
/// would follow the edge-pixel density, which is doubled along two-pixel-wide creases.
fn thin(pixels: &[(u32, u32, EdgeKind)], max: usize, seed: u64) -> Vec<usize> {
    let mut order: Vec<usize> = (0..pixels.len()).collect();
    let mut rng = Rng::new(seed);
    for i in (1..order.len()).rev() {
        order.swap(i, rng.below(i as u64 + 1) as usize);
    }
    if order.len() <= max {
        return order;
    }
    let x_max = pixels.iter().map(|p| p.0).max().unwrap_or(0) as usize;
    let y_max = pixels.iter().map(|p| p.1).max().unwrap_or(0) as usize;
    // Edges are curves about one pixel wide, so n pixels spread over max points are n/max apart.
    let mut r = pixels.len() as f64 / max as f64;
    let mut grid = Vec::new();
    while r >= 1.0 {
        // Cells of side r/√2 hold at most one kept pixel, and a pixel closer than r to a kept
        // one lies within two cells of it.
        let cell = r / std::f64::consts::SQRT_2;
        let (gw, gh) = (
            (x_max as f64 / cell) as usize + 1,
            (y_max as f64 / cell) as usize + 1,
        );
        grid.clear();
        grid.resize(gw * gh, usize::MAX);
        let mut kept = Vec::with_capacity(max);
        for &k in &order {
            let (x, y) = (f64::from(pixels[k].0), f64::from(pixels[k].1));
            let (cx, cy) = ((x / cell) as usize, (y / cell) as usize);
            let near = (cy.saturating_sub(2)..(cy + 3).min(gh))
                .flat_map(|gy| (cx.saturating_sub(2)..(cx + 3).min(gw)).map(move |gx| gy * gw + gx))
                .any(|g| {
                    let j = grid[g];
                    j != usize::MAX
                        && (f64::from(pixels[j].0) - x).powi(2)
                            + (f64::from(pixels[j].1) - y).powi(2)
                            < r * r
                });
            if !near {
                grid[cy * gw + cx] = k;
                kept.push(k);
                if kept.len() == max {
                    return kept;
                }
            }
        }
        // The kept count grows like 1/r along curves; aim a little past `max` so the next pass fills.
        r *= (0.95 * kept.len() as f64 / max as f64).clamp(0.5, 0.95);
    }
    order.truncate(max);
    order
}

/// S* from one render of `mesh` at `t_c_o` (object in camera) in the camera's rectified grid.
pub fn extract_point_set(
    mesh: &Mesh,
    camera: &Camera,
    t_c_o: &Pose,
    params: &PointSetParams,
) -> Result<PointSet> {
    ensure(params.max_points > 0, || {
        "max_points must be positive".into()
    })?;
    ensure(
        params.depth_jump_m.is_finite() && params.depth_jump_m > 0.0,
        || {
            format!(
                "depth_jump_m must be finite and positive, got {}",
                params.depth_jump_m
            )
        },
    )?;
    ensure(
        params.crease_deg.is_finite() && params.crease_deg > 0.0 && params.crease_deg < 180.0,
        || format!("crease_deg must be in (0, 180), got {}", params.crease_deg),
    )?;
    ensure(
        params.texture_grad.is_finite() && params.texture_grad > 0.0,
        || {
            format!(
                "texture_grad must be finite and positive, got {}",
                params.texture_grad
            )
        },
    )?;
    let t = t_c_o.translation.vector;
    // A camera inside the object's bounding box sees the object's inside all around: there is no
    // outline to track, and the edge count below would blame size or distance.
    let c_o = t_c_o.inverse() * Point3::origin();
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for v in &mesh.vertices {
        for i in 0..3 {
            lo[i] = lo[i].min(f64::from(v[i]));
            hi[i] = hi[i].max(f64::from(v[i]));
        }
    }
    ensure(!(0..3).all(|i| c_o[i] > lo[i] && c_o[i] < hi[i]), || {
        format!(
            "the camera is inside the object: T_c_o translation ({:.3}, {:.3}, {:.3}) m puts the camera at \
             ({:.3}, {:.3}, {:.3}) m in the object frame, within its bounding box",
            t.x, t.y, t.z, c_o.x, c_o.y, c_o.z
        )
    })?;
    let cam = camera.rectified();
    let r = render(mesh, &cam, t_c_o, None, &RenderOptions::default())?;
    let fg: Vec<f32> = r
        .depth_m
        .iter()
        .copied()
        .filter(|d| d.is_finite())
        .collect();
    if fg.is_empty() {
        return Err(Error::InvalidArgument(format!(
            "object not in view: nothing rendered at T_c_o translation ({:.3}, {:.3}, {:.3}) m in the {}x{} image",
            t.x, t.y, t.z, cam.width, cam.height
        )));
    }
    let edges = edge_pixels(&r, params);
    if edges.len() < 20 {
        let (lo, hi) = fg.iter().fold((f32::INFINITY, 0.0f32), |(lo, hi), &d| {
            (lo.min(d), hi.max(d))
        });
        // An object covering (nearly) the whole image has its outline outside it: too close.
        let why = if fg.len() as f64 >= 0.9 * f64::from(cam.width) * f64::from(cam.height) {
            "the object fills the view: it is too close"
        } else {
            "the object is too small, too far or mostly out of view"
        };
        return Err(Error::InvalidArgument(format!(
            "only {} edge pixels (need 20) at T_c_o translation ({:.3}, {:.3}, {:.3}) m, depth {lo:.3}..{hi:.3} m over {} \
             pixels: {why}",
            edges.len(),
            t.x,
            t.y,
            t.z,
            fg.len()
        )));
    }
    let t_o_c = t_c_o.inverse();
    let (mut points_o, mut kinds) = (Vec::new(), Vec::new());
    for k in thin(&edges, params.max_points, params.seed) {
        let (x, y, kind) = edges[k];
        let i = (y - r.roi.y0) as usize * r.roi.width as usize + (x - r.roi.x0) as usize;
        let p_c = cam.ray(f64::from(x), f64::from(y)) * f64::from(r.depth_m[i]);
        let p_o = t_o_c * Point3::from(p_c);
        points_o.push([p_o.x as f32, p_o.y as f32, p_o.z as f32]);
        kinds.push(kind);
    }
    Ok(PointSet { points_o, kinds })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{test_cube, Shading, Texture};
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
    use std::collections::{HashMap, HashSet};

    fn cam() -> Camera {
        Camera::new(
            640,
            480,
            600.0,
            610.0,
            322.4,
            236.9,
            [-0.3, 0.1, 0.0, 0.0, 0.0],
        )
        .unwrap()
    }

    fn pose(z: f64) -> Pose {
        Isometry3::from_parts(
            Translation3::new(0.02, -0.01, z),
            UnitQuaternion::from_euler_angles(0.5, 0.6, 0.2),
        )
    }

    /// 0.2 m cube whose faces carry a dark vertical band in the middle of a light print.
    fn printed_cube() -> Mesh {
        let m = test_cube(0.2, Shading::Constant(0.5));
        let uv = m
            .vertices
            .iter()
            .map(|v| [v[0] / 0.2 + v[2] / 0.4 + 0.5, v[1] / 0.2 + 0.5])
            .collect();
        // Fine enough that bilinear magnification keeps the band's edges sharp on screen.
        let data = (0..256)
            .map(|i| if (96..160).contains(&i) { 0.05 } else { 0.9 })
            .collect();
        let texture = Texture {
            width: 256,
            height: 1,
            data,
        };
        Mesh::new(m.vertices, m.faces, Shading::Textured { uv, texture }).unwrap()
    }

    #[test]
    fn points_lie_on_the_surface_and_reproject_onto_edge_pixels() {
        let (mesh, cam, t_c_o) = (printed_cube(), cam(), pose(0.7));
        let params = PointSetParams::default();
        let set = extract_point_set(&mesh, &cam, &t_c_o, &params).unwrap();
        assert_eq!(set.points_o.len(), 1000);
        let kinds: HashSet<EdgeKind> = set.kinds.iter().copied().collect();
        assert_eq!(
            kinds.len(),
            3,
            "silhouette, crease and texture points expected, got {kinds:?}"
        );
        let r = render(
            &mesh,
            &cam.rectified(),
            &t_c_o,
            None,
            &RenderOptions::default(),
        )
        .unwrap();
        let edges: HashMap<(u32, u32), EdgeKind> = edge_pixels(&r, &params)
            .into_iter()
            .map(|(x, y, k)| ((x, y), k))
            .collect();
        for (p, kind) in set.points_o.iter().zip(&set.kinds) {
            // On the cube surface: the largest coordinate magnitude is the half edge.
            let on_face = p.iter().fold(0.0f32, |m, c| m.max(c.abs()));
            assert!(
                (on_face - 0.1).abs() < 1e-3,
                "{p:?} is {} m off the surface",
                (on_face - 0.1).abs()
            );
            let p_c = t_c_o * Point3::from(Vector3::from(p.map(f64::from)));
            let (u, v) = cam.project_pinhole(&p_c.coords).unwrap();
            let (px, py) = (u.round(), v.round());
            assert!(
                (u - px).hypot(v - py) < 0.01,
                "({u}, {v}) is not a pixel centre"
            );
            assert_eq!(edges.get(&(px as u32, py as u32)), Some(kind), "({u}, {v})");
        }
    }

    #[test]
    fn subsampling_is_deterministic_and_spread_out() {
        let (mesh, cam, t_c_o) = (printed_cube(), cam(), pose(0.9));
        let params = PointSetParams {
            max_points: 150,
            seed: 3,
            ..Default::default()
        };
        let a = extract_point_set(&mesh, &cam, &t_c_o, &params).unwrap();
        assert_eq!(a, extract_point_set(&mesh, &cam, &t_c_o, &params).unwrap());
        let b =
            extract_point_set(&mesh, &cam, &t_c_o, &PointSetParams { seed: 4, ..params }).unwrap();
        assert_eq!(b.points_o.len(), 150);
        assert_ne!(a.points_o, b.points_o);
        let px: Vec<(f64, f64)> = a
            .points_o
            .iter()
            .map(|p| {
                cam.project_pinhole(&(t_c_o * Point3::from(Vector3::from(p.map(f64::from)))).coords)
                    .unwrap()
            })
            .collect();
        let min_gap = (0..px.len())
            .flat_map(|i| (0..i).map(move |j| (i, j)))
            .map(|(i, j)| (px[i].0 - px[j].0).hypot(px[i].1 - px[j].1))
            .fold(f64::INFINITY, f64::min);
        // A plain random pick of 150 from a few thousand edge pixels would put some within 1 px.
        assert!(
            min_gap >= 4.0,
            "closest two points are {min_gap:.2} px apart"
        );
    }

    #[test]
    fn out_of_view_tiny_and_bad_parameters_are_errors() {
        let (mesh, cam) = (printed_cube(), cam());
        let p = PointSetParams::default();
        let behind = Isometry3::translation(0.0, 0.0, -1.0);
        let err = extract_point_set(&mesh, &cam, &behind, &p).unwrap_err();
        assert!(err.to_string().contains("not in view"), "{err}");
        let far = Isometry3::translation(0.0, 0.0, 40.0);
        let err = extract_point_set(&mesh, &cam, &far, &p).unwrap_err();
        assert!(err.to_string().contains("edge pixels"), "{err}");
        let t = pose(0.7);
        assert!(
            extract_point_set(&mesh, &cam, &t, &PointSetParams { max_points: 0, ..p }).is_err()
        );
        assert!(extract_point_set(
            &mesh,
            &cam,
            &t,
            &PointSetParams {
                crease_deg: f32::NAN,
                ..p
            }
        )
        .is_err());
        assert!(extract_point_set(
            &mesh,
            &cam,
            &t,
            &PointSetParams {
                depth_jump_m: -1.0,
                ..p
            }
        )
        .is_err());
        assert!(extract_point_set(
            &mesh,
            &cam,
            &t,
            &PointSetParams {
                texture_grad: 0.0,
                ..p
            }
        )
        .is_err());
    }
}
