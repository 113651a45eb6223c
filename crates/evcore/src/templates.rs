//! Finding the object without a pose: a bank of viewpoint templates and a global search over it.
//!
//! At start-up the model is rendered from viewpoints spread evenly over the viewing sphere (a
//! Fibonacci lattice at `view_spacing_deg`); each view's S* (its visible edge points, object frame)
//! is kept. The search sweeps every view, in-plane roll (`roll_spacing_deg`) and depth
//! (`depth_min_m`..`depth_max_m` in steps of `depth_ratio`) over a few image positions where the
//! events are densest at the template's scale, scoring a thinned template on the coarsest level of
//! a field built over the whole image; the best candidates go to the caller for LM refinement and
//! the confidence test (a candidate is never trusted on its chamfer score alone).
//!
//! The same bank keeps S* in step with the attitude: the view nearest to the current one gives the
//! point set, so after the object turns far from where S* came from, its edges come from the right
//! side of it (see [`TemplateBank::nearest_view`]).

use crate::camera::Camera;
use crate::error::{ensure, Result};
use crate::field::FieldLevel;
use crate::mesh::Mesh;
use crate::pointset::{extract_point_set, PointSetParams};
use crate::se3::Pose;
use crate::solve::cost::{Pinhole, Rigid32};
use nalgebra::{Translation3, UnitQuaternion, Vector3};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BankParams {
    /// Angular spacing of the viewpoints over the sphere (degrees).
    pub view_spacing_deg: f64,
    /// Spacing of the in-plane rolls searched per view (degrees).
    pub roll_spacing_deg: f64,
    /// Depth range searched (metres) and the ratio between successive depths.
    pub depth_min_m: f64,
    pub depth_max_m: f64,
    pub depth_ratio: f64,
    /// Points per template in the coarse sweep.
    pub coarse_points: usize,
    /// Image positions tried per depth (the densest event windows).
    pub positions_per_depth: usize,
    /// Candidates handed back per depth for refinement. Per depth, because a chamfer score alone
    /// prefers small templates: the edges of a far, small view fit inside those of a near, large
    /// one. The confidence test after refinement, which weighs support against the event density
    /// around the template, tells them apart.
    pub candidates: usize,
}

impl Default for BankParams {
    fn default() -> Self {
        Self {
            view_spacing_deg: 15.0,
            roll_spacing_deg: 15.0,
            depth_min_m: 0.3,
            depth_max_m: 1.5,
            depth_ratio: 1.25,
            coarse_points: 48,
            positions_per_depth: 2,
            candidates: 4,
        }
    }
}

impl BankParams {
    pub fn validate(&self) -> Result<()> {
        let ok = |v: f64| v.is_finite() && v > 0.0;
        ensure(
            ok(self.view_spacing_deg) && self.view_spacing_deg <= 180.0,
            || {
                format!(
                    "view_spacing_deg must be in (0, 180], got {}",
                    self.view_spacing_deg
                )
            },
        )?;
        ensure(
            ok(self.roll_spacing_deg) && self.roll_spacing_deg <= 360.0,
            || {
                format!(
                    "roll_spacing_deg must be in (0, 360], got {}",
                    self.roll_spacing_deg
                )
            },
        )?;
        ensure(
            ok(self.depth_min_m) && ok(self.depth_max_m) && self.depth_min_m <= self.depth_max_m,
            || {
                format!(
                    "depth range must be 0 < min <= max, got {}..{}",
                    self.depth_min_m, self.depth_max_m
                )
            },
        )?;
        ensure(
            self.depth_ratio.is_finite() && self.depth_ratio > 1.0,
            || format!("depth_ratio must be > 1, got {}", self.depth_ratio),
        )?;
        ensure(
            self.coarse_points >= 6 && self.positions_per_depth >= 1 && self.candidates >= 1,
            || "coarse_points >= 6, positions_per_depth >= 1 and candidates >= 1 needed".into(),
        )
    }

    fn depths(&self) -> Vec<f64> {
        let mut out = vec![self.depth_min_m];
        while let Some(&z) = out.last() {
            let next = z * self.depth_ratio;
            if next > self.depth_max_m * (1.0 + 1e-9) {
                break;
            }
            out.push(next);
        }
        out
    }

    fn rolls(&self) -> Vec<f64> {
        let n = (360.0 / self.roll_spacing_deg).round().max(1.0) as usize;
        (0..n)
            .map(|i| (i as f64 * 360.0 / n as f64).to_radians())
            .collect()
    }
}

/// One viewpoint of the bank.
#[derive(Debug, Clone, PartialEq)]
pub struct TemplateView {
    /// The object's attitude in the camera for this view at roll 0.
    pub r_c_o: UnitQuaternion<f64>,
    /// Unit direction from the object's centre to the camera, object frame.
    pub dir_o: Vector3<f64>,
    /// S* rendered from this view (object frame, metres).
    pub points_o: Vec<[f32; 3]>,
    coarse: Vec<[f32; 3]>,
    /// Mean of `coarse` minus the model centre (object frame): where the template's edge mass sits
    /// relative to the centre, so that the sweep can put it on the events' mass.
    coarse_mean_o: Vector3<f64>,
    /// RMS distance of `coarse` from its mean across the view's image plane (metres): the
    /// template's size in the image at unit depth, whatever its roll.
    coarse_spread_m: f64,
}

#[derive(Debug, Clone)]
pub struct TemplateBank {
    pub params: BankParams,
    pub views: Vec<TemplateView>,
    /// Radius of the model about its centroid (metres).
    radius_m: f64,
    centre_o: Vector3<f64>,
}

/// `n` unit vectors spread evenly over the sphere (Fibonacci lattice).
fn fibonacci_sphere(n: usize) -> Vec<Vector3<f64>> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let a = golden * i as f64;
            Vector3::new(r * a.cos(), r * a.sin(), z)
        })
        .collect()
}

/// The attitude that shows the object from direction `dir_o` (object → camera, object frame):
/// R·dir_o = −z, so the camera on the optical axis looks at that side.
fn attitude_seeing(dir_o: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::rotation_between(dir_o, &-Vector3::z()).unwrap_or_else(|| {
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
    })
}

/// Where the camera sits seen from the object (unit vector, object frame) at pose `t_c_o`.
pub fn camera_direction_o(t_c_o: &Pose, centre_o: &Vector3<f64>) -> Vector3<f64> {
    let cam_o = t_c_o.inverse() * nalgebra::Point3::origin();
    (cam_o.coords - centre_o).normalize()
}

