//! EVT 3.0 / EVT 2.0 decode throughput on the real recordings, in events per second.
//! The files are read once; each iteration decodes their in-memory data into a reused vector of
//! records (the `EventCD` layout the readers hand to Python).
//! Samples come from `EVSERVO_SAMPLES` (default: ../shared/event-samples next to the workspace).
//!
//! Time is this thread's CPU time (Linux `/proc/thread-self/schedstat`) when available, so the
//! figure means "per core" even on a machine shared with other jobs; elsewhere it is wall time.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use evcore::io::{Decoder, RawHeader};
use evcore::EventCd;
use std::hint::black_box;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// CPU time this thread has run, in ns (first field of schedstat).
fn thread_cpu_ns() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    text.split_whitespace().next()?.parse().ok()
}

/// Runs `f` `iters` times and returns the CPU time it took (wall time without schedstat).
fn timed(iters: u64, mut f: impl FnMut()) -> Duration {
    let (cpu0, wall0) = (thread_cpu_ns(), Instant::now());
    for _ in 0..iters {
        f();
    }
    match (cpu0, thread_cpu_ns()) {
        // schedstat advances at scheduler ticks, so a sample shorter than a tick can read 0;
        // such a sample (criterion's first, tiny ones) takes the wall time instead.
        (Some(a), Some(b)) if b > a => Duration::from_nanos(b - a),
        _ => wall0.elapsed(),
    }
}

fn samples_dir() -> PathBuf {
    match std::env::var_os("EVSERVO_SAMPLES") {
        Some(d) => PathBuf::from(d),
        None => PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/event-samples"),
    }
}

fn decode(c: &mut Criterion) {
    let mut group = c.benchmark_group("decode");
    for (label, name) in [
        ("evt3_gen41", "prophesee_gen41_evt3_1280x720.raw"),
        ("evt2_gen3_a", "prophesee_gen3_evt2_640x480_a.raw"),
    ] {
        let path = samples_dir().join(name);
        let Ok(bytes) = std::fs::read(&path) else {
            eprintln!(
                "SKIPPED {label}: {} unavailable; set EVSERVO_SAMPLES",
                path.display()
            );
            continue;
        };
        let header = RawHeader::read_from(&mut &bytes[..]).expect("sample header");
        let data = &bytes[header.len_bytes..];
        let fresh = || {
            Decoder::for_sensor(header.format, header.width, header.height)
                .expect("sample geometry")
        };
        let mut out: Vec<EventCd> = Vec::new();
        fresh().decode(data, &mut out).expect("sample decodes");
        group.throughput(Throughput::Elements(out.len() as u64));
        group.bench_function(label, |b| {
            b.iter_custom(|iters| {
                timed(iters, || {
                    out.clear();
                    fresh()
                        .decode(black_box(data), &mut out)
                        .expect("sample decodes");
                    black_box(out.len());
                })
            })
        });
    }
    group.finish();
}

criterion_group!(benches, decode);
criterion_main!(benches);
