//! The `META` section: configuration, bounds, iteration and counters. Decoding builds the
//! field through `GuidingField::new`, so a cache's configuration and bounds are validated
//! exactly as a field built in code.

use super::*;

pub(super) fn encode_meta(field: &GuidingField) -> Vec<u8> {
    let c = &field.config;
    let mut out = Out(Vec::with_capacity(META_LEN));
    out.u8(match c.rule {
        LeafRule::L1 => 0,
        LeafRule::L2 => 1,
        LeafRule::L2Mixture => 2,
    });
    out.0.extend_from_slice(&[0; 3]);
    out.f32(c.spatial_threshold);
    out.f32(c.subdivision_threshold);
    out.u32(c.max_directional_depth);
    out.f32(c.uniform_fraction);
    out.u32(c.max_directional_nodes);
    out.u32(c.max_spatial_nodes);
    out.u32(0);
    out.u64(c.max_memory_bytes);
    out.vec3(field.bounds.min);
    out.vec3(field.bounds.max);
    out.u32(field.iteration);
    out.u32(0);
    out.u64(field.recorded_before);
    out.u64(field.spatial_refused);
    out.u64(field.directional_refused);
    let rejected = [field.rejected_before, field.rejected.get()].map(Rejections::to_array);
    for counts in rejected {
        for &c in &counts[..REASONS_3_0] {
            out.u64(c);
        }
    }
    debug_assert_eq!(out.0.len(), META_LEN_1_0);
    out.f32(c.prior_samples);
    out.u8(match c.spatial_filter {
        SpatialFilter::Nearest => 0,
        SpatialFilter::Stochastic => 1,
        SpatialFilter::Box => 2,
    });
    out.u8(match c.directional_filter {
        DirectionalFilter::Nearest => 0,
        DirectionalFilter::Box => 1,
        DirectionalFilter::DeferredBox => 2,
    });
    out.0.extend_from_slice(&[0; 2]);
    debug_assert_eq!(out.0.len(), META_LEN_1_1);
    out.u8(match c.refinement {
        Refinement::FluxShare => 0,
        Refinement::VarianceGain => 1,
    });
    out.0.extend_from_slice(&[0; 3]);
    out.f32(c.gain_threshold);
    debug_assert_eq!(out.0.len(), META_LEN_2_3);
    out.f32(c.max_guide_probability);
    debug_assert_eq!(out.0.len(), META_LEN_2_5);
    // The guide never off: a negative cost.
    out.f32(c.guide_cost.unwrap_or(-1.0));
    debug_assert_eq!(out.0.len(), META_LEN_2_6);
    let (before, current) = field.clamped.parts();
    out.u64(before);
    out.u64(current);
    debug_assert_eq!(out.0.len(), META_LEN_3_0);
    out.u32(u32::from(c.volumes));
    out.u32(0);
    for counts in rejected {
        out.u64(counts[REASONS_3_0]);
    }
    debug_assert_eq!(out.0.len(), META_LEN_3_1);
    // Filtered second moments alone: a negative count.
    out.f32(c.filter_samples.unwrap_or(-1.0));
    out.u32(0);
    debug_assert_eq!(out.0.len(), META_LEN_3_2);
    out.u8(match c.spatial_split {
        SpatialSplit::Count => 0,
        SpatialSplit::Gain => 1,
    });
    out.0.extend_from_slice(&[0; 3]);
    out.f32(c.spatial_gain_threshold);
    debug_assert_eq!(out.0.len(), META_LEN);
    out.0
}