impl TemplateBank {
    /// Render the bank: one S* of up to `points.max_points` per viewpoint, each from the object
    /// centred in front of the (rectified) `camera` at a depth where it fills a good part of it.
    pub fn render(
        mesh: &Mesh,
        camera: &Camera,
        params: BankParams,
        points: &PointSetParams,
    ) -> Result<Self> {
        params.validate()?;
        // Half resolution: S* is a set of 3D points, and a quarter of the pixels renders four
        // times faster while its edges still sit within a full-resolution pixel or two.
        let rect = camera.rectified().at_level(0);
        let centre_o = mesh.centroid();
        let radius_m = mesh.bounding_radius().max(1e-3);
        // Fill about half of the shorter image side: edges well resolved, nothing cut off.
        let z = radius_m * rect.fx.min(rect.fy) / (0.25 * f64::from(rect.width.min(rect.height)));
        let n = (4.0 * std::f64::consts::PI / params.view_spacing_deg.to_radians().powi(2))
            .round()
            .max(1.0) as usize;
        let mut views = Vec::with_capacity(n);
        for dir_o in fibonacci_sphere(n) {
            let r_c_o = attitude_seeing(&dir_o);
            let t = Vector3::new(0.0, 0.0, z) - r_c_o * centre_o;
            let pose = Pose::from_parts(Translation3::from(t), r_c_o);
            let set = extract_point_set(mesh, &rect, &pose, points)?;
            if set.points_o.len() < 6 {
                continue;
            }
            let stride = (set.points_o.len() / params.coarse_points).max(1);
            let coarse: Vec<[f32; 3]> = set.points_o.iter().step_by(stride).copied().collect();
            let sum = coarse.iter().fold(Vector3::zeros(), |a, x| {
                a + Vector3::new(f64::from(x[0]), f64::from(x[1]), f64::from(x[2]))
            });
            let mean_o = sum / coarse.len() as f64;
            let coarse_spread_m = image_plane_spread(&r_c_o, &mean_o, &coarse);
            views.push(TemplateView {
                r_c_o,
                dir_o,
                points_o: set.points_o,
                coarse,
                coarse_mean_o: mean_o - centre_o,
                coarse_spread_m,
            });
        }
        ensure(!views.is_empty(), || {
            "no viewpoint of the model gives edge points".into()
        })?;
        Ok(Self {
            params,
            views,
            radius_m,
            centre_o,
        })
    }

    /// The view whose direction is nearest to the camera's direction at `t_c_o`, and the angle
    /// (radians) between them.
    pub fn nearest_view(&self, t_c_o: &Pose) -> (usize, f64) {
        let d = camera_direction_o(t_c_o, &self.centre_o);
        self.views
            .iter()
            .enumerate()
            .map(|(i, v)| (i, v.dir_o.dot(&d).clamp(-1.0, 1.0).acos()))
            .fold((0, f64::INFINITY), |b, c| if c.1 < b.1 { c } else { b })
    }

    pub fn centre_o(&self) -> Vector3<f64> {
        self.centre_o
    }

    /// The sweep's score (mean field value of the thinned template of `view` on `level`) at `pose`.
    pub fn chamfer_at(&self, level: &FieldLevel, pin: &Pinhole, pose: &Pose, view: usize) -> f32 {
        let rig = Rigid32::from_pose(pose);
        chamfer(level, pin, &rig, &self.views[view].coarse, f32::INFINITY).unwrap_or(f32::NAN)
    }

    /// `pose` shifted across the image plane (attitude and depth kept) on a grid of one `coarse`
    /// pixel within [`NEAR_REACH_RADII`] of the object's image radius: the `n` best placements
    /// (pose, mean field value of `view`'s thinned template), each at least half a radius from the
    /// others. The sweep tries only where the events crowd most; with the background in view, that
    /// is rarely where a lost object comes back (robustness suite, occlusion-0.5s: every sweep
    /// candidate 0.25–0.7 m off, the truth's own score the best in the image).
    pub fn search_near(
        &self,
        coarse: &FieldLevel,
        pin: &Pinhole,
        pose: &Pose,
        view: usize,
        n: usize,
    ) -> Vec<(Pose, f32)> {
        let centre = pose * nalgebra::Point3::from(self.centre_o);
        if centre.z <= 0.0 {
            return Vec::new();
        }
        let r_px = (f64::from(pin.fx) * self.radius_m / centre.z).max(1.0);
        let reach = (NEAR_REACH_RADII * r_px).ceil() as i32;
        let shifted = |du: i32, dv: i32| {
            let shift = Vector3::new(
                f64::from(du) * centre.z / f64::from(pin.fx),
                f64::from(dv) * centre.z / f64::from(pin.fy),
                0.0,
            );
            Pose::from_parts(
                Translation3::from(pose.translation.vector + shift),
                pose.rotation,
            )
        };
        let mut scored: Vec<(f32, i32, i32)> = Vec::new();
        for dv in -reach..=reach {
            for du in -reach..=reach {
                let rig = Rigid32::from_pose(&shifted(du, dv));
                let points = &self.views[view].coarse;
                if let Some(c) = chamfer(coarse, pin, &rig, points, f32::INFINITY) {
                    scored.push((c, du, dv));
                }
            }
        }
        scored.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        let apart = (0.5 * r_px).max(1.0);
        let mut out: Vec<(f32, i32, i32)> = Vec::new();
        for s in scored {
            if out.len() == n {
                break;
            }
            let far =
                |o: &(f32, i32, i32)| f64::from((o.1 - s.1).abs().max((o.2 - s.2).abs())) >= apart;
            if out.iter().all(far) {
                out.push(s);
            }
        }
        out.into_iter()
            .map(|(c, du, dv)| (shifted(du, dv), c))
            .collect()
    }

    /// The global sweep on `coarse` (a level of a field built over the whole image, `pin` its
    /// pinhole): per depth, the best `params.candidates` (pose, view index, mean field value) over
    /// views, rolls and the densest positions at that depth's scale.
    pub fn search(&self, coarse: &FieldLevel, pin: &Pinhole) -> Vec<(Pose, usize, f32)> {
        let p = &self.params;
        let oriented = self.oriented(&p.rolls());
        let active = ActiveCounts::new(coarse);
        let keep = p.candidates;
        let mut out = Vec::new();
        for z in p.depths() {
            let mut best = Shortlist::new(keep);
            let r_px = (f64::from(pin.fx) * self.radius_m / z).max(1.0);
            for (u, v) in active.densest(r_px, p.positions_per_depth) {
                // The events' mass near the window (two mean-shift rounds): each template is put
                // with its own edge mass there, not its centre, as the centre of a lopsided object
                // (a drill: its body against its handle) lies far from where its edges crowd.
                let (mut mu, mut mv) = (u, v);
                for _ in 0..2 {
                    (mu, mv) = active.mean_near(mu, mv, r_px).unwrap_or((mu, mv));
                }
                for (oi, o) in oriented.iter().enumerate() {
                    best.try_at(self, coarse, pin, &oriented, oi, placed(pin, o, mu, mv, z));
                }
            }
            out.extend(best.into_poses(&oriented));
        }
        out
    }

