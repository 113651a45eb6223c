//! A z-buffered CPU triangle rasterizer into the rectified (pinhole) grid of a [`Camera`].
//!
//! Distortion is ignored on purpose: callers pass `camera.rectified()`, and the event simulator
//! remaps to the raw grid afterwards. Pixel (x, y) is the sample at its centre, the point (x, y)
//! of [`Camera::project_pinhole`]; there is one sample per pixel and no anti-aliasing.
//!
//! Pipeline: vertices go to the camera frame, each face is clipped against the near plane,
//! projected and turned into edge functions; the triangles are binned into bands of rows, and
//! rayon renders the bands in parallel, each band first resolving visibility (1/z test plus the
//! winning triangle's id) and then shading only its visible pixels, so overdraw costs no shading.
//! [`Renderer`] keeps every buffer between frames.

use crate::camera::Camera;
use crate::error::{ensure, Result};
use crate::image::Roi;
use crate::mesh::{Mesh, Shading};
use crate::se3::Pose;
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

/// Near clipping plane in metres (camera z). Geometry closer than this is cut away.
pub const NEAR_PLANE_M: f64 = 1e-3;

/// Rows per parallel work item: small enough to balance two to many cores, large enough that
/// binning a triangle into bands stays cheap.
const BAND_ROWS: usize = 8;

/// Slack, in barycentric units, that admits pixel centres lying exactly on an edge shared by two
/// triangles despite round-off; the z-test settles the resulting one-sample overlaps.
const EDGE_EPS: f64 = 1e-9;

const NO_TRIANGLE: u32 = u32::MAX;

/// Headlight Lambertian shading: `albedo * (ambient + diffuse * |n · view|)`, flat per face, so
/// that creases between faces show up as intensity edges.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    pub ambient: f32,
    pub diffuse: f32,
    /// Intensity of pixels the object does not cover.
    pub background: f32,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            ambient: 0.35,
            diffuse: 0.65,
            background: 0.0,
        }
    }
}

/// One rendered region, row-major over `roi` (index (y − y0)·width + (x − x0)).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Rendered {
    pub roi: Roi,
    /// Camera-frame z in metres; `f32::INFINITY` on background.
    pub depth_m: Vec<f32>,
    pub intensity: Vec<f32>,
    /// Camera-frame unit face normals, turned to face the camera; zeros on background.
    pub normal_c: Vec<[f32; 3]>,
}

impl Rendered {
    /// Buffer index of image pixel (x, y), `None` outside the region.
    pub fn index(&self, x: u32, y: u32) -> Option<usize> {
        self.roi.contains(x, y).then(|| {
            (y - self.roi.y0) as usize * self.roi.width as usize + (x - self.roi.x0) as usize
        })
    }

    pub fn is_foreground(&self, i: usize) -> bool {
        self.depth_m[i].is_finite()
    }
}

/// Screen-space setup of one (possibly near-clipped) triangle. Barycentric coordinates are affine
/// in the pixel position: λᵢ(x, y) = a[i]·x + b[i]·y + c[i].
#[derive(Debug, Clone, Copy)]
struct Tri {
    a: [f64; 3],
    b: [f64; 3],
    c: [f64; 3],
    /// 1/z of the three vertices (1/metres); 1/z is affine in screen space, z is not.
    inv_z: [f64; 3],
    /// Per-vertex albedo in `[0]` or UV, depending on the mesh's shading.
    attr: [[f32; 2]; 3],
    normal_c: [f32; 3],
    /// Index of the triangle's mesh in the rendered scene.
    mesh: u32,
    /// Inclusive pixel bounds, already clipped to the region.
    x_lo: i64,
    x_hi: i64,
    y_lo: i64,
    y_hi: i64,
}

impl Tri {
    #[inline]
    fn barycentric(&self, x: f64, y: f64) -> [f64; 3] {
        std::array::from_fn(|i| self.a[i] * x + self.b[i] * y + self.c[i])
    }

    #[inline]
    fn inv_z_at(&self, l: &[f64; 3]) -> f64 {
        l[0] * self.inv_z[0] + l[1] * self.inv_z[1] + l[2] * self.inv_z[2]
    }

    /// Inclusive x range of pixel centres of row `y` inside the triangle, clipped to the bounds.
    #[inline]
    fn span(&self, y: f64) -> Option<(i64, i64)> {
        let (mut lo, mut hi) = (self.x_lo as f64, self.x_hi as f64);
        for i in 0..3 {
            let k = self.b[i] * y + self.c[i] + EDGE_EPS;
            if self.a[i] > 0.0 {
                lo = lo.max(-k / self.a[i]);
            } else if self.a[i] < 0.0 {
                hi = hi.min(-k / self.a[i]);
            } else if k < 0.0 {
                return None;
            }
        }
        // Clamped to one column beyond the box, which keeps every non-empty span and leaves an
        // empty one empty, so that the integer rounding below stays in range.
        let lo = ceil_i64(lo.min(self.x_hi as f64 + 1.0));
        let hi = floor_i64(hi.max(self.x_lo as f64 - 1.0));
        (lo <= hi).then_some((lo, hi))
    }
}

/// ⌊v⌋ for finite |v| < 2⁶³. `f64::floor` is a libm call without SSE4.1 (not in the baseline
/// x86-64 target); this is one cast and a compare.
#[inline]
pub(crate) fn floor_i64(v: f64) -> i64 {
    let i = v as i64;
    i - i64::from(v < i as f64)
}

/// ⌈v⌉ for finite |v| < 2⁶³, as [`floor_i64`].
#[inline]
pub(crate) fn ceil_i64(v: f64) -> i64 {
    let i = v as i64;
    i + i64::from(v > i as f64)
}

