//! Learning, per spatial leaf, how often to sample the guide rather than the BSDF.
//!
//! A renderer draws a direction from the one-sample mixture `q_a = a·p_g + (1 − a)·p_b` of the
//! guide `p_g` and the BSDF `p_b`, and estimates `∫ f` by `f/q_a`. The estimator's second moment
//!
//! ```text
//!   M(a) = ∫ f²/q_a
//! ```
//!
//! is convex in `a` (`1/q` is convex and `q_a` is affine in `a`), so one Newton step per
//! iteration walks `a` to its minimizer. From samples drawn with any density `q0` (the pdf the
//! renderer recorded), with `d = p_g − p_b`,
//!
//! ```text
//!   M'(a)  = −E_q0[ f²·d / (q_a²·q0) ]
//!   M''(a) = 2·E_q0[ f²·d² / (q_a³·q0) ]        a ← a − M'(a)/M''(a)
//! ```
//!
//! Each spatial leaf accumulates the two sums while recording (lock-free, like the moments) and
//! [`refine`](crate::GuidingField::refine) takes the step, clamped between
//! [`MIN_GUIDE_PROBABILITY`] (0.05) and the configuration's
//! [`max_guide_probability`](crate::GuidingConfig::max_guide_probability) (default
//! [`DEFAULT_MAX_GUIDE_PROBABILITY`], 0.75; at most [`MAX_GUIDE_PROBABILITY`], 0.95), so that
//! both techniques stay in play. The upper bound is the defensive one: the BSDF may be the only
//! technique covering a direction the guide has not learned, and since `q_a ≥ (1 − a)·p_b`,
//!
//! ```text
//!   M(a) ≤ M_bsdf / (1 − a),
//! ```
//!
//! whatever the guide is. The estimates of `M'` and `M''` come from the same heavy-tailed
//! samples: an iteration that missed the rare paths only the BSDF finds sees no reason to keep
//! the BSDF and pushes `a` to its bound, where those paths then weigh `1/(1 − a)` times what they
//! weigh without guiding — 20× at 0.95, 4× at 0.75. A leaf with fewer than
//! `MIN_SELECTION_SAMPLES` (32) mixture samples in an iteration keeps its probability; a new
//! leaf starts at ½ (children after a spatial split start from their parent's).

use crate::moments::AtomicF64;
use std::sync::atomic::{AtomicU64, Ordering};

/// The smallest guide probability the selection learns.
pub const MIN_GUIDE_PROBABILITY: f32 = 0.05;
/// The largest guide probability any configuration lets a leaf learn (the BSDF keeps at least
/// 5%), and the largest a cache may hold.
pub const MAX_GUIDE_PROBABILITY: f32 = 0.95;
/// The default of [`GuidingConfig::max_guide_probability`](crate::GuidingConfig::max_guide_probability).
pub const DEFAULT_MAX_GUIDE_PROBABILITY: f32 = 0.75;
/// The guide probability of a leaf that has learned nothing yet.
pub const INITIAL_GUIDE_PROBABILITY: f32 = 0.5;
/// Mixture samples a leaf needs in an iteration before it takes a Newton step.
pub(crate) const MIN_SELECTION_SAMPLES: u64 = 32;

/// A spatial leaf's guide probability and the sums of the current iteration.
#[derive(Debug)]
pub(crate) struct GuideSelection {
    /// `a`: what queries read during the iteration.
    pub(crate) probability: f32,
    /// `Σ f²·d/(q_a²·q0)`, an estimate of `−N·M'(a)`.
    gradient: AtomicF64,
    /// `Σ f²·d²/(q_a³·q0)`, an estimate of `N·M''(a)/2`.
    curvature: AtomicF64,
    count: AtomicU64,
}

/// The sums a leaf recorded, as caches and merges see them.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct SelectionSums {
    pub gradient: f64,
    pub curvature: f64,
    pub count: u64,
}

impl Default for GuideSelection {
    fn default() -> Self {
        Self::from_parts(INITIAL_GUIDE_PROBABILITY, SelectionSums::default())
    }
}

impl Clone for GuideSelection {
    fn clone(&self) -> Self {
        Self::from_parts(self.probability, self.sums())
    }
}

impl GuideSelection {
    pub(crate) fn from_parts(probability: f32, s: SelectionSums) -> Self {
        Self {
            probability,
            gradient: AtomicF64::new(s.gradient),
            curvature: AtomicF64::new(s.curvature),
            count: AtomicU64::new(s.count),
        }
    }

    pub(crate) fn sums(&self) -> SelectionSums {
        SelectionSums {
            gradient: self.gradient.get(),
            curvature: self.curvature.get(),
            count: self.count.load(Ordering::Relaxed),
        }
    }

