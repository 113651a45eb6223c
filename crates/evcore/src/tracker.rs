//! The tracker: events in, poses out.
//!
//! [`TrackerCore`] is the synchronous engine (ingest a batch, run steps); it is what deterministic
//! simulation and tests drive. [`ThreadedTracker`] moves a core into its own thread: batches come in
//! through a lock-free bounded queue whose producer never blocks (when the solver falls behind, the
//! oldest queued batch is dropped and counted), and the newest estimate goes out through a seqlock,
//! so neither side ever waits on a lock held by the other.
//!
//! One *update* = one published pose = one LM or one search step on a field rebuilt from the
//! current active set. LM steps build the full pyramid; search steps only need the full-resolution
//! level, which is most of why they are cheap.

use crate::camera::{Camera, UndistortLut};
use crate::error::{ensure, Error, Result};
use crate::event::EventBatch;
use crate::field::{DistanceField, FieldParams};
use crate::image::Roi;
use crate::se3::Pose;
use crate::solve::cost::{centroid, cost_stats, Pinhole, Rigid32, ViewMask};
use crate::solve::lm::{lm_pyramid, LmParams};
use crate::solve::search::{axis_steps, search_step};
use crate::solve::{Schedule, SolverMode, StepKind};
use crate::surface::{make_surface, EventSurface, FrontEnd};
use crossbeam_queue::ArrayQueue;
use nalgebra::{Point3, Quaternion, Translation3, UnitQuaternion, Vector3};
use std::sync::atomic::{fence, AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

#[derive(Debug, Clone, PartialEq)]
pub struct TrackerConfig {
    pub solver: SolverMode,
    /// Search steps per LM step in the cascade (the paper's N = 4).
    pub n_search: usize,
    pub frontend: FrontEnd,
    pub field: FieldParams,
    pub lm: LmParams,
    /// Margin around the projected model for the field's region of interest on LM steps
    /// (full-res pixels); covers the coarsest level's basin (τ·4) plus some motion.
    pub roi_margin_px: f64,
    /// The same for search steps, which only sample the full-resolution field within a pixel or two
    /// of the projected points: τ plus a little. A smaller region is a cheaper field.
    pub search_roi_margin_px: f64,
    /// A point within this distance of an event counts as an inlier (full-res pixels).
    pub inlier_px: f32,
    /// Below this inlier fraction the estimate is flagged lost.
    pub lost_inlier_fraction: f32,
    /// An update that moves the pose further than this (metres or radians) is rejected as a jump.
    pub max_jump: f64,
    /// Continuous symmetries of the object as (unit axis, a point on it), object frame (metres):
    /// rotation about them is unobservable, so every update keeps the prior's spin about them.
    pub held_axes_o: Vec<(Vector3<f64>, Vector3<f64>)>,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            solver: SolverMode::EdftPlus,
            n_search: 4,
            frontend: FrontEnd::scarf_default(),
            field: FieldParams::default(),
            lm: LmParams::default(),
            roi_margin_px: 48.0,
            search_roi_margin_px: 16.0,
            inlier_px: 2.0,
            lost_inlier_fraction: 0.15,
            max_jump: 0.25,
            held_axes_o: Vec::new(),
        }
    }
}

/// One published pose estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// T_c_o: the object in the camera optical frame.
    pub pose: Pose,
    /// Time of the newest event the field was built from (µs; 0 before any event).
    pub t_us: i64,
    /// Number of updates so far (0 = the initial pose).
    pub seq: u64,
    pub step: StepKind,
    /// Mean distance-field value over the model points (full-res pixels).
    pub cost: f32,
    pub inlier_fraction: f32,
    /// Fraction of the model points that project where the sensor sees (they alone enter the cost
    /// and `inlier_fraction`); below 1 when the object is partly out of view.
    pub visible_fraction: f32,
    /// Events ingested so far.
    pub n_events: u64,
    pub lost: bool,
}

/// Per-kind step counts and time spent (wall clock, seconds).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TrackerStats {
    pub lm_steps: u64,
    pub search_steps: u64,
    pub lm_seconds: f64,
    pub search_seconds: f64,
    pub events_dropped: u64,
    pub jumps_rejected: u64,
}

