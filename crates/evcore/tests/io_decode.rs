//! Decoders and RawReader against the real Prophesee recordings in shared/event-samples, plus
//! property tests: no byte input panics, and any chunking decodes like one call.
//!
//! The recordings' expected values come from independent decoders (see the samples' README);
//! the bit-exact SHA3 digests are asserted by tests/test_io.py.
//!
//! The `fuzz_` properties feed random, truncated and corrupted byte streams to both decoders and
//! the file reader: every input must end in events or an error, never a panic or a hang.
//! `EVSERVO_FUZZ_CASES` sets their case count (default 256 each, for CI); `make bench` runs
//! `EVSERVO_FUZZ_CASES=1000000 cargo test --release -p evcore --test io_decode fuzz_`.
//! `PROPTEST_CASES` sets the count of the slower whole-recording property (default 256).

use evcore::io::{
    Decoder, Evt2Decoder, Evt3Decoder, Format, RawReader, SliceRule, BLOCK_BYTES,
    MAX_SLICES_PER_RUN,
};
use evcore::{Error, EventBatch, EventCd};
use proptest::prelude::*;
use std::path::PathBuf;
use std::sync::OnceLock;

fn samples_dir() -> PathBuf {
    match std::env::var_os("EVSERVO_SAMPLES") {
        Some(d) => PathBuf::from(d),
        None => PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/event-samples"),
    }
}

/// The sample's bytes, or `None` (with a visible note) when the samples are not installed.
fn sample(name: &str) -> Option<Vec<u8>> {
    let path = samples_dir().join(name);
    match std::fs::read(&path) {
        Ok(b) => Some(b),
        Err(e) => {
            eprintln!(
                "SKIPPED: sample {} unavailable ({e}); set EVSERVO_SAMPLES",
                path.display()
            );
            None
        }
    }
}

const EVT3: &str = "prophesee_gen41_evt3_1280x720.raw";
const EVT2_A: &str = "prophesee_gen3_evt2_640x480_a.raw";
const EVT2_B: &str = "prophesee_gen3_evt2_640x480_b.raw";

struct Expected {
    n: usize,
    t_first: i64,
    t_last: i64,
    x_max: u16,
    y_max: u16,
    on: usize,
}

fn read_all(name: &str) -> Option<(EventBatch, RawReader)> {
    sample(name)?;
    let mut r = RawReader::open(samples_dir().join(name)).unwrap();
    let mut all = EventBatch::default();
    while r.read_n_events(100_000, &mut all).unwrap() {}
    Some((all, r))
}

fn check(ev: &EventBatch, e: &Expected) {
    assert_eq!(ev.len(), e.n);
    assert_eq!(ev.t_us[0], e.t_first);
    assert_eq!(*ev.t_us.last().unwrap(), e.t_last);
    assert_eq!(*ev.x.iter().max().unwrap(), e.x_max);
    assert_eq!(*ev.y.iter().max().unwrap(), e.y_max);
    assert_eq!(ev.p.iter().filter(|&&p| p == 1).count(), e.on);
    assert!(ev.p.iter().all(|&p| p == 0 || p == 1));
}

#[test]
fn evt3_sample_matches_reference_decoders() {
    let Some((ev, r)) = read_all(EVT3) else {
        return;
    };
    assert_eq!(
        (r.format(), r.width(), r.height()),
        (Format::Evt3, 1280, 720)
    );
    check(
        &ev,
        &Expected {
            n: 219_596,
            t_first: 11_718_656,
            t_last: 11_727_457,
            x_max: 1279,
            y_max: 719,
            on: 115_532,
        },
    );
    let s = r.stats();
    assert_eq!(s.words(), 308_943);
    let by_type: Vec<(usize, u64)> = s
        .words_by_type
        .iter()
        .copied()
        .enumerate()
        .filter(|&(_, n)| n > 0)
        .collect();
    assert_eq!(
        by_type,
        [
            (0x0, 59_640),
            (0x2, 197_550),
            (0x3, 10_527),
            (0x4, 21_242),
            (0x5, 10_621),
            (0x6, 8_812),
            (0x8, 551)
        ]
    );
    // The README's trap at word 28,315: TIME_HIGH 2861 repeated, then TIME_LOW 811 and 800. That
    // is a step back, not a 4096 µs wrap: no loop, t_last above stays 8.8 ms after t_first, and
    // the events after it carry 2861 << 12 | 800 exactly.
    assert_eq!(s.time_loops, 0);
    assert!(ev.t_us.windows(2).all(|w| w[1] >= w[0]));
    assert!(ev.t_us.contains(&((2861 << 12) | 800)));
}