    /// Where the events crowd, the bank's every view at every roll (at half the sweep's roll
    /// spacing) placed with its edge mass on theirs at the depth where its size in the image
    /// matches their spread, and [`PLACE_DEPTH_RATIO`] nearer and farther: the `keep` best
    /// (pose, view index, mean field value) over the [`PLACES`] densest places. The sweep's depth
    /// steps (1.25×) leave a right attitude at the wrong scale scoring worse than a wrong one at
    /// a better scale (leave-return: its candidates nearest the truth 15–26° turned and 19–171 mm
    /// off, mostly in depth); here the depth follows each view's own size instead.
    pub fn search_place(
        &self,
        coarse: &FieldLevel,
        pin: &Pinhole,
        keep: usize,
    ) -> Vec<(Pose, usize, f32)> {
        if keep == 0 {
            return Vec::new();
        }
        let p = &self.params;
        let rolls: Vec<f64> = {
            let n = 2 * p.rolls().len();
            (0..n)
                .map(|i| (i as f64 * 360.0 / n as f64).to_radians())
                .collect()
        };
        let oriented = self.oriented(&rolls);
        let active = ActiveCounts::new(coarse);
        let f = f64::from(pin.fx);
        let z_mid = (p.depth_min_m * p.depth_max_m).sqrt();
        let r0 = (f * self.radius_m / z_mid).max(1.0);
        let mut best = Shortlist::new(keep);
        let mut blobs: Vec<(f64, f64, f64)> = Vec::new();
        for (u, v) in active.densest(r0, PLACES) {
            let Some((mu, mv, spread_px)) = active.blob_near(u, v, r0) else {
                continue;
            };
            // Two dense windows on one object lead to the same blob: search it once.
            if blobs
                .iter()
                .any(|b| (b.0 - mu).hypot(b.1 - mv) < b.2.min(spread_px))
            {
                continue;
            }
            blobs.push((mu, mv, spread_px));
            for (oi, o) in oriented.iter().enumerate() {
                let z0 = (f * self.views[o.view].coarse_spread_m / spread_px)
                    .clamp(p.depth_min_m, p.depth_max_m);
                for k in -PLACE_DEPTH_STEPS..=PLACE_DEPTH_STEPS {
                    let z = z0 * PLACE_DEPTH_RATIO.powi(k);
                    best.try_at(self, coarse, pin, &oriented, oi, placed(pin, o, mu, mv, z));
                }
            }
        }
        best.into_poses(&oriented).collect()
    }

    /// `pose` (showing `view`) moved downhill on `level` by the mean field value of that view's
    /// S* (thinned to [`DESCENT_POINTS`]): turned about the camera's three axes through the model
    /// centre, moved along the centre's ray by the step (in radians) as a share of its depth, and
    /// shifted across the image, taking the best of those twelve moves, in steps halved from
    /// [`DESCENT_START_DEG`] whenever none of them lowers it, down to [`DESCENT_END_DEG`]. The
    /// place search's best view is up to half the bank's spacing from the truth, farther than
    /// LM reaches on a field of a few fresh edges (leave-return: its seeds 6–15° off stayed there).
    pub fn descend(&self, level: &FieldLevel, pin: &Pinhole, pose: &Pose, view: usize) -> Pose {
        let all = &self.views[view].points_o;
        let stride = (all.len() / DESCENT_POINTS).max(1);
        let points: Vec<[f32; 3]> = all.iter().step_by(stride).copied().collect();
        let score = |p: &Pose| {
            chamfer(level, pin, &Rigid32::from_pose(p), &points, f32::INFINITY)
                .unwrap_or(f32::INFINITY)
        };
        let mut best = *pose;
        let mut best_cost = score(&best);
        let mut step = DESCENT_START_DEG;
        while step >= DESCENT_END_DEG {
            let centre = best * nalgebra::Point3::from(self.centre_o);
            let a = step.to_radians();
            // A shift across the image as far as the turn moves the model's rim (metres).
            let shift = a * self.radius_m;
            let mut moves: Vec<Pose> = Vec::with_capacity(12);
            for axis in [Vector3::x_axis(), Vector3::y_axis(), Vector3::z_axis()] {
                for s in [-a, a] {
                    let r = UnitQuaternion::from_axis_angle(&axis, s) * best.rotation;
                    let t = centre.coords - r * self.centre_o;
                    moves.push(Pose::from_parts(Translation3::from(t), r));
                }
            }
            for d in [
                Vector3::new(shift, 0.0, 0.0),
                Vector3::new(-shift, 0.0, 0.0),
                Vector3::new(0.0, shift, 0.0),
                Vector3::new(0.0, -shift, 0.0),
                centre.coords * a,
                -centre.coords * a,
            ] {
                moves.push(Pose::from_parts(
                    Translation3::from(best.translation.vector + d),
                    best.rotation,
                ));
            }
            let (cost, at) =
                moves
                    .iter()
                    .map(|m| (score(m), *m))
                    .fold((best_cost, None), |b, c| {
                        if c.0 < b.0 {
                            (c.0, Some(c.1))
                        } else {
                            b
                        }
                    });
            match at {
                Some(m) => {
                    best = m;
                    best_cost = cost;
                }
                None => step *= 0.5,
            }
        }
        best
    }

    /// Every view turned by every roll in `rolls` (radians), in the sweep's order (views, then
    /// rolls): the rotation and what it makes of the template's edge mass and the model centre.
    /// Formed once per sweep rather than once per depth and position (16 times over by default).
    fn oriented(&self, rolls: &[f64]) -> Vec<Oriented> {
        let rolls: Vec<UnitQuaternion<f64>> = rolls
            .iter()
            .map(|&a| UnitQuaternion::from_axis_angle(&Vector3::z_axis(), a))
            .collect();
        let mut out = Vec::with_capacity(self.views.len() * rolls.len());
        for (view, v) in self.views.iter().enumerate() {
            for roll in &rolls {
                let r = roll * v.r_c_o;
                out.push(Oriented {
                    r,
                    rig: Rigid32::from_pose(&Pose::from_parts(Translation3::identity(), r)),
                    mass: r * v.coarse_mean_o,
                    centre: r * self.centre_o,
                    view,
                });
            }
        }
        out
    }
}

/// One view of the bank at one in-plane roll, as the sweep places it (see
/// [`TemplateBank::search`]).
struct Oriented {
    r: UnitQuaternion<f64>,
    /// `r` as the f32 warp (its translation set per placement).
    rig: Rigid32,
    /// The template's edge mass relative to the model centre, and the model centre itself (object
    /// frame), both turned by `r` (metres).
    mass: Vector3<f64>,
    centre: Vector3<f64>,
    view: usize,
}

/// The `keep` best placements of oriented templates tried so far, lowest mean field value first:
/// (mean field value, translation, index into the `Oriented` list). A placement's sum is given up
/// as soon as it cannot beat the worst one kept.
struct Shortlist {
    keep: usize,
    best: Vec<(f32, Vector3<f64>, usize)>,
}

impl Shortlist {
    fn new(keep: usize) -> Self {
        Shortlist {
            keep,
            best: Vec::with_capacity(keep + 1),
        }
    }

    /// `oriented[oi]`'s thinned template with the model translated to `t` (camera frame, metres),
    /// scored on `coarse` and kept if among the best.
    fn try_at(
        &mut self,
        bank: &TemplateBank,
        coarse: &FieldLevel,
        pin: &Pinhole,
        oriented: &[Oriented],
        oi: usize,
        t: Vector3<f64>,
    ) {
        let o = &oriented[oi];
        let rig = Rigid32 {
            t: [t.x as f32, t.y as f32, t.z as f32],
            ..o.rig
        };
        let worst = if self.best.len() < self.keep {
            f32::INFINITY
        } else {
            self.best[self.keep - 1].0
        };
        let Some(cost) = chamfer(coarse, pin, &rig, &bank.views[o.view].coarse, worst) else {
            return;
        };
        let at = self.best.partition_point(|b| b.0 <= cost);
        self.best.insert(at, (cost, t, oi));
        self.best.truncate(self.keep);
    }

