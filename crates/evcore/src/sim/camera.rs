//! A rendered event camera: object mesh + background → distorted linear-intensity frame →
//! [`EventSimulator`].
//!
//! Each [`SimCamera::advance`] renders the scene in a pinhole *canvas* (the rectified grid, grown
//! so that every raw pixel's undistorted position falls inside it), resamples the canvas into
//! the raw (distorted) sensor grid through a remap table built once, and steps the sensor model.
//!
//! * **Canvas.** Barrel distortion shows, in the raw corners, rays that lie outside the
//!   rectified `width`×`height` frame, so the canvas is the bounding box of all raw pixels'
//!   undistorted positions plus a small border, with the principal point shifted accordingly.
//!   It is capped at [`MAX_CANVAS_SCALE`] times the sensor per side; raw pixels whose ray falls
//!   outside the cap, or where the distortion model cannot be inverted, see a constant black
//!   (they lie outside the lens's usable field) and never fire.
//! * **Remap.** Raw pixel (x, y) takes the bilinear sample of the canvas at its undistorted
//!   position; the canvas has one sample per pixel (no anti-aliasing).
//! * **Background.** Either a uniform intensity or an infinite textured plane: the plane z = 0
//!   of frame bg, posed in the camera by `T_c_bg`, carrying square cells of side `cell_m` whose
//!   albedo is one of four high-contrast levels drawn from a hash of (cell, seed). It is
//!   evaluated analytically per pixel (no triangles), z-tested against the object, unlit (its
//!   albedo is its intensity). Rays that miss the plane see black.
//! * **Region of interest.** While the camera does not move relative to the background, only
//!   pixels the object covers now or covered at the previous frame can change. The step then
//!   renders and simulates only that region: the canvas box of the object's vertices at both
//!   poses (pinhole projection keeps the convex cover exact), mapped to the raw grid through its
//!   sampled border, grown by `margin_px`, and stepped with [`EventSimulator::step_roi`]. With
//!   noise-free parameters it gives exactly the events of a full-frame step (tested); with noise,
//!   pixels outside the region emit no noise (see the simulator's ROI notes). A new background
//!   pose, a vertex at or behind the near plane, or the first frame force a full frame.
//! * **Flicker.** With `flicker_hz` and `flicker_depth` set (the `lab` preset), every lit
//!   surface (all of them: object, occluders and background are lit by the room's lamps) is
//!   multiplied by [`SimParams::flicker_gain`] at each frame time before the sensor step; every
//!   frame then steps the whole sensor. Between frames the sensor interpolates log intensity
//!   linearly, so frames must come well above twice the flicker frequency (the closed loop
//!   renders at ≥ 1 kHz against 100 Hz).
//! * **Sparse frames** (default). A raw tile can only change if a background cell border swept
//!   over a pixel centre of its canvas box between the previous and the current frame (borders
//!   are straight canvas lines, so this is decided per tile from the lines at both poses, see
//!   [`same_cells`]), or if its box meets the screen box of a triangle of a mesh that moved, at
//!   either pose. Only those tiles are redrawn (background by bisection between pixels of one
//!   cell, meshes only in the columns those tiles read, row by row);
//!   a redrawn tile whose canvas values did not change is dropped too, and the sensor steps the
//!   rest ([`EventSimulator::step_tiles`]), catching skipped pixels up on leak. The events equal
//!   the reference path's (`set_sparse(false)`: full frames while the background moves, the
//!   changed region otherwise) bit for bit without leak, up to f32 rounding with it (tested).
//! * **Interpolated ticks** ([`SimCamera::advance_ticks`]). One render can stand for several
//!   sensor steps: the sensor is stepped at each given earlier tick on the intensities
//!   interpolated linearly in time between the previous render and this one (ESIM's
//!   interpolation between renders), with the flicker gain of each tick, so the sensor model still
//!   sees time in ticks while the scene is drawn only when it has moved enough to matter.
//! * **Occluders.** Further meshes (e.g. the robot arms) set by [`SimCamera::set_occluders`] and
//!   posed per frame in [`SimCamera::advance_scene`] are rendered with the object into one
//!   z-tested buffer, shaded like the object. An occluder whose pose changed since the previous
//!   frame adds its vertices at both poses to the region; one unmoved is still drawn inside it.

use crate::camera::Camera;
use crate::error::{ensure, Result};
use crate::event::EventBatch;
use crate::image::Roi;
use crate::mesh::Mesh;
use crate::render::{floor_i64, sphere_misses, RenderOptions, Renderer, NEAR_PLANE_M};
use crate::se3::Pose;
use crate::sim::tiles::{tile_boxes, CanvasBox, Coverage};
use crate::sim::{EventSimulator, SimParams, TILE_PX};
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use std::sync::Arc;

/// The canvas may be at most this many times the sensor's width and height.
pub const MAX_CANVAS_SCALE: u32 = 3;

/// Spare canvas pixels around the undistorted sensor footprint, so bilinear taps stay inside.
const CANVAS_BORDER_PX: f64 = 2.0;

/// Samples per side of the canvas box when its border is mapped to the raw grid: enough that
/// the smooth distortion cannot bulge between samples by more than a small fraction of a pixel.
const BORDER_SAMPLES: usize = 64;

/// Albedo levels of the background cells: dark to bright, ≥ 1.1 log units apart, so every cell
/// border is a strong edge.
const BACKGROUND_LEVELS: [f32; 4] = [0.04, 0.15, 0.45, 0.9];

/// A textured background plane; see the module documentation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BackgroundPlane {
    /// Pose of the plane's frame in the camera (the plane is its z = 0, its x–y cells).
    pub t_c_bg: Pose,
    /// Side of a texture cell in metres.
    pub cell_m: f64,
    /// Seed of the cell albedos.
    pub seed: u64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Background {
    /// Every pixel the object does not cover has this linear intensity.
    Uniform(f32),
    Plane(BackgroundPlane),
}

impl BackgroundPlane {
    /// Albedo of cell (i, j): one of [`BACKGROUND_LEVELS`] from a 64-bit mix of (i, j, seed).
    fn albedo(&self, i: i64, j: i64) -> f32 {
        let mut h = self.seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        h ^= (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
        h = (h ^ (h >> 31)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h ^= h >> 29;
        BACKGROUND_LEVELS[(h & 3) as usize]
    }
}

/// The plane in camera coordinates, ready for per-ray evaluation.
struct PlaneInCamera {
    plane: BackgroundPlane,
    /// Plane normal (bg z axis) and its offset n·p₀ in the camera frame.
    n: Vector3<f64>,
    d: f64,
    /// Rows of R_bg_c for the x and y axes, and the matching offsets, so that
    /// (x, y)_bg = (ax·p + bx, ay·p + by) for a camera-frame point p.
    ax: Vector3<f64>,
    ay: Vector3<f64>,
    bx: f64,
    by: f64,
}

impl PlaneInCamera {
    fn new(plane: BackgroundPlane) -> Self {
        let r = plane.t_c_bg.rotation.to_rotation_matrix();
        let t = plane.t_c_bg.translation.vector;
        let (ex, ey, ez) = (
            r.matrix().column(0),
            r.matrix().column(1),
            r.matrix().column(2),
        );
        Self {
            plane,
            n: ez.into_owned(),
            d: ez.dot(&t),
            ax: ex.into_owned(),
            ay: ey.into_owned(),
            bx: -ex.dot(&t),
            by: -ey.dot(&t),
        }
    }

    /// The plane along canvas row `y` of pinhole camera `canvas`.
    fn at_row(&self, canvas: &Camera, y: usize) -> PlaneRow<'_> {
        let inv_fx = 1.0 / canvas.fx;
        let ry = (y as f64 - canvas.cy) / canvas.fy;
        // The ray through pixel x is (x·inv_fx − cx·inv_fx, ry, 1): each dot product with it is
        // affine in x.
        let affine = |v: &Vector3<f64>| (v.y * ry + v.z - v.x * canvas.cx * inv_fx, v.x * inv_fx);
        PlaneRow {
            plane: self,
            dn: affine(&self.n),
            ax: affine(&self.ax),
            ay: affine(&self.ay),
            inv_cell: 1.0 / self.plane.cell_m,
        }
    }
}

/// [`PlaneInCamera`] along one canvas row; see [`PlaneInCamera::at_row`].
struct PlaneRow<'a> {
    plane: &'a PlaneInCamera,
    /// (offset, slope) in x of n·ray, ax·ray and ay·ray.
    dn: (f64, f64),
    ax: (f64, f64),
    ay: (f64, f64),
    inv_cell: f64,
}

