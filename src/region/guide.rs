//! A directional guide: the double-buffered quadtree and the guide-vs-technique selection that
//! one kind of vertex of a region learns from.
//!
//! A region has one for surface vertices (inline in [`Region`](super::Region), laid out for
//! the query) and, in a field with [`volumes`](crate::GuidingConfig::volumes), a [`Guide`] for
//! vertices inside participating media: a medium vertex receives light from the whole sphere
//! and samples the guide's product with its phase function, a surface vertex only the
//! hemisphere above it, so the two learn apart. Both step at `refine`, merge, and are cached
//! through the same functions here, which read a guide through [`GuideView`].

use super::{RefineOutcome, StepParams};
use crate::guide_probability::GuideSelection;
use crate::quadtree::{self, RecordingTree, RefineScratch, SamplingTree};
use crate::stats::FieldStats;

/// The guide of a region's medium vertices.
#[derive(Clone, Debug)]
pub(crate) struct Guide {
    pub(crate) sampling: SamplingTree,
    pub(crate) recording: RecordingTree,
    /// The learned guide-vs-phase-function probability.
    pub(crate) selection: GuideSelection,
}

impl Default for Guide {
    fn default() -> Self {
        Self::new(SamplingTree::uniform(), RecordingTree::root())
    }
}

impl Guide {
    /// A guide with these trees that has learned nothing else yet.
    pub(crate) fn new(sampling: SamplingTree, recording: RecordingTree) -> Self {
        Self {
            sampling,
            recording,
            selection: GuideSelection::default(),
        }
    }

    /// Ends an iteration (see [`step`]).
    pub(crate) fn step(
        &mut self,
        params: &StepParams,
        splitting: bool,
        scratch: &mut RefineScratch,
    ) -> (RefineOutcome, bool) {
        step(
            &mut self.sampling,
            &mut self.recording,
            &mut self.selection,
            params,
            splitting,
            scratch,
        )
    }

    /// Adds what `other` recorded in the iteration (see [`same_start`]).
    pub(crate) fn add(&mut self, other: &impl GuideView) {
        add(&mut self.recording, &mut self.selection, other);
    }
}

/// What the cache, the merge and the statistics read of a guide.
pub(crate) trait GuideView {
    fn sampling(&self) -> &SamplingTree;
    fn recording(&self) -> &RecordingTree;
    fn selection(&self) -> &GuideSelection;
}

/// What the cache's decoders set in a guide.
pub(crate) trait GuideViewMut: GuideView {
    fn recording_mut(&mut self) -> &mut RecordingTree;
    fn set_selection(&mut self, selection: GuideSelection);
}

/// [`GuideView`] and [`GuideViewMut`] for a type that holds a guide as its fields `sampling`,
/// `recording` and `selection` (a [`Guide`], and a region's surface guide).
macro_rules! guide_fields {
    ($t:ty) => {
        impl $crate::region::GuideView for $t {
            fn sampling(&self) -> &$crate::quadtree::SamplingTree {
                &self.sampling
            }
            fn recording(&self) -> &$crate::quadtree::RecordingTree {
                &self.recording
            }
            fn selection(&self) -> &$crate::guide_probability::GuideSelection {
                &self.selection
            }
        }

        impl $crate::region::GuideViewMut for $t {
            fn recording_mut(&mut self) -> &mut $crate::quadtree::RecordingTree {
                &mut self.recording
            }
            fn set_selection(&mut self, selection: $crate::guide_probability::GuideSelection) {
                self.selection = selection;
            }
        }
    };
}
pub(super) use guide_fields;

guide_fields!(Guide);

impl<T: GuideView> GuideView for &T {
    fn sampling(&self) -> &SamplingTree {
        (*self).sampling()
    }
    fn recording(&self) -> &RecordingTree {
        (*self).recording()
    }
    fn selection(&self) -> &GuideSelection {
        (*self).selection()
    }
}

/// Ends a guide's iteration: one step of the guide probability (and whether the guide pays for
/// its cost: not asked where the region's renderer recorded continuations, `splitting`), then
/// the next sampling and recording trees. A guide that counted no sample keeps its
/// distribution. Returns what it did and whether the sampling tree changed. `scratch` is
/// working memory.
pub(crate) fn step(
    sampling: &mut SamplingTree,
    recording: &mut RecordingTree,
    selection: &mut GuideSelection,
    params: &StepParams,
    splitting: bool,
    scratch: &mut RefineScratch,
) -> (RefineOutcome, bool) {
    // Where the renderer recorded continuations (efficiency-aware roulette or splitting), the
    // guide stays on: the factors follow continuation estimates the guide shapes, so what the
    // guide is worth is not in its vertices' variance alone (see `guide_probability`).
    let cost = params.guide_cost.filter(|_| !splitting);
    selection.step(params.max_guide_probability, cost);
    recording.flush_pending_mut();
    let Some(next) = quadtree::refine(recording, &params.tree, scratch) else {
        // Nothing landed here; shares a box filter spread in from neighbouring regions are not
        // enough to learn from (shrinkage weighs by counted samples), so they are dropped with
        // the iteration, and the distribution stays.
        recording.clear_moments();
        return (RefineOutcome::default(), false);
    };
    *sampling = next.sampling;
    *recording = next.recording;
    let outcome = RefineOutcome {
        samples: next.samples,
        refused: next.refused,
        plan: None,
    };
    (outcome, true)
}

/// Whether two guides started the iteration from the same state, and if not, what differs.
pub(crate) fn same_start(a: &impl GuideView, b: &impl GuideView) -> Result<(), &'static str> {
    if a.sampling() != b.sampling() {
        return Err("distributions");
    }
    if a.recording().nodes != b.recording().nodes {
        return Err("recording topologies");
    }
    let (sa, sb) = (a.selection(), b.selection());
    if (sa.learned, sa.off()) != (sb.learned, sb.off()) {
        return Err("guide probabilities");
    }
    Ok(())
}

/// Adds what `other` recorded in the iteration to a guide's recording tree and selection: the
/// directional moments and quadrant sums, the selection sums, the sums the deferred filter
/// holds back — all exactly.
pub(crate) fn add(
    recording: &mut RecordingTree,
    selection: &mut GuideSelection,
    other: &impl GuideView,
) {
    recording.add(other.recording());
    selection.add_sums(other.selection().sums());
}

/// Adds a guide's sizes and counts to `s`'s directional fields.
pub(crate) fn add_stats(guide: &impl GuideView, s: &mut FieldStats) {
    let (leaves, depth) = guide.sampling().leaf_count_and_depth();
    s.directional_nodes += guide.sampling().node_count() as u64;
    s.directional_leaves += leaves as u64;
    s.directional_depth = s.directional_depth.max(depth);
    s.samples_recorded = s.samples_recorded.saturating_add(guide.recording().count());
    s.guides_off += u64::from(guide.selection().off());
}
