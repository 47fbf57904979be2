//! The sampling tree's product with a Henyey–Greenstein phase function: the density
//! `p(ω) ∝ p_guide(ω)·p̂(ω)` a vertex inside a participating medium samples, with `p̂`, cell by
//! cell, an estimate of `p_HG(d·ω)` about the direction of travel `d`.
//!
//! A medium scatters light from the whole sphere, so there is no horizon; what the product adds
//! is the phase function's shape, which for a strongly forward- or back-scattering medium
//! (|g| near 1) is a narrow lobe the guide alone knows nothing of. The descent is
//! [`super::product`]'s, so the density is the product of the conditionals chosen on the way
//! down and `sample` and `pdf` agree exactly whatever the estimate.
//!
//! **The estimate.** With `μ = d·ω`, the Henyey–Greenstein phase function is
//! `p_HG(μ) = (1 − g²) / (4π·A(μ)^{3/2})`, `A(μ) = 1 + g² − 2gμ`. Over a spherical cap `μ` is
//! uniform, and the mean of `p_HG` for `μ` uniform on `[lo, hi]` has the closed form
//!
//! ```text
//!   p̄ = (1 − g²)/(4π) · 2 / (s_lo·s_hi·(s_lo + s_hi)),    s = sqrt(A(μ)),
//! ```
//!
//! stable as `g → 0` and as `hi → lo` (it tends to `p_HG(lo)`). The estimate of a child is `p̄`
//! over the range of `μ` at its corners, except that the child holding `d` itself reaches
//! `μ = 1` (the lobe's peak lies inside it, not at a corner) and the one holding `−d` reaches
//! `μ = −1`. The constant factor cancels in the conditionals. `p̄ > 0` for every `|g| < 1`, so
//! the product is positive wherever the guide is: everywhere, the guide keeps a uniform floor.
//!
//! **Depth.** A leaf of the guide over whose range the phase function varies by more than a
//! factor of three is descended further, as if split, down to [`PHASE_DEPTH`] (cells of
//! 0.0035 rad, below the width of the lobe at g = 0.99, about 1 − g); where it varies by at
//! most a factor [`SETTLED`] the levels below follow the guide's own conditionals. For g = 0
//! the phase function is constant and the product is the guide.

use super::product::Lobe;
use super::{FIXED_BITS, SamplingTree};
use crate::sphere;
use glam::{BVec4A, Vec2, Vec3, Vec4};

/// How deep the product follows the phase function inside the guide's leaves.
pub(crate) const PHASE_DEPTH: u32 = 10;

/// The largest `|g|` the product takes: beyond it the phase function is so narrow that its
/// product with a piecewise-constant guide is no density `f32` represents well (at g = 1 it is
/// a Dirac delta). Larger `|g|` are clamped to it.
pub(crate) const MAX_G: f32 = 0.999;

/// Where the phase function over a cell varies by at most this factor, the levels below follow
/// the guide.
const SETTLED: f32 = 1.25;

/// `A`'s ratio over a cell beyond which `p_HG`'s ratio, `A^{3/2}`'s, exceeds 3: `3^{2/3}`.
const DESCEND_RATIO: f32 = 2.080_084;

/// `A`'s ratio at which `p_HG`'s is [`SETTLED`]: `1.25^{2/3}`.
const SETTLED_RATIO: f32 = 1.160_397;

const _: () = assert!(SETTLED == 1.25);

/// The Henyey–Greenstein phase function about a unit direction of travel, as a [`Lobe`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct PhaseLobe {
    /// The unit direction of travel `d` (forward scattering, `g > 0`, peaks along it).
    axis: Vec3,
    /// `1 + g²`.
    one_plus_g2: f32,
    /// `2g`.
    two_g: f32,
    /// The fixed-point points of `d` and `−d` on the square.
    forward: [u32; 2],
    backward: [u32; 2],
}

impl PhaseLobe {
    /// The lobe about the direction of travel `travel` (any length) with asymmetry `g`:
    /// `None` where `travel` has no direction, `g` is NaN or 0 (the product is the guide);
    /// `|g|` above [`MAX_G`] is clamped to it.
    pub(crate) fn new(travel: Vec3, g: f32) -> Option<Self> {
        let axis = sphere::normalize(travel)?;
        if g.is_nan() || g == 0.0 {
            return None;
        }
        let g = g.clamp(-MAX_G, MAX_G);
        let point = |d: Vec3| sphere::square_of(d).map(super::fixed);
        Some(Self {
            axis,
            one_plus_g2: 1.0 + g * g,
            two_g: 2.0 * g,
            forward: point(axis)?,
            backward: point(-axis)?,
        })
    }

