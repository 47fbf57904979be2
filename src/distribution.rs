//! What queries return: a spatial cell's directional distribution, its product with a
//! surface's clamped cosine, and its product with a medium's phase function.
//!
//! Both borrow the cell's sampling tree; both are `Copy`, and `sample` and `pdf` neither
//! allocate nor lock, so a render thread takes one per path vertex. A direction's solid-angle
//! density is the tree's density on the square divided by 4π (the map of [`crate::sphere`]
//! preserves area), and `sample` returns exactly the density `pdf` gives its direction.

use crate::quadtree::{
    DirectionalCell, HORIZON_DEPTH, MAX_G, PHASE_DEPTH, PhaseLobe, SURFACE_DEPTH, SamplingTree,
    SurfaceTree, Surfaces,
};
use crate::sphere::{self, INV_SPHERE_AREA, square_to_direction};
use crate::splitting::ContinuationEstimate;
use glam::{Vec2, Vec3};

/// A piecewise-constant distribution over the sphere, borrowed from a [`GuidingField`](crate::GuidingField).
///
/// Cheap to create and to copy; `sample` and `pdf` neither allocate nor lock.
#[derive(Clone, Copy, Debug)]
pub struct DirectionalDistribution<'a> {
    tree: &'a SamplingTree,
    guide_probability: f32,
    continuation: &'a ContinuationEstimate,
    surfaces: &'a Surfaces,
}

impl<'a> DirectionalDistribution<'a> {
    /// The distribution of a region's sampling tree, with what else a query reads of it.
    #[inline]
    pub(crate) fn new(
        tree: &'a SamplingTree,
        guide_probability: f32,
        continuation: &'a ContinuationEstimate,
        surfaces: &'a Surfaces,
    ) -> Self {
        Self {
            tree,
            guide_probability,
            continuation,
            surfaces,
        }
    }

    /// Draws a direction from two uniform numbers `u ∈ [0,1)²` (clamped into that range).
    /// Returns the unit direction and its solid-angle density, which equals
    /// [`pdf`](Self::pdf) of the returned direction exactly.
    #[inline]
    pub fn sample(&self, u: Vec2) -> (Vec3, f32) {
        let (s, pdf, near_border) = self.tree.sample(u);
        let direction = square_to_direction(s);
        let pdf = if near_border {
            self.density_across_border(direction, pdf)
        } else {
            pdf
        };
        (direction, pdf * INV_SPHERE_AREA)
    }

    /// The density on the square that `pdf` finds for a sampled `direction` whose point lay
    /// within rounding distance of its leaf's border (`pdf` is the density the descent found).
    /// The round trip through the sphere moves a point by rounding only, but a point that close
    /// to the border may come back in the neighbour. Rarely taken, and kept out of line so that
    /// the inverse map does not weigh on how `sample` is compiled.
    #[cold]
    #[inline(never)]
    fn density_across_border(&self, direction: Vec3, pdf: f32) -> f32 {
        sphere::square_of(direction).map_or(pdf, |back| self.tree.pdf(back))
    }

    /// The solid-angle density of drawing `direction` (which need not be unit length; a zero or
    /// non-finite direction has density 0).
    #[inline]
    pub fn pdf(&self, direction: Vec3) -> f32 {
        match sphere::square_of(direction) {
            Some(s) => self.tree.pdf(s) * INV_SPHERE_AREA,
            None => 0.0,
        }
    }

    /// The learned probability `a` of sampling this distribution rather than the BSDF, for the
    /// one-sample mixture `a·pdf + (1 − a)·p_bsdf`, between 0.05 and the configuration's
    /// [`max_guide_probability`](crate::GuidingConfig::max_guide_probability); ½ until the cell
    /// has learned it from samples recorded with
    /// [`Sample::with_mixture`](crate::Sample::with_mixture). Each iteration takes one Newton
    /// step toward the `a` that minimizes the second moment of `f/q_a`, which is convex in `a`.
    ///
    /// 0 where the field turned the guide off, since it did not pay for its
    /// [`guide_cost`](crate::GuidingConfig::guide_cost) there: sample the BSDF alone, whose pdf
    /// is then the mixture's, and skip the guide's `pdf` — except in a pass that records,
    /// where the recorded mixture terms still need it.
    #[inline]
    pub fn guide_probability(&self) -> f32 {
        self.guide_probability
    }

    /// The cell's continuation estimate, for [`Splitting::factor`](crate::Splitting::factor):
    /// what [`GuidingField::continuation`](crate::GuidingField::continuation) returns at the
    /// same position, without a second lookup.
    #[inline]
    pub fn continuation(&self) -> ContinuationEstimate {
        *self.continuation
    }

