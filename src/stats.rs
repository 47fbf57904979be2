//! What a field reports about itself: size, depth, samples taken and samples turned away.

use crate::sample::RejectReason;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicU64, Ordering};

/// How many [`RejectReason`]s there are.
pub(crate) const REASONS: usize = 6;

/// Counts of rejected samples, one per [`RejectReason`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Rejections {
    /// [`RejectReason::NonFinitePosition`].
    pub non_finite_position: u64,
    /// [`RejectReason::OutOfBounds`].
    pub out_of_bounds: u64,
    /// [`RejectReason::BadDirection`].
    pub bad_direction: u64,
    /// [`RejectReason::BadValue`].
    pub bad_value: u64,
    /// [`RejectReason::BadPdf`].
    pub bad_pdf: u64,
    /// [`RejectReason::NoVolumeGuide`].
    pub no_volume_guide: u64,
}

impl Rejections {
    /// All rejections together.
    pub fn total(&self) -> u64 {
        self.to_array().iter().sum()
    }

    /// The counts in [`RejectReason`] order.
    pub(crate) fn to_array(self) -> [u64; REASONS] {
        [
            self.non_finite_position,
            self.out_of_bounds,
            self.bad_direction,
            self.bad_value,
            self.bad_pdf,
            self.no_volume_guide,
        ]
    }

    /// Counts from an array in [`RejectReason`] order.
    pub(crate) fn from_array(c: [u64; REASONS]) -> Self {
        Self {
            non_finite_position: c[0],
            out_of_bounds: c[1],
            bad_direction: c[2],
            bad_value: c[3],
            bad_pdf: c[4],
            no_volume_guide: c[5],
        }
    }

    /// Both sets of counts added (saturating: counters never wrap).
    pub(crate) fn plus(&self, other: &Rejections) -> Rejections {
        let (a, b) = (self.to_array(), other.to_array());
        Self::from_array(std::array::from_fn(|i| a[i].saturating_add(b[i])))
    }
}

/// A snapshot of a field's shape and bookkeeping, from [`GuidingField::stats`](crate::GuidingField::stats).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FieldStats {
    /// Completed iterations (calls to `refine`).
    pub iteration: u32,
    /// Nodes of the spatial tree.
    pub spatial_nodes: u64,
    /// Leaves of the spatial tree (each owns one directional tree).
    pub spatial_leaves: u64,
    /// Depth of the deepest spatial leaf (the root is 0).
    pub spatial_depth: u32,
    /// Interior nodes over all sampling quadtrees.
    pub directional_nodes: u64,
    /// Leaves over all sampling quadtrees.
    pub directional_leaves: u64,
    /// Depth of the deepest sampling quadtree leaf (the root's children are 1).
    pub directional_depth: u32,
    /// Interior nodes over the sampling quadtrees of medium vertices (counted in
    /// `directional_nodes` too; see [`GuidingConfig::volumes`](crate::GuidingConfig::volumes)).
    pub volume_directional_nodes: u64,
    /// Samples recorded in the current iteration (surface and medium).
    pub samples_recorded: u64,
    /// Medium samples ([`Sample::volume`](crate::Sample::volume)) recorded in the current
    /// iteration.
    pub volume_samples_recorded: u64,
    /// Samples recorded over the field's life, the current iteration included.
    pub samples_recorded_total: u64,
    /// Continuations recorded in the current iteration
    /// ([`GuidingField::record_continuation`](crate::GuidingField::record_continuation)).
    pub continuations_recorded: u64,
    /// Samples and continuations rejected over the field's life, by reason.
    pub rejected: Rejections,
    /// Spatial splits refused by `max_spatial_nodes` or `max_memory_bytes`, over the field's life.
    pub spatial_splits_refused: u64,
    /// Directional splits refused by `max_directional_nodes`, over the field's life.
    pub directional_splits_refused: u64,
    /// Heap bytes held by the trees.
    pub bytes: u64,
    /// Products with a surface's cosine stored for frequent normals, over all spatial leaves
    /// (see [`Sample::normal`](crate::Sample::normal)).
    pub surface_products: u64,
    /// Nodes of those products.
    pub surface_product_nodes: u64,
    /// Guides (of surface or medium vertices) that are off: they did not pay for their cost in
    /// the last iteration that could tell (see
    /// [`GuidingConfig::guide_cost`](crate::GuidingConfig::guide_cost)).
    pub guides_off: u64,
    /// Samples and continuations recorded with a weight clamped to the range of the field's
    /// exact sums (above `2^48`), over the field's life: they were recorded, their
    /// contribution to the learned distribution capped.
    pub clamped_samples: u64,
}

/// Lock-free rejection counters (bad input is rare, so they are not contended).
#[derive(Debug, Default)]
pub(crate) struct RejectCounters([AtomicU64; REASONS]);

impl RejectCounters {
    #[cold]
    pub(crate) fn count(&self, reason: RejectReason) {
        self.0[reason as usize].fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn get(&self) -> Rejections {
        Rejections::from_array(std::array::from_fn(|i| self.0[i].load(Ordering::Relaxed)))
    }

    /// The counts, leaving zeros behind (at the end of an iteration).
    pub(crate) fn take(&mut self) -> Rejections {
        Rejections::from_array(std::array::from_fn(|i| std::mem::take(self.0[i].get_mut())))
    }

    /// Adds counts (merging), saturating.
    pub(crate) fn add(&mut self, r: &Rejections) {
        *self = Self::from_rejections(self.get().plus(r));
    }

    /// Counters holding `r` (loading a cache).
    pub(crate) fn from_rejections(r: Rejections) -> Self {
        Self(r.to_array().map(AtomicU64::new))
    }
}

impl Clone for RejectCounters {
    fn clone(&self) -> Self {
        Self(std::array::from_fn(|i| {
            AtomicU64::new(self.0[i].load(Ordering::Relaxed))
        }))
    }
}

/// A lock-free count of rare events: those of the current iteration, and those before it.
#[derive(Debug, Default)]
pub(crate) struct EventCount {
    current: AtomicU64,
    before: u64,
}

impl EventCount {
    pub(crate) fn from_parts(before: u64, current: u64) -> Self {
        Self {
            current: AtomicU64::new(current),
            before,
        }
    }

    #[cold]
    pub(crate) fn count(&self) {
        self.current.fetch_add(1, Ordering::Relaxed);
    }

    /// `(before, current)`, as the cache stores them.
    pub(crate) fn parts(&self) -> (u64, u64) {
        (self.before, self.current.load(Ordering::Relaxed))
    }

    /// Every event over the field's life.
    pub(crate) fn total(&self) -> u64 {
        let (b, c) = self.parts();
        b.saturating_add(c)
    }

    /// Ends an iteration: its events join those before.
    pub(crate) fn end_iteration(&mut self) {
        self.before = self.total();
        *self.current.get_mut() = 0;
    }

    /// Adds the current iteration's events of `other` (merging workers).
    pub(crate) fn add(&mut self, other: &EventCount) {
        let c = self.current.get_mut();
        *c = c.saturating_add(other.parts().1);
    }
}

impl Clone for EventCount {
    fn clone(&self) -> Self {
        let (b, c) = self.parts();
        Self::from_parts(b, c)
    }
}