impl PlaneRow<'_> {
    /// Depth in metres of the plane seen by canvas pixel `x`; `None` if missed.
    #[inline]
    fn depth(&self, x: usize) -> Option<f64> {
        let z = self.plane.d / (self.dn.0 + self.dn.1 * x as f64);
        (z.is_finite() && z > NEAR_PLANE_M).then_some(z)
    }

    /// (depth in metres, cell (i, j)) of the plane seen by canvas pixel `x`; `None` if missed.
    /// The one formula for both the full-frame and the sparse path, so they agree bit for bit.
    #[inline]
    fn cell(&self, x: usize) -> Option<(f64, (i64, i64))> {
        let xf = x as f64;
        let z = self.depth(x)?;
        let px = (self.ax.0 + self.ax.1 * xf) * z + self.plane.bx;
        let py = (self.ay.0 + self.ay.1 * xf) * z + self.plane.by;
        Some((
            z,
            (
                // Far-off rays saturate, which only merges cells beyond the horizon.
                floor_i64(px * self.inv_cell),
                floor_i64(py * self.inv_cell),
            ),
        ))
    }

    /// Intensities of pixels `x0 ..= x1` into `out`, given the cells `c0`, `c1` of the two ends.
    /// Where both ends see one cell, so does every pixel between: the segment maps to a
    /// segment on the plane, and cells are convex. Otherwise split in halves.
    fn fill(
        &self,
        x0: usize,
        c0: Option<(f64, (i64, i64))>,
        x1: usize,
        c1: Option<(f64, (i64, i64))>,
        out: &mut [f32],
    ) {
        let value = |c: Option<(f64, (i64, i64))>| {
            c.map_or(0.0, |(_, (i, j))| self.plane.plane.albedo(i, j))
        };
        match (c0, c1) {
            (Some((_, a)), Some((_, b))) if a == b => out.fill(value(c0)),
            _ if x1 - x0 <= 1 => {
                out[0] = value(c0);
                out[x1 - x0] = value(c1);
            }
            _ => {
                let mid = (x0 + x1) / 2;
                let cm = self.cell(mid);
                // Both halves include `mid`, and agree on it.
                self.fill(x0, c0, mid, cm, &mut out[..=mid - x0]);
                self.fill(mid, cm, x1, c1, &mut out[mid - x0..]);
            }
        }
    }

    /// (depth in metres, intensity) of canvas pixel `x`: infinitely far and black if missed.
    #[inline]
    fn hit(&self, x: usize) -> (f32, f32) {
        self.cell(x).map_or((f32::INFINITY, 0.0), |(z, (i, j))| {
            (z as f32, self.plane.plane.albedo(i, j))
        })
    }
}

/// Margin, in canvas pixels, by which a pixel centre must clear a moving cell border for
/// [`same_cells`] to count it unchanged: far above the rounding of either the analytic border or
/// the per-pixel cell evaluation, so a skipped tile is one whose cells certainly did not change.
const BORDER_MARGIN_PX: f64 = 1e-3;

/// More borders than this between a tile's corners: not worth sweeping, redraw the tile.
const MAX_SWEPT_BORDERS: i64 = 16;

impl PlaneInCamera {
    /// The canvas line where the plane coordinate `axis` (0: x, 1: y) equals `k`·cell: (α, β, γ)
    /// such that α·u + β·v + γ has the sign of (coordinate − k·cell) at every canvas pixel (u, v)
    /// whose ray hits the plane. From coordinate − k·cell = (m·ray)/(n·ray) with
    /// m = d·a + (b − k·cell)·n, and n·ray = d/z of the sign of d.
    fn border(&self, canvas: &Camera, axis: usize, k: i64) -> [f64; 3] {
        let (a, b) = if axis == 0 {
            (&self.ax, self.bx)
        } else {
            (&self.ay, self.by)
        };
        let m = self.d * a + (b - k as f64 * self.plane.cell_m) * self.n;
        let m = if self.d < 0.0 { -m } else { m };
        let (alpha, beta) = (m.x / canvas.fx, m.y / canvas.fy);
        [alpha, beta, m.z - alpha * canvas.cx - beta * canvas.cy]
    }
}

/// Whether the line `l0` (α·u + β·v + γ = 0) moving to `l1` passes over, or within
/// [`BORDER_MARGIN_PX`] of, a pixel centre (integer point) of box `b`. Solved along the axis
/// both lines are steep in; a line steep in neither counts as sweeping (never in practice).
fn sweeps_pixel(l0: [f64; 3], l1: [f64; 3], b: &CanvasBox) -> bool {
    let steep = |l: [f64; 3]| l[0].abs() >= l[1].abs();
    // (along, across): the line as `across = −(l[along_k]·along + γ) / l[across_k]`.
    let (rows, cols, k_along, k_across) = match (steep(l0), steep(l1)) {
        (true, true) => ((b.y0, b.y1), (b.x0, b.x1), 1, 0),
        (false, false) => ((b.x0, b.x1), (b.y0, b.y1), 0, 1),
        _ => return true,
    };
    (rows.0..=rows.1).any(|t| {
        let t = t as f64;
        let at = |l: [f64; 3]| -(l[k_along] * t + l[2]) / l[k_across];
        let (a, c) = (at(l0), at(l1));
        if !(a.is_finite() && c.is_finite()) {
            return true;
        }
        let lo = (a.min(c) - BORDER_MARGIN_PX).max(cols.0 as f64).ceil();
        let hi = (a.max(c) + BORDER_MARGIN_PX).min(cols.1 as f64).floor();
        lo <= hi
    })
}

/// Whether every pixel centre of canvas box `b` sees the same background cell with the plane at
/// `before` and at `now`. The plane's coordinates are projective in the canvas, so over a box
/// they take their extremes at the corners: the cell borders that can cross the box lie between
/// the corners' cells, each is a straight canvas line, and a centre changes cell only if the
/// line of some border passes over it. Conservative: any doubt (a corner that misses the plane,
/// many borders, a margin call) answers false, and the tile is redrawn and compared.
fn same_cells(before: &PlaneInCamera, now: &PlaneInCamera, canvas: &Camera, b: &CanvasBox) -> bool {
    let corners = |p: &PlaneInCamera| {
        b.corners()
            .map(|(x, y)| p.at_row(canvas, y).cell(x).map(|(_, c)| c))
    };
    let (c0, c1) = (corners(before), corners(now));
    let (Some(c0), Some(c1)) = (
        c0.into_iter().collect::<Option<Vec<_>>>(),
        c1.into_iter().collect::<Option<Vec<_>>>(),
    ) else {
        return false;
    };
    (0..2).all(|axis| {
        let pick = |c: &(i64, i64)| if axis == 0 { c.0 } else { c.1 };
        let lo = c0.iter().chain(&c1).map(pick).min().unwrap_or(0);
        let hi = c0.iter().chain(&c1).map(pick).max().unwrap_or(0);
        if hi - lo > MAX_SWEPT_BORDERS {
            return false;
        }
        (lo + 1..=hi).all(|k| {
            !sweeps_pixel(
                before.border(canvas, axis, k),
                now.border(canvas, axis, k),
                b,
            )
        })
    })
}

/// What one [`SimCamera::advance`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameInfo {
    /// Raw-grid region that was re-rendered and stepped (the full sensor on full frames).
    pub roi: Roi,
    pub full_frame: bool,
}

/// What one render draws: the object at `pose` and each occluder at its pose (both camera frame).
fn scene_of<'a>(
    mesh: &'a Mesh,
    pose: &'a Pose,
    occluders: &'a [Arc<Mesh>],
    occluder_poses: &'a [Pose],
) -> Vec<(&'a Mesh, &'a Pose)> {
    std::iter::once((mesh, pose))
        .chain(occluders.iter().map(|m| m.as_ref()).zip(occluder_poses))
        .collect()
}

/// The rendered event camera; see the module documentation.
pub struct SimCamera {
    camera: Camera,
    canvas: Camera,
    /// Canvas position (x, y) of each raw pixel, row-major; NaN where the pixel sees nothing.
    map: Vec<[f32; 2]>,
    mesh: Arc<Mesh>,
    /// Further meshes drawn with the object (z-tested), and their poses at the previous frame.
    occluders: Vec<Arc<Mesh>>,
    prev_occluder_poses: Vec<Pose>,
    renderer: Renderer,
    opts: RenderOptions,
    background: Background,
    sim: EventSimulator,
    margin_px: u32,
    /// The current raw frame (linear intensity), kept whole so that ROI steps can be cut from it.
    /// The raw frame times the flicker gain, what the sensor sees when the lighting flickers.
    lit: Vec<f32>,
    raw: Vec<f32>,
    /// Interpolated frames ([`Self::advance_ticks`]): the raw values of the redrawn tiles before
    /// the render (elsewhere stale), and the frame of one intermediate tick.
    before: Vec<f32>,
    between: Vec<f32>,
    /// Scratch: the events of one sensor step of a sparse frame.
    tick_out: EventBatch,
    /// Scratch: the composited canvas region and the raw ROI values.
    canvas_buf: Vec<f32>,
    roi_buf: Vec<f32>,
    /// The background plane over the whole canvas, (depth m, intensity) per pixel, rebuilt when
    /// the plane moves: a static camera then pays for it once.
    bg_cache: Vec<(f32, f32)>,
    prev_pose: Option<Pose>,
    last: Option<FrameInfo>,
    /// Sparse frames (the default): redraw and step only the raw tiles that can change.
    sparse: bool,
    /// Canvas box of each raw tile, the tiles redrawn by the last frame, and the canvas cells
    /// each mesh (object first, then the occluders) covered at the last frame.
    tile_boxes: Vec<Option<CanvasBox>>,
    changed: Vec<bool>,
    /// Each tile's composited canvas box as of its last redraw (empty: unknown); a redraw that
    /// reproduces it leaves the tile's raw pixels, and so its sensor pixels, alone.
    tile_cache: Vec<Vec<f32>>,
    cover: Coverage,
    cover_prev: Coverage,
}

