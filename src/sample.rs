//! What a renderer records at a path vertex, and the checks that keep bad values out of the field.
//!
//! **Why a second moment without roulette.** Roulette that follows the path's throughput plays
//! with a probability `s` that falls as a vertex's `pdf` rises, and the value it leaves, `1/s`
//! times what arrived, has a second moment that rises with it: so `value²` alone tells the l2
//! rule that directions the guide already samples often carry more light than they do, and the
//! rule keeps them. With `A` the part of the value that arrived before the first roulette after
//! the vertex and `s` that roulette's probability, `(Y² − (1 − s)·A²)/s` where the path
//! survived it, with `Y = A + s·(value − A)`, and `A²` where it ended there, is an unbiased
//! estimate of the square without that roulette, whatever the pdf: its expectation over the
//! roulette's coin is `(A + B)²`, `B` what the path would have brought after it. The field
//! scales what it records by `second_moment / value²`, so the estimate also serves
//! [`LeafRule::L2Mixture`]'s derived value; the mean the l1 rule weighs by is unbiased either
//! way and does not use it.

#[cfg(doc)]
use crate::rule::LeafRule;
use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

/// One recorded path vertex: at `position`, light of (scalar) value `value` arrived from
/// `direction`, which the renderer drew with solid-angle density `pdf`.
///
/// `pdf` must be the density the direction was *actually* drawn with — the full mixture pdf of
/// BSDF sampling and guiding — since the field weights every sample by `1/pdf`.
///
/// A sample is built with named fields, so that the value and the pdf, both `f32`, cannot be
/// swapped; the rest come from [`Default`]. A default sample has a zero direction and pdf, and
/// a field rejects (and counts) it: a forgotten field cannot pass for data.
///
/// ```
/// use sdguide::Sample;
/// use sdguide::glam::Vec3;
/// let s = Sample {
///     position: Vec3::new(0.5, 0.2, 0.1),
///     direction: Vec3::Z,
///     value: 3.0,
///     pdf: 0.25,
///     ..Sample::default()
/// };
/// assert!(s.check().is_ok());
/// assert!(Sample { value: f32::NAN, ..s }.check().is_err());
/// assert!(Sample::default().check().is_err());
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Sample {
    /// Where the light arrived (world space).
    pub position: Vec3,
    /// The direction it arrived from, pointing away from `position`. Need not be normalized.
    pub direction: Vec3,
    /// A non-negative estimate of what arrived, usually the luminance of the incident radiance.
    pub value: f32,
    /// The solid-angle density with which `direction` was drawn: finite and positive.
    pub pdf: f32,
    /// Three uniform numbers in `[0, 1)` for [`SpatialFilter::Stochastic`](crate::SpatialFilter)
    /// (ignored by the other filters). `None`: the field derives them from a hash of the
    /// sample, so recording is deterministic either way. Out-of-range values are clamped.
    pub jitter: Option<Vec3>,
    /// What the guide-vs-BSDF selection learns from, when the direction was drawn from the
    /// one-sample mixture of BSDF sampling and guiding (see
    /// [`DirectionalDistribution::guide_probability`](crate::DirectionalDistribution::guide_probability)).
    pub mixture: Option<MixtureTerms>,
    /// The shading normal at `position` (any length), the one the renderer passes to
    /// [`at_surface`](crate::DirectionalDistribution::at_surface) there. Each spatial cell
    /// tallies the normals recorded in it, and at [`refine`](crate::GuidingField::refine)
    /// stores the product with the cosine for its most frequent ones, so that `at_surface` with
    /// one of them costs about what the plain distribution costs (see
    /// [`SurfaceDistribution`](crate::SurfaceDistribution)). `None`, or a zero or non-finite
    /// normal: the sample is recorded without one.
    pub normal: Option<Vec3>,
    /// An estimate of `value²` without the variance the renderer's Russian roulette added to
    /// `value` (`None`: `value²`); non-negative and finite. With `A` what arrived before the
    /// first roulette after this vertex and `s` its probability: `(Y² − (1 − s)·A²)/s`,
    /// `Y = A + s·(value − A)`, where the path survived it, and `A²` where it ended there.
    pub second_moment: Option<f32>,
    /// Whether the vertex lies inside a participating medium (it scattered there, by a phase
    /// function): the sample then goes to its leaf's guide of medium vertices (see
    /// [`GuidingConfig::volumes`](crate::GuidingConfig::volumes)), and its mixture terms, if
    /// any, are those of the guide and the phase function. Default `false`: a surface vertex.
    #[serde(default)]
    pub volume: bool,
}

/// A sample's terms of the one-sample mixture `q = a·p_guide + (1 − a)·p_bsdf`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MixtureTerms {
    /// The full integrand at the direction, `L·f_s·|cos θ|` (at a medium vertex `L·p`, with
    /// `p` the phase function; a non-negative scalar, usually a luminance): what the mixture
    /// estimator divides by `q`.
    pub integrand: f32,
    /// The BSDF sampling pdf of the direction (solid angle; 0 where the BSDF cannot sample it);
    /// at a medium vertex, the phase function's.
    pub bsdf_pdf: f32,
    /// The guide's pdf of the direction ([`DirectionalDistribution::pdf`](crate::DirectionalDistribution::pdf)).
    pub guide_pdf: f32,
}