    /// Adds one sample: integrand `f`, the two techniques' pdfs, and the density `q0` it was
    /// drawn with (all checked finite, `q0 > 0`, by [`Sample::check`](crate::Sample::check)).
    /// Terms too large for `f64` saturate.
    #[inline]
    pub(crate) fn record(&self, f: f32, bsdf_pdf: f32, guide_pdf: f32, q0: f32) {
        let a = f64::from(self.probability);
        let (pb, pg) = (f64::from(bsdf_pdf), f64::from(guide_pdf));
        let d = pg - pb;
        let q = a * pg + (1.0 - a) * pb;
        let f2 = f64::from(f) * f64::from(f);
        if f2 > 0.0 && d != 0.0 && q > 0.0 {
            let g = f2 * d / (q * q * f64::from(q0));
            self.gradient.add(g.clamp(-f64::MAX, f64::MAX));
            self.curvature.add((g * d / q).min(f64::MAX));
        }
        self.count.fetch_add(1, Ordering::Relaxed);
    }

    /// Ends an iteration: one Newton step, `a ← a + gradient / (2·curvature)`, clamped to
    /// `[MIN_GUIDE_PROBABILITY, max]`, if the leaf saw enough samples with a positive
    /// curvature; then the sums restart.
    pub(crate) fn step(&mut self, max: f32) {
        let s = self.sums();
        if s.count >= MIN_SELECTION_SAMPLES && s.curvature > 0.0 && s.curvature.is_finite() {
            let next = f64::from(self.probability) + s.gradient / (2.0 * s.curvature);
            if next.is_finite() {
                self.probability = next as f32;
            }
        }
        // Also a leaf that learned nothing obeys the bound.
        self.probability = self.probability.clamp(MIN_GUIDE_PROBABILITY, max);
        *self = Self::from_parts(self.probability, SelectionSums::default());
    }

    /// Adds another leaf's sums (merging workers), saturating.
    pub(crate) fn add_sums(&mut self, s: SelectionSums) {
        let mine = self.sums();
        *self = Self::from_parts(
            self.probability,
            SelectionSums {
                gradient: (mine.gradient + s.gradient).clamp(-f64::MAX, f64::MAX),
                curvature: (mine.curvature + s.curvature).min(f64::MAX),
                count: mine.count.saturating_add(s.count),
            },
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn newton_steps_reach_the_closed_form_of_disjoint_techniques() {
        // The guide covers [0, 1/2) of a unit domain with density 2, the BSDF [1/2, 1) with
        // density 2; f = c1 on the first half and c2 on the second. Then
        // M(a) = c1²/(4a) + c2²/(4(1−a)), minimized at a* = c1/(c1 + c2). Sampling each half
        // exactly in proportion (a quadrature, not random draws), the steps converge.
        let (c1, c2) = (3.0f32, 1.0f32);
        let mut sel = GuideSelection::default();
        for _ in 0..12 {
            let n = 1000;
            for i in 0..n {
                let x = (i as f32 + 0.5) / n as f32;
                let (f, pg, pb) = if x < 0.5 {
                    (c1, 2.0, 0.0)
                } else {
                    (c2, 0.0, 2.0)
                };
                sel.record(f, pb, pg, 1.0); // uniform over the domain: q0 = 1
            }
            sel.step(MAX_GUIDE_PROBABILITY);
        }
        let expected = c1 / (c1 + c2);
        assert!(
            (sel.probability - expected).abs() < 1e-4,
            "{} vs {expected}",
            sel.probability
        );
    }

    #[test]
    fn the_probability_stays_within_its_bounds_and_sparse_leaves_wait() {
        let mut sel = GuideSelection::default();
        // Only the guide covers the integrand: the optimum is a = 1, clamped.
        for _ in 0..10 {
            for _ in 0..100 {
                sel.record(1.0, 0.0, 1.0, 1.0);
            }
            sel.step(MAX_GUIDE_PROBABILITY);
        }
        assert_eq!(sel.probability, MAX_GUIDE_PROBABILITY);
        // The same under the default bound, which a leaf holding more falls to even without
        // samples.
        let mut sel = GuideSelection::default();
        for _ in 0..100 {
            sel.record(1.0, 0.0, 1.0, 1.0);
        }
        sel.step(DEFAULT_MAX_GUIDE_PROBABILITY);
        assert_eq!(sel.probability, DEFAULT_MAX_GUIDE_PROBABILITY);
        let mut sel = GuideSelection::from_parts(0.9, SelectionSums::default());
        sel.step(DEFAULT_MAX_GUIDE_PROBABILITY);
        assert_eq!(sel.probability, DEFAULT_MAX_GUIDE_PROBABILITY);
        let mut sel = GuideSelection::default();
        for _ in 0..MIN_SELECTION_SAMPLES - 1 {
            sel.record(1.0, 0.0, 1.0, 1.0);
        }
        sel.step(MAX_GUIDE_PROBABILITY);
        assert_eq!(sel.probability, INITIAL_GUIDE_PROBABILITY);
        // Huge values saturate instead of poisoning the sums.
        let mut sel = GuideSelection::default();
        for _ in 0..100 {
            sel.record(f32::MAX, 0.0, f32::MAX, f32::MIN_POSITIVE);
        }
        sel.step(MAX_GUIDE_PROBABILITY);
        assert!(sel.probability.is_finite());
    }
}