#[test]
fn evt2_samples_match_reference_decoders() {
    if let Some((ev, r)) = read_all(EVT2_A) {
        assert_eq!(
            (r.format(), r.width(), r.height()),
            (Format::Evt2, 640, 480)
        );
        check(
            &ev,
            &Expected {
                n: 521_252,
                t_first: 913_716_224,
                t_last: 913_812_095,
                x_max: 639,
                y_max: 479,
                on: 185_861,
            },
        );
    }
    if let Some((ev, _)) = read_all(EVT2_B) {
        check(
            &ev,
            &Expected {
                n: 539_481,
                t_first: 1_317_888,
                t_last: 1_367_888,
                x_max: 599,
                y_max: 475,
                on: 367_855,
            },
        );
    }
}

#[test]
fn time_slices_concatenate_to_the_stream() {
    let Some((all, _)) = read_all(EVT3) else {
        return;
    };
    let mut r = RawReader::open(samples_dir().join(EVT3)).unwrap();
    let mut joined = EventBatch::default();
    let mut t = all.t_us[0];
    let mut slices = 0;
    loop {
        t += 1000;
        let mut slice = EventBatch::default();
        if !r.read_until_t(t, &mut slice).unwrap() {
            break;
        }
        // Every slice ends before the cut; steps back in time may put earlier times at a slice start.
        assert!(slice.t_us.last().is_none_or(|&l| l < t));
        joined.extend_from(&slice);
        slices += 1;
    }
    assert_eq!(slices, 9, "8.8 ms in 1 ms slices");
    assert_eq!(joined, all);
    assert!(!r.read_n_events(10, &mut joined).unwrap());
}

/// The owned slices (`next_until_t`, `next_n_events`, which hand the reader's buffer over or copy
/// the smaller part) equal the appended ones, for cuts finer than a decode block, across blocks,
/// and past the end of the file.
#[test]
fn owned_slices_equal_appended_slices() {
    for name in [EVT3, EVT2_A] {
        let path = samples_dir().join(name);
        let Ok(mut whole) = RawReader::open(&path) else {
            return;
        };
        let all = whole.read_rest().unwrap();
        let total = all.len();
        for step_us in [300, 4_000, 50_000] {
            let (mut owned, mut appended) = (
                RawReader::open(&path).unwrap(),
                RawReader::open(&path).unwrap(),
            );
            let mut t = owned.peek_t().unwrap().unwrap();
            let mut n = 0;
            loop {
                t += step_us;
                let mut want = Vec::new();
                let more = appended.read_until_t(t, &mut want).unwrap();
                let got = owned.next_until_t(t).unwrap();
                assert_eq!(got.is_some(), more, "{name} at {t}");
                let Some(got) = got else { break };
                assert_eq!(got, want, "{name} slice ending at {t}");
                n += got.len();
            }
            assert_eq!(n, total);
        }
        let mut r = RawReader::open(&path).unwrap();
        let mut joined = Vec::new();
        while let Some(block) = r.next_n_events(70_001).unwrap() {
            assert!(block.len() == 70_001 || joined.len() + block.len() == all.len());
            joined.extend(block);
        }
        assert_eq!(joined, all);
    }
}

/// The slices of `evservo.io.open_events` by their definition, one event at a time: a grid of
/// `delta_t_us` from the one holding the first event; an event at or after the current end closes
/// the slice (and every empty one it jumps over).
fn time_slices_by_definition(events: &[EventCd], delta_t_us: i64) -> Vec<Vec<EventCd>> {
    let Some(first) = events.first() else {
        return Vec::new();
    };
    let mut end = (first.t.div_euclid(delta_t_us) + 1) * delta_t_us;
    let (mut slices, mut open) = (Vec::new(), Vec::new());
    for e in events {
        while e.t >= end {
            slices.push(std::mem::take(&mut open));
            end += delta_t_us;
        }
        open.push(*e);
    }
    slices.push(open);
    slices
}

