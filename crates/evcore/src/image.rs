//! Rectangular regions of the image grid.

/// A rectangle of pixels [x0, x0+width) × [y0, y0+height) in some image grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Roi {
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
}

impl Roi {
    pub fn full(width: u32, height: u32) -> Self {
        Self {
            x0: 0,
            y0: 0,
            width,
            height,
        }
    }

    /// Bounding box of (u, v) samples grown by `margin` pixels and clipped to a `w`×`h` image;
    /// `None` if nothing of it lies inside.
    pub fn around(
        points: impl IntoIterator<Item = (f64, f64)>,
        margin: f64,
        w: u32,
        h: u32,
    ) -> Option<Self> {
        let (mut lo_u, mut lo_v, mut hi_u, mut hi_v) = (
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        );
        for (u, v) in points {
            if u.is_finite() && v.is_finite() {
                lo_u = lo_u.min(u);
                lo_v = lo_v.min(v);
                hi_u = hi_u.max(u);
                hi_v = hi_v.max(v);
            }
        }
        let x0 = (lo_u - margin).floor().max(0.0);
        let y0 = (lo_v - margin).floor().max(0.0);
        let x1 = (hi_u + margin).ceil().min(f64::from(w));
        let y1 = (hi_v + margin).ceil().min(f64::from(h));
        (x1 > x0 && y1 > y0).then_some(Self {
            x0: x0 as u32,
            y0: y0 as u32,
            width: (x1 - x0) as u32,
            height: (y1 - y0) as u32,
        })
    }

    pub fn area(&self) -> usize {
        self.width as usize * self.height as usize
    }

    pub fn contains(&self, x: u32, y: u32) -> bool {
        x >= self.x0 && y >= self.y0 && x < self.x0 + self.width && y < self.y0 + self.height
    }

    /// This region in the grid of pyramid level `level` (coordinates divided by 2^level, outward).
    pub fn at_level(&self, level: u32) -> Self {
        let x0 = self.x0 >> level;
        let y0 = self.y0 >> level;
        let x1 = (self.x0 + self.width).div_ceil(1 << level);
        let y1 = (self.y0 + self.height).div_ceil(1 << level);
        Self {
            x0,
            y0,
            width: x1 - x0,
            height: y1 - y0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn around_clips_and_grows() {
        let r = Roi::around([(10.0, 20.0), (30.0, 25.0)], 5.0, 32, 100).unwrap();
        assert_eq!(
            r,
            Roi {
                x0: 5,
                y0: 15,
                width: 27,
                height: 15
            }
        );
        assert!(Roi::around([(-50.0, -50.0)], 5.0, 32, 32).is_none());
    }

    #[test]
    fn level_covers_the_region() {
        let r = Roi {
            x0: 5,
            y0: 6,
            width: 10,
            height: 3,
        }
        .at_level(2);
        assert_eq!(
            r,
            Roi {
                x0: 1,
                y0: 1,
                width: 3,
                height: 2
            }
        );
    }
}
