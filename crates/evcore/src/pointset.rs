//! The model point set S* (paper §III-A): rendered once at the initial pose, its edge pixels
//! back-projected with the rendered depth and kept in the object frame, so that the tracker can
//! warp them by any later pose.
//!
//! An edge pixel is a foreground pixel with a 4-neighbour that is background or farther by more
//! than `depth_jump_m` (silhouette or occlusion boundary), whose normal differs from a neighbour's
//! by more than `crease_deg` with a rendered brightness step of at least `crease_contrast` across
//! (crease: one whose faces render alike fires no events), or where the rendered intensity gradient exceeds
//! `texture_grad` (print and albedo edges). Silhouette and depth jumps take the nearer pixel, so
//! every point lies at the depth of the surface that is actually seen; its point is placed half a
//! pixel outwards, on the outline's expected place rather than the pixel's centre
//! ([`outline_offset`]).
//!
//! Which edge pixels become points: a share `1 − balance` is spread evenly over the image (a part
//! hidden or out of view then takes only its share of the points with it); the rest is chosen for
//! the constraints it adds, greedily shrinking the variance of the pose the set determines (each
//! point constrains its image motion across its edge, n·∂u/∂ξ). The balanced share raises the
//! weakest direction's information (tests below) but concentrates points where few edges carry
//! it, and on the objects suite that cost more under occlusion and partial views than it gained
//! (benches/RESULTS.md, issue 13: part 30 % occluded 12 → 99 mm with half the points balanced), so
//! the default is 0: evenly spread.

use crate::camera::Camera;
use crate::error::{ensure, Error, Result};
use crate::mesh::Mesh;
use crate::render::{render, RenderOptions, Rendered};
use crate::rng::Rng;
use crate::se3::Pose;
use crate::solve::cost::{image_jacobian, Pinhole};
use nalgebra::{Matrix2, Matrix6, Point3, Vector3, Vector6};
use std::cmp::Ordering;
use std::collections::BinaryHeap;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointSetParams {
    /// Upper bound on the number of points kept.
    pub max_points: usize,
    /// Depth step (metres) between 4-neighbours that counts as an occlusion boundary.
    pub depth_jump_m: f32,
    /// Angle (degrees) between neighbouring normals that counts as a crease. Above the facet
    /// angle of tessellated curved surfaces, so that spheres and cylinders give no false creases.
    pub crease_deg: f32,
    /// Step in rendered log intensity (natural log) a crease must show to count: an event camera
    /// sees only brightness steps, and a crease both of whose faces render alike fires nothing.
    pub crease_contrast: f32,
    /// Rendered-intensity gradient magnitude (intensity units per pixel, central differences)
    /// that counts as a texture edge.
    pub texture_grad: f32,
    /// Share of the points chosen for the constraints they add rather than spread evenly, in
    /// [0, 1] (see the module doc; 0 by default).
    pub balance: f32,
    /// Seed of the subsampling.
    pub seed: u64,
}

