//! A region: everything one spatial leaf knows and learns.
//!
//! A spatial leaf of the field is a [`Region`]. It holds the directional quadtree, double
//! buffered (the [`SamplingTree`] queries descend, the [`RecordingTree`] render threads add to),
//! the tally of recorded normals and the stored products with the cosine built from it, the
//! learned guide-vs-BSDF probability with its sums, and the continuation sums of roulette and
//! splitting. The field routes each sample, continuation and query to one region; the region
//! does the rest, and so owns its three moments of an iteration:
//!
//! - `record` (`&self`, lock-free): [`record_normal`](Region::record_normal),
//!   [`record_selection`](Region::record_selection), [`record`](Region::record),
//!   [`record_continuation`](Region::record_continuation);
//! - `refine` (`&mut self`): [`Region::refine`] steps the guide probability and the
//!   continuation estimate, turns the recording tree into the next sampling and recording
//!   trees ([`quadtree::refine`]), and rebuilds the stored surface products;
//! - `merge`: [`Region::same_start`] and [`Region::add`].
//!
//! The cache reads and writes a region through the accessors at the end of this file.

use crate::config::GuidingConfig;
use crate::distribution::DirectionalDistribution;
use crate::filter::DirectionalFilter;
use crate::guide_probability::GuideSelection;
use crate::moments::Moments;
use crate::quadtree::{
    self, DirectionalCell, GRID_BYTES, RecordingTree, RefineParams, SamplingTree, Surfaces,
    Tallied, leaf_bytes,
};
use crate::splitting::{ContinuationEstimate, ContinuationStats};
use crate::stats::FieldStats;
use glam::{Vec2, Vec3};

/// What one region's step at `refine` needs besides the directional tree's parameters.
#[derive(Clone, Copy, Debug)]
pub(crate) struct StepParams {
    /// How the directional tree refines.
    pub tree: RefineParams,
    /// The guide probability's upper bound.
    pub max_guide_probability: f32,
    /// What sampling the guide costs, relative; `None`: the guide never turns off.
    pub guide_cost: Option<f32>,
}

impl StepParams {
    /// The parameters of `config`, with `max_nodes` interior nodes at most per tree.
    pub(crate) fn new(config: &GuidingConfig, max_nodes: u32) -> Self {
        Self {
            tree: RefineParams {
                rule: config.rule,
                uniform_fraction: f64::from(config.uniform_fraction),
                refinement: config.refinement,
                subdivision_threshold: f64::from(config.subdivision_threshold),
                gain_threshold: f64::from(config.gain_threshold),
                max_depth: config.max_directional_depth,
                max_nodes,
                prior_samples: f64::from(config.prior_samples),
                deferred: config.directional_filter.defers(),
            },
            max_guide_probability: config.max_guide_probability,
            guide_cost: config.guide_cost,
        }
    }
}

/// What one region's refine did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct RefineOutcome {
    /// Samples the region had counted in the iteration that ended.
    pub samples: u64,
    /// Directional cells that qualified for a split but were refused by `max_nodes`.
    pub refused: u64,
}

/// One spatial leaf's state: its directional distribution and what it records.
///
/// Laid out for the query: the sampling tree's two pointers and the first 32 bytes of
/// `surfaces` (which normals have stored products, and where they are) share the first cache
/// line.
#[derive(Clone, Debug)]
#[repr(C, align(64))]
pub(crate) struct Region {
    sampling: SamplingTree,
    surfaces: Surfaces,
    recording: RecordingTree,
    /// The learned guide-vs-BSDF selection probability.
    selection: GuideSelection,
    /// The continuation moments, for roulette and splitting.
    continuations: ContinuationStats,
}

impl Default for Region {
    fn default() -> Self {
        Self::new(SamplingTree::uniform(), RecordingTree::root())
    }
}

impl Region {
    /// A region with these trees that has learned nothing else yet.
    pub(crate) fn new(sampling: SamplingTree, recording: RecordingTree) -> Self {
        Self {
            sampling,
            surfaces: Surfaces::default(),
            recording,
            selection: GuideSelection::default(),
            continuations: ContinuationStats::default(),
        }
    }

