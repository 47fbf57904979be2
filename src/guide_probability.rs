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
//!
//! **Where the guide does not pay, it is turned off.** Sampling the guide costs: the renderer
//! evaluates its pdf for every direction the BSDF draws, and draws from it otherwise (on the
//! demo's `door`, a guided vertex costs 1.2–1.3× an unguided one). Where light arrives much as
//! the BSDF samples it — diffuse surfaces lit from all around — the best mixture lowers the
//! variance of the vertex's estimate by little, and the cost is not repaid. With `cost` the
//! guide's extra cost per vertex, relative
//! ([`guide_cost`](crate::GuidingConfig::guide_cost); off by default, since only the renderer
//! can measure it), the
//! vertex's efficiency, 1/(variance × cost), is higher with BSDF sampling alone when
//!
//! ```text
//!   (1 + cost)·V(a) ≥ V(0),        V(a) = M(a) − (∫f)²,
//! ```
//!
//! and every iteration each leaf checks it from three more sums over the same samples, each an
//! unbiased estimate whatever density `q0` drew them (the BSDF alone, where the guide is off):
//!
//! ```text
//!   M(a) ≈ (1/N) Σ f²/(q_a·q0),     M(0) ≈ (1/N) Σ f²/(p_b·q0),     ∫f ≈ (1/N) Σ f/q0.
//! ```
//!
//! A leaf where it holds reads guide probability 0 until an iteration shows the guide paying
//! again: a renderer samples the BSDF alone there and evaluates no guide pdf (the mixture pdf
//! is the BSDF's), unless it records, since the recorded mixture terms need the guide's pdf
//! for the leaf to tell. The Newton steps go on meanwhile. A leaf keeps the guide on where a
//! sample found light the BSDF cannot draw (`p_b = 0`, where BSDF sampling alone would be
//! biased), and decides nothing on fewer than `MIN_VERDICT_SAMPLES` (256) samples. The
//! criterion is the vertex's own: a path's variance also depends on the vertices after it, so
//! the default cost was chosen by the demo's renders (on `door`, half of the vertices lie in
//! leaves whose guide lowers their variance by less than 10%).
//!
//! A leaf where the renderer recorded continuations
//! ([`GuidingField::record_continuation`](crate::GuidingField::record_continuation): it plays
//! the efficiency-aware roulette or splitting of [`splitting`](crate::splitting)) keeps its
//! guide on. There the roulette and splitting factors follow continuation estimates that the
//! guide shapes, and the guide is worth more than its vertices' variance says: with the demo's
//! efficiency-aware roulette, turning guides off by it raised the error per sample (over
//! unguided's with the same roulette) from 0.44 to 0.57 on `door` and from 0.30 to 0.43 on
//! `uplight`, where with classic roulette the error at equal time fell.

use crate::exact::{AtomicSum, MAX_TERM, Signed, Sum};
use std::sync::atomic::{AtomicU64, Ordering};

/// The smallest guide probability the selection learns.
pub const MIN_GUIDE_PROBABILITY: f32 = 0.05;
/// The largest guide probability any configuration lets a leaf learn (the BSDF keeps at least
/// 5%), and the largest a cache may hold.
pub const MAX_GUIDE_PROBABILITY: f32 = 0.95;
/// The default of [`GuidingConfig::max_guide_probability`](crate::GuidingConfig::max_guide_probability).
pub const DEFAULT_MAX_GUIDE_PROBABILITY: f32 = 0.75;
/// The largest [`GuidingConfig::guide_cost`](crate::GuidingConfig::guide_cost) a
/// configuration accepts.
pub const MAX_GUIDE_COST: f32 = 100.0;
/// The guide probability of a leaf that has learned nothing yet.
pub const INITIAL_GUIDE_PROBABILITY: f32 = 0.5;
/// Mixture samples a leaf needs in an iteration before it takes a Newton step.
pub(crate) const MIN_SELECTION_SAMPLES: u64 = 32;
/// Mixture samples a leaf needs in an iteration before it turns its guide off or back on: the
/// two variances it compares come from heavy-tailed sums.
pub(crate) const MIN_VERDICT_SAMPLES: u64 = 256;

