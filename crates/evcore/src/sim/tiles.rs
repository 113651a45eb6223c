//! Bookkeeping of [`super::camera::SimCamera`]'s sparse frames: which canvas pixels each raw
//! tile reads, and which canvas cells each mesh covers.
//!
//! A raw tile ([`super::TILE_PX`] square) can only change between two frames if its canvas box
//! (every bilinear tap of its pixels) holds a background edge at either frame or meets a mesh
//! that moved, at either pose. Meshes are tracked on a grid of [`CELL_PX`]-square canvas cells,
//! marked from the rasterizer's per-triangle screen boxes, which are exact bounds after
//! near-plane clipping (unlike projected vertices, which say nothing once a mesh reaches behind
//! the camera).

use crate::sim::TILE_PX;

/// Side of a coverage cell, canvas pixels.
pub const CELL_PX: usize = 8;

/// Inclusive canvas pixel box [x0, x1] × [y0, y1].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CanvasBox {
    pub x0: usize,
    pub y0: usize,
    pub x1: usize,
    pub y1: usize,
}

impl CanvasBox {
    pub fn width(&self) -> usize {
        self.x1 - self.x0 + 1
    }

    pub fn height(&self) -> usize {
        self.y1 - self.y0 + 1
    }

    pub fn corners(&self) -> [(usize, usize); 4] {
        [
            (self.x0, self.y0),
            (self.x1, self.y0),
            (self.x0, self.y1),
            (self.x1, self.y1),
        ]
    }
}

/// The canvas box of each raw tile (row-major over the tiles), `None` where no pixel of the
/// tile has a tap: such a tile is black forever. `map` is the raw grid's remap table
/// (`width`×`height`, NaN where a pixel sees nothing) into a `cw`×`ch` canvas.
pub fn tile_boxes(
    map: &[[f32; 2]],
    width: usize,
    height: usize,
    cw: usize,
    ch: usize,
) -> Vec<Option<CanvasBox>> {
    let t = TILE_PX as usize;
    let (tx, ty) = (width.div_ceil(t), height.div_ceil(t));
    (0..tx * ty)
        .map(|k| {
            let (x0, y0) = ((k % tx) * t, (k / tx) * t);
            let (mut lo_u, mut lo_v, mut hi_u, mut hi_v) = (f32::MAX, f32::MAX, f32::MIN, f32::MIN);
            for y in y0..(y0 + t).min(height) {
                for &[u, v] in &map[y * width + x0..y * width + (x0 + t).min(width)] {
                    // NaN compares false and drops out.
                    lo_u = lo_u.min(u);
                    lo_v = lo_v.min(v);
                    hi_u = hi_u.max(u);
                    hi_v = hi_v.max(v);
                }
            }
            // The bilinear taps of (u, v) are floor(u) and floor(u) + 1 (clamped to the canvas).
            (lo_u <= hi_u).then(|| CanvasBox {
                x0: (lo_u.max(0.0).floor() as usize).min(cw - 1),
                y0: (lo_v.max(0.0).floor() as usize).min(ch - 1),
                x1: (hi_u.max(0.0).floor() as usize + 1).min(cw - 1),
                y1: (hi_v.max(0.0).floor() as usize + 1).min(ch - 1),
            })
        })
        .collect()
}

/// Which coverage cells each mesh of a scene may draw into, at one set of poses.
#[derive(Debug, Clone, Default)]
pub struct Coverage {
    gw: usize,
    gh: usize,
    /// One mask of gw×gh cells per mesh.
    masks: Vec<Vec<bool>>,
}

impl Coverage {
    /// Empty coverage of `n_meshes` meshes on a `cw`×`ch` canvas.
    pub fn new(n_meshes: usize, cw: usize, ch: usize) -> Self {
        let (gw, gh) = (cw.div_ceil(CELL_PX), ch.div_ceil(CELL_PX));
        Self {
            gw,
            gh,
            masks: vec![vec![false; gw * gh]; n_meshes],
        }
    }

    /// Clear, then mark the cells of every (mesh, [x_lo, x_hi, y_lo, y_hi]) triangle box
    /// (inclusive canvas pixels, inside the canvas).
    pub fn mark(&mut self, boxes: impl Iterator<Item = (u32, [i64; 4])>) {
        self.masks.iter_mut().for_each(|m| m.fill(false));
        let c = CELL_PX as i64;
        for (mesh, [x_lo, x_hi, y_lo, y_hi]) in boxes {
            let mask = &mut self.masks[mesh as usize];
            for gy in (y_lo / c)..=(y_hi / c) {
                let row = gy as usize * self.gw;
                mask[row + (x_lo / c) as usize..=row + (x_hi / c) as usize].fill(true);
            }
        }
    }

    /// The cells of meshes `which` in `self` or `other` (same grid), as one mask.
    pub fn union_with(&self, other: &Self, which: impl Fn(usize) -> bool) -> Vec<bool> {
        let mut out = vec![false; self.gw * self.gh];
        for (m, (a, b)) in self.masks.iter().zip(&other.masks).enumerate() {
            if which(m) {
                for ((o, &x), &y) in out.iter_mut().zip(a).zip(b) {
                    *o |= x | y;
                }
            }
        }
        out
    }

    /// Whether `mask` (a union from [`Self::union_with`]) has a cell meeting canvas box `b`.
    pub fn meets(&self, mask: &[bool], b: &CanvasBox) -> bool {
        (b.y0 / CELL_PX..=b.y1 / CELL_PX).any(|gy| {
            mask[gy * self.gw + b.x0 / CELL_PX..=gy * self.gw + b.x1 / CELL_PX]
                .iter()
                .any(|&v| v)
        })
    }
}