/// A vertex during clipping: camera-frame position and its shading attribute.
#[derive(Debug, Clone, Copy)]
struct ClipVertex {
    p: Vector3<f64>,
    attr: [f32; 2],
}

/// Sutherland–Hodgman against z ≥ near; a triangle becomes at most a quadrilateral.
fn clip_near(tri: [ClipVertex; 3], out: &mut [ClipVertex; 4]) -> usize {
    let mut n = 0;
    for i in 0..3 {
        let (cur, next) = (tri[i], tri[(i + 1) % 3]);
        let (cur_in, next_in) = (cur.p.z >= NEAR_PLANE_M, next.p.z >= NEAR_PLANE_M);
        if cur_in {
            out[n] = cur;
            n += 1;
        }
        if cur_in != next_in {
            let t = (NEAR_PLANE_M - cur.p.z) / (next.p.z - cur.p.z);
            let tf = t as f32;
            out[n] = ClipVertex {
                p: cur.p + (next.p - cur.p) * t,
                attr: [
                    cur.attr[0] + (next.attr[0] - cur.attr[0]) * tf,
                    cur.attr[1] + (next.attr[1] - cur.attr[1]) * tf,
                ],
            };
            n += 1;
        }
    }
    n
}

/// Whether a sphere (centre in the camera frame, radius, metres) cannot reach pixels
/// `[x_lo, x_hi] × [y_lo, y_hi]` of pinhole `cam` (inclusive pixel bounds): it lies wholly behind
/// the near plane, or wholly beyond one side plane of the region's viewing frustum, grown by one
/// pixel so that rounding cannot cull a triangle [`setup`] would keep. Near-clipped points stay
/// inside the sphere (they lie on its triangles), so a culled mesh would yield no triangle.
pub fn sphere_misses(cam: &Camera, centre: &Vector3<f64>, radius: f64, bounds: [f64; 4]) -> bool {
    if centre.z + radius < NEAR_PLANE_M {
        return true;
    }
    let [x_lo, x_hi, y_lo, y_hi] = bounds;
    // A point p in front of the camera projects left of u₀ iff fx·x + (cx − u₀)·z < 0: the
    // half-space below a plane through the optical centre with normal (fx, 0, cx − u₀).
    let beyond = |n: Vector3<f64>| n.dot(centre) + radius * n.norm() < 0.0;
    beyond(Vector3::new(cam.fx, 0.0, cam.cx - (x_lo - 1.0)))
        || beyond(Vector3::new(-cam.fx, 0.0, (x_hi + 1.0) - cam.cx))
        || beyond(Vector3::new(0.0, cam.fy, cam.cy - (y_lo - 1.0)))
        || beyond(Vector3::new(0.0, -cam.fy, (y_hi + 1.0) - cam.cy))
}

/// Edge-function setup of a projected triangle; `None` when it has no area on screen or misses
/// the region `[rx0, rx1] × [ry0, ry1]` (inclusive pixel bounds).
fn setup(
    cam: &Camera,
    v: [ClipVertex; 3],
    normal_c: [f32; 3],
    mesh: u32,
    bounds: [i64; 4],
) -> Option<Tri> {
    let s: [(f64, f64); 3] = v.map(|c| {
        (
            cam.fx * c.p.x / c.p.z + cam.cx,
            cam.fy * c.p.y / c.p.z + cam.cy,
        )
    });
    let [(x0, y0), (x1, y1), (x2, y2)] = s;
    let d = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0);
    if !d.is_finite() || d.abs() < 1e-12 {
        return None;
    }
    let [rx0, rx1, ry0, ry1] = bounds;
    let clamp = |lo: f64, hi: f64, min: i64, max: i64| -> Option<(i64, i64)> {
        let lo = lo.ceil().max(min as f64);
        let hi = hi.floor().min(max as f64);
        (lo <= hi).then_some((lo as i64, hi as i64))
    };
    let (x_lo, x_hi) = clamp(x0.min(x1).min(x2), x0.max(x1).max(x2), rx0, rx1)?;
    let (y_lo, y_hi) = clamp(y0.min(y1).min(y2), y0.max(y1).max(y2), ry0, ry1)?;
    let inv_d = 1.0 / d;
    Some(Tri {
        a: [(y1 - y2) * inv_d, (y2 - y0) * inv_d, (y0 - y1) * inv_d],
        b: [(x2 - x1) * inv_d, (x0 - x2) * inv_d, (x1 - x0) * inv_d],
        c: [
            (x1 * y2 - x2 * y1) * inv_d,
            (x2 * y0 - x0 * y2) * inv_d,
            (x0 * y1 - x1 * y0) * inv_d,
        ],
        inv_z: v.map(|c| 1.0 / c.p.z),
        attr: v.map(|c| c.attr),
        normal_c,
        mesh,
        x_lo,
        x_hi,
        y_lo,
        y_hi,
    })
}

/// Holds the buffers of one render target so that repeated renders allocate nothing.
#[derive(Debug, Default)]
pub struct Renderer {
    verts_c: Vec<Vector3<f64>>,
    tris: Vec<Tri>,
    /// Region the prepared triangles were clipped to, and the scene's mesh count.
    prepared: Option<(Roi, usize)>,
    bins: Vec<Vec<u32>>,
    out: Rendered,
}

impl Renderer {
    pub fn new() -> Self {
        Self::default()
    }

    /// The last render.
    pub fn rendered(&self) -> &Rendered {
        &self.out
    }

    pub fn into_rendered(self) -> Rendered {
        self.out
    }

