use super::pixel::log_intensity;
use super::*;

const EPS: f32 = 1e-3;

fn clean(sigma_c: f64, seed: u64) -> SimParams {
    SimParams {
        sigma_c,
        seed,
        ..SimParams::preset("clean").unwrap()
    }
}

fn uniform(w: u32, h: u32, i: f32) -> Vec<f32> {
    vec![i; (w * h) as usize]
}

/// Events of pixel `idx` (row-major) as (t, p).
fn of_pixel(ev: &EventBatch, w: u32, idx: usize) -> Vec<(i64, i16)> {
    (0..ev.len())
        .filter(|&k| ev.y[k] as usize * w as usize + ev.x[k] as usize == idx)
        .map(|k| (ev.t_us[k], ev.p[k]))
        .collect()
}

fn assert_sorted(ev: &EventBatch, w: u32) {
    for k in 1..ev.len() {
        let a = (ev.t_us[k - 1], ev.y[k - 1] as u32 * w + ev.x[k - 1] as u32);
        let b = (ev.t_us[k], ev.y[k] as u32 * w + ev.x[k] as u32);
        assert!(
            a <= b,
            "events {} and {k} out of order: {a:?} then {b:?}",
            k - 1
        );
    }
}

/// A vertical soft edge at column `pos` (px), dark left, bright right, over a faint texture.
fn edge_frame(w: u32, h: u32, pos: f64) -> Vec<f32> {
    let mut f = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let ramp = (f64::from(x) + 0.5 - pos).clamp(-0.5, 0.5) + 0.5;
            let texture = 0.05 * (1.0 + (f64::from(y) * 0.7).sin());
            f.push((0.05 + 0.8 * ramp + texture) as f32);
        }
    }
    f
}

fn run_edge(params: SimParams, w: u32, h: u32, steps: usize) -> Vec<EventBatch> {
    let mut sim = EventSimulator::new(w, h, params).unwrap();
    sim.reset(&edge_frame(w, h, 5.0), 0).unwrap();
    (1..=steps)
        .map(|k| {
            let mut out = EventBatch::default();
            sim.step(
                &edge_frame(w, h, 5.0 + 1.7 * k as f64),
                1000 * k as i64,
                &mut out,
            )
            .unwrap();
            out
        })
        .collect()
}

/// ON and OFF uniform steps: every pixel fires exactly ⌊ΔL / C_pixel⌋ events of the right
/// polarity, the k-th at t₀ + k·C/ΔL·Δt.
#[test]
fn uniform_step_counts_and_interpolated_times() {
    let (w, h) = (40, 30);
    for (i0, i1, on) in [(0.05f32, 0.6f32, true), (0.7, 0.02, false)] {
        let mut sim = EventSimulator::new(w, h, clean(0.02, 3)).unwrap();
        let (t0, t1) = (10_000i64, 12_500i64);
        sim.reset(&uniform(w, h, i0), t0).unwrap();
        let mut out = EventBatch::default();
        sim.step(&uniform(w, h, i1), t1, &mut out).unwrap();
        let dl = f64::from(log_intensity(i1, EPS)) - f64::from(log_intensity(i0, EPS));
        let (c_on, c_off) = sim.thresholds();
        let mut total = 0usize;
        for idx in 0..(w * h) as usize {
            let c = f64::from(if on { c_on[idx] } else { c_off[idx] });
            let n = (dl.abs() / c).floor() as usize;
            let got = of_pixel(&out, w, idx);
            assert_eq!(got.len(), n, "pixel {idx}: C {c}, ΔL {dl}");
            for (k, &(t, p)) in got.iter().enumerate() {
                let expect = t0 as f64 + (k + 1) as f64 * c / dl.abs() * (t1 - t0) as f64;
                assert!(
                    (t as f64 - expect).abs() <= 0.5 + 1e-9,
                    "pixel {idx} event {k}: {t} vs {expect}"
                );
                assert_eq!(p, i16::from(on));
            }
            total += n;
        }
        // With thresholds spread over more than one event's worth, ⌊·⌋ loses half an event on average.
        let mean = total as f64 / f64::from(w * h);
        let nominal = dl.abs() / 0.2;
        assert!(
            (mean + 0.5 - nominal).abs() < 0.3,
            "mean {mean} events/pixel, ΔL/C = {nominal}"
        );
        assert_sorted(&out, w);
    }
}