    /// The distribution's product with the clamped cosine `max(0, n·ω)` about the surface
    /// normal `normal` (any length; it is normalized): what a vertex on a surface that only
    /// reflects should sample, since the integrand `f·cos·L` is zero below it.
    ///
    /// At each node of the guide's tree each quadrant's probability is weighed by an estimate
    /// of the cosine over it (from the cosine at its corners), and leaves the horizon crosses
    /// are descended further, as if split, down to depth 16. For a normal recorded often in
    /// the cell (see [`Sample::normal`](crate::Sample::normal)) the weights are stored at
    /// `refine` and the query descends them like the plain distribution; for any other normal
    /// they are computed on the way down. Either way it is the same distribution. Its density
    /// is exact (the product of the conditionals chosen), positive wherever `n·ω > 0`, and zero
    /// on cells the estimate proves wholly below the horizon; what is drawn below lies within
    /// a hair of the horizon (`docs/performance.md` measures how much). A zero or non-finite
    /// `normal` gives the plain distribution.
    ///
    /// ```
    /// use sdguide::{Aabb, GuidingConfig, GuidingField};
    /// use glam::{Vec2, Vec3};
    /// let field = GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), GuidingConfig::default())?;
    /// let surface = field.distribution(Vec3::splat(0.5)).at_surface(Vec3::Z);
    /// let (direction, pdf) = surface.sample(Vec2::new(0.3, 0.6));
    /// assert!(direction.z > 0.0);
    /// assert_eq!(pdf, surface.pdf(direction));
    /// // Straight below the surface, almost nothing.
    /// assert!(surface.pdf(-Vec3::Z) < 1e-4 * surface.pdf(Vec3::Z));
    /// # Ok::<(), sdguide::ConfigError>(())
    /// ```
    #[inline]
    pub fn at_surface(&self, normal: Vec3) -> SurfaceDistribution<'a> {
        let normal = sphere::normalize(normal);
        SurfaceDistribution {
            plain: *self,
            normal,
            stored: normal.and_then(|n| self.surfaces.product(n)),
        }
    }

    /// The distribution's product with the Henyey–Greenstein phase function of asymmetry `g`
    /// about `travel`, the direction the path travelled to reach the vertex (any length; it is
    /// normalized): what a vertex inside a participating medium should sample, from
    /// [`GuidingField::volume_distribution`](crate::GuidingField::volume_distribution). With
    /// `μ = d·ω` the phase function is `(1 − g²)/(4π·(1 + g² − 2gμ)^{3/2})`, so `g > 0` scatters
    /// forward, along `travel`.
    ///
    /// At each node of the guide's tree each quadrant's probability is weighed by the mean of
    /// the phase function over the range of `μ` on the quadrant's corners (the quadrant holding
    /// `travel` reaching `μ = 1`), and leaves over which the phase function varies by more than
    /// a factor of three are descended further, as if split, down to depth 10. Its density is
    /// exact (the product of the conditionals chosen) and positive everywhere, like the phase
    /// function's. `g` beyond ±0.999 is clamped to it (at ±1 the phase function is a Dirac
    /// delta, which no density represents); a NaN or zero `g`, or a zero or non-finite
    /// `travel`, gives the plain distribution (the phase function is then uniform, or has no
    /// axis).
    ///
    /// For the one-sample mixture with phase-function sampling, use this distribution's `pdf`
    /// as the guide's and the phase function's own pdf as the technique's, with
    /// [`guide_probability`](PhaseDistribution::guide_probability).
    #[inline]
    pub fn with_phase(&self, travel: Vec3, g: f32) -> PhaseDistribution<'a> {
        PhaseDistribution {
            plain: *self,
            lobe: PhaseLobe::new(travel, g),
        }
    }

    /// The leaves of the distribution with their probabilities (which sum to 1).
    pub fn leaves(&self) -> Vec<(DirectionalCell, f32)> {
        self.tree.leaves()
    }
}

/// A [`DirectionalDistribution`]'s product with a surface's clamped cosine, from
/// [`DirectionalDistribution::at_surface`].
///
/// Cheap to create and to copy; `sample` and `pdf` neither allocate nor lock. With a normal
/// the cell stores the product for, they cost about what the plain distribution's do; with
/// another, more (the weights are computed on the way down; the benches measure both).
#[derive(Clone, Copy, Debug)]
pub struct SurfaceDistribution<'a> {
    plain: DirectionalDistribution<'a>,
    /// The unit normal; `None` for a normal that has no direction (the plain distribution).
    normal: Option<Vec3>,
    /// The spatial leaf's stored product with this normal, if it has one.
    stored: Option<&'a SurfaceTree>,
}

