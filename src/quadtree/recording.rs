//! The recording tree: the topology of the current iteration, and per leaf the moments and
//! quadrant sums that render threads add to with atomic operations. `record` descends it to
//! the sample's leaf; the box filter's shares are in `splat`.

use super::{DirectionalCell, LEAF_BIT, fixed, quadrant_bits};
use crate::filter::DirectionalFilter;
use crate::moments::{AtomicPending, AtomicQuadrants, AtomicSums, ExactMoments, Moments};
use glam::Vec2;

/// A child slot of a recording node under construction that will become a leaf.
pub(super) const FREE: u32 = 0;

/// The topology of the current iteration and the moments recorded into its leaves.
#[derive(Clone, Debug)]
pub(crate) struct RecordingTree {
    /// Child slots: an interior node's index, or `LEAF_BIT | index into moments`.
    pub(crate) nodes: Box<[[u32; 4]]>,
    /// Per leaf, `(Σ v/p, Σ v²/p)` with the filter's shares.
    pub(crate) moments: Box<[AtomicSums]>,
    /// Per leaf (same index as `moments`): the second-moment sums and counts of its four
    /// quadrants, from the samples that landed in it (unfiltered); the leaf's count is theirs.
    pub(crate) quadrants: Box<[AtomicQuadrants]>,
    /// Per leaf, the quadrant sums [`DirectionalFilter::DeferredBox`] has yet to spread; empty
    /// under the other filters (and until [`defer`](Self::defer), when a deferred record
    /// spreads at once).
    ///
    /// [`DirectionalFilter::DeferredBox`]: crate::DirectionalFilter::DeferredBox
    pub(crate) pending: Box<[AtomicPending]>,
}

impl RecordingTree {
    /// One root with four empty leaves.
    pub(crate) fn root() -> Self {
        Self::from_nodes(vec![[FREE; 4]], false)
    }

    /// Builds a tree from interior nodes whose leaf slots are marked `FREE`: numbers the
    /// leaves in node order and gives each a zeroed accumulator (and pending sums if `deferred`).
    pub(super) fn from_nodes(mut nodes: Vec<[u32; 4]>, deferred: bool) -> Self {
        let mut leaves = 0u32;
        for slot in nodes.iter_mut().flatten() {
            if *slot == FREE {
                *slot = LEAF_BIT | leaves;
                leaves += 1;
            }
        }
        let mut tree = Self {
            nodes: nodes.into_boxed_slice(),
            moments: (0..leaves).map(|_| AtomicSums::default()).collect(),
            quadrants: (0..leaves).map(|_| AtomicQuadrants::default()).collect(),
            pending: Box::default(),
        };
        if deferred {
            tree.defer();
        }
        tree
    }

    /// Gives every leaf pending sums, so that [`record`](Self::record) defers under
    /// [`DirectionalFilter::DeferredBox`].
    pub(crate) fn defer(&mut self) {
        if self.pending.is_empty() {
            self.pending = (0..self.moments.len())
                .map(|_| AtomicPending::default())
                .collect();
        }
    }

    /// The moments slot of the leaf that holds `s`, the leaf's depth, and the quadrant of the
    /// leaf that holds `s`.
    #[inline]
    pub(super) fn locate(&self, s: Vec2) -> (usize, u32, usize) {
        self.descend(fixed(s), |_, _| {})
    }

    /// [`locate`](Self::locate) for the fixed-point point `p`, handing `visit(depth, node)`
    /// each interior node on the way.
    #[inline]
    pub(super) fn descend(
        &self,
        p: [u32; 2],
        mut visit: impl FnMut(u32, u32),
    ) -> (usize, u32, usize) {
        let mut node = 0u32;
        let mut depth = 1;
        loop {
            visit(depth - 1, node);
            let (ix, iy) = quadrant_bits(p, depth);
            let slot = self.nodes[node as usize][ix | iy << 1];
            if slot & LEAF_BIT != 0 {
                // Depth ≤ 20 < FIXED_BITS: the bits one level below the leaf exist.
                let (qx, qy) = quadrant_bits(p, depth + 1);
                return ((slot & !LEAF_BIT) as usize, depth, qx | qy << 1);
            }
            node = slot;
            depth += 1;
        }
    }

    /// Loads leaf `k`'s moments and quadrant `q`'s sums, for the box filter to bring them in
    /// with its shares' leaves before the atomic adds (see `Shares` in `splat`); the result
    /// means nothing.
    #[inline]
    pub(super) fn touch(&self, k: usize, q: usize) -> u64 {
        self.moments[k].touch() ^ self.quadrants[k].touch(q)
    }