#[test]
fn mismatch_is_fixed_pattern_with_requested_spread() {
    let sim = EventSimulator::new(
        200,
        100,
        SimParams {
            sigma_c: 0.03,
            ..SimParams::default()
        },
    )
    .unwrap();
    let (on, off) = sim.thresholds();
    let n = on.len() as f64;
    let mean = on.iter().map(|&c| f64::from(c)).sum::<f64>() / n;
    let sd = (on
        .iter()
        .map(|&c| (f64::from(c) - mean).powi(2))
        .sum::<f64>()
        / n)
        .sqrt();
    assert!(
        (mean - 0.2).abs() < 0.001 && (sd - 0.03).abs() < 0.001,
        "mean {mean} sd {sd}"
    );
    assert_ne!(on, off, "ON and OFF thresholds are independent draws");
    let tiny = EventSimulator::new(
        50,
        50,
        SimParams {
            c_pos: 0.02,
            sigma_c: 0.05,
            ..SimParams::default()
        },
    )
    .unwrap();
    assert!(tiny
        .thresholds()
        .0
        .iter()
        .all(|&c| f64::from(c) >= MIN_THRESHOLD - 1e-9));
}

/// Static dark scene, `noisy` preset: shot 5 Hz + leak 0.1 Hz within 10 %, ON/OFF balanced.
#[test]
fn noisy_static_scene_rate() {
    let (w, h) = (200u32, 200u32);
    let p = SimParams {
        seed: 11,
        ..SimParams::preset("noisy").unwrap()
    };
    let expected = p.shot_noise_rate_hz + p.leak_rate_hz;
    let mut sim = EventSimulator::new(w, h, p).unwrap();
    let dark = uniform(w, h, 0.0);
    sim.reset(&dark, 0).unwrap();
    let (mut n, mut n_on) = (0usize, 0usize);
    let mut out = EventBatch::default();
    for k in 1..=200 {
        sim.step(&dark, k * 10_000, &mut out).unwrap();
        assert!(out
            .t_us
            .iter()
            .all(|&t| t >= (k - 1) * 10_000 && t <= k * 10_000));
        assert_sorted(&out, w);
        n += out.len();
        n_on += out.p.iter().filter(|&&p| p == 1).count();
    }
    let rate = n as f64 / f64::from(w * h) / 2.0;
    assert!(
        (rate - expected).abs() < 0.1 * expected,
        "{rate} Hz vs {expected} Hz"
    );
    let on_frac = n_on as f64 / n as f64;
    assert!((on_frac - 0.5).abs() < 0.01, "ON fraction {on_frac}");
}

/// Shot noise alone is Poisson at the configured rate in the dark and ×b at white.
#[test]
fn shot_noise_rate_and_brightness_dependence() {
    let (w, h) = (200u32, 100u32);
    let p = SimParams {
        sigma_c: 0.0,
        refractory_us: 0,
        leak_rate_hz: 0.0,
        shot_noise_rate_hz: 5.0,
        shot_noise_bright_factor: 0.25,
        ..SimParams::default()
    };
    for (level, factor) in [(0.0f32, 1.0), (1.0, 0.25)] {
        let mut sim = EventSimulator::new(w, h, p.clone()).unwrap();
        let frame = uniform(w, h, level);
        sim.reset(&frame, 0).unwrap();
        let mut n = 0usize;
        let mut out = EventBatch::default();
        for k in 1..=40 {
            sim.step(&frame, k * 50_000, &mut out).unwrap();
            n += out.len();
        }
        let expected = 5.0 * factor * f64::from(w * h) * 2.0;
        // 5σ of a Poisson count.
        assert!(
            (n as f64 - expected).abs() < 5.0 * expected.sqrt(),
            "I={level}: {n} vs {expected}"
        );
    }
}

/// Leak alone, no mismatch: a static pixel fires ON every 1/rate seconds, exactly.
#[test]
fn leak_fires_periodically() {
    let (w, h) = (20u32, 10u32);
    let p = SimParams {
        sigma_c: 0.0,
        leak_rate_hz: 5.0,
        leak_rate_spread_decades: 0.0,
        shot_noise_rate_hz: 0.0,
        ..SimParams::default()
    };
    let mut sim = EventSimulator::new(w, h, p).unwrap();
    let frame = uniform(w, h, 0.3);
    sim.reset(&frame, 0).unwrap();
    let mut all = EventBatch::default();
    let mut out = EventBatch::default();
    for k in 1..=41 {
        sim.step(&frame, k * 50_000, &mut out).unwrap();
        all.extend_from(&out);
    }
    for idx in 0..(w * h) as usize {
        let ev = of_pixel(&all, w, idx);
        let times: Vec<i64> = ev.iter().map(|e| e.0).collect();
        let expect: Vec<i64> = (1..=10).map(|j| j * 200_000).collect();
        assert_eq!(ev.len(), 10, "pixel {idx}: {times:?}");
        assert!(
            times.iter().zip(&expect).all(|(a, b)| (a - b).abs() <= 1),
            "{times:?}"
        );
        assert!(ev.iter().all(|e| e.1 == 1));
    }
}

