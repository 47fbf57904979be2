//! How a directional tree chooses its next partition: by flux share, or by how much a split
//! lowers the optimal variance.
//!
//! The l2 rule gives the best density on a fixed partition; the partition decides more. On a
//! partition into cells `C_i` with second moments `m_i = |C_i|·∫_{C_i} v²`, the best
//! piecewise-constant density has relative second moment `(Σ_i sqrt(m_i))²/μ²` (Pantaleoni &
//! Heitz, eqs. 14–18: put eq. 18's optimal `α_i` into eq. 14). So
//! replacing leaf `i` by its four quadrants lowers `Σ sqrt(m)` by
//!
//! ```text
//!   gain_i = sqrt(m_i) − Σ_{q} sqrt(m_{i,q})        ≥ 0, and 0 where the light is flat.
//! ```
//!
//! [`Refinement::FluxShare`], the SD-tree's rule, splits cells that hold a large share of the
//! mass, flat or not; [`Refinement::VarianceGain`] splits the cells with the largest gain. To
//! estimate `gain_i` each leaf records the second-moment sums (and counts) of its four
//! quadrants, from the samples that land in it; interior cells of the ended iteration have
//! theirs from their children, and keep their split if their whole known subtree gained more
//! per node spent than their first level alone.
//!
//! **Noise.** A square root of a noisy sum is biased, and the bias fakes gain: one sample in a
//! leaf puts all of its second moment in one quadrant, which looks like a point light (relative
//! gain ½), and a few hundred samples of a sharp, moving lobe still scatter the relative gain by
//! ±0.1–0.3 (measured against quadrature in the quality harness). Three guards: each quadrant's
//! sum is shrunk toward a quarter of the leaf's by `n_q/(n_q + n0)`, `n0 =`
//! `SPLIT_PRIOR_SAMPLES`, as every cell's second-moment sum is toward a quarter of its
//! parent's (the way leaf masses are, with their own `prior_samples`); and the leaf's relative
//! gain is shrunk toward its parent's — measured one level up, on four times the samples — by
//! `n/(n + N_g)`, `N_g =` `GAIN_PRIOR_SAMPLES`. A sparse leaf thus splits as well as its
//! parent did (flat light stays flat, a lobe keeps being refined), and its own evidence takes
//! over as it accumulates. And a cell splits only when it saw at least `MIN_SPLIT_SAMPLES`
//! samples. The constants are the quality harness's choice (`docs/quality.md`).
//!
//! **Below the recorded leaves.** The gain of a quadrant's own split is not recorded (that would
//! take sixteen more sums). It is predicted: a quadrant of a leaf with relative gain `g/sqrt(m)`
//! is assumed to split as well as its parent did, `gain_q = sqrt(m_q)·g/sqrt(m)` — exact for a
//! point light, zero for flat light — so one refine can go two levels below the old leaves. The
//! next iteration measures the prediction, and collapses a split that did not pay. A quadrant's
//! split is predicted only when it saw at least `MIN_PREDICTED_SPLIT_SAMPLES` samples: its
//! quadrants would be seen by too few samples to estimate otherwise.

use crate::moments::Quadrants;
use serde::{Deserialize, Serialize};

/// How refinement decides which directional cells to split.
///
/// ```
/// use sdguide::{GuidingConfig, Refinement};
/// let config = GuidingConfig { refinement: Refinement::FluxShare, ..GuidingConfig::default() };
/// assert!(config.validate().is_ok());
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[non_exhaustive]
pub enum Refinement {
    /// The SD-tree's rule: split a cell while its share of the tree's mass exceeds
    /// [`subdivision_threshold`](crate::GuidingConfig::subdivision_threshold) `ρ`; collapse it
    /// otherwise.
    FluxShare,
    /// Split cells in order of the variance their split removes, `sqrt(m_i) − Σ_q sqrt(m_{i,q})`,
    /// while it exceeds [`gain_threshold`](crate::GuidingConfig::gain_threshold) times the
    /// tree's `Σ_i sqrt(m_i)`; collapse the others. See the module documentation.
    #[default]
    VarianceGain,
}

/// Samples a cell of the ended iteration must have seen to split by variance gain (for a split
/// below the recorded leaves, `MIN_PREDICTED_SPLIT_SAMPLES`). A finer partition than the
/// samples can support costs more in badly estimated masses than its gain saves.
pub(crate) const MIN_SPLIT_SAMPLES: u64 = 64;

/// Samples a quadrant of a leaf must have seen (in the ended iteration) for its own split to be
/// predicted (see "Below the recorded leaves" in the module documentation). A predicted split
/// makes cells two levels below the recorded leaf, each of which the next iteration sees with a
/// sixteenth of the leaf's samples or fewer: on noisy light, where few samples carry the light,
/// some would see none of it, and the l2 rule would give them a small share of a mass they
/// hold. The default `gain_threshold` spends the nodes this saves where the light is smooth.
pub(crate) const MIN_PREDICTED_SPLIT_SAMPLES: u64 = 512;

/// `n0` of the gain estimates: how many samples' worth of weight a cell's second-moment sum
/// gives a quarter of its parent's, and a quadrant's sum a quarter of its leaf's, when
/// refinement by variance gain estimates what a split would gain (see the module
/// documentation). Larger than the leaf masses' own
/// [`prior_samples`](crate::GuidingConfig::prior_samples): a split decision rests on the
/// difference of square roots of noisy sums, which needs more shrinkage than a mass does.
pub(crate) const SPLIT_PRIOR_SAMPLES: f64 = 2.0;

