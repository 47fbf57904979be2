//! How many continuations to trace from a path vertex: efficiency-aware Russian roulette and
//! splitting, from moments of the continuations' contributions that the field learns.
//!
//! The derivation and how the field learns the moments are on [`Splitting`].

use crate::config::ConfigError;
use crate::exact::{AtomicSum, MAX_TERM, Sum};
use crate::sample::RejectReason;
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicU64, Ordering};

/// Continuations a leaf must record in an iteration to replace its estimate, and an estimate
/// must hold for [`Splitting::factor`] to use it.
pub const MIN_CONTINUATIONS: u64 = 16;

/// One traced continuation of a path vertex, for the field to learn from: at `position`, the
/// continuation's estimate `value` of the light the vertex reflects toward the path's previous
/// vertex, `f·cos·L_i / p` for the direction it sampled (a non-negative scalar, usually a
/// luminance, with every roulette and splitting weight *below* the vertex included and the
/// vertex's own `1/q` not), and what it cost to trace (`cost`, in any unit the renderer keeps
/// consistently: rays, say).
///
/// Record every continuation the vertex traced, and only those: a vertex that traced three
/// records three, one that roulette ended before it sampled a direction records none.
///
/// ```
/// use sdguide::Continuation;
/// use sdguide::glam::Vec3;
/// let c = Continuation { position: Vec3::new(0.5, 0.2, 0.1), value: 0.3, cost: 4.0 };
/// assert!(c.check().is_ok());
/// assert!(Continuation { cost: -1.0, ..c }.check().is_err());
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Continuation {
    /// The vertex (world space).
    pub position: Vec3,
    /// The continuation's estimate of the reflected light: finite and non-negative.
    pub value: f32,
    /// The continuation's cost: finite and non-negative.
    pub cost: f32,
}

impl Continuation {
    /// Whether the continuation can be recorded: a finite position, and a finite, non-negative
    /// value and cost.
    ///
    /// # Errors
    ///
    /// [`RejectReason::NonFinitePosition`], or [`RejectReason::BadValue`] for a value or a
    /// cost that is negative or not finite.
    pub fn check(&self) -> Result<(), RejectReason> {
        if !self.position.is_finite() {
            return Err(RejectReason::NonFinitePosition);
        }
        let ok = |x: f32| x.is_finite() && x >= 0.0;
        if !(ok(self.value) && ok(self.cost)) {
            return Err(RejectReason::BadValue);
        }
        Ok(())
    }
}

/// A spatial leaf's sums over the continuations recorded there: what
/// [`GuidingField::continuation`](crate::GuidingField::continuation) returns.
///
/// ```
/// use sdguide::ContinuationEstimate;
/// let e = ContinuationEstimate { sum: 6.0, sum_sq: 20.0, cost: 12.0, count: 3 };
/// assert_eq!(e.mean(), Some(2.0));
/// assert_eq!(e.second_moment(), Some(20.0 / 3.0));
/// assert_eq!(e.mean_cost(), Some(4.0));
/// assert_eq!(ContinuationEstimate::default().mean(), None);
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ContinuationEstimate {
    /// `Σ L` over the continuations.
    pub sum: f64,
    /// `Σ L²`.
    pub sum_sq: f64,
    /// `Σ c`.
    pub cost: f64,
    /// How many.
    pub count: u64,
}

impl ContinuationEstimate {
    /// `μ`, the mean value (`None` without continuations).
    pub fn mean(&self) -> Option<f64> {
        self.per_continuation(self.sum)
    }

    /// `M₂`, the mean squared value (`None` without continuations).
    pub fn second_moment(&self) -> Option<f64> {
        self.per_continuation(self.sum_sq)
    }

    /// `c`, the mean cost (`None` without continuations).
    pub fn mean_cost(&self) -> Option<f64> {
        self.per_continuation(self.cost)
    }

