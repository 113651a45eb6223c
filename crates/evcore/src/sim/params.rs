//! Sensor-model parameters and the named presets.
//!
//! Anchors (paraphrased from ESIM, v2e and Prophesee's `video_to_event` simulator, see the
//! project notes §B):
//!
//! | field                      | clean | imx636 | noisy | anchor                                                  |
//! |----------------------------|-------|--------|-------|---------------------------------------------------------|
//! | `hot_pixel_fraction`       | 0     | 0      | 0     | `lab`: 1e-4 (≈ 90 pixels of 1280×720), an engineering choice |
//! | `hot_pixel_rate_hz`        | 0     | 0      | 0     | `lab`: 500 Hz each, a stuck comparator firing both ways |
//! | `flicker_hz`               | 0     | 0      | 0     | `lab`: 100 Hz, mains (50 Hz) lamps flicker at twice the line frequency |
//! | `flicker_depth`            | 0     | 0      | 0     | `lab`: 0.15, lit intensity × (1 + d·sin 2πft): the light dips ln(1/0.85) = 0.16 below its mean, so the ~10 % of pixels whose OFF threshold is below that lock on and fire ON and OFF every period (≈ 20 Mev/s at 1280×720); the rest stay silent until noise moves their reference |
//! | `c_pos`, `c_neg` (log)     | 0.2   | 0.2    | 0.2   | v2e CLI θ± 0.2; Prophesee presets θ 0.2                 |
//! | `sigma_c` (log)            | 0.02  | 0.03   | 0.05  | v2e `clean` 0.02 (ESIM default 0.021); v2e CLI 0.03; v2e/Prophesee `noisy` 0.05 |
//! | `refractory_us`            | 0     | 100    | 100   | ESIM default 0; ~100 µs for IMX636 is an engineering choice (v2e CLI uses 500 µs) |
//! | `leak_rate_hz`             | 0     | 0.1    | 0.1   | v2e `noisy` and Prophesee `noisy` 0.1 Hz                |
//! | `shot_noise_rate_hz`       | 0     | 0.1    | 5     | v2e `noisy` 5 Hz (Prophesee `noisy` 10 Hz); 0.1 Hz for IMX636 sits between Prophesee `intermediate` (0.01) and `noisy` — unverified against a datasheet |
//! | `log_eps`                  | 1e-3  | 1e-3   | 1e-3  | ESIM `log_eps` 0.001 (Prophesee uses 1e-5 on a [0,1] scale) |
//! | `leak_rate_spread_decades` | 0     | 0.1    | 0.1   | v2e per-pixel leak factor 10^(0.1·N(0,1))               |
//! | `shot_noise_bright_factor` | 1     | 0.25   | 0.25  | v2e: shot rate falls to ×0.25 at full brightness        |
//!
//! `lab` is `imx636` (its noise and refractory period) plus the hot pixels and mains flicker
//! above: the realism preset of the rendered reference suite. The flicker is applied by
//! [`super::camera::SimCamera`] to every lit surface (object, arms, background), as a factor on
//! the frame at each render time; the bare [`super::EventSimulator`] takes frames as given.
//! A front-end anti-flicker filter should find the fundamental at `flicker_hz`.

use crate::error::{ensure, Result};

/// Parameters of [`super::EventSimulator`]. Thresholds are in natural-log intensity units,
/// rates in hertz per pixel, times in microseconds.
#[derive(Debug, Clone, PartialEq)]
pub struct SimParams {
    /// Nominal ON contrast threshold (log units); each pixel draws its own once.
    pub c_pos: f64,
    /// Nominal OFF contrast threshold (log units, positive).
    pub c_neg: f64,
    /// Standard deviation of the per-pixel threshold mismatch (log units).
    pub sigma_c: f64,
    /// A pixel cannot fire again within this many microseconds of its last event.
    pub refractory_us: i64,
    /// Mean leak-event rate per pixel in a static scene (Hz).
    pub leak_rate_hz: f64,
    /// Spread of the per-pixel leak-rate factor, in decades (log-normal, normalised to mean 1).
    pub leak_rate_spread_decades: f64,
    /// Shot-noise rate per pixel in the dark (Hz), ON and OFF together.
    pub shot_noise_rate_hz: f64,
    /// Shot-noise rate multiplier at intensity 1 (linear in between from 1 at intensity 0);
    /// 1 disables the intensity dependence.
    pub shot_noise_bright_factor: f64,
    /// ε in L = ln(ε + I); bounds the log of black pixels.
    pub log_eps: f64,
    /// Fraction of pixels that are hot (drawn once from the seed), each firing extra shot
    /// noise at `hot_pixel_rate_hz` (Hz, ON and OFF together).
    pub hot_pixel_fraction: f64,
    pub hot_pixel_rate_hz: f64,
    /// Mains flicker of the lighting: lit intensity × (1 + `flicker_depth`·sin(2π·`flicker_hz`·t)),
    /// t in seconds of sensor time. 0 Hz or depth 0 is off. Applied by the rendered camera.
    pub flicker_hz: f64,
    pub flicker_depth: f64,
    /// Seed of every random draw (threshold mismatch, leak factors, shot noise).
    pub seed: u64,
}