pub struct TrackerCore {
    rect: Camera,
    lut: UndistortLut,
    surface: Box<dyn EventSurface>,
    field: DistanceField,
    points: Vec<[f32; 3]>,
    pivot_o: Vector3<f64>,
    pins: Vec<Pinhole>,
    view: ViewMask,
    /// The points visible at the current step (reused buffer).
    visible: Vec<[f32; 3]>,
    schedule: Schedule,
    config: TrackerConfig,
    last: Estimate,
    last_t_us: Option<i64>,
    stats: TrackerStats,
    mask: Vec<u8>,
    pixels: Vec<u32>,
    polarity: Vec<i16>,
}

/// Model points closer than this to the border of what the sensor sees leave the cost (full-res
/// pixels): their field is cut off on one side.
const VIEW_MARGIN_PX: f64 = 2.0;

/// Fewer visible model points than this and the pose is not updated (one per degree of freedom).
const MIN_VISIBLE_POINTS: usize = 6;

/// `new` with its rotation relative to `prior` about each of `axes` (object frame, each a unit
/// axis and a point on it) removed; the points on the axis stay where `new` put them.
fn hold_axes(prior: &Pose, new: Pose, axes: &[(Vector3<f64>, Vector3<f64>)]) -> Pose {
    let mut out = new;
    for (axis, on_axis) in axes {
        let relative = (prior.rotation.inverse() * out.rotation).scaled_axis();
        let spin = UnitQuaternion::from_scaled_axis(axis * relative.dot(axis));
        let anchor = out * Point3::from(*on_axis);
        let rotation = out.rotation * spin.inverse();
        let translation = anchor.coords - rotation * on_axis;
        out = Pose::from_parts(Translation3::from(translation), rotation);
    }
    out
}

fn check_pose(pose: &Pose) -> Result<()> {
    let ok = pose.translation.vector.iter().all(|v| v.is_finite())
        && pose.rotation.coords.iter().all(|v| v.is_finite());
    ensure(ok, || "pose contains NaN or infinite values".into())?;
    ensure(pose.translation.z > 0.0, || {
        format!(
            "object must be in front of the camera (z = {} m)",
            pose.translation.z
        )
    })
}

impl TrackerCore {
    /// `camera` is the sensor's (raw, distorted); `points_o` is S* in the object frame (metres);
    /// `t_c_o` the initial pose of the object in the camera.
    pub fn new(
        camera: &Camera,
        points_o: Vec<[f32; 3]>,
        t_c_o: Pose,
        config: TrackerConfig,
    ) -> Result<Self> {
        ensure(points_o.len() >= 6, || {
            format!(
                "the point set needs at least 6 points, got {}",
                points_o.len()
            )
        })?;
        ensure(points_o.iter().flatten().all(|v| v.is_finite()), || {
            "the point set contains NaN".into()
        })?;
        check_pose(&t_c_o)?;
        let camera = camera.checked()?;
        let rect = camera.rectified();
        let surface = make_surface(&config.frontend, camera.width, camera.height)?;
        let field = DistanceField::new(config.field)?;
        let pins = (0..config.field.levels)
            .map(|l| Pinhole::at_level(&rect, l))
            .collect();
        let schedule = Schedule::new(config.solver, config.n_search)?;
        let pivot_o = centroid(&points_o);
        let mut core = Self {
            rect,
            lut: UndistortLut::new(&camera),
            surface,
            field,
            points: points_o,
            pivot_o,
            pins,
            view: ViewMask::new(&camera, VIEW_MARGIN_PX),
            visible: Vec::new(),
            schedule,
            config,
            last: Estimate {
                pose: t_c_o,
                t_us: 0,
                seq: 0,
                step: StepKind::Search,
                cost: 0.0,
                inlier_fraction: 0.0,
                visible_fraction: 1.0,
                n_events: 0,
                lost: false,
            },
            last_t_us: None,
            stats: TrackerStats::default(),
            mask: Vec::new(),
            pixels: Vec::new(),
            polarity: Vec::new(),
        };
        ensure(core.roi(0.0).is_some(), || {
            "the object does not project into the image at the initial pose".into()
        })?;
        core.last.cost = core.field_max();
        Ok(core)
    }

    fn field_max(&self) -> f32 {
        self.config.field.tau_px
    }

    pub fn config(&self) -> &TrackerConfig {
        &self.config
    }