    /// Render `mesh` at pose `t_c_o` (object in camera) into `roi` of the camera's pinhole grid
    /// (the full image when `None`). The camera's distortion is ignored.
    pub fn render_into(
        &mut self,
        mesh: &Mesh,
        camera: &Camera,
        t_c_o: &Pose,
        roi: Option<Roi>,
        opts: &RenderOptions,
    ) -> Result<&Rendered> {
        self.render_scene_into(&[(mesh, t_c_o)], camera, roi, opts)
    }

    /// Render several meshes, each at its own pose in the camera, into one intensity and depth
    /// buffer: the nearest surface wins each pixel (a z-test across meshes, e.g. the object and
    /// the arms occluding it). Shading is per mesh; `opts` applies to all. An empty scene renders
    /// background only.
    pub fn render_scene_into(
        &mut self,
        scene: &[(&Mesh, &Pose)],
        camera: &Camera,
        roi: Option<Roi>,
        opts: &RenderOptions,
    ) -> Result<&Rendered> {
        let roi = roi.unwrap_or(Roi::full(camera.width, camera.height));
        self.prepare_scene(scene, camera, Some(roi), opts)?;
        self.draw_prepared(scene, camera, roi, opts)
    }

    /// Screen boxes of the prepared triangles: (mesh index in the scene, [x_lo, x_hi, y_lo, y_hi])
    /// in inclusive pixels, clipped to the prepared region. A pixel no box contains shows no mesh.
    pub fn triangle_boxes(&self) -> impl Iterator<Item = (u32, [i64; 4])> + '_ {
        self.tris
            .iter()
            .map(|t| (t.mesh, [t.x_lo, t.x_hi, t.y_lo, t.y_hi]))
    }

    /// First half of [`Self::render_scene_into`]: validate, pose, near-clip and project the
    /// scene's triangles for `region` (the full image when `None`), without drawing. Then
    /// [`Self::triangle_boxes`] tells where the scene can be, and [`Self::draw_prepared`] draws
    /// any sub-region with exactly the pixels a direct render of it would give.
    pub fn prepare_scene(
        &mut self,
        scene: &[(&Mesh, &Pose)],
        camera: &Camera,
        region: Option<Roi>,
        opts: &RenderOptions,
    ) -> Result<()> {
        let roi = region.unwrap_or(Roi::full(camera.width, camera.height));
        self.prepared = None;
        ensure(roi.width > 0 && roi.height > 0, || {
            format!("render region {roi:?} is empty")
        })?;
        ensure(
            roi.x0
                .checked_add(roi.width)
                .is_some_and(|x| x <= camera.width)
                && roi
                    .y0
                    .checked_add(roi.height)
                    .is_some_and(|y| y <= camera.height),
            || {
                format!(
                    "render region {roi:?} exceeds the {}x{} image",
                    camera.width, camera.height
                )
            },
        )?;
        ensure(
            camera.fx.is_finite() && camera.fy.is_finite() && camera.fx > 0.0 && camera.fy > 0.0,
            || {
                format!(
                    "camera focal lengths fx={}, fy={} must be finite and positive",
                    camera.fx, camera.fy
                )
            },
        )?;
        for (_, t_c_o) in scene {
            let finite_pose = t_c_o
                .translation
                .vector
                .iter()
                .chain(t_c_o.rotation.coords.iter())
                .all(|v| v.is_finite());
            ensure(finite_pose, || {
                "pose T_c_o contains NaN or infinite entries".into()
            })?;
        }
        ensure(
            [opts.ambient, opts.diffuse, opts.background]
                .iter()
                .all(|v| v.is_finite()),
            || format!("render options must be finite, got {opts:?}"),
        )?;
        ensure(u32::try_from(scene.len()).is_ok(), || {
            "too many meshes in the scene".into()
        })?;

        let bounds = [
            i64::from(roi.x0),
            i64::from(roi.x0 + roi.width) - 1,
            i64::from(roi.y0),
            i64::from(roi.y0 + roi.height) - 1,
        ];
        self.tris.clear();
        let region = bounds.map(|b| b as f64);
        for (mesh_id, &(mesh, t_c_o)) in scene.iter().enumerate() {
            let mesh_id = mesh_id as u32;
            // Meshes out of view (e.g. most links of the camera's own arm) cost nothing.
            let (centre, radius) = mesh.bounding_sphere();
            if sphere_misses(
                camera,
                &(t_c_o * Point3::from(centre)).coords,
                radius,
                region,
            ) {
                continue;
            }
            self.verts_c.clear();
            self.verts_c
                .par_extend(mesh.vertices.par_iter().with_min_len(1024).map(|v| {
                    (t_c_o * Point3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]))).coords
                }));
            let attr_of = |k: usize| -> [f32; 2] {
                match &mesh.shading {
                    Shading::Constant(_) => [0.0, 0.0],
                    Shading::VertexIntensity(a) => [a[k], 0.0],
                    Shading::Textured { uv, .. } => uv[k],
                }
            };
            let verts_c = &self.verts_c;
            self.tris
                .par_extend(mesh.faces.par_iter().with_min_len(256).flat_map_iter(|f| {
                    let v = f.map(|k| ClipVertex {
                        p: verts_c[k as usize],
                        attr: attr_of(k as usize),
                    });
                    let mut n = (v[1].p - v[0].p).cross(&(v[2].p - v[0].p));
                    let mut out = [v[0]; 4];
                    let count = match n.try_normalize(0.0) {
                        Some(unit) if v.iter().any(|c| c.p.z >= NEAR_PLANE_M) => {
                            // Face the camera: the view ray to the face is +p, so n·p must be
                            // negative.
                            n = if unit.dot(&v[0].p) > 0.0 { -unit } else { unit };
                            clip_near(v, &mut out)
                        }
                        _ => 0,
                    };
                    let normal = [n.x as f32, n.y as f32, n.z as f32];
                    (1..count.saturating_sub(1)).filter_map(move |i| {
                        setup(
                            camera,
                            [out[0], out[i], out[i + 1]],
                            normal,
                            mesh_id,
                            bounds,
                        )
                    })
                }));
        }
        self.prepared = Some((roi, scene.len()));
        Ok(())
    }

    /// Second half of [`Self::render_scene_into`]: draw the triangles of the last
    /// [`Self::prepare_scene`] into `roi`, which must lie inside the prepared region. `scene`
    /// must be the prepared one (its meshes give the shading).
    pub fn draw_prepared(
        &mut self,
        scene: &[(&Mesh, &Pose)],
        camera: &Camera,
        roi: Roi,
        opts: &RenderOptions,
    ) -> Result<&Rendered> {
        self.draw_prepared_rows(scene, camera, roi, None, opts)
    }

    /// [`Self::draw_prepared`] restricted to a column range per row: `rows[k]` is the inclusive
    /// pixel range [x_lo, x_hi] drawn in row `roi.y0 + k` (empty when x_lo > x_hi). Only depth
    /// and intensity inside the ranges are written: the rest of `roi`, and `normal_c`, hold
    /// whatever they held (the rendered camera reads no more). Drawn pixels equal those of a
    /// whole-region draw up to the rounding of 1/z stepped from a different first column.
    pub fn draw_prepared_rows(
        &mut self,
        scene: &[(&Mesh, &Pose)],
        camera: &Camera,
        roi: Roi,
        rows: Option<&[(i64, i64)]>,
        opts: &RenderOptions,
    ) -> Result<&Rendered> {
        ensure(rows.is_none_or(|r| r.len() == roi.height as usize), || {
            format!(
                "{} column ranges for the {} rows of {roi:?}",
                rows.map_or(0, <[_]>::len),
                roi.height
            )
        })?;
        let Some((region, n_meshes)) = self.prepared else {
            return Err(crate::Error::InvalidArgument(
                "draw_prepared before prepare_scene".into(),
            ));
        };
        ensure(
            n_meshes == scene.len()
                && roi.width > 0
                && roi.height > 0
                && roi.x0 >= region.x0
                && roi.y0 >= region.y0
                && roi.x0 + roi.width <= region.x0 + region.width
                && roi.y0 + roi.height <= region.y0 + region.height,
            || {
                format!("draw region {roi:?} is empty or outside the prepared {region:?}, or the scene changed")
            },
        )?;
        let bounds = [
            i64::from(roi.x0),
            i64::from(roi.x0 + roi.width) - 1,
            i64::from(roi.y0),
            i64::from(roi.y0 + roi.height) - 1,
        ];
        let meshes: Vec<&Mesh> = scene.iter().map(|(m, _)| *m).collect();

        let (w, h) = (roi.width as usize, roi.height as usize);
        let n_bands = h.div_ceil(BAND_ROWS);
        // Each band's columns: the union of its rows' ranges (the whole region without `rows`).
        let band_cols: Vec<(i64, i64)> = (0..n_bands)
            .map(|b| match rows {
                None => (bounds[0], bounds[1]),
                Some(r) => r[b * BAND_ROWS..((b + 1) * BAND_ROWS).min(h)].iter().fold(
                    (i64::MAX, i64::MIN),
                    |(lo, hi), &(a, z)| {
                        if a > z {
                            (lo, hi)
                        } else {
                            (lo.min(a), hi.max(z))
                        }
                    },
                ),
            })
            .collect();
        self.bins.resize_with(n_bands, Vec::new);
        self.bins.iter_mut().for_each(Vec::clear);
        for (id, t) in self.tris.iter().enumerate() {
            let (y_lo, y_hi) = (t.y_lo.max(bounds[2]), t.y_hi.min(bounds[3]));
            if t.x_hi < bounds[0] || t.x_lo > bounds[1] || y_lo > y_hi {
                continue;
            }
            let first = (y_lo - bounds[2]) as usize / BAND_ROWS;
            let last = (y_hi - bounds[2]) as usize / BAND_ROWS;
            for (bin, &(lo, hi)) in self.bins[first..=last]
                .iter_mut()
                .zip(&band_cols[first..=last])
            {
                if t.x_hi >= lo && t.x_lo <= hi {
                    bin.push(id as u32);
                }
            }
        }

        let n = roi.area();
        self.out.roi = roi;
        self.out.depth_m.resize(n, 0.0);
        self.out.intensity.resize(n, 0.0);
        self.out.normal_c.resize(n, [0.0; 3]);
        let band_len = BAND_ROWS * w;
        let (tris, bins, rows_cols) = (&self.tris, &self.bins, rows);
        let Rendered {
            depth_m,
            intensity,
            normal_c,
            ..
        } = &mut self.out;
        depth_m
            .par_chunks_mut(band_len)
            .zip(intensity.par_chunks_mut(band_len))
            .zip(normal_c.par_chunks_mut(band_len))
            .enumerate()
            // Triangle ids live in a per-worker scratch band that stays in cache; a full-frame
            // id buffer would add megabytes of memory traffic per frame.
            .for_each_init(Vec::new, |scratch, (band, ((depth, inten), normals))| {
                scratch.resize(depth.len(), NO_TRIANGLE);
                let ids = &mut scratch[..depth.len()];
                let y_first = bounds[2] + (band * BAND_ROWS) as i64;
                let rows = depth.len() / w;
                let band_bounds = Band {
                    x0: bounds[0],
                    y0: y_first,
                    width: w,
                    rows,
                    cols: rows_cols.map(|r| &r[band * BAND_ROWS..band * BAND_ROWS + rows]),
                };
                rasterize_band(tris, &bins[band], &band_bounds, depth, ids);
                shade_band(
                    &meshes,
                    camera,
                    opts,
                    tris,
                    &band_bounds,
                    depth,
                    ids,
                    inten,
                    normals,
                );
            });
        Ok(&self.out)
    }
}