/// Names accepted by [`SimParams::preset`].
pub const PRESETS: [&str; 4] = ["clean", "imx636", "noisy", "lab"];

impl Default for SimParams {
    fn default() -> Self {
        Self {
            c_pos: 0.2,
            c_neg: 0.2,
            sigma_c: 0.03,
            refractory_us: 100,
            leak_rate_hz: 0.1,
            leak_rate_spread_decades: 0.1,
            shot_noise_rate_hz: 0.1,
            shot_noise_bright_factor: 0.25,
            log_eps: 1e-3,
            hot_pixel_fraction: 0.0,
            hot_pixel_rate_hz: 0.0,
            flicker_hz: 0.0,
            flicker_depth: 0.0,
            seed: 0,
        }
    }
}

impl SimParams {
    /// One of [`PRESETS`]; `"imx636"` is also [`SimParams::default`].
    pub fn preset(name: &str) -> Result<Self> {
        let base = Self::default();
        match name {
            "imx636" => Ok(base),
            "clean" => Ok(Self {
                sigma_c: 0.02,
                refractory_us: 0,
                leak_rate_hz: 0.0,
                leak_rate_spread_decades: 0.0,
                shot_noise_rate_hz: 0.0,
                shot_noise_bright_factor: 1.0,
                ..base
            }),
            "noisy" => Ok(Self {
                sigma_c: 0.05,
                shot_noise_rate_hz: 5.0,
                ..base
            }),
            "lab" => Ok(Self {
                hot_pixel_fraction: 1e-4,
                hot_pixel_rate_hz: 500.0,
                flicker_hz: 100.0,
                flicker_depth: 0.15,
                ..base
            }),
            _ => Err(crate::Error::InvalidArgument(format!(
                "unknown simulator preset {name:?}; expected one of {PRESETS:?}"
            ))),
        }
    }

    /// Every field finite and in range: thresholds > 0, spreads and rates ≥ 0, ε > 0.
    pub fn validate(&self) -> Result<()> {
        let finite = [
            self.c_pos,
            self.c_neg,
            self.sigma_c,
            self.leak_rate_hz,
            self.leak_rate_spread_decades,
            self.shot_noise_rate_hz,
            self.shot_noise_bright_factor,
            self.log_eps,
            self.hot_pixel_fraction,
            self.hot_pixel_rate_hz,
            self.flicker_hz,
            self.flicker_depth,
        ];
        ensure(finite.iter().all(|v| v.is_finite()), || {
            format!("simulator parameters must be finite: {self:?}")
        })?;
        ensure(self.c_pos > 0.0 && self.c_neg > 0.0, || {
            format!(
                "thresholds must be > 0, got c_pos {} c_neg {}",
                self.c_pos, self.c_neg
            )
        })?;
        ensure(self.sigma_c >= 0.0, || {
            format!("sigma_c must be >= 0, got {}", self.sigma_c)
        })?;
        ensure(self.refractory_us >= 0, || {
            format!("refractory_us must be >= 0, got {}", self.refractory_us)
        })?;
        ensure(
            self.leak_rate_hz >= 0.0 && self.shot_noise_rate_hz >= 0.0,
            || {
                format!(
                    "noise rates must be >= 0, got leak {} Hz shot {} Hz",
                    self.leak_rate_hz, self.shot_noise_rate_hz
                )
            },
        )?;
        // Above a few decades the log-normal factor overflows f32 for some pixels.
        ensure((0.0..=2.0).contains(&self.leak_rate_spread_decades), || {
            format!(
                "leak_rate_spread_decades must be in [0, 2], got {}",
                self.leak_rate_spread_decades
            )
        })?;
        ensure(self.shot_noise_bright_factor >= 0.0, || {
            format!(
                "shot_noise_bright_factor must be >= 0, got {}",
                self.shot_noise_bright_factor
            )
        })?;
        ensure(
            (0.0..=1.0).contains(&self.hot_pixel_fraction) && self.hot_pixel_rate_hz >= 0.0,
            || {
                format!(
                    "hot pixels need a fraction in [0, 1] and a rate >= 0, got {} and {} Hz",
                    self.hot_pixel_fraction, self.hot_pixel_rate_hz
                )
            },
        )?;
        ensure(
            self.flicker_hz >= 0.0 && (0.0..1.0).contains(&self.flicker_depth),
            || {
                format!(
                    "flicker needs a frequency >= 0 Hz and a depth in [0, 1), got {} Hz and {}",
                    self.flicker_hz, self.flicker_depth
                )
            },
        )?;
        ensure(self.log_eps > 0.0, || {
            format!("log_eps must be > 0, got {}", self.log_eps)
        })
    }

