//! Filters (splatting): how one recorded sample is spread over the cells around it. What each
//! filter does, and why, is on [`SpatialFilter`] and [`DirectionalFilter`].

use glam::Vec3;
use serde::{Deserialize, Serialize};

/// How a sample is spread over spatial leaves.
///
/// Recording a sample only into the leaf that contains it starves small cells: a spatial leaf
/// learns only from the points inside it, a directional leaf only from the directions inside it,
/// so neighbouring cells' estimates of the same smooth light are independent and noisy. A filter
/// spreads each sample over a footprint the size of the cell it landed in:
///
/// - [`SpatialFilter::Stochastic`] moves the recorded position by a random offset within the
///   extent of its spatial leaf (one leaf receives the sample; on average the sample is spread
///   like a box). The offset comes from [`Sample::jitter`](crate::Sample::jitter), or from a hash
///   of the sample when the caller gives none, so recording stays deterministic.
/// - [`SpatialFilter::Box`] adds the sample to every spatial leaf that a box the size of its leaf,
///   centred on the position, overlaps, weighted by the overlapped volume.
///
/// Spatial footprints are clipped to the cube and the weights renormalized, and directional
/// ones keep their area by folding, so every filter records a sample's whole weight. Sample
/// *counts* (which drive spatial splits and the shrinkage of sparse cells) go to the cell
/// containing the sample only.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[non_exhaustive]
pub enum SpatialFilter {
    /// Only the leaf containing the position.
    #[default]
    Nearest,
    /// The leaf containing the position moved by a random offset within its leaf's extent.
    Stochastic,
    /// Every leaf a leaf-sized box around the position overlaps, by overlapped volume.
    Box,
}

/// How a sample is spread over directional leaves.
///
/// Recording a sample only into the leaf that contains it starves small cells: a spatial leaf
/// learns only from the points inside it, a directional leaf only from the directions inside it,
/// so neighbouring cells' estimates of the same smooth light are independent and noisy. A filter
/// spreads each sample over a footprint the size of the cell it landed in:
///
/// - [`DirectionalFilter::Box`] adds the sample to every directional leaf that a square the size
///   of its leaf, centred on its point of the equal-area square, overlaps, weighted by the
///   overlapped area. Where the square crosses the border of the unit square, the part outside
///   is folded back in as the octahedral map folds the sphere (see
///   [`sphere`](crate::sphere)): the directions just past the border are those just inside it,
///   mirrored through the side's midpoint, so the sample reaches its neighbours on the sphere.
/// - [`DirectionalFilter::DeferredBox`] is the same square, placed at refine: a sample adds to
///   the quadrant of its leaf it fell in (a quarter of the leaf), and
///   [`refine`](crate::GuidingField::refine) spreads each quadrant's sums from the quadrant's
///   centre. The spreading is then paid once per quadrant instead of once per sample; the
///   price is a footprint placed to within a quarter of the leaf. Reading a field's recorded
///   moments (saving, merging, [`recorded`](crate::SpatialCell::recorded)) spreads what is
///   pending first, so they always mean the same as under `Box`.
///
/// Spatial footprints are clipped to the cube and the weights renormalized, and directional
/// ones keep their area by folding, so every filter records a sample's whole weight. Sample
/// *counts* (which drive spatial splits and the shrinkage of sparse cells) go to the cell
/// containing the sample only.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[non_exhaustive]
pub enum DirectionalFilter {
    /// Only the leaf containing the direction.
    Nearest,
    /// Every leaf a leaf-sized square around the direction overlaps, by overlapped area (the
    /// default).
    #[default]
    Box,
    /// The box filter applied at [`refine`](crate::GuidingField::refine) instead of at
    /// `record`: recording adds the sample to its leaf's quadrant, and refining spreads each
    /// quadrant's sums with a leaf-sized square centred on the quadrant. It records in about
    /// half the time of [`Box`](Self::Box), for 64 more bytes per directional leaf, and its
    /// variance is within a few percent of `Box`'s (see `docs/quality.md`, *Filters*).
    DeferredBox,
}

impl DirectionalFilter {
    /// Whether the filter holds sums back for [`refine`](crate::GuidingField::refine) to spread
    /// ([`DeferredBox`](Self::DeferredBox)), so that leaves need pending sums.
    pub(crate) fn defers(self) -> bool {
        self == DirectionalFilter::DeferredBox
    }
}

/// Length of the overlap of the intervals `[a0, a1)` and `[b0, b1)`.
#[inline]
pub(crate) fn overlap(a0: f64, a1: f64, b0: f64, b1: f64) -> f64 {
    (a1.min(b1) - a0.max(b0)).max(0.0)
}

/// Three numbers in `[0, 1)` from the bits of a position and a direction: the stochastic
/// filter's offset when the caller gives none. Deterministic, and decorrelated from both inputs
/// by the SplitMix64 finalizer.
pub(crate) fn hash_jitter(position: Vec3, direction: Vec3) -> Vec3 {
    let mut h = 0x9e37_79b9_7f4a_7c15u64;
    for v in position.to_array().into_iter().chain(direction.to_array()) {
        h = mix(h ^ u64::from(v.to_bits()));
    }
    let unit = |bits: u64| (bits >> 40) as f32 * (1.0 / (1u64 << 24) as f32);
    Vec3::new(unit(h), unit(h << 21), unit(h << 42))
}

fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overlaps_are_interval_intersections() {
        assert_eq!(overlap(0.0, 1.0, 0.5, 2.0), 0.5);
        assert_eq!(overlap(0.0, 1.0, 1.5, 2.0), 0.0);
        assert_eq!(overlap(0.25, 0.5, 0.0, 1.0), 0.25);
    }

    #[test]
    fn hashed_jitter_is_deterministic_uniform_and_varies() {
        let a = hash_jitter(Vec3::new(0.1, 0.2, 0.3), Vec3::Z);
        assert_eq!(a, hash_jitter(Vec3::new(0.1, 0.2, 0.3), Vec3::Z));
        assert_ne!(a, hash_jitter(Vec3::new(0.1, 0.2, 0.30001), Vec3::Z));
        // Mean of each coordinate over many inputs: 1/2 within 5σ (σ = sqrt(1/12/n)).
        let n = 100_000;
        let mut sum = Vec3::ZERO;
        for i in 0..n {
            let j = hash_jitter(Vec3::splat(i as f32 * 1e-3), Vec3::X);
            assert!(j.cmpge(Vec3::ZERO).all() && j.cmplt(Vec3::ONE).all());
            sum += j;
        }
        let mean = sum / n as f32;
        let sigma = (1.0 / 12.0 / n as f32).sqrt();
        assert!(
            (mean - Vec3::splat(0.5)).abs().max_element() < 5.0 * sigma,
            "{mean}"
        );
    }
}
