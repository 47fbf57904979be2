//! The configuration as C sees it: `sdg_config`, its constants, and the one conversion each
//! way between it and the Rust `GuidingConfig`.

use crate::error::{Failure, fail, guard, put, sdg_status};
use sdguide::{
    DirectionalFilter, GuidingConfig, LeafRule, Refinement, SpatialFilter, SpatialSplit,
};

/// Leaf rule `L1`: mass proportional to the mean.
pub const SDG_RULE_L1: u32 = 0;
/// Leaf rule `L2`: the variance-optimal rule (the default).
pub const SDG_RULE_L2: u32 = 1;
/// The L2 rule for the renderer's estimator inside the guide–BSDF mixture (samples recorded
/// with their mixture terms).
pub const SDG_RULE_L2_MIXTURE: u32 = 2;

/// Filter: record into the cell containing the sample only.
pub const SDG_FILTER_NEAREST: u32 = 0;
/// Spatial filter: move the position by a random offset within its leaf (hash-derived).
pub const SDG_FILTER_STOCHASTIC: u32 = 1;
/// Filter: spread the sample over the cells a cell-sized box around it overlaps.
pub const SDG_FILTER_BOX: u32 = 2;
/// Directional filter: the box filter applied at refine to each leaf quadrant's sums (records
/// in about half the time of `SDG_FILTER_BOX`).
pub const SDG_FILTER_DEFERRED_BOX: u32 = 3;

/// Refinement: split directional cells by their share of the mass (`subdivision_threshold`).
pub const SDG_REFINEMENT_FLUX_SHARE: u32 = 0;
/// Refinement: split directional cells by the variance the split removes (`gain_threshold`;
/// the default).
pub const SDG_REFINEMENT_VARIANCE_GAIN: u32 = 1;

/// Spatial splits: a leaf splits past `c·sqrt(2^k)` samples in iteration `k` (the default).
pub const SDG_SPATIAL_SPLIT_COUNT: u32 = 0;
/// Spatial splits: a leaf splits where its halves see different light
/// (`spatial_gain_threshold`).
pub const SDG_SPATIAL_SPLIT_GAIN: u32 = 1;

/// The field's configuration; `sdg_config_default` fills in the defaults. Fields mean what the
/// same-named fields of the Rust `GuidingConfig` mean.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct sdg_config {
    /// `SDG_RULE_L1`, `SDG_RULE_L2` or `SDG_RULE_L2_MIXTURE`.
    pub rule: u32,
    /// `c`: spatial leaves split past `c·sqrt(2^k)` samples in iteration `k`.
    pub spatial_threshold: f32,
    /// `ρ`: directional cells split while their share of the mass exceeds it.
    pub subdivision_threshold: f32,
    /// Deepest directional level, 1..=20.
    pub max_directional_depth: u32,
    /// Share of every distribution spread uniformly, in [1e-9, 1].
    pub uniform_fraction: f32,
    /// Interior nodes per directional tree, 1..=65535.
    pub max_directional_nodes: u32,
    /// Spatial tree nodes.
    pub max_spatial_nodes: u32,
    /// Memory budget in bytes.
    pub max_memory_bytes: u64,
    /// `n0`: samples' worth of weight a directional cell's estimate gives its parent's in the
    /// leaf masses; >= 0.
    pub prior_samples: f32,
    /// `SDG_FILTER_NEAREST`, `SDG_FILTER_STOCHASTIC` or `SDG_FILTER_BOX`.
    pub spatial_filter: u32,
    /// `SDG_FILTER_NEAREST`, `SDG_FILTER_BOX` or `SDG_FILTER_DEFERRED_BOX`.
    pub directional_filter: u32,
    /// `SDG_REFINEMENT_FLUX_SHARE` or `SDG_REFINEMENT_VARIANCE_GAIN`.
    pub refinement: u32,
    /// `τ`: directional cells split while the split lowers `Σ sqrt(m)` by more than `τ` times it.
    pub gain_threshold: f32,
    /// The largest guide probability a leaf learns, in [0.5, 0.95].
    pub max_guide_probability: f32,
    /// What sampling the guide adds to a path vertex's cost, relative, in [0, 100]: a leaf
    /// whose guide does not lower the variance below `1/(1 + guide_cost)` of BSDF sampling's
    /// turns it off (guide probability 0). Read only with `SDG_CONFIG_GUIDE_COST` in `flags`;
    /// without it the guide never turns off.
    pub guide_cost: f32,
    /// Which optional fields and switches are set: `SDG_CONFIG_GUIDE_COST`,
    /// `SDG_CONFIG_VOLUMES`, `SDG_CONFIG_FILTER_SAMPLES`, or'ed; 0 for none.
    pub flags: u32,
    /// `n_f`: samples a directional leaf needs before its own second moment weighs as much as
    /// the filtered one in the l2 masses; finite, >= 0. Read only with
    /// `SDG_CONFIG_FILTER_SAMPLES` in `flags` (set by `sdg_config_default`); without it the
    /// masses use the filtered sums alone.
    pub filter_samples: f32,
    /// `SDG_SPATIAL_SPLIT_COUNT` or `SDG_SPATIAL_SPLIT_GAIN`.
    pub spatial_split: u32,
    /// `τ` of `SDG_SPATIAL_SPLIT_GAIN`: a spatial cell splits when its split lowers the
    /// estimator's second moment by more than `τ` of it beyond what noise gains; in [0, 1).
    pub spatial_gain_threshold: f32,
}

