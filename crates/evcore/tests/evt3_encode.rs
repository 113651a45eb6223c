//! EVT 3.0 encoder against the decoder: any representable event stream, encoded in packets by
//! one streaming encoder and decoded from the concatenated bytes cut at arbitrary 16-bit word
//! (or byte) boundaries, comes back exactly. `PROPTEST_CASES` sets the case count (default 256).

use evcore::io::{encode_evt3, Evt3Decoder, Evt3Encoder};
use evcore::EventBatch;
use proptest::prelude::*;

const PERIOD_US: i64 = 1 << 24;
const W: u32 = 1280;
const H: u32 = 720;

/// One step of a generated stream: how time moves, then a single event or a row burst.
#[derive(Debug, Clone)]
enum Step {
    /// A single event `dt` µs after the previous one (negative: a small step back in time).
    Single { dt: i64, x: u16, y: u16, p: i16 },
    /// Several events at one time, row and polarity, x strictly increasing (a vector's shape),
    /// `dt` µs after the previous event.
    Burst {
        dt: i64,
        x0: u16,
        y: u16,
        p: i16,
        gaps: Vec<u16>,
    },
}

fn step() -> impl Strategy<Value = Step> {
    let dt = prop_oneof![
        6 => 0i64..40,
        1 => Just(0i64),
        1 => -3000i64..0,
        1 => 4000i64..200_000,
        1 => (PERIOD_US - 50_000)..(3 * PERIOD_US),
    ];
    prop_oneof![
        4 => (dt.clone(), 0..W as u16, 0..H as u16, 0i16..2)
            .prop_map(|(dt, x, y, p)| Step::Single { dt, x, y, p }),
        1 => (dt, 0..(W as u16 - 64), 0..H as u16, 0i16..2, prop::collection::vec(1u16..4, 1..16))
            .prop_map(|(dt, x0, y, p, gaps)| Step::Burst { dt, x0, y, p, gaps }),
    ]
}

/// The events of `steps`, with backward steps that would leave the current 2^24 µs period or
/// go below zero turned into forward ones (the encoder rejects those, see its own tests).
fn events(steps: &[Step]) -> EventBatch {
    let mut b = EventBatch::default();
    let mut t = 0i64;
    let mut push = |x: u16, y: u16, p: i16, t: i64| {
        b.x.push(x);
        b.y.push(y);
        b.p.push(p);
        b.t_us.push(t);
    };
    for s in steps {
        let dt = match s {
            Step::Single { dt, .. } | Step::Burst { dt, .. } => *dt,
        };
        t = if dt < 0 && (t + dt) / PERIOD_US == t / PERIOD_US && t + dt >= 0 {
            t + dt
        } else {
            t + dt.abs()
        };
        match s {
            Step::Single { x, y, p, .. } => push(*x, *y, *p, t),
            Step::Burst { x0, y, p, gaps, .. } => {
                let mut x = *x0;
                push(x, *y, *p, t);
                for g in gaps {
                    x += g;
                    push(x, *y, *p, t);
                }
            }
        }
    }
    b
}

fn slice(b: &EventBatch, r: std::ops::Range<usize>) -> EventBatch {
    EventBatch {
        x: b.x[r.clone()].to_vec(),
        y: b.y[r.clone()].to_vec(),
        p: b.p[r.clone()].to_vec(),
        t_us: b.t_us[r].to_vec(),
    }
}

/// Sorted, deduplicated cut positions in 0..=len, from fractions.
fn cuts(len: usize, fractions: &[f64], unit: usize) -> Vec<usize> {
    let mut c: Vec<usize> = fractions
        .iter()
        .map(|f| ((f * len as f64) as usize / unit * unit).min(len))
        .collect();
    c.sort_unstable();
    c.dedup();
    c
}

fn decode_in_chunks(bytes: &[u8], cuts: &[usize]) -> EventBatch {
    let mut d = Evt3Decoder::with_geometry(W, H).unwrap();
    let mut out = EventBatch::default();
    let mut start = 0;
    for &c in cuts.iter().chain(std::iter::once(&bytes.len())) {
        d.decode(&bytes[start..c], &mut out).unwrap();
        start = c;
    }
    assert_eq!(d.pending_bytes(), 0);
    out
}

proptest! {
    #[test]
    fn packets_encode_to_one_stream_that_decodes_back_exactly(
        steps in prop::collection::vec(step(), 1..400),
        packet_cuts in prop::collection::vec(0.0f64..1.0, 0..8),
        word_cuts in prop::collection::vec(0.0f64..1.0, 0..12),
        byte_cuts in prop::collection::vec(0.0f64..1.0, 0..4),
    ) {
        let ev = events(&steps);
        // Packets: one streaming encoder, as the bag writer uses it.
        let mut enc = Evt3Encoder::with_geometry(W, H).unwrap();
        let mut bytes = Vec::new();
        let mut start = 0;
        for &c in cuts(ev.len(), &packet_cuts, 1).iter().chain(std::iter::once(&ev.len())) {
            enc.encode(&slice(&ev, start..c), &mut bytes).unwrap();
            start = c;
        }
        // One-shot encoding differs only where a vector run straddles a packet cut.
        prop_assert_eq!(decode_in_chunks(&encode_evt3(&ev, W, H).unwrap(), &[]), ev.clone());
        prop_assert_eq!(decode_in_chunks(&bytes, &cuts(bytes.len(), &word_cuts, 2)), ev.clone());
        prop_assert_eq!(decode_in_chunks(&bytes, &cuts(bytes.len(), &byte_cuts, 1)), ev);
    }
}

#[test]
fn vectors_make_dense_rows_compact() {
    // A full row at one time: 1280 events in 107 vectors (+ a base and time/row words),
    // against 1280 ADDR_X words without vectors.
    let mut ev = EventBatch::default();
    for x in 0..W as u16 {
        ev.x.push(x);
        ev.y.push(7);
        ev.p.push(1);
        ev.t_us.push(1000);
    }
    let bytes = encode_evt3(&ev, W, H).unwrap();
    assert_eq!(bytes.len() / 2, 4 + 107);
    assert_eq!(decode_in_chunks(&bytes, &[]), ev);
}