    /// The kept placements as (pose, view index, mean field value), best first.
    fn into_poses(self, oriented: &[Oriented]) -> impl Iterator<Item = (Pose, usize, f32)> + '_ {
        self.best.into_iter().map(|(c, t, oi)| {
            let o = &oriented[oi];
            (Pose::from_parts(Translation3::from(t), o.r), o.view, c)
        })
    }
}

/// The translation that puts `o`'s edge mass at image point (`mu`, `mv`) of `pin` with the model
/// centre at depth `z` (metres).
fn placed(pin: &Pinhole, o: &Oriented, mu: f64, mv: f64, z: f64) -> Vector3<f64> {
    let (cu, cv) = (
        mu - f64::from(pin.fx) * o.mass.x / z,
        mv - f64::from(pin.fy) * o.mass.y / z,
    );
    let ray = Vector3::new(
        (cu - f64::from(pin.cx)) / f64::from(pin.fx),
        (cv - f64::from(pin.cy)) / f64::from(pin.fy),
        1.0,
    );
    ray * z - o.centre
}

/// RMS distance (metres) of `points` (object frame) from `mean_o` across the image plane of a
/// camera seeing them at attitude `r_c_o`.
fn image_plane_spread(
    r_c_o: &UnitQuaternion<f64>,
    mean_o: &Vector3<f64>,
    points: &[[f32; 3]],
) -> f64 {
    let sum: f64 = points
        .iter()
        .map(|x| {
            let d =
                r_c_o * (Vector3::new(f64::from(x[0]), f64::from(x[1]), f64::from(x[2])) - mean_o);
            d.x * d.x + d.y * d.y
        })
        .sum();
    (sum / points.len().max(1) as f64).sqrt()
}

/// Points of S* [`TemplateBank::descend`] scores, and its first and last turn (degrees).
const DESCENT_POINTS: usize = 160;
const DESCENT_START_DEG: f64 = 8.0;
const DESCENT_END_DEG: f64 = 1.0;

/// Places (the densest event windows) the place search tries per pass.
const PLACES: usize = 2;
/// Depths the place search tries about each view's own: this many steps of
/// [`PLACE_DEPTH_RATIO`] nearer and farther.
const PLACE_DEPTH_STEPS: i32 = 1;
const PLACE_DEPTH_RATIO: f64 = 1.07;

/// How far (in the object's image radii) [`TemplateBank::search_near`] shifts a pose across the
/// image: a lost object the camera stopped following comes back within a few of its radii of
/// where it was lost (the robustness suite's occlusions: 20–60 mm at Z = 0.9 m, a box radius or so).
pub const NEAR_REACH_RADII: f64 = 2.0;

/// A global-search candidate must account for at least this share of the event mass around it
/// to score in full (stricter than the tracker's [`crate::confidence::EXPLAINED_ENOUGH`]): on the
/// drill and the textured box (sim, Z = 0.7 m, five attitudes), refined true poses explain
/// 0.80–0.99 of it, while the partial fits a sweep finds (a smaller, farther view on part of the
/// edges) explain 0.45–0.73 at a support in excess of chance as high as the truth's. Kept when the
/// events to explain became the freshly fired pixels only: the truth of the robustness suite's
/// leave-return, moving back into view, then explains 0.78–0.92 (0.62–0.69 before), and no
/// candidate elsewhere in its or the other scenarios' passes scored above 0.26
/// (benches/RESULTS.md, issue 12, "Round 16").
pub const EXPLAINED_FOR_ACQUISITION: f32 = 0.8;

/// The score a global-search candidate is accepted on: support in excess of chance (the plain
/// difference, which a sparse full-image field makes hard to earn), times the square of the share
/// of [`EXPLAINED_FOR_ACQUISITION`] it explains of the events around it (squared: a drill fit
/// 15 cm off explaining 0.66 had support − chance 0.63, the truth 0.58); 0 with less than half of
/// the model in view.
pub fn acquisition_score(e: &crate::confidence::Evidence) -> f32 {
    if e.visible < crate::confidence::MIN_VISIBLE {
        return 0.0;
    }
    let explained = (e.explained / EXPLAINED_FOR_ACQUISITION).min(1.0);
    (e.support - e.chance).clamp(0.0, 1.0) * explained * explained
}

/// A candidate is trusted only when it scores this many times as high as any candidate of the
/// same pass that is elsewhere (see `tracker::same_place`): a textured box turned 180° about its
/// axis shows the same outline and scores 0.50–0.66 against the truth's 0.56–0.69. An object whose
/// edges two attitudes explain alike (a plain cube, a box whose print is out of sight) is then
/// never trusted from a global search: the search cannot tell which attitude it is in.
pub const ACQUISITION_MARGIN: f32 = 1.15;

/// Mean field value over the projected `points`, or None as soon as it must exceed `give_up`.
fn chamfer(
    map: &FieldLevel,
    pin: &Pinhole,
    rig: &Rigid32,
    points: &[[f32; 3]],
    give_up: f32,
) -> Option<f32> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2.
        return unsafe { chamfer_avx2(map, pin, rig, points, give_up) };
    }
    let budget = give_up * points.len() as f32;
    let sum = chamfer_sum(map, pin, rig, points, 0.0, budget)?;
    Some(sum / points.len().max(1) as f32)
}

/// `sum` plus the field values at the projected `points` (the level's far value for a point the
/// projection refuses), added one by one in order; None once it reaches `budget`.
fn chamfer_sum(
    map: &FieldLevel,
    pin: &Pinhole,
    rig: &Rigid32,
    points: &[[f32; 3]],
    mut sum: f32,
    budget: f32,
) -> Option<f32> {
    let far = map.max_value();
    for &x in points {
        sum += pin
            .project(rig.apply(x))
            .map_or(far, |(u, v)| map.sample(u, v));
        if sum >= budget {
            return None;
        }
    }
    Some(sum)
}

/// [`chamfer`] eight points at a time: their warp and projection
/// ([`crate::solve::cost::warp_project8_avx2`]) and, when all eight cells lie inside the level,
/// their bilinear values ([`FieldLevel::sample_slope8_avx2`]) in vectors, each lane formed by the
/// same operations as the one-point path and added to the sum in the same order, so the same
/// score. The sum only grows (field values are ≥ 0), so giving up after a chunk instead of after
/// a point refuses the same placements. The sweep scores ≈ 70 000 placements per pass.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn chamfer_avx2(
    map: &FieldLevel,
    pin: &Pinhole,
    rig: &Rigid32,
    points: &[[f32; 3]],
    give_up: f32,
) -> Option<f32> {
    use std::arch::x86_64::_mm256_storeu_ps;
    let budget = give_up * points.len() as f32;
    let mut sum = 0.0f32;
    let mut chunks = points.chunks_exact(8);
    for chunk in &mut chunks {
        // SAFETY: the CPU has AVX2 and the chunk holds eight points.
        let projected = unsafe { crate::solve::cost::warp_project8_avx2(pin, rig, chunk) };
        let Some([value, _, _]) = projected.and_then(|p| map.sample_slope8_avx2(p.u, p.v)) else {
            sum = chamfer_sum(map, pin, rig, chunk, sum, budget)?;
            continue;
        };
        let mut f = [0.0f32; 8];
        // SAFETY: an 8-lane store into an 8-lane array.
        unsafe { _mm256_storeu_ps(f.as_mut_ptr(), value) };
        for v in f {
            sum += v;
        }
        if sum >= budget {
            return None;
        }
    }
    let sum = chamfer_sum(map, pin, rig, chunks.remainder(), sum, budget)?;
    Some(sum / points.len().max(1) as f32)
}