    /// Records weights `(v/p, v²/p)` at `s` through the directional `filter`: the one entry
    /// point of recording. `counted` is whether this is a sample's own record, which counts the
    /// sample (and its second moment in the quadrant of its leaf it landed in); a spatial filter
    /// that spreads one sample over several spatial leaves records its other shares uncounted.
    /// Under [`DirectionalFilter::DeferredBox`] the sums wait in the leaf quadrant's pending
    /// sums for [`flush_pending`](Self::flush_pending) to spread; a tree without pending sums
    /// spreads them at once, as the box filter does.
    #[inline]
    pub(crate) fn record(
        &self,
        filter: DirectionalFilter,
        s: Vec2,
        weights: (f64, f64),
        counted: bool,
    ) {
        match filter {
            DirectionalFilter::Box => self.record_box(s, weights, counted),
            DirectionalFilter::DeferredBox if self.pending.is_empty() => {
                self.record_box(s, weights, counted)
            }
            DirectionalFilter::Nearest | DirectionalFilter::DeferredBox => {
                let (k, _, q) = self.locate(s);
                if counted {
                    self.quadrants[k].add(q, weights.1);
                }
                if filter == DirectionalFilter::Nearest {
                    self.moments[k].add_sums(weights);
                } else {
                    self.pending[k].add(q, weights);
                }
            }
        }
    }

    /// Counts a sample in the leaf that holds `s`, and its second-moment weight `w2` in the
    /// leaf's quadrant that holds `s` (its sums go elsewhere: a filter spreads them).
    #[inline]
    pub(crate) fn count_sample(&self, s: Vec2, w2: f64) {
        let (k, _, q) = self.locate(s);
        self.quadrants[k].add(q, w2);
    }

    /// The moments slot of the leaf that holds the fixed-point point `p`, descending from
    /// interior node `node`, whose cell (which holds `p`) is at `depth`.
    #[inline]
    pub(super) fn leaf_below(&self, mut node: u32, mut depth: u32, p: [u32; 2]) -> usize {
        loop {
            let (ix, iy) = quadrant_bits(p, depth + 1);
            let slot = self.nodes[node as usize][ix | iy << 1];
            if slot & LEAF_BIT != 0 {
                return (slot & !LEAF_BIT) as usize;
            }
            node = slot;
            depth += 1;
        }
    }

    /// Every leaf with its recorded moments, in depth-first order (pending sums spread first).
    pub(crate) fn leaves(&self) -> Vec<(DirectionalCell, Moments)> {
        self.flush_pending();
        let mut out = Vec::new();
        self.visit_leaves(|k, cell| out.push((cell, self.moments_of(k))));
        out
    }

    /// Calls `f` with every leaf's moments index and cell, in depth-first order.
    pub(super) fn visit_leaves(&self, mut f: impl FnMut(usize, DirectionalCell)) {
        let mut stack = vec![(0usize, DirectionalCell::ROOT)];
        while let Some((node, cell)) = stack.pop() {
            for (q, &slot) in self.nodes[node].iter().enumerate() {
                if slot & LEAF_BIT != 0 {
                    f((slot & !LEAF_BIT) as usize, cell.child(q));
                } else {
                    stack.push((slot as usize, cell.child(q)));
                }
            }
        }
    }

    /// Leaf `k`'s moments: its sums and its quadrants' count.
    pub(crate) fn moments_of(&self, k: usize) -> Moments {
        self.exact_moments(k).moments()
    }

    /// Leaf `k`'s exact moments.
    pub(crate) fn exact_moments(&self, k: usize) -> ExactMoments {
        let (sum, sum_sq) = self.moments[k].exact();
        ExactMoments {
            sum,
            sum_sq,
            count: self.quadrants[k].count(),
        }
    }

    /// Total samples recorded into the tree (saturating: counts loaded from a file or merged
    /// from many workers may be arbitrarily large).
    pub(crate) fn count(&self) -> u64 {
        self.quadrants
            .iter()
            .fold(0, |n, q| n.saturating_add(q.count()))
    }

    /// Zeroes every leaf's moments (their quadrant sums are not kept past an iteration).
    pub(crate) fn clear_moments(&mut self) {
        for m in self.moments.iter_mut() {
            *m = AtomicSums::default();
        }
    }

    /// Adds the moments, quadrant sums and pending sums of `other`, a tree of the same
    /// topology (a merge), exactly: pending sums stay pending, so that they spread at `refine`
    /// as one machine's would.
    pub(crate) fn add(&mut self, other: &RecordingTree) {
        if !other.pending.is_empty() {
            self.defer();
            for (x, y) in self.pending.iter_mut().zip(other.pending.iter()) {
                x.add_exact(&y.exact());
            }
        }
        for (x, y) in self.moments.iter_mut().zip(other.moments.iter()) {
            x.add_exact(y.exact());
        }
        for (x, y) in self.quadrants.iter_mut().zip(other.quadrants.iter()) {
            x.add_exact(&y.exact());
        }
    }

    pub(crate) fn bytes(&self) -> usize {
        std::mem::size_of_val(&*self.nodes)
            + std::mem::size_of_val(&*self.moments)
            + std::mem::size_of_val(&*self.quadrants)
            + std::mem::size_of_val(&*self.pending)
    }
}