impl SurfaceDistribution<'_> {
    /// Draws a direction from `u ∈ [0,1)²` (clamped into that range): the unit direction and
    /// its solid-angle density, which equals [`pdf`](Self::pdf) of the direction exactly.
    #[inline]
    pub fn sample(&self, u: Vec2) -> (Vec3, f32) {
        let Some(n) = self.normal else {
            return self.plain.sample(u);
        };
        let (s, pdf, near_border, centre) = match self.stored {
            Some(stored) => stored.sample(u),
            None => self.plain.tree.sample_surface(n, u),
        };
        let direction = square_to_direction(s);
        if !near_border {
            return (direction, pdf * INV_SPHERE_AREA);
        }
        self.across_border(direction, centre)
    }

    /// What `sample` returns for a point that may lie within rounding distance of its cell's
    /// border: the density `pdf` finds for its direction (the round trip through the sphere may
    /// have moved it into the neighbour). Rarely taken.
    #[cold]
    #[inline(never)]
    fn across_border(&self, direction: Vec3, centre: Vec2) -> (Vec3, f32) {
        let back = self.pdf(direction);
        if back > 0.0 {
            return (direction, back);
        }
        // The point came back in a neighbour wholly below the horizon, where the density is
        // 0: draw the cell's centre instead (a sliver of rounding width moves there), whose
        // round trip stays in the cell.
        let direction = square_to_direction(centre);
        (direction, self.pdf(direction))
    }

    /// The solid-angle density of drawing `direction` (which need not be unit length; a zero
    /// or non-finite direction has density 0).
    #[inline]
    pub fn pdf(&self, direction: Vec3) -> f32 {
        let Some(n) = self.normal else {
            return self.plain.pdf(direction);
        };
        let density = match (sphere::square_of(direction), self.stored) {
            (None, _) => 0.0,
            (Some(s), Some(stored)) => stored.pdf(s),
            (Some(s), None) => self.plain.tree.pdf_surface(n, s),
        };
        density * INV_SPHERE_AREA
    }

    /// The cell's learned guide probability, as
    /// [`DirectionalDistribution::guide_probability`].
    #[inline]
    pub fn guide_probability(&self) -> f32 {
        self.plain.guide_probability
    }

    /// The cell's continuation estimate, as [`DirectionalDistribution::continuation`].
    #[inline]
    pub fn continuation(&self) -> ContinuationEstimate {
        self.plain.continuation()
    }

    /// The unit normal the product is taken with (`None`: the plain distribution).
    pub fn normal(&self) -> Option<Vec3> {
        self.normal
    }
}

/// A [`DirectionalDistribution`]'s product with a Henyey–Greenstein phase function, from
/// [`DirectionalDistribution::with_phase`].
///
/// Cheap to create and to copy; `sample` and `pdf` neither allocate nor lock. They cost more
/// than the plain distribution's, the more the narrower the lobe (the benches measure it).
#[derive(Clone, Copy, Debug)]
pub struct PhaseDistribution<'a> {
    plain: DirectionalDistribution<'a>,
    /// The phase function; `None`: uniform, or without an axis (the plain distribution).
    lobe: Option<PhaseLobe>,
}

impl PhaseDistribution<'_> {
    /// Draws a direction from `u ∈ [0,1)²` (clamped into that range): the unit direction and
    /// its solid-angle density, which equals [`pdf`](Self::pdf) of the direction exactly.
    #[inline]
    pub fn sample(&self, u: Vec2) -> (Vec3, f32) {
        let Some(lobe) = &self.lobe else {
            return self.plain.sample(u);
        };
        let (s, pdf, near_border) = self.plain.tree.sample_phase(lobe, u);
        let direction = square_to_direction(s);
        if near_border {
            // The round trip through the sphere may have moved the point into the neighbour
            // (rarely): its density there, positive like every density of the product.
            return (direction, self.pdf(direction));
        }
        (direction, pdf * INV_SPHERE_AREA)
    }

    /// The solid-angle density of drawing `direction` (which need not be unit length; a zero
    /// or non-finite direction has density 0).
    #[inline]
    pub fn pdf(&self, direction: Vec3) -> f32 {
        let Some(lobe) = &self.lobe else {
            return self.plain.pdf(direction);
        };
        match sphere::square_of(direction) {
            Some(s) => self.plain.tree.pdf_phase(lobe, s) * INV_SPHERE_AREA,
            None => 0.0,
        }
    }

    /// The cell's learned probability of sampling the guide rather than the phase function
    /// (see [`DirectionalDistribution::guide_probability`]; 0 in a field without volumes).
    #[inline]
    pub fn guide_probability(&self) -> f32 {
        self.plain.guide_probability
    }

    /// The cell's continuation estimate, as [`DirectionalDistribution::continuation`].
    #[inline]
    pub fn continuation(&self) -> ContinuationEstimate {
        self.plain.continuation()
    }
}

const _: () = assert!(
    SURFACE_DEPTH == 8 && HORIZON_DEPTH == 16,
    "at_surface's documentation names the depth"
);

const _: () = assert!(
    PHASE_DEPTH == 10 && MAX_G == 0.999,
    "with_phase's documentation names the depth and the largest |g|"
);