    pub fn camera(&self) -> &Camera {
        &self.rect
    }

    pub fn points(&self) -> &[[f32; 3]] {
        &self.points
    }

    pub fn latest(&self) -> Estimate {
        self.last
    }

    pub fn stats(&self) -> TrackerStats {
        self.stats
    }

    pub fn surface(&self) -> &dyn EventSurface {
        self.surface.as_ref()
    }

    /// Steps per cycle: 1 LM + N search for EDFT⁺, N + 1 steps of the single solver otherwise.
    pub fn cycle_len(&self) -> usize {
        self.schedule.cycle_len()
    }

    /// Validate a batch (sensor bounds, time never going backwards) without ingesting it.
    pub fn validate(&self, batch: &EventBatch) -> Result<()> {
        batch.validate(self.rect.width, self.rect.height, self.last_t_us)
    }

    /// Validate and ingest a batch into the front-end. A rejected batch leaves the tracker unchanged.
    pub fn ingest(&mut self, batch: &EventBatch) -> Result<()> {
        self.validate(batch)?;
        self.ingest_unchecked(batch);
        Ok(())
    }

    /// Ingest a batch that has already been validated against this sensor and time line.
    pub(crate) fn ingest_unchecked(&mut self, batch: &EventBatch) {
        self.pixels.clear();
        self.polarity.clear();
        for i in 0..batch.len() {
            let idx = self.lut.map(batch.x[i], batch.y[i]);
            if idx != UndistortLut::OUTSIDE {
                self.pixels.push(idx);
                self.polarity.push(batch.p[i]);
            }
        }
        self.surface.ingest(&self.pixels, &self.polarity);
        self.last.n_events += batch.len() as u64;
        if let Some(t) = batch.last_t_us() {
            self.last_t_us = Some(t);
        }
    }

    /// Region of the rectified image around the model projected at the current pose.
    fn roi(&self, margin_px: f64) -> Option<Roi> {
        let rig = Rigid32::from_pose(&self.last.pose);
        let pin = self.pins[0];
        let uv = self
            .points
            .iter()
            .filter_map(|&x| pin.project(rig.apply(x)))
            .map(|(u, v)| (f64::from(u), f64::from(v)));
        Roi::around(uv, margin_px, self.rect.width, self.rect.height)
    }

    /// Set the pose (e.g. re-initialisation); the front-end keeps its events.
    pub fn reset_pose(&mut self, t_c_o: Pose) -> Result<()> {
        check_pose(&t_c_o)?;
        self.last.pose = t_c_o;
        self.last.lost = false;
        self.schedule.restart();
        Ok(())
    }

    /// One update: rebuild the field from the current active set and run the next scheduled step.
    pub fn step(&mut self) -> Estimate {
        let kind = self.schedule.next_step();
        let started = Instant::now();
        let pose = self.last.pose;
        let margin = match kind {
            StepKind::Lm => self.config.roi_margin_px,
            StepKind::Search => self.config.search_roi_margin_px,
        };
        let Some(roi) = self.roi(margin) else {
            self.last.lost = true;
            self.last.seq += 1;
            return self.last;
        };
        let mut visible = std::mem::take(&mut self.visible);
        self.view.visible_points(
            &self.pins[0],
            &Rigid32::from_pose(&pose),
            &self.points,
            &mut visible,
        );
        let visible_fraction = visible.len() as f32 / self.points.len() as f32;
        if visible.len() < MIN_VISIBLE_POINTS {
            self.visible = visible;
            self.last.lost = true;
            self.last.visible_fraction = visible_fraction;
            self.last.seq += 1;
            return self.last;
        }
        let n_levels = if kind == StepKind::Lm {
            self.config.field.levels
        } else {
            1
        };
        self.mask.resize(roi.area(), 0);
        self.surface.fill_mask(roi, &mut self.mask);
        let built = self.field.build(&self.mask, roi, n_levels, false);
        let new_pose = match (built, kind) {
            (Err(_), _) => pose,
            (Ok(()), StepKind::Lm) => {
                let levels: Vec<_> = (0..n_levels)
                    .rev()
                    .map(|l| (self.field.level(l), self.pins[l as usize]))
                    .collect();
                lm_pyramid(&levels, pose, &visible, &self.pivot_o, &self.config.lm).pose
            }
            (Ok(()), StepKind::Search) => {
                let deltas = axis_steps(&self.pins[0], &pose, &visible, &self.pivot_o, 8);
                search_step(
                    self.field.level(0),
                    &self.pins[0],
                    &pose,
                    &visible,
                    &self.pivot_o,
                    &deltas,
                )
                .pose
            }
        };
        let new_pose = hold_axes(&pose, new_pose, &self.config.held_axes_o);
        let (dt, dr) = crate::se3::distance(&pose, &new_pose);
        let accepted = if check_pose(&new_pose).is_ok()
            && dt <= self.config.max_jump
            && dr <= self.config.max_jump
        {
            new_pose
        } else {
            self.stats.jumps_rejected += 1;
            pose
        };
        let quality = cost_stats(
            self.field.level(0),
            &self.pins[0],
            &Rigid32::from_pose(&accepted),
            &visible,
            self.config.inlier_px,
        );
        self.visible = visible;
        self.last = Estimate {
            pose: accepted,
            t_us: self.last_t_us.unwrap_or(0),
            seq: self.last.seq + 1,
            step: kind,
            cost: quality.mean,
            inlier_fraction: quality.inlier_fraction,
            visible_fraction,
            n_events: self.last.n_events,
            lost: quality.inlier_fraction < self.config.lost_inlier_fraction,
        };
        let secs = started.elapsed().as_secs_f64();
        match kind {
            StepKind::Lm => {
                self.stats.lm_steps += 1;
                self.stats.lm_seconds += secs;
            }
            StepKind::Search => {
                self.stats.search_steps += 1;
                self.stats.search_seconds += secs;
            }
        }
        self.last
    }

