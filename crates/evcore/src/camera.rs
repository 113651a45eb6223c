//! Pinhole camera with OpenCV's radial–tangential distortion (k1 k2 p1 p2 k3).
//!
//! Two pixel grids appear in evcore. The *raw* grid is the sensor's, where events arrive and where
//! distortion applies. The *rectified* grid has the same size and the same K but no distortion; the
//! front-ends, the distance field and the solvers all work there, so the solvers project with the
//! pure pinhole model. Events move from raw to rectified through [`UndistortLut`], built once.

use crate::error::{ensure, Result};
use crate::prefetch::prefetch;
use nalgebra::{Matrix2, Vector2, Vector3};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Sensor width and height in pixels.
    pub width: u32,
    pub height: u32,
    /// Focal lengths and principal point in pixels.
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// OpenCV distortion coefficients (k1, k2, p1, p2, k3).
    pub dist: [f64; 5],
}

impl Camera {
    pub fn new(
        width: u32,
        height: u32,
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        dist: [f64; 5],
    ) -> Result<Self> {
        ensure(
            (1..=16384).contains(&width) && (1..=16384).contains(&height),
            || format!("sensor size {width}x{height} must be within 1..=16384 pixels"),
        )?;
        ensure(
            fx.is_finite() && fy.is_finite() && fx > 0.0 && fy > 0.0,
            || format!("focal lengths must be finite and positive, got fx={fx}, fy={fy}"),
        )?;
        ensure(cx.is_finite() && cy.is_finite(), || {
            format!("principal point ({cx}, {cy}) must be finite")
        })?;
        ensure(dist.iter().all(|d| d.is_finite()), || {
            format!("distortion {dist:?} must be finite")
        })?;
        Ok(Self {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            dist,
        })
    }

    /// The same camera after the checks of [`Camera::new`]: the fields are public, so a camera built
    /// by hand is validated where it enters a long-lived object.
    pub fn checked(self) -> Result<Self> {
        Self::new(
            self.width,
            self.height,
            self.fx,
            self.fy,
            self.cx,
            self.cy,
            self.dist,
        )
    }

    /// The Prophesee IMX636 (EVK4) of the paper: 1280×720, calibrated intrinsics, k1 only.
    pub fn imx636() -> Self {
        Self {
            width: 1280,
            height: 720,
            fx: 1163.59,
            fy: 1173.48,
            cx: 658.823,
            cy: 339.619,
            dist: [-0.2819, 0.0, 0.0, 0.0, 0.0],
        }
    }

    /// The same camera without distortion (the rectified grid).
    pub fn rectified(&self) -> Self {
        Self {
            dist: [0.0; 5],
            ..*self
        }
    }

    pub fn n_pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    pub fn has_distortion(&self) -> bool {
        self.dist.iter().any(|&d| d != 0.0)
    }

    /// Camera scaled to pyramid level `level` (image size divided by 2^level). Pixel centres map
    /// as u_l = (u + 0.5) / 2^l − 0.5, so cx, cy shift accordingly.
    pub fn at_level(&self, level: u32) -> Self {
        let s = f64::from(1u32 << level);
        Self {
            width: self.width.div_ceil(1 << level),
            height: self.height.div_ceil(1 << level),
            fx: self.fx / s,
            fy: self.fy / s,
            cx: (self.cx + 0.5) / s - 0.5,
            cy: (self.cy + 0.5) / s - 0.5,
            dist: self.dist,
        }
    }

