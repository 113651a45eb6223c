//! The ASCII header of a RAW file: lines `% key value`, ended by `% end` or by the first line
//! that does not start with `%` (older files have no `% end`).

use super::{check_geometry, MAX_SENSOR_SIDE_PX};
use crate::error::{Error, Result};
use std::fmt;
use std::io::{BufRead, Read};

/// Longest header line accepted; real lines are well under 200 bytes, so this only stops a
/// binary file without newlines from being read whole as a "line".
const MAX_LINE_BYTES: u64 = 64 * 1024;
/// Largest header accepted.
const MAX_HEADER_BYTES: usize = 1024 * 1024;

/// Event encoding of the binary part.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Format {
    /// EVT 2.0: 32-bit words, 6 µs bits per event plus 28-bit TIME_HIGH.
    Evt2,
    /// EVT 3.0: 16-bit stateful words with vectorised x runs.
    Evt3,
}

impl Format {
    pub fn name(self) -> &'static str {
        match self {
            Self::Evt2 => "EVT2",
            Self::Evt3 => "EVT3",
        }
    }

    /// Capacity to reserve for the events of `bytes` of data: exact as a bound for EVT 2.0 (one
    /// event per word at most); for EVT 3.0 one per word, above the ≈ 0.7 of real streams (a
    /// denser stream grows the output as it decodes).
    pub fn events_hint(self, bytes: usize) -> usize {
        match self {
            Self::Evt2 => bytes / 4,
            Self::Evt3 => bytes / 2,
        }
    }
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A parsed RAW header.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RawHeader {
    pub format: Format,
    pub width: u32,
    pub height: u32,
    /// Every header line as (first word, rest), in file order, without the `% `.
    pub fields: Vec<(String, String)>,
    /// Offset added to every decoded timestamp, from `% t0 N` (µs): writers that store times
    /// relative to the first event (faery) record the original start there. 0 without the line.
    pub t0_us: i64,
    /// Length of the header in bytes: the binary data starts at this offset.
    pub len_bytes: usize,
}

impl RawHeader {
    /// Reads the header from the start of a RAW stream, leaving `reader` at the first data byte.
    pub fn read_from<R: BufRead>(reader: &mut R) -> Result<Self> {
        let mut fields = Vec::new();
        let mut len_bytes = 0usize;
        let mut line = Vec::new();
        loop {
            let next = reader
                .fill_buf()
                .map_err(|e| Error::Decode(format!("reading RAW header: {e}")))?;
            if next.first() != Some(&b'%') {
                break;
            }
            line.clear();
            let n = reader
                .by_ref()
                .take(MAX_LINE_BYTES)
                .read_until(b'\n', &mut line)
                .map_err(|e| Error::Decode(format!("reading RAW header: {e}")))?;
            if n as u64 == MAX_LINE_BYTES && line.last() != Some(&b'\n') {
                return Err(Error::Decode(format!(
                    "RAW header line longer than {MAX_LINE_BYTES} bytes"
                )));
            }
            len_bytes += n;
            if len_bytes > MAX_HEADER_BYTES {
                return Err(Error::Decode(format!(
                    "RAW header longer than {MAX_HEADER_BYTES} bytes"
                )));
            }
            let text = String::from_utf8_lossy(&line[1..]);
            let text = text.trim();
            if text == "end" {
                break;
            }
            let (key, value) = text.split_once(char::is_whitespace).unwrap_or((text, ""));
            fields.push((key.to_string(), value.trim().to_string()));
        }
        let (format, width, height) = interpret(&fields)?;
        let t0_us = match lookup(&fields, "t0") {
            None => 0,
            Some(v) => v
                .parse::<i64>()
                .ok()
                .filter(|t| (0..1 << 62).contains(t))
                .ok_or_else(|| {
                    Error::Decode(format!("bad RAW header `t0 {v}` (expected 0..2^62 µs)"))
                })?,
        };
        Ok(Self {
            format,
            width,
            height,
            fields,
            t0_us,
            len_bytes,
        })
    }

    /// The value of the first line whose first word is `key`.
    pub fn get(&self, key: &str) -> Option<&str> {
        lookup(&self.fields, key)
    }
}

fn lookup<'a>(fields: &'a [(String, String)], key: &str) -> Option<&'a str> {
    fields
        .iter()
        .find(|(k, _)| k == key)
        .map(|(_, v)| v.as_str())
}

/// Format and geometry from the header lines. `% format` (newer files) wins over `% evt`;
/// geometry comes from the `% format` keys, else `% geometry`, else the camera plugin name.
fn interpret(fields: &[(String, String)]) -> Result<(Format, u32, u32)> {
    let mut format = None;
    let mut geometry = None;
    if let Some(spec) = lookup(fields, "format") {
        let mut parts = spec.split(';');
        let name = parts.next().unwrap_or("").trim();
        format = Some(match name.to_ascii_uppercase().as_str() {
            "EVT2" => Format::Evt2,
            "EVT3" => Format::Evt3,
            _ => {
                return Err(Error::Decode(format!(
                    "unsupported RAW event format `{name}` (supported: EVT2, EVT3)"
                )))
            }
        });
        let (mut w, mut h) = (None, None);
        for part in parts {
            match part.split_once('=') {
                Some(("width", v)) => w = Some(parse_side(v, "width")?),
                Some(("height", v)) => h = Some(parse_side(v, "height")?),
                _ => {}
            }
        }
        if let (Some(w), Some(h)) = (w, h) {
            geometry = Some((w, h));
        }
    }
    if format.is_none() {
        if let Some(v) = lookup(fields, "evt") {
            format = Some(match v {
                "2.0" => Format::Evt2,
                "3.0" => Format::Evt3,
                _ => {
                    return Err(Error::Decode(format!(
                        "unsupported RAW event format `evt {v}` (supported: 2.0, 3.0)"
                    )))
                }
            });
        }
    }
    let format = format.ok_or_else(|| {
        Error::Decode("RAW header names no event format (expected `% evt 2.0|3.0` or `% format EVT2|EVT3;...`)".into())
    })?;
    if geometry.is_none() {
        if let Some(v) = lookup(fields, "geometry") {
            let (w, h) = v
                .split_once('x')
                .ok_or_else(|| Error::Decode(format!("bad RAW header `geometry {v}`")))?;
            geometry = Some((parse_side(w, "width")?, parse_side(h, "height")?));
        }
    }
    if geometry.is_none() {
        geometry = lookup(fields, "plugin_name").and_then(plugin_geometry);
    }
    let (width, height) = geometry.ok_or_else(|| {
        Error::Decode("RAW header gives no sensor geometry (no `% geometry WxH`, no width/height in `% format`, unknown plugin)".into())
    })?;
    let (width, height) = check_geometry(width, height)?;
    Ok((format, width, height))
}