/// Reads `META` into a field with its configuration, bounds and counters (and no trees yet).
pub(super) fn decode_meta(bytes: &[u8]) -> Result<GuidingField, CacheError> {
    let mut r = In::new(bytes, "meta");
    let rule = match r.u8()? {
        0 => LeafRule::L1,
        1 => LeafRule::L2,
        2 => LeafRule::L2Mixture,
        other => return Err(corrupt("meta", format!("unknown leaf rule {other}"))),
    };
    r.take(3)?;
    let mut config = GuidingConfig {
        rule,
        spatial_threshold: r.f32()?,
        subdivision_threshold: r.f32()?,
        max_directional_depth: r.u32()?,
        uniform_fraction: r.f32()?,
        max_directional_nodes: r.u32()?,
        max_spatial_nodes: r.u32()?,
        ..GuidingConfig::default()
    };
    r.u32()?;
    config.max_memory_bytes = r.u64()?;
    let bounds = Aabb::new(r.vec3()?, r.vec3()?);
    // `new` validates the configuration and the bounds exactly as for a field built in code.
    let mut field =
        GuidingField::new(bounds, config).map_err(|e| corrupt("meta", e.to_string()))?;
    field.iteration = r.u32()?;
    r.u32()?;
    field.recorded_before = r.u64()?;
    field.spatial_refused = r.u64()?;
    field.directional_refused = r.u64()?;
    let mut counts = [[0u64; REASONS]; 2];
    for c in &mut counts {
        for x in &mut c[..REASONS_3_0] {
            *x = r.u64()?;
        }
    }
    // 1.1: shrinkage and filters. A 1.0 file trained without shrinkage (and unfiltered), and
    // keeps training so.
    if r.bytes.is_empty() {
        field.config.prior_samples = 0.0;
    } else {
        field.config.prior_samples = r.f32()?;
        field.config.spatial_filter = match r.u8()? {
            0 => SpatialFilter::Nearest,
            1 => SpatialFilter::Stochastic,
            2 => SpatialFilter::Box,
            other => return Err(corrupt("meta", format!("unknown spatial filter {other}"))),
        };
        field.config.directional_filter = match r.u8()? {
            0 => DirectionalFilter::Nearest,
            1 => DirectionalFilter::Box,
            2 => DirectionalFilter::DeferredBox,
            other => {
                return Err(corrupt(
                    "meta",
                    format!("unknown directional filter {other}"),
                ));
            }
        };
        r.take(2)?;
    }
    // 1.2: the refinement criterion. A 1.1 (or 1.0) file was refined by flux share, and keeps
    // being so.
    if r.bytes.is_empty() {
        field.config.refinement = Refinement::FluxShare;
    } else {
        field.config.refinement = match r.u8()? {
            0 => Refinement::FluxShare,
            1 => Refinement::VarianceGain,
            other => return Err(corrupt("meta", format!("unknown refinement {other}"))),
        };
        r.take(3)?;
        field.config.gain_threshold = r.f32()?;
    }
    // 2.4: the guide probability's bound. An older file learned up to the largest, and keeps
    // learning so.
    field.config.max_guide_probability = if r.bytes.is_empty() {
        MAX_GUIDE_PROBABILITY
    } else {
        r.f32()?
    };
    // 2.6: the guide's cost. An older file never turned a guide off, and keeps not doing so.
    field.config.guide_cost = if r.bytes.is_empty() {
        None
    } else {
        unset_if_negative(r.f32()?)
    };
    // 3.0: the clamped-sample counters. An older file's sums were floating point: none clamped.
    if !r.bytes.is_empty() {
        field.clamped = EventCount::from_parts(r.u64()?, r.u64()?);
    }
    // 3.1: the flags (volumes) and the medium samples rejected for want of a volume guide. An
    // older file has no volume guides.
    if !r.bytes.is_empty() {
        let flags = r.u32()?;
        r.u32()?;
        if flags > 1 {
            return Err(corrupt("meta", format!("unknown flags {flags:#x}")));
        }
        field.config.volumes = flags == 1;
        counts[0][REASONS_3_0] = r.u64()?;
        counts[1][REASONS_3_0] = r.u64()?;
    }
    // 3.2: the filter's sample count in the l2 masses. An older file's masses were the filtered
    // sums alone, and keep being so.
    field.config.filter_samples = if r.bytes.is_empty() {
        None
    } else {
        let n = r.f32()?;
        r.u32()?;
        unset_if_negative(n)
    };
    // 3.3: the spatial split rule. An older file split by count, and keeps doing so.
    if !r.bytes.is_empty() {
        field.config.spatial_split = match r.u8()? {
            0 => SpatialSplit::Count,
            1 => SpatialSplit::Gain,
            other => return Err(corrupt("meta", format!("unknown spatial split {other}"))),
        };
        r.take(3)?;
        field.config.spatial_gain_threshold = r.f32()?;
    }
    field.rejected_before = Rejections::from_array(counts[0]);
    field.rejected = RejectCounters::from_rejections(Rejections::from_array(counts[1]));
    field
        .config
        .validate()
        .map_err(|e| corrupt("meta", e.to_string()))?;
    Ok(field)
}

/// An optional number as `META` stores it: negative for `None`. NaN stays, for validation to
/// refuse.
fn unset_if_negative(v: f32) -> Option<f32> {
    Some(v).filter(|&v| v >= 0.0 || v.is_nan())
}