/// `N_g`: how many samples' worth of weight a leaf's relative gain gives its parent's (see the
/// module documentation).
pub(crate) const GAIN_PRIOR_SAMPLES: f64 = 1000.0;

/// What a leaf's quadrant sums say about splitting it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct SplitEstimate {
    /// `gain / sqrt(m)` of splitting the leaf, in `[0, ½]`.
    pub relative_gain: f64,
    /// `sqrt(m_q)/sqrt(m)` for each quadrant, from the leaf's own sums (they sum to
    /// `1 − ` the leaf's own relative gain).
    pub fractions: [f64; 4],
}

/// Estimates the relative gain of splitting a leaf from its quadrant sums `(Σ v²/p, n)`, shrunk
/// toward the even split with `prior_samples` samples' worth of weight (refinement passes
/// [`SPLIT_PRIOR_SAMPLES`]), then toward `parent_gain`, the relative gain measured one level
/// up (see the module documentation).
///
/// With `S_q` the shrunk sums and `T = Σ S_q`, the quadrants' cells are a quarter of the leaf's,
/// so `sqrt(m_q)/sqrt(m) = sqrt(S_q/4)/sqrt(T)`.
pub(crate) fn split_gain(
    quadrants: &Quadrants,
    prior_samples: f64,
    parent_gain: f64,
) -> SplitEstimate {
    let n = quadrants
        .iter()
        .fold(0u64, |a, &(_, count)| a.saturating_add(count)) as f64;
    let total: f64 = quadrants.iter().map(|&(s, _)| s).sum();
    let (own, fractions) = if total > 0.0 && total.is_finite() {
        let even = 0.25 * total;
        let shrunk = quadrants.map(|(s, count)| {
            let w = shrink_weight(count as f64, prior_samples);
            w * s + (1.0 - w) * even
        });
        let shrunk_total: f64 = shrunk.iter().sum();
        let fractions = shrunk.map(|s| (0.25 * s / shrunk_total).sqrt());
        (1.0 - fractions.iter().sum::<f64>(), fractions)
    } else {
        (0.0, [0.25; 4])
    };
    let w = shrink_weight(n, GAIN_PRIOR_SAMPLES);
    SplitEstimate {
        relative_gain: (w * own + (1.0 - w) * parent_gain).clamp(0.0, 0.5),
        fractions,
    }
}

/// `n/(n + n0)`, the weight an estimate from `n` samples gets against a prior worth `n0`
/// (1 when `n0 = 0`).
pub(crate) fn shrink_weight(n: f64, n0: f64) -> f64 {
    if n0 > 0.0 { n / (n + n0) } else { 1.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_light_gains_half_and_flat_light_nothing() {
        let n = 1e9 as u64; // enough samples that the parent's gain does not matter
        let point = split_gain(&[(0.0, 0), (0.0, 0), (8.0, n), (0.0, 0)], 0.0, 0.0);
        assert!((point.relative_gain - 0.5).abs() < 1e-6);
        assert_eq!(point.fractions, [0.0, 0.0, 0.5, 0.0]);
        let flat = split_gain(&[(2.0, n); 4], 2.0, 0.5);
        assert!(flat.relative_gain.abs() < 1e-6);
        // Two bright quadrants of four: sqrt(½)·2/2 = 0.707 of sqrt(m) remains.
        let half = split_gain(&[(1.0, n), (1.0, n), (0.0, 0), (0.0, 0)], 0.0, 0.0);
        assert!((half.relative_gain - (1.0 - 0.5f64.sqrt())).abs() < 1e-6);
    }

    #[test]
    fn a_sparse_leaf_splits_as_well_as_its_parent() {
        // One sample looks like a point light; it barely moves the parent's estimate.
        let one = split_gain(&[(5.0, 1), (0.0, 0), (0.0, 0), (0.0, 0)], 0.0, 0.1);
        let w = shrink_weight(1.0, GAIN_PRIOR_SAMPLES);
        assert!((one.relative_gain - (w * 0.5 + (1.0 - w) * 0.1)).abs() < 1e-12);
        // Nothing recorded, or sums that overflowed: the parent's gain, an even split.
        for q in [
            [(0.0, 0); 4],
            [(f64::MAX, 40), (f64::MAX, 40), (0.0, 0), (0.0, 0)],
        ] {
            let e = split_gain(&q, 2.0, 0.2);
            assert_eq!(e.fractions, [0.25; 4]);
            let n: f64 = q.iter().map(|&(_, n)| n as f64).sum();
            let expected = (1.0 - shrink_weight(n, GAIN_PRIOR_SAMPLES)) * 0.2;
            assert!((e.relative_gain - expected).abs() < 1e-12);
        }
    }

    #[test]
    fn shrinkage_pulls_a_thinly_sampled_quadrant_toward_the_even_split() {
        // One sample in quadrant 0 among 39 flat ones: shrinkage halves its excess.
        let quads = [(10.0, 1), (1.0, 13), (1.0, 13), (1.0, 13)];
        let raw = split_gain(&quads, 0.0, 0.0).relative_gain;
        let shrunk = split_gain(&quads, 2.0, 0.0).relative_gain;
        assert!(0.0 < shrunk && shrunk < raw, "{shrunk} vs {raw}");
    }
}