    fn per_continuation(&self, total: f64) -> Option<f64> {
        (self.count > 0).then(|| total / self.count as f64)
    }

    /// Both sums added, saturating.
    pub(crate) fn plus(&self, o: &ContinuationEstimate) -> ContinuationEstimate {
        ContinuationEstimate {
            sum: (self.sum + o.sum).min(f64::MAX),
            sum_sq: (self.sum_sq + o.sum_sq).min(f64::MAX),
            cost: (self.cost + o.cost).min(f64::MAX),
            count: self.count.saturating_add(o.count),
        }
    }

    /// Whether the sums could have come from recorded continuations: finite, non-negative, and
    /// all zero without a count.
    pub(crate) fn is_valid(&self) -> bool {
        let ok = |x: f64| x.is_finite() && x >= 0.0;
        ok(self.sum)
            && ok(self.sum_sq)
            && ok(self.cost)
            && (self.count > 0 || (self.sum == 0.0 && self.sum_sq == 0.0 && self.cost == 0.0))
    }
}

/// A spatial leaf's recorded continuation sums, exact (see [`crate::exact`]): what caches and
/// merges keep.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct ContinuationSums {
    pub(crate) sum: Sum,
    pub(crate) sum_sq: Sum,
    pub(crate) cost: Sum,
    pub(crate) count: u64,
}

impl ContinuationSums {
    /// The sums as an estimate.
    pub(crate) fn estimate(&self) -> ContinuationEstimate {
        ContinuationEstimate {
            sum: self.sum.value(),
            sum_sq: self.sum_sq.value(),
            cost: self.cost.value(),
            count: self.count,
        }
    }

    /// Both leaves' sums (merging workers): exact, in any order.
    pub(crate) fn plus(&self, o: &ContinuationSums) -> ContinuationSums {
        ContinuationSums {
            sum: self.sum.plus(o.sum),
            sum_sq: self.sum_sq.plus(o.sum_sq),
            cost: self.cost.plus(o.cost),
            count: self.count.saturating_add(o.count),
        }
    }

    /// Sums with a sample count, or none at all.
    pub(crate) fn is_valid(&self) -> bool {
        self.count > 0 || (self.sum.is_zero() && self.sum_sq.is_zero() && self.cost.is_zero())
    }
}

/// A spatial leaf's continuation estimate (what queries read) and the iteration's sums (what
/// recording adds to, lock-free).
#[derive(Debug, Default)]
pub(crate) struct ContinuationStats {
    pub(crate) estimate: ContinuationEstimate,
    sum: AtomicSum,
    sum_sq: AtomicSum,
    cost: AtomicSum,
    count: AtomicU64,
}

impl Clone for ContinuationStats {
    fn clone(&self) -> Self {
        Self::from_parts(self.estimate, self.recorded())
    }
}

impl ContinuationStats {
    pub(crate) fn from_parts(estimate: ContinuationEstimate, r: ContinuationSums) -> Self {
        Self {
            estimate,
            sum: AtomicSum::new(r.sum.units()),
            sum_sq: AtomicSum::new(r.sum_sq.units()),
            cost: AtomicSum::new(r.cost.units()),
            count: AtomicU64::new(r.count),
        }
    }

    /// Adds one continuation (checked by [`Continuation::check`]); returns whether a term was
    /// clamped to the sums' range.
    #[inline]
    pub(crate) fn record(&self, value: f32, cost: f32) -> bool {
        let v = f64::from(value);
        let (v2, c) = (v * v, f64::from(cost));
        self.sum.add(v);
        self.sum_sq.add(v2);
        self.cost.add(c);
        self.count.fetch_add(1, Ordering::Relaxed);
        v2.max(c) > MAX_TERM
    }

    /// The current iteration's sums.
    pub(crate) fn recorded(&self) -> ContinuationSums {
        ContinuationSums {
            sum: self.sum.sum(),
            sum_sq: self.sum_sq.sum(),
            cost: self.cost.sum(),
            count: self.count.load(Ordering::Relaxed),
        }
    }