impl Default for PointSetParams {
    fn default() -> Self {
        Self {
            max_points: 1000,
            depth_jump_m: 0.01,
            crease_deg: 30.0,
            // Half the sensor's typical contrast threshold (0.2, see `sim::params`): a step that
            // small fires hardly ever; the plate's unlit rim creases render below 0.1.
            crease_contrast: 0.1,
            texture_grad: 0.08,
            balance: 0.0,
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
                if n[0] * m[0] + n[1] * m[1] + n[2] * m[2] < cos_crease
                    && log_step(r.intensity[i], r.intensity[q]) >= params.crease_contrast
                {
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

/// Step between two rendered intensities in log units, as the event camera's pixels compare them
/// (`LOG_EPS` keeps black finite).
fn log_step(a: f32, b: f32) -> f32 {
    const LOG_EPS: f32 = 1e-3;
    ((a + LOG_EPS) / (b + LOG_EPS)).ln().abs()
}

/// Where the outline through silhouette pixel `i` of render `r` lies, relative to the pixel's
/// centre (pixels): halfway to its background (or farther, by more than `depth_jump_m`)
/// 4-neighbours, averaged over them.
///
/// Why: the renderer samples pixel centres, so the last centre inside an outline lies 0 to 1
/// pixel spacing inside it, half a pixel on average, while the camera's events fire where the
/// outline crosses a centre, i.e. on the outline itself. Points at the centres made the model's
/// outline half a pixel too small all round, which the solvers read as the object being nearer
/// than it is: 0.5 px on a 40 px wide object is 2.5 % of its depth (30 mm at 1.2 m). Halfway to
/// the outer neighbour is the outline's expected place for an edge along a pixel axis; for one
/// at 45° both outer neighbours count and the mean step across it is again the expected 0.35 px.
fn outline_offset(r: &Rendered, i: usize, depth_jump_m: f32) -> [f64; 2] {
    let w = r.roi.width as usize;
    let (x, y) = (i % w, i / w);
    let d = r.depth_m[i];
    let steps = [
        (x > 0).then(|| (i - 1, [-1.0, 0.0])),
        (x + 1 < w).then(|| (i + 1, [1.0, 0.0])),
        (y > 0).then(|| (i - w, [0.0, -1.0])),
        (i + w < r.depth_m.len()).then(|| (i + w, [0.0, 1.0])),
    ];
    let (mut sum, mut n) = ([0.0, 0.0], 0.0);
    for (q, [sx, sy]) in steps.into_iter().flatten() {
        if r.depth_m[q] - d > depth_jump_m {
            sum = [sum[0] + sx, sum[1] + sy];
            n += 1.0;
        }
    }
    if n == 0.0 {
        return [0.0, 0.0];
    }
    [0.5 * sum[0] / n, 0.5 * sum[1] / n]
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

/// Unit normal of the edge curve through edge pixel `k` (image coordinates), from the spread of
/// the edge pixels within two pixels of it; `None` where they do not line up (a corner or a
/// blob), which constrains the image motion both ways.
fn edge_normal(is_edge: &[bool], w: usize, h: usize, x: usize, y: usize) -> Option<[f64; 2]> {
    let (mut sxx, mut sxy, mut syy, mut n) = (0.0, 0.0, 0.0, 0.0);
    for yy in y.saturating_sub(2)..(y + 3).min(h) {
        for xx in x.saturating_sub(2)..(x + 3).min(w) {
            if is_edge[yy * w + xx] {
                let (dx, dy) = (xx as f64 - x as f64, yy as f64 - y as f64);
                (sxx, sxy, syy, n) = (sxx + dx * dx, sxy + dx * dy, syy + dy * dy, n + 1.0);
            }
        }
    }
    if n < 3.0 {
        return None;
    }
    // Eigenvalues of the 2×2 scatter; the tangent is the larger one's eigenvector.
    let (m, d) = (
        0.5 * (sxx + syy),
        (0.25 * (sxx - syy).powi(2) + sxy * sxy).sqrt(),
    );
    let (big, small) = (m + d, m - d);
    if big <= 0.0 || small > 0.3 * big {
        return None;
    }
    let (tx, ty) = if sxy.abs() > 1e-12 {
        (sxy, big - sxx)
    } else if sxx >= syy {
        (1.0, 0.0)
    } else {
        (0.0, 1.0)
    };
    let norm = tx.hypot(ty);
    Some([-ty / norm, tx / norm])
}

/// What one candidate point tells about the pose: up to two rows of image motion per unit twist
/// (about the candidates' centroid, translation scaled by their radius); one row, across the
/// edge, where the edge has a direction.
struct Constraint {
    rows: [Vector6<f64>; 2],
}

impl Constraint {
    /// How much the point shrinks tr(P), P the inverse of the information so far (the summed
    /// variance of the pose, A-optimal design): tr(P Aᵀ (I + A P Aᵀ)⁻¹ A P). Unlike the
    /// log-determinant, this weighs a direction by how uncertain it still is, so the weakest
    /// direction is served first.
    fn gain(&self, p: &Matrix6<f64>) -> f64 {
        let pa = [*p * self.rows[0], *p * self.rows[1]];
        let Some(si) = (Matrix2::identity() + self.projected(p)).try_inverse() else {
            return 0.0;
        };
        (0..2)
            .flat_map(|i| (0..2).map(move |j| (i, j)))
            .map(|(i, j)| si[(i, j)] * pa[i].dot(&pa[j]))
            .sum()
    }

    fn projected(&self, p: &Matrix6<f64>) -> Matrix2<f64> {
        Matrix2::from_fn(|i, j| self.rows[i].dot(&(p * self.rows[j])))
    }

    /// Adds the point to the information whose inverse is `p` (Woodbury).
    fn absorb(&self, p: &mut Matrix6<f64>) {
        let pa = [*p * self.rows[0], *p * self.rows[1]];
        let s = Matrix2::identity() + self.projected(p);
        let Some(si) = s.try_inverse() else { return };
        for i in 0..2 {
            for j in 0..2 {
                *p -= pa[i] * pa[j].transpose() * si[(i, j)];
            }
        }
    }
}

/// Image-motion constraints of edge pixels `chosen` of render `r` (camera `cam`).
fn constraints(
    r: &Rendered,
    cam: &Camera,
    pixels: &[(u32, u32, EdgeKind)],
    chosen: &[usize],
) -> Vec<Constraint> {
    let (w, h) = (r.roi.width as usize, r.roi.height as usize);
    let mut is_edge = vec![false; w * h];
    for &(x, y, _) in pixels {
        is_edge[(y - r.roi.y0) as usize * w + (x - r.roi.x0) as usize] = true;
    }
    let p_c: Vec<Vector3<f64>> = chosen
        .iter()
        .map(|&k| {
            let (x, y, _) = pixels[k];
            let i = (y - r.roi.y0) as usize * w + (x - r.roi.x0) as usize;
            cam.ray(f64::from(x), f64::from(y)) * f64::from(r.depth_m[i])
        })
        .collect();
    let n = p_c.len().max(1) as f64;
    let c = p_c.iter().sum::<Vector3<f64>>() / n;
    let radius = (p_c.iter().map(|p| (p - c).norm_squared()).sum::<f64>() / n)
        .sqrt()
        .max(1e-6);
    let pin = Pinhole::at_level(cam, 0);
    let pivot = [c.x as f32, c.y as f32, c.z as f32];
    chosen
        .iter()
        .zip(&p_c)
        .map(|(&k, p)| {
            let j = image_jacobian(&pin, [p.x as f32, p.y as f32, p.z as f32], pivot);
            let row = |r: usize| {
                Vector6::from_fn(|c, _| f64::from(j[r][c]) * if c < 3 { radius } else { 1.0 })
            };
            let (x, y, _) = pixels[k];
            let (u, v) = ((x - r.roi.x0) as usize, (y - r.roi.y0) as usize);
            let rows = match edge_normal(&is_edge, w, h, u, v) {
                Some([nx, ny]) => [row(0) * nx + row(1) * ny, Vector6::zeros()],
                None => [row(0) * 0.5f64.sqrt(), row(1) * 0.5f64.sqrt()],
            };
            Constraint { rows }
        })
        .collect()
}

/// A candidate's gain as of the information it was last scored against (`stamp` points taken).
struct Scored {
    gain: f64,
    candidate: usize,
    stamp: usize,
}

impl PartialEq for Scored {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == Ordering::Equal
    }
}
impl Eq for Scored {}
impl PartialOrd for Scored {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Scored {
    fn cmp(&self, o: &Self) -> Ordering {
        // Ties go to the earlier candidate (the shuffled order), so the choice is deterministic.
        self.gain
            .total_cmp(&o.gain)
            .then(o.candidate.cmp(&self.candidate))
    }
}

/// At most `max` of `pixels`: `1 − balance` of them evenly spread ([`thin`]), the rest picked one
/// by one from an evenly spread pool four times denser, each time the one that most shrinks the
/// pose's variance ([`Constraint::gain`]); a pick rules out the pool pixels within half the even
/// spacing of it, so that the points stay distinct edges rather than a clump. Gains shrink as
/// points are added, so a stale gain is an upper bound and most candidates are never rescored
/// (lazy greedy).
fn select(
    r: &Rendered,
    cam: &Camera,
    pixels: &[(u32, u32, EdgeKind)],
    max: usize,
    balance: f32,
    seed: u64,
) -> Vec<usize> {
    let n_info = ((max as f64) * f64::from(balance)).round() as usize;
    if pixels.len() <= max || n_info == 0 {
        return thin(pixels, max, seed);
    }
    let mut kept = thin(pixels, max - n_info, seed);
    let pool = thin(pixels, (4 * max).min(pixels.len()), seed.wrapping_add(1));
    let all: Vec<usize> = kept.iter().chain(&pool).copied().collect();
    let cons = constraints(r, cam, pixels, &all);
    let (base, cands) = cons.split_at(kept.len());
    // A weak prior keeps the information invertible before the points fill every direction.
    let scale = cons
        .iter()
        .map(|c| c.rows[0].norm_squared() + c.rows[1].norm_squared())
        .sum::<f64>()
        / cons.len().max(1) as f64;
    let mut p = Matrix6::identity() / (1e-3 * scale.max(1e-12));
    for c in base {
        c.absorb(&mut p);
    }
    // Edges are about a pixel wide: `max` points evenly along them are this far apart. Should the
    // pool run dry (the picks crowd one region), the exclusion radius halves and picking goes on.
    let mut gap = (0.5 * pixels.len() as f64 / max as f64).max(1.0);
    let mut chosen = vec![false; pool.len()];
    let mut stamp = 0;
    while kept.len() < max && gap >= 0.5 {
        let mut open: Vec<bool> = chosen.iter().map(|&c| !c).collect();
        let close_out = |k: usize, open: &mut [bool]| {
            let (x, y) = (f64::from(pixels[k].0), f64::from(pixels[k].1));
            for (i, &q) in pool.iter().enumerate() {
                let (dx, dy) = (f64::from(pixels[q].0) - x, f64::from(pixels[q].1) - y);
                if dx * dx + dy * dy < gap * gap {
                    open[i] = false;
                }
            }
        };
        kept.iter().for_each(|&k| close_out(k, &mut open));
        let mut heap: BinaryHeap<Scored> = (0..cands.len())
            .filter(|&i| open[i])
            .map(|i| Scored {
                gain: cands[i].gain(&p),
                candidate: i,
                stamp,
            })
            .collect();
        while kept.len() < max {
            let Some(top) = heap.pop() else { break };
            if !open[top.candidate] {
                continue;
            }
            if top.stamp == stamp {
                cands[top.candidate].absorb(&mut p);
                kept.push(pool[top.candidate]);
                chosen[top.candidate] = true;
                close_out(pool[top.candidate], &mut open);
                stamp += 1;
            } else {
                heap.push(Scored {
                    gain: cands[top.candidate].gain(&p),
                    stamp,
                    ..top
                });
            }
        }
        gap *= 0.5;
    }
    kept
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
        params.crease_contrast.is_finite() && params.crease_contrast >= 0.0,
        || {
            format!(
                "crease_contrast must be finite and non-negative, got {}",
                params.crease_contrast
            )
        },
    )?;
    ensure((0.0..=1.0).contains(&params.balance), || {
        format!("balance must be in [0, 1], got {}", params.balance)
    })?;
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
    for k in select(
        &r,
        &cam,
        &edges,
        params.max_points,
        params.balance,
        params.seed,
    ) {
        let (x, y, kind) = edges[k];
        let i = (y - r.roi.y0) as usize * r.roi.width as usize + (x - r.roi.x0) as usize;
        let [dx, dy] = match kind {
            EdgeKind::Silhouette => outline_offset(&r, i, params.depth_jump_m),
            EdgeKind::Crease | EdgeKind::Texture => [0.0, 0.0],
        };
        let p_c = cam.ray(f64::from(x) + dx, f64::from(y) + dy) * f64::from(r.depth_m[i]);
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
            let p_c = t_c_o * Point3::from(Vector3::from(p.map(f64::from)));
            let (u, v) = cam.project_pinhole(&p_c.coords).unwrap();
            // On the cube surface (the largest coordinate magnitude is the half edge); an outline
            // point may stand off it by its half-pixel step outwards, 0.5 px at its depth.
            let slack = match kind {
                EdgeKind::Silhouette => 0.5 * p_c.z / cam.fx,
                EdgeKind::Crease | EdgeKind::Texture => 0.0,
            };
            let on_face = f64::from(p.iter().fold(0.0f32, |m, c| m.max(c.abs())));
            assert!(
                (on_face - 0.1).abs() < 1e-3 + slack,
                "{p:?} is {} m off the surface",
                (on_face - 0.1).abs()
            );
            // Crease and texture points sit on their pixel's centre, outline points within half a
            // pixel of a silhouette pixel's centre.
            let reach = if *kind == EdgeKind::Silhouette {
                0.501
            } else {
                0.01
            };
            let hit = (-1..=1)
                .flat_map(|dy| {
                    (-1..=1).map(move |dx| (u.round() + dx as f64, v.round() + dy as f64))
                })
                .any(|(px, py)| {
                    (u - px).hypot(v - py) < reach
                        && edges.get(&(px as u32, py as u32)) == Some(kind)
                });
            assert!(hit, "({u}, {v}) is no {kind:?} pixel's point");
        }
    }

    /// A cube seen along its body diagonal under the headlight: its three faces render alike, so
    /// the creases between them fire no events and must give no points; the outline still does.
    #[test]
    fn creases_whose_faces_render_alike_give_no_points() {
        let cam = cam();
        let mesh = test_cube(0.2, Shading::Constant(0.5));
        let diagonal = UnitQuaternion::rotation_between(
            &Vector3::new(1.0, 1.0, 1.0),
            &Vector3::new(0.0, 0.0, -1.0),
        )
        .unwrap();
        let t_c_o = Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.7), diagonal);
        let set = extract_point_set(&mesh, &cam, &t_c_o, &PointSetParams::default()).unwrap();
        let count = |k: EdgeKind| set.kinds.iter().filter(|&&q| q == k).count();
        assert_eq!(count(EdgeKind::Crease), 0);
        assert!(
            count(EdgeKind::Silhouette) > 500,
            "{}",
            count(EdgeKind::Silhouette)
        );
        // Turned off the diagonal the faces differ in brightness and the creases count again.
        let turned = t_c_o * UnitQuaternion::from_euler_angles(0.0, 0.5, 0.0);
        let set = extract_point_set(&mesh, &cam, &turned, &PointSetParams::default()).unwrap();
        assert!(set.kinds.contains(&EdgeKind::Crease));
    }

    /// Signed distance (pixels, negative inside) of (u, v) from the convex polygon `corners`
    /// (image points in order around it).
    fn signed_distance_px(corners: &[(f64, f64)], (u, v): (f64, f64)) -> f64 {
        let n = corners.len();
        let area2: f64 = (0..n)
            .map(|i| {
                let ((x0, y0), (x1, y1)) = (corners[i], corners[(i + 1) % n]);
                x0 * y1 - x1 * y0
            })
            .sum();
        (0..n)
            .map(|i| {
                let ((x0, y0), (x1, y1)) = (corners[i], corners[(i + 1) % n]);
                let len = (x1 - x0).hypot(y1 - y0);
                // Outward normal for either winding.
                let cross = (x1 - x0) * (v - y0) - (y1 - y0) * (u - x0);
                -cross.signum() * area2.signum() * (cross.abs() / len)
            })
            .fold(f64::NEG_INFINITY, f64::max)
    }

    /// Events fire where an outline crosses a pixel centre, i.e. on the outline; S*'s outline points
    /// must sit there too, not half a pixel inside it (which reads as the object being nearer).
    #[test]
    fn outline_points_sit_on_the_outline_not_inside_it() {
        let cam = cam();
        let mesh = test_cube(0.2, Shading::Constant(0.5));
        for roll in [0.0, 0.35, std::f64::consts::FRAC_PI_4] {
            // Where an outline falls between pixel centres decides how far inside the last centre
            // is; eight sub-pixel shifts (1 px is 2 mm here) spread it evenly.
            let mut d = Vec::new();
            for k in 0..8 {
                let shift_m = 0.25e-3 * f64::from(k);
                // Face-on, 1.2 m away (a 100 px square): the outline is the front face's border.
                let t_c_o = Isometry3::from_parts(
                    Translation3::new(0.013 + shift_m, -0.007 + 0.7 * shift_m, 1.2),
                    UnitQuaternion::from_euler_angles(0.0, 0.0, roll),
                );
                let set =
                    extract_point_set(&mesh, &cam, &t_c_o, &PointSetParams::default()).unwrap();
                let corners: Vec<(f64, f64)> = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
                    .iter()
                    .map(|&(a, b)| {
                        let p = t_c_o * Point3::new(0.1 * a, 0.1 * b, -0.1);
                        cam.project_pinhole(&p.coords).unwrap()
                    })
                    .collect();
                d.extend(
                    set.points_o
                        .iter()
                        .zip(&set.kinds)
                        .filter(|(_, k)| **k == EdgeKind::Silhouette)
                        .map(|(p, _)| {
                            let p_c = t_c_o * Point3::from(Vector3::from(p.map(f64::from)));
                            signed_distance_px(&corners, cam.project_pinhole(&p_c.coords).unwrap())
                        }),
                );
            }
            assert!(d.len() > 1600, "{} outline points", d.len());
            let mean = d.iter().sum::<f64>() / d.len() as f64;
            // Pixel centres inside the outline sit 0.35-0.5 px inside it on average.
            assert!(
                mean.abs() < 0.1,
                "roll {roll}: outline points {mean:.3} px off the outline"
            );
        }
    }

    #[test]
    fn subsampling_is_deterministic_and_spread_out() {
        let (mesh, cam, t_c_o) = (printed_cube(), cam(), pose(0.9));
        // Evenly spread only: the balanced share may sit closer (its own test below).
        let params = PointSetParams {
            max_points: 150,
            seed: 3,
            balance: 0.0,
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

    /// Smallest eigenvalue of the information of `chosen` edge pixels (the scaled twist units of
    /// [`constraints`]): how well the weakest direction is pinned down.
    fn weakest(r: &Rendered, cam: &Camera, px: &[(u32, u32, EdgeKind)], chosen: &[usize]) -> f64 {
        constraints(r, cam, px, chosen)
            .iter()
            .fold(Matrix6::zeros(), |h, c| {
                h + c.rows[0] * c.rows[0].transpose() + c.rows[1] * c.rows[1].transpose()
            })
            .symmetric_eigenvalues()
            .min()
    }

    /// A plain bar 0.4 m long and 0.04 m across: sliding along it is seen only at its two short ends.
    fn bar() -> Mesh {
        let m = test_cube(1.0, Shading::Constant(0.5));
        let v = m
            .vertices
            .iter()
            .map(|v| [0.4 * v[0], 0.04 * v[1], 0.04 * v[2]])
            .collect();
        Mesh::new(v, m.faces, Shading::Constant(0.5)).unwrap()
    }

    #[test]
    fn balanced_points_constrain_the_weakest_direction_better_than_even_spacing() {
        let cam = cam().rectified();
        let bar_pose = Isometry3::from_parts(
            Translation3::new(0.0, 0.0, 0.8),
            UnitQuaternion::from_euler_angles(0.3, 0.2, 0.1),
        );
        for (mesh, t_c_o) in [(printed_cube(), pose(0.9)), (bar(), bar_pose)] {
            let r = render(&mesh, &cam, &t_c_o, None, &RenderOptions::default()).unwrap();
            let px = edge_pixels(&r, &PointSetParams::default());
            let even = thin(&px, 200, 0);
            let balanced = select(&r, &cam, &px, 200, 0.5, 0);
            assert_eq!(balanced.len(), 200);
            let distinct: HashSet<usize> = balanced.iter().copied().collect();
            assert_eq!(distinct.len(), 200, "a pixel was chosen twice");
            let (we, wb) = (
                weakest(&r, &cam, &px, &even),
                weakest(&r, &cam, &px, &balanced),
            );
            eprintln!(
                "{} px: weakest even {we:.3e} balanced {wb:.3e} ratio {:.2}",
                px.len(),
                wb / we
            );
            assert!(wb > 1.15 * we, "even {we:.3e}, balanced {wb:.3e}");
        }
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