#[test]
fn leak_factors_average_to_the_configured_rate() {
    let sim = EventSimulator::new(
        200,
        200,
        SimParams {
            leak_rate_hz: 0.1,
            ..SimParams::default()
        },
    )
    .unwrap();
    let rates = sim.leak_rates_hz();
    let mean = rates.iter().sum::<f64>() / rates.len() as f64;
    let (lo, hi) = rates
        .iter()
        .fold((f64::MAX, 0.0f64), |(lo, hi), &r| (lo.min(r), hi.max(r)));
    assert!((mean - 0.1).abs() < 0.001, "mean {mean}");
    assert!(
        lo < 0.07 && hi > 0.14,
        "spread {lo}..{hi} too narrow for 0.1 decades"
    );
}

/// Five crossings at ΔL = 1.1, C = 0.2 over 2000 µs; a 1000 µs refractory period keeps the
/// 1st and 4th, and the dropped levels are consumed (ESIM): the next static frame is silent.
#[test]
fn refractory_drops_and_consumes_crossings() {
    let (w, h) = (4u32, 3u32);
    let p = SimParams {
        refractory_us: 1000,
        ..clean(0.0, 0)
    };
    let mut sim = EventSimulator::new(w, h, p).unwrap();
    let i0 = 0.1f32;
    let i1 = ((f64::from(i0) + 1e-3) * 1.1f64.exp() - 1e-3) as f32;
    let dl = f64::from(log_intensity(i1, EPS)) - f64::from(log_intensity(i0, EPS));
    sim.reset(&uniform(w, h, i0), 0).unwrap();
    let mut out = EventBatch::default();
    sim.step(&uniform(w, h, i1), 2000, &mut out).unwrap();
    let level_t = |k: f64| (k * 0.2f32 as f64 / dl * 2000.0).round() as i64;
    for idx in 0..(w * h) as usize {
        assert_eq!(
            of_pixel(&out, w, idx),
            vec![(level_t(1.0), 1), (level_t(4.0), 1)]
        );
    }
    sim.step(&uniform(w, h, i1), 4000, &mut out).unwrap();
    assert!(out.is_empty(), "{} events after a static frame", out.len());
}

#[test]
fn refractory_holds_for_moving_content() {
    let p = SimParams {
        refractory_us: 300,
        seed: 5,
        ..SimParams::preset("noisy").unwrap()
    };
    let (w, h) = (64, 48);
    let mut last = vec![i64::MIN; (w * h) as usize];
    let mut checked = 0;
    for out in run_edge(p, w, h, 30) {
        for k in 0..out.len() {
            let idx = out.y[k] as usize * w as usize + out.x[k] as usize;
            if last[idx] != i64::MIN {
                assert!(
                    out.t_us[k] - last[idx] >= 300,
                    "pixel {idx}: {} after {}",
                    out.t_us[k],
                    last[idx]
                );
                checked += 1;
            }
            last[idx] = out.t_us[k];
        }
    }
    assert!(checked > 1000, "only {checked} repeat events checked");
}

#[test]
fn seeded_determinism_across_thread_counts() {
    let p = SimParams {
        seed: 42,
        ..SimParams::preset("noisy").unwrap()
    };
    let (w, h) = (96, 64);
    let in_pool = |threads: usize, p: SimParams| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| run_edge(p, w, h, 12))
    };
    let one = in_pool(1, p.clone());
    let two = in_pool(2, p.clone());
    assert_eq!(one, two);
    assert!(one.iter().map(EventBatch::len).sum::<usize>() > 1000);
    for out in &one {
        assert_sorted(out, w);
    }
    let other = in_pool(2, SimParams { seed: 43, ..p });
    assert_ne!(one, other);
}