/// In `sdg_config::flags`: `guide_cost` is set (without it, the guide never turns off).
pub const SDG_CONFIG_GUIDE_COST: u32 = 1;
/// In `sdg_config::flags`: every spatial leaf keeps a second guide for vertices inside
/// participating media (see the Rust `GuidingConfig::volumes`, `sdg_field_volume_distribution`
/// and `SDG_SAMPLE_VOLUME`).
pub const SDG_CONFIG_VOLUMES: u32 = 2;
/// In `sdg_config::flags`: `filter_samples` is set (see the Rust
/// `GuidingConfig::filter_samples`).
pub const SDG_CONFIG_FILTER_SAMPLES: u32 = 4;

/// The C codes of a library enum, in one table that both conversions read.
struct Codes<T: 'static> {
    what: &'static str,
    table: &'static [(u32, T)],
}

impl<T: Copy + PartialEq> Codes<T> {
    fn code(&self, value: T) -> Result<u32, Failure> {
        match self.table.iter().find(|(_, v)| *v == value) {
            Some(&(code, _)) => Ok(code),
            // The library's enums may grow; this crate is built with the library, so a default
            // without a code does not happen.
            None => fail(
                sdg_status::Config,
                format!(
                    "the library's {} has no code in this version of the C API",
                    self.what
                ),
            ),
        }
    }

    fn value(&self, code: u32) -> Result<T, Failure> {
        match self.table.iter().find(|(c, _)| *c == code) {
            Some(&(_, value)) => Ok(value),
            None => fail(sdg_status::Config, format!("unknown {} {code}", self.what)),
        }
    }
}

const RULES: Codes<LeafRule> = Codes {
    what: "rule",
    table: &[
        (SDG_RULE_L1, LeafRule::L1),
        (SDG_RULE_L2, LeafRule::L2),
        (SDG_RULE_L2_MIXTURE, LeafRule::L2Mixture),
    ],
};

const SPATIAL_FILTERS: Codes<SpatialFilter> = Codes {
    what: "spatial filter",
    table: &[
        (SDG_FILTER_NEAREST, SpatialFilter::Nearest),
        (SDG_FILTER_STOCHASTIC, SpatialFilter::Stochastic),
        (SDG_FILTER_BOX, SpatialFilter::Box),
    ],
};

const DIRECTIONAL_FILTERS: Codes<DirectionalFilter> = Codes {
    what: "directional filter",
    table: &[
        (SDG_FILTER_NEAREST, DirectionalFilter::Nearest),
        (SDG_FILTER_BOX, DirectionalFilter::Box),
        (SDG_FILTER_DEFERRED_BOX, DirectionalFilter::DeferredBox),
    ],
};

