//! The global search a lost tracker runs (issue 12): one pass over the whole 1280×720 image —
//! full-image field (3 levels), the template bank's sweep over views, rolls, depths and the densest
//! positions, LM refinement of the best candidates and their confidence test. Target ≤ 100 ms on
//! one core. The printed box at Z = 0.6 m, its edges plus 20 % noise within the last 10 ms, a 15°
//! bank. Timed in the thread's CPU time (Linux schedstat), not wall time: on a shared machine
//! wall time counts whatever else ran on the core; the pass itself is single-threaded.

mod common;

use common::{pose, textured_box};
use criterion::{criterion_group, criterion_main, Criterion};
use evcore::pointset::{extract_point_set, PointSetParams};
use evcore::rng::Rng;
use evcore::solve::cost::Rigid32;
use evcore::templates::{BankParams, TemplateBank};
use evcore::tracker::{TrackerConfig, TrackerCore};
use evcore::{Camera, EventBatch};
use std::hint::black_box;
use std::time::{Duration, Instant};

/// CPU time this thread has run (ns), from /proc/thread-self/schedstat.
fn thread_cpu_ns() -> u64 {
    let stat = std::fs::read_to_string("/proc/thread-self/schedstat").expect("Linux schedstat");
    stat.split_whitespace()
        .next()
        .and_then(|f| f.parse().ok())
        .expect("schedstat's first field")
}

fn bench(c: &mut Criterion) {
    let cam = Camera::imx636();
    let mesh = textured_box([0.16, 0.21, 0.06], 1);
    let started = Instant::now();
    let bank = TemplateBank::render(
        &mesh,
        &cam,
        BankParams::default(),
        &PointSetParams::default(),
    )
    .expect("bank");
    eprintln!(
        "bank: {} views rendered in {:.2} s",
        bank.views.len(),
        started.elapsed().as_secs_f64()
    );
    let dense = PointSetParams {
        max_points: 100_000,
        ..PointSetParams::default()
    };
    let edge = extract_point_set(&mesh, &cam.rectified(), &pose(), &dense)
        .expect("edges")
        .points_o;
    let rig = Rigid32::from_pose(&pose());
    let mut batch = EventBatch::with_capacity(edge.len() * 6 / 5);
    let mut rng = Rng::new(3);
    // All within the last 10 ms: the search only sees what fired recently.
    let t_of = |i: usize| (i * 10_000 / edge.len()) as i64;
    for (i, &x) in edge.iter().enumerate() {
        let p = rig.apply(x);
        let v = nalgebra::Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
        if let Some((u, v)) = cam.project(&v) {
            let (u, v) = (u.round(), v.round());
            if u >= 0.0 && v >= 0.0 && u < 1280.0 && v < 720.0 {
                batch.push(u as u16, v as u16, 1, t_of(i));
            }
        }
        if i % 5 == 0 {
            batch.push(rng.below(1280) as u16, rng.below(720) as u16, 0, t_of(i));
        }
    }
    let mut core = TrackerCore::searching(&cam, bank, TrackerConfig::default()).expect("core");
    core.ingest(&batch).expect("ingest");
    let found = core.step();
    eprintln!(
        "one pass: lost = {}, confidence {:.2}, {:.1} mm from the truth",
        found.lost,
        found.confidence,
        (found.pose.translation.vector - pose().translation.vector).norm() * 1e3
    );
    c.bench_function("reacquire_global_pass_1280x720_cpu", |b| {
        b.iter_custom(|iters| {
            let t0 = thread_cpu_ns();
            for _ in 0..iters {
                core.start_search();
                black_box(core.step());
            }
            Duration::from_nanos(thread_cpu_ns() - t0)
        })
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench
}
criterion_main!(benches);
