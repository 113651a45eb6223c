//! The tracker: events in, poses out.
//!
//! A tracker has two halves that share only lock-free state:
//! - [`Ingest`] validates each batch, maps it through the undistortion table and inserts it into
//!   the front-end's writer. It runs on the caller's thread (the producer's core), so a fast
//!   producer pays for its own events and the solver never waits for them.
//! - [`Solver`] reads the front-end's active set, rebuilds the distance field and runs one LM or
//!   search step per update.
//!
//! Between them: the front-end (SCARF's count image is single-writer/many-reader without locks),
//! and [`TrackerOutput`]: the newest estimate in a seqlock, the newest ingested event time and the
//! live counters. [`TrackerCore`] holds both halves for synchronous use (deterministic simulation,
//! tests); [`ThreadedTracker`] keeps the ingest half with the caller and moves the solver into its
//! own thread.
//!
//! Overload: a live producer can offer more events per second than one core can insert. The
//! threaded ingest then keeps a uniform fraction of each batch (every k-th event in stream order,
//! so uniform in time), sized so that ingest uses at most a set share of the caller's core.
//! SCARF's active set does not depend on the event rate, so a thinned stream draws the same edges,
//! and the pose stays fresh instead of falling behind a backlog.
//!
//! One *update* = one published pose = one LM or one search step on a field rebuilt from the
//! current active set. LM steps build the full pyramid; search steps only need the full-resolution
//! level, which is most of why they are cheap.

use crate::camera::{Camera, UndistortLut};
use crate::clock::thread_cpu_ns;
use crate::confidence::{evidence, explained_fraction, Evidence, Query};
use crate::error::{ensure, Error, Result};
use crate::event::{validate_events, EventRecords};
use crate::field::{DistanceField, FieldParams};
use crate::freshness::{max_age_us, Activity, MotionMemory, Recency};
use crate::image::Roi;
use crate::latency::{Claim, LatencyHistogram, PendingBatches};
use crate::se3::unit_twist;
use crate::se3::Pose;
use crate::solve::cost::{apply_increment, centroid, cost_stats, Pinhole, Rigid32, ViewMask};
use crate::solve::lm::{lm_pyramid, LmParams, LmReport};
use crate::solve::search::{axis_steps, search_step, Gate};
use crate::solve::{Schedule, SolverMode, StepKind};
use crate::surface::{split_surface, FlickerFilter, FrontEnd, SurfaceReader, SurfaceWriter};
use crate::templates::{
    acquisition_score, camera_direction_o, pool_above_background, TemplateBank, ACQUISITION_MARGIN,
};
use nalgebra::{Point3, Quaternion, Translation3, UnitQuaternion, Vector3};
use std::sync::atomic::{fence, AtomicBool, AtomicI64, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::{self, JoinHandle, Thread};
use std::time::{Duration, Instant};

/// Default confidence below which a pose is flagged lost (chosen from the ROC in
/// benches/RESULTS.md, "Confidence and loss").
pub const LOST_BELOW: f32 = 0.25;
/// Default confidence a lost tracker needs before its pose is trusted again.
pub const RELOCK_ABOVE: f32 = 0.4;

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
    /// The estimate turns lost when its confidence falls below this ...
    pub lost_below: f32,
    /// ... for this long (event time, µs; see `Solver::judge`) ...
    pub lost_hold_us: i64,
    /// ... and is trusted again only once it reaches this (hysteresis against flicker).
    pub relock_above: f32,
    /// While lost, the global search only sees pixels whose block fired within this time (µs).
    pub search_fresh_us: i64,
    /// A candidate of the global search is accepted only with at least this acquisition score
    /// ([`crate::templates::acquisition_score`]) in `CONFIRM_PASSES` passes in a row: a sweep over
    /// thousands of templates finds partial fits that a tracked pose, which moves continuously,
    /// never jumps to. True poses of the drill and the textured box (sim, Z = 0.7 m) score
    /// 0.56–0.62, the sweep's wrong fits ≤ 0.41.
    pub reacquire_above: f32,
    /// An update that moves the pose further than this (metres or radians) is rejected as a jump.
    pub max_jump: f64,
    /// How much the threaded tracker may thin an overloading stream; see [`IngestLimit`].
    pub ingest_limit: IngestLimit,
    /// Light flicker frequencies (Hz) whose periodic pixels are dropped before the front-end
    /// (100 on 50 Hz mains, 120 on 60 Hz); empty = no anti-flicker. See [`FlickerFilter`].
    pub anti_flicker_hz: Vec<f64>,
    /// Continuous symmetries of the object as (unit axis, a point on it), object frame (metres):
    /// rotation about them is unobservable, so every update keeps the prior's spin about them.
    pub held_axes_o: Vec<(Vector3<f64>, Vector3<f64>)>,
    /// While S* is not wholly in view (the outline is cut by the image border; see
    /// `FULL_VIEW_FRACTION`), a search step moves to its best candidate only when that candidate
    /// beats the null one by at least this many standard errors of the per-point gains in LM's
    /// robust loss (`lm`; see [`crate::solve::search::Gate`]); 0 = the paper's plain argmin
    /// everywhere. With it on,
    /// the steps after an event dropout also hold the pose until the fresh field has as many fired
    /// pixels as S* has points. None: the solver's default ([`SolverMode::default_search_min_t`]:
    /// 3 for EDFT⁺, 0 for EDOPTS and EDFT).
    pub search_min_t: Option<f32>,
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
            lost_below: LOST_BELOW,
            relock_above: RELOCK_ABOVE,
            lost_hold_us: 15_000,
            // 10 ms, not 50: with the camera stopped, the sensor's noise refreshes most blocks
            // within 50 ms and the front-end's old edges came back with them (occlusion-0.5s:
            // chance 0.44–0.77 over the image, the true pose scoring 0.30–0.37 < 0.5; at 10 ms
            // chance 0.31–0.33 and the truth 0.55–0.63).
            search_fresh_us: 10_000,
            reacquire_above: 0.5,
            max_jump: 0.25,
            held_axes_o: Vec::new(),
            ingest_limit: IngestLimit::default(),
            anti_flicker_hz: Vec::new(),
            search_min_t: None,
        }
    }
}

impl TrackerConfig {
    /// The significance threshold of the search steps in effect: `search_min_t`, or the solver's
    /// default.
    pub fn effective_search_min_t(&self) -> f32 {
        self.search_min_t
            .unwrap_or_else(|| self.solver.default_search_min_t())
    }
}

/// When the threaded tracker's ingest starts keeping only a fraction of the events pushed
/// (synchronous ingest always keeps every event, so simulation stays deterministic).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum IngestLimit {
    /// Keep every event whatever it costs the caller.
    Off,
    /// Keep at most as many events as ingest can insert using this share of the caller's core
    /// (0..=1], measured on the fly (so a busier machine thins more), but never fewer than the
    /// tracker needs to follow a fast edge (2 Mev/s of event time).
    CoreShare(f64),
    /// Keep at most this many events per second of event time (a fixed, reproducible cap).
    EventsPerSecond(f64),
}

impl Default for IngestLimit {
    /// Half of the producer's core: the rest is left for the producer itself (decoding, Python).
    fn default() -> Self {
        Self::CoreShare(0.5)
    }
}

impl IngestLimit {
    fn check(&self) -> Result<()> {
        match *self {
            Self::Off => Ok(()),
            Self::CoreShare(f) => ensure(f.is_finite() && f > 0.0 && f <= 1.0, || {
                format!("the ingest core share {f} must be in (0, 1]")
            }),
            Self::EventsPerSecond(r) => ensure(r.is_finite() && r > 0.0, || {
                format!("the ingest rate limit {r} ev/s must be positive")
            }),
        }
    }
}

/// One published pose estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// T_c_o: the object in the camera optical frame.
    pub pose: Pose,
    /// Time of the newest event ingested before the field was built (µs; 0 before any event).
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
    /// Events ingested into the front-end so far (after any thinning).
    pub n_events: u64,
    /// How much better than chance the events support this pose, 0–1 (see [`crate::confidence`]).
    pub confidence: f32,
    /// The pose is not to be trusted: before the first update confirms it, once the confidence
    /// fell below `lost_below` until it is back above `relock_above`, or the model is out of view.
    pub lost: bool,
    /// When the batch holding the newest event behind this estimate (`t_us`) was handed to
    /// ingest ([`crate::clock::now_ns`], ns; 0 before any event).
    pub pushed_ns: u64,
    /// When this estimate was published ([`crate::clock::now_ns`], ns). `published_ns −
    /// pushed_ns` is the event-to-pose latency of its newest event, measured where it happens,
    /// whoever reads the estimate and however late.
    pub published_ns: u64,
    /// When the oldest batch that no earlier estimate contained was pushed (ns; 0 when this
    /// update took in no new batch). `published_ns − oldest_pushed_ns` bounds the latency of
    /// every event this estimate is the first to use, including batches superseded before any
    /// step could show them as the newest.
    pub oldest_pushed_ns: u64,
}

impl Estimate {
    /// Event-to-pose latency of the newest event behind this estimate (ns; None before any event).
    pub fn latency_ns(&self) -> Option<u64> {
        (self.pushed_ns != 0).then(|| self.published_ns.saturating_sub(self.pushed_ns))
    }

    /// Event-to-pose latency of the oldest batch first used by this estimate (ns; None when it
    /// took in no new batch): a bound for every event it is the first to use.
    pub fn oldest_latency_ns(&self) -> Option<u64> {
        (self.oldest_pushed_ns != 0)
            .then(|| self.published_ns.saturating_sub(self.oldest_pushed_ns))
    }
}

/// Per-kind step counts and time spent (wall clock, seconds), and what happened to the events.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TrackerStats {
    pub lm_steps: u64,
    pub search_steps: u64,
    pub lm_seconds: f64,
    pub search_seconds: f64,
    /// Events in accepted batches.
    pub events_offered: u64,
    /// Events inserted into the front-end.
    pub events_ingested: u64,
    /// Events left out: thinned under overload or removed as flicker (offered − ingested).
    pub events_dropped: u64,
    pub jumps_rejected: u64,
    /// Global searches run while lost, and their time (wall clock, seconds).
    pub reacquire_passes: u64,
    pub reacquire_seconds: f64,
}

/// Model points closer than this to the border of what the sensor sees leave the cost (full-res
/// pixels): their field is cut off on one side.
const VIEW_MARGIN_PX: f64 = 2.0;

/// How long (event time, µs) a given pose may read lost before the tracker searches for the
/// object instead (with a template bank): a start pose that never locks is taken to be wrong.
const UNCONFIRMED_US: i64 = 100_000;

/// A stretch of event time this long (µs) without a single event is a dropout (sensor, link or a
/// thinning producer), not a quiet scene: the sensor's background activity alone fires every few
/// µs. Whatever the front-end held before it shows where things were, not where they are.
pub const EVENT_GAP_US: i64 = 20_000;
/// For this long (µs) after events resume from a gap, the solver sees only pixels whose block has
/// fired since: the pre-gap edges would hold the pose where the object was.
const AFTER_GAP_US: i64 = 100_000;

/// While lost with a template bank, a global pass runs at most this often (event time, µs); the
/// steps in between keep tracking locally, so a pose that is right again is trusted again at once
/// (the global pass alone only accepts a pose it found itself).
const GLOBAL_PASS_EVERY_US: i64 = 10_000;

/// Whether a kind of global pass is due at event time `t_us` while lost with a pose to track on:
/// at most every [`GLOBAL_PASS_EVERY_US`], and only once the other steps since the last one
/// (started at `pass_us`, the first step after it at `after_us`) have had `rest` times the event
/// time it took. A full pass costs tens of milliseconds (63 ms of CPU at 1280×720), far over
/// `GLOBAL_PASS_EVERY_US`: without this rule the solver ran nothing else, and a tracked pose lost
/// while the object was hidden stood where it was as the object came back and moved off
/// (occlusion-0.5s: one pass every 58 ms, no local step, never trusted again).
fn global_pass_due(t_us: i64, pass_us: Option<i64>, after_us: Option<i64>, rest: i64) -> bool {
    let Some(pass_us) = pass_us else {
        return true;
    };
    if t_us < pass_us {
        return true; // the time line restarted
    }
    let took_us = after_us.map_or(0, |a| a - pass_us);
    t_us - pass_us >= GLOBAL_PASS_EVERY_US && after_us.is_some_and(|a| t_us - a >= rest * took_us)
}

/// When a kind of global pass last ran and when the first step of any other kind after it did
/// (event times, µs; None: not yet).
#[derive(Debug, Clone, Copy, Default)]
struct PassClock {
    ran_us: Option<i64>,
    after_us: Option<i64>,
}

impl PassClock {
    /// See [`global_pass_due`].
    fn due(&self, t_us: i64, rest: i64) -> bool {
        global_pass_due(t_us, self.ran_us, self.after_us, rest)
    }

    /// A step at `t_us`: this kind of pass (`ran`) or any other.
    fn note(&mut self, ran: bool, t_us: i64) {
        if ran {
            self.ran_us = Some(t_us);
            self.after_us = None;
        } else {
            self.after_us.get_or_insert(t_us);
        }
    }
}

/// The other steps get this many times the event time a full pass took (the near passes and the
/// local steps between them share it), and as much as a near pass took.
const FULL_PASS_REST: i64 = 2;
const NEAR_PASS_REST: i64 = 1;

/// The window (µs of event time) over which the model's blocks must have fired to count as active.
const ACTIVE_WINDOW_US: i64 = 10_000;
/// Every this many model points are sampled for the activity test.
const ACTIVITY_POINT_STRIDE: usize = 4;
/// A trusted model whose blocks fire at least this much above their surroundings (the excess share
/// of [`Activity::excess`]) is visibly active: its own edges are making events ...
const EXPECT_ACTIVE: f32 = 0.15;
/// ... and if, within this time (µs of event time) of being so, its blocks fire no more than
/// [`QUIET`] above their surroundings, its events stopped at once while the rest of the scene
/// goes on: it is hidden. An object that slows down (the camera following it settles, it comes to
/// rest) fades over tens of milliseconds; its excess stays above `QUIET` or falls below it only
/// long after it was last active (closed-loop episodes, benches/RESULTS.md, issue 12 "Round 6":
/// locked 0.05–1.0 with dips below 0.04 of ≤ 8 ms, hidden ≤ 0.025).
const ACTIVE_MEMORY_US: i64 = 25_000;
const QUIET: f32 = 0.04;
/// ... and only if its own blocks fire at less than this share of the rate they fired at when it
/// was last visibly active: a hidden object's blocks fall to the background's rate (edges
/// occlusion: 0.5–0.8 → ≤ 0.04), while a followed object in front of a textured background that
/// the moving camera makes fire keeps firing and only looks quiet against it (the brief's rendered
/// drill, measured cost: 0.35 → 0.25 against 0.16 → 0.33 around, flagged lost with confidence 0.40
/// before this test; benches/RESULTS.md, issue 12 "Round 6").
const FALLEN: f32 = 0.5;

/// The global sweep runs on a field level at most this wide (pixels; see `Solver::sweep_level`).
const SWEEP_MAX_WIDTH: usize = 200;

/// Global-search candidates scoring at least this are refined again with S* of their nearest view
/// (see `Solver::refine`).
const RESCORE_ABOVE: f32 = 0.25;

/// A full pass's best candidates (this many, whatever they score) are refined again turned by a
/// view spacing each way (see `Solver::turn_best`).
const TURNED_CANDIDATES: usize = 4;
/// A global-search candidate's `explained` share (and so its acquisition score) is measured only
/// when its support exceeds chance by at least this (see `Solver::score_floor`); below it the
/// candidates rank for turning by support − chance alone.
const EXPLAIN_ABOVE: f32 = 0.15;

/// Candidates of the place search (see `TemplateBank::search_place`) refined per full pass.
const PLACE_CANDIDATES: usize = 6;

/// Placements of the lost pose shifted across the image (see `TemplateBank::search_near`) refined
/// per global pass.
const NEAR_CANDIDATES: usize = 3;

/// Global passes in a row that must find a candidate (the later ones refining it from where the
/// local steps took it since) before it is trusted.
const CONFIRM_PASSES: u32 = 2;

/// The passes that a pose trusted again by the local steps while lost with a template bank counts
/// as having passed (see `Solver::judge`): it is held as a pending candidate, and one more pass
/// (a confirm pass: LM on a full-image field of fresh pixels whatever the solver, the acquisition
/// score with its `explained` share, the margin over the pass's other fits, and agreement within
/// `same_place`) must find it before it is trusted. The local confidence's share form
/// (support − chance) / (1 − chance) lets a partial fit over a busy region read as confident
/// (support 0.75–0.91 at chance 0.53–0.74); the acquisition score is the plain difference.
const LOCAL_FINDINGS: u32 = CONFIRM_PASSES - 1;

/// Whether two candidates of successive global passes are the same hypothesis: within 2 cm and 5°
/// (the object moves little between passes; a different fit sits elsewhere or turned).
fn same_place(a: &Pose, b: &Pose) -> bool {
    let (dt, dr) = crate::se3::distance(a, b);
    dt < 0.02 && dr < 5f64.to_radians()
}

/// Fewer visible model points than this and the pose is not updated (one per degree of freedom).
const MIN_VISIBLE_POINTS: usize = 6;

/// Below this share of S* in view, or with S* reaching within `BORDER_CUT_PX` of the image border
/// (an object cut by the border from the start has only its visible part in S*), LM registers at
/// full resolution only. The coarse levels' wide basins are safe while the whole outline holds
/// them in place; with part of it out of view they slide towards edges the missing part would
/// have ruled out (issue 13, objects suite: can at 0.6 m partly out of view, 233 mm / 22° with
/// three levels, about 1 mm / 0.5° with one).
const FULL_VIEW_FRACTION: f32 = 0.99;
const BORDER_CUT_PX: f32 = 3.0 * VIEW_MARGIN_PX as f32;

/// True when one of `points` projects (at `pose`, pinhole `pin`) within `BORDER_CUT_PX` of the
/// border of a `width` × `height` image.
fn reaches_border(
    pin: &Pinhole,
    pose: &Rigid32,
    points: &[[f32; 3]],
    width: u32,
    height: u32,
) -> bool {
    let (hi_u, hi_v) = (
        width as f32 - 1.0 - BORDER_CUT_PX,
        height as f32 - 1.0 - BORDER_CUT_PX,
    );
    points.iter().any(|&x| {
        pin.project(pose.apply(x))
            .is_some_and(|(u, v)| u < BORDER_CUT_PX || v < BORDER_CUT_PX || u > hi_u || v > hi_v)
    })
}

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

/// Words of an encoded [`Estimate`].
const ESTIMATE_WORDS: usize = 19;

/// A lock-free single-writer cell holding the newest estimate (a seqlock over its words).
pub struct EstimateCell {
    version: AtomicU64,
    words: [AtomicU64; ESTIMATE_WORDS],
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

