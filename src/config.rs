//! The field's configuration: every knob, its default, and the checks that reject absurd values.

use crate::filter::{DirectionalFilter, SpatialFilter};
use crate::guide_probability::{
    DEFAULT_MAX_GUIDE_PROBABILITY, INITIAL_GUIDE_PROBABILITY, MAX_GUIDE_COST, MAX_GUIDE_PROBABILITY,
};
use crate::refinement::Refinement;
use crate::rule::LeafRule;
use crate::spatial_split::SpatialSplit;
use serde::{Deserialize, Serialize};
use std::fmt;

/// The deepest directional quadtree level supported: a depth-20 cell is 2⁻²⁰ of the square on a
/// side, about as fine as `f32` sample coordinates can still resolve uniformly.
pub const MAX_DIRECTIONAL_DEPTH: u32 = 20;

/// The smallest [`GuidingConfig::uniform_fraction`]. A cell of the deepest level holds 4⁻²⁰ of
/// the square, so every sampling probability of a node is at least `ε·4⁻²⁰`; from 10⁻⁹ that is
/// above 10⁻²¹, which `f32` holds exactly enough, where a smaller `ε` could round a cell's
/// probability to zero and give a direction `sample` drew a density of 0.
pub const MIN_UNIFORM_FRACTION: f32 = 1e-9;

