//! Where the decoders' hot loops write events: raw slots past the end of columns
//! ([`EventBatch`]) or of records (`Vec<EventCd>`), so that a file decodes straight into the
//! layout its reader hands out, without a second pass.

use crate::{EventBatch, EventCd};

/// Raw output slots a hot loop writes into by index.
pub trait Slots: Copy {
    /// Write event `i`.
    ///
    /// # Safety
    /// Slot `i` must lie inside the room reserved by [`DecodeTarget::reserve_slots`].
    unsafe fn put(self, i: usize, x: u16, y: u16, p: i16, t: i64);

    /// Write event `i` from `xyp` = x | y << 16 | p << 32 (bits 48..64 zero): the first 8
    /// bytes of an [`EventCd`] read as a little-endian u64, so that a record is two stores.
    ///
    /// # Safety
    /// As for [`Slots::put`].
    #[inline(always)]
    unsafe fn put_packed(self, i: usize, xyp: u64, t: i64) {
        self.put(i, xyp as u16, (xyp >> 16) as u16, (xyp >> 32) as i16, t);
    }
}

/// An output a decoder appends to: reserve room, write slots, commit how many were written.
pub trait DecodeTarget {
    type Slots: Slots;
    /// Events already in the output.
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Make room for `room` more events and return the slots past the current end.
    fn reserve_slots(&mut self, room: usize) -> Self::Slots;
    /// Extend the output by the first `n` slots past its end.
    ///
    /// # Safety
    /// Those `n` slots must have been reserved and written.
    unsafe fn commit(&mut self, n: usize);
}

/// Slots of the four columns of an [`EventBatch`].
#[derive(Clone, Copy)]
pub struct ColumnSlots {
    x: *mut u16,
    y: *mut u16,
    p: *mut i16,
    t: *mut i64,
}

impl Slots for ColumnSlots {
    #[inline(always)]
    unsafe fn put(self, i: usize, x: u16, y: u16, p: i16, t: i64) {
        *self.x.add(i) = x;
        *self.y.add(i) = y;
        *self.p.add(i) = p;
        *self.t.add(i) = t;
    }
}

impl DecodeTarget for EventBatch {
    type Slots = ColumnSlots;

    fn len(&self) -> usize {
        self.x.len()
    }

    fn reserve_slots(&mut self, room: usize) -> ColumnSlots {
        debug_assert!([self.y.len(), self.p.len(), self.t_us.len()] == [self.x.len(); 3]);
        self.x.reserve(room);
        self.y.reserve(room);
        self.p.reserve(room);
        self.t_us.reserve(room);
        let n = self.x.len();
        // SAFETY: each column has capacity >= n + room, so these point inside (or one past) it.
        unsafe {
            ColumnSlots {
                x: self.x.as_mut_ptr().add(n),
                y: self.y.as_mut_ptr().add(n),
                p: self.p.as_mut_ptr().add(n),
                t: self.t_us.as_mut_ptr().add(n),
            }
        }
    }

    unsafe fn commit(&mut self, n: usize) {
        let len = self.x.len() + n;
        self.x.set_len(len);
        self.y.set_len(len);
        self.p.set_len(len);
        self.t_us.set_len(len);
    }
}

/// Slots of contiguous [`EventCd`] records: one 16-byte store per event.
#[derive(Clone, Copy)]
pub struct RecordSlots(*mut EventCd);

impl Slots for RecordSlots {
    #[inline(always)]
    unsafe fn put(self, i: usize, x: u16, y: u16, p: i16, t: i64) {
        self.0.add(i).write(EventCd::new(x, y, p, t));
    }

    #[inline(always)]
    unsafe fn put_packed(self, i: usize, xyp: u64, t: i64) {
        if cfg!(target_endian = "little") {
            // EventCd is x, y, p, pad (2 bytes each), then t: on a little-endian machine its
            // first 8 bytes are `xyp`. It is 8-aligned, so the slot is a valid [u64; 2].
            self.0.add(i).cast::<[u64; 2]>().write([xyp, t as u64]);
        } else {
            self.put(i, xyp as u16, (xyp >> 16) as u16, (xyp >> 32) as i16, t);
        }
    }
}

impl DecodeTarget for Vec<EventCd> {
    type Slots = RecordSlots;

    fn len(&self) -> usize {
        Vec::len(self)
    }

    fn reserve_slots(&mut self, room: usize) -> RecordSlots {
        self.reserve(room);
        // SAFETY: capacity >= len + room.
        RecordSlots(unsafe { self.as_mut_ptr().add(Vec::len(self)) })
    }

    unsafe fn commit(&mut self, n: usize) {
        self.set_len(Vec::len(self) + n);
    }
}