/// Image position of one band: its first pixel (x0, y0), width and number of rows, and the
/// inclusive column range drawn in each of its rows (all of them when `None`).
struct Band<'a> {
    x0: i64,
    y0: i64,
    width: usize,
    rows: usize,
    cols: Option<&'a [(i64, i64)]>,
}

/// Visibility pass: `inv_z` holds 1/z (0 = nothing yet), `ids` the winning triangle.
fn rasterize_band(tris: &[Tri], bin: &[u32], band: &Band, inv_z: &mut [f32], ids: &mut [u32]) {
    inv_z.fill(0.0);
    ids.fill(NO_TRIANGLE);
    let y_end = band.y0 + band.rows as i64 - 1;
    for &id in bin {
        let t = &tris[id as usize];
        for y in t.y_lo.max(band.y0)..=t.y_hi.min(y_end) {
            let yf = y as f64;
            let Some((xs, xe)) = t.span(yf) else { continue };
            // Clipping to the band's columns here equals clipping the box at setup: the bounds
            // are integers, so they commute with the span's rounding.
            let (xs, xe) = (xs.max(band.x0), xe.min(band.x0 + band.width as i64 - 1));
            let (xs, xe) = match band.cols {
                Some(c) => {
                    let (lo, hi) = c[(y - band.y0) as usize];
                    (xs.max(lo), xe.min(hi))
                }
                None => (xs, xe),
            };
            if xs > xe {
                continue;
            }
            let row = (y - band.y0) as usize * band.width;
            // 1/z is affine along the row, so step it instead of re-evaluating the barycentrics.
            let iz_a = t.a[0] * t.inv_z[0] + t.a[1] * t.inv_z[1] + t.a[2] * t.inv_z[2];
            let mut iz = t.inv_z_at(&t.barycentric(xs as f64, yf));
            for x in xs..=xe {
                let i = row + (x - band.x0) as usize;
                let izf = iz as f32;
                if izf > inv_z[i] {
                    inv_z[i] = izf;
                    ids[i] = id;
                }
                iz += iz_a;
            }
        }
    }
}