    /// Apply distortion to normalised coordinates (x, y) = (X/Z, Y/Z), OpenCV convention.
    pub fn distort_normalized(&self, x: f64, y: f64) -> (f64, f64) {
        let [k1, k2, p1, p2, k3] = self.dist;
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        (
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// Jacobian of [`Self::distort_normalized`] with respect to (x, y).
    fn distort_jacobian(&self, x: f64, y: f64) -> Matrix2<f64> {
        let [k1, k2, p1, p2, k3] = self.dist;
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        let dradial_dr2 = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
        let (drx, dry) = (2.0 * x * dradial_dr2, 2.0 * y * dradial_dr2);
        Matrix2::new(
            radial + x * drx + 2.0 * p1 * y + 6.0 * p2 * x,
            x * dry + 2.0 * p1 * x + 2.0 * p2 * y,
            y * drx + 2.0 * p1 * x + 2.0 * p2 * y,
            radial + y * dry + 6.0 * p1 * y + 2.0 * p2 * x,
        )
    }

    /// Invert the distortion: the normalised point whose distorted image is (xd, yd).
    /// Gauss–Newton from (xd, yd); `None` if it does not converge (outside the model's valid range).
    pub fn undistort_normalized(&self, xd: f64, yd: f64) -> Option<(f64, f64)> {
        if !self.has_distortion() {
            return Some((xd, yd));
        }
        let target = Vector2::new(xd, yd);
        let mut p = target;
        for _ in 0..50 {
            let (ux, uy) = self.distort_normalized(p.x, p.y);
            let r = Vector2::new(ux, uy) - target;
            if r.norm() < 1e-12 {
                return Some((p.x, p.y));
            }
            let step = self.distort_jacobian(p.x, p.y).try_inverse()? * r;
            p -= step;
            if !p.x.is_finite() || !p.y.is_finite() {
                return None;
            }
        }
        let (ux, uy) = self.distort_normalized(p.x, p.y);
        ((Vector2::new(ux, uy) - target).norm() < 1e-9).then_some((p.x, p.y))
    }

    /// Project a point in the camera frame (metres) to raw pixels, with distortion.
    /// `None` for points at or behind the camera plane.
    pub fn project(&self, p_c: &Vector3<f64>) -> Option<(f64, f64)> {
        if p_c.z <= 0.0 {
            return None;
        }
        let (xd, yd) = self.distort_normalized(p_c.x / p_c.z, p_c.y / p_c.z);
        Some((self.fx * xd + self.cx, self.fy * yd + self.cy))
    }

    /// Project to the rectified grid (pinhole only).
    pub fn project_pinhole(&self, p_c: &Vector3<f64>) -> Option<(f64, f64)> {
        (p_c.z > 0.0).then(|| {
            (
                self.fx * p_c.x / p_c.z + self.cx,
                self.fy * p_c.y / p_c.z + self.cy,
            )
        })
    }

    /// Raw pixel (u, v) to its rectified position; `None` where the inversion fails.
    pub fn rectify_pixel(&self, u: f64, v: f64) -> Option<(f64, f64)> {
        let (x, y) = self.undistort_normalized((u - self.cx) / self.fx, (v - self.cy) / self.fy)?;
        Some((self.fx * x + self.cx, self.fy * y + self.cy))
    }

    /// Rectified pixel (u, v) to the raw pixel where it is seen.
    pub fn distort_pixel(&self, u: f64, v: f64) -> (f64, f64) {
        let (xd, yd) = self.distort_normalized((u - self.cx) / self.fx, (v - self.cy) / self.fy);
        (self.fx * xd + self.cx, self.fy * yd + self.cy)
    }

    /// Viewing ray through rectified pixel (u, v) at depth z = 1.
    pub fn ray(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0)
    }
}

/// How far ahead [`UndistortLut::map_in_place`] prefetches, in pixels.
const PREFETCH_PIXELS: usize = 16;

/// Raw sensor pixel → rectified pixel index, built once per camera. Pixels whose rectified
/// position falls outside the image map to [`UndistortLut::OUTSIDE`] and their events are dropped.
#[derive(Debug, Clone)]
pub struct UndistortLut {
    pub width: u32,
    pub height: u32,
    /// For raw pixel y·W + x, the rectified pixel index y'·W + x' (rounded to the nearest pixel).
    pub index: Vec<u32>,
}

impl UndistortLut {
    pub const OUTSIDE: u32 = u32::MAX;

    pub fn new(camera: &Camera) -> Self {
        let (w, h) = (camera.width, camera.height);
        let index = (0..camera.n_pixels())
            .map(|i| {
                let (u, v) = ((i % w as usize) as f64, (i / w as usize) as f64);
                match camera.rectify_pixel(u, v) {
                    Some((ur, vr)) => {
                        let (xr, yr) = (ur.round(), vr.round());
                        if xr >= 0.0 && yr >= 0.0 && xr < f64::from(w) && yr < f64::from(h) {
                            yr as u32 * w + xr as u32
                        } else {
                            Self::OUTSIDE
                        }
                    }
                    None => Self::OUTSIDE,
                }
            })
            .collect();
        Self {
            width: w,
            height: h,
            index,
        }
    }

