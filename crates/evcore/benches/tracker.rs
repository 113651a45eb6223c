//! Per-update costs of the tracker at the paper's working point: the printed box at Z = 0.6 m on
//! the 1280×720 IMX636, ~1000 model points, the SCARF active set holding the box's edges plus
//! 20 % noise. An *update* is one published pose: the field rebuilt from the active set, then one
//! LM or one search step. Also the solver steps alone on a fixed field, and EDFT⁺'s update in
//! clutter (`tracker/update_edft+_clutter`): the same box, but the active set refilled before each
//! update by a 1 ms batch of the rendered drill episode's rate, most of it a textured background
//! sliding past (the camera moves) — the ROI full of events, as in the closed loop.

mod clock;
mod common;

use clock::BenchClock;
use common::{pose, textured_box};
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use evcore::clock::thread_cpu_ns;
use evcore::confidence::{evidence, Query};
use evcore::field::{DistanceField, FieldParams};
use evcore::pointset::{extract_point_set, PointSetParams};
use evcore::rng::Rng;
use evcore::solve::cost::{centroid, Pinhole, Rigid32};
use evcore::solve::lm::{lm_pyramid, LmParams};
use evcore::solve::search::{axis_steps, search_step, Gate};
use evcore::solve::SolverMode;
use evcore::tracker::{TrackerConfig, TrackerCore};
use evcore::{Camera, EventBatch, Roi};
use nalgebra::{Translation3, Vector6};
use std::hint::black_box;
use std::time::Duration;

/// Events per 1 ms batch of the cluttered stream (20 Mev/s, the rendered drill episode's rate
/// between its peaks) and its shares: the box's edges, the background's edges, uniform noise.
const CLUTTER_EVENTS_PER_MS: usize = 20_000;
const CLUTTER_BOX_SHARE: f64 = 0.2;
const CLUTTER_NOISE_SHARE: f64 = 0.1;
/// Distinct batches cycled through (32 ms of stream).
const CLUTTER_BATCHES: usize = 32;
/// How far the background slides per batch (px per ms: 1000 px/s).
const CLUTTER_SHIFT_PX_PER_MS: usize = 1;

/// The box's edge pixels at `pose` (raw sensor pixels).
fn box_edge_pixels(cam: &Camera, mesh: &evcore::mesh::Mesh) -> Vec<(u16, u16)> {
    let dense = PointSetParams {
        max_points: 100_000,
        ..PointSetParams::default()
    };
    let points = extract_point_set(mesh, cam, &pose(), &dense)
        .expect("points")
        .points_o;
    let rig = Rigid32::from_pose(&pose());
    points
        .iter()
        .filter_map(|&x| {
            let p = rig.apply(x);
            let (u, v) = cam.project(&nalgebra::Vector3::new(
                f64::from(p[0]),
                f64::from(p[1]),
                f64::from(p[2]),
            ))?;
            let (u, v) = (u.round(), v.round());
            (u >= 0.0 && v >= 0.0 && u < f64::from(cam.width) && v < f64::from(cam.height))
                .then_some((u as u16, v as u16))
        })
        .collect()
}

/// Events on every edge pixel of the box at `pose`, in random order, plus 20 % uniform noise.
fn edge_events(cam: &Camera, box_px: &[(u16, u16)], seed: u64) -> EventBatch {
    let mut px = box_px.to_vec();
    let mut rng = Rng::new(seed);
    let n_noise = px.len() / 5;
    for _ in 0..n_noise {
        px.push((
            rng.below(u64::from(cam.width)) as u16,
            rng.below(u64::from(cam.height)) as u16,
        ));
    }
    for i in (1..px.len()).rev() {
        px.swap(i, rng.below(i as u64 + 1) as usize);
    }
    let mut batch = EventBatch::with_capacity(px.len());
    for (i, (x, y)) in px.into_iter().enumerate() {
        batch.push(x, y, 1, i as i64);
    }
    batch
}

/// Pixels (raw sensor) where a background of random grey cells, 6–29 px on a side, slid
/// `shift_px` to the left, has an edge: a cell boundary between two different greys.
fn background_edges(cam: &Camera, shift_px: usize, seed: u64) -> Vec<(u16, u16)> {
    let mut rng = Rng::new(seed);
    let (w, h) = (cam.width as usize, cam.height as usize);
    let span = w + CLUTTER_SHIFT_PX_PER_MS * CLUTTER_BATCHES;
    let mut cells = |n: usize| {
        let mut id = Vec::with_capacity(n);
        let mut k = 0u32;
        while id.len() < n {
            let len = 6 + rng.below(24) as usize;
            id.extend(std::iter::repeat_n(k, len));
            k += 1;
        }
        id.truncate(n);
        id
    };
    let (col, row) = (cells(span), cells(h));
    let grey = |x: usize, y: usize| {
        let mut r = Rng::new(seed ^ (u64::from(col[x]) << 32) ^ u64::from(row[y]));
        r.below(4)
    };
    let mut px = Vec::new();
    for y in 1..h {
        for x in 1..w {
            let tx = x + shift_px;
            let g = grey(tx, y);
            if g != grey(tx - 1, y) || g != grey(tx, y - 1) {
                px.push((x as u16, y as u16));
            }
        }
    }
    px
}

