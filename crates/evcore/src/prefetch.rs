//! A cache hint for table lookups whose addresses are known a few events ahead (the undistortion
//! table, SCARF's pixel words): asking early lets the misses overlap the work in between.

/// Hint that `at` will be read soon; never faults, so any address (even past the end) is fine.
/// A no-op off x86_64.
#[inline(always)]
pub(crate) fn prefetch<T>(at: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch has no architectural effect and does not fault on any address.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(at.cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = at;
}