/// A spatial leaf's guide probability and the sums of the current iteration.
#[derive(Debug)]
pub(crate) struct GuideSelection {
    /// What queries read during the iteration: the learned `a`, or 0 where the guide is off.
    pub(crate) probability: f32,
    /// The learned `a`, which the Newton steps move (also while the guide is off).
    pub(crate) learned: f32,
    /// `Σ f²·d/(q_a²·q0)`, an estimate of `−N·M'(a)` (signed).
    gradient: AtomicSum,
    /// `Σ f²·d²/(q_a³·q0)`, an estimate of `N·M''(a)/2`.
    curvature: AtomicSum,
    count: AtomicU64,
    /// `Σ f²/(q_a·q0)`, an estimate of `N·M(a)`.
    guided: AtomicSum,
    /// `Σ f²/(p_b·q0)` over the samples with `p_b > 0`, an estimate of `N·M(0)`.
    bsdf: AtomicSum,
    /// `Σ f/q0`, an estimate of `N·∫f`.
    first: AtomicSum,
    /// Samples with `f ≠ 0` where `p_b = 0`: light BSDF sampling alone would never find.
    uncovered: AtomicU64,
}

/// The sums a leaf recorded, as caches and merges see them (exact: see [`crate::exact`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct SelectionSums {
    pub gradient: Signed,
    pub curvature: Sum,
    pub count: u64,
    /// `Σ f²/(q_a·q0)`.
    pub guided: Sum,
    /// `Σ f²/(p_b·q0)`.
    pub bsdf: Sum,
    /// `Σ f/q0`.
    pub first: Signed,
    pub uncovered: u64,
}

impl SelectionSums {
    /// The sums in range: none without samples.
    pub(crate) fn valid(&self) -> bool {
        let empty = self.gradient.is_zero()
            && self.curvature.is_zero()
            && self.guided.is_zero()
            && self.bsdf.is_zero()
            && self.first.is_zero()
            && self.uncovered == 0;
        self.count > 0 || empty
    }

    /// Both leaves' sums (merging workers): exact, in any order.
    pub(crate) fn plus(&self, s: &SelectionSums) -> SelectionSums {
        SelectionSums {
            gradient: self.gradient.plus(s.gradient),
            curvature: self.curvature.plus(s.curvature),
            count: self.count.saturating_add(s.count),
            guided: self.guided.plus(s.guided),
            bsdf: self.bsdf.plus(s.bsdf),
            first: self.first.plus(s.first),
            uncovered: self.uncovered.saturating_add(s.uncovered),
        }
    }

    /// Whether sampling the guide does not pay for its cost: whether the variance of the
    /// mixture's estimate `f/q_a` is at least `1/(1 + cost)` of BSDF sampling's alone, `f/p_b`
    /// (`cost`: the guide's extra cost per sample, relative). `None` with too few samples to
    /// tell.
    fn guide_idle(&self, cost: f32) -> Option<bool> {
        if self.count < MIN_VERDICT_SAMPLES {
            return None;
        }
        if self.uncovered > 0 {
            return Some(false);
        }
        let n = self.count as f64;
        let mean = self.first.value() / n;
        let variance = |second: Sum| (second.value() / n - mean * mean).max(0.0);
        Some(variance(self.guided) * (1.0 + f64::from(cost)) >= variance(self.bsdf))
    }
}

impl Default for GuideSelection {
    fn default() -> Self {
        Self::from_parts(INITIAL_GUIDE_PROBABILITY, false, SelectionSums::default())
    }
}

impl Clone for GuideSelection {
    fn clone(&self) -> Self {
        Self::from_parts(self.learned, self.off(), self.sums())
    }
}

impl GuideSelection {
    /// The selection with learned probability `learned`, the guide off if `off`, and sums `s`.
    pub(crate) fn from_parts(learned: f32, off: bool, s: SelectionSums) -> Self {
        Self {
            probability: if off { 0.0 } else { learned },
            learned,
            gradient: AtomicSum::new(s.gradient.units()),
            curvature: AtomicSum::new(s.curvature.units()),
            count: AtomicU64::new(s.count),
            guided: AtomicSum::new(s.guided.units()),
            bsdf: AtomicSum::new(s.bsdf.units()),
            first: AtomicSum::new(s.first.units()),
            uncovered: AtomicU64::new(s.uncovered),
        }
    }

    /// Whether queries are told not to sample the guide (probability 0).
    pub(crate) fn off(&self) -> bool {
        self.probability == 0.0
    }

    pub(crate) fn sums(&self) -> SelectionSums {
        SelectionSums {
            gradient: self.gradient.signed(),
            curvature: self.curvature.sum(),
            count: self.count.load(Ordering::Relaxed),
            guided: self.guided.sum(),
            bsdf: self.bsdf.sum(),
            first: self.first.signed(),
            uncovered: self.uncovered.load(Ordering::Relaxed),
        }
    }