    /// Synchronous update: ingest the batch, run one full cycle, return the last estimate.
    pub fn update(&mut self, batch: &EventBatch) -> Result<Estimate> {
        self.ingest(batch)?;
        for _ in 0..self.cycle_len() {
            self.step();
        }
        Ok(self.last)
    }

    /// The model points projected at the current pose (rectified pixels); for overlays.
    pub fn projected_points(&self) -> Vec<(f32, f32)> {
        let rig = Rigid32::from_pose(&self.last.pose);
        self.points
            .iter()
            .filter_map(|&x| self.pins[0].project(rig.apply(x)))
            .collect()
    }

    /// The full-resolution field as last built, with its region (for overlays and diagnostics).
    pub fn field_level0(&self) -> &crate::field::FieldLevel {
        self.field.level(0)
    }

    /// The model's pivot (centroid of S*) in the camera frame at the current pose.
    pub fn pivot_c(&self) -> Vector3<f64> {
        (self.last.pose * Point3::from(self.pivot_o)).coords
    }
}

/// A lock-free single-writer cell holding the newest estimate (a seqlock over 16 words).
pub struct EstimateCell {
    version: AtomicU64,
    words: [AtomicU64; 16],
}

impl EstimateCell {
    pub fn new(initial: &Estimate) -> Self {
        let cell = Self {
            version: AtomicU64::new(0),
            words: std::array::from_fn(|_| AtomicU64::new(0)),
        };
        cell.publish(initial);
        cell
    }

    fn encode(e: &Estimate) -> [u64; 16] {
        let t = e.pose.translation.vector;
        let q = e.pose.rotation.coords;
        [
            t.x.to_bits(),
            t.y.to_bits(),
            t.z.to_bits(),
            q.x.to_bits(),
            q.y.to_bits(),
            q.z.to_bits(),
            q.w.to_bits(),
            e.t_us as u64,
            e.seq,
            u64::from(e.step == StepKind::Lm),
            u64::from(e.cost.to_bits()),
            u64::from(e.inlier_fraction.to_bits()),
            e.n_events,
            u64::from(e.lost),
            u64::from(e.visible_fraction.to_bits()),
            0,
        ]
    }

    fn decode(w: &[u64; 16]) -> Estimate {
        let f = f64::from_bits;
        let q = UnitQuaternion::new_unchecked(Quaternion::new(f(w[6]), f(w[3]), f(w[4]), f(w[5])));
        Estimate {
            pose: Pose::from_parts(Translation3::new(f(w[0]), f(w[1]), f(w[2])), q),
            t_us: w[7] as i64,
            seq: w[8],
            step: if w[9] == 1 {
                StepKind::Lm
            } else {
                StepKind::Search
            },
            cost: f32::from_bits(w[10] as u32),
            inlier_fraction: f32::from_bits(w[11] as u32),
            n_events: w[12],
            lost: w[13] != 0,
            visible_fraction: f32::from_bits(w[14] as u32),
        }
    }

