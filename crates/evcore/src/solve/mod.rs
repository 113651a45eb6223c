//! The solvers of EDFT⁺ on the shared cost of Eq. (1): pyramidal Levenberg–Marquardt ([`lm`]),
//! hypothesis search ([`search`]) and their interleaving ([`cascade`]). All of them only sample a
//! [`cost::CostMap`] at projected model points, so they share one cost surface by construction.

pub mod cascade;
pub mod cost;
pub mod lm;
pub mod search;
#[cfg(target_arch = "x86_64")]
mod star8;

pub use cascade::{Schedule, SolverMode, StepKind};
pub use cost::{CostMap, Pinhole, Rigid32};
pub use lm::{LmParams, LmReport};
pub use search::SearchOutcome;