    /// The lighting factor at `t_us` (1 without flicker).
    pub fn flicker_gain(&self, t_us: i64) -> f64 {
        if self.flicker_hz == 0.0 || self.flicker_depth == 0.0 {
            return 1.0;
        }
        let phase = 2.0 * std::f64::consts::PI * self.flicker_hz * (t_us as f64 * 1e-6);
        1.0 + self.flicker_depth * phase.sin()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_validate_and_differ_where_documented() {
        for name in PRESETS {
            SimParams::preset(name).unwrap().validate().unwrap();
        }
        let clean = SimParams::preset("clean").unwrap();
        assert_eq!(
            (
                clean.shot_noise_rate_hz,
                clean.leak_rate_hz,
                clean.refractory_us
            ),
            (0.0, 0.0, 0)
        );
        assert_eq!(SimParams::preset("noisy").unwrap().shot_noise_rate_hz, 5.0);
        assert_eq!(SimParams::preset("imx636").unwrap(), SimParams::default());
        let lab = SimParams::preset("lab").unwrap();
        assert_eq!((lab.flicker_hz, lab.flicker_depth), (100.0, 0.15));
        assert_eq!(lab.refractory_us, SimParams::default().refractory_us);
        // 100 Hz: the gain repeats every 10 ms and swings by the depth.
        assert!((lab.flicker_gain(2_500) - 1.15).abs() < 1e-12);
        assert!((lab.flicker_gain(12_500) - 1.15).abs() < 1e-9);
        assert!((lab.flicker_gain(7_500) - 0.85).abs() < 1e-9);
        assert_eq!(SimParams::default().flicker_gain(2_500), 1.0);
        assert!(SimParams::preset("imx999").is_err());
    }

    #[test]
    fn rejects_out_of_range_fields() {
        let ok = SimParams::default();
        let bad = [
            SimParams {
                c_pos: 0.0,
                ..ok.clone()
            },
            SimParams {
                c_neg: -0.1,
                ..ok.clone()
            },
            SimParams {
                sigma_c: f64::NAN,
                ..ok.clone()
            },
            SimParams {
                refractory_us: -1,
                ..ok.clone()
            },
            SimParams {
                leak_rate_hz: -1.0,
                ..ok.clone()
            },
            SimParams {
                shot_noise_rate_hz: f64::INFINITY,
                ..ok.clone()
            },
            SimParams {
                log_eps: 0.0,
                ..ok.clone()
            },
            SimParams {
                leak_rate_spread_decades: 3.0,
                ..ok.clone()
            },
            SimParams {
                shot_noise_bright_factor: -0.5,
                ..ok.clone()
            },
            SimParams {
                hot_pixel_fraction: 1.5,
                ..ok.clone()
            },
            SimParams {
                flicker_depth: 1.0,
                ..ok.clone()
            },
            SimParams {
                flicker_hz: -100.0,
                ..ok.clone()
            },
        ];
        for p in bad {
            assert!(p.validate().is_err(), "{p:?}");
        }
    }
}
