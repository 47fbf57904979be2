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
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[non_exhaustive]
pub enum LeafRule {
    /// Mass ∝ the cell's mean contribution `S1` (the classic SD-tree rule).
    L1,
    /// Mass ∝ `sqrt(|C| · S2)`: the variance-optimal rule, the default.
    #[default]
    L2,
}

impl LeafRule {
    /// The unnormalized mass of a leaf covering `area` (fraction of the sphere, in `(0, 1]`)
    /// with statistics `s1 = Σ v/p` and `s2 = Σ v²/p`.
    #[inline]
    pub fn mass(self, area: f64, s1: f64, s2: f64) -> f64 {
        match self {
            LeafRule::L1 => s1,
            LeafRule::L2 => (area * s2).sqrt(),
        }
    }
}
