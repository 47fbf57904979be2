//! # sdguide — path guiding with variance-optimal SD-trees
//!
//! sdguide learns, while a renderer renders, where light comes from, and hands back a
//! directional distribution to sample at every path vertex. Its structure is the SD-tree: a
//! spatial binary tree over the scene with a directional quadtree over the sphere in every
//! spatial leaf. What sets it apart is the leaf rule: every cell keeps the sum *and the sum of
//! squares* of its samples, and leaf masses follow the optimal l2 rule
//! `mass ∝ sqrt(|C|·Σ v²/p)`, which minimizes the variance of the importance-sampling
//! estimator (Pantaleoni & Heitz, "Notes on optimal approximations for importance sampling").
//!
//! ## Data flow
//!
//! ```text
//!   record   render threads, &self, lock-free     Sample ─► filter ─► region (spatial leaf) ─► quadtree leaf moments
//!                                                  (mixture terms ─► the leaf's guide-selection sums;
//!                                                   under L2Mixture also the value: f·sqrt(p_s·p_g)/q)
//!   refine   between iterations, &mut self        (deferred box filter: pending quadrant sums ─► moments)
//!                                                  moments (l2: own second moment blended in) ─► shrinkage ─► rule masses ─► sampling tree
//!                                                  quadrant sums ─► split gains ─► new topology
//!                                                  counts (or split signatures) ─► spatial splits
//!                                                  guide probability ─► one Newton step
//!                                                  tallied normals ─► stored products with the cosine
//!   query    render threads, &self, lock-free     distribution(x) ─► sample(u) / pdf(ω) / guide_probability()
//!                                                  distribution(x).at_surface(n) ─► the same, times the clamped cosine
//!                                                    (stored for the cell's frequent normals, else weighed on the way down)
//!
//!   save     GuidingField::save / save_to_path     field ─► versioned, checksummed cache bytes
//!   load     GuidingField::load / load_from_path   cache bytes ─► validated field (or CacheError)
//!   merge    GuidingField::merge                   worker fields ─► summed statistics (exact) ─► refine
//!
//!   a path, per render thread:
//!   PathRecorder   push / add_radiance / roulette / split as they happen ─► finish ─► every
//!                  vertex's Sample (incident value, roulette-free square) and Continuation ─► record
//!
//!   roulette and splitting, beside the guide:
//!   record   record_continuation(c)                 a traced continuation's value and cost ─► the leaf's sums
//!   refine                                          sums ─► the leaf's continuation estimate
//!   query    continuation(x) ─► Splitting::factor   how many continuations to trace from a vertex
//! ```
//!
//! ## Determinism
//!
//! Every statistic a field keeps is an exact fixed-point sum (`exact`: integers in units of
//! 2⁻⁴⁰, a term clamped at 2⁴⁸ and counted in [`FieldStats::clamped_samples`]), and everything
//! `refine` decides follows from the sums alone. So the same samples give the same field —
//! the same [`GuidingField::to_bytes`] — whatever the number of threads that recorded them,
//! the order they arrived in, or how a farm split them over workers and [merged](GuidingField::merge)
//! the workers' fields, in any order. A render whose samples depend only on its seed and the
//! field trains the same field every time.
//!
//! ```
//! use sdguide::{Aabb, GuidingConfig, GuidingField, Sample};
//! use glam::{Vec2, Vec3};
//!
//! let mut field = GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), GuidingConfig::default())?;
//! for _iteration in 0..3 {
//!     // Render: at each path vertex, guide the direction...
//!     let dist = field.distribution(Vec3::new(0.2, 0.5, 0.5));
//!     let (direction, pdf) = dist.sample(Vec2::new(0.25, 0.75));
//!     // ...trace, and once the path is done, record what arrived from there.
//!     let radiance = 1.0;
//!     let position = Vec3::new(0.2, 0.5, 0.5);
//!     field.record(&Sample { position, direction, value: radiance, pdf, ..Sample::default() });
//!     // Between passes: learn.
//!     field.refine();
//! }
//! assert_eq!(field.stats().iteration, 3);
//! # Ok::<(), sdguide::ConfigError>(())
//! ```
//!
//! ## Modules
//!
//! The modules are private; every public item is re-exported here, with one path each
//! (`sphere`'s functions keep theirs: `sdguide::sphere::square_to_direction`). In the order a
//! sample travels:
//!
//! - `sample`, `config`: what goes in — [`Sample`] (checked: [`RejectReason`]),
//!   [`MixtureTerms`], [`GuidingConfig`] (validated: [`ConfigError`]).
//! - `field`: [`GuidingField`], which routes samples, continuations and queries to the
//!   spatial leaf that holds their position (`spatial`, the binary tree over the scene's
//!   bounding cube; `spatial_split`, [`SpatialSplit`]: which spatial leaves split, by count or
//!   by what the split gains; `filter`, [`SpatialFilter`] and [`DirectionalFilter`]).
//! - `region`: one spatial leaf's state — its directional quadtree, its tally of normals and
//!   their stored products, its guide probability, its continuation sums — and its part in
//!   record, refine and merge.
//! - `quadtree`: the double-buffered directional quadtree: `recording` (what `record` adds
//!   to), `splat` (the directional box filter), `refine` (from the iteration's recording tree
//!   to the next sampling and recording trees), `sampling` (what `sample` and `pdf` descend),
//!   `product` (the descent of a guide's product with a lobe), `horizon` and `surfaces` (the
//!   product with the clamped cosine), `phase` (the product with a Henyey–Greenstein phase
//!   function).
//! - `moments` ([`Moments`]: `Σ v/p`, `Σ v²/p`, `n`), kept as `exact` sums; `rule`
//!   ([`LeafRule`]: how moments become leaf masses), `refinement` ([`Refinement`]: which
//!   directional cells to split).
//! - `guide_probability`: the per-region probability of sampling the guide rather than the
//!   BSDF, and whether the guide pays for its cost there.
//! - `path`: [`PathRecorder`], which turns a camera sample's vertices, as the renderer reports
//!   them, into their [`Sample`]s and [`Continuation`]s ([`PathVertex`], [`PathRecord`]).
//! - `splitting`: efficiency-aware Russian roulette and splitting — [`Continuation`],
//!   [`ContinuationEstimate`], [`Splitting`]; `image`: the image terms it needs,
//!   [`ImageStatistics`], and the passes' combination by inverse variance, [`pass_weights`].
//! - `distribution`: what queries return — [`DirectionalDistribution`], its product with a
//!   surface's clamped cosine, [`SurfaceDistribution`], and with a medium's phase function,
//!   [`PhaseDistribution`].
//! - `batch`: the queries and `record` over slices, for wavefront renderers
//!   ([`GuidingField::sample_batch`], [`BatchError`]).
//! - `cache` (save, load: [`CacheError`]; the format is `docs/cache-format.md`), `merge`
//!   ([`MergeError`]), `stats` ([`FieldStats`]).
//! - [`sphere`]: the equal-area map between directions and the unit square.
//! - `techniques`: [`TechniqueProbabilities`], variance-optimal selection probabilities among
//!   any sampling techniques a renderer mixes (the paper's section 3).
//!
//! The analytic light fields, the training workload and the quality harness the tests and the
//! documented tables use live in the workspace's `lab` crate, not here.