impl SimCamera {
    /// `camera`: the sensor with its distortion. `mesh`: the object, shaded with `opts`
    /// (`opts.background` is ignored; `background` decides). `params`: the sensor model.
    /// `margin_px`: growth of the ROI around the object's raw-grid box, pixels.
    pub fn new(
        camera: Camera,
        mesh: Arc<Mesh>,
        opts: RenderOptions,
        background: Background,
        params: SimParams,
        margin_px: u32,
    ) -> Result<Self> {
        let camera = camera.checked()?;
        ensure(
            [opts.ambient, opts.diffuse]
                .iter()
                .all(|v| v.is_finite() && *v >= 0.0),
            || format!("shading must be finite and >= 0, got {opts:?}"),
        )?;
        match background {
            Background::Uniform(v) => ensure(v.is_finite() && v >= 0.0, || {
                format!("background intensity must be finite and >= 0, got {v}")
            })?,
            Background::Plane(p) => {
                ensure(p.cell_m.is_finite() && p.cell_m > 0.0, || {
                    format!(
                        "background cell size must be finite and > 0 m, got {}",
                        p.cell_m
                    )
                })?;
                let finite = p
                    .t_c_bg
                    .translation
                    .vector
                    .iter()
                    .chain(p.t_c_bg.rotation.coords.iter())
                    .all(|v| v.is_finite());
                ensure(finite, || "background pose T_c_bg must be finite".into())?;
            }
        }
        ensure(margin_px <= 1024, || {
            format!("ROI margin must be <= 1024 px, got {margin_px}")
        })?;
        let sim = EventSimulator::new(camera.width, camera.height, params)?;
        let (canvas, map) = build_canvas(&camera)?;
        let (cw, ch) = (canvas.width as usize, canvas.height as usize);
        let tile_boxes = tile_boxes(&map, camera.width as usize, camera.height as usize, cw, ch);
        Ok(Self {
            changed: vec![false; tile_boxes.len()],
            tile_cache: vec![Vec::new(); tile_boxes.len()],
            tile_boxes,
            cover: Coverage::new(1, cw, ch),
            cover_prev: Coverage::new(1, cw, ch),
            sparse: true,
            raw: vec![0.0; camera.n_pixels()],
            lit: Vec::new(),
            before: Vec::new(),
            between: Vec::new(),
            tick_out: EventBatch::default(),
            camera,
            canvas,
            map,
            mesh,
            occluders: Vec::new(),
            prev_occluder_poses: Vec::new(),
            renderer: Renderer::new(),
            opts: RenderOptions {
                background: 0.0,
                ..opts
            },
            background,
            sim,
            margin_px,
            canvas_buf: Vec::new(),
            roi_buf: Vec::new(),
            bg_cache: Vec::new(),
            prev_pose: None,
            last: None,
        })
    }

    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// The pinhole canvas the scene is rendered in (rectified grid, shifted and grown).
    pub fn canvas(&self) -> &Camera {
        &self.canvas
    }

    pub fn simulator(&self) -> &EventSimulator {
        &self.sim
    }

    /// The current raw frame, linear intensity, row-major `width`×`height`, before the
    /// lighting's flicker gain ([`SimParams::flicker_gain`]).
    pub fn frame(&self) -> &[f32] {
        &self.raw
    }

    /// What the last advance did, `None` before the first.
    pub fn last_frame(&self) -> Option<FrameInfo> {
        self.last
    }

    pub fn background(&self) -> Background {
        self.background
    }

    /// The occluder meshes, in the order their poses are given to [`Self::advance_scene`].
    pub fn occluders(&self) -> &[Arc<Mesh>] {
        &self.occluders
    }

    /// Replace the occluders (meshes drawn with the object and z-tested against it, e.g. the
    /// robot arms); each [`Self::advance_scene`] then poses every one of them. The next frame
    /// is a full frame.
    pub fn set_occluders(&mut self, meshes: Vec<Arc<Mesh>>) {
        let (cw, ch) = (self.canvas.width as usize, self.canvas.height as usize);
        self.cover = Coverage::new(1 + meshes.len(), cw, ch);
        self.cover_prev = self.cover.clone();
        self.occluders = meshes;
        self.prev_occluder_poses.clear();
        self.prev_pose = None;
    }

    /// Sparse frames on (the default) or off. Sparse frames redraw and step only the raw tiles
    /// whose canvas box holds a background edge or a moving mesh (module docs); off, every frame
    /// with a moving background is a full frame and the rest use the changed region. Both give
    /// the same events without leak noise (tested), up to f32 rounding of the leak with it. The
    /// next frame is a full frame.
    pub fn set_sparse(&mut self, on: bool) {
        self.sparse = on;
        self.prev_pose = None;
    }

