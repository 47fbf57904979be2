//! Variance-optimal selection probabilities for a mixture of sampling techniques (the paper's
//! section 3).
//!
//! An integrand `f = Σ_i α_i f_i` is estimated by picking technique `i` with probability `α̃_i`,
//! drawing `x ~ g_i`, and weighting by `(α_i/α̃_i) · f_i(x)/g_i(x)`. The estimator's second
//! moment is `Σ_i m_i / α̃_i` with
//!
//! ```text
//!   m_i = α_i² ∫ f_i²/g_i = E_{g_i}[ (α_i f_i/g_i)² ]
//! ```
//!
//! and it is smallest for `α̃_i = sqrt(m_i) / Σ_j sqrt(m_j)` (eq. 31) — not for the customary
//! `α̃_i = α_i`. [`TechniqueProbabilities`] estimates each `m_i` online from the weights `w = α_i f_i/g_i` of
//! the samples technique `i` produced (an unbiased estimate whatever `α̃` they were drawn with)
//! and returns those probabilities. Uses: choosing among lights, among BSDF lobes, between any
//! partitioned techniques.
//!
//! A defensive floor keeps every probability at least `floor`: a technique that has seen only
//! zeros so far may still contribute, and a zero probability there would bias the estimate.

use crate::moments::AtomicMoments;
use std::fmt;

/// Samples a technique needs before its second moment is trusted; until then it is treated as
/// the most important technique seen so far, so that it keeps being tried.
pub const MIN_TECHNIQUE_SAMPLES: u64 = 32;

/// Why [`TechniqueProbabilities`] refused its arguments.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum TechniqueError {
    /// [`TechniqueProbabilities::new`] was asked for no technique.
    NoTechniques,
    /// The floor is not in `(0, 1/techniques]`.
    FloorOutOfRange {
        /// The floor asked for.
        floor: f64,
        /// The number of techniques.
        techniques: usize,
    },
    /// A weight was recorded for a technique index past the last one.
    UnknownTechnique {
        /// The index given.
        technique: usize,
        /// The number of techniques.
        techniques: usize,
    },
    /// A recorded weight was negative or not finite.
    BadWeight {
        /// The weight given.
        weight: f32,
    },
}

impl fmt::Display for TechniqueError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::NoTechniques => write!(f, "a selection needs at least one technique"),
            Self::FloorOutOfRange { floor, techniques } => {
                write!(f, "floor {floor} is not in (0, 1/{techniques}]")
            }
            Self::UnknownTechnique {
                technique,
                techniques,
            } => write!(f, "technique {technique} of {techniques}"),
            Self::BadWeight { weight } => {
                write!(f, "weight {weight} is negative or not finite")
            }
        }
    }
}

impl std::error::Error for TechniqueError {}

/// Online, thread-safe estimator of variance-optimal technique selection probabilities.
///
/// ```
/// use sdguide::TechniqueProbabilities;
/// let selection = TechniqueProbabilities::new(2, 0.05)?;
/// // Technique 0 produced weights of 4, technique 1 weights of 1 (α_i f_i/g_i, per sample).
/// for _ in 0..100 {
///     selection.record(0, 4.0)?;
///     selection.record(1, 1.0)?;
/// }
/// let p = selection.probabilities();
/// // sqrt(m) = 4 and 1: 0.05 + 0.9 · 4/5 = 0.77 and 0.05 + 0.9 · 1/5 = 0.23.
/// assert!((p[0] - 0.77).abs() < 1e-12 && (p[1] - 0.23).abs() < 1e-12);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug)]
pub struct TechniqueProbabilities {
    techniques: Box<[AtomicMoments]>,
    floor: f64,
}

impl TechniqueProbabilities {
    /// A selection among `techniques` techniques (at least 1), each kept at probability
    /// `floor` or more; `floor` must be in `(0, 1/techniques]` (at `1/techniques` the
    /// selection is uniform).
    ///
    /// # Errors
    ///
    /// [`TechniqueError::NoTechniques`] when `techniques` is 0,
    /// [`TechniqueError::FloorOutOfRange`] when `floor` is out of range.
    pub fn new(techniques: usize, floor: f64) -> Result<Self, TechniqueError> {
        if techniques == 0 {
            return Err(TechniqueError::NoTechniques);
        }
        if !(floor > 0.0 && floor * techniques as f64 <= 1.0) {
            return Err(TechniqueError::FloorOutOfRange { floor, techniques });
        }
        Ok(Self {
            techniques: (0..techniques).map(|_| AtomicMoments::default()).collect(),
            floor,
        })
    }

    /// Records the weight `α_i · f_i(x)/g_i(x)` of a sample `x` that technique `i` drew (without
    /// the selection factor `1/α̃_i`). Any number of threads may record at once.
    ///
    /// # Errors
    ///
    /// [`TechniqueError::BadWeight`] when the weight is negative or not finite,
    /// [`TechniqueError::UnknownTechnique`] when the index is out of range; nothing is
    /// recorded then.
    pub fn record(&self, technique: usize, weight: f32) -> Result<(), TechniqueError> {
        if !(weight >= 0.0 && weight.is_finite()) {
            return Err(TechniqueError::BadWeight { weight });
        }
        let slot = self
            .techniques
            .get(technique)
            .ok_or(TechniqueError::UnknownTechnique {
                technique,
                techniques: self.techniques.len(),
            })?;
        let w = f64::from(weight);
        slot.add((w, w * w));
        Ok(())
    }

    /// The estimated `m_i` of each technique (`None` before it has [`MIN_TECHNIQUE_SAMPLES`] samples).
    pub fn second_moments(&self) -> Vec<Option<f64>> {
        self.techniques
            .iter()
            .map(|t| {
                let m = t.get();
                (m.count >= MIN_TECHNIQUE_SAMPLES).then(|| m.sum_sq / m.count as f64)
            })
            .collect()
    }

    /// The selection probabilities `α̃_i = floor + (1 − n·floor) · sqrt(m_i)/Σ_j sqrt(m_j)`;
    /// they sum to 1 and each lies in `[floor, 1]`. A technique without enough samples counts as
    /// the largest `sqrt(m)` seen; with no information at all the selection is uniform.
    pub fn probabilities(&self) -> Vec<f64> {
        let roots: Vec<Option<f64>> = self
            .second_moments()
            .into_iter()
            .map(|m| m.map(f64::sqrt))
            .collect();
        let known_max = roots.iter().flatten().copied().fold(0.0, f64::max);
        let n = roots.len() as f64;
        let weights: Vec<f64> = roots.iter().map(|r| r.unwrap_or(known_max)).collect();
        let total: f64 = weights.iter().sum();
        if !(total > 0.0 && total.is_finite()) {
            return vec![1.0 / n; roots.len()];
        }
        let spread = 1.0 - n * self.floor;
        weights
            .iter()
            .map(|w| self.floor + spread * w / total)
            .collect()
    }

    /// Forgets what was recorded (for instance between training iterations).
    pub fn reset(&mut self) {
        for t in self.techniques.iter_mut() {
            *t = AtomicMoments::default();
        }
    }
}