    /// `A(μ) = 1 + g² − 2gμ`, lane by lane (positive: `|g| < 1`).
    #[inline(always)]
    fn a(&self, mu: Vec4) -> Vec4 {
        (Vec4::splat(self.one_plus_g2) - self.two_g * mu).max(Vec4::splat(f32::MIN_POSITIVE))
    }

    /// `A`'s ratio over `[lo, hi]`: `≥ 1`.
    #[inline(always)]
    fn a_ratio(&self, lo: f32, hi: f32) -> f32 {
        let a = self.a(Vec4::new(lo, hi, 0.0, 0.0));
        a.x.max(a.y) / a.x.min(a.y)
    }
}

/// Lane `q` set where the quadrant of `point` below the cell `parent` (children at `depth`)
/// is child `q`; no lane where `parent` does not hold `point`.
#[inline(always)]
fn holding(point: [u32; 2], parent: [u32; 2], depth: u32) -> BVec4A {
    let shift = FIXED_BITS - depth;
    let child = [point[0] >> shift, point[1] >> shift];
    let inside = child[0] >> 1 == parent[0] && child[1] >> 1 == parent[1];
    let q = (child[0] & 1) | (child[1] & 1) << 1;
    BVec4A::new(
        inside && q == 0,
        inside && q == 1,
        inside && q == 2,
        inside && q == 3,
    )
}

impl Lobe for PhaseLobe {
    #[inline(always)]
    fn axis(&self) -> Vec3 {
        self.axis
    }

    #[inline(always)]
    fn children(&self, lo: Vec4, hi: Vec4, parent: [u32; 2], depth: u32) -> (Vec4, Vec4, Vec4) {
        let hi = Vec4::select(holding(self.forward, parent, depth), Vec4::ONE, hi);
        let lo = Vec4::select(holding(self.backward, parent, depth), -Vec4::ONE, lo);
        let (s_lo, s_hi) = (self.a(lo).sqrt(), self.a(hi).sqrt());
        (2.0 / (s_lo * s_hi * (s_lo + s_hi)), lo, hi)
    }

    #[inline(always)]
    fn ends(&self, _: f32, _: f32) -> bool {
        false
    }

    #[inline(always)]
    fn settles(&self, lo: f32, hi: f32) -> bool {
        self.a_ratio(lo, hi) <= SETTLED_RATIO
    }

    #[inline(always)]
    fn descends_inside(&self, lo: f32, hi: f32, depth: u32) -> bool {
        depth < PHASE_DEPTH && self.a_ratio(lo, hi) > DESCEND_RATIO
    }
}

impl SamplingTree {
    /// [`sample`](SamplingTree::sample) of the product with the phase function `lobe`: the
    /// point, its density on the square, and whether it may lie within rounding distance of its
    /// cell's border.
    pub(crate) fn sample_phase(&self, lobe: &PhaseLobe, u: Vec2) -> (Vec2, f32, bool) {
        let (point, pdf, near_border, _) = self.sample_product(lobe, u);
        (point, pdf, near_border)
    }

    /// [`pdf`](SamplingTree::pdf) of the product with the phase function `lobe` at
    /// `s ∈ [0,1)²`.
    pub(crate) fn pdf_phase(&self, lobe: &PhaseLobe, s: Vec2) -> f32 {
        self.pdf_product(lobe, s)
    }
}

/// The Henyey–Greenstein phase function's density at `μ = d·ω` (per steradian), for tests and
/// for a renderer's reference: `(1 − g²)/(4π·(1 + g² − 2gμ)^{3/2})`.
#[cfg(test)]
pub(crate) fn henyey_greenstein(mu: f64, g: f64) -> f64 {
    (1.0 - g * g) / (4.0 * std::f64::consts::PI * (1.0 + g * g - 2.0 * g * mu).powf(1.5))
}

#[cfg(test)]
#[path = "phase_tests.rs"]
mod tests;