/// The sweep's mask: `mask` (`width` × `height`, full resolution, nonzero = active) pooled into
/// cells of 2^`level` × 2^`level` pixels, a cell active when it holds more active pixels than the
/// background's firing would put there but rarely (see [`background_cell_bar`]); its width and
/// height. A plain OR-pool lets scattered noise light most coarse cells (start-without-pose:
/// 2 % of the pixels active, ≈ 1.3 per 8×8 cell, about three cells in four active), so every
/// template scores a near-zero chamfer anywhere and the sweep cannot tell the object from the
/// clutter; an edge crossing a cell puts several pixels in it.
pub fn pool_above_background(
    mask: &[u8],
    width: usize,
    height: usize,
    level: u32,
) -> (Vec<u8>, usize, usize) {
    let cell = 1usize << level;
    let (w, h) = (width.div_ceil(cell), height.div_ceil(cell));
    let mut counts = vec![0u32; w * h];
    for (y, row) in mask.chunks_exact(width.max(1)).take(height).enumerate() {
        let cells = &mut counts[(y >> level) * w..][..w];
        for (x, &m) in row.iter().enumerate() {
            cells[x >> level] += u32::from(m != 0);
        }
    }
    let bar = background_cell_bar(&counts);
    (counts.iter().map(|&c| u8::from(c >= bar)).collect(), w, h)
}

/// The fewest active pixels a cell must hold to count as active: one more than the background's
/// mean per cell plus three standard deviations (Poisson, so about 1 % of background cells pass).
/// The mean comes from the share of empty cells (−ln of it), which the object's own cells, few
/// and full, hardly move; on a clean image it is near 0 and one pixel is enough, as in an OR-pool.
fn background_cell_bar(counts: &[u32]) -> u32 {
    let n = counts.len().max(1) as f64;
    let empty = counts.iter().filter(|&&c| c == 0).count() as f64;
    let mean = -(empty.max(1.0) / n).ln();
    1 + (mean + 3.0 * mean.sqrt()) as u32
}

/// Half-side of the window [`ActiveCounts::blob_near`] measures a blob's spread in, in spreads:
/// an outline's RMS radius is about 0.7–0.8 of its radius.
const BLOB_WINDOW_SPREADS: f64 = 2.0;

/// Integral image of the active pixels (field value 0) of a level, to find where events crowd.
struct ActiveCounts {
    x0: f64,
    y0: f64,
    w: usize,
    h: usize,
    sums: Vec<u32>,
    active: Vec<bool>,
}

impl ActiveCounts {
    fn new(level: &FieldLevel) -> Self {
        let (w, h) = (level.roi.width as usize, level.roi.height as usize);
        let mut sums = vec![0u32; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0u32;
            for x in 0..w {
                row += u32::from(level.value[y * w + x] == 0.0);
                sums[(y + 1) * (w + 1) + x + 1] = sums[y * (w + 1) + x + 1] + row;
            }
        }
        Self {
            x0: f64::from(level.roi.x0),
            y0: f64::from(level.roi.y0),
            w,
            h,
            sums,
            active: level.value.iter().map(|&f| f == 0.0).collect(),
        }
    }

    /// Mean position (level pixels) of the active pixels within `r_px` (half-side) of (`u`, `v`),
    /// or None when there are none.
    fn mean_near(&self, u: f64, v: f64, r_px: f64) -> Option<(f64, f64)> {
        let (u, v) = (u - self.x0, v - self.y0);
        let clip = |a: f64, n: usize| (a.max(0.0) as usize).min(n);
        let (xa, xb) = (clip(u - r_px, self.w), clip(u + r_px + 1.0, self.w));
        let (ya, yb) = (clip(v - r_px, self.h), clip(v + r_px + 1.0, self.h));
        let (mut n, mut sx, mut sy) = (0usize, 0usize, 0usize);
        for y in ya..yb {
            for x in xa..xb {
                if self.active[y * self.w + x] {
                    n += 1;
                    sx += x;
                    sy += y;
                }
            }
        }
        (n > 0).then(|| {
            (
                sx as f64 / n as f64 + self.x0,
                sy as f64 / n as f64 + self.y0,
            )
        })
    }

    /// The mean position and RMS spread (level pixels) of the active pixels about (`u`, `v`),
    /// each round within twice the last round's spread of the last mean (the first within
    /// `r_px`): the blob there, with little of what lies beyond it.
    fn blob_near(&self, u: f64, v: f64, r_px: f64) -> Option<(f64, f64, f64)> {
        let (mut mu, mut mv, mut r) = (u, v, r_px);
        let mut spread = 0.0;
        for _ in 0..3 {
            let (x0, y0) = (mu - self.x0, mv - self.y0);
            let clip = |a: f64, n: usize| (a.max(0.0) as usize).min(n);
            let (xa, xb) = (clip(x0 - r, self.w), clip(x0 + r + 1.0, self.w));
            let (ya, yb) = (clip(y0 - r, self.h), clip(y0 + r + 1.0, self.h));
            let (mut n, mut sx, mut sy, mut sq) = (0.0, 0.0, 0.0, 0.0);
            for y in ya..yb {
                for x in xa..xb {
                    if self.active[y * self.w + x] {
                        let (x, y) = (x as f64, y as f64);
                        n += 1.0;
                        sx += x;
                        sy += y;
                        sq += x * x + y * y;
                    }
                }
            }
            if n < 1.0 {
                return None;
            }
            let (ax, ay) = (sx / n, sy / n);
            spread = (sq / n - ax * ax - ay * ay).max(0.0).sqrt().max(1.0);
            (mu, mv) = (ax + self.x0, ay + self.y0);
            r = BLOB_WINDOW_SPREADS * spread;
        }
        Some((mu, mv, spread))
    }

    fn count(&self, x0: usize, y0: usize, x1: usize, y1: usize) -> u32 {
        let s = |x: usize, y: usize| self.sums[y * (self.w + 1) + x];
        s(x1, y1) + s(x0, y0) - s(x0, y1) - s(x1, y0)
    }