    /// Largest raw-pixel displacement of any mesh vertex between poses `a` and `b` (both object
    /// in camera). Vertices at or behind the near plane in either pose count as infinitely far,
    /// so a caller sub-dividing by this never skips past a crossing of the camera plane.
    pub fn max_displacement_px(&self, a: &Pose, b: &Pose) -> f64 {
        self.mesh
            .vertices
            .par_iter()
            .with_min_len(512)
            .map(|v| {
                let p = Point3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]));
                let (pa, pb) = ((a * p).coords, (b * p).coords);
                if pa.z <= NEAR_PLANE_M || pb.z <= NEAR_PLANE_M {
                    return f64::INFINITY;
                }
                match (self.camera.project(&pa), self.camera.project(&pb)) {
                    (Some((ua, va)), Some((ub, vb))) => (ua - ub).hypot(va - vb),
                    _ => f64::INFINITY,
                }
            })
            .reduce(|| 0.0, f64::max)
    }

    /// Largest raw-pixel displacement of the occluders' visible vertices between their poses
    /// `a` and `b` (one per occluder, in camera). Unlike [`Self::max_displacement_px`] it skips
    /// what cannot be seen in either pose: vertices at or behind the near plane in either pose
    /// (parts of an arm passing behind the camera are clipped, not bounded) and vertices outside
    /// the canvas in both. A vertex whose distorted projection fails counts by its pinhole motion.
    /// 0 with no occluders.
    pub fn occluder_displacement_px(&self, a: &[Pose], b: &[Pose]) -> Result<f64> {
        let n = self.occluders.len();
        ensure(a.len() == n && b.len() == n, || {
            format!(
                "{n} occluders need {n} poses each, got {} and {}",
                a.len(),
                b.len()
            )
        })?;
        let (cam, canvas) = (&self.camera, &self.canvas);
        let (w, h) = (f64::from(canvas.width), f64::from(canvas.height));
        let pin = |p: &Vector3<f64>| {
            (
                canvas.fx * p.x / p.z + canvas.cx,
                canvas.fy * p.y / p.z + canvas.cy,
            )
        };
        let inside = |(u, v): (f64, f64)| u >= -1.0 && v >= -1.0 && u <= w && v <= h;
        let worst = self
            .occluders
            .iter()
            .zip(a.iter().zip(b))
            .filter(|(mesh, (pa, pb))| {
                // A link out of the canvas at both poses has no vertex inside it at either.
                let (centre, radius) = mesh.bounding_sphere();
                let c = Point3::from(centre);
                let bounds = [0.0, w - 1.0, 0.0, h - 1.0];
                let misses = |p: &Pose| sphere_misses(canvas, &(p * c).coords, radius, bounds);
                pa != pb && !(misses(pa) && misses(pb))
            })
            .map(|(mesh, (pa, pb))| {
                mesh.vertices
                    .par_iter()
                    .with_min_len(512)
                    .map(|v| {
                        let p = Point3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]));
                        let (qa, qb) = ((pa * p).coords, (pb * p).coords);
                        if qa.z <= NEAR_PLANE_M || qb.z <= NEAR_PLANE_M {
                            return 0.0;
                        }
                        let (sa, sb) = (pin(&qa), pin(&qb));
                        if !inside(sa) && !inside(sb) {
                            return 0.0;
                        }
                        match (cam.project(&qa), cam.project(&qb)) {
                            (Some((ua, va)), Some((ub, vb))) => (ua - ub).hypot(va - vb),
                            _ => (sa.0 - sb.0).hypot(sa.1 - sb.1),
                        }
                    })
                    .reduce(|| 0.0, f64::max)
            })
            .fold(0.0, f64::max);
        Ok(worst)
    }

    /// Render the object at `t_c_o` (and the background, moved to `t_c_bg` if given) at time
    /// `t_us`, step the sensor and put the interval's events in `out` (cleared first). The first
    /// call only initialises the sensor and yields no events. Times must increase strictly.
    /// With occluders set, use [`Self::advance_scene`].
    pub fn advance(
        &mut self,
        t_c_o: &Pose,
        t_us: i64,
        t_c_bg: Option<&Pose>,
        out: &mut EventBatch,
    ) -> Result<FrameInfo> {
        self.advance_scene(t_c_o, &[], t_us, t_c_bg, out)
    }

    /// [`Self::advance`] with the occluders at `occluder_poses` (one per occluder, in camera).
    pub fn advance_scene(
        &mut self,
        t_c_o: &Pose,
        occluder_poses: &[Pose],
        t_us: i64,
        t_c_bg: Option<&Pose>,
        out: &mut EventBatch,
    ) -> Result<FrameInfo> {
        self.advance_ticks(t_c_o, occluder_poses, (&[], t_us), t_c_bg, out)
    }

    /// [`Self::advance_scene`] rendering once, at `t_us`, but stepping the sensor at each of the
    /// earlier `ticks` too (µs, increasing, strictly between the previous frame and `t_us`) on
    /// the intensities interpolated linearly in time between the previous render and this one
    /// (ESIM's interpolation between renders, in linear intensity: exact for an edge moving at
    /// constant speed across a pixel's bilinear ramp). The sensor model then still sees time in
    /// ticks (the lighting's flicker is sampled at each), while the scene is drawn once. Needs
    /// sparse frames and a previous frame unless `ticks` is empty. `out` gets every tick's
    /// events, in time order.
    pub fn advance_ticks(
        &mut self,
        t_c_o: &Pose,
        occluder_poses: &[Pose],
        (ticks, t_us): (&[i64], i64),
        t_c_bg: Option<&Pose>,
        out: &mut EventBatch,
    ) -> Result<FrameInfo> {
        let finite = |p: &Pose| {
            p.translation
                .vector
                .iter()
                .chain(p.rotation.coords.iter())
                .all(|v| v.is_finite())
        };
        ensure(finite(t_c_o), || "pose T_c_o must be finite".into())?;
        ensure(occluder_poses.len() == self.occluders.len(), || {
            format!(
                "{} occluders need as many poses, got {}",
                self.occluders.len(),
                occluder_poses.len()
            )
        })?;
        ensure(occluder_poses.iter().all(finite), || {
            "occluder poses must be finite".into()
        })?;
        if let Some(t) = self.sim.time_us() {
            ensure(t_us > t, || {
                format!("frame time {t_us} µs is not after the previous frame at {t} µs")
            })?;
        }
        let prev_background = self.background;
        let mut moved_background = false;
        if let Some(bg) = t_c_bg {
            ensure(finite(bg), || {
                "background pose T_c_bg must be finite".into()
            })?;
            match &mut self.background {
                Background::Plane(p) => {
                    moved_background = p.t_c_bg != *bg;
                    p.t_c_bg = *bg;
                }
                Background::Uniform(_) => {
                    return Err(crate::Error::InvalidArgument(
                        "a background pose needs a background plane, not a uniform background"
                            .into(),
                    ))
                }
            }
        }
        ensure(
            ticks.is_empty() || (self.sparse && self.prev_pose.is_some()),
            || "interpolated ticks need sparse frames and a previous frame".into(),
        )?;
        let after_prev = |t: i64| self.sim.time_us().is_none_or(|p| t > p);
        ensure(
            ticks.first().is_none_or(|&t| after_prev(t))
                && ticks.windows(2).all(|w| w[0] < w[1])
                && ticks.last().is_none_or(|&t| t < t_us),
            || "ticks must increase strictly between the previous frame and t_us".into(),
        )?;
        if let (true, Some(prev)) = (self.sparse, self.prev_pose) {
            let info = self.advance_sparse(
                (&prev, t_c_o),
                occluder_poses,
                (prev_background, moved_background),
                (ticks, t_us),
                out,
            )?;
            self.prev_pose = Some(*t_c_o);
            self.prev_occluder_poses.clear();
            self.prev_occluder_poses.extend_from_slice(occluder_poses);
            self.last = Some(info);
            return Ok(info);
        }
        if moved_background || self.prev_pose.is_none() {
            self.cache_background();
        }
        let region = match self.prev_pose {
            // Flicker changes every lit pixel.
            Some(prev) if !moved_background && !self.flickers() => {
                self.changed_region(&prev, t_c_o, occluder_poses)
            }
            _ => Region::Full,
        };
        let info = match region {
            Region::Full => {
                let full = Roi::full(self.camera.width, self.camera.height);
                self.render_raw(
                    t_c_o,
                    occluder_poses,
                    full,
                    Roi::full(self.canvas.width, self.canvas.height),
                )?;
                if self.flickers() {
                    let gain = self.gain(t_us);
                    light(&mut self.lit, &self.raw, gain);
                    self.sim.step(&self.lit, t_us, out)?;
                } else {
                    self.sim.step(&self.raw, t_us, out)?;
                }
                FrameInfo {
                    roi: full,
                    full_frame: true,
                }
            }
            Region::Part { raw, canvas } => {
                self.render_raw(t_c_o, occluder_poses, raw, canvas)?;
                self.step_roi(raw, t_us, out)?;
                FrameInfo {
                    roi: raw,
                    full_frame: false,
                }
            }
            Region::Nothing => {
                // Time must still advance, or the next step would spread its changes over the
                // skipped interval too; one unchanged pixel does that at no cost.
                let roi = Roi {
                    x0: 0,
                    y0: 0,
                    width: 1,
                    height: 1,
                };
                self.step_roi(roi, t_us, out)?;
                FrameInfo {
                    roi,
                    full_frame: false,
                }
            }
        };
        if self.sparse {
            // The renderer holds this full frame's triangles: the coverage the next sparse frame
            // compares against.
            self.cover.mark(self.renderer.triangle_boxes());
            self.tile_cache.iter_mut().for_each(Vec::clear);
        }
        self.prev_pose = Some(*t_c_o);
        self.prev_occluder_poses.clear();
        self.prev_occluder_poses.extend_from_slice(occluder_poses);
        self.last = Some(info);
        Ok(info)
    }

    /// A sparse frame (module docs): the object from `prev` to `cur`, the occluders from their
    /// previous poses to `occluder_poses`, the background from `prev_background` (`moved` if its
    /// pose changed) to the current one.
    fn advance_sparse(
        &mut self,
        (prev, cur): (&Pose, &Pose),
        occluder_poses: &[Pose],
        (prev_background, moved_background): (Background, bool),
        (ticks, t_us): (&[i64], i64),
        out: &mut EventBatch,
    ) -> Result<FrameInfo> {
        let scene = scene_of(&self.mesh, cur, &self.occluders, occluder_poses);
        self.renderer
            .prepare_scene(&scene, &self.canvas, None, &self.opts)?;
        std::mem::swap(&mut self.cover, &mut self.cover_prev);
        self.cover.mark(self.renderer.triangle_boxes());
        let mesh_moved: Vec<bool> = std::iter::once(prev != cur)
            .chain(
                self.prev_occluder_poses
                    .iter()
                    .zip(occluder_poses)
                    .map(|(a, b)| a != b),
            )
            .collect();
        let moving = self.cover.union_with(&self.cover_prev, |m| mesh_moved[m]);
        let drawn = self.cover.union_with(&self.cover, |_| true);
        let plane_now = match self.background {
            Background::Plane(p) => Some(PlaneInCamera::new(p)),
            Background::Uniform(_) => None,
        };
        let plane_before = match (moved_background, prev_background) {
            (true, Background::Plane(p)) => Some(PlaneInCamera::new(p)),
            _ => None,
        };
        let canvas = self.canvas;
        let cell_at = |plane: &PlaneInCamera, (x, y): (usize, usize)| {
            plane.at_row(&canvas, y).cell(x).map(|(_, c)| c)
        };
        // One cell under all four corners of a box means one cell under all of it: the box maps
        // to a convex quadrilateral on the plane and the cells are convex.
        let one_cell = |plane: &PlaneInCamera, b: &CanvasBox| {
            let [a, rest @ ..] = b.corners().map(|c| cell_at(plane, c));
            a.filter(|a| rest.iter().all(|c| *c == Some(*a)))
        };
        let cover = &self.cover;
        let mut need: Option<CanvasBox> = None;
        // Per canvas row, the columns that redrawn tiles meeting a mesh read: the only mesh
        // pixels the composite looks at (an arm across the view has a much larger box).
        let mut cols = vec![(i64::MAX, i64::MIN); self.canvas.height as usize];
        for (flag, b) in self.changed.iter_mut().zip(&self.tile_boxes) {
            let Some(b) = b else {
                *flag = false;
                continue;
            };
            let bg_changed = plane_before.as_ref().is_some_and(|before| {
                plane_now
                    .as_ref()
                    .is_none_or(|now| !same_cells(before, now, &canvas, b))
            });
            *flag = bg_changed || cover.meets(&moving, b);
            if *flag && cover.meets(&drawn, b) {
                for c in &mut cols[b.y0..=b.y1] {
                    *c = (c.0.min(b.x0 as i64), c.1.max(b.x1 as i64));
                }
                need = Some(need.map_or(*b, |n| CanvasBox {
                    x0: n.x0.min(b.x0),
                    y0: n.y0.min(b.y0),
                    x1: n.x1.max(b.x1),
                    y1: n.y1.max(b.y1),
                }));
            }
        }
        let mesh_roi = need.map(|n| Roi {
            x0: n.x0 as u32,
            y0: n.y0 as u32,
            width: n.width() as u32,
            height: n.height() as u32,
        });
        let rendered = match mesh_roi {
            Some(roi) => {
                let rows = &cols[roi.y0 as usize..(roi.y0 + roi.height) as usize];
                Some(self.renderer.draw_prepared_rows(
                    &scene,
                    &self.canvas,
                    roi,
                    Some(rows),
                    &self.opts,
                )?)
            }
            None => None,
        };
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let t = TILE_PX as usize;
        let tx = w.div_ceil(t);
        let (map, boxes) = (&self.map, &self.tile_boxes);
        let background = self.background;
        let keep_before = !ticks.is_empty();
        self.before.resize(if keep_before { w * h } else { 0 }, 0.0);
        let mut before_rows: Vec<&mut [f32]> = self.before.chunks_mut(t * w).collect();
        before_rows.resize_with(h.div_ceil(t), Default::default);
        self.raw
            .par_chunks_mut(t * w)
            .zip(before_rows.into_par_iter())
            .zip(self.changed.par_chunks_mut(tx))
            .zip(self.tile_cache.par_chunks_mut(tx))
            .enumerate()
            .for_each(|(ty, (((rows, before), changed), cache))| {
                for kx in 0..tx {
                    let (true, Some(b)) = (changed[kx], boxes[ty * tx + kx]) else {
                        continue;
                    };
                    let uniform = match (&plane_now, background) {
                        _ if cover.meets(&drawn, &b) => None,
                        (Some(p), _) => one_cell(p, &b).map(|(i, j)| p.plane.albedo(i, j)),
                        (None, Background::Uniform(level)) => Some(level),
                        (None, Background::Plane(_)) => None,
                    };
                    let old = std::mem::take(&mut cache[kx]);
                    let mut buf = Vec::with_capacity(b.width() * b.height());
                    match uniform {
                        Some(level) => buf.resize(b.width() * b.height(), level),
                        None => {
                            let meshes = rendered.filter(|_| cover.meets(&drawn, &b));
                            composite(
                                &mut buf,
                                &b,
                                &canvas,
                                meshes,
                                plane_now.as_ref(),
                                background,
                            )
                        }
                    }
                    let same = old.len() == buf.len()
                        && old
                            .iter()
                            .zip(&buf)
                            .all(|(x, y)| x.to_bits() == y.to_bits());
                    cache[kx] = buf;
                    if same {
                        // Same canvas values, same raw values: nothing for the sensor either.
                        changed[kx] = false;
                        continue;
                    }
                    let buf = &cache[kx];
                    let (x0, n_rows) = (kx * t, rows.len() / w);
                    let x1 = (x0 + t).min(w);
                    if keep_before {
                        for r in 0..n_rows {
                            let span = r * w + x0..r * w + x1;
                            before[span.clone()].copy_from_slice(&rows[span]);
                        }
                    }
                    for r in 0..n_rows {
                        let y = ty * t + r;
                        let taps = &map[y * w + x0..y * w + x1];
                        for (o, &[u, v]) in rows[r * w + x0..r * w + x1].iter_mut().zip(taps) {
                            *o = match uniform {
                                // A NaN tap sees nothing, as in `bilinear`.
                                Some(level) if u.is_finite() => level,
                                Some(_) => 0.0,
                                None => bilinear(
                                    buf,
                                    b.width(),
                                    b.height(),
                                    u - b.x0 as f32,
                                    v - b.y0 as f32,
                                ),
                            };
                        }
                    }
                }
            });
        if self.flickers() {
            // Every lit pixel changes, so every tile that sees something is stepped; only the
            // redrawn ones differ between the two renders and are interpolated.
            let redrawn = std::mem::take(&mut self.changed);
            self.changed = self.tile_boxes.iter().map(Option::is_some).collect();
            self.step_between(&redrawn, (ticks, t_us), out)?;
            let gain = self.gain(t_us);
            light(&mut self.lit, &self.raw, gain);
            self.sim
                .step_tiles(&self.lit, &self.changed, t_us, &mut self.tick_out)?;
        } else {
            let redrawn = self.changed.clone();
            self.step_between(&redrawn, (ticks, t_us), out)?;
            self.sim
                .step_tiles(&self.raw, &self.changed, t_us, &mut self.tick_out)?;
        }
        out.extend_from(&self.tick_out);
        // Report the box of the redrawn tiles (a 1-pixel region when none was).
        let (mut lo, mut hi) = ((w, h), (0, 0));
        for (k, _) in self.changed.iter().enumerate().filter(|(_, &c)| c) {
            let (x, y) = ((k % tx) * t, (k / tx) * t);
            lo = (lo.0.min(x), lo.1.min(y));
            hi = (hi.0.max((x + t).min(w)), hi.1.max((y + t).min(h)));
        }
        let roi = if hi.0 > lo.0 {
            Roi {
                x0: lo.0 as u32,
                y0: lo.1 as u32,
                width: (hi.0 - lo.0) as u32,
                height: (hi.1 - lo.1) as u32,
            }
        } else {
            Roi {
                x0: 0,
                y0: 0,
                width: 1,
                height: 1,
            }
        };
        Ok(FrameInfo {
            roi,
            full_frame: false,
        })
    }

    /// Whether the sensor parameters ask for mains flicker of the lighting.
    fn flickers(&self) -> bool {
        let p = self.sim.params();
        p.flicker_hz > 0.0 && p.flicker_depth > 0.0
    }

    /// The lighting's flicker gain at `t_us`.
    fn gain(&self, t_us: i64) -> f32 {
        self.sim.params().flicker_gain(t_us) as f32
    }

    /// Step the sensor at each of `ticks` (before `t_us`, the time of this render) on the frame
    /// interpolated linearly in time between the previous render (`before`, on the tiles flagged
    /// in `redrawn`, the only ones whose values changed) and this one (`raw`); `out` (cleared
    /// first) gets the events.
    fn step_between(
        &mut self,
        redrawn: &[bool],
        (ticks, t_us): (&[i64], i64),
        out: &mut EventBatch,
    ) -> Result<()> {
        out.clear();
        let (Some(t_prev), false) = (self.sim.time_us(), ticks.is_empty()) else {
            return Ok(());
        };
        let (w, t) = (self.camera.width as usize, TILE_PX as usize);
        let tx = w.div_ceil(t);
        self.between.clear();
        self.between.extend_from_slice(&self.raw);
        for &tick in ticks {
            let s = (tick - t_prev) as f32 / (t_us - t_prev) as f32;
            self.between
                .par_chunks_mut(t * w)
                .zip(self.before.par_chunks(t * w))
                .zip(self.raw.par_chunks(t * w))
                .zip(redrawn.par_chunks(tx))
                .for_each(|(((mid, before), raw), redrawn)| {
                    let n_rows = mid.len() / w;
                    for kx in (0..tx).filter(|&kx| redrawn[kx]) {
                        let (x0, x1) = (kx * t, ((kx + 1) * t).min(w));
                        for r in 0..n_rows {
                            let span = r * w + x0..r * w + x1;
                            let rows = mid[span.clone()].iter_mut().zip(&before[span.clone()]);
                            for ((m, &b), &a) in rows.zip(&raw[span]) {
                                *m = b + (a - b) * s;
                            }
                        }
                    }
                });
            if self.flickers() {
                let gain = self.gain(tick);
                light(&mut self.lit, &self.between, gain);
                self.sim
                    .step_tiles(&self.lit, &self.changed, tick, &mut self.tick_out)?;
            } else {
                self.sim
                    .step_tiles(&self.between, &self.changed, tick, &mut self.tick_out)?;
            }
            out.extend_from(&self.tick_out);
        }
        Ok(())
    }

    fn cache_background(&mut self) {
        let Background::Plane(plane) = self.background else {
            self.bg_cache = Vec::new();
            return;
        };
        let plane = PlaneInCamera::new(plane);
        let c = &self.canvas;
        let w = c.width as usize;
        self.bg_cache.resize(c.n_pixels(), (0.0, 0.0));
        self.bg_cache
            .par_chunks_mut(w)
            .enumerate()
            .for_each(|(y, row)| {
                let plane = plane.at_row(c, y);
                for (x, px) in row.iter_mut().enumerate() {
                    *px = plane.hit(x);
                }
            });
    }

    fn step_roi(&mut self, roi: Roi, t_us: i64, out: &mut EventBatch) -> Result<()> {
        let w = self.camera.width as usize;
        self.roi_buf.clear();
        for y in roi.y0..roi.y0 + roi.height {
            let start = y as usize * w + roi.x0 as usize;
            self.roi_buf
                .extend_from_slice(&self.raw[start..start + roi.width as usize]);
        }
        self.sim.step_roi(&self.roi_buf, roi, t_us, out)
    }

    /// The raw and canvas regions that can change between the object at `prev` and at `cur`
    /// and the occluders at their previous poses and at `occluders`.
    fn changed_region(&self, prev: &Pose, cur: &Pose, occluders: &[Pose]) -> Region {
        let mut pts = Vec::with_capacity(2 * self.mesh.vertices.len());
        let moved = self
            .occluders
            .iter()
            .zip(self.prev_occluder_poses.iter().zip(occluders))
            .filter(|(_, (a, b))| a != b)
            .flat_map(|(m, (a, b))| [(m.as_ref(), a), (m.as_ref(), b)]);
        let posed = [(self.mesh.as_ref(), prev), (self.mesh.as_ref(), cur)]
            .into_iter()
            .chain(moved);
        for (mesh, pose) in posed {
            for v in &mesh.vertices {
                let p =
                    (pose * Point3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]))).coords;
                if p.z <= NEAR_PLANE_M {
                    // Near-plane clipping makes the projected cover unbounded.
                    return Region::Full;
                }
                pts.push((
                    self.canvas.fx * p.x / p.z + self.canvas.cx,
                    self.canvas.fy * p.y / p.z + self.canvas.cy,
                ));
            }
        }
        // Anything outside the canvas is seen by no raw pixel.
        let Some(cover) = Roi::around(pts, 1.0, self.canvas.width, self.canvas.height) else {
            return Region::Nothing;
        };
        // Map the cover's border to the raw grid: the distortion is a smooth bijection over
        // the canvas, so the image of a box is bounded by the image of its border.
        let (x0, y0) = (f64::from(cover.x0), f64::from(cover.y0));
        let (x1, y1) = (x0 + f64::from(cover.width), y0 + f64::from(cover.height));
        let (ox, oy) = (
            self.canvas.cx - self.camera.cx,
            self.canvas.cy - self.camera.cy,
        );
        let border = (0..=BORDER_SAMPLES).flat_map(|k| {
            let s = k as f64 / BORDER_SAMPLES as f64;
            let (xs, ys) = (x0 + s * (x1 - x0), y0 + s * (y1 - y0));
            [(xs, y0), (xs, y1), (x0, ys), (x1, ys)]
        });
        let raw_pts: Vec<(f64, f64)> = border
            .map(|(u, v)| self.camera.distort_pixel(u - ox, v - oy))
            .collect();
        let Some(raw) = Roi::around(
            raw_pts,
            f64::from(self.margin_px) + 1.0,
            self.camera.width,
            self.camera.height,
        ) else {
            return Region::Nothing;
        };
        // The canvas pixels the raw region's bilinear taps read.
        let w = self.camera.width as usize;
        let (mut lo_x, mut lo_y, mut hi_x, mut hi_y) = (f32::MAX, f32::MAX, f32::MIN, f32::MIN);
        for y in raw.y0..raw.y0 + raw.height {
            let row = &self.map[y as usize * w + raw.x0 as usize..][..raw.width as usize];
            for &[u, v] in row {
                // NaN compares false and drops out.
                lo_x = lo_x.min(u);
                lo_y = lo_y.min(v);
                hi_x = hi_x.max(u);
                hi_y = hi_y.max(v);
            }
        }
        if lo_x > hi_x {
            return Region::Nothing;
        }
        let canvas = Roi::around(
            [
                (f64::from(lo_x), f64::from(lo_y)),
                (f64::from(hi_x), f64::from(hi_y)),
            ],
            1.0,
            self.canvas.width,
            self.canvas.height,
        );
        match canvas {
            Some(canvas) => Region::Part { raw, canvas },
            None => Region::Nothing,
        }
    }

    /// Render `canvas_roi` of the canvas, composite the background, and resample `raw_roi` of
    /// the raw frame from it. `canvas_roi` must hold every bilinear tap of `raw_roi`.
    fn render_raw(
        &mut self,
        t_c_o: &Pose,
        occluder_poses: &[Pose],
        raw_roi: Roi,
        canvas_roi: Roi,
    ) -> Result<()> {
        let scene = scene_of(&self.mesh, t_c_o, &self.occluders, occluder_poses);
        let rendered =
            self.renderer
                .render_scene_into(&scene, &self.canvas, Some(canvas_roi), &self.opts)?;
        let cw = canvas_roi.width as usize;
        self.canvas_buf.clear();
        self.canvas_buf.extend_from_slice(&rendered.intensity);
        let canvas = &self.canvas;
        match self.background {
            Background::Uniform(level) => {
                self.canvas_buf
                    .par_iter_mut()
                    .zip(rendered.depth_m.par_iter())
                    .with_min_len(4096)
                    .for_each(|(i, d)| {
                        if !d.is_finite() {
                            *i = level;
                        }
                    });
            }
            Background::Plane(_) => {
                let stride = canvas.width as usize;
                let cache = &self.bg_cache;
                self.canvas_buf
                    .par_chunks_mut(cw)
                    .zip(rendered.depth_m.par_chunks(cw))
                    .enumerate()
                    .for_each(|(r, (row, depth))| {
                        let start = (canvas_roi.y0 as usize + r) * stride + canvas_roi.x0 as usize;
                        for ((i, &d), &(z, value)) in
                            row.iter_mut().zip(depth).zip(&cache[start..start + cw])
                        {
                            // A miss is stored at infinite depth with black: background pixels
                            // take it, object pixels keep their shade.
                            if z < d || !d.is_finite() {
                                *i = value;
                            }
                        }
                    });
            }
        }
        let (w, src) = (self.camera.width as usize, &self.canvas_buf);
        let ch = canvas_roi.height as usize;
        let (cx0, cy0) = (canvas_roi.x0 as f32, canvas_roi.y0 as f32);
        let map = &self.map;
        self.raw
            .par_chunks_mut(w)
            .enumerate()
            .skip(raw_roi.y0 as usize)
            .take(raw_roi.height as usize)
            .for_each(|(y, row)| {
                let x0 = raw_roi.x0 as usize;
                let span = &mut row[x0..x0 + raw_roi.width as usize];
                let taps = &map[y * w + x0..][..span.len()];
                for (out, &[u, v]) in span.iter_mut().zip(taps) {
                    *out = bilinear(src, cw, ch, u - cx0, v - cy0);
                }
            });
        Ok(())
    }
}