    fn encode(e: &Estimate) -> [u64; ESTIMATE_WORDS] {
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
            u64::from(e.confidence.to_bits()),
            e.pushed_ns,
            e.published_ns,
            e.oldest_pushed_ns,
        ]
    }

    fn decode(w: &[u64; ESTIMATE_WORDS]) -> Estimate {
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
            confidence: f32::from_bits(w[15] as u32),
            pushed_ns: w[16],
            published_ns: w[17],
            oldest_pushed_ns: w[18],
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
            let words: [u64; ESTIMATE_WORDS] =
                std::array::from_fn(|i| self.words[i].load(Ordering::Relaxed));
            fence(Ordering::Acquire);
            if self.version.load(Ordering::Relaxed) == v1 {
                return Self::decode(&words);
            }
        }
    }
}

/// The newest accepted batch: its last event time and when it was pushed, read as one pair (a
/// seqlock; the ingest half is its only writer).
struct NewestBatch {
    version: AtomicU64,
    /// Event time (µs); `i64::MIN` before any batch.
    t_us: AtomicI64,
    /// [`crate::clock::now_ns`] when the batch was handed to ingest.
    pushed_ns: AtomicU64,
}

impl NewestBatch {
    fn new() -> Self {
        Self {
            version: AtomicU64::new(0),
            t_us: AtomicI64::new(i64::MIN),
            pushed_ns: AtomicU64::new(0),
        }
    }

    /// Only the ingest half writes. Release: a reader that sees the pair also sees the events
    /// ingested before it.
    fn set(&self, t_us: i64, pushed_ns: u64) {
        let v = self.version.load(Ordering::Relaxed);
        self.version.store(v.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        self.t_us.store(t_us, Ordering::Relaxed);
        self.pushed_ns.store(pushed_ns, Ordering::Relaxed);
        self.version.store(v.wrapping_add(2), Ordering::Release);
    }

    /// (event time µs, push stamp ns) of the newest batch; None before any.
    fn get(&self) -> Option<(i64, u64)> {
        loop {
            let v1 = self.version.load(Ordering::Acquire);
            if v1 % 2 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let t = self.t_us.load(Ordering::Relaxed);
            let pushed = self.pushed_ns.load(Ordering::Relaxed);
            fence(Ordering::Acquire);
            if self.version.load(Ordering::Relaxed) == v1 {
                return (t != i64::MIN).then_some((t, pushed));
            }
        }
    }
}

/// What both halves of a tracker publish, readable from any thread without locks: the newest
/// estimate, the newest ingested batch and live counters.
pub struct TrackerOutput {
    latest: EstimateCell,
    newest: NewestBatch,
    /// Time (µs) of the first event after the last gap of at least [`EVENT_GAP_US`] in the
    /// stream; `i64::MIN` if none.
    resumed_at_us: AtomicI64,
    /// The stream time (µs) the producer has vouched for through [`Ingest::advance_time`]: no event
    /// was missed up to it; `i64::MIN` if never.
    stream_us: AtomicI64,
    /// Accepted non-empty batches; the solver compares it to see whether anything new arrived.
    batches: AtomicU64,
    offered: AtomicU64,
    ingested: AtomicU64,
    lm_steps: AtomicU64,
    search_steps: AtomicU64,
    lm_ns: AtomicU64,
    search_ns: AtomicU64,
    jumps_rejected: AtomicU64,
    reacquire_passes: AtomicU64,
    reacquire_ns: AtomicU64,
    /// Kernel thread id of the running solver thread (Linux), 0 when unknown or not running.
    solver_tid: AtomicI64,
    /// Batches ingested since the last step claimed them.
    pending: PendingBatches,
    /// Latency of each newest batch to the first estimate holding it (one sample per batch that
    /// was ever the newest behind a pose).
    newest_latency: LatencyHistogram,
    /// Latency bound of every batch: its first estimate's publication minus the push of the oldest
    /// batch that estimate took in (one sample per batch).
    oldest_latency: LatencyHistogram,
    /// Latency of every batch, hence of each of its events: its first estimate's publication
    /// minus its own push (one sample per batch).
    batch_latency: LatencyHistogram,
}

/// The latency histograms of [`TrackerOutput::latency`].
#[derive(Debug, Clone, Copy)]
pub struct Latencies<'a> {
    /// Each batch's own latency: every event's.
    pub batch: &'a LatencyHistogram,
    /// Each batch that was the newest behind a pose.
    pub newest: &'a LatencyHistogram,
    /// The bound of every batch by the oldest batch its pose took in.
    pub oldest: &'a LatencyHistogram,
}

impl TrackerOutput {
    fn new(initial: &Estimate) -> Self {
        Self {
            latest: EstimateCell::new(initial),
            newest: NewestBatch::new(),
            resumed_at_us: AtomicI64::new(i64::MIN),
            stream_us: AtomicI64::new(i64::MIN),
            batches: AtomicU64::new(0),
            offered: AtomicU64::new(0),
            ingested: AtomicU64::new(0),
            lm_steps: AtomicU64::new(0),
            search_steps: AtomicU64::new(0),
            lm_ns: AtomicU64::new(0),
            search_ns: AtomicU64::new(0),
            jumps_rejected: AtomicU64::new(0),
            reacquire_passes: AtomicU64::new(0),
            reacquire_ns: AtomicU64::new(0),
            solver_tid: AtomicI64::new(0),
            pending: PendingBatches::default(),
            newest_latency: LatencyHistogram::default(),
            oldest_latency: LatencyHistogram::default(),
            batch_latency: LatencyHistogram::default(),
        }
    }

    /// The newest published estimate (lock-free; a few ns).
    pub fn latest(&self) -> Estimate {
        self.latest.read()
    }

    /// The counters as of now (live while a solver thread runs).
    pub fn stats(&self) -> TrackerStats {
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        let (offered, ingested) = (get(&self.offered), get(&self.ingested));
        TrackerStats {
            lm_steps: get(&self.lm_steps),
            search_steps: get(&self.search_steps),
            lm_seconds: get(&self.lm_ns) as f64 * 1e-9,
            search_seconds: get(&self.search_ns) as f64 * 1e-9,
            events_offered: offered,
            events_ingested: ingested,
            events_dropped: offered.saturating_sub(ingested),
            jumps_rejected: get(&self.jumps_rejected),
            reacquire_passes: get(&self.reacquire_passes),
            reacquire_seconds: get(&self.reacquire_ns) as f64 * 1e-9,
        }
    }

    /// (event time µs, push stamp ns) of the newest accepted batch; None before any.
    fn newest(&self) -> Option<(i64, u64)> {
        self.newest.get()
    }

    /// Event-to-pose latencies so far, one sample per batch: of each batch (its first pose's
    /// publication minus its own push), of each newest batch (as [`Estimate::latency_ns`]) and
    /// the bound of every batch (as [`Estimate::oldest_latency_ns`]).
    pub fn latency(&self) -> Latencies<'_> {
        Latencies {
            batch: &self.batch_latency,
            newest: &self.newest_latency,
            oldest: &self.oldest_latency,
        }
    }
}

/// Decides which fraction of a batch to keep under overload (see the module doc).
#[derive(Debug, Clone)]
struct Thinning {
    limit: IngestLimit,
    /// Offered rate (events per µs of event time), smoothed over ≥ 1 ms windows; 0 = unknown.
    rate_ev_per_us: f64,
    window_events: u64,
    window_t0: Option<i64>,
    /// Measured costs (ns of the producer's CPU time) of validating one offered event and inserting
    /// one kept event; 0 = unknown.
    validate_ns: f64,
    insert_ns: f64,
    /// Position of the next kept event relative to the start of the next batch (in events), so the
    /// kept events are evenly spaced across batch boundaries.
    next_pos: f64,
}

/// Event time over which the offered rate is measured (µs).
const RATE_WINDOW_US: i64 = 1000;
/// Batches smaller than this are not timed (the clock's own cost would dominate).
const MIN_TIMED_EVENTS: usize = 256;
/// Weight of a new batch in the running mean of the ingest costs (≈ the last four batches count).
const COST_SMOOTHING: f64 = 0.25;
/// Never keep less than this fraction: the tracker must still see every edge.
const MIN_KEEP: f64 = 1.0 / 256.0;
/// Nor fewer than this many events per µs of event time when thinning by core share. SCARF keeps
/// a fixed count per block, so a thinner stream refreshes each block more slowly: at 0.4–1 Mev/s
/// kept (what a loaded core's share bought at 100 Mev/s offered) the active set of a box edge
/// moving at 0.3 m/s spans several milliseconds of motion and the pose stays behind on it (lost
/// within 50 ms in the latency suite), while 1.5–2 Mev/s of the same stream tracks to 2 mm.
/// Inserting 2 Mev/s costs about 5 % of a core, so the floor stays well within any share.
const MIN_KEPT_EV_PER_US: f64 = 2.0;

impl Thinning {
    fn new(limit: IngestLimit) -> Self {
        Self {
            limit,
            rate_ev_per_us: 0.0,
            window_events: 0,
            window_t0: None,
            validate_ns: 0.0,
            insert_ns: 0.0,
            next_pos: 0.0,
        }
    }

    fn reset(&mut self) {
        *self = Self::new(self.limit);
    }

    /// Account for an accepted batch of `n` events ending at `last_t` (after `prev_t`, the end of
    /// the previous batch, if any) and return the fraction of it to keep.
    fn offer(&mut self, n: usize, first_t: i64, last_t: i64, prev_t: Option<i64>) -> f64 {
        let t0 = *self.window_t0.get_or_insert(prev_t.unwrap_or(first_t));
        self.window_events += n as u64;
        let span = last_t - t0;
        if span >= RATE_WINDOW_US {
            let rate = self.window_events as f64 / span as f64;
            self.rate_ev_per_us = if self.rate_ev_per_us > 0.0 {
                0.5 * (self.rate_ev_per_us + rate)
            } else {
                rate
            };
            self.window_events = 0;
            self.window_t0 = Some(last_t);
        }
        let rate = if self.rate_ev_per_us > 0.0 {
            self.rate_ev_per_us
        } else if span > 0 {
            self.window_events as f64 / span as f64
        } else {
            return 1.0;
        };
        let keep = match self.limit {
            IngestLimit::Off => 1.0,
            IngestLimit::EventsPerSecond(cap) => cap * 1e-6 / rate,
            IngestLimit::CoreShare(share) => {
                if self.insert_ns <= 0.0 {
                    return 1.0;
                }
                // Per µs of event time: rate·(validate + keep·insert) ns ≤ share·1000 ns.
                let budget = (share * 1e3 / rate - self.validate_ns) / self.insert_ns;
                budget.max(MIN_KEPT_EV_PER_US / rate)
            }
        };
        keep.clamp(MIN_KEEP, 1.0)
    }

    /// Fold a batch's measured costs (ns of the producer thread's CPU time, which preemption does
    /// not inflate) into the estimates: a running mean over the last few batches, so the share is
    /// what ingest really takes. The cost of a kept event rises as fewer are kept (a thinned
    /// batch's pixels are farther apart: a cache miss on the undistortion table each, 60 ns against
    /// 20 ns whole in the rendered drill episode), and a lower envelope held the cheap figure of
    /// the unthinned stream (it rose 5 % a batch): 0.55 of the core where 0.5 was asked.
    fn record_costs(&mut self, offered: usize, kept: usize, validate_ns: u64, insert_ns: u64) {
        let mean = |old: f64, new: f64| {
            if old > 0.0 {
                old + COST_SMOOTHING * (new - old)
            } else {
                new
            }
        };
        if offered >= MIN_TIMED_EVENTS {
            self.validate_ns = mean(self.validate_ns, validate_ns as f64 / offered as f64);
        }
        if kept >= MIN_TIMED_EVENTS {
            self.insert_ns = mean(self.insert_ns, insert_ns as f64 / kept as f64);
        }
    }
}

/// The ingest half: validation, undistortion, optional thinning and the front-end's writer.
pub struct Ingest {
    width: u32,
    height: u32,
    lut: UndistortLut,
    writer: Box<dyn SurfaceWriter>,
    last_t_us: Option<i64>,
    thinning: Thinning,
    flicker: Option<FlickerFilter>,
    /// Indices of the events that passed the flicker filter (scratch).
    unflickered: Vec<u32>,
    pixels: Vec<u32>,
    /// Newest event time per block, for the solver's freshness test.
    recency: Arc<Recency>,
    out: Arc<TrackerOutput>,
}

impl Ingest {
    /// Validate `events` and insert them (all of them when `thin` is false, else the fraction the
    /// ingest limit allows). A rejected batch changes nothing.
    pub fn push<E: EventRecords + ?Sized>(&mut self, events: &E, thin: bool) -> Result<()> {
        let pushed_ns = crate::clock::now_ns();
        let n = events.n_events();
        let timed = thin && n >= MIN_TIMED_EVENTS;
        let cpu_ns = || if timed { thread_cpu_ns() } else { 0 };
        let started = cpu_ns();
        validate_events(events, self.width, self.height, self.last_t_us)?;
        if n == 0 {
            return Ok(());
        }
        let (first_t, last_t) = (events.t_at(0), events.t_at(n - 1));
        if self
            .last_t_us
            .is_some_and(|prev| first_t - prev >= EVENT_GAP_US)
        {
            self.out.resumed_at_us.store(first_t, Ordering::Release);
        }
        let validated = cpu_ns();
        let keep = if thin {
            self.thinning.offer(n, first_t, last_t, self.last_t_us)
        } else {
            1.0
        };
        // Candidates: every event, or those the flicker filter lets through (it must see all).
        let m = match &mut self.flicker {
            None => n,
            Some(f) => {
                self.unflickered.clear();
                for i in 0..n {
                    let (x, y) = events.xy(i);
                    if f.pass(x, y, events.p_at(i), events.t_at(i)) {
                        self.unflickered.push(i as u32);
                    }
                }
                self.unflickered.len()
            }
        };
        // Per-pixel times only while the solver searches globally: its candidates' `explained`
        // share is their only reader, and they make every event a store into a sensor-sized table.
        let per_pixel = self.recency.pixel_times_wanted();
        if per_pixel != self.recency.keeps_pixel_times() {
            self.recency.keep_pixel_times(per_pixel.then_some(first_t));
        }
        let filtered = self.flicker.is_some();
        let unflickered = &self.unflickered;
        let index = |j: usize| if filtered { unflickered[j] as usize } else { j };
        self.pixels.clear();
        if keep >= 1.0 {
            for j in 0..m {
                let i = index(j);
                let (x, y) = events.xy(i);
                self.recency.record(x, y, events.t_at(i), per_pixel);
                self.pixels.push(self.lut.raw_index(x, y));
            }
        } else {
            // Every (1/keep)-th event: the loop runs over kept events only.
            let (step, end) = (1.0 / keep, m as f64);
            let mut pos = self.thinning.next_pos;
            while pos < end {
                let i = index(pos as usize);
                let (x, y) = events.xy(i);
                self.recency.record(x, y, events.t_at(i), per_pixel);
                self.pixels.push(self.lut.raw_index(x, y));
                pos += step;
            }
            self.thinning.next_pos = pos - end;
        }
        // A second pass, as the table lookups are cache misses that prefetching can overlap only
        // when the kept events' pixels are known ahead.
        self.lut.map_in_place(&mut self.pixels);
        let kept = self.pixels.len();
        // The writer skips OUTSIDE (≥ width·height) itself.
        self.writer.ingest(&self.pixels);
        if timed {
            self.thinning
                .record_costs(n, kept, validated - started, cpu_ns() - validated);
        }
        self.last_t_us = Some(last_t);
        self.out.offered.fetch_add(n as u64, Ordering::Relaxed);
        self.out.ingested.fetch_add(kept as u64, Ordering::Relaxed);
        // Release: a solver that sees this time (or batch count) also sees the events in its mask.
        self.out.newest.set(last_t, pushed_ns);
        self.out.pending.mark(pushed_ns);
        self.out.batches.fetch_add(1, Ordering::Release);
        Ok(())
    }

    /// The stream has reached `t_us` with no events after those pushed (a decoder's time-high word
    /// in an empty slice, a driver's empty packet): lets the solver tell a dropout from a slow
    /// stream. Times before the newest event are refused.
    pub fn advance_time(&mut self, t_us: i64) -> Result<()> {
        if let Some(last) = self.last_t_us {
            ensure(t_us >= last, || {
                format!("stream time {t_us} µs is before the newest event ({last} µs)")
            })?;
        }
        self.out.stream_us.fetch_max(t_us, Ordering::Release);
        // Wakes a resting solver, which then sees the gap.
        self.out.batches.fetch_add(1, Ordering::Release);
        Ok(())
    }

    /// Forget every event and the time line (e.g. after the camera restarted its clock).
    pub fn reset(&mut self) {
        self.writer.reset();
        self.recency.reset();
        self.last_t_us = None;
        self.thinning.reset();
        if let Some(f) = &mut self.flicker {
            f.reset();
        }
        self.out.newest.set(i64::MIN, 0);
        self.out.resumed_at_us.store(i64::MIN, Ordering::Release);
        self.out.stream_us.store(i64::MIN, Ordering::Release);
    }
}