/// The cluttered stream: [`CLUTTER_BATCHES`] batches of 1 ms, each the box's edge pixels, the
/// background's edges at that batch's slide and uniform noise, drawn at random in their shares.
fn clutter_stream(cam: &Camera, box_px: &[(u16, u16)], seed: u64) -> Vec<EventBatch> {
    let mut rng = Rng::new(seed);
    (0..CLUTTER_BATCHES)
        .map(|b| {
            let back = background_edges(cam, b * CLUTTER_SHIFT_PX_PER_MS, seed);
            let mut batch = EventBatch::with_capacity(CLUTTER_EVENTS_PER_MS);
            for i in 0..CLUTTER_EVENTS_PER_MS {
                let r = rng.uniform();
                let (x, y) = if r < CLUTTER_BOX_SHARE {
                    box_px[rng.below(box_px.len() as u64) as usize]
                } else if r < CLUTTER_BOX_SHARE + CLUTTER_NOISE_SHARE {
                    (
                        rng.below(u64::from(cam.width)) as u16,
                        rng.below(u64::from(cam.height)) as u16,
                    )
                } else {
                    back[rng.below(back.len() as u64) as usize]
                };
                let t_us = (b * 1000 + i * 1000 / CLUTTER_EVENTS_PER_MS) as i64;
                batch.push(x, y, (i % 2) as i16, t_us);
            }
            batch
        })
        .collect()
}