/// With a static outside and no noise, a ROI step gives exactly the full step's events inside
/// the region; with noise, nothing is emitted outside it.
#[test]
fn roi_step_matches_full_step_inside() {
    let (w, h) = (80u32, 60u32);
    let roi = Roi {
        x0: 10,
        y0: 20,
        width: 30,
        height: 25,
    };
    let crop = |f: &[f32]| -> Vec<f32> {
        (roi.y0..roi.y0 + roi.height)
            .flat_map(|y| (roi.x0..roi.x0 + roi.width).map(move |x| (y, x)))
            .map(|(y, x)| f[(y * w + x) as usize])
            .collect()
    };
    let p = clean(0.03, 9);
    let (mut full, mut part) = (
        EventSimulator::new(w, h, p.clone()).unwrap(),
        EventSimulator::new(w, h, p).unwrap(),
    );
    let f0 = edge_frame(w, h, 12.0);
    full.reset(&f0, 0).unwrap();
    part.reset(&f0, 0).unwrap();
    let (mut a, mut b) = (EventBatch::default(), EventBatch::default());
    let mut n = 0;
    for k in 1..=10 {
        // Content changes only inside the ROI: the edge moves across columns 12..33.
        let f = edge_frame(w, h, 12.0 + 2.0 * k as f64);
        let mut masked = f0.clone();
        for y in roi.y0..roi.y0 + roi.height {
            for x in roi.x0..roi.x0 + roi.width {
                masked[(y * w + x) as usize] = f[(y * w + x) as usize];
            }
        }
        full.step(&masked, k * 1000, &mut a).unwrap();
        part.step_roi(&crop(&f), roi, k * 1000, &mut b).unwrap();
        assert_eq!(a, b, "step {k}");
        n += a.len();
    }
    assert!(n > 500, "{n} events");

    let mut noisy = EventSimulator::new(
        w,
        h,
        SimParams {
            shot_noise_rate_hz: 1000.0,
            ..SimParams::default()
        },
    )
    .unwrap();
    noisy.reset(&f0, 0).unwrap();
    noisy.step_roi(&crop(&f0), roi, 10_000, &mut b).unwrap();
    assert!(b.len() > 100);
    assert!((0..b.len()).all(|k| roi.contains(u32::from(b.x[k]), u32::from(b.y[k]))));
}

#[test]
fn first_step_initialises_and_reset_replays() {
    let (w, h) = (32, 24);
    let mut sim = EventSimulator::new(
        w,
        h,
        SimParams {
            seed: 1,
            ..SimParams::preset("noisy").unwrap()
        },
    )
    .unwrap();
    let mut out = EventBatch::default();
    out.push(1, 1, 1, 1);
    sim.step(&edge_frame(w, h, 3.0), 0, &mut out).unwrap();
    assert!(out.is_empty());
    assert_eq!(sim.time_us(), Some(0));
    let mut run = |sim: &mut EventSimulator| {
        let mut all = EventBatch::default();
        for k in 1..=5 {
            sim.step(&edge_frame(w, h, 3.0 + 2.0 * k as f64), k * 2000, &mut out)
                .unwrap();
            all.extend_from(&out);
        }
        all
    };
    let first = run(&mut sim);
    sim.reset(&edge_frame(w, h, 3.0), 0).unwrap();
    assert_eq!(run(&mut sim), first);
    assert!(!first.is_empty());
}