/// The solver half: everything an update needs, reading the front-end through a shared handle.
pub struct Solver {
    sensor: Camera,
    rect: Camera,
    reader: Arc<dyn SurfaceReader>,
    field: DistanceField,
    points: Vec<[f32; 3]>,
    pivot_o: Vector3<f64>,
    pins: Vec<Pinhole>,
    view: ViewMask,
    /// The points visible at the current step (reused buffer).
    visible: Vec<[f32; 3]>,
    /// The last LM step of this cycle: its held directions are held in the search steps too.
    last_lm: Option<LmReport>,
    schedule: Schedule,
    config: TrackerConfig,
    last: Estimate,
    mask: Vec<u8>,
    out: Arc<TrackerOutput>,
    /// Newest event time per block, written by the ingest half.
    recency: Arc<Recency>,
    /// The model's recent image speed (how fresh its support must be).
    motion: MotionMemory,
    /// Lost for real (confidence fell, or no pose was given): the next steps search globally when
    /// there is a template bank. Not set by an unconfirmed [`Solver::reset_pose`].
    searching: bool,
    /// Event time (µs) of the first update of a trusted pose below `lost_below`.
    low_since_us: Option<i64>,
    /// Event time (µs) of the first update that did not confirm a given pose.
    unconfirmed_since_us: Option<i64>,
    /// Viewpoint templates for re-acquisition and S* swaps (None: neither).
    bank: Option<Arc<TemplateBank>>,
    /// Camera direction (object frame) of the view the current S* was rendered from.
    points_dir_o: Option<Vector3<f64>>,
    /// What the events said at the last tracked pose (diagnostics).
    evidence: Evidence,
    /// A pose was given or trusted once: while lost, local steps track on from it between the
    /// global passes.
    had_pose: bool,
    /// When the last full global pass, near pass and pass of any kind ran (see [`Pass`]); the near
    /// pass's clock restarts whenever a pose is trusted (the next loss opens with one).
    full_pass: PassClock,
    near_pass: PassClock,
    any_pass: PassClock,
    /// The last pose trusted (the object was there when it was lost).
    trusted_pose: Option<Pose>,
    /// The sweep's field when the coarsest level is wider than `SWEEP_MAX_WIDTH` (one level,
    /// OR-pooled from the coarsest; built lazily).
    sweep_field: Option<DistanceField>,
    /// The place search's mask, and its fields at the sweep's level and one finer (see
    /// `Solver::place_seeds`).
    place_mask: Vec<u8>,
    place_field: Option<DistanceField>,
    descent_field: Option<DistanceField>,
    /// Event time (µs) since which the pixels of the last full-image field (a global pass's)
    /// fired per block; a candidate's `explained` share counts only the pixels that themselves
    /// fired since then (see `Solver::evidence_of`).
    global_since_us: i64,
    /// Passes in a row that found the current pose, a global-search candidate that passed
    /// `reacquire_above` and was taken as the pose to track on while still lost: the next pass
    /// only has to find it again where the local steps took it before it is trusted. Also set
    /// (to [`LOCAL_FINDINGS`]) when the local steps would trust a lost pose again.
    pending: Option<u32>,
    /// The batches this update took in, claimed at its start.
    claim: Claim,
    /// Scratch for [`Solver::activity_at`]: projected model points, and which cells of the
    /// region around them hold one.
    uv: Vec<(f32, f32)>,
    near_model: Vec<bool>,
    /// The stretch of trusted updates over which the model was last visibly active.
    active_at: Option<ActiveStretch>,
    /// Why the current pose is lost, which decides how it is trusted again.
    lost_by: LostBy,
    /// A pose trusted again after a dropout on a still scene (see [`LostBy::Dropout`]): it stays
    /// trusted while nothing fires on the model above its surroundings, whatever the confidence.
    held_still: bool,
    /// The model's expected image speed (pixels/s) at the last tracked update.
    speed_px_s: f32,
}

/// A stretch of updates whose model was visibly active (see [`Solver::judge`]), each within
/// [`ACTIVE_MEMORY_US`] of the one before.
#[derive(Debug, Clone, Copy)]
struct ActiveStretch {
    /// Event time (µs) of its first update.
    from_us: i64,
    /// Event time (µs) of its last update.
    at_us: i64,
    /// The share of the model's blocks that fired at its last update.
    share: f32,
    /// Since its last update the blocks around the model were seen visibly busier than the
    /// model's own: what fired there went on elsewhere (see `Solver::judge`).
    deserted: bool,
    /// Since its last update the model's blocks fell quiet, and the low clock has run on that
    /// since: only visibly active again ends the silence (see `Solver::judge`).
    hushed: bool,
}

/// Why a pose is lost (see [`Solver::judge`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
enum LostBy {
    /// Its confidence fell (or it was never confirmed): trusted again from `relock_above`.
    #[default]
    Evidence,
    /// The model's blocks fell quiet while the rest of the scene fired on (hidden): trusted again
    /// only once they fire again.
    Silence,
    /// Only the events stopped (see [`Solver::blind`]); `still`: the model was still in the image
    /// when they did.
    Dropout { still: bool },
}

/// What a global pass searches while lost (see [`Solver::pass_due`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Pass {
    /// The whole bank over the whole image (tens of milliseconds), and what `Near` searches.
    Full,
    /// The image around the last trusted pose and the current one (`TemplateBank::search_near`;
    /// a few thousand chamfer placements and a few LM refinements): the first pass of a loss,
    /// then run between full passes.
    Near,
    /// The current pose, a candidate being tracked, and its look-alikes: whether it is found again.
    Confirm,
}

/// A candidate of a global search (diagnostics and the acceptance test).
#[derive(Debug, Clone, Copy)]
pub struct Candidate {
    /// Where the sweep (or the caller) put it before LM.
    pub seed: Pose,
    /// The bank view whose S* it uses (None: the current S*).
    pub view: Option<usize>,
    /// The sweep's chamfer score (mean coarse field value; NaN when not from the sweep).
    pub chamfer: f32,
    /// After LM.
    pub pose: Pose,
    pub evidence: Evidence,
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

impl Solver {
    /// `sensor` has been checked; `out` is the output shared with the ingest half.
    fn new(
        sensor: Camera,
        points_o: Vec<[f32; 3]>,
        t_c_o: Pose,
        config: TrackerConfig,
        reader: Arc<dyn SurfaceReader>,
        recency: Arc<Recency>,
        out: Arc<TrackerOutput>,
    ) -> Result<Self> {
        let min_t = config.effective_search_min_t();
        ensure(min_t.is_finite() && min_t >= 0.0, || {
            format!("search_min_t {min_t} must be finite and non-negative")
        })?;
        let rect = sensor.rectified();
        let field = DistanceField::new(config.field)?;
        let pins = (0..config.field.levels)
            .map(|l| Pinhole::at_level(&rect, l))
            .collect();
        let schedule = Schedule::new(config.solver, config.n_search)?;
        let pivot_o = centroid(&points_o);
        let view = ViewMask::new(&sensor, VIEW_MARGIN_PX);
        let mut solver = Self {
            sensor,
            rect,
            reader,
            field,
            points: points_o,
            pivot_o,
            pins,
            view,
            visible: Vec::new(),
            last_lm: None,
            schedule,
            last: Estimate {
                pose: t_c_o,
                t_us: 0,
                seq: 0,
                step: StepKind::Search,
                cost: config.field.tau_px,
                inlier_fraction: 0.0,
                visible_fraction: 1.0,
                n_events: 0,
                confidence: 0.0,
                lost: true,
                pushed_ns: 0,
                published_ns: 0,
                oldest_pushed_ns: 0,
            },
            config,
            mask: Vec::new(),
            out,
            recency,
            motion: MotionMemory::default(),
            searching: false,
            unconfirmed_since_us: None,
            low_since_us: None,
            bank: None,
            points_dir_o: None,
            evidence: Evidence::default(),
            had_pose: true,
            full_pass: PassClock::default(),
            near_pass: PassClock::default(),
            any_pass: PassClock::default(),
            trusted_pose: None,
            pending: None,
            sweep_field: None,
            place_mask: Vec::new(),
            place_field: None,
            descent_field: None,
            global_since_us: i64::MIN,
            claim: Claim::default(),
            uv: Vec::new(),
            near_model: Vec::new(),
            active_at: None,
            lost_by: LostBy::Evidence,
            held_still: false,
            speed_px_s: 0.0,
        };
        solver.publish();
        Ok(solver)
    }

    /// Stamp the estimate with the time and the batches it is the first to contain, hand it to
    /// readers and book its latencies.
    fn publish(&mut self) {
        let claim = std::mem::take(&mut self.claim);
        let newest_was = self.out.latest().pushed_ns;
        self.last.oldest_pushed_ns = claim.oldest_pushed_ns;
        self.last.published_ns = crate::clock::now_ns();
        self.out.latest.publish(&self.last);
        if self.last.pushed_ns != newest_was {
            if let Some(ns) = self.last.latency_ns() {
                self.out.newest_latency.record(ns, 1);
            }
        }
        if let Some(ns) = self.last.oldest_latency_ns() {
            self.out.oldest_latency.record(ns, claim.count);
        }
        let published = self.last.published_ns;
        for stamp in self.out.pending.claimed_stamps(&claim) {
            // A lost stamp is booked at the claim's bound, which holds it (see `claim`).
            let pushed = stamp.unwrap_or(claim.oldest_pushed_ns);
            self.out
                .batch_latency
                .record(published.saturating_sub(pushed), 1);
        }
    }