    /// Only one thread may publish (the tracker thread owns the writer side).
    pub fn publish(&self, e: &Estimate) {
        let v = self.version.load(Ordering::Relaxed);
        self.version.store(v.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        for (slot, word) in self.words.iter().zip(Self::encode(e)) {
            slot.store(word, Ordering::Relaxed);
        }
        self.version.store(v.wrapping_add(2), Ordering::Release);
    }

    /// The newest complete estimate; retries while a publication is in flight (a few ns).
    pub fn read(&self) -> Estimate {
        loop {
            let v1 = self.version.load(Ordering::Acquire);
            if v1 % 2 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let words: [u64; 16] = std::array::from_fn(|i| self.words[i].load(Ordering::Relaxed));
            fence(Ordering::Acquire);
            if self.version.load(Ordering::Relaxed) == v1 {
                return Self::decode(&words);
            }
        }
    }
}

struct Shared {
    queue: ArrayQueue<EventBatch>,
    latest: EstimateCell,
    stop: AtomicBool,
    dropped_events: AtomicU64,
}

/// A tracker core running in its own thread.
pub struct ThreadedTracker {
    shared: Arc<Shared>,
    handle: Option<JoinHandle<TrackerCore>>,
    width: u32,
    height: u32,
    last_pushed_t_us: Option<i64>,
}

/// Batches that may wait in the queue; beyond this the oldest is dropped (and counted).
pub const QUEUE_CAPACITY: usize = 1024;

impl ThreadedTracker {
    /// Move `core` into a new thread and start the solver loop.
    pub fn start(core: TrackerCore) -> Result<Self> {
        let shared = Arc::new(Shared {
            queue: ArrayQueue::new(QUEUE_CAPACITY),
            latest: EstimateCell::new(&core.latest()),
            stop: AtomicBool::new(false),
            dropped_events: AtomicU64::new(0),
        });
        let (width, height, last_pushed_t_us) = (core.rect.width, core.rect.height, core.last_t_us);
        let worker = Arc::clone(&shared);
        let handle = thread::Builder::new()
            .name("evservo-tracker".into())
            .spawn(move || run(core, &worker))
            .map_err(|e| Error::Tracking(format!("could not start the tracker thread: {e}")))?;
        Ok(Self {
            shared,
            handle: Some(handle),
            width,
            height,
            last_pushed_t_us,
        })
    }

    /// Hand a batch to the tracker thread. Never blocks: validates, enqueues, and if the queue is
    /// full drops the oldest waiting batch.
    pub fn push(&mut self, batch: EventBatch) -> Result<()> {
        batch.validate(self.width, self.height, self.last_pushed_t_us)?;
        if batch.is_empty() {
            return Ok(());
        }
        self.last_pushed_t_us = batch.last_t_us().or(self.last_pushed_t_us);
        if let Some(old) = self.shared.queue.force_push(batch) {
            self.shared
                .dropped_events
                .fetch_add(old.len() as u64, Ordering::Relaxed);
        }
        if let Some(h) = &self.handle {
            h.thread().unpark();
        }
        Ok(())
    }

    pub fn latest(&self) -> Estimate {
        self.shared.latest.read()
    }

    pub fn dropped_events(&self) -> u64 {
        self.shared.dropped_events.load(Ordering::Relaxed)
    }

    pub fn is_running(&self) -> bool {
        self.handle.as_ref().is_some_and(|h| !h.is_finished())
    }

    /// Stop the thread and get the core back (with its stats).
    pub fn stop(mut self) -> Result<TrackerCore> {
        self.stop_inner()
    }