    /// The distribution queries at positions in this region receive.
    #[inline]
    pub(crate) fn distribution(&self) -> DirectionalDistribution<'_> {
        DirectionalDistribution::new(
            &self.sampling,
            self.selection.probability,
            &self.continuations.estimate,
            &self.surfaces,
        )
    }

    /// The continuation estimate, for roulette and splitting.
    #[inline]
    pub(crate) fn continuation(&self) -> ContinuationEstimate {
        self.continuations.estimate
    }

    /// Gives the recording tree pending sums, for the deferred box filter.
    pub(crate) fn defer(&mut self) {
        self.recording.defer();
    }

    // --- record (&self, any thread) ---

    /// Tallies a recorded sample's (unit) normal.
    #[inline]
    pub(crate) fn record_normal(&self, n: Vec3, priority: u64) {
        self.surfaces.record(n, priority);
    }

    /// Adds a sample's mixture terms to the guide-selection sums (`pdf`: the mixture's).
    #[inline]
    /// Returns whether a term was clamped to the sums' range.
    pub(crate) fn record_selection(
        &self,
        integrand: f32,
        bsdf_pdf: f32,
        guide_pdf: f32,
        pdf: f32,
    ) -> bool {
        self.selection.record(integrand, bsdf_pdf, guide_pdf, pdf)
    }

    /// The density on the square the sampling tree gives `square`.
    #[inline]
    pub(crate) fn square_pdf(&self, square: Vec2) -> f32 {
        self.sampling.pdf(square)
    }

    /// Records weights `w` at `square` through the directional filter; `counted`: as the
    /// sample's own record (see [`RecordingTree::record`]).
    #[inline]
    pub(crate) fn record(
        &self,
        filter: DirectionalFilter,
        square: Vec2,
        w: (f64, f64),
        counted: bool,
    ) {
        self.recording.record(filter, square, w, counted);
    }

    /// Counts a sample whose weights the spatial box filter spreads over other regions.
    #[inline]
    pub(crate) fn count_sample(&self, square: Vec2, w2: f64) {
        self.recording.count_sample(square, w2);
    }

    /// Adds one traced continuation's value and cost.
    #[inline]
    /// Returns whether a term was clamped to the sums' range.
    pub(crate) fn record_continuation(&self, value: f32, cost: f32) -> bool {
        self.continuations.record(value, cost)
    }

    // --- refine (&mut self) ---

    /// Ends an iteration: one step of the guide probability (and whether the guide pays for
    /// its cost), the continuation estimate, the next sampling and recording trees, and the
    /// stored surface products for them. A region that counted no sample keeps its
    /// distribution.
    pub(crate) fn refine(&mut self, params: &StepParams) -> RefineOutcome {
        // Where the renderer recorded continuations (efficiency-aware roulette or splitting),
        // the guide stays on: the factors follow continuation estimates the guide shapes, so
        // what the guide is worth is not in its vertices' variance alone (see
        // `guide_probability`).
        let splitting = self.continuations.recorded().count > 0;
        let cost = params.guide_cost.filter(|_| !splitting);
        self.selection.step(params.max_guide_probability, cost);
        self.continuations.step();
        self.recording.flush_pending_mut();
        let samples = self.recording.count();
        if samples == 0 {
            // Nothing landed here; shares a box filter spread in from neighbouring regions are
            // not enough to learn from (shrinkage weighs by counted samples), so they are
            // dropped with the iteration, and the distribution stays.
            self.recording.clear_moments();
            return RefineOutcome::default();
        }
        let next = quadtree::refine(&self.recording, &params.tree);
        self.sampling = next.sampling;
        self.recording = next.recording;
        self.surfaces.refine(&self.sampling);
        RefineOutcome {
            samples,
            refused: next.refused,
        }
    }

    /// Drops the stored surface products; returns the bytes freed.
    pub(crate) fn drop_surface_products(&mut self) -> usize {
        self.surfaces.drop_products()
    }

    // --- merge ---

    /// Whether `other` started the iteration from the same state, and if not, what differs.
    pub(crate) fn same_start(&self, other: &Region) -> Result<(), &'static str> {
        let (a, b) = (self, other);
        if a.sampling != b.sampling {
            return Err("distributions");
        }
        if a.recording.nodes != b.recording.nodes {
            return Err("recording topologies");
        }
        if (a.selection.learned, a.selection.off()) != (b.selection.learned, b.selection.off()) {
            return Err("guide probabilities");
        }
        if a.continuations.estimate != b.continuations.estimate {
            return Err("continuation estimates");
        }
        if a.surfaces.products != b.surfaces.products
            || a.surfaces.held_keys() != b.surfaces.held_keys()
        {
            return Err("stored surface products");
        }
        Ok(())
    }

    /// Adds what `other` recorded in the iteration (see [`same_start`](Self::same_start)):
    /// the directional moments and quadrant sums, the guide-selection and continuation sums,
    /// the normal tally, and the sums the deferred filter holds back — all exactly.
    pub(crate) fn add(&mut self, other: &Region) {
        self.recording.add(&other.recording);
        self.selection.add_sums(other.selection.sums());
        self.continuations
            .add_recorded(&other.continuations.recorded());
        self.surfaces.add_tally(&other.surfaces);
    }

    // --- statistics ---

    /// Adds this region's sizes and counts to `s`.
    pub(crate) fn add_stats(&self, s: &mut FieldStats) {
        let (leaves, depth) = self.sampling.leaf_count_and_depth();
        s.directional_nodes += self.sampling.node_count() as u64;
        s.directional_leaves += leaves as u64;
        s.directional_depth = s.directional_depth.max(depth);
        s.samples_recorded = s.samples_recorded.saturating_add(self.recording.count());
        s.surface_products += self.surfaces.products.len() as u64;
        s.surface_product_nodes += self.surfaces.node_count() as u64;
        s.guides_off += u64::from(self.selection.off());
        s.continuations_recorded = s
            .continuations_recorded
            .saturating_add(self.continuations.recorded().count);
    }

    /// The leaves of the current recording topology and their moments (pending sums spread
    /// first).
    pub(crate) fn recorded(&self) -> Vec<(DirectionalCell, Moments)> {
        self.recording.leaves()
    }

    /// The heap and inline bytes of the region.
    pub(crate) fn bytes(&self) -> usize {
        self.sampling.bytes() + self.recording.bytes() + self.surfaces.bytes() + size_of::<Region>()
    }

    /// The bytes of the stored surface products.
    pub(crate) fn surface_bytes(&self) -> usize {
        self.surfaces.bytes()
    }

    /// Bytes a region costs besides its directional tree's interior nodes: the struct itself,
    /// its sampling tree's grid, and the sums of the one leaf that is not paid for by a node
    /// (`3·nodes + 1` leaves).
    pub(crate) const fn fixed_bytes(deferred: bool) -> u64 {
        (size_of::<Region>() + GRID_BYTES) as u64 + leaf_bytes(deferred)
    }

    // --- cache accessors ---

    pub(crate) fn sampling(&self) -> &SamplingTree {
        &self.sampling
    }

    pub(crate) fn recording(&self) -> &RecordingTree {
        &self.recording
    }

    pub(crate) fn recording_mut(&mut self) -> &mut RecordingTree {
        &mut self.recording
    }

    pub(crate) fn selection(&self) -> &GuideSelection {
        &self.selection
    }

    pub(crate) fn set_selection(&mut self, selection: GuideSelection) {
        self.selection = selection;
    }

    pub(crate) fn continuations(&self) -> &ContinuationStats {
        &self.continuations
    }

    pub(crate) fn set_continuations(&mut self, continuations: ContinuationStats) {
        self.continuations = continuations;
    }

    pub(crate) fn surfaces(&self) -> &Surfaces {
        &self.surfaces
    }

    /// Sets the normal tally (`slots`, and the samples that found no slot) and rebuilds the
    /// stored products from the sampling tree.
    pub(crate) fn set_tally(&mut self, slots: impl IntoIterator<Item = Tallied>, others: u32) {
        self.surfaces.set(slots, others, &self.sampling);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quadtree::SurfaceTree;

    #[test]
    fn what_a_query_reads_shares_one_cache_line() {
        // The sampling tree's pointers (its nodes, and its grid with the cuts), the product
        // keys and the products' pointer.
        assert_eq!(std::mem::offset_of!(Region, surfaces), 24);
        assert_eq!(std::mem::align_of::<Region>(), 64);
        let s = Surfaces::default();
        let base = std::ptr::from_ref(&s) as usize;
        let end = std::ptr::from_ref(&s.products) as usize + size_of::<Box<[SurfaceTree]>>();
        assert_eq!(end - base, 32);
    }
}