    /// (event time µs, push stamp ns) of the newest batch, or the last estimate's before any.
    fn newest(&self) -> (i64, u64) {
        self.out
            .newest()
            .unwrap_or((self.last.t_us, self.last.pushed_ns))
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

    fn reset_pose(&mut self, t_c_o: Pose) -> Result<()> {
        check_pose(&t_c_o)?;
        self.last.pose = t_c_o;
        self.last_lm = None;
        // Not locked until an update confirms the new pose against the events; but a given pose
        // is tracked from, not searched for.
        self.last.lost = true;
        self.searching = false;
        self.had_pose = true;
        self.unconfirmed_since_us = None;
        self.lost_by = LostBy::Evidence;
        self.held_still = false;
        self.active_at = None;
        self.pending = None;
        self.trusted_pose = None;
        self.motion.reset();
        self.schedule.restart();
        self.publish();
        Ok(())
    }

    /// One update: rebuild the field from the current active set and run the next scheduled step
    /// (or, while lost with a template bank, one global search).
    fn step(&mut self) -> Estimate {
        // Both read before the mask: every event up to this time, and every batch claimed, is in
        // what the mask shows.
        let newest = self.newest();
        self.claim = self.out.pending.claim();
        let t_us = newest.0;
        self.want_pixel_times();
        if self
            .out
            .stream_us
            .load(Ordering::Acquire)
            .saturating_sub(t_us)
            >= EVENT_GAP_US
        {
            return self.blind(newest);
        }
        if self.searching {
            if let Some(bank) = self.bank.clone() {
                // Without a pose ever trusted or a candidate to confirm there is nothing to
                // track locally.
                let tracking = self.had_pose || self.pending.is_some();
                if !tracking && self.full_pass.ran_us == Some(t_us) {
                    // No event since the last pass: the same search would find the same, and a
                    // candidate is only confirmed by a pass over newer events.
                    self.last.seq += 1;
                    self.publish();
                    return self.last;
                }
                if let Some(pass) = self.pass_due(t_us, tracking) {
                    return self.reacquire(&bank, pass);
                }
            }
        }
        let kind = self.schedule.next_step();
        let started = Instant::now();
        let pose = self.last.pose;
        let n_events = self.out.ingested.load(Ordering::Relaxed);
        let margin = match kind {
            StepKind::Lm => self.config.roi_margin_px,
            StepKind::Search => self.config.search_roi_margin_px,
        };
        let Some(roi) = self.roi(margin) else {
            self.lose(newest, n_events, 1.0);
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
            self.lose(newest, n_events, visible_fraction);
            return self.last;
        }
        let whole = visible_fraction >= FULL_VIEW_FRACTION
            && !reaches_border(
                &self.pins[0],
                &Rigid32::from_pose(&pose),
                &visible,
                self.rect.width,
                self.rect.height,
            );
        let n_levels = if kind == StepKind::Lm && whole {
            self.config.field.levels
        } else {
            1
        };
        self.mask.resize(roi.area(), 0);
        self.reader.fill_mask(roi, &mut self.mask);
        let min_t = self.config.effective_search_min_t();
        let resumed = self.out.resumed_at_us.load(Ordering::Acquire);
        // After a gap in the events, and while the model is lost to silence (hidden), the
        // front-end's edges from before show where the object was, and would hold the pose there
        // while the object comes back elsewhere (occlusion-0.5s: the pose stayed on them, 20 → 55
        // mm off, confidence 0.3 → 0.05, never trusted again): the field is built only from
        // pixels whose block fired since the events resumed, or within the activity window
        // (since the silence began, the background has fired in most blocks). So too while a
        // global-search candidate is tracked: it was found on such a field, and the front-end
        // may hold what drowned the object (pure-noise: chance 0.56 around the candidate, its
        // confidence 0.02, and LM never pulled it the 22 mm the object moved during the pass).
        let fresh_since = if (0..AFTER_GAP_US).contains(&t_us.saturating_sub(resumed)) {
            Some(resumed)
        } else if self.last.lost && (self.lost_by == LostBy::Silence || self.pending.is_some()) {
            Some(t_us - ACTIVE_WINDOW_US)
        } else {
            None
        };
        let mut refilling = false;
        if let Some(since) = fresh_since {
            self.recency.keep_fresh(&mut self.mask, roi, since);
            // With the significance test on, the search steps that would pull the pose back onto
            // a sparse post-gap field are mostly held back while LM follows its few fresh pixels;
            // and a hidden object's field holds only background, onto which any solver would
            // wander (occlusion-0.5s, EDOPTS and EDFT: 0.36 and 0.6 m RMS). So nothing moves
            // until the field has as many fired pixels as S* has points.
            let silent = since != resumed;
            refilling = (min_t > 0.0 || silent)
                && self.mask.iter().filter(|&&m| m != 0).count() < self.points.len();
        }
        let built = self.field.build(&self.mask, roi, n_levels);
        let new_pose = match (&built, kind) {
            (Err(_), _) => pose,
            // A pose held still after a dropout (see `Solver::judge`) is held until its blocks
            // fire: till then the field around it holds background only (the refill's count of
            // fired pixels is reached by background alone in ~20 ms), which the steps would fit
            // (stop-go dropout episode: the held pose wandered 3.2 -> 5.6 mm; with a randomly
            // subsampled source, one LM step took it 65 mm off and the episode ended).
            (Ok(()), _) if refilling || self.held_still => pose,
            (Ok(()), StepKind::Lm) => {
                let levels: Vec<_> = (0..n_levels)
                    .rev()
                    .map(|l| (self.field.level(l), self.pins[l as usize]))
                    .collect();
                let report = lm_pyramid(&levels, pose, &visible, &self.pivot_o, &self.config.lm);
                self.last_lm = Some(report);
                report.pose
            }
            (Ok(()), StepKind::Search) => {
                let deltas = axis_steps(&self.pins[0], &pose, &visible, &self.pivot_o, 8);
                let out = search_step(
                    self.field.level(0),
                    &self.pins[0],
                    &pose,
                    &visible,
                    &self.pivot_o,
                    &deltas,
                    // Only while the outline is cut by the border: with the whole outline in view
                    // LM undoes a noise-level search move, and under occlusion the test held back
                    // the search steps that kept the pose on the object (objects suite, mug at
                    // 0.6 m 30 % occluded: 3.2 mm plain, 23 mm with the test everywhere).
                    (!whole).then(|| Gate::new(min_t, &self.config.lm)),
                );
                match &self.last_lm {
                    Some(lm) if lm.n_held > 0 && out.candidate > 0 => {
                        let k = (out.candidate - 1) / 2;
                        let sign = if out.candidate % 2 == 1 { 1.0 } else { -1.0 };
                        let xi = lm.without_held(&(unit_twist(k) * (sign * deltas[k])));
                        let pivot_c = pose * Point3::from(self.pivot_o);
                        apply_increment(&pose, &xi, &pivot_c.coords)
                    }
                    _ => out.pose,
                }
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
            self.out.jumps_rejected.fetch_add(1, Ordering::Relaxed);
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
        let confidence = if built.is_ok() {
            self.confidence_at(t_us, &accepted)
        } else {
            0.0
        };
        let lost = self.judge(t_us, confidence, built.is_ok());
        // A pose that fell is searched for at once; one still waiting for its first confirmation
        // (a given start pose) gets `UNCONFIRMED_US` of event time to lock before the search.
        if lost && !self.last.lost {
            self.searching = true;
        } else if lost {
            let since = *self.unconfirmed_since_us.get_or_insert(t_us);
            self.searching |= t_us - since >= UNCONFIRMED_US;
        } else {
            self.unconfirmed_since_us = None;
        }
        if !lost {
            self.searching = false;
            self.pending = None;
            self.near_pass = PassClock::default();
            self.trusted_pose = Some(accepted);
            self.follow_view(&accepted);
        }
        self.last = Estimate {
            pose: accepted,
            t_us,
            seq: self.last.seq + 1,
            step: kind,
            cost: quality.mean,
            inlier_fraction: quality.inlier_fraction,
            visible_fraction,
            n_events,
            confidence,
            lost,
            pushed_ns: newest.1,
            published_ns: 0,
            oldest_pushed_ns: 0,
        };
        self.publish();
        let ns = started.elapsed().as_nanos() as u64;
        let (count, time) = match kind {
            StepKind::Lm => (&self.out.lm_steps, &self.out.lm_ns),
            StepKind::Search => (&self.out.search_steps, &self.out.search_ns),
        };
        count.fetch_add(1, Ordering::Relaxed);
        time.fetch_add(ns, Ordering::Relaxed);
        self.last
    }
}

impl Solver {
    /// Number the next published estimate and stamp it with its newest batch's event time (µs)
    /// and push time (ns).
    fn stamp(&mut self, (t_us, pushed_ns): (i64, u64)) {
        self.last.seq += 1;
        self.last.t_us = t_us;
        self.last.pushed_ns = pushed_ns;
    }

    /// Publish an update without a pose change: the object is out of view (or nothing of it
    /// projects), so the pose cannot be trusted and is searched for.
    fn lose(&mut self, (t_us, pushed_ns): (i64, u64), n_events: u64, visible_fraction: f32) {
        self.stamp((t_us, pushed_ns));
        self.last.n_events = n_events;
        self.last.visible_fraction = visible_fraction;
        self.last.confidence = 0.0;
        self.last.lost = true;
        self.lost_by = LostBy::Evidence;
        self.held_still = false;
        self.searching = true;
        self.publish();
    }

    /// Publish an update without a pose change while the events have stopped (the stream went on
    /// for [`EVENT_GAP_US`] without one): the tracker is blind, so its pose is not to be trusted.
    /// Nothing is searched for: once events resume the pose is tracked on from where it was
    /// (seeing only what fired since, see [`AFTER_GAP_US`]) and judged as [`Solver::judge`] says.
    fn blind(&mut self, (t_us, pushed_ns): (i64, u64)) -> Estimate {
        self.stamp((t_us, pushed_ns));
        self.last.confidence = 0.0;
        if !self.last.lost {
            let still = max_age_us(self.speed_px_s).is_none();
            self.lost_by = LostBy::Dropout { still };
            // A moving object is elsewhere once the events resume: with a bank it is searched
            // for then, not trusted on the weaker local evidence (see `Solver::judge`).
            self.searching |= !still && self.bank.is_some();
        }
        self.held_still = false;
        self.last.lost = true;
        self.low_since_us = None;
        self.publish();
        self.last
    }

    /// Whether the pose published at `t_us` with `confidence` is lost. A trusted pose turns lost
    /// when its confidence stays below `lost_below` for `lost_hold_us` of event time: a step that
    /// lands a few pixels off (a search step on a fast turn) dips to 0 for an update and recovers
    /// the next, a pose that slid off the object does not. A lost one is trusted again from
    /// `relock_above` on; with a template bank, once searching, only by a global pass that finds
    /// it again (see [`LOCAL_FINDINGS`]).
    ///
    /// A model whose blocks fell quiet (see [`QUIET`]; only judged on a `built` field) counts as
    /// low whatever its support: a hidden object leaves its old edges in the front-end. A pose lost
    /// that way is trusted again only once its blocks fire again.
    ///
    /// A pose lost to a dropout is trusted again from `lost_below` once its blocks are visibly
    /// active again: blindness is no evidence against it, but the edges from before are. (Held to `relock_above`, a pose tracked
    /// on while the loop holds the camera still reads 0.25–0.38 as the object runs through the
    /// image, and is never trusted again: benches/RESULTS.md, issue 12 "Round 6"; with a template
    /// bank a moving object is searched for instead and held to `relock_above`.) If the model was still
    /// when the events stopped and, over a whole activity window since they resumed, its blocks fire
    /// no more than their surroundings, nothing has moved there: the pose is trusted again and held
    /// (`held_still`) until its blocks are visibly active again and, within [`AFTER_GAP_US`] of the
    /// resumption, its confidence reaches `lost_below`; active and below it until then, it is lost
    /// when the refill ends. Its support cannot say so: the
    /// pre-gap edges are hidden for [`AFTER_GAP_US`] and a still scene fires only background. An
    /// object that moved during the dropout and stopped elsewhere is trusted there all the same
    /// until something moves (nothing in the events tells them apart).
    fn judge(&mut self, t_us: i64, confidence: f32, built: bool) -> bool {
        let excess = Activity {
            on_model: self.evidence.active,
            around: self.evidence.active_around,
        }
        .excess();
        let firing = built && excess >= QUIET;
        if self.last.lost {
            if self.pending.is_some() {
                // A global-search candidate being tracked is trusted by the pass that confirms
                // it, on its stricter score, never by its local confidence alone.
                return true;
            }
            // Back from silence or a dropout only when visibly active again: the front-end's old
            // edges would otherwise be trusted (a sampled share of a few hundred blocks at the
            // background's rate passes `QUIET` now and then by chance: occlusion-0.5s, 270 ms
            // confidently wrong with `QUIET` here; after a dropout they are where the object was).
            let active = built && excess >= EXPECT_ACTIVE;
            let lost = match self.lost_by {
                LostBy::Evidence => confidence < self.config.relock_above,
                LostBy::Silence => confidence < self.config.relock_above || !active,
                LostBy::Dropout { still } => {
                    let resumed = self.out.resumed_at_us.load(Ordering::Acquire);
                    self.held_still = still
                        && built
                        && !firing
                        && t_us.saturating_sub(resumed) >= ACTIVE_WINDOW_US;
                    // With a bank, a moving object is searched for after the dropout (see
                    // `Solver::blind`), so the pose tracked on is held to `relock_above` like any
                    // other: at `lost_below` it was trusted 20 mm / 24° off at 0.25–0.38 for up to
                    // 104 ms (events-stop, EDFT, wip/relock8).
                    let back = if !still && self.bank.is_some() {
                        self.config.relock_above
                    } else {
                        self.config.lost_below
                    };
                    !(self.held_still || (active && confidence >= back))
                }
            };
            if !lost
                && self.searching
                && self.bank.is_some()
                && matches!(self.lost_by, LostBy::Evidence | LostBy::Silence)
            {
                // Lost for real with a search at hand: the local steps only propose the pose, and
                // the global search's test takes it (see `LOCAL_FINDINGS`). A held pose tracked on
                // by the search-only solver slid onto part of the box re-entering the view and
                // read 0.41–0.46 here while 75–191 mm and 26–35° off, then stayed above
                // `lost_below` for 15–444 ms (leave-return, EDOPTS, measured cost: in 9 of 18 runs,
                // 30 ms or more in 7; the passes scored such poses 0.05–0.21; benches/RESULTS.md,
                // issue 12, "Round 17").
                self.pending = Some(LOCAL_FINDINGS);
                return true;
            }
            return lost;
        }
        if self.held_still {
            // Released only when visibly active (a sampled share passes `QUIET` by chance now
            // and then): it moves, and from here its events say whether the pose is right.
            let active = built && excess >= EXPECT_ACTIVE;
            let resumed = self.out.resumed_at_us.load(Ordering::Acquire);
            if t_us.saturating_sub(resumed) < AFTER_GAP_US {
                // The field still refills after the gap (only blocks fired since, see
                // `AFTER_GAP_US`): as the object sets off few of its edges have fired, so a right
                // pose may read below `lost_below` for a while (stop-go dropout episode, source
                // outline half a pixel out: 0.10-0.12 at 1.55 s on a pose 3 mm off). It stays
                // trusted, but the low clock runs from its first active step and only the
                // confidence reaching `lost_below` before the refill ends stops it.
                if confidence >= self.config.lost_below {
                    self.low_since_us = None;
                } else if active {
                    self.low_since_us.get_or_insert(t_us);
                }
                if !(active && confidence >= self.config.lost_below) {
                    return false;
                }
            } else if self.low_since_us.take().is_some() {
                // Active and never confirmed while the field refilled: lost now, not judged on
                // the full field, where the edges from before the gap vouch for the held pose
                // however wrong it is (a wrong held pose is trusted until the refill ends at most).
                self.held_still = false;
                self.lost_by = LostBy::Evidence;
                return true;
            } else if !active {
                return false;
            }
            self.held_still = false;
        }
        let on_model = self.evidence.active;
        if built && excess >= EXPECT_ACTIVE {
            let from_us = match self.active_at {
                Some(a) if t_us - a.at_us <= ACTIVE_MEMORY_US => a.from_us,
                _ => t_us,
            };
            self.active_at = Some(ActiveStretch {
                from_us,
                at_us: t_us,
                share: on_model,
                deserted: false,
                hushed: false,
            });
        } else if let Some(a) = self.active_at.as_mut() {
            // The excess the other way round: the surroundings visibly busier than the model.
            a.deserted |= built
                && Activity {
                    on_model: self.evidence.active_around,
                    around: on_model,
                }
                .excess()
                    >= EXPECT_ACTIVE;
        }
        // Only a model that was active for a whole activity window can fall silent: a burst of a
        // few milliseconds (a still object's edges firing once as the sensor starts, a flash)
        // fades by itself (the default episode, seeds 2 and 3: flagged lost 22 ms in, on a right
        // pose of a still box, and never trusted again before this test). Unless what fired
        // there went on around the model (`deserted`): an object that set off from where the
        // pose stays; a burst fades everywhere. Held still after a dropout and setting off at
        // 4 mm/ms, the square's blocks fired for 9 ms before its events moved off them, and the
        // pose, trusted on the edges the set-off left there, was flagged lost only 41 ms after it
        // was 30 mm off, and trusted again on them 96 ms later.
        //
        // Once quiet, it stays so until visibly active again, as a pose lost to silence is trusted
        // again only then: a sampled share of the background's blocks on the model passes `QUIET`
        // now and then by chance (≈ 0.05 for a few ms), and restarting the low clock on such a
        // blip let the memory window close before it ran out — the hidden object's pose on the
        // front-end's old edges was then trusted until it came back (occlusion-2s, EDFT, measured
        // cost: 1.7 s confidently wrong in 2 of 3 suite runs; benches/RESULTS.md, issue 12,
        // "Round 17").
        let low_clock = self.low_since_us.is_some();
        let quiet = built
            && self.active_at.is_some_and(|a| {
                let fell = !firing
                    && (a.at_us - a.from_us >= ACTIVE_WINDOW_US || a.deserted)
                    && (0..=ACTIVE_MEMORY_US).contains(&(t_us - a.at_us));
                let stays = a.hushed && low_clock && excess < EXPECT_ACTIVE;
                (fell || stays) && on_model < FALLEN * a.share
            });
        if let Some(a) = self.active_at.as_mut() {
            a.hushed = quiet;
        }
        if confidence >= self.config.lost_below && !quiet {
            self.low_since_us = None;
            return false;
        }
        let since = *self.low_since_us.get_or_insert(t_us);
        let lost = t_us - since >= self.config.lost_hold_us;
        if lost {
            self.low_since_us = None;
            self.lost_by = if quiet {
                LostBy::Silence
            } else {
                LostBy::Evidence
            };
        }
        lost
    }

    /// The confidence of `pose` on the last built full-resolution field at `t_us`, its support
    /// required to be fresh while the model has been moving in the image.
    fn confidence_at(&mut self, t_us: i64, pose: &Pose) -> f32 {
        let speed = self.motion.update(t_us, pose, &self.pins[0], &self.points);
        self.speed_px_s = speed;
        let fresh = max_age_us(speed).map(|age| t_us - age);
        self.evidence = self.evidence_of(pose, &self.points, fresh, None);
        let activity = self.activity_at(t_us, pose);
        self.evidence.active = activity.on_model;
        self.evidence.active_around = activity.around;
        self.evidence.confidence()
    }

    /// How busy the model's blocks at `pose` were over the last [`ACTIVE_WINDOW_US`] before
    /// `t_us`, against the blocks around it (every [`ACTIVITY_POINT_STRIDE`]-th model point: a
    /// fraction needs a few hundred samples, and each costs a look-up in a sensor-sized table).
    fn activity_at(&mut self, t_us: i64, pose: &Pose) -> Activity {
        let rig = Rigid32::from_pose(pose);
        let pin = self.pins[0];
        let (w, h) = (self.rect.width as f32, self.rect.height as f32);
        let mut uv = std::mem::take(&mut self.uv);
        uv.clear();
        uv.extend(
            self.points
                .iter()
                .step_by(ACTIVITY_POINT_STRIDE)
                .filter_map(|&x| pin.project(rig.apply(x)))
                .filter(|&(u, v)| u >= 0.0 && v >= 0.0 && u < w && v < h),
        );
        let activity = Roi::around(
            uv.iter().map(|&(u, v)| (f64::from(u), f64::from(v))),
            self.config.search_roi_margin_px,
            self.rect.width,
            self.rect.height,
        )
        .map_or_else(Activity::default, |region| {
            self.recency
                .activity(&uv, region, t_us - ACTIVE_WINDOW_US, &mut self.near_model)
        });
        self.uv = uv;
        activity
    }

    /// The evidence for `pose` with `points` on the last built full-resolution field, its chance
    /// level taken over the search region around the projected model (the same region for LM and
    /// search steps, so both score alike); `fresh_since`: supported points also need an event in
    /// their block since then (µs). `explain_above`: also measure the share of the events around
    /// the pose that it explains (global search), when its support exceeds chance by at least
    /// that much; else `explained` stays 0. Scanning the region for it was the dearest part of
    /// scoring a candidate, and the acquisition score is at most that excess. The events to explain
    /// are the field's pixels that themselves fired since the global pass's freshness time.
    fn evidence_of(
        &self,
        pose: &Pose,
        points: &[[f32; 3]],
        fresh_since: Option<i64>,
        explain_above: Option<f32>,
    ) -> Evidence {
        let rig = Rigid32::from_pose(pose);
        let pin = self.pins[0];
        let uv = points
            .iter()
            .filter_map(|&x| pin.project(rig.apply(x)))
            .map(|(u, v)| (f64::from(u), f64::from(v)));
        let Some(region) = Roi::around(
            uv,
            self.config.search_roi_margin_px,
            self.rect.width,
            self.rect.height,
        ) else {
            return Evidence::default();
        };
        let query = Query {
            inlier_px: self.config.inlier_px,
            region,
            image: (self.rect.width, self.rect.height),
            fresh_since: fresh_since.map(|t| (&*self.recency, t)),
            explain: false,
        };
        let level = self.field.level(0);
        let mut e = evidence(level, &pin, &rig, points, &query);
        if explain_above.is_some_and(|floor| e.support - e.chance >= floor) {
            let fresh = Some((&*self.recency, self.global_since_us));
            e.explained = explained_fraction(level, &pin, &rig, points, region, fresh);
        }
        e
    }

    /// The acquisition score below which a global-search candidate decides nothing: it is not
    /// refined again ([`RESCORE_ABOVE`]), ranks below every measured one for turning
    /// ([`EXPLAIN_ABOVE`]), not taken
    /// (`reacquire_above`), and as a rival it cannot deny a candidate that could be taken its
    /// margin ([`ACQUISITION_MARGIN`]). Its `explained` share is not measured (see
    /// `evidence_of`); on the recordings of `tests/test_acquisition.py` (drill, box, 5 windows
    /// each) 40–67 % of the sweep's candidates have support − chance below it.
    fn score_floor(&self) -> f32 {
        EXPLAIN_ABOVE
            .min(RESCORE_ABOVE)
            .min(self.config.reacquire_above / ACQUISITION_MARGIN)
    }

    /// Which global pass, if any, is due at event time `t_us` while searching (`tracking`: there
    /// is a pose to track on locally between passes); notes its time.
    fn pass_due(&mut self, t_us: i64, tracking: bool) -> Option<Pass> {
        let resumed = self.out.resumed_at_us.load(Ordering::Acquire);
        let settling = (0..self.config.search_fresh_us).contains(&t_us.saturating_sub(resumed));
        let pass = if tracking && settling {
            // Events back from a gap for less than the search's freshness window: the full-image
            // field would hold the few pixels fired since and the edges from before the gap in
            // their blocks, which vouch for the held pose (events-stop: the first pass, 1 ms
            // after the return, scored the pose held 18 mm off at 0.49 and found nothing; 10 ms
            // after it, the box 1.3 mm off at 0.67). The local steps track on meanwhile, seeing
            // only what fired since (see `AFTER_GAP_US`).
            None
        } else if self.pending.is_some() {
            // Confirming a candidate costs a few LM refinements, not a sweep: it is due once the
            // local steps have tracked it for `GLOBAL_PASS_EVERY_US` (the object moved on while
            // the pass that found it ran: 18–24 mm in its 80 ms, occlusion-0.5s).
            self.any_pass
                .after_us
                .is_some_and(|a| t_us - a >= GLOBAL_PASS_EVERY_US || t_us < a)
                .then_some(Pass::Confirm)
        } else if self.had_pose && self.near_pass.ran_us.is_none() {
            // The first pass of a loss looks only around where the pose is and was trusted: the
            // object is most often still near there (events back after a dropout, a pose that
            // slid off a fast object), and a near pass costs a fraction of a full one, which
            // publishes nothing for its whole length (events-stop: the full pass charged
            // 100–150 ms while the right held pose read lost). A full pass follows if it finds
            // nothing.
            Some(Pass::Near)
        } else if !tracking || self.full_pass.due(t_us, FULL_PASS_REST) {
            Some(Pass::Full)
        } else if self.had_pose && self.near_pass.due(t_us, NEAR_PASS_REST) {
            Some(Pass::Near)
        } else {
            None
        };
        self.full_pass.note(pass == Some(Pass::Full), t_us);
        self.near_pass.note(pass == Some(Pass::Near), t_us);
        self.any_pass.note(pass.is_some(), t_us);
        pass
    }

    /// Build a field over the whole image from the pixels that fired within `search_fresh_us` of
    /// `t_us` and refine by LM, on it, the current pose, `extra` and what `pass` searches; every
    /// refined candidate with its evidence (None: the field could not be built).
    fn global_candidates(
        &mut self,
        bank: &TemplateBank,
        t_us: i64,
        extra: &[(Pose, Option<usize>)],
        pass: Pass,
    ) -> Option<Vec<Candidate>> {
        let full = Roi::full(self.rect.width, self.rect.height);
        let levels = self.config.field.levels;
        self.mask.resize(full.area(), 0);
        self.reader.fill_mask(full, &mut self.mask);
        // Search only what fired recently: the front-end keeps stale edges (where the object was)
        // and accumulates background noise, both of which would draw the search.
        self.global_since_us = t_us - self.config.search_fresh_us;
        self.recency
            .keep_fresh(&mut self.mask, full, self.global_since_us);
        self.field.build(&self.mask, full, levels).ok()?;
        let mut seeds: Vec<(Pose, Option<usize>, f32)> = vec![(self.last.pose, None, f32::NAN)];
        let coarsest = levels - 1;
        let sweep_level = self.sweep_level(coarsest);
        let pin = Pinhole::at_level(&self.rect, sweep_level);
        let mut sweep_field = self.sweep_field.take();
        self.build_pooled(&mut sweep_field, &self.mask, sweep_level)?;
        self.sweep_field = sweep_field;
        if pass == Pass::Full {
            seeds.extend(self.place_seeds(bank, sweep_level));
        }
        let level = self.sweep_field.as_ref()?.level(0);
        if pass == Pass::Full {
            seeds.extend(
                bank.search(level, &pin)
                    .into_iter()
                    .map(|(pose, view, cost)| (pose, Some(view), cost)),
            );
        }
        let mut anchors = Vec::new();
        if pass == Pass::Confirm {
            // Around the candidate being tracked: the object moved on while the pass that found
            // it ran, and the local steps do not always pull the candidate back (start-without-
            // pose: found 1.3 mm off, 27 mm off when the 134 ms pass was over, still 28 mm off at
            // the confirm pass 10 ms later; never trusted).
            anchors.push(self.last.pose);
        } else if self.had_pose {
            // Around where the object was last trusted (the camera stopped there) and where
            // the local steps took the pose since (a tracked pose drifts while the object is
            // hidden or drowned in noise: pure-noise, 35 mm / 30° at its end).
            anchors.push(self.last.pose);
            anchors.extend(
                self.trusted_pose
                    .filter(|p| !same_place(p, &self.last.pose)),
            );
        }
        for anchor in anchors {
            let view = bank.nearest_view(&anchor).0;
            seeds.extend(
                bank.search_near(level, &pin, &anchor, view, NEAR_CANDIDATES)
                    .into_iter()
                    .map(|(pose, cost)| (pose, Some(view), cost)),
            );
        }
        for &(p, v) in extra {
            let v = v.unwrap_or_else(|| bank.nearest_view(&p).0);
            let c = bank.chamfer_at(
                self.field.level(coarsest),
                &self.pins[coarsest as usize],
                &p,
                v,
            );
            seeds.push((p, Some(v), c));
        }
        Some(
            seeds
                .into_iter()
                .filter_map(|(seed, view, chamfer)| self.refine(bank, seed, view, chamfer))
                .collect(),
        )
    }

    /// The level the sweep runs on: the coarsest pyramid level, or coarser while that is wider
    /// than `SWEEP_MAX_WIDTH` pixels. The sweep's tolerance to a template's misplacement is a few
    /// field pixels, so it must see the object at about the same size in pixels whatever the
    /// sensor (at 1280×720 the coarsest level, 320 px wide, left the drill and the box unfound
    /// where at 640×360 they were found).
    fn sweep_level(&self, coarsest: u32) -> u32 {
        let width = self.rect.width as usize;
        let mut level = coarsest;
        while width.div_ceil(1 << level) > SWEEP_MAX_WIDTH {
            level += 1;
        }
        level
    }

    /// Build `field` (one level, made on first use) from the full-image `mask` pooled at `level`
    /// (see [`crate::templates::pool_above_background`]); None: not built.
    fn build_pooled(
        &self,
        field: &mut Option<DistanceField>,
        mask: &[u8],
        level: u32,
    ) -> Option<()> {
        let (width, height) = (self.rect.width as usize, self.rect.height as usize);
        let (pooled, w, h) = pool_above_background(mask, width, height, level);
        let params = FieldParams {
            levels: 1,
            ..self.config.field
        };
        let field = match field {
            Some(f) => f,
            none => none.insert(DistanceField::new(params).ok()?),
        };
        field.build(&pooled, Roi::full(w as u32, h as u32), 1).ok()
    }

    /// The place search's candidates (see `TemplateBank::search_place`), each moved downhill
    /// (`TemplateBank::descend`) on a field one level finer than the sweep's: (seed, view, chamfer).
    /// Both fields are pooled from the pixels that themselves fired since the pass's freshness
    /// time (see `Solver::fill_place_mask`), not every pixel of a block that fired.
    fn place_seeds(
        &mut self,
        bank: &TemplateBank,
        sweep_level: u32,
    ) -> Vec<(Pose, Option<usize>, f32)> {
        self.fill_place_mask();
        let fine_level = sweep_level.saturating_sub(1);
        let (mut coarse, mut fine) = (self.place_field.take(), self.descent_field.take());
        let built = self
            .build_pooled(&mut coarse, &self.place_mask, sweep_level)
            .and_then(|()| self.build_pooled(&mut fine, &self.place_mask, fine_level));
        let seeds = match (built, &coarse, &fine) {
            (Some(()), Some(c), Some(f)) => {
                let (pin, fine_pin) = (
                    Pinhole::at_level(&self.rect, sweep_level),
                    Pinhole::at_level(&self.rect, fine_level),
                );
                bank.search_place(c.level(0), &pin, PLACE_CANDIDATES)
                    .into_iter()
                    .map(|(pose, view, cost)| {
                        (
                            bank.descend(f.level(0), &fine_pin, &pose, view),
                            Some(view),
                            cost,
                        )
                    })
                    .collect()
            }
            _ => Vec::new(),
        };
        (self.place_field, self.descent_field) = (coarse, fine);
        seeds
    }

    /// `place_mask`: the pixels of the full-image `mask` that themselves fired since
    /// `global_since_us` (see [`Recency::pixel_fired_since`]). The mask keeps every pixel of a
    /// block that fired, and the front-end holds background noise for seconds: in leave-return,
    /// 40 % of the sweep's cells were active over the whole image, and the densest place was
    /// anywhere.
    fn fill_place_mask(&mut self) {
        let width = (self.rect.width as usize).max(1);
        let (mask, recency, since) = (&self.mask, &self.recency, self.global_since_us);
        self.place_mask.clear();
        self.place_mask.resize(mask.len(), 0);
        for (v, (row, out)) in mask
            .chunks_exact(width)
            .zip(self.place_mask.chunks_exact_mut(width))
            .enumerate()
        {
            for (u, (&m, o)) in row.iter().zip(out.iter_mut()).enumerate() {
                *o = u8::from(m != 0 && recency.pixel_fired_since(u as u32, v as u32, since));
            }
        }
    }

    /// Refine `seed` by LM on the last full-image field with S* of `view` (None: the current S*)
    /// and weigh the events' evidence for the result (None: no valid pose).
    fn refine(
        &self,
        bank: &TemplateBank,
        seed: Pose,
        view: Option<usize>,
        chamfer: f32,
    ) -> Option<Candidate> {
        let pyramid: Vec<_> = (0..self.config.field.levels)
            .rev()
            .map(|l| (self.field.level(l), self.pins[l as usize]))
            .collect();
        let points = view.map_or(&self.points, |v| &bank.views[v].points_o);
        let pivot = centroid(points);
        let pose = lm_pyramid(&pyramid, seed, points, &pivot, &self.config.lm).pose;
        check_pose(&pose).ok()?;
        let evidence = self.evidence_of(&pose, points, None, Some(self.score_floor()));
        let first = Candidate {
            seed,
            view,
            chamfer,
            pose,
            evidence,
        };
        // LM may have turned the pose away from the view it started from: a promising candidate
        // is refined again at full resolution with S* of the view nearest to where it went (the
        // edges, print included, seen from there) and scored on that; a view 27° off leaves part
        // of the true edges out and the truth explaining too little of the events.
        let (near, _) = bank.nearest_view(&pose);
        if view.is_none() || view == Some(near) || acquisition_score(&evidence) < RESCORE_ABOVE {
            return Some(first);
        }
        let points = &bank.views[near].points_o;
        let pivot = centroid(points);
        let finest = &pyramid[pyramid.len() - 1..];
        let pose = lm_pyramid(finest, pose, points, &pivot, &self.config.lm).pose;
        if check_pose(&pose).is_err() {
            return Some(first);
        }
        let evidence = self.evidence_of(&pose, points, None, Some(self.score_floor()));
        Some(Candidate {
            seed,
            view: Some(near),
            chamfer,
            pose,
            evidence,
        })
    }

    /// One global search over the whole image (see [`crate::templates`]): the bank's best
    /// candidates and the current pose are refined by LM on a full-image field, and the most
    /// confident is taken if it passes `reacquire_above`; otherwise the tracker stays lost.
    fn reacquire(&mut self, bank: &TemplateBank, pass: Pass) -> Estimate {
        let started = Instant::now();
        let (t_us, pushed_ns) = self.newest();
        let n_events = self.out.ingested.load(Ordering::Relaxed);
        let pending = self.pending.take();
        let mut found = self
            .global_candidates(bank, t_us, &[], pass)
            .unwrap_or_default();
        if pass == Pass::Full {
            let turned = self.turn_best(bank, &found);
            found.extend(turned);
        }
        let mut scored: Vec<(f32, Pose, Option<usize>)> = found
            .into_iter()
            .map(|c| (acquisition_score(&c.evidence), c.pose, c.view))
            .collect();
        let top = |scored: &[(f32, Pose, Option<usize>)]| {
            scored
                .iter()
                .copied()
                .fold(None, |b: Option<(f32, Pose, Option<usize>)>, c| {
                    if b.as_ref().is_none_or(|b| c.0 > b.0) {
                        Some(c)
                    } else {
                        b
                    }
                })
        };
        // A candidate good enough to take has look-alikes the sweep may have missed: the object
        // turned half a turn about one of its axes through its centre (a box's outline is the same
        // then; only its print tells). They are refined and scored too, so that the margin below
        // weighs the truth against them whichever of them the sweep found.
        if let Some((_, pose, _)) = top(&scored).filter(|b| b.0 >= self.config.reacquire_above) {
            let c = bank.centre_o();
            for axis in [Vector3::x_axis(), Vector3::y_axis(), Vector3::z_axis()] {
                let turn = UnitQuaternion::from_axis_angle(&axis, std::f64::consts::PI);
                let about = Pose::from_parts(Translation3::from(c - turn * c), turn);
                let seed = pose * about;
                let view = bank.nearest_view(&seed).0;
                if let Some(k) = self.refine(bank, seed, Some(view), f32::NAN) {
                    scored.push((acquisition_score(&k.evidence), k.pose, k.view));
                }
            }
        }
        let best = top(&scored);
        // The best must stand out from every fit elsewhere: an outline that two poses explain
        // alike (a box turned 180°) is not evidence for either.
        let rival = best.map_or(0.0, |b| {
            scored
                .iter()
                .filter(|c| !same_place(&c.1, &b.1))
                .map(|c| c.0)
                .fold(0.0, f32::max)
        });
        let best = best.filter(|b| b.0 >= ACQUISITION_MARGIN * rival);
        self.stamp((t_us, pushed_ns));
        self.last.n_events = n_events;
        self.last.step = StepKind::Lm;
        self.last.confidence = best.map_or(0.0, |b| b.0);
        self.last.lost = true;
        if let Some((c, pose, view)) = best.filter(|b| b.0 >= self.config.reacquire_above) {
            // Trusted only once a later pass finds it again where the local steps took it on the
            // new events: a fit that one pass's events happen to allow, on noise or on part of the
            // edges, rarely survives the next. Until then it is tracked, still lost: the object
            // moves on between passes (occlusion-0.5s: 45 mm in the 150 ms to the next full pass,
            // and a candidate refined from where the first pass left it was never found again).
            let passes = match pending {
                Some(n) if same_place(&self.last.pose, &pose) => n + 1,
                _ => 1,
            };
            if let Some(v) = view {
                self.use_view(bank, v);
            }
            self.last.pose = pose;
            self.motion.reset();
            self.schedule.restart();
            if passes >= CONFIRM_PASSES {
                self.had_pose = true;
                self.near_pass = PassClock::default();
                self.trusted_pose = Some(pose);
                self.last.confidence = c;
                self.last.lost = false;
                self.last.visible_fraction = 1.0;
                self.searching = false;
                self.lost_by = LostBy::Evidence;
                self.held_still = false;
            } else {
                self.pending = Some(passes);
            }
        }
        self.publish();
        self.out.reacquire_passes.fetch_add(1, Ordering::Relaxed);
        self.out
            .reacquire_ns
            .fetch_add(started.elapsed().as_nanos() as u64, Ordering::Relaxed);
        self.last
    }

    /// The [`TURNED_CANDIDATES`] best of `found` (by acquisition score, then support − chance,
    /// whatever they score) refined again, each turned by one view spacing either way about the
    /// camera's three axes through the object's centre. The sweep keeps a few attitudes per place,
    /// and on the right place a wrong attitude often has the better coarse chamfer; LM from 13–30°
    /// off stops 47–57 mm / 13–17° off (start-without-pose: acquisition 0.22–0.31, the truth
    /// 0.64); from within half a view spacing it converges. Not only the two best scoring 0.15 or
    /// more, as before: on the drill the refinement nearest the truth often sits at the right
    /// place 16–22° turned scoring 0.13–0.31, under that or behind two better wrong fits (one
    /// pass per window, drill at 1280×720: found in 11 → 22 of 33 windows, none wrong; the pass
    /// 1.47× as dear; benches/RESULTS.md, issue 12, "Round 14").
    fn turn_best(&self, bank: &TemplateBank, found: &[Candidate]) -> Vec<Candidate> {
        let mut best: Vec<(f32, f32, Pose)> = found
            .iter()
            .map(|c| {
                let e = &c.evidence;
                (acquisition_score(e), e.support - e.chance, c.pose)
            })
            .collect();
        best.sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(b.1.total_cmp(&a.1)));
        let step = bank.params.view_spacing_deg.to_radians();
        let centre_o = bank.centre_o();
        let mut turned = Vec::new();
        for (_, _, pose) in best.into_iter().take(TURNED_CANDIDATES) {
            let centre_c = pose * Point3::from(centre_o);
            for axis in [Vector3::x_axis(), Vector3::y_axis(), Vector3::z_axis()] {
                for angle in [-step, step] {
                    let r = UnitQuaternion::from_axis_angle(&axis, angle) * pose.rotation;
                    let t = centre_c.coords - r * centre_o;
                    let seed = Pose::from_parts(Translation3::from(t), r);
                    let view = bank.nearest_view(&seed).0;
                    turned.extend(self.refine(bank, seed, Some(view), f32::NAN));
                }
            }
        }
        turned
    }

    /// Ask the ingest half for per-pixel event times while a global search may run (see
    /// [`Recency::pixel_fired_since`]).
    fn want_pixel_times(&self) {
        self.recency
            .want_pixel_times(self.searching && self.bank.is_some());
    }

    /// Take S* from view `v` of `bank` (between updates: the next step uses it).
    fn use_view(&mut self, bank: &TemplateBank, v: usize) {
        self.points.clone_from(&bank.views[v].points_o);
        self.pivot_o = centroid(&self.points);
        self.points_dir_o = Some(bank.views[v].dir_o);
        self.last_lm = None;
    }

    /// Swap S* for the bank's view nearest to `pose` once the object has turned more than ¾ of the
    /// view spacing away from the view the current S* came from: its visible edges have changed.
    fn follow_view(&mut self, pose: &Pose) {
        let (Some(bank), Some(dir)) = (self.bank.clone(), self.points_dir_o) else {
            return;
        };
        let now = camera_direction_o(pose, &bank.centre_o());
        let limit = 0.75 * bank.params.view_spacing_deg.to_radians();
        if dir.dot(&now).clamp(-1.0, 1.0).acos() <= limit {
            return;
        }
        let (v, angle) = bank.nearest_view(pose);
        if angle < limit {
            self.use_view(&bank, v);
        }
    }
}

/// Both halves in one place, driven synchronously: ingest a batch, run steps.
pub struct TrackerCore {
    ingest: Ingest,
    solver: Solver,
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
        config.ingest_limit.check()?;
        let camera = camera.checked()?;
        let (writer, reader) = split_surface(&config.frontend, camera.width, camera.height)?;
        let placeholder = Estimate {
            pose: t_c_o,
            t_us: 0,
            seq: 0,
            step: StepKind::Search,
            cost: 0.0,
            inlier_fraction: 0.0,
            visible_fraction: 1.0,
            n_events: 0,
            confidence: 0.0,
            lost: true,
            pushed_ns: 0,
            published_ns: 0,
            oldest_pushed_ns: 0,
        };
        let out = Arc::new(TrackerOutput::new(&placeholder));
        let recency = Arc::new(Recency::new(&camera, &camera.rectified()));
        let ingest = Ingest {
            width: camera.width,
            height: camera.height,
            lut: UndistortLut::new(&camera),
            writer,
            last_t_us: None,
            thinning: Thinning::new(config.ingest_limit),
            flicker: (!config.anti_flicker_hz.is_empty())
                .then(|| FlickerFilter::new(camera.width, camera.height, &config.anti_flicker_hz))
                .transpose()?,
            unflickered: Vec::new(),
            pixels: Vec::new(),
            recency: Arc::clone(&recency),
            out: Arc::clone(&out),
        };
        let solver = Solver::new(camera, points_o, t_c_o, config, reader, recency, out)?;
        ensure(solver.roi(0.0).is_some(), || {
            "the object does not project into the image at the initial pose".into()
        })?;
        Ok(Self { ingest, solver })
    }

    /// A tracker without a pose: it starts lost and searches the whole image with `bank` until the
    /// confidence test accepts a candidate.
    pub fn searching(camera: &Camera, bank: TemplateBank, config: TrackerConfig) -> Result<Self> {
        let view = &bank.views[0];
        let t = Vector3::new(0.0, 0.0, bank.params.depth_max_m) - view.r_c_o * bank.centre_o();
        let pose = Pose::from_parts(Translation3::from(t), view.r_c_o);
        let mut core = Self::new(camera, view.points_o.clone(), pose, config)?;
        core.solver.points_dir_o = Some(view.dir_o);
        core.solver.bank = Some(Arc::new(bank));
        core.solver.searching = true;
        core.solver.had_pose = false;
        core.solver.want_pixel_times();
        Ok(core)
    }

    /// Diagnostics: one global search on the current events without changing the tracker's state
    /// (beyond its field), `extra` poses refined and scored alongside the sweep's candidates.
    /// Empty without a template bank. A candidate whose support exceeds chance by less than the
    /// search's score floor reads `explained` 0 (not measured: its score cannot matter).
    pub fn global_candidates(&mut self, extra: &[Pose]) -> Vec<Candidate> {
        let s = &mut self.solver;
        let Some(bank) = s.bank.clone() else {
            return Vec::new();
        };
        let t_us = s.newest().0;
        let extra: Vec<_> = extra.iter().map(|&p| (p, None)).collect();
        s.global_candidates(&bank, t_us, &extra, Pass::Full)
            .unwrap_or_default()
    }

    /// The template bank's model centre (object frame), if there is a bank.
    pub fn bank_centre_o(&self) -> Option<Vector3<f64>> {
        self.solver.bank.as_ref().map(|b| b.centre_o())
    }

    /// Give up the current pose: the estimate reads lost and, with a template bank, the next
    /// updates search the whole image (e.g. when the caller knows the object was moved).
    pub fn start_search(&mut self) {
        let s = &mut self.solver;
        s.last.lost = true;
        s.last.confidence = 0.0;
        s.searching = true;
        s.had_pose = false;
        s.trusted_pose = None;
        s.pending = None;
        s.full_pass = PassClock::default();
        s.near_pass = PassClock::default();
        s.any_pass = PassClock::default();
        s.want_pixel_times();
        s.publish();
    }

    /// Re-acquire with `bank` while lost, and take S* from its nearest view when the object turns
    /// away from where the current S* was rendered.
    pub fn set_templates(&mut self, bank: TemplateBank) {
        let s = &mut self.solver;
        s.points_dir_o = Some(camera_direction_o(&s.last.pose, &bank.centre_o()));
        s.bank = Some(Arc::new(bank));
    }

    pub fn config(&self) -> &TrackerConfig {
        &self.solver.config
    }

    /// The rectified camera the solver works in.
    pub fn camera(&self) -> &Camera {
        &self.solver.rect
    }

    pub fn points(&self) -> &[[f32; 3]] {
        &self.solver.points
    }

    pub fn latest(&self) -> Estimate {
        self.solver.last
    }

    /// What the events said at the last tracked pose: the parts of its confidence.
    pub fn evidence(&self) -> Evidence {
        self.solver.evidence
    }

    pub fn stats(&self) -> TrackerStats {
        self.solver.out.stats()
    }

    /// The output both halves publish to; stays valid (and live) when the solver moves to a thread.
    pub fn output(&self) -> Arc<TrackerOutput> {
        Arc::clone(&self.solver.out)
    }

    /// The front-end's active set for `roi` of the rectified image (see [`crate::EventSurface::fill_mask`]).
    pub fn fill_mask(&self, roi: Roi, out: &mut [u8]) {
        self.solver.reader.fill_mask(roi, out);
    }

    /// Steps per cycle: 1 LM + N search for EDFT⁺, N + 1 steps of the single solver otherwise.
    pub fn cycle_len(&self) -> usize {
        self.solver.schedule.cycle_len()
    }

    /// Validate and ingest every event of a batch into the front-end (no thinning). A rejected
    /// batch leaves the tracker unchanged.
    pub fn ingest<E: EventRecords + ?Sized>(&mut self, events: &E) -> Result<()> {
        self.ingest.push(events, false)
    }

    /// As [`Self::ingest`], but thinned under overload exactly as [`ThreadedTracker::push`] does
    /// (for a simulated producer that must behave like the threaded tracker's).
    pub fn ingest_thinned<E: EventRecords + ?Sized>(&mut self, events: &E) -> Result<()> {
        self.ingest.push(events, true)
    }

    /// Forget every event and the time line; the pose stays. After this, time may start anew
    /// (e.g. a camera that restarted its clock, or a batch of corrupt time stamps).
    pub fn reset_events(&mut self) {
        self.ingest.reset();
    }

    /// The stream has reached `t_us` without further events (see [`Ingest::advance_time`]).
    pub fn advance_time(&mut self, t_us: i64) -> Result<()> {
        self.ingest.advance_time(t_us)
    }

    /// Set the pose (e.g. re-initialisation); the front-end keeps its events. The estimate reads
    /// lost until the next update.
    pub fn reset_pose(&mut self, t_c_o: Pose) -> Result<()> {
        self.solver.reset_pose(t_c_o)
    }

    /// One update: rebuild the field from the current active set and run the next scheduled step.
    pub fn step(&mut self) -> Estimate {
        self.solver.step()
    }

    /// Synchronous update: ingest the batch, run one full cycle, return the last estimate.
    pub fn update<E: EventRecords + ?Sized>(&mut self, events: &E) -> Result<Estimate> {
        self.ingest(events)?;
        for _ in 0..self.cycle_len() {
            self.step();
        }
        Ok(self.solver.last)
    }

    /// The model points projected at the current pose (rectified pixels); for overlays.
    pub fn projected_points(&self) -> Vec<(f32, f32)> {
        let s = &self.solver;
        let rig = Rigid32::from_pose(&s.last.pose);
        s.points
            .iter()
            .filter_map(|&x| s.pins[0].project(rig.apply(x)))
            .collect()
    }

    /// The full-resolution field as last built, with its region (for overlays and diagnostics).
    pub fn field_level0(&self) -> &crate::field::FieldLevel {
        self.solver.field.level(0)
    }

    /// The model's pivot (centroid of S*) in the camera frame at the current pose.
    pub fn pivot_c(&self) -> Vector3<f64> {
        (self.solver.last.pose * Point3::from(self.solver.pivot_o)).coords
    }
}

/// Why [`ThreadedTracker::start`] failed, with the core handed back unchanged.
pub struct StartFailed {
    pub core: Box<TrackerCore>,
    pub error: Error,
}

/// A tracker whose solver runs in its own thread while the owner ingests on its own thread.
pub struct ThreadedTracker {
    ingest: Ingest,
    out: Arc<TrackerOutput>,
    control: Arc<Control>,
    handle: Option<JoinHandle<Solver>>,
    thread: Thread,
    /// The process that started the thread: after `fork()` a child has the memory but not the thread.
    pid: u32,
    /// What a replacement solver needs if the thread is gone (fork) or died (panic).
    rebuild: (Camera, Vec<[f32; 3]>, TrackerConfig),
}

impl ThreadedTracker {
    /// Move the solver of `core` into a new thread. On failure (e.g. no memory for a stack) the
    /// core comes back untouched.
    pub fn start(core: TrackerCore) -> std::result::Result<Self, StartFailed> {
        Self::start_with(core, thread::Builder::new())
    }

