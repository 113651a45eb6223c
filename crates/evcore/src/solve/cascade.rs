//! Which solver runs at each update: EDFT⁺ interleaves one LM step with N search steps (Section
//! III-B-c); EDOPTS searches only; EDFT registers only.

use crate::error::{Error, Result};

/// EDFT⁺'s search steps on an outline cut by the image border move only when their best candidate
/// beats the null one by this many standard errors of the per-point gains (issue 13: noise-level
/// wins ratcheted small, far objects at the image border to 60 mm / 13°).
pub const EDFT_PLUS_SEARCH_MIN_T: f32 = 3.0;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SolverMode {
    /// The cascade: 1 pyramidal LM step, then `n_search` hypothesis-search steps.
    EdftPlus,
    /// Hypothesis search only (EDOPT's paradigm on the SCARF front-end).
    Edopts,
    /// Pyramidal LM only (EDFT's paradigm).
    Edft,
}

impl SolverMode {
    /// Every mode, in the order of [`SolverMode::NAMES`].
    pub const ALL: [Self; 3] = [Self::EdftPlus, Self::Edopts, Self::Edft];
    /// The accepted names, one per mode: the only spellings [`SolverMode::parse`] takes (the
    /// bindings hand this list to Python for its command-line choices).
    pub const NAMES: [&'static str; 3] = ["edft+", "edopts", "edft"];

    pub fn parse(name: &str) -> Result<Self> {
        Self::ALL
            .into_iter()
            .find(|m| m.name() == name)
            .ok_or_else(|| {
                Error::InvalidArgument(format!(
                    "unknown solver {name:?}; choose one of {}",
                    Self::NAMES.join(", ")
                ))
            })
    }

    /// The significance a search step's best candidate needs by default before the step moves (see
    /// [`crate::solve::search::search_step`]): [`EDFT_PLUS_SEARCH_MIN_T`] in the cascade, where LM
    /// does the fine registration and a noisy search step can only push the pose along directions
    /// LM sees weakly; 0 (the paper's plain argmin) where the search is the whole solver.
    pub fn default_search_min_t(self) -> f32 {
        match self {
            Self::EdftPlus => EDFT_PLUS_SEARCH_MIN_T,
            Self::Edopts | Self::Edft => 0.0,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::EdftPlus => "edft+",
            Self::Edopts => "edopts",
            Self::Edft => "edft",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StepKind {
    Lm,
    Search,
}

/// The fixed-ratio schedule; one cycle is N + 1 steps in every mode.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Schedule {
    pub mode: SolverMode,
    pub n_search: usize,
    position: usize,
}

impl Schedule {
    pub fn new(mode: SolverMode, n_search: usize) -> Result<Self> {
        if n_search == 0 && mode == SolverMode::EdftPlus {
            return Err(Error::InvalidArgument(
                "edft+ needs at least one search step per LM step".into(),
            ));
        }
        if n_search > 1000 {
            return Err(Error::InvalidArgument(format!(
                "n_search {n_search} is unreasonably large (max 1000)"
            )));
        }
        Ok(Self {
            mode,
            n_search,
            position: 0,
        })
    }

    pub fn cycle_len(&self) -> usize {
        self.n_search + 1
    }

    /// The kind of the next step; advances the schedule.
    pub fn next_step(&mut self) -> StepKind {
        let kind = match self.mode {
            SolverMode::Edft => StepKind::Lm,
            SolverMode::Edopts => StepKind::Search,
            SolverMode::EdftPlus if self.position == 0 => StepKind::Lm,
            SolverMode::EdftPlus => StepKind::Search,
        };
        self.position = (self.position + 1) % self.cycle_len();
        kind
    }

    /// Restart at the beginning of a cycle (after a reset of the pose).
    pub fn restart(&mut self) {
        self.position = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edft_plus_runs_one_lm_then_n_searches() {
        let mut s = Schedule::new(SolverMode::EdftPlus, 4).unwrap();
        let kinds: Vec<_> = (0..10).map(|_| s.next_step()).collect();
        use StepKind::*;
        assert_eq!(
            kinds,
            [Lm, Search, Search, Search, Search, Lm, Search, Search, Search, Search]
        );
        let mut e = Schedule::new(SolverMode::Edopts, 4).unwrap();
        assert!((0..5).all(|_| e.next_step() == Search));
        assert!(Schedule::new(SolverMode::EdftPlus, 0).is_err());
        for (mode, name) in SolverMode::ALL.into_iter().zip(SolverMode::NAMES) {
            assert_eq!(SolverMode::parse(name).unwrap(), mode);
            assert_eq!(mode.name(), name);
        }
        // Only the cascade asks its search steps for a significant win by default.
        assert_eq!(SolverMode::EdftPlus.default_search_min_t(), 3.0);
        assert_eq!(SolverMode::Edopts.default_search_min_t(), 0.0);
        assert_eq!(SolverMode::Edft.default_search_min_t(), 0.0);
        // One spelling per solver: no case or alias variants.
        for other in ["EDFT+", "edftplus", "edopt", "icp"] {
            assert!(SolverMode::parse(other).is_err(), "{other}");
        }
    }
}