    /// Ends an iteration: the recorded sums replace the estimate if there are enough of them,
    /// else join it; then they restart.
    pub(crate) fn step(&mut self) {
        let r = self.recorded().estimate();
        let estimate = if r.count >= MIN_CONTINUATIONS {
            r
        } else {
            self.estimate.plus(&r)
        };
        *self = Self::from_parts(estimate, ContinuationSums::default());
    }

    /// Adds another leaf's recorded sums (merging workers).
    pub(crate) fn add_recorded(&mut self, r: &ContinuationSums) {
        *self = Self::from_parts(self.estimate, self.recorded().plus(r));
    }
}

/// Whether a vertex may trace more than one continuation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum SplittingMode {
    /// Russian roulette only: factors up to 1 (efficiency-aware roulette, "EAR").
    Roulette,
    /// Roulette and splitting: factors up to `max_splits` ("EARS").
    #[default]
    RouletteAndSplitting,
}

/// The image-wide terms of the splitting factor, and its bounds: what a renderer sets once per
/// pass.
///
/// Choosing a direction at a vertex cannot remove the variance of what the path finds after it;
/// choosing how many continuations to trace can. At a vertex the renderer traces `n`
/// continuations with `E[n] = q` (the *splitting factor*; below 1 it is a survival probability)
/// and weighs each by `1/q`, which keeps the estimate unbiased for any `q > 0`. Each
/// continuation estimates the light the vertex reflects, `L = f·cos·L_i / p` for its sampled
/// direction, with mean `μ` and second moment `M₂`, and costs `c` (rays, say). Its share of the
/// pixel estimate's per-sample variance, with `T` the path's throughput weight from the camera
/// to the vertex (every earlier `1/q` included), is
///
/// ```text
///   T²·(M₂/q − μ²)        roulette, q ≤ 1
///   T²·(M₂ − μ²)/q        splitting, q ≥ 1 (plus a small term from rounding q)
/// ```
///
/// and its share of the cost `q·c`. The image is judged by its relative error, the mean over
/// pixels of `V_p / P_p²` (`P_p² = I_p² + ε`), at the cost of its mean camera sample `C̄`.
/// Minimizing the product of the two — the inverse of the render's efficiency — over `q` at one
/// vertex, with the rest of the image held at its current relative variance `V̄`, gives
///
/// ```text
///   q* = (T / P) · sqrt( a · C̄ / (V̄ · c) ),    a = M₂ (roulette), a = M₂ − μ² (splitting)
/// ```
///
/// This is the splitting factor of Rath et al. 2022 ("EARS: Efficiency-aware Russian roulette
/// and splitting"), with the variance rather than the second moment where the vertex splits.
/// [`Splitting::factor`] evaluates it: `q*` from `M₂` when that is below 1, else from the
/// variance, at least 1; clamped to `[min_survival, max_splits]`, so that an estimate that is
/// wrong can make a region noisier but never drop it (no zero survival, no bias).
///
/// The field learns `μ`, `M₂` and `c` per spatial leaf from [`Continuation`]s the renderer
/// records (the value of one traced continuation, and its cost), lock-free like every other
/// statistic. At [`refine`](crate::GuidingField::refine) a leaf that recorded at least
/// [`MIN_CONTINUATIONS`] continuations in the iteration replaces its estimate by them; one that
/// recorded fewer adds them to the estimate it had, so sparse leaves accumulate. Spatial
/// children start from their parent's estimate. The estimate and the iteration's sums are saved
/// in the cache and merged exactly.
///
/// ```
/// use sdguide::{ContinuationEstimate, Splitting, SplittingMode};
/// // The image: mean relative variance per sample 0.5, a camera sample costs 8 rays.
/// let policy = Splitting::new(SplittingMode::RouletteAndSplitting, 0.5, 8.0);
/// // A cell whose continuations have mean 1, second moment 3, and cost 4 rays.
/// let cell = ContinuationEstimate { sum: 32.0, sum_sq: 96.0, cost: 128.0, count: 32 };
/// // At a vertex with throughput 0.1 in a pixel of value 1: q = 0.1·sqrt(3·8/(0.5·4)) < 1.
/// let q = policy.factor(&cell, 0.1, 1.0).unwrap();
/// assert!((q - 0.1 * (3.0f32 * 8.0 / 2.0).sqrt()).abs() < 1e-6);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Splitting {
    mode: SplittingMode,
    relative_variance: f64,
    cost: f64,
    min_survival: f32,
    max_splits: f32,
}