    /// Adds one sample: integrand `f`, the two techniques' pdfs, and the density `q0` it was
    /// drawn with (all checked finite, `q0 > 0`, by [`Sample::check`](crate::Sample::check)).
    /// Returns whether a term was clamped to the sums' range (see [`crate::exact`]).
    #[inline]
    pub(crate) fn record(&self, f: f32, bsdf_pdf: f32, guide_pdf: f32, q0: f32) -> bool {
        let a = f64::from(self.learned);
        let (pb, pg) = (f64::from(bsdf_pdf), f64::from(guide_pdf));
        let d = pg - pb;
        let q = a * pg + (1.0 - a) * pb;
        let (f, q0) = (f64::from(f), f64::from(q0));
        let f2 = f * f;
        let mut largest = 0.0f64;
        if f2 > 0.0 && q > 0.0 {
            let weight = f2 / (q * q0);
            self.guided.add(weight);
            largest = weight;
            if d != 0.0 {
                let g = weight * d / q;
                let c = g * d / q;
                self.gradient.add_signed(g);
                self.curvature.add(c);
                largest = largest.max(g.abs()).max(c);
            }
        }
        if f2 > 0.0 {
            if pb > 0.0 {
                let b = f2 / (pb * q0);
                self.bsdf.add(b);
                largest = largest.max(b);
            } else {
                self.uncovered.fetch_add(1, Ordering::Relaxed);
            }
            self.first.add_signed(f / q0);
            largest = largest.max((f / q0).abs());
        }
        self.count.fetch_add(1, Ordering::Relaxed);
        // NaN (an infinite weight's product) counts as clamped too.
        largest.is_nan() || largest > MAX_TERM
    }

    /// Ends an iteration: one Newton step, `a ← a + gradient / (2·curvature)`, clamped to
    /// `[MIN_GUIDE_PROBABILITY, max]`, if the leaf saw enough samples with a positive
    /// curvature; the guide turned off, or back on, by whether it paid for `cost` in the
    /// iteration (kept as it was without enough samples to tell); then the sums restart.
    pub(crate) fn step(&mut self, max: f32, cost: Option<f32>) {
        let s = self.sums();
        let mut learned = self.learned;
        let curvature = s.curvature.value();
        if s.count >= MIN_SELECTION_SAMPLES && curvature > 0.0 {
            let next = f64::from(learned) + s.gradient.value() / (2.0 * curvature);
            if next.is_finite() {
                learned = next as f32;
            }
        }
        // Also a leaf that learned nothing obeys the bound.
        let learned = learned.clamp(MIN_GUIDE_PROBABILITY, max);
        let verdict = cost.and_then(|c| s.guide_idle(c));
        let off = verdict.unwrap_or(self.off() && cost.is_some());
        *self = Self::from_parts(learned, off, SelectionSums::default());
    }