    fn start_with(
        core: TrackerCore,
        builder: thread::Builder,
    ) -> std::result::Result<Self, StartFailed> {
        let TrackerCore { ingest, solver } = core;
        let rebuild = (solver.sensor, solver.points.clone(), solver.config.clone());
        let out = Arc::clone(&solver.out);
        let control = Arc::new(Control::default());
        // The solver waits in a slot the thread takes it from, so that a failed spawn (which
        // drops the closure) does not take the solver with it.
        let slot = Arc::new(Mutex::new(Some(solver)));
        // Taken here, not in the thread: a batch pushed before the thread gets going must count as new.
        let idle_at_start = out.stats().events_ingested == 0;
        let batches_at_start = out.batches.load(Ordering::Acquire);
        let spawned = {
            let (slot, control) = (Arc::clone(&slot), Arc::clone(&control));
            builder.name("evservo-tracker".into()).spawn(move || {
                let solver = slot
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .take()
                    .expect("the solver is handed over exactly once");
                run(solver, &control, batches_at_start, idle_at_start)
            })
        };
        match spawned {
            Ok(handle) => Ok(Self {
                ingest,
                out,
                control,
                thread: handle.thread().clone(),
                handle: Some(handle),
                pid: std::process::id(),
                rebuild,
            }),
            Err(e) => {
                let solver = slot
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .take()
                    .expect("a thread that was never created cannot have taken the solver");
                Err(StartFailed {
                    core: Box::new(TrackerCore { ingest, solver }),
                    error: Error::Tracking(format!("could not start the tracker thread: {e}")),
                })
            }
        }
    }