    fn stop_inner(&mut self) -> Result<TrackerCore> {
        self.shared.stop.store(true, Ordering::Release);
        let handle = self
            .handle
            .take()
            .ok_or_else(|| Error::Tracking("tracker thread already stopped".into()))?;
        handle.thread().unpark();
        let mut core = handle
            .join()
            .map_err(|_| Error::Tracking("the tracker thread panicked".into()))?;
        core.stats.events_dropped += self.shared.dropped_events.load(Ordering::Relaxed);
        Ok(core)
    }
}

impl Drop for ThreadedTracker {
    fn drop(&mut self) {
        if self.handle.is_some() {
            let _ = self.stop_inner();
        }
    }
}

fn run(mut core: TrackerCore, shared: &Shared) -> TrackerCore {
    // After a full cycle without new events the field cannot change, so the solver rests until
    // the next push instead of spinning.
    let mut steps_without_events = 0;
    while !shared.stop.load(Ordering::Acquire) {
        // Only what is queued now: a producer faster than ingest must not starve the solver.
        // Anything beyond that waits for the next step, or is dropped at the queue if it keeps
        // coming faster than it can be ingested.
        let mut got = false;
        for _ in 0..shared.queue.len() {
            let Some(batch) = shared.queue.pop() else {
                break;
            };
            core.ingest_unchecked(&batch);
            got = true;
        }
        if got {
            steps_without_events = 0;
        }
        if steps_without_events >= core.cycle_len() {
            thread::park_timeout(Duration::from_millis(5));
            continue;
        }
        let estimate = core.step();
        shared.latest.publish(&estimate);
        steps_without_events += 1;
    }
    core
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn held_axes_keep_the_prior_spin_and_the_rest_of_the_update() {
        let prior = crate::se3::exp(&nalgebra::Vector6::new(0.01, -0.02, 0.7, 0.3, -0.2, 0.1));
        let axis = Vector3::new(0.0, 1.0, 0.0);
        let on_axis = Vector3::new(0.01, 0.0, -0.02);
        // One update's worth: 2° of spin about the axis, 0.5° of tilt about the object's x, 5 mm sideways.
        let spin = Pose::from_parts(
            Translation3::from(
                on_axis - UnitQuaternion::from_scaled_axis(axis * 2f64.to_radians()) * on_axis,
            ),
            UnitQuaternion::from_scaled_axis(axis * 2f64.to_radians()),
        );
        let tilt = Pose::from_parts(
            Translation3::new(0.005, 0.0, 0.0),
            // About the object's x (camera-frame axis), which has no part along the held y.
            UnitQuaternion::from_scaled_axis(prior.rotation * Vector3::x() * 0.5f64.to_radians()),
        );
        let new = tilt * prior * spin;
        let held = hold_axes(&prior, new, &[(axis, on_axis)]);
        let expected = tilt * prior;
        let (dt, dr) = crate::se3::distance(&held, &expected);
        // The tilt about x and the spin about y do not commute: what remains is second order.
        assert!(
            dt < 5e-5 && dr < 0.03f64.to_radians(),
            "{} mm, {} deg",
            dt * 1e3,
            dr.to_degrees()
        );
        let (dt, dr) = crate::se3::distance(&held, &new);
        assert!(
            dr > 1.99f64.to_radians(),
            "spin not removed: {} mm, {} deg",
            dt * 1e3,
            dr.to_degrees()
        );
        assert_eq!(hold_axes(&prior, new, &[]), new);
    }

    #[test]
    fn estimate_cell_round_trips_and_survives_concurrent_readers() {
        let pose = crate::se3::exp(&nalgebra::Vector6::new(0.1, 0.2, 0.6, 0.1, 0.2, 0.3));
        let mk = |seq: u64| Estimate {
            pose,
            t_us: seq as i64 * 10,
            seq,
            step: StepKind::Lm,
            cost: 1.5,
            inlier_fraction: 0.5,
            visible_fraction: 0.75,
            n_events: seq * 3,
            lost: false,
        };
        let cell = Arc::new(EstimateCell::new(&mk(0)));
        assert_eq!(cell.read(), mk(0));
        let reader = {
            let cell = Arc::clone(&cell);
            thread::spawn(move || {
                let mut last = 0;
                for _ in 0..200_000 {
                    let e = cell.read();
                    // Never torn: every field belongs to the same publication.
                    assert_eq!(e.t_us, e.seq as i64 * 10);
                    assert_eq!(e.n_events, e.seq * 3);
                    assert!(e.seq >= last);
                    last = e.seq;
                }
            })
        };
        for seq in 1..200_000 {
            cell.publish(&mk(seq));
        }
        reader.join().unwrap();
    }
}