/// Every run of `next_slices` split at its ends, checking each run's shape on the way.
fn slices_in_runs(mut reader: RawReader, mut rule: SliceRule) -> Vec<Vec<EventCd>> {
    let mut slices = Vec::new();
    while let Some(run) = reader.next_slices(&mut rule).unwrap() {
        assert!(!run.ends.is_empty() && run.ends.len() <= MAX_SLICES_PER_RUN);
        assert_eq!(run.ends.last(), Some(&run.events.len()));
        let mut start = 0;
        for &stop in &run.ends {
            slices.push(run.events[start..stop].to_vec());
            start = stop;
        }
    }
    slices
}

#[test]
fn slice_runs_are_the_defined_slices_for_any_block_size() {
    for name in [EVT3, EVT2_A] {
        let path = samples_dir().join(name);
        let Ok(mut whole) = RawReader::open(&path) else {
            return;
        };
        let all = whole.read_rest().unwrap();
        // 4 KiB and an odd size (blocks ending inside words) carry partial slices from run to
        // run; 1 µs slices of sample a are more than one run may hold.
        for block in [4096, 65_537, BLOCK_BYTES] {
            let reader = || {
                let mut r = RawReader::open(&path).unwrap();
                r.set_block_bytes(block);
                r
            };
            for dt in [1, 300, 4_000, 50_000] {
                let got = slices_in_runs(reader(), SliceRule::time(dt).unwrap());
                assert!(
                    got == time_slices_by_definition(&all, dt),
                    "{name}: {dt} µs slices, {block}-byte blocks"
                );
            }
            for n in [1, 70_001] {
                let got = slices_in_runs(reader(), SliceRule::count(n).unwrap());
                let want: Vec<Vec<EventCd>> = all.chunks(n).map(<[EventCd]>::to_vec).collect();
                assert!(got == want, "{name}: {n}-event slices, {block}-byte blocks");
            }
        }
    }
}

#[test]
fn truncated_file_inside_a_word_is_an_error() {
    let Some(bytes) = sample(EVT2_B) else { return };
    let cut = &bytes[..bytes.len() - 3];
    let mut r = RawReader::new(cut).unwrap();
    let mut out = EventBatch::default();
    let err = loop {
        match r.read_n_events(50_000, &mut out) {
            Ok(true) => {}
            Ok(false) => panic!("truncation went unnoticed"),
            Err(e) => break e,
        }
    };
    assert!(
        matches!(err, Error::Decode(ref m) if m.contains("truncated")),
        "{err}"
    );
    // Sticky: the reader does not pretend to have recovered.
    assert_eq!(r.read_n_events(1, &mut out).unwrap_err(), err);
}

/// Header length of a sample: data starts after the header lines.
fn data_of(bytes: &[u8]) -> &[u8] {
    let mut r = std::io::BufReader::new(bytes);
    let h = evcore::io::RawHeader::read_from(&mut r).unwrap();
    &bytes[h.len_bytes..]
}

#[test]
fn events_before_the_first_time_high_are_skipped() {
    // EVT3: ADDR_Y 5, ADDR_X 7 (no time yet), TIME_HIGH 1, TIME_LOW 3, ADDR_X 9 ON.
    let words: [u16; 5] = [0x0005, 0x2007, 0x8001, 0x6003, 0x2809];
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    let mut d = Evt3Decoder::new();
    let mut out = EventBatch::default();
    d.decode(&bytes, &mut out).unwrap();
    // The ADDR_Y before TIME_HIGH is dropped too, so y is still 0.
    assert_eq!(
        out,
        EventBatch::from_columns(vec![9], vec![0], vec![1], vec![4096 + 3]).unwrap()
    );
    assert_eq!(d.stats().skipped_before_time_high, 2);
}

#[test]
fn evt3_vectors_expand_and_advance_the_base() {
    // TIME_HIGH 2, TIME_LOW 5, ADDR_Y 10, VECT_BASE_X 100 OFF, VECT_12 bits {0, 11}, VECT_8 bit 7.
    let words: [u16; 6] = [0x8002, 0x6005, 0x000a, 0x3064, 0x4801, 0x5080];
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    let mut out = EventBatch::default();
    Evt3Decoder::new().decode(&bytes, &mut out).unwrap();
    assert_eq!(out.x, [100, 111, 119]);
    assert_eq!(out.y, [10, 10, 10]);
    assert_eq!(out.p, [0, 0, 0]);
    assert_eq!(out.t_us, [8197; 3]);
}