impl Splitting {
    /// The smallest survival probability a factor takes by default.
    pub const DEFAULT_MIN_SURVIVAL: f32 = 0.05;
    /// The largest factor by default (under [`SplittingMode::RouletteAndSplitting`]).
    pub const DEFAULT_MAX_SPLITS: f32 = 8.0;

    /// The policy for an image whose per-sample relative variance, averaged over pixels, is
    /// `relative_variance` (`V̄`: the mean of `s_p² / (I_p² + ε)`, with `s_p²` a pixel's
    /// per-sample variance and `I_p` its estimated value), and whose camera samples cost
    /// `cost` on average (`C̄`, in the unit of [`Continuation::cost`]); with the default bounds.
    /// Values that are not finite and positive make every [`factor`](Self::factor) `None`.
    pub fn new(mode: SplittingMode, relative_variance: f64, cost: f64) -> Self {
        Self {
            mode,
            relative_variance,
            cost,
            min_survival: Self::DEFAULT_MIN_SURVIVAL,
            max_splits: Self::DEFAULT_MAX_SPLITS,
        }
    }

    /// The policy with other bounds: `min_survival` in `(0, 1]`, `max_splits` finite and at
    /// least 1.
    ///
    /// # Errors
    ///
    /// A [`ConfigError`] naming the bound out of range.
    pub fn with_bounds(self, min_survival: f32, max_splits: f32) -> Result<Self, ConfigError> {
        if !(min_survival > 0.0 && min_survival <= 1.0) {
            return Err(ConfigError {
                field: "min_survival",
                value: min_survival.to_string(),
                requirement: "in (0, 1]",
            });
        }
        if !(max_splits.is_finite() && max_splits >= 1.0) {
            return Err(ConfigError {
                field: "max_splits",
                value: max_splits.to_string(),
                requirement: "finite and at least 1",
            });
        }
        Ok(Self {
            min_survival,
            max_splits,
            ..self
        })
    }

    /// The mode.
    pub fn mode(&self) -> SplittingMode {
        self.mode
    }

    /// The splitting factor `q` at a vertex in a cell with continuation estimate `estimate`,
    /// reached with throughput weight `throughput` (`T`, a luminance, every earlier `1/q`
    /// included), in a pixel whose value the image's error is relative to is `pixel`
    /// (`P = sqrt(I² + ε)` for the relative error `(Î − I)²/(I² + ε)`): in
    /// `[min_survival, 1]` under [`SplittingMode::Roulette`], in `[min_survival, max_splits]`
    /// otherwise. A zero throughput, or a cell whose continuations all returned nothing,
    /// gives `min_survival`.
    ///
    /// `None` — no factor; the renderer falls back to its own roulette — when the estimate
    /// holds fewer than [`MIN_CONTINUATIONS`] continuations, when `throughput` is negative or
    /// not finite, when `pixel` is not finite and positive, or when the policy's image terms
    /// are not.
    pub fn factor(
        &self,
        estimate: &ContinuationEstimate,
        throughput: f32,
        pixel: f32,
    ) -> Option<f32> {
        if estimate.count < MIN_CONTINUATIONS
            || !(throughput.is_finite() && throughput >= 0.0)
            || !(pixel.is_finite() && pixel > 0.0)
            || !(self.relative_variance.is_finite() && self.relative_variance > 0.0)
            || !(self.cost.is_finite() && self.cost > 0.0)
        {
            return None;
        }
        let n = estimate.count as f64;
        let (mean, second) = (estimate.sum / n, estimate.sum_sq / n);
        // A continuation costs something; a recorded zero cost must not make it free.
        let cost = (estimate.cost / n).max(f64::MIN_POSITIVE);
        let scale = f64::from(throughput) / f64::from(pixel)
            * (self.cost / (self.relative_variance * cost)).sqrt();
        let roulette = scale * second.sqrt();
        let q = if roulette < 1.0 || self.mode == SplittingMode::Roulette {
            roulette.min(1.0)
        } else {
            (scale * (second - mean * mean).max(0.0).sqrt()).max(1.0)
        };
        let q = if q.is_nan() { 1.0 } else { q as f32 };
        let max = match self.mode {
            SplittingMode::Roulette => 1.0,
            SplittingMode::RouletteAndSplitting => self.max_splits,
        };
        Some(q.clamp(self.min_survival, max))
    }
}