/// Shading pass over the visible pixels; turns `depth` from 1/z into metres. Works on runs of
/// pixels won by the same triangle, so the shading model is chosen once per run and the
/// barycentrics are stepped along the row instead of re-evaluated.
#[allow(clippy::too_many_arguments)]
fn shade_band(
    meshes: &[&Mesh],
    cam: &Camera,
    opts: &RenderOptions,
    tris: &[Tri],
    band: &Band,
    depth: &mut [f32],
    ids: &[u32],
    intensity: &mut [f32],
    normals: &mut [[f32; 3]],
) {
    let w = band.width;
    for r in 0..band.rows {
        let y = (band.y0 + r as i64) as f64;
        // With column ranges only they are shaded, and normals are left alone.
        let (mut c, w) = match band.cols {
            Some(cols) => {
                let (lo, hi) = cols[r];
                let (lo, hi) = (lo.max(band.x0), hi.min(band.x0 + w as i64 - 1));
                if lo > hi {
                    continue;
                }
                ((lo - band.x0) as usize, (hi - band.x0) as usize + 1)
            }
            None => (0, w),
        };
        while c < w {
            let row = r * band.width;
            let id = ids[row + c];
            let end = ids[row + c..row + w]
                .iter()
                .position(|&k| k != id)
                .map_or(w, |n| c + n);
            let run = row + c..row + end;
            let normals = band.cols.is_none().then_some(&mut *normals);
            if id == NO_TRIANGLE {
                depth[run.clone()].fill(f32::INFINITY);
                intensity[run.clone()].fill(opts.background);
                if let Some(n) = normals {
                    n[run].fill([0.0; 3]);
                }
            } else {
                let t = &tris[id as usize];
                let x0 = (band.x0 + c as i64) as f64;
                let out = Run {
                    depth: &mut depth[run.clone()],
                    intensity: &mut intensity[run.clone()],
                };
                match &meshes[t.mesh as usize].shading {
                    Shading::Constant(a) => shade_run(cam, opts, t, x0, y, out, |_| *a),
                    Shading::VertexIntensity(_) => shade_run(cam, opts, t, x0, y, out, |a| a[0]),
                    Shading::Textured { texture, .. } => {
                        shade_run(cam, opts, t, x0, y, out, |uv| texture.sample(uv[0], uv[1]))
                    }
                }
                if let Some(n) = normals {
                    n[run].fill(t.normal_c);
                }
            }
            c = end;
        }
    }
}

/// Output slices of one run of pixels.
struct Run<'a> {
    depth: &'a mut [f32],
    intensity: &'a mut [f32],
}