/// Fill `buf` with canvas box `b` composited as in [`SimCamera::render_raw`]: the meshes where
/// `rendered` has a surface nearer than the background, the background elsewhere.
/// `lit` = `frame` under the lighting's flicker `gain`.
fn light(lit: &mut Vec<f32>, frame: &[f32], gain: f32) {
    lit.resize(frame.len(), 0.0);
    lit.par_chunks_mut(1 << 14)
        .zip(frame.par_chunks(1 << 14))
        .for_each(|(l, r)| l.iter_mut().zip(r).for_each(|(l, r)| *l = r * gain));
}

fn composite(
    buf: &mut Vec<f32>,
    b: &CanvasBox,
    canvas: &Camera,
    rendered: Option<&crate::render::Rendered>,
    plane: Option<&PlaneInCamera>,
    background: Background,
) {
    buf.clear();
    for y in b.y0..=b.y1 {
        let row = plane.map(|p| p.at_row(canvas, y));
        // The mesh buffer's slice of this row, when the meshes reach it.
        let mesh = rendered.and_then(|r| {
            let k = r.index(b.x0 as u32, y as u32)?;
            Some((&r.depth_m[k..k + b.width()], &r.intensity[k..k + b.width()]))
        });
        if let Some(row) = &row {
            // Runs of background are filled by bisection between pixels of one cell; mesh pixels
            // need only the plane's depth unless the plane is nearer (as the reference does it).
            let start = buf.len();
            buf.resize(start + b.width(), 0.0);
            let out = &mut buf[start..];
            let depth = mesh.map(|(d, _)| d);
            let mut c = 0;
            while c < out.len() {
                let bg = |k: usize| depth.is_none_or(|d| !d[k].is_finite());
                let end = (c..out.len())
                    .find(|&k| bg(k) != bg(c))
                    .unwrap_or(out.len());
                if bg(c) {
                    let (xa, xb) = (b.x0 + c, b.x0 + end - 1);
                    row.fill(xa, row.cell(xa), xb, row.cell(xb), &mut out[c..end]);
                } else if let Some((d, i)) = mesh {
                    for k in c..end {
                        let x = b.x0 + k;
                        out[k] = match row.depth(x) {
                            Some(z) if (z as f32) < d[k] => row.hit(x).1,
                            _ => i[k],
                        };
                    }
                }
                c = end;
            }
            continue;
        }
        for (c, x) in (b.x0..=b.x1).enumerate() {
            let (d, i) = mesh.map_or((f32::INFINITY, 0.0), |(d, i)| (d[c], i[c]));
            let value = match (&row, background) {
                (Some(row), _) => {
                    let (z, value) = row.hit(x);
                    if z < d || !d.is_finite() {
                        value
                    } else {
                        i
                    }
                }
                (None, Background::Uniform(level)) if !d.is_finite() => level,
                (None, _) => i,
            };
            buf.push(value);
        }
    }
}