fn parse_side(v: &str, what: &str) -> Result<u32> {
    let side: u32 = v
        .trim()
        .parse()
        .map_err(|_| Error::Decode(format!("bad sensor {what} `{v}` in RAW header")))?;
    if side == 0 || side > MAX_SENSOR_SIDE_PX {
        return Err(Error::Decode(format!(
            "sensor {what} {side} px is outside 1..={MAX_SENSOR_SIDE_PX}"
        )));
    }
    Ok(side)
}

/// Geometry of the sensors behind OpenEB's HAL plugins, for files written before the header
/// carried it. Longer prefixes first: `gen4` must not shadow `gen41`.
fn plugin_geometry(plugin: &str) -> Option<(u32, u32)> {
    const KNOWN: [(&str, (u32, u32)); 6] = [
        ("hal_plugin_gen31", (640, 480)),
        ("hal_plugin_gen3", (640, 480)),
        ("hal_plugin_gen41", (1280, 720)),
        ("hal_plugin_gen4", (1280, 720)),
        ("hal_plugin_imx636", (1280, 720)),
        ("hal_plugin_genx320", (320, 320)),
    ];
    KNOWN
        .iter()
        .find(|(prefix, _)| plugin.starts_with(prefix))
        .map(|(_, g)| *g)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &[u8]) -> Result<(RawHeader, Vec<u8>)> {
        let mut r = std::io::BufReader::with_capacity(16, text);
        let h = RawHeader::read_from(&mut r)?;
        let mut rest = Vec::new();
        r.read_to_end(&mut rest).unwrap();
        Ok((h, rest))
    }

    #[test]
    fn format_line_with_geometry_keys_and_end_marker() {
        let (h, rest) =
            parse(b"% camera x\n% format EVT3;width=1280;height=720\n% end\n%\x2d\x8b").unwrap();
        assert_eq!((h.format, h.width, h.height), (Format::Evt3, 1280, 720));
        // `% end` ends the header even if the data then starts with a '%' byte.
        assert_eq!(rest, b"%\x2d\x8b");
        assert_eq!(h.len_bytes, 53);
        assert_eq!(h.get("camera"), Some("x"));
    }

    #[test]
    fn evt_line_with_geometry_line_and_no_end_marker() {
        let (h, rest) = parse(b"% evt 2.0\r\n% geometry 640x480\n\x01\x02").unwrap();
        assert_eq!((h.format, h.width, h.height), (Format::Evt2, 640, 480));
        assert_eq!(rest, b"\x01\x02");
    }

    #[test]
    fn t0_line_sets_the_time_offset() {
        let (h, _) = parse(b"% evt 3.0\n% geometry 640x480\n% t0 4006\n% end\n").unwrap();
        assert_eq!(h.t0_us, 4006);
        let (h, _) = parse(b"% evt 3.0\n% geometry 640x480\n").unwrap();
        assert_eq!(h.t0_us, 0);
        for bad in [
            &b"% t0 -1\n"[..],
            b"% t0 12us\n",
            b"% t0 99999999999999999999\n",
        ] {
            let mut text = b"% evt 2.0\n% geometry 640x480\n".to_vec();
            text.extend_from_slice(bad);
            let err = parse(&text).unwrap_err();
            assert!(err.to_string().contains("t0"), "{err}");
        }
    }

    #[test]
    fn geometry_from_plugin_name() {
        let (h, _) = parse(b"% evt 3.0\n% plugin_name hal_plugin_gen41_evk3\n").unwrap();
        assert_eq!((h.width, h.height), (1280, 720));
        let (h, _) = parse(b"% plugin_name hal_plugin_gen3_fx3\n% evt 2.0\n").unwrap();
        assert_eq!((h.width, h.height), (640, 480));
    }

    #[test]
    fn missing_or_unknown_format_and_geometry_are_decode_errors() {
        for bad in [
            &b"% geometry 640x480\n"[..],
            b"\x00\x01\x02",
            b"% evt 2.1\n% geometry 640x480\n",
            b"% format EVT21;width=640;height=480\n",
            b"% evt 3.0\n",
            b"% evt 3.0\n% geometry 640by480\n",
            b"% evt 3.0\n% geometry 4096x480\n",
            b"% format EVT3;width=0;height=720\n",
        ] {
            let err = parse(bad).unwrap_err();
            assert!(matches!(err, Error::Decode(_)), "{err}");
        }
    }

    #[test]
    fn endless_header_line_is_rejected_without_reading_everything() {
        let mut data = b"% evt 3.0 ".to_vec();
        data.resize(200_000, b'a');
        let err = parse(&data).unwrap_err();
        assert!(err.to_string().contains("longer than"), "{err}");
    }
}
