//! Leaf rules: how a directional leaf's recorded statistics become its share of the distribution.
//!
//! For a leaf `C_i` with recorded `S1_i = Σ v/p` and `S2_i = Σ v²/p`, and cell area `|C_i|`
//! (the fraction of the sphere it covers), the paper's section 2 gives
//!
//! ```text
//!   L1:  α_i ∝ S1_i                    the customary projection, mass ∝ mean          (eq. 12)
//!   L2:  α_i ∝ sqrt(|C_i| · S2_i)      minimizes Var[v/p] over the partition          (eq. 18)
//! ```
//!
//! Both statistics are sums over the iteration's samples, so the common factor `1/N` cancels
//! when the masses are normalized. On a fixed partition the L2 masses reach the variance
//! `V_opt = (Σ_i sqrt(m_i))² − μ²` with `m_i = |C_i| ∫_{C_i} v²`, the smallest any piecewise-
//! constant density on that partition can.

use serde::{Deserialize, Serialize};

/// Which projection turns recorded statistics into leaf masses.
///
/// ```
/// use sdguide::LeafRule;
/// // A quarter of the sphere that saw Σ v/p = 2 and Σ v²/p = 16:
/// assert_eq!(LeafRule::L1.mass(0.25, 2.0, 16.0), 2.0);
/// assert_eq!(LeafRule::L2.mass(0.25, 2.0, 16.0), 2.0); // sqrt(0.25 · 16)
/// ```
///
/// # The rule inside the mixture with BSDF sampling
///
/// A renderer does not estimate with the guide `p_g` alone: it draws from the one-sample
/// mixture `q = a·p_g + (1 − a)·p_b` and estimates `∫ f` by `f/q`, with `f = L·f_s·|cos θ|`.
/// The guide's masses `m_i` that minimize that estimator's second moment `∫ f²/q` satisfy
/// (the paper's eq. 20, the components overlapping)
///
/// ```text
///   (1/|C_i|) ∫_{C_i} f²/q²  =  λ       on every leaf with m_i > 0,
/// ```
///
/// the same for every leaf: a leaf where the BSDF already samples `f` well needs less of the
/// guide. With `p_g = m_i/|C_i|` on leaf `i`, the fixed-point iteration
/// `m_i ← m_i·sqrt((1/|C_i|) ∫_{C_i} f²/q²)` (normalized) stops exactly there, and it is the
/// L2 rule applied to the value
///
/// ```text
///   v = f · p_g / q                                         (L2Mixture)
/// ```
///
/// since `m_i² · (1/|C_i|) ∫ f²/q² = |C_i| ∫ f²·p_g²/q²`. Without the BSDF (`a = 1`) it is the
/// L2 rule on `f`, reached in one step; where the BSDF dominates (`q ≫ a·p_g`) the leaf's share
/// falls with `p_g/q`. When the guide was sampled with a product (such as
/// [`at_surface`](crate::DirectionalDistribution::at_surface)) its pdf `p_s` differs from the
/// tree's `p_g`, and the same argument gives `v = f·sqrt(p_s·p_g)/q`: that is what a field
/// with [`LeafRule::L2Mixture`] records, from a sample's
/// [`mixture`](crate::Sample::mixture) terms (`p_s` their `guide_pdf`, `q` its `pdf`, `p_g`
/// the field's own pdf of the direction). A sample recorded without mixture terms
/// contributes its `value`, as under [`LeafRule::L2`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[non_exhaustive]
pub enum LeafRule {
    /// Mass ∝ the cell's mean contribution `S1` (the classic SD-tree rule).
    L1,
    /// Mass ∝ `sqrt(|C| · S2)`: the variance-optimal rule for the guide's own estimator
    /// `v/p`, the default.
    #[default]
    L2,
    /// The L2 rule for the renderer's estimator `f/q` of the guide–BSDF mixture: mass ∝
    /// `sqrt(|C| · S2)` of the value `f·sqrt(p_s·p_g)/q` the field derives from each sample's
    /// mixture terms (see the [type's documentation](LeafRule)).
    L2Mixture,
}

impl LeafRule {
    /// The unnormalized mass of a leaf covering `area` (fraction of the sphere, in `(0, 1]`)
    /// with statistics `s1 = Σ v/p` and `s2 = Σ v²/p` (for [`L2Mixture`](Self::L2Mixture),
    /// of the value it records).
    #[inline]
    pub fn mass(self, area: f64, s1: f64, s2: f64) -> f64 {
        match self {
            LeafRule::L1 => s1,
            LeafRule::L2 | LeafRule::L2Mixture => (area * s2).sqrt(),
        }
    }
}

/// The value [`LeafRule::L2Mixture`] records for a sample: `f·sqrt(p_s·p_g)/q`, from its
/// integrand `f`, the pdf `p_s` the guide drew it with, the tree's own pdf `p_g` of the
/// direction and the mixture pdf `q` (saturating at `f32::MAX`).
#[inline]
pub(crate) fn mixture_value(integrand: f32, guide_pdf: f32, tree_pdf: f64, pdf: f32) -> f32 {
    let v = f64::from(integrand) * (f64::from(guide_pdf) * tree_pdf).sqrt() / f64::from(pdf);
    v.min(f64::from(f32::MAX)) as f32
}