    /// True in a process forked from the one that started the thread (which does not exist here).
    fn forked(&self) -> bool {
        std::process::id() != self.pid
    }

    /// Validate and ingest a batch on the caller's thread, thinned under overload, then wake the
    /// solver. Never waits for the solver.
    pub fn push<E: EventRecords + ?Sized>(&mut self, events: &E) -> Result<()> {
        if self.forked() {
            return Err(Error::Tracking(
                "the tracker thread was started before fork() and does not exist in this process: \
                 call stop() and start() to run a new one here"
                    .into(),
            ));
        }
        if !self.is_running() {
            return Err(Error::Tracking(
                "the tracker thread has ended unexpectedly: call stop() to recover the tracker"
                    .into(),
            ));
        }
        self.ingest.push(events, true)?;
        self.thread.unpark();
        Ok(())
    }

    /// Forget every event and the time line (see [`TrackerCore::reset_events`]).
    pub fn reset_events(&mut self) {
        self.ingest.reset();
    }

    /// The stream has reached `t_us` without further events (see [`Ingest::advance_time`]); wakes
    /// the solver.
    pub fn advance_time(&mut self, t_us: i64) -> Result<()> {
        self.ingest.advance_time(t_us)?;
        self.thread.unpark();
        Ok(())
    }

    pub fn latest(&self) -> Estimate {
        self.out.latest()
    }

    pub fn stats(&self) -> TrackerStats {
        self.out.stats()
    }

    pub fn output(&self) -> Arc<TrackerOutput> {
        Arc::clone(&self.out)
    }

    /// The solver thread's kernel id (Linux), for affinity and scheduling; waits up to a second
    /// for a thread that has just been started to report it. None where it cannot be known.
    pub fn solver_thread_id(&self) -> Option<i64> {
        let deadline = Instant::now() + Duration::from_secs(1);
        while self.is_running() && Instant::now() < deadline {
            match self.out.solver_tid.load(Ordering::Acquire) {
                0 => thread::sleep(Duration::from_micros(100)),
                tid => return (tid > 0).then_some(tid),
            }
        }
        None
    }

    /// Keep the solver thread busy at most `share` (0..=1] of the wall time while it has work,
    /// spread as short pauses after its steps; None = no limit (the default).
    ///
    /// For a solver at real-time priority (SCHED_FIFO): Linux reserves a share of every second for
    /// ordinary tasks waiting on a CPU that a real-time thread keeps busy (the fair server or RT
    /// throttling, 50 ms per second by default), and takes it in one piece: a solver that never
    /// rests would stop for ~50 ms once a second, which is a lost pose on a moving object. Resting
    /// a little after each step gives the ordinary tasks their share in slivers instead.
    pub fn limit_busy_share(&self, share: Option<f64>) -> Result<()> {
        let bits = match share {
            None => 0,
            Some(s) => {
                ensure(s.is_finite() && s > 0.0 && s <= 1.0, || {
                    format!("the busy share {s} must be in (0, 1]")
                })?;
                s.to_bits()
            }
        };
        self.control.busy_share.store(bits, Ordering::Relaxed);
        Ok(())
    }

    /// True while the solver thread runs in this process.
    pub fn is_running(&self) -> bool {
        !self.forked() && self.handle.as_ref().is_some_and(|h| !h.is_finished())
    }

    /// Stop the thread and get the core back. Where the thread cannot be joined (a forked child)
    /// or has died, a new solver is built at the last published pose; the front-end keeps its
    /// events either way.
    pub fn stop(mut self) -> TrackerCore {
        let solver = self.stop_thread();
        let ingest = self.take_ingest();
        let solver = solver.unwrap_or_else(|| {
            let (camera, points, config) = self.rebuild.clone();
            let last = self.out.latest();
            let mut s = Solver::new(
                camera,
                points,
                last.pose,
                config,
                ingest.writer.reader(),
                Arc::clone(&ingest.recency),
                Arc::clone(&self.out),
            )
            .expect("these parameters built a solver before");
            s.last = Estimate { lost: true, ..last };
            s.publish();
            s
        });
        TrackerCore { ingest, solver }
    }

    /// Ask the thread to stop and join it; None if there is no thread to join here.
    fn stop_thread(&mut self) -> Option<Solver> {
        let handle = self.handle.take()?;
        if self.forked() {
            // Joining a thread of another process is undefined; its memory here is just leaked.
            std::mem::forget(handle);
            return None;
        }
        self.control.stop.store(true, Ordering::Release);
        self.thread.unpark();
        handle.join().ok()
    }