#[test]
fn evt3_time_wraps_once_per_period() {
    // TIME_HIGH 0xfff, TIME_LOW 1, ADDR_X 1; TIME_HIGH 0 (wrap), ADDR_X 2; TIME_HIGH 0xffe (jitter back, not a wrap).
    let words: [u16; 8] = [
        0x8fff, 0x6001, 0x2001, 0x8000, 0x6002, 0x2002, 0x8001, 0x2003,
    ];
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    let mut d = Evt3Decoder::new();
    let mut out = EventBatch::default();
    d.decode(&bytes, &mut out).unwrap();
    assert_eq!(out.t_us, [0xfff_001, (1 << 24) + 2, (1 << 24) + 4096 + 2]);
    assert_eq!(d.stats().time_loops, 1);
}

#[test]
fn evt2_time_and_fields() {
    // TIME_HIGH 3, CD_ON ts 5 x 600 y 7, CD_OFF ts 63 x 0 y 479, TIME_HIGH 0 (a 192 µs step back, not a wrap), CD_ON.
    let words: [u32; 5] = [
        0x8000_0003,
        0x1000_0000 | (5 << 22) | (600 << 11) | 7,
        (63 << 22) | 479,
        0x8000_0000,
        0x1000_0000,
    ];
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    let mut d = Evt2Decoder::with_geometry(640, 480).unwrap();
    let mut out = EventBatch::default();
    d.decode(&bytes, &mut out).unwrap();
    assert_eq!(
        out,
        EventBatch::from_columns(
            vec![600, 0, 0],
            vec![7, 479, 0],
            vec![1, 0, 1],
            vec![197, 255, 0]
        )
        .unwrap()
    );
    assert_eq!(d.stats().time_loops, 0);
}

#[test]
fn out_of_sensor_events_are_sticky_decode_errors() {
    let ok = 0x1000_0000u32 | (639 << 11) | 479;
    let bad = 0x1000_0000u32 | (640 << 11);
    let bytes: Vec<u8> = [0x8000_0001u32, ok, bad, ok]
        .iter()
        .flat_map(|w| w.to_le_bytes())
        .collect();
    let mut d = Evt2Decoder::with_geometry(640, 480).unwrap();
    let mut out = EventBatch::default();
    let err = d.decode(&bytes, &mut out).unwrap_err();
    assert_eq!(
        err.to_string(),
        "decode error: EVT2 event at (640, 0) lies outside the 640x480 sensor (word 2)"
    );
    assert_eq!(out.len(), 1, "events before the bad word are kept");
    assert_eq!(d.decode(&bytes[..4], &mut out).unwrap_err(), err);

    // EVT3 vector reaching past the right edge: base 1276, bit 4 → x 1280.
    let words: [u16; 4] = [0x8001, 0x0000, 0x34fc, 0x4011];
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    let mut d = Evt3Decoder::with_geometry(1280, 720).unwrap();
    let err = d.decode(&bytes, &mut EventBatch::default()).unwrap_err();
    assert!(err.to_string().contains("(1280, 0)"), "{err}");
}

fn decode_whole(format: Format, bytes: &[u8]) -> (EventBatch, Result<(), Error>) {
    let mut d = match format {
        Format::Evt2 => Decoder::Evt2(Evt2Decoder::new()),
        Format::Evt3 => Decoder::Evt3(Evt3Decoder::new()),
    };
    let mut out = EventBatch::default();
    let res = d.decode(bytes, &mut out);
    assert_time_bound(&d, &out);
    (out, res)
}

/// The decoder's time bound holds every event it output, errors included (the slicer skips
/// searching for boundaries above it).
fn assert_time_bound(d: &Decoder, out: &EventBatch) {
    if let Some(&t_max) = out.t_us.iter().max() {
        let bound = d
            .t_bound()
            .expect("events were output, so the time base is known");
        assert!(
            t_max <= bound,
            "event at {t_max} µs above the bound {bound}"
        );
    }
}