    /// Centres (level pixels) of the `n` windows of half-side `r_px` holding the most active
    /// pixels, at least a window apart.
    fn densest(&self, r_px: f64, n: usize) -> Vec<(f64, f64)> {
        let r = (r_px.round() as usize).clamp(1, self.w.min(self.h).max(2) / 2);
        if self.w < 2 * r || self.h < 2 * r {
            return Vec::new();
        }
        let step = (r / 4).max(1);
        let mut scored = Vec::new();
        for y in (0..=self.h - 2 * r).step_by(step) {
            for x in (0..=self.w - 2 * r).step_by(step) {
                scored.push((self.count(x, y, x + 2 * r, y + 2 * r), x + r, y + r));
            }
        }
        scored.sort_unstable_by_key(|s| std::cmp::Reverse(s.0));
        let mut out: Vec<(usize, usize)> = Vec::new();
        for (c, x, y) in scored {
            if out.len() == n || c == 0 {
                break;
            }
            if out
                .iter()
                .all(|&(ox, oy)| ox.abs_diff(x) >= r || oy.abs_diff(y) >= r)
            {
                out.push((x, y));
            }
        }
        out.into_iter()
            .map(|(x, y)| (x as f64 + self.x0, y as f64 + self.y0))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::confidence::{evidence, Query};
    use crate::field::{DistanceField, FieldParams};
    use crate::image::Roi;
    use crate::mesh::{test_cube, Shading};
    use crate::se3::distance;
    use crate::solve::lm::{lm_pyramid, LmParams};
    use crate::tracker::{TrackerConfig, TrackerCore};

    #[test]
    fn the_eight_point_chamfer_scores_and_gives_up_as_the_one_point_path() {
        let cam = Camera::imx636().rectified();
        let mesh = test_cube(0.15, Shading::Constant(0.8));
        let r = UnitQuaternion::from_scaled_axis(Vector3::new(0.4, 0.3, 0.1));
        let truth = Pose::from_parts(Translation3::new(0.05, -0.02, 0.7), r);
        let field = edge_field(&mesh, &cam, &truth, &PointSetParams::default());
        // Not a multiple of eight, so the last points take the one-point path.
        let few = PointSetParams {
            max_points: 61,
            ..PointSetParams::default()
        };
        let points = extract_point_set(&mesh, &cam, &truth, &few)
            .unwrap()
            .points_o;
        assert_eq!(points.len() % 8, 5, "{} points", points.len());
        let (level, pin) = (field.level(2), Pinhole::at_level(&cam, 2));
        let n = points.len() as f32;
        let (w, h) = (level.roi.width as f32 - 2.0, level.roi.height as f32 - 2.0);
        let mut rng = crate::rng::Rng::new(7);
        let mut uniform = |a: f64, b: f64| a + (b - a) * rng.uniform();
        let (mut whole, mut cut, mut given_up) = (0, 0, 0);
        for _ in 0..3000 {
            // Over the image, across its borders and behind the camera's minimum depth.
            let t = Translation3::new(uniform(-0.5, 0.5), uniform(-0.3, 0.3), uniform(-0.05, 1.5));
            let axis = Vector3::new(uniform(-3.0, 3.0), uniform(-3.0, 3.0), uniform(-3.0, 3.0));
            let rig =
                Rigid32::from_pose(&Pose::from_parts(t, UnitQuaternion::from_scaled_axis(axis)));
            let sum = chamfer_sum(level, &pin, &rig, &points, 0.0, f32::INFINITY).unwrap();
            let score = chamfer(level, &pin, &rig, &points, f32::INFINITY).unwrap();
            assert_eq!(score.to_bits(), (sum / n).to_bits());
            let inside = points.iter().all(|&x| {
                pin.project(rig.apply(x))
                    .is_some_and(|(u, v)| u >= 1.0 && v >= 1.0 && u < w && v < h)
            });
            if inside {
                whole += 1;
            } else {
                cut += 1;
            }
            let give_up = score * uniform(0.8, 1.2) as f32;
            let kept = chamfer(level, &pin, &rig, &points, give_up);
            assert_eq!(
                kept.is_none(),
                sum >= give_up * n,
                "{score} against {give_up}"
            );
            given_up += usize::from(kept.is_none());
        }
        // Both paths and both outcomes were exercised.
        assert!(
            whole > 100 && cut > 100,
            "{whole} inside, {cut} across a border"
        );
        assert!(given_up > 500 && given_up < 2500, "{given_up} given up");
    }

    #[test]
    fn the_global_search_finds_a_cube_anywhere_in_the_image() {
        let cam = Camera::imx636().rectified();
        let (mesh, bank) = cube_bank(&cam);
        let dense = PointSetParams {
            max_points: 4000,
            ..PointSetParams::default()
        };
        assert!(bank.views.len() > 150, "{} views", bank.views.len());
        let r = UnitQuaternion::from_scaled_axis(Vector3::new(0.5, -0.7, 0.3));
        let truth = Pose::from_parts(Translation3::new(-0.15, 0.08, 0.8), r);
        let field = edge_field(&mesh, &cam, &truth, &dense);
        let full = Roi::full(cam.width, cam.height);
        let pin = Pinhole::at_level(&cam, 0);
        let found = bank.search(field.level(2), &Pinhole::at_level(&cam, 2));
        // The tracker refines each candidate and keeps the most confident; the confidence alone
        // must already point at the right one.
        let confidence = |pose: &Pose, view: usize| {
            let pts = &bank.views[view].points_o;
            let rig = Rigid32::from_pose(pose);
            let uv = pts.iter().filter_map(|&x| pin.project(rig.apply(x)));
            let region = Roi::around(
                uv.map(|(u, v)| (f64::from(u), f64::from(v))),
                16.0,
                cam.width,
                cam.height,
            );
            let q = Query {
                inlier_px: 2.0,
                region: region.unwrap_or(full),
                image: (cam.width, cam.height),
                fresh_since: None,
                explain: true,
            };
            evidence(field.level(0), &pin, &rig, pts, &q).confidence()
        };
        let pyramid: Vec<_> = (0..3)
            .rev()
            .map(|l| (field.level(l), Pinhole::at_level(&cam, l)))
            .collect();
        let refined: Vec<(Pose, usize, f32)> = found
            .iter()
            .map(|&(pose, v, _)| {
                let pts = &bank.views[v].points_o;
                let pivot = crate::solve::cost::centroid(pts);
                let p = lm_pyramid(&pyramid, pose, pts, &pivot, &LmParams::default()).pose;
                (p, v, confidence(&p, v))
            })
            .collect();
        let &(pose, _, conf) = refined.iter().max_by(|a, b| a.2.total_cmp(&b.2)).unwrap();
        let (dt, _) = distance(&pose, &truth);
        // A cube looks the same under its 24 rotations: the relative rotation must be one of them
        // (a signed permutation matrix), not the identity.
        let rel = (truth.rotation.inverse() * pose.rotation).to_rotation_matrix();
        let symmetric = rel
            .matrix()
            .iter()
            .all(|&e| e.abs() < 0.05 || (e.abs() - 1.0).abs() < 0.05);
        assert!(
            dt < 0.005 && symmetric && conf > 0.8,
            "{dt} m, {rel:?}, confidence {conf}"
        );
    }

    /// A 15 cm grey cube and a tracker with no pose searching for it over its template bank.
    #[test]
    fn the_place_search_finds_a_cube_between_the_sweeps_depths_and_the_descent_turns_it_onto_it() {
        // The cube at 0.53 m, between the sweep's depths 0.47 and 0.59 m, at an attitude none of
        // the bank's views shows exactly; the fields are pooled as the tracker pools them at
        // 1280×720 (the sweep's level 3, the descent's level 2).
        let cam = Camera::imx636().rectified();
        let (mesh, bank) = cube_bank(&cam);
        let dense = PointSetParams {
            max_points: 4000,
            ..PointSetParams::default()
        };
        let r = UnitQuaternion::from_scaled_axis(Vector3::new(0.4, -0.6, 0.25));
        let truth = Pose::from_parts(Translation3::new(0.12, -0.05, 0.53), r);
        let edge = extract_point_set(&mesh, &cam, &truth, &dense).unwrap();
        let (w, h) = (cam.width as usize, cam.height as usize);
        let mut mask = vec![0u8; w * h];
        let (rig, pin) = (Rigid32::from_pose(&truth), Pinhole::at_level(&cam, 0));
        for &x in &edge.points_o {
            let (u, v) = pin.project(rig.apply(x)).unwrap();
            mask[v.round() as usize * w + u.round() as usize] = 1;
        }
        let pooled = |level: u32| {
            let (m, pw, ph) = pool_above_background(&mask, w, h, level);
            let params = FieldParams {
                levels: 1,
                ..FieldParams::default()
            };
            let mut f = DistanceField::new(params).unwrap();
            f.build(&m, Roi::full(pw as u32, ph as u32), 1).unwrap();
            f
        };
        let (coarse, fine) = (pooled(3), pooled(2));
        let (pin3, pin2) = (Pinhole::at_level(&cam, 3), Pinhole::at_level(&cam, 2));
        let found = bank.search_place(coarse.level(0), &pin3, 6);
        assert_eq!(found.len(), 6);
        // Off by a cube symmetry (24 look the same): the smallest angle to any of them.
        let off = |pose: &Pose| {
            let (dt, _) = distance(pose, &truth);
            let rel = (truth.rotation.inverse() * pose.rotation).to_rotation_matrix();
            let m = rel.matrix();
            let nearest = m.map(|e| if e.abs() > 0.5 { e.signum() } else { 0.0 });
            let sym = UnitQuaternion::from_matrix(&nearest);
            let ang = UnitQuaternion::from_matrix(m).angle_to(&sym);
            (dt, ang.to_degrees())
        };
        let depth_off = found
            .iter()
            .map(|(p, _, _)| (p * nalgebra::Point3::from(bank.centre_o())).z - 0.53)
            .fold(f64::INFINITY, |a, d| a.min(d.abs()));
        assert!(depth_off < 0.02, "nearest depth {depth_off} m off");
        let descended: Vec<(f64, f64)> = found
            .iter()
            .map(|(p, v, _)| off(&bank.descend(fine.level(0), &pin2, p, *v)))
            .collect();
        let before = found
            .iter()
            .map(|(p, _, _)| off(p).1)
            .fold(f64::INFINITY, f64::min);
        let best = descended
            .iter()
            .copied()
            .fold((f64::INFINITY, f64::INFINITY), |a, b| {
                if b.1 < a.1 {
                    b
                } else {
                    a
                }
            });
        assert!(
            best.0 < 0.01 && best.1 < 3.0,
            "descended {best:?} (before: nearest {before:.1}°); all {descended:?}"
        );
    }

    #[test]
    fn the_search_near_a_lost_pose_puts_it_back_on_the_object() {
        let cam = Camera::imx636().rectified();
        let (mesh, bank) = cube_bank(&cam);
        let r = UnitQuaternion::from_scaled_axis(Vector3::new(0.5, -0.7, 0.3));
        let truth = Pose::from_parts(Translation3::new(-0.05, 0.03, 0.8), r);
        let field = edge_field(&mesh, &cam, &truth, &PointSetParams::default());
        // Lost 60 mm to the side and 40 mm up (within two of the cube's image radii at 0.8 m).
        let lost = Pose::from_parts(Translation3::new(0.01, -0.01, 0.8), r);
        let view = bank.nearest_view(&truth).0;
        let near = bank.search_near(field.level(2), &Pinhole::at_level(&cam, 2), &lost, view, 3);
        assert_eq!(near.len(), 3);
        let (dt, dr) = distance(&near[0].0, &truth);
        // One level-2 pixel is 4 full-resolution pixels, 3.5 mm at 0.8 m.
        assert!(
            dt < 0.004 && dr < 1e-9,
            "best placement {dt} m, {dr} rad off"
        );
    }

    #[test]
    fn a_sweep_cell_needs_more_pixels_than_the_background_puts_there() {
        // Clean, the object's edges in 3 cells of 100: an OR-pool (one pixel is enough).
        let mut counts = vec![0u32; 97];
        counts.extend([9, 12, 3]);
        assert_eq!(background_cell_bar(&counts), 1);
        // Poisson(1.3) background (e^-1.3 = 27 % of cells empty): mean 1.3 + 3 × 1.14 → 5.
        let mut counts = vec![0u32; 27];
        counts.extend(std::iter::repeat_n(2, 73));
        assert_eq!(background_cell_bar(&counts), 5);
        // Every cell full: bounded, not infinite.
        assert!(background_cell_bar(&[64; 100]) < 20);
    }

    /// Scattered noise on 2 % of the pixels (the robustness suite's start-without-pose: about
    /// 1.3 active pixels per 8×8 sweep cell). OR-pooled, it lights three sweep cells in four and
    /// no sweep candidate lands on the cube; pooled above the background, one does.
    #[test]
    fn the_sweep_finds_a_cube_in_scattered_noise() {
        let cam = Camera::imx636().rectified();
        let (mesh, bank) = cube_bank(&cam);
        let r = UnitQuaternion::from_scaled_axis(Vector3::new(0.5, -0.7, 0.3));
        let truth = Pose::from_parts(Translation3::new(-0.15, 0.08, 0.8), r);
        let dense = PointSetParams {
            max_points: 4000,
            ..PointSetParams::default()
        };
        let (w, h) = (cam.width as usize, cam.height as usize);
        let mut mask = vec![0u8; w * h];
        let (rig, pin) = (Rigid32::from_pose(&truth), Pinhole::at_level(&cam, 0));
        for &x in &extract_point_set(&mesh, &cam, &truth, &dense)
            .unwrap()
            .points_o
        {
            let (u, v) = pin.project(rig.apply(x)).unwrap();
            mask[v.round() as usize * w + u.round() as usize] = 1;
        }
        let mut state = 0x9e37_79b9_7f4a_7c15u64; // xorshift64: reproducible noise
        for m in &mut mask {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            *m |= u8::from(state.is_multiple_of(50));
        }
        // The sweep's level at 1280×720 (160 px wide).
        let level = 3;
        let cell = 1usize << level;
        let (cw, ch) = (w.div_ceil(cell), h.div_ceil(cell));
        let mut or_pooled = vec![0u8; cw * ch];
        for (i, &m) in mask.iter().enumerate() {
            or_pooled[(i / w / cell) * cw + (i % w) / cell] |= m;
        }
        let (above, aw, ah) = pool_above_background(&mask, w, h, level);
        assert_eq!((aw, ah), (cw, ch));
        let sweep_pin = Pinhole::at_level(&cam, level);
        let centre = |p: &Pose| {
            pin.project(Rigid32::from_pose(p).apply(centre_of(&bank)))
                .unwrap()
        };
        let (tu, tv) = centre(&truth);
        let r_px = f64::from(pin.fx) * bank.radius_m / truth.translation.z;
        let on_cube = |pooled: &[u8]| {
            let mut field = DistanceField::new(FieldParams {
                levels: 1,
                ..FieldParams::default()
            })
            .unwrap();
            field
                .build(pooled, Roi::full(cw as u32, ch as u32), 1)
                .unwrap();
            let found = bank.search(field.level(0), &sweep_pin);
            let active = pooled.iter().filter(|&&m| m != 0).count() as f64 / pooled.len() as f64;
            let nearest = found
                .iter()
                .map(|(p, _, _)| {
                    let (u, v) = centre(p);
                    f64::from((u - tu).hypot(v - tv))
                })
                .fold(f64::INFINITY, f64::min);
            (nearest < 0.25 * r_px, active, nearest)
        };
        let (found_or, active_or, off_or) = on_cube(&or_pooled);
        assert!(
            !found_or && active_or > 0.6,
            "OR-pooled: {active_or} of the cells active, nearest candidate {off_or} px off"
        );
        let (found, active, off) = on_cube(&above);
        assert!(
            found && active < 0.1,
            "pooled above the background: {active} of the cells active, nearest {off} px off \
             (the cube's image radius {r_px} px)"
        );
    }

    fn centre_of(bank: &TemplateBank) -> [f32; 3] {
        let c = bank.centre_o();
        [c.x as f32, c.y as f32, c.z as f32]
    }

    /// A 15 cm grey cube and its template bank (default spacing and depths).
    fn cube_bank(cam: &Camera) -> (Mesh, TemplateBank) {
        let mesh = test_cube(0.15, Shading::Constant(0.8));
        let bank = TemplateBank::render(
            &mesh,
            cam,
            BankParams::default(),
            &PointSetParams::default(),
        )
        .unwrap();
        (mesh, bank)
    }

    /// A three-level field over the whole image of `mesh`'s edge points at `pose`, each one pixel.
    fn edge_field(
        mesh: &Mesh,
        cam: &Camera,
        pose: &Pose,
        params: &PointSetParams,
    ) -> DistanceField {
        let edge = extract_point_set(mesh, cam, pose, params).unwrap();
        let full = Roi::full(cam.width, cam.height);
        let mut mask = vec![0u8; full.area()];
        let (rig, pin) = (Rigid32::from_pose(pose), Pinhole::at_level(cam, 0));
        for &x in &edge.points_o {
            let (u, v) = pin.project(rig.apply(x)).unwrap();
            mask[v.round() as usize * cam.width as usize + u.round() as usize] = 1;
        }
        let mut field = DistanceField::new(FieldParams::default()).unwrap();
        field.build(&mask, full, 3).unwrap();
        field
    }

    fn searching_cube(cam: &Camera) -> (Mesh, TrackerCore) {
        let (mesh, bank) = cube_bank(cam);
        let core = TrackerCore::searching(cam, bank, TrackerConfig::default()).unwrap();
        (mesh, core)
    }

    #[test]
    fn a_pass_needs_newer_events_and_a_symmetric_cube_is_never_trusted() {
        use crate::event::EventBatch;
        // A camera without distortion: the events below are written at rectified pixels.
        let cam = Camera::imx636().rectified();
        let (mesh, mut core) = searching_cube(&cam);
        let r = UnitQuaternion::from_scaled_axis(Vector3::new(0.5, -0.7, 0.3));
        let truth = Pose::from_parts(Translation3::new(-0.15, 0.08, 0.8), r);
        let dense = PointSetParams {
            max_points: 4000,
            ..PointSetParams::default()
        };
        let edge = extract_point_set(&mesh, &cam, &truth, &dense).unwrap();
        let pin = Pinhole::at_level(&cam, 0);
        let rig = Rigid32::from_pose(&truth);
        // The whole outline firing once per millisecond (a still cube under flicker).
        let outline = |t: i64| {
            let mut batch = EventBatch::default();
            for &x in &edge.points_o {
                let (u, v) = pin.project(rig.apply(x)).unwrap();
                batch.push(u.round() as u16, v.round() as u16, 1, t);
            }
            batch
        };
        core.ingest(&outline(1000)).unwrap();
        assert!(core.step().lost, "trusted after a single pass");
        let passes = core.stats().reacquire_passes;
        assert!(core.step().lost);
        assert_eq!(
            core.stats().reacquire_passes,
            passes,
            "no newer events: the same pass run again"
        );
        // Found every pass (a clean outline), but the cube's turns explain its edges alike: which
        // of its attitudes it is in cannot be told, so none is trusted.
        for k in 2..6 {
            core.ingest(&outline(k * 1000)).unwrap();
            let e = core.step();
            assert!(e.lost, "pass {k}: {e:?}");
        }
        assert_eq!(core.stats().reacquire_passes, passes + 4);
    }

    #[test]
    fn a_tracker_without_a_pose_never_relocks_on_a_wrong_pose() {
        use crate::event::EventBatch;
        let raw = Camera::imx636();
        let cam = raw.rectified();
        let (mesh, mut core) = searching_cube(&cam);
        assert!(core.latest().lost);
        let r = UnitQuaternion::from_scaled_axis(Vector3::new(0.5, -0.7, 0.3));
        let at =
            |k: i64| Pose::from_parts(Translation3::new(-0.15 + 2e-4 * k as f64, 0.08, 0.8), r);
        let dense = PointSetParams {
            max_points: 4000,
            ..PointSetParams::default()
        };
        let edge = extract_point_set(&mesh, &cam, &at(0), &dense).unwrap();
        let pin = Pinhole::at_level(&cam, 0);
        // Events where an edge point changes pixel (about one pixel every 3 ms at 0.2 m/s), plus
        // 20 % uniform noise.
        let pixel = |k: i64, x: [f32; 3]| {
            let (u, v) = pin.project(Rigid32::from_pose(&at(k)).apply(x)).unwrap();
            (u.round() as u16, v.round() as u16)
        };
        let mut rng = crate::rng::Rng::new(5);
        for k in 1..60 {
            let mut batch = EventBatch::default();
            for &x in &edge.points_o {
                let p = pixel(k, x);
                if p != pixel(k - 1, x) {
                    batch.push(p.0, p.1, 1, k * 1000);
                    if rng.below(5) == 0 {
                        batch.push(rng.below(1280) as u16, rng.below(720) as u16, 0, k * 1000);
                    }
                }
            }
            core.ingest(&batch).unwrap();
        }
        // The sweep does not always find a sparse, smeared cube in one pass; what it must never do
        // is re-lock on a wrong pose.
        for _ in 0..3 {
            let e = core.step();
            let (dt, _) = distance(&e.pose, &at(59));
            assert!(e.lost || dt < 0.01, "{e:?} {dt}");
        }
    }
}