#[test]
fn bad_input_is_an_error() {
    assert!(EventSimulator::new(0, 10, SimParams::default()).is_err());
    assert!(EventSimulator::new(70_000, 10, SimParams::default()).is_err());
    assert!(EventSimulator::new(
        10,
        10,
        SimParams {
            c_neg: 0.0,
            ..SimParams::default()
        }
    )
    .is_err());
    let (w, h) = (8u32, 6u32);
    let mut sim = EventSimulator::new(w, h, SimParams::default()).unwrap();
    let mut out = EventBatch::default();
    let roi = Roi {
        x0: 0,
        y0: 0,
        width: 2,
        height: 2,
    };
    assert!(
        sim.step_roi(&[0.5; 4], roi, 5, &mut out).is_err(),
        "ROI step before initialisation"
    );
    let f = uniform(w, h, 0.5);
    assert!(sim.reset(&f[1..], 0).is_err());
    sim.reset(&f, 100).unwrap();
    assert!(
        sim.step(&f, 100, &mut out).is_err(),
        "time must move forward"
    );
    assert!(sim.step(&f, 99, &mut out).is_err());
    assert!(sim.step(&f[..10], 200, &mut out).is_err());
    let mut bad = f.clone();
    bad[7] = -0.1;
    assert!(sim.step(&bad, 200, &mut out).is_err());
    bad[7] = f32::NAN;
    assert!(sim.step(&bad, 200, &mut out).is_err());
    assert!(sim
        .step_roi(
            &[0.5; 4],
            Roi {
                x0: 7,
                y0: 0,
                width: 2,
                height: 2
            },
            200,
            &mut out
        )
        .is_err());
    assert!(sim.step_roi(&[0.5; 3], roi, 200, &mut out).is_err());
    assert!(sim
        .step_roi(&[], Roi { width: 0, ..roi }, 200, &mut out)
        .is_err());
    assert!(
        sim.step(&f, i64::MAX, &mut out).is_err(),
        "10⁵ s at 0.1 Hz noise exceeds the per-step budget"
    );
    let mut far = EventSimulator::new(w, h, SimParams::preset("clean").unwrap()).unwrap();
    far.reset(&f, i64::MIN).unwrap();
    assert!(
        far.step(&f, i64::MAX, &mut out).is_err(),
        "interval overflows i64"
    );
    // Errors leave the state usable.
    sim.step(&f, 200, &mut out).unwrap();
    assert_eq!(sim.time_us(), Some(200));
}

#[test]
fn adaptive_dt_follows_the_half_pixel_rule() {
    // 0.4 m/s at Z = 0.6 m with fx ≈ 1163.6 px: ~776 px/s, so ~1550 samples per second.
    let flow = 1163.59 * 0.4 / 0.6;
    assert_eq!(adaptive_dt_us(flow, 0.5, 30.0).unwrap(), 644);
    assert_eq!(adaptive_dt_us(0.0, 0.5, 30.0).unwrap(), 33_333);
    assert_eq!(
        adaptive_dt_us(1.0, 0.5, 30.0).unwrap(),
        33_333,
        "capped by the floor rate"
    );
    assert_eq!(adaptive_dt_us(1e12, 0.5, 30.0).unwrap(), 1);
    for (f, l, r) in [
        (-1.0, 0.5, 30.0),
        (f64::NAN, 0.5, 30.0),
        (1.0, 0.0, 30.0),
        (1.0, 0.5, 0.0),
        (1.0, 0.5, f64::INFINITY),
    ] {
        assert!(adaptive_dt_us(f, l, r).is_err(), "({f}, {l}, {r})");
    }
}

/// A noise event resets the reference to the current level (v2e): a pixel that fired noise
/// after a sub-threshold rise of 0.15 no longer fires when the rise reaches 0.25; one that
/// did not fires exactly once.
#[test]
fn shot_noise_resets_the_reference() {
    let (w, h) = (20u32, 20u32);
    let p = SimParams {
        shot_noise_rate_hz: 3.0,
        ..clean(0.0, 21)
    };
    let mut sim = EventSimulator::new(w, h, p).unwrap();
    let level = |dl: f64| ((0.2f64 + 1e-3) * dl.exp() - 1e-3) as f32;
    sim.reset(&uniform(w, h, level(0.0)), 0).unwrap();
    // Changes happen over 1 µs, where the chance of a noise event on the whole sensor is ~10⁻³;
    // noise gets 300 ms of static scene in between.
    let mut out = EventBatch::default();
    sim.step(&uniform(w, h, level(0.15)), 1, &mut out).unwrap();
    assert!(out.is_empty());
    let mut noise = EventBatch::default();
    sim.step(&uniform(w, h, level(0.15)), 300_000, &mut noise)
        .unwrap();
    sim.step(&uniform(w, h, level(0.25)), 300_001, &mut out)
        .unwrap();
    let (mut quiet, mut reset) = (0, 0);
    for idx in 0..(w * h) as usize {
        if of_pixel(&noise, w, idx).is_empty() {
            assert_eq!(
                of_pixel(&out, w, idx),
                vec![(300_001, 1)],
                "pixel {idx} without noise"
            );
            quiet += 1;
        } else {
            assert!(
                of_pixel(&out, w, idx).is_empty(),
                "pixel {idx} fired after a noise reset"
            );
            reset += 1;
        }
    }
    assert!(
        quiet > 50 && reset > 50,
        "{quiet} quiet, {reset} reset pixels"
    );
}