    /// Adds another leaf's sums (merging workers), exactly.
    pub(crate) fn add_sums(&mut self, s: SelectionSums) {
        *self = Self::from_parts(self.learned, self.off(), self.sums().plus(&s));
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
            sel.step(MAX_GUIDE_PROBABILITY, None);
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
            sel.step(MAX_GUIDE_PROBABILITY, None);
        }
        assert_eq!(sel.probability, MAX_GUIDE_PROBABILITY);
        // The same under the default bound, which a leaf holding more falls to even without
        // samples.
        let mut sel = GuideSelection::default();
        for _ in 0..100 {
            sel.record(1.0, 0.0, 1.0, 1.0);
        }
        sel.step(DEFAULT_MAX_GUIDE_PROBABILITY, None);
        assert_eq!(sel.probability, DEFAULT_MAX_GUIDE_PROBABILITY);
        let mut sel = GuideSelection::from_parts(0.9, false, SelectionSums::default());
        sel.step(DEFAULT_MAX_GUIDE_PROBABILITY, None);
        assert_eq!(sel.probability, DEFAULT_MAX_GUIDE_PROBABILITY);
        let mut sel = GuideSelection::default();
        for _ in 0..MIN_SELECTION_SAMPLES - 1 {
            sel.record(1.0, 0.0, 1.0, 1.0);
        }
        sel.step(MAX_GUIDE_PROBABILITY, None);
        assert_eq!(sel.probability, INITIAL_GUIDE_PROBABILITY);
        // Huge values saturate instead of poisoning the sums.
        let mut sel = GuideSelection::default();
        for _ in 0..100 {
            sel.record(f32::MAX, 0.0, f32::MAX, f32::MIN_POSITIVE);
        }
        sel.step(MAX_GUIDE_PROBABILITY, None);
        assert!(sel.probability.is_finite());
    }

    /// Records `n` samples of the unit interval by the midpoint rule, drawn uniformly
    /// (`q0 = 1`): `(f, p_g, p_b)` at each point.
    fn record_quadrature(sel: &GuideSelection, n: usize, at: impl Fn(f32) -> (f32, f32, f32)) {
        for i in 0..n {
            let (f, pg, pb) = at((i as f32 + 0.5) / n as f32);
            sel.record(f, pb, pg, 1.0);
        }
    }

    /// `(f, p_g, p_b)`: light (f = 1) on `[0, ½)` only, the guide all there (density 2), the
    /// BSDF uniform.
    fn light_on_half(x: f32) -> (f32, f32, f32) {
        if x < 0.5 {
            (1.0, 2.0, 1.0)
        } else {
            (0.0, 0.0, 1.0)
        }
    }

    #[test]
    fn the_guide_turns_off_where_the_variance_it_saves_does_not_pay_its_cost() {
        // f = 1 on [0, ½), 0 past it; the BSDF uniform, the guide all on [0, ½). BSDF sampling:
        // M(0) = ½, ∫f = ½, V(0) = ¼. The mixture at a = ½ has q = 1 + a on [0, ½):
        // M = ½/(1 + a) = ⅓, V = 1/12, a third of V(0). So the guide pays for a cost below 2
        // (V·(1 + cost) < V(0)) and not above. The midpoint rule is exact here.
        for (cost, off) in [(1.9, false), (2.1, true)] {
            let mut sel = GuideSelection::default();
            record_quadrature(&sel, 1000, light_on_half);
            sel.step(MAX_GUIDE_PROBABILITY, Some(cost));
            assert_eq!(sel.off(), off, "cost {cost}");
            // The learned probability moves either way; queries read 0 while the guide is off.
            assert!(sel.learned > INITIAL_GUIDE_PROBABILITY, "{}", sel.learned);
            let published = if off { 0.0 } else { sel.learned };
            assert_eq!(sel.probability, published);
        }
        // A guide equal to the BSDF saves nothing: off at any cost, and without light too.
        for at in [|x: f32| (x, 1.0, 1.0), |_: f32| (0.0, 1.0, 1.0)] {
            let mut sel = GuideSelection::default();
            record_quadrature(&sel, 1000, at);
            sel.step(MAX_GUIDE_PROBABILITY, Some(0.0));
            assert!(sel.off());
            assert_eq!(sel.probability, 0.0);
            assert_eq!(sel.learned, INITIAL_GUIDE_PROBABILITY);
        }
    }

    #[test]
    fn an_idle_guide_turns_back_on_once_it_pays_and_waits_for_enough_samples() {
        let mut sel = GuideSelection::from_parts(0.3, true, SelectionSums::default());
        assert_eq!(sel.probability, 0.0);
        // Too few samples to tell: the guide stays off (the Newton step still runs).
        record_quadrature(&sel, MIN_VERDICT_SAMPLES as usize - 1, light_on_half);
        sel.step(MAX_GUIDE_PROBABILITY, Some(0.25));
        assert!(sel.off());
        assert!(sel.learned > 0.3);
        // Enough samples drawn from the BSDF alone (what a leaf with its guide off records) show
        // the guide paying: it turns back on, at the probability it learned meanwhile.
        record_quadrature(&sel, 1000, light_on_half);
        sel.step(MAX_GUIDE_PROBABILITY, Some(0.25));
        assert!(!sel.off());
        assert_eq!(sel.probability, sel.learned);
        // Without a cost the guide never turns off, and a guide that was off turns back on.
        let mut sel = GuideSelection::from_parts(0.5, true, SelectionSums::default());
        record_quadrature(&sel, 1000, |x| (x, 1.0, 1.0));
        sel.step(MAX_GUIDE_PROBABILITY, None);
        assert!(!sel.off());
    }

    #[test]
    fn light_the_bsdf_cannot_sample_keeps_the_guide_on() {
        // The BSDF has no density on [½, 1), where f is not zero: BSDF sampling alone would be
        // biased there, whatever the variances of what it does reach say.
        let mut sel = GuideSelection::default();
        record_quadrature(&sel, 1000, |x| (1.0, 1.0, if x < 0.5 { 2.0 } else { 0.0 }));
        assert!(sel.sums().uncovered > 0);
        sel.step(MAX_GUIDE_PROBABILITY, Some(MAX_GUIDE_COST));
        assert!(!sel.off());
    }
}
