//! The plain C types a render thread passes in: vectors, samples, continuations and the
//! splitting policy, and their conversions to the Rust types.

use crate::error::{Failure, fail, sdg_status};
use glam::Vec3;
use sdguide::{Continuation, Sample, Splitting, SplittingMode};

/// A 3D vector (world space).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct sdg_vec3 {
    /// x
    pub x: f32,
    /// y
    pub y: f32,
    /// z
    pub z: f32,
}

impl From<sdg_vec3> for Vec3 {
    fn from(v: sdg_vec3) -> Vec3 {
        Vec3::new(v.x, v.y, v.z)
    }
}

impl From<Vec3> for sdg_vec3 {
    fn from(v: Vec3) -> sdg_vec3 {
        sdg_vec3 {
            x: v.x,
            y: v.y,
            z: v.z,
        }
    }
}

/// One recorded path vertex (see the Rust `Sample`): at `position`, light of `value` arrived
/// from `direction`, which was drawn with solid-angle density `pdf` (the full mixture pdf).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct sdg_sample {
    /// Where the light arrived.
    pub position: sdg_vec3,
    /// Where it came from (need not be normalized).
    pub direction: sdg_vec3,
    /// Non-negative estimate of what arrived (luminance).
    pub value: f32,
    /// Solid-angle density the direction was drawn with (the full mixture pdf).
    pub pdf: f32,
    /// Mixture terms for learning the guide probability (see
    /// `sdg_distribution_guide_probability`), read with `SDG_SAMPLE_MIXTURE` in `flags`: the
    /// integrand `L·f_s·|cos|` at the direction, and the BSDF's and the guide's pdfs of it.
    pub integrand: f32,
    /// The BSDF sampling pdf of the direction.
    pub bsdf_pdf: f32,
    /// The guide's pdf of the direction.
    pub guide_pdf: f32,
    /// The shading normal at `position`, the one set with `sdg_distribution_set_normal` there
    /// (see the Rust `Sample::normal`: a cell stores the product with the cosine for its most
    /// frequent normals, which makes those queries about as cheap as plain ones). Read with
    /// `SDG_SAMPLE_NORMAL` in `flags`.
    pub normal: sdg_vec3,
    /// An estimate of `value²` without the variance the renderer's Russian roulette added to
    /// `value` (see the Rust `Sample::second_moment`: with throughput roulette, `value²` rises
    /// with the pdf, and the l2 rule would keep directions the guide already favours). Read
    /// with `SDG_SAMPLE_SECOND_MOMENT` in `flags`; without it `value²` is used.
    pub second_moment: f32,
    /// Which optional fields are set: `SDG_SAMPLE_MIXTURE`, `SDG_SAMPLE_NORMAL`,
    /// `SDG_SAMPLE_SECOND_MOMENT`, `SDG_SAMPLE_VOLUME`, or'ed; 0 for none.
    pub flags: u32,
}

/// In `sdg_sample::flags`: `integrand`, `bsdf_pdf` and `guide_pdf` are set.
pub const SDG_SAMPLE_MIXTURE: u32 = 1;
/// In `sdg_sample::flags`: `normal` is set.
pub const SDG_SAMPLE_NORMAL: u32 = 2;
/// In `sdg_sample::flags`: `second_moment` is set.
pub const SDG_SAMPLE_SECOND_MOMENT: u32 = 4;
/// In `sdg_sample::flags` and `sdg_path_vertex::flags`: the vertex lies inside a participating
/// medium, and the sample goes to its leaf's volume guide (see the Rust `Sample::volume`); the
/// mixture terms are then the phase function's. A field without `SDG_CONFIG_VOLUMES` rejects
/// it (counted in `sdg_stats::rejected_no_volume_guide`).
pub const SDG_SAMPLE_VOLUME: u32 = 8;

impl sdg_sample {
    /// The library sample this one means (the library checks it when recording).
    pub(crate) fn to_rust(self) -> Sample {
        let has = |flag: u32| self.flags & flag != 0;
        let sample = Sample {
            position: self.position.into(),
            direction: self.direction.into(),
            value: self.value,
            pdf: self.pdf,
            normal: has(SDG_SAMPLE_NORMAL).then_some(self.normal.into()),
            second_moment: has(SDG_SAMPLE_SECOND_MOMENT).then_some(self.second_moment),
            volume: has(SDG_SAMPLE_VOLUME),
            ..Sample::default()
        };
        if has(SDG_SAMPLE_MIXTURE) {
            sample.with_mixture(self.integrand, self.bsdf_pdf, self.guide_pdf)
        } else {
            sample
        }
    }
}

/// Splitting mode: Russian roulette only (factors up to 1).
pub const SDG_SPLITTING_ROULETTE: u32 = 0;
/// Splitting mode: roulette and splitting (factors up to `max_splits`).
pub const SDG_SPLITTING_ROULETTE_AND_SPLITTING: u32 = 1;

/// One traced continuation of a path vertex (see the Rust `Continuation`): at `position`, the
/// continuation's estimate `value` of the light the vertex reflects (`f·cos·L_i/p`, with every
/// roulette and splitting weight below the vertex and not the vertex's own), and its `cost`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct sdg_continuation {
    /// The vertex.
    pub position: sdg_vec3,
    /// Non-negative estimate of the reflected light (luminance).
    pub value: f32,
    /// Non-negative cost of tracing the continuation (rays, say).
    pub cost: f32,
}

/// The image-wide terms of efficiency-aware roulette and splitting (see the Rust `Splitting`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct sdg_splitting {
    /// `SDG_SPLITTING_ROULETTE` or `SDG_SPLITTING_ROULETTE_AND_SPLITTING`.
    pub mode: u32,
    /// The image's per-sample relative variance, averaged over pixels.
    pub relative_variance: f64,
    /// The mean cost of a camera sample, in the unit of `sdg_continuation::cost`.
    pub cost: f64,
    /// The smallest survival probability, in (0, 1] (0.05 is the library's default).
    pub min_survival: f32,
    /// The largest factor, finite and at least 1 (8 is the library's default).
    pub max_splits: f32,
}

impl sdg_continuation {
    /// The library continuation this one means (the library checks it when recording).
    pub(crate) fn to_rust(self) -> Continuation {
        Continuation {
            position: self.position.into(),
            value: self.value,
            cost: self.cost,
        }
    }
}

impl sdg_splitting {
    /// The library policy this one means: an unknown mode or bounds out of range fail.
    pub(crate) fn to_rust(self) -> Result<Splitting, Failure> {
        let mode = match self.mode {
            SDG_SPLITTING_ROULETTE => SplittingMode::Roulette,
            SDG_SPLITTING_ROULETTE_AND_SPLITTING => SplittingMode::RouletteAndSplitting,
            m => return fail(sdg_status::InvalidArgument, format!("unknown mode {m}")),
        };
        Splitting::new(mode, self.relative_variance, self.cost)
            .with_bounds(self.min_survival, self.max_splits)
            .or_else(|e| fail(sdg_status::InvalidArgument, e.to_string()))
    }
}