enum Region {
    Full,
    Part { raw: Roi, canvas: Roi },
    Nothing,
}

/// Bilinear sample of a `w`×`h` image at (x, y) (pixel centres at integers); 0 outside or NaN.
#[inline]
fn bilinear(img: &[f32], w: usize, h: usize, x: f32, y: f32) -> f32 {
    if !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f32 && y <= (h - 1) as f32) {
        return 0.0;
    }
    let (x0, y0) = (x as usize, y as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let (r0, r1) = (&img[y0 * w..], &img[y1 * w..]);
    let top = r0[x0] + (r0[x1] - r0[x0]) * fx;
    let bottom = r1[x0] + (r1[x1] - r1[x0]) * fx;
    top + (bottom - top) * fy
}

/// The pinhole canvas covering every raw pixel's undistorted position, and the remap table.
fn build_canvas(camera: &Camera) -> Result<(Camera, Vec<[f32; 2]>)> {
    let w = camera.width as usize;
    let rect: Vec<Option<(f64, f64)>> = (0..camera.n_pixels())
        .into_par_iter()
        .with_min_len(1024)
        .map(|i| camera.rectify_pixel((i % w) as f64, (i / w) as f64))
        .collect();
    let (wf, hf) = (f64::from(camera.width), f64::from(camera.height));
    let cap = |v: f64, size: f64| {
        let extra = 0.5 * (f64::from(MAX_CANVAS_SCALE) - 1.0) * size;
        v.clamp(-extra, size - 1.0 + extra)
    };
    let (mut lo_x, mut lo_y, mut hi_x, mut hi_y) = (0.0_f64, 0.0_f64, wf - 1.0, hf - 1.0);
    for &(u, v) in rect.iter().flatten() {
        lo_x = lo_x.min(cap(u, wf));
        lo_y = lo_y.min(cap(v, hf));
        hi_x = hi_x.max(cap(u, wf));
        hi_y = hi_y.max(cap(v, hf));
    }
    let ox = (CANVAS_BORDER_PX - lo_x).ceil();
    let oy = (CANVAS_BORDER_PX - lo_y).ceil();
    let cw = (hi_x + ox + CANVAS_BORDER_PX).ceil() as u32 + 1;
    let ch = (hi_y + oy + CANVAS_BORDER_PX).ceil() as u32 + 1;
    let canvas = Camera::new(
        cw,
        ch,
        camera.fx,
        camera.fy,
        camera.cx + ox,
        camera.cy + oy,
        [0.0; 5],
    )?;
    let map = rect
        .into_iter()
        .map(|r| match r {
            Some((u, v)) if cap(u, wf) == u && cap(v, hf) == v => {
                [(u + ox) as f32, (v + oy) as f32]
            }
            _ => [f32::NAN; 2],
        })
        .collect();
    Ok((canvas, map))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{test_cube, Shading};
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    fn small_camera() -> Camera {
        Camera::new(
            320,
            200,
            300.0,
            305.0,
            158.3,
            101.7,
            [-0.25, 0.05, 0.0, 0.0, 0.0],
        )
        .unwrap()
    }

    fn pose(x: f64, z: f64, angle: f64) -> Pose {
        Isometry3::from_parts(
            Translation3::new(x, 0.01, z),
            UnitQuaternion::from_euler_angles(0.3 + angle, -0.4, 0.2),
        )
    }

    fn plane() -> Background {
        Background::Plane(BackgroundPlane {
            t_c_bg: Isometry3::translation(0.0, 0.0, 1.5),
            cell_m: 0.05,
            seed: 3,
        })
    }

    fn sim_camera(margin: u32) -> SimCamera {
        let mesh = Arc::new(test_cube(0.12, Shading::Constant(0.8)));
        let params = SimParams::preset("clean").unwrap();
        SimCamera::new(
            small_camera(),
            mesh,
            RenderOptions::default(),
            plane(),
            params,
            margin,
        )
        .unwrap()
    }

    #[test]
    fn canvas_covers_every_raw_pixel() {
        let cam = small_camera();
        let sc = sim_camera(2);
        assert!(sc.canvas.width > cam.width && sc.canvas.height > cam.height);
        let valid = sc.map.iter().filter(|m| m[0].is_finite()).count();
        assert_eq!(valid, cam.n_pixels());
        // Each raw pixel's tap is the undistorted position shifted into the canvas.
        let (ox, oy) = (sc.canvas.cx - cam.cx, sc.canvas.cy - cam.cy);
        let [u, v] = sc.map[5 * cam.width as usize + 7];
        let (ud, vd) = cam.distort_pixel(f64::from(u) - ox, f64::from(v) - oy);
        assert!(
            (ud - 7.0).abs() < 1e-3 && (vd - 5.0).abs() < 1e-3,
            "({ud}, {vd})"
        );
    }

    #[test]
    fn roi_steps_equal_full_frame_steps() {
        // Same motion through the ROI path and through forced full frames (a margin of the
        // whole sensor makes every region the full sensor).
        let mut roi_cam = sim_camera(2);
        let mut full_cam = sim_camera(1024);
        let (mut a, mut b) = (EventBatch::default(), EventBatch::default());
        let mut total = 0;
        for k in 0..40 {
            let p = pose(-0.05 + 0.002 * k as f64, 0.7, 0.01 * k as f64);
            let ia = roi_cam.advance(&p, 1000 * k, None, &mut a).unwrap();
            full_cam.advance(&p, 1000 * k, None, &mut b).unwrap();
            assert_eq!(a, b, "step {k}");
            if k > 0 {
                assert!(!ia.full_frame && ia.roi.area() < small_camera().n_pixels());
            }
            total += a.len();
        }
        assert!(total > 1000, "the moving cube fires ({total} events)");
        assert_eq!(roi_cam.frame(), full_cam.frame());
    }

    #[test]
    fn static_scene_is_silent_and_moving_background_redraws_everything() {
        for sparse in [true, false] {
            static_scene_then_moving_background(sparse);
        }
    }

    fn static_scene_then_moving_background(sparse: bool) {
        let mut sc = sim_camera(2);
        sc.set_sparse(sparse);
        let mut ev = EventBatch::default();
        let p = pose(0.0, 0.7, 0.0);
        for k in 0..5 {
            sc.advance(&p, 1000 * k, None, &mut ev).unwrap();
            assert!(ev.is_empty());
        }
        let bg = Isometry3::translation(0.03, 0.0, 1.5);
        let info = sc.advance(&p, 6000, Some(&bg), &mut ev).unwrap();
        // A reference frame is full; a sparse one redraws every tile a cell edge crossed.
        let n = small_camera().n_pixels();
        assert_eq!(info.full_frame, !sparse);
        assert!(info.roi.area() > n * 9 / 10, "{:?}", info.roi);
        assert!(ev.len() > 500, "{} events", ev.len());
        // Off-screen object: nothing changes, time still advances.
        let gone = pose(5.0, 0.7, 0.0);
        sc.advance(&gone, 7000, None, &mut ev).unwrap();
        let n_leave = ev.len();
        sc.advance(&gone, 8000, None, &mut ev).unwrap();
        assert!(n_leave > 100 && ev.is_empty());
        assert_eq!(sc.simulator().time_us(), Some(8000));
    }

    #[test]
    fn bad_inputs_are_errors() {
        let mut sc = sim_camera(2);
        let mut ev = EventBatch::default();
        let nan = Isometry3::translation(f64::NAN, 0.0, 1.0);
        assert!(sc.advance(&nan, 0, None, &mut ev).is_err());
        sc.advance(&pose(0.0, 0.7, 0.0), 10, None, &mut ev).unwrap();
        assert!(sc.advance(&pose(0.0, 0.7, 0.0), 10, None, &mut ev).is_err());
        let mesh = Arc::new(test_cube(0.12, Shading::Constant(0.8)));
        let params = SimParams::preset("clean").unwrap();
        let bad_bg = Background::Plane(BackgroundPlane {
            t_c_bg: Pose::identity(),
            cell_m: 0.0,
            seed: 0,
        });
        let opts = RenderOptions::default();
        assert!(SimCamera::new(
            small_camera(),
            mesh.clone(),
            opts,
            bad_bg,
            params.clone(),
            2
        )
        .is_err());
        let mut uniform = SimCamera::new(
            small_camera(),
            mesh,
            opts,
            Background::Uniform(0.2),
            params,
            2,
        )
        .unwrap();
        uniform
            .advance(&pose(0.0, 0.7, 0.0), 0, None, &mut ev)
            .unwrap();
        let bg = Pose::identity();
        assert!(uniform
            .advance(&pose(0.0, 0.7, 0.0), 5, Some(&bg), &mut ev)
            .is_err());
        // Behind the camera: no error (the reference path takes a full frame).
        let behind = pose(0.0, -0.5, 0.0);
        uniform.advance(&behind, 9, None, &mut ev).unwrap();
        uniform.set_sparse(false);
        uniform.advance(&behind, 10, None, &mut ev).unwrap();
        assert!(
            uniform
                .advance(&pose(0.0, -0.4, 0.0), 11, None, &mut ev)
                .unwrap()
                .full_frame
        );
    }

    #[test]
    fn moving_occluders_fire_and_roi_steps_still_equal_full_frames() {
        // A slab (an "arm") sweeps in front of the cube while the cube holds still: it hides part
        // of the cube, fires on its own edges, and the ROI path stays exact.
        let slab = Arc::new(test_cube(0.05, Shading::Constant(0.3)));
        let mut roi_cam = sim_camera(2);
        let mut full_cam = sim_camera(1024);
        roi_cam.set_occluders(vec![slab.clone()]);
        full_cam.set_occluders(vec![slab]);
        let cube = pose(0.0, 0.7, 0.0);
        let slab_at = |k: i64| vec![Isometry3::translation(-0.08 + 0.002 * k as f64, 0.0, 0.5)];
        let (mut a, mut b) = (EventBatch::default(), EventBatch::default());
        let mut total = 0;
        for k in 0..30 {
            let occ = slab_at(k);
            let ia = roi_cam
                .advance_scene(&cube, &occ, 1000 * k, None, &mut a)
                .unwrap();
            full_cam
                .advance_scene(&cube, &occ, 1000 * k, None, &mut b)
                .unwrap();
            assert_eq!(a, b, "step {k}");
            if k > 0 {
                assert!(!ia.full_frame && ia.roi.area() < small_camera().n_pixels());
            }
            total += a.len();
        }
        assert!(total > 500, "the moving slab fires ({total} events)");
        assert_eq!(roi_cam.frame(), full_cam.frame());
        // Its image motion is bounded like the object's: 2 mm at 0.5 m, f = 300 px, ~1.2 px.
        let d = roi_cam
            .occluder_displacement_px(&slab_at(0), &slab_at(1))
            .unwrap();
        assert!((0.8..2.0).contains(&d), "{d}");
        assert_eq!(
            roi_cam
                .occluder_displacement_px(&slab_at(3), &slab_at(3))
                .unwrap(),
            0.0
        );
        // Behind the camera it is not seen and does not count.
        let behind = vec![Isometry3::translation(0.0, 0.0, -0.5)];
        let behind2 = vec![Isometry3::translation(0.01, 0.0, -0.5)];
        assert_eq!(
            roi_cam.occluder_displacement_px(&behind, &behind2).unwrap(),
            0.0
        );
        // Poses must match the occluders.
        assert!(roi_cam
            .advance_scene(&cube, &[], 40_000, None, &mut a)
            .is_err());
        assert!(roi_cam.advance(&cube, 40_000, None, &mut a).is_err());
        assert!(roi_cam.occluder_displacement_px(&[], &[]).is_err());
    }

    #[test]
    fn sparse_frames_equal_the_reference_path() {
        // A moving background (the camera moving against the world), a moving cube and a slab
        // sweeping in front: sparse frames give exactly the events of the full-frame reference.
        let slab = Arc::new(test_cube(0.05, Shading::Constant(0.3)));
        let mut sparse = sim_camera(2);
        let mut reference = sim_camera(2);
        reference.set_sparse(false);
        for c in [&mut sparse, &mut reference] {
            c.set_occluders(vec![slab.clone()]);
        }
        let (mut a, mut b) = (EventBatch::default(), EventBatch::default());
        let (mut total, mut skipped) = (0, 0);
        for k in 0..40 {
            let kf = k as f64;
            let cube = pose(-0.05 + 0.002 * kf, 0.7, 0.01 * kf);
            let occ = [Isometry3::translation(-0.08 + 0.003 * kf, 0.0, 0.5)];
            // The background moves for 20 frames, then holds still.
            let bg = Isometry3::translation(0.001 * kf.min(20.0), -0.0005 * kf.min(20.0), 1.5);
            let info = sparse
                .advance_scene(&cube, &occ, 1000 * k, Some(&bg), &mut a)
                .unwrap();
            reference
                .advance_scene(&cube, &occ, 1000 * k, Some(&bg), &mut b)
                .unwrap();
            assert_eq!(a, b, "frame {k}");
            assert_eq!(sparse.frame(), reference.frame(), "frame {k}");
            total += a.len();
            if k > 0 {
                assert!(!info.full_frame);
                skipped += sparse.changed.iter().filter(|c| !**c).count();
            }
        }
        assert!(total > 5000, "the scene fires ({total} events)");
        // Even with 10-pixel background cells sweeping the view, a third of the tiles are
        // skipped (the real sensor's cells span ~30 pixels).
        let tiles = sparse.changed.len() * 39;
        assert!(skipped * 3 > tiles, "{skipped} of {tiles} tiles skipped");
    }

    #[test]
    fn lab_preset_flickers_at_mains_frequency_and_has_hot_pixels() {
        // A static scene under the `lab` preset: everything lit fires with the 100 Hz flicker,
        // ON while the light rises and OFF while it falls; hot pixels fire at their own rate.
        let mesh = Arc::new(test_cube(0.12, Shading::Constant(0.8)));
        let params = SimParams {
            seed: 2,
            ..SimParams::preset("lab").unwrap()
        };
        let mut sc = SimCamera::new(
            small_camera(),
            mesh,
            RenderOptions::default(),
            plane(),
            params.clone(),
            2,
        )
        .unwrap();
        let mut all = EventBatch::default();
        let mut ev = EventBatch::default();
        let p = pose(0.0, 0.7, 0.0);
        // 20 ms to settle (a pixel's reference starts mid-swing), then 40 ms counted.
        for k in 0..=120 {
            sc.advance(&p, 500 * k, None, &mut ev).unwrap();
            if k > 40 {
                all.extend_from(&ev);
            }
        }
        let n = small_camera().n_pixels();
        // The light dips 0.16 log below its mean; OFF thresholds are N(0.2, 0.03): ~10 % of
        // the pixels lock on.
        let w = small_camera().width as usize;
        let mut fired = vec![false; n];
        for k in 0..all.len() {
            fired[all.y[k] as usize * w + all.x[k] as usize] = true;
        }
        let frac = fired.iter().filter(|f| **f).count() as f64 / n as f64;
        assert!((0.04..0.25).contains(&frac), "{frac} of pixels flicker");
        // d/dt sin(2π·100·t) > 0 on the first and last quarter of each 10 ms period.
        let rising = |t: i64| {
            let phase = (t.rem_euclid(10_000)) as f64 / 10_000.0;
            !(0.25..0.75).contains(&phase)
        };
        let agree = (0..all.len())
            .filter(|&k| rising(all.t_us[k]) == (all.p[k] == 1))
            .count();
        assert!(
            agree * 100 > all.len() * 95,
            "{agree} of {} events follow the light",
            all.len()
        );
        let hot = sc.simulator().hot_pixels();
        assert!(
            !hot.is_empty() && hot.len() < n / 1000 + 10,
            "{} hot pixels",
            hot.len()
        );
        // Without flicker the same static scene is silent but for noise and hot pixels.
        let quiet = SimParams {
            flicker_depth: 0.0,
            ..params
        };
        let mesh = Arc::new(test_cube(0.12, Shading::Constant(0.8)));
        let mut sc = SimCamera::new(
            small_camera(),
            mesh,
            RenderOptions::default(),
            plane(),
            quiet,
            2,
        )
        .unwrap();
        let mut count = 0;
        for k in 0..=120 {
            sc.advance(&p, 500 * k, None, &mut ev).unwrap();
            count += ev.len();
        }
        // Each hot pixel: 500 Hz for 60 ms ≈ 30 events; shot noise and leak add ≈ 40.
        let expected = hot.len() * 30;
        assert!(
            count > expected / 2 && count < 2 * expected + 60,
            "{count} events, {} hot pixels",
            hot.len()
        );
    }

    #[test]
    fn same_cells_never_misses_a_changed_pixel_and_spares_most_border_tiles() {
        // The background plane slides and turns by sub-pixel steps under 18-pixel boxes all over
        // the canvas: whenever `same_cells` says a box kept its cells, every pixel centre of it
        // did (checked one by one); and it says so for most boxes a border crosses.
        let canvas = sim_camera(2).canvas;
        let plane_at = |k: f64| {
            PlaneInCamera::new(BackgroundPlane {
                t_c_bg: Isometry3::from_parts(
                    Translation3::new(0.00005 * k, -0.00003 * k, 1.5),
                    UnitQuaternion::from_euler_angles(0.2, -0.15 + 0.00002 * k, 0.1),
                ),
                cell_m: 0.1,
                seed: 3,
            })
        };
        let (mut spared, mut crossed, mut changed) = (0, 0, 0);
        for k in 0..12 {
            let (before, now) = (plane_at(f64::from(k)), plane_at(f64::from(k) + 1.0));
            for y0 in (0..canvas.height as usize - 18).step_by(7) {
                for x0 in (0..canvas.width as usize - 18).step_by(11) {
                    let b = CanvasBox {
                        x0,
                        y0,
                        x1: x0 + 17,
                        y1: y0 + 17,
                    };
                    let cells = |p: &PlaneInCamera| -> Vec<_> {
                        (y0..=b.y1)
                            .flat_map(|y| (x0..=b.x1).map(move |x| (x, y)))
                            .map(|(x, y)| p.at_row(&canvas, y).cell(x).map(|(_, c)| c))
                            .collect()
                    };
                    let (c0, c1) = (cells(&before), cells(&now));
                    let same = same_cells(&before, &now, &canvas, &b);
                    assert!(!same || c0 == c1, "box {b:?}, step {k}");
                    changed += usize::from(c0 != c1);
                    if c0.iter().any(|c| *c != c0[0]) {
                        crossed += 1;
                        spared += usize::from(same);
                    }
                }
            }
        }
        assert!(crossed > 1000, "{crossed} boxes hold a border");
        assert!(changed > 50, "{changed} boxes changed");
        assert!(
            spared * 2 > crossed,
            "{spared} of {crossed} border boxes spared"
        );
    }

    #[test]
    fn displacement_bounds_the_motion_of_vertices() {
        let sc = sim_camera(2);
        let (a, b) = (pose(0.0, 0.7, 0.0), pose(0.001, 0.7, 0.0));
        let d = sc.max_displacement_px(&a, &b);
        // 1 mm at ~0.7 m with f = 300 px is ~0.43 px at the centre, more where distortion
        // stretches less; the bound is what matters.
        assert!((0.3..0.7).contains(&d), "{d}");
        assert_eq!(sc.max_displacement_px(&a, &a), 0.0);
        assert!(sc
            .max_displacement_px(&a, &pose(0.0, -0.1, 0.0))
            .is_infinite());
    }

    /// The cube moving `dx_m` per 1 ms tick for 60 ticks, rendered every `every` ticks with the
    /// sensor stepped at each tick in between ([`SimCamera::advance_ticks`]); all events.
    fn every_few_ticks(params: SimParams, dx_m: f64, every: usize) -> EventBatch {
        let mesh = Arc::new(test_cube(0.12, Shading::Constant(0.8)));
        let mut sc = SimCamera::new(
            small_camera(),
            mesh,
            RenderOptions::default(),
            plane(),
            params,
            2,
        )
        .unwrap();
        let at = |t_us: i64| pose(dx_m * (t_us / 1000) as f64, 0.7, 0.0);
        let (mut all, mut ev) = (EventBatch::default(), EventBatch::default());
        sc.advance(&at(0), 0, None, &mut ev).unwrap();
        let ticks: Vec<i64> = (1..=60).map(|k| 1000 * k).collect();
        for chunk in ticks.chunks(every) {
            let (&t_us, before) = chunk.split_last().unwrap();
            sc.advance_ticks(&at(t_us), &[], (before, t_us), None, &mut ev)
                .unwrap();
            all.extend_from(&ev);
        }
        all
    }

    fn pixel_counts(ev: &EventBatch) -> Vec<i64> {
        let w = small_camera().width as usize;
        let mut n = vec![0; small_camera().n_pixels()];
        for k in 0..ev.len() {
            n[ev.y[k] as usize * w + ev.x[k] as usize] += 1;
        }
        n
    }

    #[test]
    fn ticks_between_renders_step_the_sensor_as_a_render_per_tick_does() {
        // A still scene under the `lab` preset (flicker, hot pixels, shot noise, leak): frames
        // interpolated between renders 5 ticks apart equal the renders, so the sensor must see
        // exactly the steps, flicker samples and noise of a render per tick.
        let lab = SimParams {
            seed: 2,
            ..SimParams::preset("lab").unwrap()
        };
        let per_tick = every_few_ticks(lab.clone(), 0.0, 1);
        assert!(per_tick.len() > 1000, "{} events", per_tick.len());
        assert_eq!(every_few_ticks(lab, 0.0, 5), per_tick);
        // The cube moving 0.1 px per tick, noise-free: one render per 5 ticks (half a pixel)
        // puts the same events on the same pixels, up to the few whose intensity between two
        // renders is not linear in time (an edge crossing a canvas pixel centre).
        let clean = SimParams::preset("clean").unwrap();
        let dx_m = 0.1 * 0.7 / 300.0;
        let (per_tick, every_5) = (
            every_few_ticks(clean.clone(), dx_m, 1),
            every_few_ticks(clean, dx_m, 5),
        );
        // ... at the same times: the interpolation moves them within the ticks between renders.
        let mean_t = |e: &EventBatch| e.t_us.iter().sum::<i64>() as f64 / e.len() as f64;
        let shift_us = mean_t(&every_5) - mean_t(&per_tick);
        assert!(shift_us.abs() < 250.0, "mean event time {shift_us} µs off");
        let (a, b) = (pixel_counts(&per_tick), pixel_counts(&every_5));
        let total: i64 = a.iter().sum();
        let l1: i64 = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).sum();
        assert!(total > 2000, "{total} events");
        assert!(l1 * 50 < total, "{l1} of {total} events on other pixels");
        let moved: i64 = b.iter().sum();
        assert!(
            (moved - total).abs() * 100 < total,
            "{moved} vs {total} events"
        );
    }

    #[test]
    fn interpolated_ticks_must_lie_between_frames() {
        let mut sc = sim_camera(2);
        let mut ev = EventBatch::default();
        let p = pose(0.0, 0.7, 0.0);
        assert!(sc
            .advance_ticks(&p, &[], (&[500], 1000), None, &mut ev)
            .is_err());
        sc.advance(&p, 0, None, &mut ev).unwrap();
        for bad in [&[0, 500][..], &[600, 500], &[500, 1000]] {
            assert!(sc
                .advance_ticks(&p, &[], (bad, 1000), None, &mut ev)
                .is_err());
        }
        sc.set_sparse(false);
        assert!(sc
            .advance_ticks(&p, &[], (&[500], 1000), None, &mut ev)
            .is_err());
    }
}