/// How a [`GuidingField`](crate::GuidingField) learns and how large it may grow.
///
/// Serializable (missing fields take their defaults) and checked by [`GuidingConfig::validate`],
/// which [`GuidingField::new`](crate::GuidingField::new) calls.
///
/// ```
/// use sdguide::{GuidingConfig, LeafRule};
/// let config = GuidingConfig { rule: LeafRule::L1, ..GuidingConfig::default() };
/// assert!(config.validate().is_ok());
/// let bad = GuidingConfig { subdivision_threshold: 2.0, ..GuidingConfig::default() };
/// assert_eq!(bad.validate().unwrap_err().field, "subdivision_threshold");
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GuidingConfig {
    /// How recorded statistics become leaf masses (default [`LeafRule::L2`]).
    pub rule: LeafRule,
    /// `c` in the spatial split rule: a spatial leaf splits when it received more than
    /// `c·sqrt(2^k)` samples in iteration `k` (default 12000). Must be finite and ≥ 1. A larger
    /// `c` gives fewer, larger cells: a smaller field with cheaper queries, and a guide that
    /// follows the light's change with position less closely (`docs/render.md` measures it).
    pub spatial_threshold: f32,
    /// Which spatial leaves split at refine (default [`SpatialSplit::Count`], the rule above).
    /// [`SpatialSplit::Gain`] splits where a leaf's halves see different light.
    pub spatial_split: SpatialSplit,
    /// `τ` of [`SpatialSplit::Gain`]: a spatial cell splits when its split lowers the
    /// estimator's second moment over the cell by more than `τ` of it, beyond what the noise
    /// of its sums gains (default 0.01, chosen with the quality harness and the demo:
    /// `docs/quality.md`, *Spatial splits*). Must be in `[0, 1)`.
    pub spatial_gain_threshold: f32,
    /// Which directional cells split at refine (default [`Refinement::VarianceGain`], chosen
    /// with the quality harness: see `docs/quality.md`).
    pub refinement: Refinement,
    /// `ρ` of [`Refinement::FluxShare`]: a directional cell is subdivided when its share of the
    /// tree's mass exceeds `ρ`, and collapsed when it does not (default 0.01). Must be in
    /// `(0, 1)`.
    pub subdivision_threshold: f32,
    /// `τ` of [`Refinement::VarianceGain`]: a directional cell is subdivided when splitting it
    /// lowers the tree's `Σ sqrt(m)` by more than `τ` times it, and collapsed when it does not
    /// (default 0.0007). Must be in `(0, 1)`.
    pub gain_threshold: f32,
    /// Deepest directional level (default and maximum [`MAX_DIRECTIONAL_DEPTH`]). Must be ≥ 1.
    pub max_directional_depth: u32,
    /// Fraction of every distribution spread uniformly over the sphere (default 0.01), so that no
    /// direction has zero density — cells that saw no light this iteration may still carry some,
    /// and a zero pdf there would bias the estimator. Must be in
    /// `[`[`MIN_UNIFORM_FRACTION`]`, 1]`; 1 is uniform sampling.
    pub uniform_fraction: f32,
    /// Cap on interior nodes per directional quadtree (default 8192). Refinement splits the
    /// cells with the largest share first and stops at the cap. Must be in `1..=65535`.
    pub max_directional_nodes: u32,
    /// Cap on spatial tree nodes (default 2²⁰). Spatial splits beyond it are refused and
    /// counted in [`FieldStats`](crate::FieldStats). Must be ≥ 1.
    pub max_spatial_nodes: u32,
    /// Memory budget in bytes (default 1 GiB): a spatial split that would take the field's
    /// footprint above it is refused, and each directional tree is held to its share of what
    /// the spatial tree and the trees' fixed parts (about 3 KB each) leave of it
    /// (`left / (trees · 456 bytes)` interior nodes, 456 bytes bounding what one node costs,
    /// 840 under [`DirectionalFilter::DeferredBox`]); refusals are counted. The
    /// products stored for frequent surface normals (see [`Sample::normal`](crate::Sample::normal))
    /// count too, and are dropped, largest first, where they would take the footprint above
    /// it. Must be ≥ 64 KiB.
    pub max_memory_bytes: u64,
    /// `n0`: how many samples' worth of weight a directional cell's estimate gives its parent's
    /// when leaf masses are computed: at refine a cell's sums become
    /// `w · own + (1 − w) · parent's / 4`, `w = n/(n + n0)`, top-down, so a sparse leaf
    /// borrows from its siblings (default 0.5, chosen for the l2 rule: `docs/quality.md`).
    /// 0 turns it off. Must be finite and ≥ 0.
    pub prior_samples: f32,
    /// `n_f`: how many samples a directional leaf must have seen before the second moment of
    /// its own samples weighs as much as the filtered one in the l2 rules' masses; default
    /// `None`, the filtered sums alone. With `Some(n_f)`, under a filter that spreads samples
    /// (the directional box filters, the spatial box and stochastic ones), a leaf's mass uses
    /// `w·own + (1 − w)·filtered`, `w = n/(n + n_f)`, `n` its samples. The filter pools
    /// neighbouring leaves' evidence where a leaf saw few samples; where it saw many, what it
    /// carries in from a small bright neighbour can cost more than the noise it removes, and
    /// the square root of the l2 mass magnifies it (a leaf handed 4% of a source's second
    /// moment takes 20% of its mass). 128 is the value measured: 2.5× lower variance under a
    /// tiny sun, but on heavy-tailed values a count overstates what a leaf's own sums know
    /// (`docs/quality.md`, *Filters*). [`LeafRule::L1`] keeps only filtered first moments and
    /// is unaffected. Must be finite and ≥ 0.
    pub filter_samples: Option<f32>,
    /// How a sample is spread over spatial leaves (default [`SpatialFilter::Nearest`], chosen
    /// with the quality harness).
    pub spatial_filter: SpatialFilter,
    /// How a sample is spread over directional leaves (default [`DirectionalFilter::Box`], chosen
    /// with the quality harness: lower variance on every light field, most on noisy ones).
    pub directional_filter: DirectionalFilter,
    /// The largest guide probability `a` a spatial leaf learns (default 0.75; see
    /// [`DirectionalDistribution::guide_probability`](crate::DirectionalDistribution::guide_probability)).
    /// The BSDF keeps at least `1 − a` of
    /// the samples, which bounds a vertex's second moment by `1/(1 − a)` times BSDF sampling's
    /// alone, whatever the guide learned wrong. Must be in
    /// `[0.5, `[`MAX_GUIDE_PROBABILITY`](crate::MAX_GUIDE_PROBABILITY)`]`.
    pub max_guide_probability: f32,
    /// What sampling the guide adds to the cost of a path vertex, relative to a vertex that
    /// samples only the BSDF; default `None`: every guide stays on. A spatial leaf whose guide does not
    /// lower the variance of its vertices' estimates below `1/(1 + guide_cost)` of BSDF
    /// sampling's turns the guide off: its guide probability reads 0 until an iteration's
    /// samples show the guide paying again. A leaf where continuations were recorded
    /// ([`GuidingField::record_continuation`](crate::GuidingField::record_continuation))
    /// keeps its guide on. Set it only to what a guided vertex was measured to cost in your
    /// renderer: render a pass with the guide probability fixed at 0 and one with the learned
    /// one, from the same trained field; the ratio of their times per vertex, less 1 (the
    /// demo's `render --cost` does it; 0.25 there). A guess too high turns guides off that
    /// pay. `Some(0.0)` turns a guide off only where it does not lower the variance at all.
    /// Must be finite and in `[0, 100]`.
    pub guide_cost: Option<f32>,
    /// Whether every spatial leaf keeps a second guide, for vertices inside participating
    /// media; default `false`. A medium vertex receives light from the whole sphere and
    /// samples the guide's product with its phase function
    /// ([`DirectionalDistribution::with_phase`](crate::DirectionalDistribution::with_phase)),
    /// so it learns apart from the surfaces: samples with [`Sample::volume`](crate::Sample::volume)
    /// go to it, and [`GuidingField::volume_distribution`](crate::GuidingField::volume_distribution)
    /// reads it. Without it a medium sample is rejected
    /// ([`RejectReason::NoVolumeGuide`](crate::RejectReason::NoVolumeGuide)). The second
    /// guide shares the memory budget and the continuation estimate of its leaf.
    pub volumes: bool,
}