const SPATIAL_SPLITS: Codes<SpatialSplit> = Codes {
    what: "spatial split",
    table: &[
        (SDG_SPATIAL_SPLIT_COUNT, SpatialSplit::Count),
        (SDG_SPATIAL_SPLIT_GAIN, SpatialSplit::Gain),
    ],
};

const REFINEMENTS: Codes<Refinement> = Codes {
    what: "refinement",
    table: &[
        (SDG_REFINEMENT_FLUX_SHARE, Refinement::FluxShare),
        (SDG_REFINEMENT_VARIANCE_GAIN, Refinement::VarianceGain),
    ],
};

/// `$dst { … }` with every field the two configuration types share as the same number copied
/// from `$src`, and the fields in `$rest` (the coded ones) as given: the one list of the plain
/// fields, for both conversions.
macro_rules! with_plain_fields {
    ($src:ident => $dst:ident { $($rest:tt)* }) => {
        $dst {
            spatial_threshold: $src.spatial_threshold,
            subdivision_threshold: $src.subdivision_threshold,
            max_directional_depth: $src.max_directional_depth,
            uniform_fraction: $src.uniform_fraction,
            max_directional_nodes: $src.max_directional_nodes,
            max_spatial_nodes: $src.max_spatial_nodes,
            max_memory_bytes: $src.max_memory_bytes,
            prior_samples: $src.prior_samples,
            gain_threshold: $src.gain_threshold,
            max_guide_probability: $src.max_guide_probability,
            spatial_gain_threshold: $src.spatial_gain_threshold,
            $($rest)*
        }
    };
}

/// `bit` where `on`, else 0.
fn flag(on: bool, bit: u32) -> u32 {
    if on { bit } else { 0 }
}

impl sdg_config {
    /// The C form of a library configuration.
    fn from_rust(c: &GuidingConfig) -> Result<Self, Failure> {
        Ok(with_plain_fields!(c => Self {
            rule: RULES.code(c.rule)?,
            spatial_filter: SPATIAL_FILTERS.code(c.spatial_filter)?,
            directional_filter: DIRECTIONAL_FILTERS.code(c.directional_filter)?,
            refinement: REFINEMENTS.code(c.refinement)?,
            spatial_split: SPATIAL_SPLITS.code(c.spatial_split)?,
            guide_cost: c.guide_cost.unwrap_or(0.0),
            flags: flag(c.guide_cost.is_some(), SDG_CONFIG_GUIDE_COST)
                | flag(c.volumes, SDG_CONFIG_VOLUMES)
                | flag(c.filter_samples.is_some(), SDG_CONFIG_FILTER_SAMPLES),
            filter_samples: c.filter_samples.unwrap_or(0.0),
        }))
    }

    /// The library configuration this one means; unknown codes fail here, values out of range
    /// at the field's validation.
    pub(crate) fn to_rust(self) -> Result<GuidingConfig, Failure> {
        let c = self;
        Ok(with_plain_fields!(c => GuidingConfig {
            rule: RULES.value(c.rule)?,
            spatial_filter: SPATIAL_FILTERS.value(c.spatial_filter)?,
            directional_filter: DIRECTIONAL_FILTERS.value(c.directional_filter)?,
            refinement: REFINEMENTS.value(c.refinement)?,
            spatial_split: SPATIAL_SPLITS.value(c.spatial_split)?,
            guide_cost: (c.flags & SDG_CONFIG_GUIDE_COST != 0).then_some(c.guide_cost),
            volumes: c.flags & SDG_CONFIG_VOLUMES != 0,
            filter_samples: (c.flags & SDG_CONFIG_FILTER_SAMPLES != 0).then_some(c.filter_samples),
        }))
    }
}

/// Fills `out` with the default configuration.
///
/// # Safety
/// `out` must be null or valid for writing an `sdg_config`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_config_default(out: *mut sdg_config) -> sdg_status {
    guard(|| {
        let config = sdg_config::from_rust(&GuidingConfig::default())?;
        // SAFETY: the caller's contract.
        unsafe { put(out, "out", config) }?;
        Ok(sdg_status::Ok)
    })
}