/// Feeds `bytes` in pieces cut at `cuts` (sorted, possibly repeated), stopping at the first error.
fn decode_chunked(format: Format, bytes: &[u8], cuts: &[usize]) -> (EventBatch, Result<(), Error>) {
    let mut d = match format {
        Format::Evt2 => Decoder::Evt2(Evt2Decoder::new()),
        Format::Evt3 => Decoder::Evt3(Evt3Decoder::new()),
    };
    let mut out = EventBatch::default();
    let mut start = 0;
    for &c in cuts.iter().chain(std::iter::once(&bytes.len())) {
        let c = c.clamp(start, bytes.len());
        let res = d.decode(&bytes[start..c], &mut out);
        assert_time_bound(&d, &out);
        if let Err(e) = res {
            return (out, Err(e));
        }
        start = c;
    }
    (out, Ok(()))
}

/// Cases per `fuzz_` property: `EVSERVO_FUZZ_CASES`, else a CI-sized default.
fn fuzz_cases() -> u32 {
    std::env::var("EVSERVO_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(256)
}

/// The data words of the three recordings (header stripped) with their formats, read once per
/// test process; empty when the samples are not installed.
fn sample_streams() -> &'static [(Format, Vec<u8>)] {
    static STREAMS: OnceLock<Vec<(Format, Vec<u8>)>> = OnceLock::new();
    STREAMS.get_or_init(|| {
        [
            (EVT3, Format::Evt3),
            (EVT2_A, Format::Evt2),
            (EVT2_B, Format::Evt2),
        ]
        .into_iter()
        .filter_map(|(name, format)| Some((format, data_of(&sample(name)?).to_vec())))
        .collect()
    })
}

/// Word size of a format in bytes.
fn word_bytes(format: Format) -> usize {
    match format {
        Format::Evt2 => 4,
        Format::Evt3 => 2,
    }
}

/// EVT 3.0 decoded word by word straight from the format description, as plainly as possible:
/// the oracle for the optimised decoder. Same conventions: nothing before the first TIME_HIGH,
/// wraps only on a near-full-period drop, an out-of-sensor event stops with an error.
fn evt3_reference(bytes: &[u8], width: u32, height: u32) -> (EventBatch, bool) {
    const PERIOD: i64 = 1 << 24;
    const GUARD: i64 = (10 << 12) + (1 << 12);
    let mut out = EventBatch::default();
    let (mut started, mut loops) = (false, 0i64);
    let (mut high, mut low, mut y, mut base, mut vp) = (0i64, 0i64, 0u32, 0u32, 0i16);
    for c in bytes.chunks_exact(2) {
        let w = u16::from_le_bytes([c[0], c[1]]);
        let ty = w >> 12;
        if !started {
            if ty != 0x8 {
                continue;
            }
            started = true;
        }
        let emit = |x: u32, p: i16, out: &mut EventBatch| -> bool {
            if x >= width || y >= height {
                return false;
            }
            out.x.push(x as u16);
            out.y.push(y as u16);
            out.p.push(p);
            out.t_us.push(high + low);
            true
        };
        match ty {
            0x0 => y = u32::from(w & 0x7ff),
            0x2 => {
                let (x, p) = (u32::from(w & 0x7ff), ((w >> 11) & 1) as i16);
                if !emit(x, p, &mut out) {
                    return (out, false);
                }
            }
            0x3 => {
                base = u32::from(w & 0x7ff);
                vp = ((w >> 11) & 1) as i16;
            }
            0x4 | 0x5 => {
                let bits = if ty == 0x4 { 12 } else { 8 };
                // The whole vector is checked before any of its events is output.
                let mask = u32::from(w) & ((1 << bits) - 1);
                if mask != 0 && (base + 31 - mask.leading_zeros() >= width || y >= height) {
                    return (out, false);
                }
                for i in 0..bits {
                    if mask & (1 << i) != 0 {
                        emit(base + i, vp, &mut out);
                    }
                }
                base = base.saturating_add(bits);
            }
            0x6 => low = i64::from(w & 0xfff),
            0x8 => {
                let mut new_high = (i64::from(w & 0xfff) << 12) + loops * PERIOD;
                if high > new_high && high - new_high >= PERIOD - GUARD {
                    new_high += PERIOD;
                    loops += 1;
                }
                high = new_high;
            }
            _ => {}
        }
    }
    (out, true)
}