impl Default for GuidingConfig {
    fn default() -> Self {
        Self {
            rule: LeafRule::L2,
            spatial_threshold: 12000.0,
            spatial_split: SpatialSplit::Count,
            spatial_gain_threshold: 0.01,
            refinement: Refinement::VarianceGain,
            subdivision_threshold: 0.01,
            gain_threshold: 0.0007,
            max_directional_depth: MAX_DIRECTIONAL_DEPTH,
            uniform_fraction: 0.01,
            max_directional_nodes: 8192,
            max_spatial_nodes: 1 << 20,
            max_memory_bytes: 1 << 30,
            prior_samples: 0.5,
            filter_samples: None,
            spatial_filter: SpatialFilter::Nearest,
            directional_filter: DirectionalFilter::Box,
            max_guide_probability: DEFAULT_MAX_GUIDE_PROBABILITY,
            guide_cost: None,
            volumes: false,
        }
    }
}

impl GuidingConfig {
    /// Checks every field against its documented range.
    ///
    /// # Errors
    ///
    /// A [`ConfigError`] naming the first field out of its documented range.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let check = |ok: bool, field: &'static str, value: String, requirement: &'static str| {
            if ok {
                Ok(())
            } else {
                Err(ConfigError {
                    field,
                    value,
                    requirement,
                })
            }
        };
        check(
            self.spatial_threshold.is_finite() && self.spatial_threshold >= 1.0,
            "spatial_threshold",
            self.spatial_threshold.to_string(),
            "a finite number >= 1",
        )?;
        check(
            (0.0..1.0).contains(&self.spatial_gain_threshold),
            "spatial_gain_threshold",
            self.spatial_gain_threshold.to_string(),
            "a number in [0, 1)",
        )?;
        check(
            self.subdivision_threshold > 0.0 && self.subdivision_threshold < 1.0,
            "subdivision_threshold",
            self.subdivision_threshold.to_string(),
            "a number in (0, 1)",
        )?;
        check(
            self.gain_threshold > 0.0 && self.gain_threshold < 1.0,
            "gain_threshold",
            self.gain_threshold.to_string(),
            "a number in (0, 1)",
        )?;
        check(
            (1..=MAX_DIRECTIONAL_DEPTH).contains(&self.max_directional_depth),
            "max_directional_depth",
            self.max_directional_depth.to_string(),
            "an integer in 1..=20",
        )?;
        check(
            (MIN_UNIFORM_FRACTION..=1.0).contains(&self.uniform_fraction),
            "uniform_fraction",
            self.uniform_fraction.to_string(),
            "a number in [1e-9, 1]",
        )?;
        check(
            (1..=crate::quadtree::MAX_NODES).contains(&self.max_directional_nodes),
            "max_directional_nodes",
            self.max_directional_nodes.to_string(),
            "an integer in 1..=65535",
        )?;
        check(
            self.max_spatial_nodes >= 1,
            "max_spatial_nodes",
            self.max_spatial_nodes.to_string(),
            "an integer >= 1",
        )?;
        check(
            self.max_memory_bytes >= 64 * 1024,
            "max_memory_bytes",
            self.max_memory_bytes.to_string(),
            "at least 65536",
        )?;
        check(
            self.prior_samples.is_finite() && self.prior_samples >= 0.0,
            "prior_samples",
            self.prior_samples.to_string(),
            "a finite number >= 0",
        )?;
        check(
            self.filter_samples
                .is_none_or(|n| n.is_finite() && n >= 0.0),
            "filter_samples",
            format!("{:?}", self.filter_samples),
            "None, or a finite number >= 0",
        )?;
        check(
            (INITIAL_GUIDE_PROBABILITY..=MAX_GUIDE_PROBABILITY)
                .contains(&self.max_guide_probability),
            "max_guide_probability",
            self.max_guide_probability.to_string(),
            "a number in [0.5, 0.95]",
        )?;
        check(
            self.guide_cost
                .is_none_or(|c| (0.0..=MAX_GUIDE_COST).contains(&c)),
            "guide_cost",
            format!("{:?}", self.guide_cost),
            "None, or a number in [0, 100]",
        )
    }
}

/// A configuration value (or the scene bounds) outside its documented range.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConfigError {
    /// The offending field, as named in [`GuidingConfig`] (or `"bounds"`).
    pub field: &'static str,
    /// The value that was given, printed.
    pub value: String,
    /// What the field must be.
    pub requirement: &'static str,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "invalid `{}` = {}: must be {}",
            self.field, self.value, self.requirement
        )
    }
}

impl std::error::Error for ConfigError {}