    fn take_ingest(&mut self) -> Ingest {
        // `stop` consumes self, and Drop only needs the thread: swap in an inert ingest.
        let inert = Ingest {
            width: 0,
            height: 0,
            lut: UndistortLut {
                width: 0,
                height: 0,
                index: Vec::new(),
            },
            writer: Box::new(NoWriter),
            last_t_us: None,
            thinning: Thinning::new(IngestLimit::Off),
            flicker: None,
            unflickered: Vec::new(),
            pixels: Vec::new(),
            recency: Arc::clone(&self.ingest.recency),
            out: Arc::clone(&self.out),
        };
        std::mem::replace(&mut self.ingest, inert)
    }
}

/// A writer with nothing behind it, for the ingest left in a stopped [`ThreadedTracker`].
struct NoWriter;

impl SurfaceWriter for NoWriter {
    fn ingest(&mut self, _pixels: &[u32]) {}
    fn reset(&mut self) {}
    fn reader(&self) -> Arc<dyn SurfaceReader> {
        Arc::new(NoReader)
    }
}

struct NoReader;

impl SurfaceReader for NoReader {
    fn fill_mask(&self, _roi: Roi, out: &mut [u8]) {
        out.fill(0);
    }
}

impl Drop for ThreadedTracker {
    fn drop(&mut self) {
        self.stop_thread();
    }
}

/// This thread's kernel id, from `/proc/thread-self` (Linux; None elsewhere).
fn kernel_thread_id() -> Option<i64> {
    let link = std::fs::read_link("/proc/thread-self").ok()?;
    link.file_name()?.to_str()?.parse().ok()
}

fn run(solver: Solver, control: &Control, mut seen: u64, idle_at_start: bool) -> Solver {
    let tid = kernel_thread_id().unwrap_or(-1);
    solver.out.solver_tid.store(tid, Ordering::Release);
    let solver = run_steps(solver, control, &mut seen, idle_at_start);
    solver.out.solver_tid.store(0, Ordering::Release);
    solver
}

fn run_steps(mut solver: Solver, control: &Control, seen: &mut u64, idle_at_start: bool) -> Solver {
    // After a full cycle without new events the field cannot change, so the solver rests until
    // the next push instead of spinning.
    let cycle = solver.schedule.cycle_len();
    let mut steps_without_events = if idle_at_start { cycle } else { 0 };
    let mut owed = Duration::ZERO;
    while !control.stop.load(Ordering::Acquire) {
        let batches = solver.out.batches.load(Ordering::Acquire);
        if batches != *seen {
            *seen = batches;
            steps_without_events = 0;
        }
        if steps_without_events >= cycle {
            // Resting here pays off what the busy-share limit is owed (a park can end at once).
            let rested = Instant::now();
            thread::park_timeout(Duration::from_millis(5));
            owed = owed.saturating_sub(rested.elapsed());
            continue;
        }
        let started = Instant::now();
        solver.step();
        steps_without_events += 1;
        if let Some(share) = control.busy_share() {
            owed += started.elapsed().mul_f64(1.0 / share - 1.0);
            if owed >= MIN_PAUSE {
                let paused = Instant::now();
                thread::sleep(owed);
                owed = owed.saturating_sub(paused.elapsed());
            }
        }
    }
    solver
}

/// Shortest pause the busy-share limit takes (shorter ones are owed until they add up: a sleep
/// costs a few µs and the timer's slack).
const MIN_PAUSE: Duration = Duration::from_micros(100);

/// What the owner of a [`ThreadedTracker`] tells its solver thread.
#[derive(Debug, Default)]
struct Control {
    stop: AtomicBool,
    /// Largest share of wall time the thread may spend in steps while it has work (f64 bits;
    /// 0 = no limit). See [`ThreadedTracker::limit_busy_share`].
    busy_share: AtomicU64,
}

impl Control {
    fn busy_share(&self) -> Option<f64> {
        match self.busy_share.load(Ordering::Relaxed) {
            0 => None,
            bits => Some(f64::from_bits(bits)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::event::EventCd;

    /// The outline of a 0.12 m square in its own plane, 0.6 m in front of the IMX636, and events on
    /// every pixel of that outline (raw sensor pixels) at times `t0..`.
    fn square() -> (Camera, Vec<[f32; 3]>, Pose) {
        let pts = (0..400)
            .map(|i| {
                let s = (i % 100) as f32 / 100.0 * 0.12 - 0.06;
                match i / 100 {
                    0 => [s, -0.06, 0.0],
                    1 => [s, 0.06, 0.0],
                    2 => [-0.06, s, 0.0],
                    _ => [0.06, s, 0.0],
                }
            })
            .collect();
        let pose = Pose::from_parts(Translation3::new(0.0, 0.0, 0.6), UnitQuaternion::identity());
        (Camera::imx636(), pts, pose)
    }

    fn outline_events(
        cam: &Camera,
        pts: &[[f32; 3]],
        pose: &Pose,
        t0: i64,
        n: usize,
    ) -> Vec<EventCd> {
        (0..n)
            .map(|i| {
                let p = pts[i % pts.len()];
                let pc = pose * Point3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
                let (u, v) = cam.project(&pc.coords).expect("in view");
                EventCd::new(u.round() as u16, v.round() as u16, 1, t0 + i as i64 / 10)
            })
            .collect()
    }

    fn core(limit: IngestLimit) -> (TrackerCore, Vec<[f32; 3]>, Pose) {
        let (cam, pts, pose) = square();
        let config = TrackerConfig {
            ingest_limit: limit,
            ..TrackerConfig::default()
        };
        (
            TrackerCore::new(&cam, pts.clone(), pose, config).unwrap(),
            pts,
            pose,
        )
    }

    #[test]
    fn not_locked_before_the_first_update_then_locked() {
        let (mut core, pts, pose) = core(IngestLimit::Off);
        let first = core.output().latest();
        assert!(first.lost && first.seq == 0 && first.inlier_fraction == 0.0);
        let ev = outline_events(core.camera(), &pts, &pose, 0, 4000);
        let est = core.update(ev.as_slice()).unwrap();
        assert!(!est.lost, "{est:?}");
        assert!(est.inlier_fraction > 0.8, "{est:?}");
        assert_eq!(core.output().latest(), est);
        assert_eq!(est.t_us, ev.last().unwrap().t);
        core.reset_pose(pose).unwrap();
        assert!(core.latest().lost);
    }

    #[test]
    fn latency_runs_from_the_push_of_the_newest_batch_to_the_publication() {
        let (mut core, pts, pose) = core(IngestLimit::Off);
        let cam = *core.camera();
        assert_eq!(core.latest().latency_ns(), None, "no event yet");
        let before = crate::clock::now_ns();
        core.ingest(outline_events(&cam, &pts, &pose, 0, 2000).as_slice())
            .unwrap();
        thread::sleep(Duration::from_millis(3));
        let second = crate::clock::now_ns();
        core.ingest(outline_events(&cam, &pts, &pose, 1000, 2000).as_slice())
            .unwrap();
        thread::sleep(Duration::from_millis(5));
        let est = core.step();
        let after = crate::clock::now_ns();
        // The stamp is the second batch's (it holds the newest event), not the first's.
        assert_eq!(est.t_us, 1199);
        assert!(est.pushed_ns >= second && est.pushed_ns <= est.published_ns);
        assert!(est.pushed_ns > before + 3_000_000, "{est:?}");
        assert!(est.published_ns <= after);
        let latency = est.latency_ns().unwrap();
        assert!((5_000_000..after - second).contains(&latency), "{latency}");
        assert_eq!(core.output().latest(), est);
        // A later step on the same events keeps the push stamp: its latency only grows.
        let again = core.step();
        assert_eq!(again.pushed_ns, est.pushed_ns);
        assert!(again.published_ns >= est.published_ns);
        core.reset_events();
        assert_eq!(core.output().newest(), None);
    }

    #[test]
    fn the_oldest_stamp_is_the_first_batch_a_pose_takes_in() {
        let (mut core, pts, pose) = core(IngestLimit::Off);
        let cam = *core.camera();
        let before = crate::clock::now_ns();
        core.ingest(outline_events(&cam, &pts, &pose, 0, 2000).as_slice())
            .unwrap();
        let between = crate::clock::now_ns();
        thread::sleep(Duration::from_millis(3));
        core.ingest(outline_events(&cam, &pts, &pose, 1000, 2000).as_slice())
            .unwrap();
        let est = core.step();
        // The first batch's push, not the second's (which is the newest, `pushed_ns`).
        assert!(
            (before..=between).contains(&est.oldest_pushed_ns),
            "{est:?}"
        );
        assert!(est.pushed_ns > between);
        let bound = est.oldest_latency_ns().unwrap();
        assert!(bound >= 3_000_000 && bound > est.latency_ns().unwrap());
        // A step with nothing new takes in no batch.
        let again = core.step();
        assert_eq!(
            (again.oldest_pushed_ns, again.oldest_latency_ns()),
            (0, None)
        );
        // Booked by the tracker: both batches under the first pose's bound, one newest sample,
        // and each batch at its own latency: the first at the bound, the second 3 ms less.
        let out = core.output();
        let lat = out.latency();
        assert_eq!(
            (lat.newest.count(), lat.oldest.count(), lat.batch.count()),
            (1, 2, 2)
        );
        assert_eq!(lat.oldest.max_ns(), Some(bound));
        assert!(lat.oldest.quantile_ns(0.5).unwrap() >= bound.min(lat.newest.max_ns().unwrap()));
        assert_eq!(lat.batch.max_ns(), Some(bound));
        let second = lat.batch.quantile_ns(0.5).unwrap();
        assert!(second <= bound - 3_000_000 + 10_000, "{second} {bound}");
        assert!(second >= est.latency_ns().unwrap());
    }

    #[test]
    fn a_busy_share_rests_the_solver_between_steps() {
        let (core, pts, pose) = core(IngestLimit::Off);
        let cam = *core.camera();
        let started = Instant::now();
        let mut tr = ThreadedTracker::start(core).ok().expect("thread");
        assert!(tr.limit_busy_share(Some(1.5)).is_err());
        tr.limit_busy_share(Some(0.25)).unwrap();
        // New events every 200 µs: without the limit the solver would never rest. Pushed until a
        // dozen steps ran (a debug build's steps take milliseconds), within 20 s.
        let mut k = 0;
        while tr.stats().lm_steps + tr.stats().search_steps <= 12
            && started.elapsed().as_secs() < 20
        {
            tr.push(outline_events(&cam, &pts, &pose, k * 200, 400).as_slice())
                .unwrap();
            thread::sleep(Duration::from_micros(200));
            k += 1;
        }
        let core = tr.stop();
        let elapsed = started.elapsed().as_secs_f64();
        let s = core.stats();
        let in_steps = s.lm_seconds + s.search_seconds;
        assert!(s.lm_steps + s.search_steps > 10, "{s:?}");
        // Resting is owed 3 s for every 1 s of steps; all of it is paid but the last < 100 µs.
        assert!(
            elapsed >= in_steps / 0.25 - MIN_PAUSE.as_secs_f64(),
            "{elapsed} s elapsed for {in_steps} s in steps"
        );
    }

    #[test]
    fn newest_batch_pairs_are_never_torn() {
        let cell = Arc::new(NewestBatch::new());
        let reader = {
            let cell = Arc::clone(&cell);
            thread::spawn(move || {
                for _ in 0..200_000 {
                    if let Some((t, pushed)) = cell.get() {
                        assert_eq!(pushed, t as u64 * 3);
                    }
                }
            })
        };
        for t in 1..200_000i64 {
            cell.set(t, t as u64 * 3);
        }
        reader.join().unwrap();
    }

    #[test]
    fn after_a_gap_in_the_events_the_pose_follows_the_new_ones_not_the_old_edges() {
        // Locked on the square; then no events at all for 60 ms, while the square moves 12 mm
        // (about 29 px) sideways; then its events resume there. The front-end still holds the old
        // outline, which would keep the pose where the square was.
        let (mut core, pts, pose) = core(IngestLimit::Off);
        for k in 0..10 {
            let ev = outline_events(core.camera(), &pts, &pose, k * 1000, 400);
            core.update(ev.as_slice()).unwrap();
        }
        assert!(!core.latest().lost);
        let moved = Pose::from_parts(
            Translation3::new(0.012, 0.0, 0.6),
            UnitQuaternion::identity(),
        );
        let mut est = core.latest();
        for k in 70..75 {
            let ev = outline_events(core.camera(), &pts, &moved, k * 1000, 400);
            est = core.update(ev.as_slice()).unwrap();
        }
        // Sideways (what the image pins down) to 0.5 mm; a flat square's depth only to a few mm.
        let (dt, _) = crate::se3::distance(&est.pose, &moved);
        let dx = (est.pose.translation.x - 0.012).abs();
        assert!(
            dx < 5e-4 && dt < 0.003 && !est.lost,
            "{dx} m sideways, {dt} m off after 5 ms of events: {est:?}"
        );
    }

    /// One millisecond from `t0`: the square's outline firing (`outline`) and 50 background events
    /// at random pixels (50 kev/s over the sensor), time-sorted.
    fn millisecond(
        cam: &Camera,
        pts: &[[f32; 3]],
        pose: &Pose,
        t0: i64,
        outline: bool,
        rng: &mut crate::rng::Rng,
    ) -> Vec<EventCd> {
        let mut ev = if outline {
            outline_events(cam, pts, pose, t0, 400)
        } else {
            Vec::new()
        };
        ev.extend((0..50).map(|_| {
            let (x, y) = (
                rng.below(u64::from(cam.width)),
                rng.below(u64::from(cam.height)),
            );
            EventCd::new(x as u16, y as u16, 1, t0 + rng.below(1000) as i64)
        }));
        ev.sort_by_key(|e| e.t);
        ev
    }

    /// Locked on the square (at `at(k)` in millisecond `k`) while its outline fires every
    /// millisecond among the background for 60 ms.
    fn locked_while_firing(
        core: &mut TrackerCore,
        pts: &[[f32; 3]],
        at: impl Fn(i64) -> Pose,
        rng: &mut crate::rng::Rng,
    ) {
        let cam = *core.camera();
        for k in 0..60 {
            let ev = millisecond(&cam, pts, &at(k), k * 1000, true, rng);
            core.update(ev.as_slice()).unwrap();
        }
        assert!(!core.latest().lost, "locked while the outline fires");
    }

    /// [`locked_while_firing`]; then every event is lost for 60 ms (the producer's slices go on,
    /// empty), to 120 ms.
    fn locked_then_a_dropout(
        core: &mut TrackerCore,
        pts: &[[f32; 3]],
        at: impl Fn(i64) -> Pose,
        rng: &mut crate::rng::Rng,
    ) {
        locked_while_firing(core, pts, at, rng);
        for k in 60..120 {
            core.advance_time(k * 1000).unwrap();
            core.step();
        }
    }

    /// After [`locked_then_a_dropout`], only the background comes back until the pose held at
    /// `pose` is trusted again (within 20 ms); the millisecond after that update.
    fn background_until_trusted(
        core: &mut TrackerCore,
        pts: &[[f32; 3]],
        pose: &Pose,
        rng: &mut crate::rng::Rng,
    ) -> i64 {
        let cam = *core.camera();
        let mut k = 120;
        while core.latest().lost {
            let ev = millisecond(&cam, pts, pose, k * 1000, false, rng);
            core.update(ev.as_slice()).unwrap();
            k += 1;
            assert!(k < 140, "the held pose is trusted again within 20 ms");
        }
        k
    }

    #[test]
    fn an_object_that_falls_silent_while_the_background_fires_on_reads_as_lost() {
        // Locked on the square while its outline fires every millisecond (a followed object that
        // keeps making events); then it is hidden: only the background fires. The front-end keeps
        // the outline, so the pose stays supported (confidence ≈ 0.9, no motion to demand fresh
        // events) and only the silence of the model's own blocks tells.
        let (mut core, pts, pose) = core(IngestLimit::Off);
        let cam = *core.camera();
        let mut rng = crate::rng::Rng::new(5);
        locked_while_firing(&mut core, &pts, |_| pose, &mut rng);
        let (mut flagged_at, mut silent_support) = (None, 1.0f32);
        for k in 60..200 {
            let ev = millisecond(&cam, &pts, &pose, k * 1000, false, &mut rng);
            let est = core.update(ev.as_slice()).unwrap();
            if est.lost && flagged_at.is_none() {
                flagged_at = Some(k * 1000);
            }
            if !est.lost {
                silent_support = silent_support.min(core.evidence().support_any);
            }
            assert_eq!(
                est.lost,
                flagged_at.is_some(),
                "lost stays set at {k} ms: {est:?}"
            );
        }
        let delay = flagged_at.expect("never flagged") - 60_000;
        assert!(
            delay <= 50_000,
            "flagged {delay} µs after the object fell silent"
        );
        assert!(
            silent_support > 0.9,
            "the front-end still holds the outline while silent: {silent_support}"
        );
        // Once lost, the field shows only what fired within the activity window: the old outline
        // no longer holds the pose.
        assert!(core.evidence().support_any < 0.2, "{:?}", core.evidence());
        // The outline fires again: trusted again within a few milliseconds.
        let mut est = core.latest();
        for k in 200..205 {
            let ev = millisecond(&cam, &pts, &pose, k * 1000, true, &mut rng);
            est = core.update(ev.as_slice()).unwrap();
        }
        assert!(!est.lost, "{est:?}");
    }

    #[test]
    fn a_hidden_object_whose_blocks_blip_now_and_then_still_reads_as_lost() {
        // As above, but every 20 ms a few of the hidden model's blocks fire (the background's
        // events landing on them): for an activity window at a time its excess passes `QUIET`,
        // never `EXPECT_ACTIVE`. Restarting the low clock on each blip let the memory window
        // close before the clock ran out: never flagged (the blip at 76 ms reset the clock
        // started at 69 ms).
        let (mut core, pts, pose) = core(IngestLimit::Off);
        let cam = *core.camera();
        let mut rng = crate::rng::Rng::new(5);
        locked_while_firing(&mut core, &pts, |_| pose, &mut rng);
        let blip: Vec<[f32; 3]> = pts.iter().step_by(50).copied().collect();
        let (mut flagged_at, mut blip_excess) = (None, 0.0f32);
        for k in 60..200 {
            let mut ev = millisecond(&cam, &pts, &pose, k * 1000, false, &mut rng);
            if k % 20 == 16 {
                ev.extend(outline_events(&cam, &blip, &pose, k * 1000, blip.len()));
                ev.sort_by_key(|e| e.t);
            }
            let est = core.update(ev.as_slice()).unwrap();
            if est.lost && flagged_at.is_none() {
                flagged_at = Some(k * 1000);
            }
            if k >= 70 {
                let e = core.evidence();
                let excess = crate::freshness::Activity {
                    on_model: e.active,
                    around: e.active_around,
                }
                .excess();
                blip_excess = blip_excess.max(excess);
            }
            assert_eq!(
                est.lost,
                flagged_at.is_some(),
                "lost stays set at {k} ms: {est:?}"
            );
        }
        assert!(
            (QUIET..EXPECT_ACTIVE).contains(&blip_excess),
            "the blips pass QUIET, not EXPECT_ACTIVE: {blip_excess}"
        );
        let delay = flagged_at.expect("never flagged") - 60_000;
        assert!(
            delay <= 50_000,
            "flagged {delay} µs after the object fell silent"
        );
    }

    #[test]
    fn events_that_stop_while_the_stream_goes_on_read_as_lost_within_the_gap() {
        // Locked on the square; then the producer's slices go on every millisecond, empty (every
        // event lost on the link). The tracker sees stream time pass without events.
        let (mut core, pts, pose) = core(IngestLimit::Off);
        for k in 0..10 {
            let ev = outline_events(core.camera(), &pts, &pose, k * 1000, 400);
            core.update(ev.as_slice()).unwrap();
        }
        assert!(!core.latest().lost);
        let last_event = core.latest().t_us;
        let mut flagged_at = None;
        for t in (10_000..100_000).step_by(1000) {
            core.advance_time(t).unwrap();
            let est = core.step();
            if est.lost && flagged_at.is_none() {
                flagged_at = Some(t);
            }
            assert_eq!(est.lost, flagged_at.is_some(), "lost stays set at {t} µs");
        }
        let delay = flagged_at.expect("never flagged") - last_event;
        assert!(
            (EVENT_GAP_US..=EVENT_GAP_US + 1000).contains(&delay),
            "flagged {delay} µs after the last event"
        );
        assert!(
            core.advance_time(last_event - 1).is_err(),
            "a stream time before the newest event is refused"
        );
        // Events resume where the square is: trusted again at once.
        let ev = outline_events(core.camera(), &pts, &pose, 100_000, 400);
        assert!(!core.update(ev.as_slice()).unwrap().lost);
    }

    #[test]
    fn after_a_gap_a_sparse_fresh_field_moves_nothing_under_the_significance_test() {
        // As above, but the events resume sparsely: an eighth of the outline fires, far fewer
        // pixels than S* has points. EDFT⁺ (search_min_t 3) holds the pose until the field has
        // filled; the paper's plain argmin (search_min_t 0) already moves on it.
        let moved = Pose::from_parts(
            Translation3::new(0.012, 0.0, 0.6),
            UnitQuaternion::identity(),
        );
        for min_t in [None, Some(0.0)] {
            let (cam, pts, pose) = square();
            let config = TrackerConfig {
                ingest_limit: IngestLimit::Off,
                search_min_t: min_t,
                ..TrackerConfig::default()
            };
            let mut core = TrackerCore::new(&cam, pts.clone(), pose, config).unwrap();
            for k in 0..10 {
                let ev = outline_events(&cam, &pts, &pose, k * 1000, 400);
                core.update(ev.as_slice()).unwrap();
            }
            let locked = core.latest();
            assert!(!locked.lost);
            let sparse: Vec<[f32; 3]> = pts.iter().step_by(8).copied().collect();
            let mut est = locked;
            for k in 70..75 {
                let ev = outline_events(&cam, &sparse, &moved, k * 1000, 50);
                est = core.update(ev.as_slice()).unwrap();
            }
            if min_t.is_none() {
                assert_eq!(est.pose, locked.pose, "held while the field refills");
                // Once the whole outline fires, the pose follows it.
                for k in 75..80 {
                    let ev = outline_events(&cam, &pts, &moved, k * 1000, 400);
                    est = core.update(ev.as_slice()).unwrap();
                }
                let dx = (est.pose.translation.x - 0.012).abs();
                assert!(dx < 5e-4 && !est.lost, "{dx} m sideways: {est:?}");
            } else {
                assert_ne!(
                    est.pose, locked.pose,
                    "the plain argmin moves on the sparse field"
                );
            }
        }
    }

    #[test]
    fn after_a_dropout_a_still_object_is_trusted_again_once_nothing_moved_a_moving_one_is_not() {
        // Locked on the square while its outline fires every millisecond among the background;
        // then every event is lost for 60 ms (the producer's slices go on, empty); then only the
        // background comes back. Still, nothing has moved: its last pose is trusted again within
        // an activity window and stays so past the post-gap window, although the support says
        // nothing (the pre-gap edges are hidden, then drowned by background). Moving (0.2 m/s,
        // ≈ 390 px/s), it must have gone on: the pose stays lost.
        for moving in [false, true] {
            let (mut core, pts, pose) = core(IngestLimit::Off);
            let cam = *core.camera();
            let mut rng = crate::rng::Rng::new(7);
            let at = |k: i64| {
                let mut p = pose;
                if moving {
                    p.translation.vector.x += 0.2e-3 * k as f64;
                }
                p
            };
            locked_then_a_dropout(&mut core, &pts, at, &mut rng);
            assert!(core.latest().lost, "moving {moving}: blind");
            let mut trusted_at = None;
            for k in 120..300 {
                let ev = millisecond(&cam, &pts, &at(k), k * 1000, false, &mut rng);
                let est = core.update(ev.as_slice()).unwrap();
                if !est.lost && trusted_at.is_none() {
                    trusted_at = Some(k);
                }
                assert_eq!(est.lost, trusted_at.is_none(), "moving {moving} at {k} ms");
            }
            if moving {
                assert_eq!(trusted_at, None);
            } else {
                let after = trusted_at.expect("never trusted again") - 120;
                assert!(
                    (ACTIVE_WINDOW_US / 1000..=ACTIVE_WINDOW_US / 1000 + 2).contains(&after),
                    "trusted again {after} ms after the events resumed"
                );
            }
        }
    }

    /// The square of the test above, held still through a 60 ms dropout until its pose is trusted
    /// again (only the background came back), then 5 ms later setting off diagonally at
    /// `speed_m_s` for 40 mm along x and y (57 mm) and stopping there: its outline fires while it
    /// moves (400 events a millisecond, each where the outline is at its time), not once it
    /// stops. Per update from the set-off for `for_ms`: (event time µs, position error m, lost).
    fn set_off_after_a_held_dropout(speed_m_s: f64, for_ms: i64) -> Vec<(i64, f64, bool)> {
        let (mut core, pts, pose) = core(IngestLimit::Off);
        let cam = *core.camera();
        let mut rng = crate::rng::Rng::new(7);
        locked_then_a_dropout(&mut core, &pts, |_| pose, &mut rng);
        let k = background_until_trusted(&mut core, &pts, &pose, &mut rng);
        for k in k..k + 5 {
            let ev = millisecond(&cam, &pts, &pose, k * 1000, false, &mut rng);
            core.update(ev.as_slice()).unwrap();
        }
        let set_off_us = (k + 5) * 1000;
        let at = |t_us: i64| {
            let s = ((t_us - set_off_us) as f64 * 1e-6 * speed_m_s / 2f64.sqrt()).min(0.04);
            let mut p = pose;
            p.translation.vector += Vector3::new(s, s, 0.0);
            (p, s < 0.04)
        };
        (set_off_us / 1000..set_off_us / 1000 + for_ms)
            .map(|k| {
                let mut ev: Vec<EventCd> = (0..400)
                    .filter_map(|i| {
                        let t = k * 1000 + i as i64 * 5 / 2;
                        let (p, moving) = at(t);
                        let [x, y, z] = pts[i].map(f64::from);
                        let (u, v) = cam.project(&(p * Point3::new(x, y, z)).coords)?;
                        (moving && (0.0..1279.5).contains(&u) && (0.0..719.5).contains(&v))
                            .then(|| EventCd::new(u.round() as u16, v.round() as u16, 1, t))
                    })
                    .collect();
                ev.extend(millisecond(&cam, &pts, &pose, k * 1000, false, &mut rng));
                ev.sort_by_key(|e| e.t);
                let est = core.update(ev.as_slice()).unwrap();
                let (err, _) = crate::se3::distance(&est.pose, &at(est.t_us).0);
                (est.t_us, err, est.lost)
            })
            .collect()
    }

    #[test]
    fn a_held_pose_left_behind_by_a_fast_set_off_is_lost_within_50_ms_and_stays_lost() {
        // Issue 12: wrong beyond 30 mm at Z = 0.6 m; lost within 50 ms of turning wrong, never
        // wrong and trusted for more than 100 ms. The pose stays where it was held (the field
        // refills from fresh events only, see `AFTER_GAP_US`), on the edges the set-off left
        // there: before the deserted-model test it was flagged 13–41 ms after turning wrong, as
        // those edges aged, and at 4 mm/ms trusted on them again 96 ms later, to the end.
        for speed_m_s in [2.0, 4.0, 8.0] {
            let run = set_off_after_a_held_dropout(speed_m_s, 450);
            let wrong_at = run.iter().find(|r| r.1 > 0.03).expect("never wrong").0;
            let lost_at = run.iter().find(|r| r.2).map_or(i64::MAX, |r| r.0);
            assert!(
                lost_at - wrong_at <= 50_000,
                "{speed_m_s} m/s: wrong from {wrong_at} µs, lost at {lost_at} µs"
            );
            let (mut spell_from, mut longest) = (None, 0);
            for &(t_us, err, lost) in &run {
                if err > 0.03 && !lost {
                    longest = longest.max(t_us - *spell_from.get_or_insert(t_us));
                } else {
                    spell_from = None;
                }
            }
            assert!(
                longest <= 100_000,
                "{speed_m_s} m/s: wrong and trusted for {longest} µs"
            );
        }
        // At 0.5 m/s it follows, trusted and within 10 mm while it moves.
        for &(t_us, err, lost) in &set_off_after_a_held_dropout(0.5, 110) {
            assert!(
                err < 0.01 && !lost,
                "0.5 m/s at {t_us} µs: {err} m off, lost {lost}"
            );
        }
    }

    #[test]
    fn a_pose_held_still_after_a_dropout_is_not_moved_by_the_background() {
        // As above, still: after the dropout only the background comes back, so the steps on the
        // refilling field have nothing of the object to fit, only background pixels near its
        // outline. The pose trusted again must stay where it was until the object fires.
        let (mut core, pts, pose) = core(IngestLimit::Off);
        let cam = *core.camera();
        let mut rng = crate::rng::Rng::new(7);
        locked_then_a_dropout(&mut core, &pts, |_| pose, &mut rng);
        let before = core.latest().pose;
        for k in 120..300 {
            let ev = millisecond(&cam, &pts, &pose, k * 1000, false, &mut rng);
            let est = core.update(ev.as_slice()).unwrap();
            let (dt, dr) = crate::se3::distance(&before, &est.pose);
            assert!(
                est.pose == before,
                "moved {:.2} mm / {:.2} deg at {k} ms (lost {}, held still {})",
                dt * 1e3,
                dr.to_degrees(),
                est.lost,
                core.solver.held_still
            );
        }
        assert!(core.solver.held_still && !core.latest().lost);
    }

    #[test]
    fn a_held_pose_whose_blocks_fire_without_confirming_it_is_lost_when_the_refill_ends() {
        // Held still after a dropout as above (only background came back). Then something fires
        // on the model's blocks (excess 0.45): the object setting off right where the pose is
        // held and moving on (it confirms the pose, confidence 0.3), or for 20 ms something that
        // does not confirm it (0.05: the object, moved during the dropout, setting off from
        // nearby; a hand passing), after which the blocks fall quiet and the edges from before
        // the gap, back in the field once it refilled, vouch for the pose (0.8). Judged step by
        // step on that evidence: the unconfirmed pose is trusted until the refill ends at most
        // (with the refill's low confidence merely ignored, it was trusted to the end).
        for confirmed in [false, true] {
            let (mut core, pts, pose) = core(IngestLimit::Off);
            let mut rng = crate::rng::Rng::new(7);
            locked_then_a_dropout(&mut core, &pts, |_| pose, &mut rng);
            let k = background_until_trusted(&mut core, &pts, &pose, &mut rng);
            let solver = &mut core.solver;
            assert!(solver.held_still && k < 140, "held still at {k} ms");
            let refill_end_us = solver.out.resumed_at_us.load(Ordering::Acquire) + AFTER_GAP_US;
            let set_off_us = (k + 5) * 1000;
            let mut lost_at_us = None;
            for t_us in (set_off_us..400_000).step_by(1000) {
                let firing = confirmed || t_us < set_off_us + 20_000;
                (solver.evidence.active, solver.evidence.active_around) =
                    if firing { (0.5, 0.05) } else { (0.02, 0.02) };
                let confidence = match (confirmed, t_us < refill_end_us) {
                    (true, _) => 0.3,
                    (false, true) => 0.05,
                    (false, false) => 0.8,
                };
                solver.last.lost = solver.judge(t_us, confidence, true);
                if solver.last.lost && lost_at_us.is_none() {
                    lost_at_us = Some(t_us);
                }
            }
            if confirmed {
                assert_eq!(lost_at_us, None);
            } else {
                let lost_at_us = lost_at_us.expect("a wrong held pose trusted to the end");
                assert!(
                    lost_at_us <= refill_end_us + 1000,
                    "trusted {} ms after the set-off, the refill ended {} ms after it",
                    (lost_at_us - set_off_us) / 1000,
                    (refill_end_us - set_off_us) / 1000
                );
            }
        }
    }

    #[test]
    fn absurd_time_is_refused_and_the_time_line_can_restart() {
        let (mut core, pts, pose) = core(IngestLimit::Off);
        let cam = *core.camera();
        let mut ev = outline_events(&cam, &pts, &pose, 1_000, 100);
        ev[50].t = i64::MAX;
        assert!(core.ingest(ev.as_slice()).is_err());
        assert_eq!(
            core.stats().events_offered,
            0,
            "a rejected batch changes nothing"
        );
        core.ingest(outline_events(&cam, &pts, &pose, 5_000, 100).as_slice())
            .unwrap();
        // A clock that restarted is refused until the time line is reset; the pose survives.
        let early = outline_events(&cam, &pts, &pose, 0, 100);
        assert!(core.ingest(early.as_slice()).is_err());
        core.reset_events();
        core.ingest(early.as_slice()).unwrap();
        assert_eq!(core.stats().events_ingested, 200);
    }

    /// The undistortion lookup moved to a prefetching second pass; the ingested state must be what
    /// the event-by-event path (`lut.map` per kept event, straight into the writer) leaves.
    #[test]
    fn ingest_state_matches_the_event_by_event_path_thinned_and_whole() {
        for limit in [IngestLimit::Off, IngestLimit::EventsPerSecond(3.3e6)] {
            let (mut tracker, _, _) = core(limit);
            let (mut reference, _, _) = core(IngestLimit::Off);
            let cam = *tracker.camera();
            let mut rng = crate::rng::Rng::new(5);
            let mut t_us = 0;
            let mut kept_total = 0;
            for _ in 0..30 {
                // 10 Mev/s over the whole sensor, ragged batch lengths.
                let n = 2000 + rng.below(20_000) as usize;
                let batch: Vec<EventCd> = (0..n)
                    .map(|i| {
                        let (x, y) = (rng.below(1280) as u16, rng.below(720) as u16);
                        EventCd::new(x, y, (i % 2) as i16, t_us + i as i64 / 10)
                    })
                    .collect();
                t_us += n as i64 / 10 + 1;
                // Which events the thinning keeps: every (1/keep)-th from where the last batch left off.
                let ing = &tracker.ingest;
                let keep = ing
                    .thinning
                    .clone()
                    .offer(n, batch[0].t, batch[n - 1].t, ing.last_t_us);
                let mut kept = Vec::new();
                let mut pos = ing.thinning.next_pos;
                while pos < n as f64 {
                    kept.push(batch[pos as usize]);
                    pos += if keep >= 1.0 { 1.0 } else { 1.0 / keep };
                }
                tracker.ingest_thinned(batch.as_slice()).unwrap();
                let r = &mut reference.ingest;
                let pixels: Vec<u32> = kept
                    .iter()
                    .map(|e| {
                        r.recency.record(e.x, e.y, e.t, false);
                        r.lut.map(e.x, e.y)
                    })
                    .collect();
                r.writer.ingest(&pixels);
                kept_total += kept.len() as u64;
            }
            let stats = tracker.stats();
            assert_eq!(stats.events_ingested, kept_total, "{limit:?}");
            if matches!(limit, IngestLimit::Off) {
                assert_eq!(stats.events_dropped, 0);
            } else {
                let kept = kept_total as f64 / stats.events_offered as f64;
                assert!((0.25..0.4).contains(&kept), "kept fraction {kept}");
            }
            let roi = Roi::full(cam.width, cam.height);
            let mut masks = [vec![0u8; roi.area()], vec![0u8; roi.area()]];
            tracker.fill_mask(roi, &mut masks[0]);
            reference.fill_mask(roi, &mut masks[1]);
            assert!(masks[0].iter().filter(|&&m| m != 0).count() > 10_000);
            assert!(
                masks[0] == masks[1],
                "{limit:?}: SCARF's active sets differ"
            );
            for v in 0..cam.height {
                for u in 0..cam.width {
                    let (u, v) = (u as f32, v as f32);
                    assert_eq!(
                        tracker.ingest.recency.last_us(u, v),
                        reference.ingest.recency.last_us(u, v),
                        "{limit:?}: recency at ({u}, {v})"
                    );
                }
            }
        }
    }

    #[test]
    fn threaded_ingest_counts_live_and_thins_to_the_cap() {
        // 1000 events per 1 ms of event time = 1 Mev/s offered against a cap of 0.25 Mev/s.
        let (core, pts, pose) = core(IngestLimit::EventsPerSecond(250_000.0));
        let cam = *core.camera();
        let mut tr = ThreadedTracker::start(core).ok().expect("thread");
        for k in 0..40 {
            tr.push(
                outline_events(&cam, &pts, &pose, k * 1000, 10_000)[..10_000]
                    .iter()
                    .step_by(10)
                    .copied()
                    .collect::<Vec<_>>()
                    .as_slice(),
            )
            .unwrap();
        }
        let deadline = Instant::now() + Duration::from_secs(20);
        while tr.stats().lm_steps == 0 && Instant::now() < deadline {
            thread::sleep(Duration::from_millis(1));
        }
        let live = tr.stats();
        assert!(live.lm_steps > 0, "step counters are live while running");
        assert_eq!(live.events_offered, 40_000);
        assert_eq!(
            live.events_offered,
            live.events_ingested + live.events_dropped
        );
        // The first window is taken whole (no rate known yet); after it, a quarter is kept.
        let kept = live.events_ingested as f64;
        assert!((9_500.0..=12_000.0).contains(&kept), "{live:?}");
        // The solver reaches the newest pushed event by itself.
        while tr.latest().t_us != 39_999 && Instant::now() < deadline {
            thread::sleep(Duration::from_millis(1));
        }
        assert_eq!(tr.latest().t_us, 39_999);
        let core = tr.stop();
        assert_eq!(core.stats().events_ingested, live.events_ingested);
    }

    #[test]
    fn a_core_share_never_thins_below_the_rate_the_tracker_needs() {
        let mut thin = Thinning::new(IngestLimit::CoreShare(0.5));
        // Costs a loaded core measured: 6 ns to validate, 40 ns to insert an event.
        thin.record_costs(50_000, 50_000, 300_000, 2_000_000);
        let offer = |thin: &mut Thinning, per_batch: usize| {
            (0..10)
                .map(|k| {
                    thin.offer(
                        per_batch,
                        k * 500,
                        k * 500 + 499,
                        (k > 0).then(|| k * 500 - 1),
                    )
                })
                .last()
                .unwrap()
        };
        // 100 Mev/s: validation alone takes more than half the core; 2 of every 100 are kept.
        assert!((offer(&mut thin, 50_000) - 0.02).abs() < 1e-4);
        // 1 Mev/s fits the share whole.
        let mut thin = Thinning::new(IngestLimit::CoreShare(0.5));
        thin.record_costs(500, 500, 3_000, 20_000);
        assert_eq!(offer(&mut thin, 500), 1.0);
        // 20 Mev/s at those costs: the share decides, (500/20 − 6)/40 of the events.
        let mut thin = Thinning::new(IngestLimit::CoreShare(0.5));
        thin.record_costs(500, 500, 3_000, 20_000);
        assert!((offer(&mut thin, 10_000) - 19.0 / 40.0).abs() < 1e-3);
    }

    #[test]
    fn the_core_share_follows_a_dearer_insert_within_a_few_batches() {
        // Whole, an event costs 20 ns to insert; thinned, its pixels scatter and each costs 60 ns
        // (the rendered drill episode). The share is sized on what ingest costs now, not on the
        // cheapest batch seen: after 16 batches at 60 ns the estimate is within 1 % of it (a lower
        // envelope rising 5 % a batch was at 44 ns).
        let mut thin = Thinning::new(IngestLimit::CoreShare(0.5));
        thin.record_costs(10_000, 10_000, 20_000, 200_000);
        for _ in 0..16 {
            thin.record_costs(10_000, 2_500, 20_000, 150_000);
        }
        assert!((thin.insert_ns - 60.0).abs() < 0.6, "{}", thin.insert_ns);
        // At 30 Mev/s the share buys (500/30 − 2)/60 of the events, not (500/30 − 2)/20.
        let keep = (0..3)
            .map(|k| {
                thin.offer(
                    30_000,
                    k * 1000,
                    k * 1000 + 999,
                    (k > 0).then(|| k * 1000 - 1),
                )
            })
            .last()
            .unwrap();
        assert!((keep - (500.0 / 30.0 - 2.0) / 60.0).abs() < 0.01, "{keep}");
    }

    #[test]
    fn a_failed_spawn_hands_the_core_back() {
        let (core, pts, pose) = core(IngestLimit::Off);
        let cam = *core.camera();
        let failed =
            ThreadedTracker::start_with(core, thread::Builder::new().stack_size(usize::MAX / 2))
                .err()
                .expect("no thread can get that stack");
        assert!(failed.error.to_string().contains("could not start"));
        let mut core = *failed.core;
        core.update(outline_events(&cam, &pts, &pose, 0, 1000).as_slice())
            .unwrap();
        let tr = ThreadedTracker::start(core)
            .ok()
            .expect("a normal start works");
        assert!(tr.is_running());
        tr.stop();
    }

    /// A lost pose that the local steps find partly supported again is not trusted on their
    /// confidence: a corner of background edges (two of the held outline's four sides, run on
    /// past the corner, in sparse clutter) lines up with it after the object has left the view.
    /// Trusted on the local confidence (0.68, over `relock_above`) at the corner's first
    /// millisecond before `LOCAL_FINDINGS`; the global search's test refuses it (the held pose
    /// refined on a pass's field: support 0.77, chance 0.18, explained 0.60, score 0.32).
    /// Deterministic: synchronous steps, seeded clutter and noise.
    #[test]
    fn a_lost_pose_that_a_corner_of_background_edges_half_supports_is_not_trusted() {
        use crate::event::EventBatch;
        use crate::mesh::{test_cube, Shading};
        use crate::pointset::{extract_point_set, PointSetParams};
        use crate::se3::distance;
        let cam = Camera::imx636().rectified();
        let mesh = test_cube(0.15, Shading::Constant(0.8));
        let bank = TemplateBank::render(
            &mesh,
            &cam,
            crate::templates::BankParams::default(),
            &PointSetParams::default(),
        )
        .unwrap();
        // Face-on at 1 m: the outline is a square.
        let held = Pose::from_parts(Translation3::new(0.0, 0.0, 1.0), UnitQuaternion::identity());
        let dense = PointSetParams {
            max_points: 4000,
            ..PointSetParams::default()
        };
        let pin = Pinhole::at_level(&cam, 0);
        let rig = Rigid32::from_pose(&held);
        let outline: Vec<(u16, u16)> = extract_point_set(&mesh, &cam, &held, &dense)
            .unwrap()
            .points_o
            .iter()
            .map(|&x| {
                let (u, v) = pin.project(rig.apply(x)).unwrap();
                (u.round() as u16, v.round() as u16)
            })
            .collect();
        let (u0, u1) = (
            outline.iter().map(|p| p.0).min().unwrap(),
            outline.iter().map(|p| p.0).max().unwrap(),
        );
        let (v0, v1) = (
            outline.iter().map(|p| p.1).min().unwrap(),
            outline.iter().map(|p| p.1).max().unwrap(),
        );
        // The top and left sides of the square, each run on past the corner by a quarter side.
        let (du, dv) = ((u1 - u0) / 4, (v1 - v0) / 4);
        let corner: Vec<(u16, u16)> = (u0 - du..=u1)
            .map(|u| (u, v0))
            .chain((v0 - dv..=v1).map(|v| (u0, v)))
            .collect();
        let mut rng = crate::rng::Rng::new(17);
        // Clutter: a fixed 0.5 % of the pixels within a side of the square, firing every ms.
        let clutter: Vec<(u16, u16)> = (0..4 * (u1 - u0) as u64 * (v1 - v0) as u64 / 200)
            .map(|_| {
                let u = u0 - (u1 - u0) / 2 + rng.below(2 * (u1 - u0) as u64) as u16;
                let v = v0 - (v1 - v0) / 2 + rng.below(2 * (v1 - v0) as u64) as u16;
                (u, v)
            })
            .collect();
        let mut core = TrackerCore::new(
            &cam,
            bank.views[bank.nearest_view(&held).0].points_o.clone(),
            held,
            TrackerConfig::default(),
        )
        .unwrap();
        core.set_templates(bank);
        // Each millisecond: what fires, and 200 noise events over the whole image.
        let mut millisecond = |t_ms: i64, fire: &[&[(u16, u16)]]| {
            let mut batch = EventBatch::default();
            for &(u, v) in fire.iter().copied().flatten() {
                batch.push(u, v, 1, t_ms * 1000);
            }
            for _ in 0..200 {
                let (u, v) = (rng.below(1280) as u16, rng.below(720) as u16);
                batch.push(u, v, 0, t_ms * 1000);
            }
            core.ingest(&batch).unwrap();
            core.step()
        };
        let locked = (1..=20)
            .map(|t| millisecond(t, &[&outline, &clutter]))
            .last()
            .unwrap();
        assert!(!locked.lost, "the cube in view: {locked:?}");
        // The cube leaves the view: the clutter goes on.
        let left = (21..=80)
            .map(|t| millisecond(t, &[&clutter]))
            .last()
            .unwrap();
        assert!(left.lost, "the cube out of view for 60 ms: {left:?}");
        // The corner appears where the held outline is. The cube is out of view: no pose of it is
        // right, and none may be trusted.
        for t in 81..=200 {
            let e = millisecond(t, &[&corner, &clutter]);
            assert!(e.lost, "{t} ms: trusted with the cube out of view: {e:?}");
        }
        // Refused on its score, not only for the cube's look-alike turns (which the margin weighs):
        // the held pose refined on a global pass's field falls short of the bar.
        let held_fit = core
            .global_candidates(&[held])
            .into_iter()
            .min_by(|a, b| {
                distance(&a.pose, &held)
                    .0
                    .total_cmp(&distance(&b.pose, &held).0)
            })
            .unwrap();
        let score = acquisition_score(&held_fit.evidence);
        assert!(
            score < TrackerConfig::default().reacquire_above,
            "the held pose refined on the corner scores {score}: {:?}",
            held_fit.evidence
        );
    }

    #[test]
    fn a_global_pass_leaves_the_local_steps_as_much_time_as_it_took() {
        assert!(global_pass_due(5_000, None, None, 1));
        // A pass at 0 that took 60 ms (the first step after it at 60 ms): the other steps run
        // until 120 ms (180 ms with twice the rest), however long ago the pass started.
        assert!(!global_pass_due(60_000, Some(0), None, 1));
        assert!(!global_pass_due(119_000, Some(0), Some(60_000), 1));
        assert!(global_pass_due(120_000, Some(0), Some(60_000), 1));
        assert!(!global_pass_due(179_000, Some(0), Some(60_000), 2));
        assert!(global_pass_due(180_000, Some(0), Some(60_000), 2));
        // A quick pass: at most every GLOBAL_PASS_EVERY_US.
        assert!(!global_pass_due(9_000, Some(0), Some(1_000), 1));
        assert!(global_pass_due(
            GLOBAL_PASS_EVERY_US,
            Some(0),
            Some(1_000),
            1
        ));
        // The time line restarted.
        assert!(global_pass_due(1_000, Some(50_000), Some(60_000), 1));
    }

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
            confidence: 0.25,
            lost: false,
            pushed_ns: seq * 7,
            published_ns: seq * 11,
            oldest_pushed_ns: seq * 5,
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
                    assert_eq!((e.pushed_ns, e.published_ns), (e.seq * 7, e.seq * 11));
                    assert_eq!(e.oldest_pushed_ns, e.seq * 5);
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