/// Random EVT 3.0 words, mostly of the types real streams carry, with fields anywhere in range.
fn evt3_words() -> impl Strategy<Value = Vec<u8>> {
    let word = prop_oneof![
        6 => (0u16..0x1000).prop_map(|v| 0x2000 | v),
        3 => 0u16..0x1000,
        2 => (0u16..0x1000).prop_map(|v| 0x4000 | v),
        1 => (0u16..0x1000).prop_map(|v| 0x5000 | v),
        1 => (0u16..0x1000).prop_map(|v| 0x3000 | v),
        1 => (0u16..0x1000).prop_map(|v| 0x6000 | v),
        1 => (0u16..0x1000).prop_map(|v| 0x8000 | v),
        1 => any::<u16>(),
    ];
    prop::collection::vec(word, 0..3000)
        .prop_map(|ws| ws.iter().flat_map(|w| w.to_le_bytes()).collect())
}

#[test]
fn evt3_sample_matches_the_plain_reference_decoder() {
    let Some(bytes) = sample(EVT3) else { return };
    let data = data_of(&bytes);
    let mut d = Evt3Decoder::with_geometry(1280, 720).unwrap();
    let mut out = EventBatch::default();
    d.decode(data, &mut out).unwrap();
    let (reference, ok) = evt3_reference(data, 1280, 720);
    assert!(ok);
    assert_eq!(out, reference);
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: fuzz_cases(),
        // Shrinking a failure of a million-case run can take longer than the run: report it as found.
        max_shrink_iters: 256,
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    /// Random bytes through both decoders, whole and cut in random pieces: the same events and
    /// the same error either way (a panic fails the test).
    #[test]
    fn fuzz_random_bytes_never_panic_and_chunking_is_invisible(
        bytes in prop::collection::vec(any::<u8>(), 0..4096),
        mut cuts in prop::collection::vec(0usize..4096, 0..16),
    ) {
        cuts.sort_unstable();
        for format in [Format::Evt2, Format::Evt3] {
            let whole = decode_whole(format, &bytes);
            prop_assert_eq!(decode_chunked(format, &bytes, &cuts), whole);
        }
    }

    /// The optimised EVT 3.0 decoder equals the plain reference on random word streams, on a
    /// sensor small enough that many of them end in an out-of-sensor error.
    #[test]
    fn fuzz_evt3_matches_the_plain_reference_decoder(
        bytes in evt3_words(),
        (width, height) in (1u32..=2048, 1u32..=2048),
    ) {
        let mut d = Evt3Decoder::with_geometry(width, height).unwrap();
        let mut out = EventBatch::default();
        let ok = d.decode(&bytes, &mut out).is_ok();
        if let Some(&t_max) = out.t_us.iter().max() {
            prop_assert!(d.t_bound().is_some_and(|b| t_max <= b));
        }
        prop_assert_eq!((out, ok), evt3_reference(&bytes, width, height));
    }

    /// Windows of the real recordings, cut at any byte at both ends (so mid-word and without the
    /// stream's earlier state) and optionally with a few bytes overwritten. Untouched windows
    /// that start on a word boundary hold valid words and must decode without error.
    #[test]
    fn fuzz_truncated_and_corrupted_real_streams(
        which in 0usize..3,
        start in any::<prop::sample::Index>(),
        len in 0usize..16_384,
        flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 0..4),
        mut cuts in prop::collection::vec(0usize..16_384, 0..8),
    ) {
        let streams = sample_streams();
        if streams.is_empty() {
            return Ok(());
        }
        let (format, data) = &streams[which % streams.len()];
        let start = start.index(data.len());
        let mut window = data[start..(start + len).min(data.len())].to_vec();
        if !window.is_empty() {
            for (at, byte) in &flips {
                let at = at.index(window.len());
                window[at] = *byte;
            }
        }
        cuts.sort_unstable();
        let whole = decode_whole(*format, &window);
        if flips.is_empty() && start % word_bytes(*format) == 0 {
            prop_assert!(whole.1.is_ok(), "{:?}", whole.1);
        }
        prop_assert_eq!(decode_chunked(*format, &window, &cuts), whole);
    }

    /// Any header + body through the file reader, read in slices of any size: it ends, and
    /// every event it returns lies on the sensor.
    #[test]
    fn fuzz_reader_survives_any_file(
        header in prop::sample::select(vec![
            &b"% evt 3.0\n% geometry 64x32\n"[..],
            b"% format EVT2;width=64;height=32\n% end\n",
            b"% evt 2.0\n",
            b"",
        ]),
        body in prop::collection::vec(any::<u8>(), 0..2048),
        n in 1usize..500,
    ) {
        let mut file = header.to_vec();
        file.extend_from_slice(&body);
        if let Ok(mut r) = RawReader::new(&file[..]) {
            let mut out = EventBatch::default();
            // Each successful call either appends or ends the stream, so this terminates.
            while let Ok(true) = r.read_n_events(n, &mut out) {}
            prop_assert!(out.x.iter().all(|&x| u32::from(x) < r.width()));
            prop_assert!(out.y.iter().all(|&y| u32::from(y) < r.height()));
        }
        // The same file in runs of slices (small blocks, so that several runs are read): it ends,
        // and where it reads without error the runs hold what one read of the rest gives.
        if let (Ok(mut runs), Ok(mut whole)) = (RawReader::new(&file[..]), RawReader::new(&file[..])) {
            runs.set_block_bytes(n);
            let mut rule = SliceRule::count(n).unwrap();
            let mut got = Vec::new();
            while let Ok(Some(run)) = runs.next_slices(&mut rule) {
                got.extend(run.events);
            }
            if let Ok(all) = whole.read_rest() {
                prop_assert_eq!(got, all);
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(
        std::env::var("PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(256)
    ))]

    /// Whole recordings, truncated at any point and cut anywhere, decode like one call and
    /// without error (a property over the full files, too slow for a million cases).
    #[test]
    fn real_files_split_or_truncated_decode_like_one_shot(
        which in 0usize..3,
        keep in 0.0f64..=1.0,
        mut cuts in prop::collection::vec(0usize..3_000_000, 0..12),
    ) {
        let streams = sample_streams();
        if streams.is_empty() {
            return Ok(());
        }
        let (format, data) = &streams[which % streams.len()];
        let data = &data[..(data.len() as f64 * keep) as usize];
        cuts.sort_unstable();
        let whole = decode_whole(*format, data);
        prop_assert!(whole.1.is_ok());
        prop_assert_eq!(decode_chunked(*format, data, &cuts), whole);
    }
}

/// Vector runs (VECT_BASE_X, VECT_12, VECT_12, VECT_8, which the decoder takes as one 32-bit mask
/// when the run is whole within one call) decode as they do word by word (one word per call, no
/// run ever whole): same events, same error, same word counts. Bases and masks reach past the
/// sensor's edge, masks are often empty, and ADDR_Y words move y on and off the sensor.
#[test]
fn vector_runs_decode_as_word_by_word() {
    let mut rng = evcore::rng::Rng::new(0x9e37_79b9_7f4a_7c15u64);
    let mut next = move || rng.next_u64();
    for case in 0..3000 {
        let (width, height) = (1 + (next() % 1400) as u32, 1 + (next() % 800) as u32);
        let mut words: Vec<u16> = vec![0x8000 | (next() & 0xfff) as u16];
        for _ in 0..(next() % 40) {
            let r = next();
            let m = next() as u16;
            // A quarter of the masks empty.
            let mask = |bits: u32| {
                if r >> 62 == 0 {
                    0
                } else {
                    m & ((1 << bits) - 1)
                }
            };
            match r % 8 {
                0..=3 => words.extend([
                    0x3000 | ((next() as u16 & 0xfff) % (width as u16 + 40)),
                    0x4000 | mask(12),
                    0x4000 | (mask(12) ^ (r as u16 & 0xfff)),
                    0x5000 | mask(8),
                ]),
                4 => words.push((next() as u16 & 0x7ff) % (height as u16 + 4)),
                5 => words.push(0x2000 | ((next() as u16 & 0xfff) % (width as u16))),
                6 => words.push(0x6000 | (next() as u16 & 0xfff)),
                _ => words
                    .push([0x4000, 0x5000, 0x3000][(r >> 8) as usize % 3] | next() as u16 & 0xfff),
            }
        }
        let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
        let run = |step: usize| {
            let mut d = Evt3Decoder::with_geometry(width, height).unwrap();
            let mut out = EventBatch::default();
            let mut res = Ok(());
            for chunk in bytes.chunks(step) {
                res = d.decode(chunk, &mut out);
                if res.is_err() {
                    break;
                }
            }
            (out, res.map_err(|e| e.to_string()), d.stats().clone())
        };
        assert_eq!(run(bytes.len().max(1)), run(2), "case {case}");
    }
}
