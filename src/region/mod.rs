//! A region: everything one spatial leaf knows and learns.
//!
//! A spatial leaf of the field is a [`Region`]. It holds the directional quadtree of its
//! surface vertices, double buffered (the [`SamplingTree`] queries descend, the
//! [`RecordingTree`] render threads add to), the tally of recorded normals and the stored
//! products with the cosine built from it, the learned guide-vs-BSDF probability with its
//! sums, the continuation sums of roulette and splitting, and — in a field with volumes — the
//! [`Guide`] of its medium vertices. The field routes each sample, continuation and query to one
//! region; the region does the rest, and so owns its three moments of an iteration:
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

mod guide;

pub(crate) use guide::{Guide, GuideView, GuideViewMut};

use crate::config::GuidingConfig;
use crate::distribution::DirectionalDistribution;
use crate::filter::DirectionalFilter;
use crate::guide_probability::GuideSelection;
use crate::moments::Moments;
use crate::quadtree::{
    DirectionalCell, GRID_BYTES, RecordingTree, RefineParams, RefineScratch, SamplingTree,
    Surfaces, Tallied, leaf_bytes,
};
use crate::spatial_split::{Bins, SignatureSums, SplitPlan, SplitSignature, count_threshold};
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
    /// The count rule's threshold for the iteration that ends (a floor for splits by gain).
    pub spatial_threshold: f64,
    /// `τ` of splits by gain.
    pub spatial_gain_threshold: f64,
}

impl StepParams {
    /// The parameters of `config` at the end of iteration `iteration`, with `max_nodes`
    /// interior nodes at most per tree.
    pub(crate) fn new(config: &GuidingConfig, iteration: u32, max_nodes: u32) -> Self {
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
                filter_samples: config.filter_samples.map(f64::from),
                deferred: config.directional_filter.defers(),
            },
            max_guide_probability: config.max_guide_probability,
            guide_cost: config.guide_cost,
            spatial_threshold: count_threshold(config, iteration),
            spatial_gain_threshold: f64::from(config.spatial_gain_threshold),
        }
    }
}

/// What one region's refine did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct RefineOutcome {
    /// Samples the region had counted in the iteration that ended.
    pub samples: u64,
    /// Which of its cells split, by gain (`None`: by count).
    pub plan: Option<SplitPlan>,
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
    /// The continuation moments, for roulette and splitting (surface and medium vertices).
    continuations: ContinuationStats,
    /// The guide of medium vertices, in a field with volumes.
    volume: Option<Box<Guide>>,
    /// What the leaf's halves saw, in a field that splits spatial leaves by gain.
    signature: Option<Box<SplitSignature>>,
}

impl Default for Region {
    fn default() -> Self {
        Self::new(SamplingTree::uniform(), RecordingTree::root())
    }
}