/// How many continuations a factor `q` traces, by stochastic rounding with the uniform number
/// `u ∈ [0, 1)`, and the weight `1/q` each carries: `⌊q⌋ + 1` with probability `q − ⌊q⌋`,
/// else `⌊q⌋`, so that the expected count is `q` and the weighted sum is unbiased. A factor
/// that is not finite and positive traces one continuation with weight 1.
///
/// ```
/// use sdguide::continuations;
/// assert_eq!(continuations(2.25, 0.1), (3, 1.0 / 2.25));
/// assert_eq!(continuations(2.25, 0.5), (2, 1.0 / 2.25));
/// assert_eq!(continuations(0.5, 0.7), (0, 2.0));
/// assert_eq!(continuations(f32::NAN, 0.7), (1, 1.0));
/// ```
pub fn continuations(q: f32, u: f32) -> (u32, f32) {
    if !(q.is_finite() && q > 0.0) {
        return (1, 1.0);
    }
    let whole = q.floor();
    let n = whole as u32 + u32::from(u < q - whole);
    (n, 1.0 / q)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cell(mean: f64, second: f64, cost: f64, count: u64) -> ContinuationEstimate {
        let n = count as f64;
        ContinuationEstimate {
            sum: mean * n,
            sum_sq: second * n,
            cost: cost * n,
            count,
        }
    }

    #[test]
    fn the_factor_matches_its_closed_form_on_both_sides_of_one() {
        // V̄ = 0.25, C̄ = 10, c = 2.5: the scale is (T/P)·sqrt(10/(0.25·2.5)) = 4·T/P.
        let policy = Splitting::new(SplittingMode::RouletteAndSplitting, 0.25, 10.0);
        let e = cell(2.0, 5.0, 2.5, 64);
        // Roulette: q = 4·(0.05/1)·sqrt(5) = 0.447…
        let q = policy.factor(&e, 0.05, 1.0).unwrap();
        assert!((q - 0.2 * 5f32.sqrt()).abs() < 1e-6, "{q}");
        // Splitting: 4·(1/2)·sqrt(5) > 1, so q = 4·(1/2)·sqrt(5 − 4) = 2.
        let q = policy.factor(&e, 1.0, 2.0).unwrap();
        assert!((q - 2.0).abs() < 1e-6, "{q}");
        // Between: sqrt(M₂) says split, the variance says fewer than one: exactly one.
        let q = policy.factor(&e, 0.2, 1.0).unwrap();
        assert_eq!(q, 1.0);
        // Roulette only: the same vertex that split stops at 1.
        let ear = Splitting::new(SplittingMode::Roulette, 0.25, 10.0);
        assert_eq!(ear.factor(&e, 1.0, 2.0), Some(1.0));
        assert!((ear.factor(&e, 0.05, 1.0).unwrap() - 0.2 * 5f32.sqrt()).abs() < 1e-6);
    }

    #[test]
    fn the_factor_stays_within_its_bounds() {
        let policy = Splitting::new(SplittingMode::RouletteAndSplitting, 0.25, 10.0)
            .with_bounds(0.1, 4.0)
            .unwrap();
        let e = cell(2.0, 5.0, 2.5, 64);
        assert_eq!(policy.factor(&e, 1e6, 1.0), Some(4.0));
        assert_eq!(policy.factor(&e, 0.0, 1.0), Some(0.1));
        // A cell that only ever returned zero still survives, at the floor.
        assert_eq!(policy.factor(&cell(0.0, 0.0, 3.0, 64), 1.0, 1.0), Some(0.1));
        // A zero recorded cost does not divide by zero.
        assert_eq!(policy.factor(&cell(2.0, 5.0, 0.0, 64), 1.0, 1.0), Some(4.0));
    }

    #[test]
    fn unusable_inputs_give_no_factor() {
        let policy = Splitting::new(SplittingMode::RouletteAndSplitting, 0.25, 10.0);
        let e = cell(2.0, 5.0, 2.5, 64);
        for t in [f32::NAN, f32::INFINITY, -1.0] {
            assert_eq!(policy.factor(&e, t, 1.0), None, "throughput {t}");
        }
        for p in [f32::NAN, f32::INFINITY, 0.0, -1.0] {
            assert_eq!(policy.factor(&e, 1.0, p), None, "pixel {p}");
        }
        assert_eq!(policy.factor(&cell(2.0, 5.0, 2.5, 15), 1.0, 1.0), None);
        for (v, c) in [
            (0.0, 10.0),
            (f64::NAN, 10.0),
            (0.25, -1.0),
            (0.25, f64::INFINITY),
        ] {
            let p = Splitting::new(SplittingMode::RouletteAndSplitting, v, c);
            assert_eq!(p.factor(&e, 1.0, 1.0), None, "image terms {v}, {c}");
        }
        let bad = Splitting::new(SplittingMode::Roulette, 1.0, 1.0);
        assert!(bad.with_bounds(0.0, 2.0).is_err());
        assert!(bad.with_bounds(f32::NAN, 2.0).is_err());
        assert!(bad.with_bounds(0.5, 0.5).is_err());
        assert!(bad.with_bounds(0.5, f32::INFINITY).is_err());
    }

    #[test]
    fn stochastic_rounding_is_unbiased() {
        // Over a stratified u, the mean count is q exactly (up to the strata).
        for q in [0.05f32, 0.3, 1.0, 1.7, 3.25, 8.0] {
            let n = 10_000;
            let total: u32 = (0..n)
                .map(|i| continuations(q, (i as f32 + 0.5) / n as f32).0)
                .sum();
            let mean = total as f32 / n as f32;
            assert!((mean - q).abs() < 1e-3, "q {q}: mean count {mean}");
            assert_eq!(continuations(q, 0.5).1, 1.0 / q);
        }
    }

    #[test]
    fn sparse_leaves_accumulate_and_full_ones_replace() {
        let mut s = ContinuationStats::default();
        for _ in 0..MIN_CONTINUATIONS - 1 {
            s.record(1.0, 2.0);
        }
        s.step();
        assert_eq!(s.estimate.count, MIN_CONTINUATIONS - 1);
        s.record(3.0, 1.0);
        s.step();
        assert_eq!(s.estimate.count, MIN_CONTINUATIONS);
        assert_eq!(s.estimate.sum, (MIN_CONTINUATIONS - 1) as f64 + 3.0);
        for _ in 0..MIN_CONTINUATIONS {
            s.record(0.5, 1.0);
        }
        s.step();
        assert_eq!(s.estimate, cell(0.5, 0.25, 1.0, MIN_CONTINUATIONS));
        assert_eq!(s.recorded(), ContinuationSums::default());
    }
}