#![deny(missing_docs)]
#![forbid(unsafe_code)]

mod batch;
mod bounds;
mod cache;
mod config;
mod distribution;
mod exact;
mod field;
mod filter;
mod guide_probability;
mod image;
mod merge;
mod moments;
mod path;
mod quadtree;
mod refinement;
mod region;
mod rule;
mod sample;
mod spatial;
mod spatial_split;
pub mod sphere;
mod splitting;
mod stats;
mod techniques;

/// The vector types of the API (`Vec2`, `Vec3`), from the glam version sdguide is built with.
pub use glam;

// The public surface: every item has this one path (`sphere`'s functions are reached through
// their module, `sdguide::sphere::…`).
pub use batch::{BATCH_CHUNK, BatchError};
pub use bounds::Aabb;
pub use cache::{CacheError, FORMAT_MAJOR, FORMAT_MINOR, MAGIC};
pub use config::{ConfigError, GuidingConfig, MAX_DIRECTIONAL_DEPTH, MIN_UNIFORM_FRACTION};
pub use distribution::{DirectionalDistribution, PhaseDistribution, SurfaceDistribution};
pub use field::{GuidingField, SpatialCell};
pub use filter::{DirectionalFilter, SpatialFilter};
pub use guide_probability::{
    DEFAULT_MAX_GUIDE_PROBABILITY, INITIAL_GUIDE_PROBABILITY, MAX_GUIDE_COST,
    MAX_GUIDE_PROBABILITY, MIN_GUIDE_PROBABILITY,
};
pub use image::{ImageStatistics, PixelSums, pass_weights};
pub use merge::MergeError;
pub use moments::Moments;
pub use path::{PathRecord, PathRecorder, PathRecorderStats, PathVertex, TechniquePdfs, VertexId};
pub use quadtree::DirectionalCell;
pub use refinement::Refinement;
pub use rule::LeafRule;
pub use sample::{MixtureTerms, RejectReason, Sample};
pub use spatial_split::SpatialSplit;
pub use splitting::{
    Continuation, ContinuationEstimate, MIN_CONTINUATIONS, Splitting, SplittingMode, continuations,
};
pub use stats::{FieldStats, Rejections};
pub use techniques::{MIN_TECHNIQUE_SAMPLES, TechniqueError, TechniqueProbabilities};

/// Uniform `f32`s in `[0, 1)` from a 64-bit LCG seeded with `seed`: the unit tests' random
/// stream (the `lab` crate's is for the integration tests, which depend on it).
#[cfg(test)]
pub(crate) fn test_uniforms(seed: u64) -> impl FnMut() -> f32 {
    let mut state = seed;
    move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 40) as f32 / (1u64 << 24) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn field_is_send_and_sync() {
        fn check<T: Send + Sync>() {}
        check::<GuidingField>();
        check::<DirectionalDistribution<'static>>();
        check::<SurfaceDistribution<'static>>();
        check::<PhaseDistribution<'static>>();
    }
}

/// The README's examples, compiled and run as doctests.
#[doc = include_str!("../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;