impl Sample {
    /// The sample with its mixture terms: the integrand `L·f_s·|cos θ|`, and the BSDF's and
    /// the guide's pdfs of the direction. `pdf` stays the mixture pdf it was drawn with. Pass
    /// the guide's pdf also where the guide probability is 0 (the BSDF drew the direction):
    /// from it the cell learns whether the guide pays again.
    ///
    /// ```
    /// use sdguide::{Aabb, GuidingConfig, GuidingField, Sample};
    /// use glam::{Vec2, Vec3};
    /// let field = GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), GuidingConfig::default())?;
    /// let x = Vec3::splat(0.5);
    /// let dist = field.distribution(x);
    /// let a = dist.guide_probability(); // ½ until the cell has learned it
    /// let (d, guide_pdf) = dist.sample(Vec2::new(0.2, 0.9));
    /// let bsdf_pdf = 0.1; // the BSDF's pdf of `d`
    /// let (radiance, bsdf_cos) = (2.0, 0.05);
    /// let q = a * guide_pdf + (1.0 - a) * bsdf_pdf;
    /// let sample = Sample { position: x, direction: d, value: radiance, pdf: q, ..Sample::default() }
    ///     .with_mixture(radiance * bsdf_cos, bsdf_pdf, guide_pdf);
    /// assert!(field.try_record(&sample).is_ok());
    /// # Ok::<(), sdguide::ConfigError>(())
    /// ```
    pub const fn with_mixture(mut self, integrand: f32, bsdf_pdf: f32, guide_pdf: f32) -> Self {
        self.mixture = Some(MixtureTerms {
            integrand,
            bsdf_pdf,
            guide_pdf,
        });
        self
    }

    /// The sample with the stochastic spatial filter's random numbers `u ∈ [0, 1)³`.
    ///
    /// ```
    /// use sdguide::{Aabb, GuidingConfig, GuidingField, Sample, SpatialFilter};
    /// use glam::Vec3;
    /// let config = GuidingConfig { spatial_filter: SpatialFilter::Stochastic, ..Default::default() };
    /// let field = GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), config)?;
    /// let s = Sample { position: Vec3::splat(0.5), direction: Vec3::Z, value: 1.0, pdf: 0.5, ..Sample::default() }
    ///     .with_jitter(Vec3::new(0.1, 0.7, 0.4));
    /// field.record(&s);
    /// assert_eq!(field.stats().samples_recorded, 1);
    /// # Ok::<(), sdguide::ConfigError>(())
    /// ```
    pub const fn with_jitter(mut self, u: Vec3) -> Self {
        self.jitter = Some(u);
        self
    }

    /// What the field scales the recorded second moment by: `second_moment / value²`, in
    /// `f64`; 1 without a second moment or with a zero value (which records nothing either
    /// way).
    #[inline]
    pub(crate) fn square_ratio(&self) -> f64 {
        match self.second_moment {
            Some(m) if self.value > 0.0 => f64::from(m) / f64::from(self.value).powi(2),
            _ => 1.0,
        }
    }

    /// Checks the sample and returns its direction's point on the unit square (see
    /// [`sphere`](crate::sphere)), or why the field rejects it.
    ///
    /// # Errors
    ///
    /// The [`RejectReason`] of the first check the sample fails.
    #[inline]
    pub fn check(&self) -> Result<Vec2, RejectReason> {
        if !self.position.is_finite() {
            return Err(RejectReason::NonFinitePosition);
        }
        // Values, second moments and the mixture's pdfs may be 0; the sample's own pdf may not.
        let non_negative = |v: f32| v >= 0.0 && v.is_finite();
        if !(non_negative(self.value) && self.second_moment.is_none_or(non_negative)) {
            return Err(RejectReason::BadValue);
        }
        if !(self.pdf > 0.0 && self.pdf.is_finite()) {
            return Err(RejectReason::BadPdf);
        }
        if let Some(m) = &self.mixture {
            if !non_negative(m.integrand) {
                return Err(RejectReason::BadValue);
            }
            if !(non_negative(m.bsdf_pdf) && non_negative(m.guide_pdf)) {
                return Err(RejectReason::BadPdf);
            }
        }
        crate::sphere::square_of(self.direction).ok_or(RejectReason::BadDirection)
    }
}

/// Why a recorded sample was rejected (the mixture terms, when given, are checked like the
/// value and the pdf). Each reason has its own counter in
/// [`FieldStats::rejected`](crate::FieldStats::rejected).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum RejectReason {
    /// A position coordinate was NaN or infinite.
    NonFinitePosition,
    /// The position lay outside the field's bounding cube (beyond a small tolerance).
    OutOfBounds,
    /// The direction was zero, NaN or infinite.
    BadDirection,
    /// The value (or the mixture's integrand, or the second moment) was negative, NaN or
    /// infinite.
    BadValue,
    /// The pdf was zero, negative, NaN or infinite (or a mixture pdf negative or not finite).
    BadPdf,
    /// A medium sample ([`Sample::volume`]) was recorded into a field without volumes
    /// ([`GuidingConfig::volumes`](crate::GuidingConfig::volumes)).
    NoVolumeGuide,
}

impl std::fmt::Display for RejectReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            RejectReason::NonFinitePosition => "the position is not finite",
            RejectReason::OutOfBounds => "the position lies outside the field's bounds",
            RejectReason::BadDirection => "the direction is zero or not finite",
            RejectReason::BadValue => "the value is negative or not finite",
            RejectReason::BadPdf => "the pdf is not positive and finite",
            RejectReason::NoVolumeGuide => "a medium sample, and the field keeps no volume guides",
        })
    }
}

impl std::error::Error for RejectReason {}