/// Tile flags (row-major over `sim.tiles()`) of the tiles where frames `a` and `b` differ.
fn differing_tiles(sim: &EventSimulator, a: &[f32], b: &[f32]) -> Vec<bool> {
    let (tx, ty) = sim.tiles();
    let (w, t) = (sim.width() as usize, TILE_PX as usize);
    let mut flags = vec![false; tx * ty];
    for (k, (x, y)) in a.iter().zip(b).enumerate() {
        if x.to_bits() != y.to_bits() {
            flags[(k / w) / t * tx + (k % w) / t] = true;
        }
    }
    flags
}

#[test]
fn tile_steps_equal_full_steps_with_noise_and_leak() {
    // The imx636 preset with strong noise: shot noise, leak, refractory period. The edge moves
    // through a few tiles only; the rest are skipped but still leak and take shot noise.
    let (w, h) = (70, 40);
    let p = SimParams {
        shot_noise_rate_hz: 200.0,
        leak_rate_hz: 50.0,
        seed: 4,
        ..SimParams::default()
    };
    let (mut full, mut tiled) = (
        EventSimulator::new(w, h, p.clone()).unwrap(),
        EventSimulator::new(w, h, p).unwrap(),
    );
    let mut prev = edge_frame(w, h, 20.0);
    full.reset(&prev, 0).unwrap();
    tiled.reset(&prev, 0).unwrap();
    let (mut a, mut b) = (EventBatch::default(), EventBatch::default());
    let (mut all_a, mut all_b) = (EventBatch::default(), EventBatch::default());
    let mut skipped = 0;
    for k in 1..=200 {
        // The edge moves for 20 steps, then the scene is static (leak and noise only).
        let f = edge_frame(w, h, 20.0 + 0.4 * (k.min(20)) as f64);
        let flags = differing_tiles(&tiled, &prev, &f);
        skipped += flags.iter().filter(|f| !**f).count();
        full.step(&f, k * 1000, &mut a).unwrap();
        tiled.step_tiles(&f, &flags, k * 1000, &mut b).unwrap();
        assert_sorted(&b, w);
        assert!((0..b.len()).all(|i| b.t_us[i] >= (k - 1) * 1000 && b.t_us[i] <= k * 1000));
        all_a.extend_from(&a);
        all_b.extend_from(&b);
        prev = f;
    }
    assert!(skipped > 200 * 15 / 2, "most tiles are skipped ({skipped})");
    // Leak makes ~50 Hz·0.2 s·2800 px ≈ 28 000 events and shot noise ≈ 110 000; the edge a few
    // thousand. Each pixel fires the same events, at most a microsecond apart (f32 rounding of
    // the leak accumulated over a skipped stretch instead of per step).
    assert!(all_a.len() > 30_000, "{}", all_a.len());
    let mut mismatched = 0;
    for idx in 0..(w * h) as usize {
        let (ea, eb) = (of_pixel(&all_a, w, idx), of_pixel(&all_b, w, idx));
        let same = ea.len() == eb.len()
            && ea
                .iter()
                .zip(&eb)
                .all(|(x, y)| x.1 == y.1 && (x.0 - y.0).abs() <= 1);
        mismatched += usize::from(!same);
    }
    assert!(
        mismatched * 100 <= (w * h) as usize,
        "{mismatched} pixels differ"
    );

    // All tiles flagged every step: bit-identical to full steps.
    let p = SimParams {
        shot_noise_rate_hz: 200.0,
        leak_rate_hz: 50.0,
        seed: 5,
        ..SimParams::default()
    };
    let (mut full, mut tiled) = (
        EventSimulator::new(w, h, p.clone()).unwrap(),
        EventSimulator::new(w, h, p).unwrap(),
    );
    let mut f = edge_frame(w, h, 30.0);
    full.reset(&f, 0).unwrap();
    tiled.reset(&f, 0).unwrap();
    let all = vec![true; flags_len(&tiled)];
    for k in 1..=10 {
        f = edge_frame(w, h, 30.0 + 0.7 * k as f64);
        full.step(&f, k * 1000, &mut a).unwrap();
        tiled.step_tiles(&f, &all, k * 1000, &mut b).unwrap();
        assert_eq!(a, b, "step {k}");
    }
    assert!(tiled.step_tiles(&f, &all[1..], 300_000, &mut b).is_err());
    let mut bad = f.clone();
    bad[0] = f32::NAN;
    assert!(tiled.step_tiles(&bad, &all, 300_000, &mut b).is_err());
}

fn flags_len(sim: &EventSimulator) -> usize {
    let (tx, ty) = sim.tiles();
    tx * ty
}