/// Shade a run of pixels of triangle `t` starting at pixel (x0, y); `albedo` maps the
/// perspective-correct vertex attribute to an albedo.
#[inline(always)]
fn shade_run(
    cam: &Camera,
    opts: &RenderOptions,
    t: &Tri,
    x0: f64,
    y: f64,
    out: Run<'_>,
    albedo: impl Fn([f32; 2]) -> f32,
) {
    let mut l = t.barycentric(x0, y);
    let n = t.normal_c.map(f64::from);
    let inv_fx = 1.0 / cam.fx;
    let ry = (y - cam.cy) / cam.fy;
    // n · ray is affine along the row; |ray|² is quadratic, so it is evaluated per pixel.
    let mut rx = (x0 - cam.cx) * inv_fx;
    let ry2_1 = ry * ry + 1.0;
    let n_dot_base = n[1] * ry + n[2];
    for (d, i) in out.depth.iter_mut().zip(out.intensity.iter_mut()) {
        let pz = [l[0] * t.inv_z[0], l[1] * t.inv_z[1], l[2] * t.inv_z[2]];
        let z = 1.0 / (pz[0] + pz[1] + pz[2]);
        // Perspective-correct weights: λᵢ/zᵢ normalised by their sum 1/z.
        let wgt = pz.map(|v| (v * z) as f32);
        let attr = std::array::from_fn(|k| {
            wgt[0] * t.attr[0][k] + wgt[1] * t.attr[1][k] + wgt[2] * t.attr[2][k]
        });
        let cos = ((n[0] * rx + n_dot_base) / (rx * rx + ry2_1).sqrt()).abs() as f32;
        *d = z as f32;
        *i = albedo(attr) * (opts.ambient + opts.diffuse * cos);
        for (lk, ak) in l.iter_mut().zip(&t.a) {
            *lk += ak;
        }
        rx += inv_fx;
    }
}