    /// Rectified pixel index of raw pixel (x, y), or `OUTSIDE`. The caller has validated bounds.
    #[inline]
    pub fn map(&self, x: u16, y: u16) -> u32 {
        self.index[self.raw_index(x, y) as usize]
    }

    /// Raw pixel index y·W + x, the input of [`Self::map_in_place`]. The caller has validated
    /// bounds.
    #[inline]
    pub fn raw_index(&self, x: u16, y: u16) -> u32 {
        u32::from(y) * self.width + u32::from(x)
    }

    /// Replace each raw pixel index (from [`Self::raw_index`]) by its rectified index, as
    /// [`Self::map`]. Events scattered over the sensor (a thinned stream, a cluttered scene) each
    /// miss the cache on this 4-byte-per-pixel table (3.7 MB at 1280×720); knowing the indices
    /// in advance, the entry a few events ahead is asked for early so the misses overlap.
    pub fn map_in_place(&self, pixels: &mut [u32]) {
        for i in 0..pixels.len() {
            if let Some(&ahead) = pixels.get(i + PREFETCH_PIXELS) {
                prefetch(self.index.as_ptr().wrapping_add(ahead as usize));
            }
            pixels[i] = self.index[pixels[i] as usize];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_bad_intrinsics() {
        assert!(Camera::new(640, 480, 0.0, 500.0, 320.0, 240.0, [0.0; 5]).is_err());
        assert!(Camera::new(640, 480, 500.0, f64::NAN, 320.0, 240.0, [0.0; 5]).is_err());
        assert!(Camera::new(0, 480, 500.0, 500.0, 320.0, 240.0, [0.0; 5]).is_err());
    }

    #[test]
    fn mapping_in_place_is_the_per_pixel_map() {
        let lut = UndistortLut::new(&Camera::imx636());
        let mut rng = crate::rng::Rng::new(9);
        let raw: Vec<(u16, u16)> = (0..200_000)
            .map(|_| (rng.below(1280) as u16, rng.below(720) as u16))
            .chain([(0, 0), (1279, 719)])
            .collect();
        let mut pixels: Vec<u32> = raw.iter().map(|&(x, y)| lut.raw_index(x, y)).collect();
        lut.map_in_place(&mut pixels);
        // The table's definition: entry y·W + x for raw pixel (x, y).
        let expected: Vec<u32> = raw
            .iter()
            .map(|&(x, y)| lut.index[usize::from(y) * 1280 + usize::from(x)])
            .collect();
        assert_eq!(pixels, expected);
        assert_eq!(pixels[pixels.len() - 1], lut.map(1279, 719));
    }

    #[test]
    fn rectify_inverts_distort_across_the_sensor() {
        let cam = Camera {
            dist: [-0.2819, 0.05, 0.001, -0.002, 0.01],
            ..Camera::imx636()
        };
        for &(u, v) in &[(0.0, 0.0), (1279.0, 719.0), (640.0, 360.0), (100.0, 650.0)] {
            let (ur, vr) = cam.rectify_pixel(u, v).expect("inside the valid range");
            let (ud, vd) = cam.distort_pixel(ur, vr);
            assert!(
                (ud - u).abs() < 1e-6 && (vd - v).abs() < 1e-6,
                "({u},{v}) -> ({ud},{vd})"
            );
        }
    }

    #[test]
    fn lut_maps_centre_to_itself_and_drops_far_corners() {
        let cam = Camera::imx636();
        let lut = UndistortLut::new(&cam);
        let c = lut.map(659, 340);
        assert_eq!((c % 1280, c / 1280), (659, 340));
        // Barrel distortion: the raw corner shows rays beyond the rectified frame.
        assert_eq!(lut.map(0, 0), UndistortLut::OUTSIDE);
    }

    #[test]
    fn pyramid_level_maps_pixel_centres() {
        let cam = Camera::imx636();
        let l2 = cam.at_level(2);
        let p = Vector3::new(0.1, -0.05, 0.8);
        let (u0, v0) = cam.project_pinhole(&p).unwrap();
        let (u2, v2) = l2.project_pinhole(&p).unwrap();
        assert!(((u0 + 0.5) / 4.0 - 0.5 - u2).abs() < 1e-9);
        assert!(((v0 + 0.5) / 4.0 - 0.5 - v2).abs() < 1e-9);
        assert_eq!((l2.width, l2.height), (320, 180));
    }
}