fn bench(c: &mut Criterion<BenchClock>) {
    let cam = Camera::imx636();
    let mesh = textured_box([0.16, 0.21, 0.06], 1);
    let points = extract_point_set(&mesh, &cam.rectified(), &pose(), &PointSetParams::default())
        .expect("S*")
        .points_o;
    let box_px = box_edge_pixels(&cam, &mesh);
    let events = edge_events(&cam, &box_px, 7);
    eprintln!(
        "{} model points, {} events in the active set input",
        points.len(),
        events.len()
    );
    // Start a few pixels off so the steps do real work.
    let start = Translation3::new(0.002, -0.001, 0.0) * pose();

    let mut group = c.benchmark_group("tracker");
    group.throughput(Throughput::Elements(1));
    for mode in [SolverMode::EdftPlus, SolverMode::Edopts, SolverMode::Edft] {
        let config = TrackerConfig {
            solver: mode,
            ..TrackerConfig::default()
        };
        let mut core = TrackerCore::new(&cam, points.clone(), start, config).expect("core");
        core.ingest(&events).expect("ingest");
        group.bench_function(format!("update_{}", mode.name()), |b| {
            b.iter(|| {
                // Re-centre now and then so the estimate does not settle into a no-op.
                if core.latest().seq.is_multiple_of(50) {
                    core.reset_pose(start).expect("pose");
                }
                black_box(core.step())
            })
        });
    }
    // In clutter: a fresh batch before each update (not timed), the update on the thread's CPU
    // clock.
    let mut batches = clutter_stream(&cam, &box_px, 5);
    let mut clutter =
        TrackerCore::new(&cam, points.clone(), start, TrackerConfig::default()).expect("core");
    for b in &batches {
        clutter.ingest(b).expect("ingest");
    }
    let mut next = CLUTTER_BATCHES;
    group.bench_function("update_edft+_clutter", |b| {
        b.iter_custom(|iters| {
            let mut cpu_ns = 0;
            for _ in 0..iters {
                if next == CLUTTER_BATCHES {
                    for batch in batches.iter_mut() {
                        batch
                            .t_us
                            .iter_mut()
                            .for_each(|t| *t += (CLUTTER_BATCHES * 1000) as i64);
                    }
                    next = 0;
                }
                clutter.ingest(&batches[next]).expect("ingest");
                next += 1;
                if clutter.latest().seq.is_multiple_of(50) {
                    clutter.reset_pose(start).expect("pose");
                }
                let t0 = thread_cpu_ns();
                black_box(clutter.step());
                cpu_ns += thread_cpu_ns() - t0;
            }
            Duration::from_nanos(cpu_ns)
        })
    });
    group.finish();

    // The pieces on a fixed field.
    let rect = cam.rectified();
    let pins: Vec<Pinhole> = (0..3).map(|l| Pinhole::at_level(&rect, l)).collect();
    let rig = Rigid32::from_pose(&pose());
    let uv = points
        .iter()
        .filter_map(|&x| pins[0].project(rig.apply(x)))
        .map(|(u, v)| (f64::from(u), f64::from(v)));
    let roi = Roi::around(uv, 48.0, rect.width, rect.height).expect("in view");
    let lut = evcore::UndistortLut::new(&cam);
    let mut mask_full = vec![0u8; rect.n_pixels()];
    for i in 0..events.len() {
        let idx = lut.map(events.x[i], events.y[i]);
        if idx != evcore::UndistortLut::OUTSIDE {
            mask_full[idx as usize] = 1;
        }
    }
    let mut mask = Vec::with_capacity(roi.area());
    for y in roi.y0..roi.y0 + roi.height {
        let row = (y * rect.width + roi.x0) as usize;
        mask.extend_from_slice(&mask_full[row..row + roi.width as usize]);
    }
    let active = |m: &[u8]| m.iter().filter(|&&a| a != 0).count() as f64 / m.len() as f64;
    let mut clutter_mask = vec![0u8; roi.area()];
    clutter.fill_mask(roi, &mut clutter_mask);
    eprintln!(
        "ROI {}x{}: {:.1} % active, {:.1} % in clutter",
        roi.width,
        roi.height,
        100.0 * active(&mask),
        100.0 * active(&clutter_mask)
    );
    let mut fill_core =
        TrackerCore::new(&cam, points.clone(), pose(), TrackerConfig::default()).expect("core");
    fill_core.ingest(&events).expect("ingest");
    let mut scratch = vec![0u8; roi.area()];
    c.bench_function("scarf_fill_mask_roi", |b| {
        b.iter(|| fill_core.fill_mask(black_box(roi), &mut scratch))
    });
    let mut field = DistanceField::new(FieldParams::default()).expect("field");
    c.bench_function("field_build_level0", |b| {
        b.iter(|| field.build(black_box(&mask), roi, 1).expect("build"))
    });
    c.bench_function("field_build_3_levels", |b| {
        b.iter(|| field.build(black_box(&mask), roi, 3).expect("build"))
    });
    field.build(&mask, roi, 3).expect("build");
    let pivot = centroid(&points);
    let off = evcore::solve::cost::apply_increment(
        &pose(),
        &Vector6::new(0.002, -0.001, 0.0, 0.0, 0.0, 0.0),
        &pivot,
    );
    let deltas = axis_steps(&pins[0], &off, &points, &pivot, 8);
    // EDFT⁺'s default at the border (min_t 3): the same step with the significance test of its
    // best candidate.
    for (name, gate) in [
        ("search_step", None),
        (
            "search_step_min_t3",
            Some(Gate::new(3.0, &LmParams::default())),
        ),
    ] {
        c.bench_function(name, |b| {
            b.iter(|| {
                search_step(
                    field.level(0),
                    &pins[0],
                    black_box(&off),
                    &points,
                    &pivot,
                    &deltas,
                    gate,
                )
            })
        });
    }
    // The evidence a tracked update scores its pose by (support and chance level over the roi).
    let query = Query {
        inlier_px: TrackerConfig::default().inlier_px,
        region: roi,
        image: (rect.width, rect.height),
        fresh_since: None,
        explain: false,
    };
    c.bench_function("evidence_roi", |b| {
        b.iter(|| {
            evidence(
                field.level(0),
                &pins[0],
                &Rigid32::from_pose(black_box(&off)),
                &points,
                &query,
            )
        })
    });
    let levels: Vec<_> = (0..3u32)
        .rev()
        .map(|l| (field.level(l), pins[l as usize]))
        .collect();
    c.bench_function("lm_step_3_levels", |b| {
        b.iter(|| {
            lm_pyramid(
                &levels,
                black_box(off),
                &points,
                &pivot,
                &LmParams::default(),
            )
        })
    });
    let mut ingest_core =
        TrackerCore::new(&cam, points.clone(), pose(), TrackerConfig::default()).expect("core");
    let mut g = c.benchmark_group("ingest");
    g.throughput(Throughput::Elements(events.len() as u64));
    let mut t = 0i64;
    let mut batch = events.clone();
    g.bench_function("tracker_ingest_scarf", |b| {
        b.iter(|| {
            // Keep time moving forward so every batch validates.
            for v in batch.t_us.iter_mut() {
                t += 1;
                *v = t;
            }
            ingest_core.ingest(black_box(&batch)).expect("ingest")
        })
    });
    g.finish();
}

criterion_group! {
    name = benches;
    config = clock::config();
    targets = bench
}
criterion_main!(benches);
