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
//!   record   render threads, &self, lock-free     Sample ─► filter ─► spatial leaf ─► quadtree leaf moments
//!                                                  (mixture terms ─► the leaf's guide-selection sums;
//!                                                   under L2Mixture also the value: f·sqrt(p_s·p_g)/q)
//!   refine   between iterations, &mut self        (deferred box filter: pending quadrant sums ─► moments)
//!                                                  moments ─► shrinkage ─► rule masses ─► sampling tree
//!                                                  quadrant sums ─► split gains ─► new topology
//!                                                  guide probability ─► one Newton step
//!                                                  tallied normals ─► stored products with the cosine
//!   query    render threads, &self, lock-free     distribution(x) ─► sample(u) / pdf(ω) / guide_probability()
//!                                                  distribution(x).at_surface(n) ─► the same, times the clamped cosine
//!                                                    (stored for the cell's frequent normals, else weighed on the way down)
//!
//!   save     GuidingField::save / save_to_path     field ─► versioned, checksummed cache bytes
//!   load     GuidingField::load / load_from_path   cache bytes ─► validated field (or CacheError)
//!   merge    GuidingField::merge                   worker fields ─► summed statistics ─► refine
//!
//!   roulette and splitting, beside the guide:
//!   record   record_continuation(c)                 a traced continuation's value and cost ─► the leaf's sums
//!   refine                                          sums ─► the leaf's continuation estimate
//!   query    continuation(x) ─► Splitting::factor   how many continuations to trace from a vertex
//! ```
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
//! - [`sphere`]: the equal-area map between directions and the unit square.
//! - `moments`: the per-cell sums `Σ v/p`, `Σ v²/p`, `n` and their lock-free accumulation.
//! - `rule`: [`LeafRule`], how moments become leaf masses, and the L2 rule inside the
//!   guide–BSDF mixture.
//! - `quadtree`: the double-buffered directional quadtree: `sampling` (what `sample` and `pdf`
//!   descend), `recording` (what `record` adds to), `splat` (the directional box filter) and
//!   `refine` (the next distribution and topology).
//! - [`refinement`]: which directional cells to split — by flux share, or by the variance a
//!   split removes.
//! - `spatial`: the binary tree over the scene's bounding cube.
//! - `field`: [`GuidingField`], which ties them together.
//! - `distribution`: what queries return — [`DirectionalDistribution`], and its product with a
//!   surface's clamped cosine, [`SurfaceDistribution`] (the descent is `quadtree`'s `horizon`).
//! - `cache`: the cache file format (save, load, validation; see `docs/cache-format.md`).
//! - [`filter`]: spreading a recorded sample over neighbouring cells (splatting).
//! - `merge`: adding the statistics of fields trained in parallel.
//! - [`mixture`]: variance-optimal selection probabilities among sampling techniques.
//! - [`splitting`]: efficiency-aware Russian roulette and splitting — the continuation moments
//!   each spatial leaf learns, and the factor they give.
//! - [`guide_probability`]: the per-cell probability of sampling the guide rather than the BSDF.
//! - `config`, `sample`, `stats`: what goes in ([`GuidingConfig`], [`Sample`]) and what comes
//!   out ([`FieldStats`]).
//!
//! The analytic light fields, the training workload and the quality harness the tests and the
//! documented tables use live in the workspace's `lab` crate, not here.

#![deny(missing_docs)]
#![forbid(unsafe_code)]

mod bounds;
mod cache;
mod config;
mod distribution;
mod field;
pub mod filter;
pub mod guide_probability;
mod merge;
pub mod mixture;
mod moments;
mod quadtree;
pub mod refinement;
mod rule;
mod sample;
mod spatial;
pub mod sphere;
pub mod splitting;
mod stats;

/// The vector types of the API (`Vec2`, `Vec3`), from the glam version sdguide is built with.
pub use glam;

pub use bounds::Aabb;
pub use cache::{CacheError, FORMAT_MAJOR, FORMAT_MINOR, MAGIC};
pub use config::{ConfigError, GuidingConfig, MAX_DIRECTIONAL_DEPTH, MIN_UNIFORM_FRACTION};
pub use distribution::{DirectionalDistribution, SurfaceDistribution};
pub use field::{GuidingField, SpatialCell};
pub use filter::{DirectionalFilter, SpatialFilter};
pub use merge::MergeError;
pub use moments::Moments;
pub use quadtree::DirectionalCell;
pub use refinement::Refinement;
pub use rule::LeafRule;
pub use sample::{MixtureTerms, RejectReason, Sample};
pub use splitting::{Continuation, ContinuationEstimate, Splitting, SplittingMode};
pub use stats::{FieldStats, Rejections};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn field_is_send_and_sync() {
        fn check<T: Send + Sync>() {}
        check::<GuidingField>();
        check::<DirectionalDistribution<'static>>();
        check::<SurfaceDistribution<'static>>();
    }
}

/// The README's examples, compiled and run as doctests.
#[doc = include_str!("../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;