/// The parts of a region's guide for one kind of vertex that `record` touches.
#[derive(Clone, Copy)]
struct Parts<'a> {
    sampling: &'a SamplingTree,
    recording: &'a RecordingTree,
    selection: &'a GuideSelection,
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
            volume: None,
            signature: None,
        }
    }

    /// Gives the region a guide for medium vertices, or takes it away.
    pub(crate) fn set_volume(&mut self, volume: Option<Guide>) {
        self.volume = volume.map(Box::new);
    }

    /// Gives the region a split signature (empty), or takes it away.
    pub(crate) fn set_signature(&mut self, on: bool) {
        self.signature = None;
        if on {
            self.set_signature_sums(&SignatureSums::default());
        }
    }

    /// The split signature's sums, if the region keeps one.
    pub(crate) fn signature(&self) -> Option<SignatureSums> {
        self.signature.as_deref().map(SplitSignature::get)
    }

    /// Sets the split signature's sums (for a region that keeps one).
    pub(crate) fn set_signature_sums(&mut self, sums: &SignatureSums) {
        let bins = Bins::of(&self.sampling);
        self.signature = Some(Box::new(SplitSignature::new(bins, sums)));
    }

    /// The guide of medium vertices, if the region keeps one.
    pub(crate) fn volume(&self) -> Option<&Guide> {
        self.volume.as_deref()
    }

    /// The parts `record` touches of the guide of surface vertices, or of medium vertices
    /// (`volume`; the surface guide's in a region without one, where the field never asks).
    #[inline(always)]
    fn parts(&self, volume: bool) -> Parts<'_> {
        match self.volume.as_deref() {
            Some(g) if volume => Parts {
                sampling: &g.sampling,
                recording: &g.recording,
                selection: &g.selection,
            },
            _ => Parts {
                sampling: &self.sampling,
                recording: &self.recording,
                selection: &self.selection,
            },
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

    /// The distribution queries at medium vertices in this region receive: the uniform
    /// distribution with guide probability 0 (sample the phase function alone) in a region
    /// without a volume guide.
    #[inline]
    pub(crate) fn volume_distribution(&self) -> DirectionalDistribution<'_> {
        match self.volume.as_deref() {
            Some(g) => DirectionalDistribution::new(
                &g.sampling,
                g.selection.probability,
                &self.continuations.estimate,
                Surfaces::none(),
            ),
            None => DirectionalDistribution::new(
                SamplingTree::uniform_ref(),
                0.0,
                &self.continuations.estimate,
                Surfaces::none(),
            ),
        }
    }

    /// The continuation estimate, for roulette and splitting.
    #[inline]
    pub(crate) fn continuation(&self) -> ContinuationEstimate {
        self.continuations.estimate
    }

    /// Gives the recording trees pending sums, for the deferred box filter.
    pub(crate) fn defer(&mut self) {
        self.recording.defer();
        if let Some(g) = self.volume.as_deref_mut() {
            g.recording.defer();
        }
    }

    // --- record (&self, any thread) ---

    /// Tallies a recorded sample's (unit) normal.
    #[inline]
    pub(crate) fn record_normal(&self, n: Vec3, priority: u64) {
        self.surfaces.record(n, priority);
    }

    /// Adds a sample's mixture terms to the guide-selection sums (`pdf`: the mixture's) of the
    /// surface guide or the medium one (`volume`).
    #[inline]
    /// Returns whether a term was clamped to the sums' range.
    pub(crate) fn record_selection(
        &self,
        volume: bool,
        integrand: f32,
        technique_pdf: f32,
        guide_pdf: f32,
        pdf: f32,
    ) -> bool {
        self.parts(volume)
            .selection
            .record(integrand, technique_pdf, guide_pdf, pdf)
    }

    /// The density on the square the surface (or medium, `volume`) guide gives `square`.
    #[inline]
    pub(crate) fn square_pdf(&self, volume: bool, square: Vec2) -> f32 {
        self.parts(volume).sampling.pdf(square)
    }

    /// Records weights `w` at `square` through the directional filter into the surface (or
    /// medium, `volume`) guide; `counted`: as the sample's own record (see
    /// [`RecordingTree::record`]).
    #[inline]
    pub(crate) fn record(
        &self,
        volume: bool,
        filter: DirectionalFilter,
        square: Vec2,
        w: (f64, f64),
        counted: bool,
    ) {
        self.parts(volume)
            .recording
            .record(filter, square, w, counted);
    }

    /// Counts a sample whose weights the spatial box filter spreads over other regions.
    #[inline]
    pub(crate) fn count_sample(&self, volume: bool, square: Vec2, w2: f64) {
        self.parts(volume).recording.count_sample(square, w2);
    }

    /// Records a sample's second-moment weight `w2` at `square` into the split signature, in
    /// resolved cell `cell` and null group `group` (see [`crate::spatial_split`]).
    #[inline]
    pub(crate) fn record_signature(&self, cell: usize, group: bool, square: Vec2, w2: f64) {
        if let Some(s) = &self.signature {
            s.record(cell, group, square, w2);
        }
    }

    /// Adds one traced continuation's value and cost.
    #[inline]
    /// Returns whether a term was clamped to the sums' range.
    pub(crate) fn record_continuation(&self, value: f32, cost: f32) -> bool {
        self.continuations.record(value, cost)
    }

    // --- refine (&mut self) ---

    /// Ends an iteration: for the surface guide and the medium one, one step of the guide
    /// probability (and whether the guide pays for its cost) and the next sampling and
    /// recording trees; the continuation estimate; and the stored surface products for the new
    /// surface guide. A guide that counted no sample keeps its distribution. `scratch` is
    /// working memory, kept from one region to the next.
    pub(crate) fn refine(
        &mut self,
        params: &StepParams,
        scratch: &mut RefineScratch,
    ) -> RefineOutcome {
        let plan = self.signature.as_deref().map(|s| {
            s.get().plan(
                s.bins(),
                params.spatial_threshold,
                params.spatial_gain_threshold,
            )
        });
        let splitting = self.continuations.recorded().count > 0;
        self.continuations.step();
        let (mut outcome, rebuilt) = guide::step(
            &mut self.sampling,
            &mut self.recording,
            &mut self.selection,
            params,
            splitting,
            scratch,
        );
        if rebuilt {
            self.surfaces.refine(&self.sampling);
        }
        if let Some(g) = self.volume.as_deref_mut() {
            let (v, _) = g.step(params, splitting, scratch);
            outcome.samples = outcome.samples.saturating_add(v.samples);
            outcome.refused += v.refused;
        }
        if let Some(s) = self.signature.as_deref_mut() {
            s.restart(Bins::of(&self.sampling));
        }
        outcome.plan = plan;
        outcome
    }

    /// Drops the stored surface products; returns the bytes freed.
    pub(crate) fn drop_surface_products(&mut self) -> usize {
        self.surfaces.drop_products()
    }

    // --- merge ---

    /// Whether `other` started the iteration from the same state, and if not, what differs.
    pub(crate) fn same_start(&self, other: &Region) -> Result<(), &'static str> {
        let (a, b) = (self, other);
        guide::same_start(a, b)?;
        match (a.volume(), b.volume()) {
            (Some(va), Some(vb)) => guide::same_start(va, vb).map_err(|_| "volume guides")?,
            (None, None) => {}
            _ => return Err("volume guides"),
        }
        if a.signature.is_some() != b.signature.is_some() {
            return Err("split signatures");
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
    /// the normal tally, and the sums the deferred filter holds back, of both guides — all
    /// exactly.
    pub(crate) fn add(&mut self, other: &Region) {
        guide::add(&mut self.recording, &mut self.selection, other);
        if let (Some(v), Some(w)) = (self.volume.as_deref_mut(), other.volume()) {
            v.add(w);
        }
        self.continuations
            .add_recorded(&other.continuations.recorded());
        self.surfaces.add_tally(&other.surfaces);
        if let (Some(s), Some(o)) = (self.signature.as_deref_mut(), other.signature()) {
            s.add(&o);
        }
    }

    // --- statistics ---

    /// Adds this region's sizes and counts to `s`.
    pub(crate) fn add_stats(&self, s: &mut FieldStats) {
        guide::add_stats(self, s);
        if let Some(g) = self.volume() {
            guide::add_stats(g, s);
            s.volume_directional_nodes += g.sampling.node_count() as u64;
            s.volume_samples_recorded = s
                .volume_samples_recorded
                .saturating_add(g.recording.count());
        }
        s.surface_products += self.surfaces.products.len() as u64;
        s.surface_product_nodes += self.surfaces.node_count() as u64;
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
        let volume = self.volume().map_or(0, |g| {
            g.sampling.bytes() + g.recording.bytes() + size_of::<Guide>()
        });
        self.sampling.bytes()
            + self.recording.bytes()
            + self.surfaces.bytes()
            + size_of::<Region>()
            + volume
            + self.signature.as_deref().map_or(0, SplitSignature::bytes)
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

    /// [`fixed_bytes`](Self::fixed_bytes) of a region's medium guide.
    pub(crate) const fn fixed_volume_bytes(deferred: bool) -> u64 {
        (size_of::<Guide>() + GRID_BYTES) as u64 + leaf_bytes(deferred)
    }

    // --- cache accessors (the surface guide's through `GuideView`) ---

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

guide::guide_fields!(Region);

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