/// Render once into fresh buffers; see [`Renderer::render_into`].
pub fn render(
    mesh: &Mesh,
    camera: &Camera,
    t_c_o: &Pose,
    roi: Option<Roi>,
    opts: &RenderOptions,
) -> Result<Rendered> {
    let mut r = Renderer::new();
    r.render_into(mesh, camera, t_c_o, roi, opts)?;
    Ok(r.into_rendered())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{test_cube as cube, Texture};
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    fn cam() -> Camera {
        Camera::new(320, 240, 300.0, 310.0, 161.3, 118.7, [0.0; 5]).unwrap()
    }

    fn pose() -> Pose {
        Isometry3::from_parts(
            Translation3::new(0.05, -0.03, 1.2),
            UnitQuaternion::from_euler_angles(0.4, -0.5, 0.3),
        )
    }

    /// Signed distance (pixels, positive inside) from (x, y) to the convex polygon `hull` (CCW or CW).
    fn signed_dist(hull: &[(f64, f64)], x: f64, y: f64) -> f64 {
        let area: f64 = (0..hull.len())
            .map(|i| {
                let (a, b) = (hull[i], hull[(i + 1) % hull.len()]);
                a.0 * b.1 - b.0 * a.1
            })
            .sum();
        let s = area.signum();
        (0..hull.len())
            .map(|i| {
                let (a, b) = (hull[i], hull[(i + 1) % hull.len()]);
                let (ex, ey) = (b.0 - a.0, b.1 - a.1);
                s * (ex * (y - a.1) - ey * (x - a.0)) / (ex * ex + ey * ey).sqrt()
            })
            .fold(f64::INFINITY, f64::min)
    }

    fn convex_hull(mut p: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
        p.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let cross = |o: (f64, f64), a: (f64, f64), b: (f64, f64)| {
            (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0)
        };
        let mut hull: Vec<(f64, f64)> = Vec::new();
        for pass in 0..2 {
            let start = hull.len();
            let iter: Box<dyn Iterator<Item = &(f64, f64)>> = if pass == 0 {
                Box::new(p.iter())
            } else {
                Box::new(p.iter().rev())
            };
            for &q in iter {
                while hull.len() >= start + 2
                    && cross(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0.0
                {
                    hull.pop();
                }
                hull.push(q);
            }
            hull.pop();
        }
        hull
    }

    #[test]
    fn cube_depth_matches_the_analytic_planes_and_silhouette_matches_projection() {
        let (cam, pose) = (cam(), pose());
        let mesh = cube(0.3, Shading::Constant(0.8));
        let r = render(&mesh, &cam, &pose, None, &RenderOptions::default()).unwrap();
        let mut fg = 0;
        for y in 0..cam.height {
            for x in 0..cam.width {
                let i = r.index(x, y).unwrap();
                if !r.is_foreground(i) {
                    continue;
                }
                fg += 1;
                // The face plane n·p = d in the camera frame: n is the outward normal of a visible face,
                // so d is the largest n·p over the cube's vertices.
                let n = Vector3::from(r.normal_c[i].map(f64::from));
                let d = (0..8)
                    .map(|k| {
                        n.dot(
                            &(pose * Point3::from(Vector3::from(mesh.vertices[k].map(f64::from))))
                                .coords,
                        )
                    })
                    .fold(f64::NEG_INFINITY, f64::max);
                let ray = cam.ray(f64::from(x), f64::from(y));
                let z = d / n.dot(&ray);
                assert!(
                    (f64::from(r.depth_m[i]) - z).abs() < 2e-6,
                    "({x},{y}): {} vs {z}",
                    r.depth_m[i]
                );
                assert!((n.norm() - 1.0).abs() < 1e-5 && n.dot(&ray) < 0.0);
            }
        }
        assert!(fg > 5000, "cube covers only {fg} pixels");
        let projected: Vec<(f64, f64)> = mesh
            .vertices
            .iter()
            .map(|v| {
                cam.project_pinhole(&(pose * Point3::from(Vector3::from(v.map(f64::from)))).coords)
                    .unwrap()
            })
            .collect();
        let hull = convex_hull(projected);
        assert!(hull.len() >= 6, "a tilted cube shows a hexagonal outline");
        for y in 0..cam.height {
            for x in 0..cam.width {
                let s = signed_dist(&hull, f64::from(x), f64::from(y));
                let is_fg = r.is_foreground(r.index(x, y).unwrap());
                assert!(
                    s.abs() < 1e-6 || is_fg == (s > 0.0),
                    "pixel ({x},{y}) at {s:.3} px from the outline, fg {is_fg}"
                );
            }
        }
    }

    #[test]
    fn crease_shows_in_intensity_and_background_is_clean() {
        let (cam, pose) = (cam(), pose());
        let opts = RenderOptions {
            background: 0.25,
            ..Default::default()
        };
        let r = render(&cube(0.3, Shading::Constant(1.0)), &cam, &pose, None, &opts).unwrap();
        let mut levels: Vec<f32> = (0..r.depth_m.len())
            .filter(|&i| r.is_foreground(i))
            .map(|i| r.intensity[i])
            .collect();
        levels.sort_by(f32::total_cmp);
        levels.dedup_by(|a, b| (*a - *b).abs() < 0.02);
        assert!(
            levels.len() >= 3,
            "three visible faces give three shades, got {levels:?}"
        );
        assert!(levels.iter().all(|&l| (0.35..=1.0).contains(&l)));
        let bg = (0..r.depth_m.len()).find(|&i| !r.is_foreground(i)).unwrap();
        assert_eq!(
            (r.intensity[bg], r.normal_c[bg], r.depth_m[bg]),
            (0.25, [0.0; 3], f32::INFINITY)
        );
    }

    #[test]
    fn roi_render_equals_the_crop_of_a_full_render() {
        let (cam, pose) = (cam(), pose());
        let tex = Texture {
            width: 4,
            height: 4,
            data: (0..16).map(|i| (i % 5) as f32 / 4.0).collect(),
        };
        let mesh = cube(0.3, Shading::Constant(0.5));
        let uv = mesh
            .vertices
            .iter()
            .map(|v| [v[0] / 0.3 + 0.5, v[1] / 0.3 + 0.5])
            .collect();
        let mesh = Mesh {
            shading: Shading::Textured { uv, texture: tex },
            ..mesh
        };
        let full = render(&mesh, &cam, &pose, None, &RenderOptions::default()).unwrap();
        let roi = Roi {
            x0: 101,
            y0: 57,
            width: 93,
            height: 61,
        };
        let mut renderer = Renderer::new();
        let part = renderer
            .render_into(&mesh, &cam, &pose, Some(roi), &RenderOptions::default())
            .unwrap()
            .clone();
        assert_eq!(part.depth_m.len(), 93 * 61);
        for y in roi.y0..roi.y0 + roi.height {
            for x in roi.x0..roi.x0 + roi.width {
                let (i, j) = (full.index(x, y).unwrap(), part.index(x, y).unwrap());
                assert_eq!(
                    (full.depth_m[i], full.intensity[i]),
                    (part.depth_m[j], part.intensity[j])
                );
            }
        }
        // Reusing the renderer for the full frame reproduces the one-shot render exactly.
        assert_eq!(
            renderer
                .render_into(&mesh, &cam, &pose, None, &RenderOptions::default())
                .unwrap(),
            &full
        );
    }

    #[test]
    fn vertex_intensity_is_perspective_correct() {
        // A floor plane receding in depth, albedo = its own z coordinate in the object frame.
        let cam = cam();
        let v = vec![
            [-1.0, 0.2, 0.5],
            [1.0, 0.2, 0.5],
            [1.0, 0.2, 3.0],
            [-1.0, 0.2, 3.0],
        ];
        let albedo = v.iter().map(|p: &[f32; 3]| p[2] / 3.0).collect();
        let mesh = Mesh::new(
            v,
            vec![[0, 1, 2], [0, 2, 3]],
            Shading::VertexIntensity(albedo),
        )
        .unwrap();
        let opts = RenderOptions {
            ambient: 1.0,
            diffuse: 0.0,
            background: 0.0,
        };
        let r = render(&mesh, &cam, &Pose::identity(), None, &opts).unwrap();
        let mut checked = 0;
        for i in (0..r.depth_m.len()).filter(|&i| r.is_foreground(i)) {
            assert!(
                (r.intensity[i] - r.depth_m[i] / 3.0).abs() < 1e-4,
                "{} vs {}",
                r.intensity[i],
                r.depth_m[i]
            );
            checked += 1;
        }
        assert!(checked > 1000);
    }

    #[test]
    fn triangles_crossing_the_camera_plane_are_clipped() {
        let cam = cam();
        // A wall at z = 0.5 m plus a triangle reaching from behind the camera to z = 2 m.
        let v = vec![
            [-5.0, -5.0, 0.5],
            [5.0, -5.0, 0.5],
            [0.0, 5.0, 0.5],
            [0.0, 0.1, -1.0],
            [0.3, 0.1, 2.0],
            [-0.3, 0.1, 2.0],
        ];
        let mesh = Mesh::new(v, vec![[0, 1, 2], [3, 4, 5]], Shading::Constant(0.5)).unwrap();
        let r = render(
            &mesh,
            &cam,
            &Pose::identity(),
            None,
            &RenderOptions::default(),
        )
        .unwrap();
        assert!(r
            .depth_m
            .iter()
            .all(|d| d.is_finite() && *d >= NEAR_PLANE_M as f32 && *d <= 0.5 + 1e-6));
        assert!(r.intensity.iter().all(|v| v.is_finite()));
        let nearer = r.depth_m.iter().filter(|&&d| d < 0.499).count();
        assert!(
            nearer > 100,
            "the clipped triangle covers pixels in front of the wall ({nearer})"
        );
        // Entirely behind the camera: nothing drawn, no error.
        let behind = Isometry3::translation(0.0, 0.0, -3.0);
        let r = render(&mesh, &cam, &behind, None, &RenderOptions::default()).unwrap();
        assert!(r.depth_m.iter().all(|d| d.is_infinite()));
    }

    #[test]
    fn culled_meshes_would_draw_nothing() {
        // A cube swept out of view across each side of the image and of a region, and through
        // the camera plane: wherever the sphere test culls it, a render without the test (the
        // mesh's triangles set up one by one) covers no pixel; and far enough out it culls.
        let cam = cam();
        let mesh = cube(0.2, Shading::Constant(0.5));
        let (centre, radius) = mesh.bounding_sphere();
        assert!(mesh.vertices.iter().all(|v| (Vector3::new(
            f64::from(v[0]),
            f64::from(v[1]),
            f64::from(v[2])
        ) - centre)
            .norm()
            <= radius));
        let regions = [[0.0, 319.0, 0.0, 239.0], [100.0, 179.0, 60.0, 139.0]];
        let mut culled = 0;
        for bounds in regions {
            for k in -40..=40 {
                let s = f64::from(k) * 0.05;
                for t in [
                    Isometry3::translation(s, 0.0, 1.0),
                    Isometry3::translation(0.0, s, 1.0),
                    Isometry3::translation(0.3 * s, 0.2, 0.4 * s),
                ] {
                    let t = t * Isometry3::rotation(Vector3::new(0.3, 0.2 * s, 0.1));
                    let c = (t * Point3::from(centre)).coords;
                    if !sphere_misses(&cam, &c, radius, bounds) {
                        continue;
                    }
                    culled += 1;
                    let roi = Roi {
                        x0: bounds[0] as u32,
                        y0: bounds[2] as u32,
                        width: (bounds[1] - bounds[0]) as u32 + 1,
                        height: (bounds[3] - bounds[2]) as u32 + 1,
                    };
                    let ib = bounds.map(|b| b as i64);
                    for f in &mesh.faces {
                        let v = f.map(|k| {
                            let p = mesh.vertices[k as usize];
                            let q = Point3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
                            ClipVertex {
                                p: (t * q).coords,
                                attr: [0.0; 2],
                            }
                        });
                        let mut out = [v[0]; 4];
                        let n = clip_near(v, &mut out);
                        for i in 1..n.saturating_sub(1) {
                            let tri = [out[0], out[i], out[i + 1]];
                            assert!(
                                setup(&cam, tri, [0.0; 3], 0, ib).is_none(),
                                "{t:?} culled in {roi:?} but a triangle reaches it"
                            );
                        }
                    }
                }
            }
        }
        assert!(culled > 100, "{culled} poses culled");
    }

    #[test]
    fn scene_render_z_tests_across_meshes() {
        // A bright far cube and a dark near cube partly in front of it: every pixel of the scene
        // render is the nearer of the two single-mesh renders, with that mesh's shading.
        let cam = cam();
        let far = cube(0.3, Shading::Constant(1.0));
        let near = cube(0.1, Shading::Constant(0.2));
        let (p_far, p_near) = (pose(), Isometry3::translation(0.08, 0.0, 0.7));
        let opts = RenderOptions::default();
        let a = render(&far, &cam, &p_far, None, &opts).unwrap();
        let b = render(&near, &cam, &p_near, None, &opts).unwrap();
        let mut r = Renderer::new();
        let both = r
            .render_scene_into(&[(&far, &p_far), (&near, &p_near)], &cam, None, &opts)
            .unwrap();
        let (mut overlap, mut n) = (0, 0);
        for i in 0..both.depth_m.len() {
            let (da, db) = (a.depth_m[i], b.depth_m[i]);
            let want = if db <= da { &b } else { &a };
            assert_eq!(both.depth_m[i], want.depth_m[i], "pixel {i}");
            assert_eq!(both.intensity[i], want.intensity[i], "pixel {i}");
            overlap += usize::from(da.is_finite() && db.is_finite());
            n += usize::from(both.depth_m[i].is_finite());
        }
        assert!(
            overlap > 500,
            "the near cube hides part of the far one ({overlap})"
        );
        assert!(n > overlap);
        // The order of the meshes does not matter.
        let swapped = r
            .render_scene_into(&[(&near, &p_near), (&far, &p_far)], &cam, None, &opts)
            .unwrap();
        assert_eq!(swapped.depth_m, both_depth(&a, &b));
        // An empty scene is all background.
        let empty = r.render_scene_into(&[], &cam, None, &opts).unwrap();
        assert!(empty.depth_m.iter().all(|d| d.is_infinite()));
    }

    fn both_depth(a: &Rendered, b: &Rendered) -> Vec<f32> {
        a.depth_m
            .iter()
            .zip(&b.depth_m)
            .map(|(x, y)| x.min(*y))
            .collect()
    }

    #[test]
    fn bad_inputs_are_errors() {
        let (cam, mesh) = (cam(), cube(0.3, Shading::Constant(0.5)));
        let opts = RenderOptions::default();
        let p = pose();
        assert!(render(
            &mesh,
            &cam,
            &p,
            Some(Roi {
                x0: 300,
                y0: 0,
                width: 30,
                height: 10
            }),
            &opts
        )
        .is_err());
        assert!(render(
            &mesh,
            &cam,
            &p,
            Some(Roi {
                x0: 0,
                y0: 0,
                width: 0,
                height: 10
            }),
            &opts
        )
        .is_err());
        assert!(render(
            &mesh,
            &cam,
            &p,
            Some(Roi {
                x0: u32::MAX,
                y0: 0,
                width: 2,
                height: 10
            }),
            &opts
        )
        .is_err());
        let nan = Isometry3::translation(f64::NAN, 0.0, 1.0);
        assert!(render(&mesh, &cam, &nan, None, &opts).is_err());
        assert!(render(
            &mesh,
            &cam,
            &p,
            None,
            &RenderOptions {
                ambient: f32::NAN,
                ..opts
            }
        )
        .is_err());
    }
}
