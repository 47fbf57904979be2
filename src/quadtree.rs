//! The directional quadtree over the unit square (the sphere, through [`crate::sphere`]).
//!
//! Each spatial leaf owns one [`DirectionalTree`], double-buffered as the design asks:
//!
//! - a [`SamplingTree`]: read-only during an iteration, it holds for each node the probability of
//!   each of its four quadrants, and the [`Cuts`] of `u` that `sample` descends by. `sample` and
//!   `pdf` descend it without locks or allocation.
//! - a [`RecordingTree`]: the topology for the current iteration with an [`AtomicMoments`] per
//!   leaf. Recording descends it and adds to one leaf; interior sums are never kept.
//!
//! [`DirectionalTree::refine`] ends an iteration: it turns the leaf moments into masses with the
//! active [`LeafRule`], mixes in the uniform floor, sums interior masses bottom-up into the next
//! sampling tree, and derives the next recording topology by the active [`Refinement`]: split
//! the cells whose share of those masses exceeds ρ (flux share), or whose split gain, estimated
//! from the quadrant sums, exceeds its threshold (variance gain); collapse the others.
//!
//! Quadrants are numbered `q = ix + 2·iy`, with `ix = [s.x ≥ ½]` and `iy = [s.y ≥ ½]` in the
//! node's local frame. Nodes are stored so that a child always comes after its parent, which
//! lets bottom-up passes run as one reverse sweep.

use crate::filter::overlap;
use crate::moments::{AtomicMoments, AtomicPending, AtomicQuadrants};
use crate::refinement::{
    MIN_PREDICTED_SPLIT_SAMPLES, MIN_SPLIT_SAMPLES, Refinement, SPLIT_PRIOR_SAMPLES, split_gain,
};
use crate::selection::GuideSelection;
use crate::sphere::{self, ONE_MINUS_EPSILON, ROUND_TRIP_BOUND};
use crate::{LeafRule, Moments};
use glam::Vec2;
use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// In a [`RecordingTree`] node, marks a child slot as a leaf; the low bits index its moments.
pub(crate) const LEAF_BIT: u32 = 1 << 31;

/// In a [`SamplingTree`] node, the child index of a leaf (the root is node 0, nobody's child).
pub(crate) const NO_CHILD: u16 = 0;

/// Most interior nodes a directional tree may have: sampling nodes index children with `u16`.
pub(crate) const MAX_NODES: u32 = u16::MAX as u32;

/// Bytes one recording leaf holds: its moments (24) and its quadrant sums (64), and under the
/// deferred box filter its pending sums (64 more).
pub(crate) const fn leaf_bytes(deferred: bool) -> u64 {
    let pending = if deferred {
        size_of::<AtomicPending>()
    } else {
        0
    };
    (size_of::<AtomicMoments>() + size_of::<AtomicQuadrants>() + pending) as u64
}

/// Upper bound on the bytes one interior node costs a directional tree: its sampling node (32)
/// and the cuts `sample` descends by (24), its recording node (16), and the three leaves it
/// adds net (336 in all; 528 under the deferred box filter).
pub(crate) const fn bytes_per_node(deferred: bool) -> u64 {
    (size_of::<SamplingNode>() + size_of::<Cuts>() + size_of::<[u32; 4]>()) as u64
        + 3 * leaf_bytes(deferred)
}

/// Bits of the fixed-point square coordinates descents use: deeper than any tree (20 levels).
const FIXED_BITS: u32 = 24;

/// One interior node of a sampling tree: 32 bytes, two to a cache line.
///
/// The node stores conditional probabilities rather than masses, so neither sampling nor pdf
/// evaluation divides: quadrant `q = ix + 2·iy` has probability `px[ix] · py[ix][iy]`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(32))]
pub(crate) struct SamplingNode {
    /// Probability of the left (`ix = 0`) and right column.
    pub(crate) px: [f32; 2],
    /// Within column `ix`: probability of the lower (`iy = 0`) and upper cell.
    pub(crate) py: [[f32; 2]; 2],
    /// Index of each quadrant's node, or [`NO_CHILD`] for a leaf.
    pub(crate) child: [u16; 4],
}

impl SamplingNode {
    /// `4·P(q)`: the density factor of descending into quadrant `(ix, iy)`. Sampling and pdf
    /// evaluation both call this, so the pdf a sample returns is bit-identical to `pdf`'s.
    #[inline]
    fn density_factor(&self, ix: usize, iy: usize) -> f32 {
        4.0 * self.px[ix] * self.py[ix][iy]
    }

    /// The node for quadrant masses `m` (all positive).
    fn from_masses(m: [f64; 4], child: [u16; 4]) -> Self {
        let col = [m[0] + m[2], m[1] + m[3]];
        let total = col[0] + col[1];
        Self {
            px: col.map(|c| (c / total) as f32),
            py: [0, 1].map(|ix| [(m[ix] / col[ix]) as f32, (m[ix + 2] / col[ix]) as f32]),
            child,
        }
    }

    const UNIFORM: SamplingNode = SamplingNode {
        px: [0.5; 2],
        py: [[0.5; 2]; 2],
        child: [NO_CHILD; 4],
    };
}

/// A point of `[0,1)²` as `FIXED_BITS`-bit integers: at depth `d` (1-based) the quadrant bits
/// are bit `FIXED_BITS − d` of each. Exact: `floor(s·2^24) >> (24 − d) = floor(s·2^d)`.
#[inline]
fn fixed(s: Vec2) -> [u32; 2] {
    let scale = (1u32 << FIXED_BITS) as f32;
    let max = (1u32 << FIXED_BITS) - 1;
    // `as` saturates (NaN becomes 0), and `min` keeps 1.0 itself inside.
    [(s.x * scale) as u32, (s.y * scale) as u32].map(|v| v.min(max))
}

/// [`fixed`] for a point in `f64`, exactly: `floor(p·2^24)`. The box filter finds where its
/// parts' centres lie with it, and a part can be a sliver a hair from a cell's border, whose
/// centre rounding to `f32` could move across it.
#[inline]
fn fixed_f64(p: [f64; 2]) -> [u32; 2] {
    let scale = f64::from(1u32 << FIXED_BITS);
    let max = (1u32 << FIXED_BITS) - 1;
    p.map(|c| ((c * scale) as u32).min(max))
}

/// The quadrant bits of a fixed-point point at depth `d`.
#[inline]
fn quadrant_bits(p: [u32; 2], d: u32) -> (usize, usize) {
    let shift = FIXED_BITS - d;
    (
        ((p[0] >> shift) & 1) as usize,
        ((p[1] >> shift) & 1) as usize,
    )
}

/// `4^-depth`, the area of a cell at `depth`, built from its exponent bits (no `powi` call).
#[inline]
fn cell_area(depth: u32) -> f64 {
    f64::from_bits(u64::from(1023 - 2 * depth) << 52)
}

/// The interval `[a, b)`, no longer than `size`, cut where it crosses a multiple of `size` (a
/// power of 2, so the cut is exact): one or two pieces.
fn grid_cut([a, b]: [f64; 2], size: f64) -> [Option<[f64; 2]>; 2] {
    let line = ((a / size).floor() + 1.0) * size;
    if line < b {
        [Some([a, line]), Some([line, b])]
    } else {
        [Some([a, b]), None]
    }
}

/// `if choice == 1 { b } else { a }` (`choice` is 0 or 1), by bit masks: in a descent each
/// choice is a coin flip, and the compiler turns an `if`, or `choice as f32`, into a jump that
/// is mispredicted half the time. (`std::hint::select_unpredictable` on `choice == 1` came out
/// slower here, measured: 87.5 against 66.8 ns per `sample` in a loop over one distribution.)
#[inline(always)]
fn pick(choice: usize, a: f32, b: f32) -> f32 {
    let mask = 0u32.wrapping_sub(choice as u32);
    f32::from_bits(b.to_bits() & mask | a.to_bits() & !mask)
}

/// Clamps a sample coordinate into `[0, 1)`; NaN becomes 0 (which `clamp` would not do).
#[inline]
#[allow(clippy::manual_clamp, reason = "max/min map NaN to 0; clamp keeps NaN")]
fn unit(x: f32) -> f32 {
    x.max(0.0).min(ONE_MINUS_EPSILON)
}

/// A directional cell: the square `[origin, origin + size)` of the unit square at `depth` (the
/// root's children are at depth 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DirectionalCell {
    /// The cell's corner with the smallest coordinates, on the unit square.
    pub origin: Vec2,
    /// The cell's side: `2^-depth`.
    pub size: f32,
    /// The cell's level in the quadtree.
    pub depth: u32,
}

impl DirectionalCell {
    /// The fraction of the square (and of the sphere) the cell covers.
    pub fn area(&self) -> f64 {
        f64::from(self.size) * f64::from(self.size)
    }

    /// Whether the cell holds the point `s` of the unit square (its lower sides in, its upper
    /// sides out, as the quadtree descends). With [`sphere::direction_to_square`], this finds
    /// the leaf that holds a direction among a distribution's
    /// [`leaves`](crate::DirectionalDistribution::leaves).
    ///
    /// ```
    /// use glam::Vec2;
    /// use sdguide::DirectionalCell;
    /// let cell = DirectionalCell { origin: Vec2::new(0.5, 0.25), size: 0.25, depth: 2 };
    /// assert!(cell.contains(Vec2::new(0.5, 0.25)));
    /// assert!(cell.contains(Vec2::new(0.7, 0.4)));
    /// assert!(!cell.contains(Vec2::new(0.75, 0.3)));
    /// ```
    ///
    /// [`sphere::direction_to_square`]: crate::sphere::direction_to_square
    pub fn contains(&self, s: Vec2) -> bool {
        let (lo, hi) = (self.origin, self.origin + Vec2::splat(self.size));
        s.cmpge(lo).all() && s.cmplt(hi).all()
    }

    pub(crate) fn child(&self, q: usize) -> DirectionalCell {
        let half = 0.5 * self.size;
        let offset = Vec2::new((q & 1) as f32, (q >> 1) as f32) * half;
        DirectionalCell {
            origin: self.origin + offset,
            size: half,
            depth: self.depth + 1,
        }
    }

    const ROOT: DirectionalCell = DirectionalCell {
        origin: Vec2::ZERO,
        size: 1.0,
        depth: 0,
    };
}

/// Where [`SamplingTree::sample`] cuts one node's interval of `u`: the node's
/// [`SamplingNode`] probabilities turned into absolute thresholds along the node's path, once,
/// when the tree is built. With them the descent is a chain of compares and loads, with no
/// arithmetic on the values of the levels above.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(8))]
pub(crate) struct Cuts {
    /// `u.x` at or past it takes the right column (`ix = 1`).
    x: f32,
    /// Within column `ix`, `u.y` at or past `y[ix]` takes the upper cell (`iy = 1`).
    y: [f32; 2],
    /// The node's children, as in its [`SamplingNode`], child `q` in bits `16q..16q + 16`:
    /// one load with the cuts, and a shift once the quadrant is known (a second load would
    /// lengthen the chain).
    child: u64,
}

/// The read-only, piecewise-constant density on the square that queries use.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct SamplingTree {
    nodes: Box<[SamplingNode]>,
    /// Per node, the thresholds `sample` descends by (derived from `nodes`).
    cuts: Box<[Cuts]>,
}

impl SamplingTree {
    /// The uniform density: one root with four equal leaves.
    pub(crate) fn uniform() -> Self {
        Self::new(Box::new([SamplingNode::UNIFORM]))
    }

    /// The tree of `nodes` (children after their parents, the root first).
    ///
    /// Each node's interval of `u` is `[a, a + w)`, with `a` and `w` what the descent has
    /// accumulated on the way down, in the same `f32` operations in the same order as a
    /// descent that cuts the interval level by level; so the cuts are bit for bit the values
    /// that descent would compare against.
    pub(crate) fn new(nodes: Box<[SamplingNode]>) -> Self {
        let mut interval = vec![(Vec2::ZERO, Vec2::ONE); nodes.len()];
        let mut cuts = Vec::with_capacity(nodes.len());
        for (i, n) in nodes.iter().enumerate() {
            let (a, w) = interval[i];
            let left = w.x * n.px[0];
            let low = [w.y * n.py[0][0], w.y * n.py[1][0]];
            cuts.push(Cuts {
                x: a.x + left,
                y: [a.y + low[0], a.y + low[1]],
                child: n
                    .child
                    .iter()
                    .rev()
                    .fold(0, |bits, &c| bits << 16 | u64::from(c)),
            });
            for (q, &c) in n.child.iter().enumerate() {
                let (ix, iy) = (q & 1, q >> 1);
                // Children come after their parents; a forged file is checked before this.
                if let Some(slot) = interval.get_mut(usize::from(c)).filter(|_| c != NO_CHILD) {
                    *slot = (
                        Vec2::new(a.x + left * ix as f32, a.y + low[ix] * iy as f32),
                        Vec2::new(w.x * n.px[ix], w.y * n.py[ix][iy]),
                    );
                }
            }
        }
        Self {
            nodes,
            cuts: cuts.into_boxed_slice(),
        }
    }

    /// The nodes, root first.
    pub(crate) fn nodes(&self) -> &[SamplingNode] {
        &self.nodes
    }

    /// Draws a point from `u ∈ [0,1)²`: returns the point, its density on the square, and
    /// whether the point may lie within rounding distance of its leaf's border.
    ///
    /// The descent uses the caller's two numbers throughout: at each level the interval of `u`
    /// that leads to the current node, `[a, a + w)`, is cut by the quadrant probabilities, and
    /// inside the leaf `(u − a)/w` places the point uniformly. (Cutting the interval instead of
    /// rescaling `u` keeps divisions off the per-level dependency chain.)
    #[inline]
    pub(crate) fn sample(&self, u: Vec2) -> (Vec2, f32, bool) {
        let u = Vec2::new(unit(u.x), unit(u.y));
        let (mut a, mut w) = (Vec2::ZERO, Vec2::ONE);
        let mut cell = [0u32; 2];
        let mut depth = 0;
        let mut pdf = 1.0;
        let mut node = 0usize;
        loop {
            // The chain from one level to the next: load the cuts (with the children), compare,
            // shift out the child.
            // Branch-free: with random `u` each choice is a coin flip no predictor can learn, so
            // choices become indices and selects, never jumps. The lower/upper choice is made
            // for both columns at once, off the x chain. `a`, `w` and the density follow off
            // the chain.
            let c = &self.cuts[node];
            let ix = usize::from(u.x >= c.x);
            let up = [u.y >= c.y[0], u.y >= c.y[1]];
            let iy = usize::from(up[0]) & (ix ^ 1) | usize::from(up[1]) & ix;
            let n = &self.nodes[node];
            a.x = pick(ix, a.x, c.x);
            a.y = pick(iy, a.y, c.y[ix]);
            w.x *= n.px[ix];
            w.y *= n.py[ix][iy];
            pdf *= n.density_factor(ix, iy);
            cell = [2 * cell[0] + ix as u32, 2 * cell[1] + iy as u32];
            depth += 1;
            match (c.child >> (16 * (ix | iy << 1))) as u16 {
                NO_CHILD => break,
                c => node = usize::from(c),
            }
        }
        // 2^∓depth from exponent bits (depth ≤ 20: both are normal f32), not `powi` calls.
        let size = f32::from_bits((127 - depth) << 23);
        let inv_size = f32::from_bits((127 + depth) << 23);
        let local = Vec2::new(unit((u.x - a.x) / w.x), unit((u.y - a.y) / w.y));
        let origin = Vec2::new(cell[0] as f32, cell[1] as f32) * size;
        let margin = ROUND_TRIP_BOUND * inv_size;
        let near_border = local.min_element() <= margin || local.max_element() >= 1.0 - margin;
        (origin + local * size, pdf, near_border)
    }

    /// The density on the square at `s ∈ [0,1)²`.
    #[inline]
    pub(crate) fn pdf(&self, s: Vec2) -> f32 {
        let p = fixed(s);
        let mut pdf = 1.0;
        let mut node = 0usize;
        let mut depth = 1;
        loop {
            let n = &self.nodes[node];
            let (ix, iy) = quadrant_bits(p, depth);
            pdf *= n.density_factor(ix, iy);
            match n.child[ix | iy << 1] {
                NO_CHILD => return pdf,
                c => node = usize::from(c),
            }
            depth += 1;
        }
    }

    /// Every leaf with its probability (its mass), in depth-first order.
    pub(crate) fn leaves(&self) -> Vec<(DirectionalCell, f32)> {
        let mut out = Vec::new();
        let mut stack = vec![(0usize, DirectionalCell::ROOT, 1.0f32)];
        while let Some((node, cell, mass)) = stack.pop() {
            let n = &self.nodes[node];
            for q in 0..4 {
                let m = mass * n.px[q & 1] * n.py[q & 1][q >> 1];
                match n.child[q] {
                    NO_CHILD => out.push((cell.child(q), m)),
                    c => stack.push((usize::from(c), cell.child(q), m)),
                }
            }
        }
        out
    }

    pub(crate) fn node_count(&self) -> usize {
        self.nodes.len()
    }

    pub(crate) fn bytes(&self) -> usize {
        std::mem::size_of_val(&*self.nodes) + std::mem::size_of_val(&*self.cuts)
    }
}

/// An interior node of a recording tree with its cell, where a box filter's walk starts.
#[derive(Clone, Copy, Debug)]
struct Walk {
    node: u32,
    /// The cell's corner with the smallest coordinates.
    x: f64,
    y: f64,
    /// The cell's side.
    cell: f64,
    depth: u32,
}

impl Walk {
    const ROOT: Walk = Walk {
        node: 0,
        x: 0.0,
        y: 0.0,
        cell: 1.0,
        depth: 0,
    };

    /// Whether the node's cell holds the piece `[x0, x1) × [y0, y1)`.
    fn holds(&self, [x0, x1]: [f64; 2], [y0, y1]: [f64; 2]) -> bool {
        x0 >= self.x && y0 >= self.y && x1 <= self.x + self.cell && y1 <= self.y + self.cell
    }
}

/// The interior nodes on the way from the root down to a leaf, and the leaf's cell: where the
/// box filter's lookups near the leaf start, so that they need not walk from the root.
#[derive(Clone, Copy, Debug)]
struct Ancestry {
    /// `nodes[d]` is the interior node whose cell, at depth `d`, holds the leaf (`nodes[0]` is
    /// the root); entries at the leaf's depth and below mean nothing.
    nodes: [u32; FIXED_BITS as usize],
    /// The leaf's depth, at least 1.
    depth: u32,
    /// A point of the leaf's cell in fixed point: all of them share the bits that name it.
    at: [u32; 2],
}

impl Ancestry {
    fn new(at: [u32; 2]) -> Self {
        Self {
            nodes: [0; FIXED_BITS as usize],
            depth: 1,
            at,
        }
    }

    /// The leaf's side.
    fn side(&self) -> f64 {
        cell_area(self.depth).sqrt()
    }

    /// The leaf's cell: its corner with the smallest coordinates.
    fn corner(&self) -> [f64; 2] {
        self.corner_at(self.depth)
    }

    /// The corner of the cell at depth `d` that holds the leaf (`d` at most the leaf's depth).
    fn corner_at(&self, d: u32) -> [f64; 2] {
        let shift = FIXED_BITS - d;
        self.at.map(|c| f64::from(c >> shift) * cell_area(d).sqrt())
    }

    /// Whether the point `p` lies in the leaf's cell.
    fn leaf_holds(&self, p: [f64; 2]) -> bool {
        let (corner, side) = (self.corner(), self.side());
        (0..2).all(|i| p[i] >= corner[i] && p[i] < corner[i] + side)
    }

    /// The moments slot of the leaf that holds the point `p` (outside the leaf), descending
    /// from the deepest node of the chain whose cell holds it: the depth at which `p`'s bits
    /// part from the leaf's.
    fn leaf_near(&self, tree: &RecordingTree, p: [u32; 2]) -> usize {
        let shared =
            ((self.at[0] ^ p[0]) | (self.at[1] ^ p[1])).leading_zeros() - (32 - FIXED_BITS);
        let d = shared.min(self.depth - 1);
        tree.leaf_below(self.nodes[d as usize], d, p)
    }

    /// The deepest node of the chain whose cell holds the piece `[x0, x1) × [y0, y1)`: a walk
    /// from the root would pass through it.
    fn holding(&self, x: [f64; 2], y: [f64; 2]) -> Walk {
        (0..self.depth)
            .rev()
            .map(|d| {
                let [x, y] = self.corner_at(d);
                Walk {
                    node: self.nodes[d as usize],
                    x,
                    y,
                    cell: cell_area(d).sqrt(),
                    depth: d,
                }
            })
            .find(|w| w.holds(x, y))
            .unwrap_or(Walk::ROOT)
    }
}

/// One sample's shares of the box filter, gathered before any is added. An atomic add is a
/// locked instruction on x86, and the loads after it wait for it: added as the walk finds them,
/// the shares would pay their leaves' cache misses one after another. Loaded first, together
/// ([`touch`](Self::touch)), the misses overlap, and the adds find their lines in cache. With
/// the grid cut of [`box_shares`](RecordingTree::box_shares), that took `record` under the box
/// filter from about 365 to 315–330 ns on the standard workload, in interleaved runs. One
/// leaf's adds (no filter, or the deferred filter's) gained nothing from loading first.
struct Shares {
    parts: [(usize, (f64, f64)); Self::CAP],
    len: usize,
}

impl Shares {
    /// Enough for the shares of a sample whose square stays inside the unit square: at most
    /// four. Near the border, where the square is folded into up to four pieces with up to
    /// four shares each, the shares past these are added at once.
    const CAP: usize = 8;

    fn new() -> Self {
        Self {
            parts: [(0, (0.0, 0.0)); Self::CAP],
            len: 0,
        }
    }

    fn push(&mut self, moments: &[AtomicMoments], leaf: usize, part: (f64, f64)) {
        if self.len < Self::CAP {
            self.parts[self.len] = (leaf, part);
            self.len += 1;
        } else {
            moments[leaf].add_sums(part);
        }
    }

    /// Loads the targets' words (see the type's doc); the result means nothing.
    fn touch(&self, moments: &[AtomicMoments]) -> u64 {
        self.parts[..self.len]
            .iter()
            .fold(0, |t, &(leaf, _)| t ^ moments[leaf].touch())
    }

    fn add(&self, moments: &[AtomicMoments]) {
        for &(leaf, part) in &self.parts[..self.len] {
            moments[leaf].add_sums(part);
        }
    }
}

/// A child slot of a recording node under construction that will become a leaf.
const FREE: u32 = 0;

/// The topology of the current iteration and the moments recorded into its leaves.
#[derive(Clone, Debug)]
pub(crate) struct RecordingTree {
    /// Child slots: an interior node's index, or `LEAF_BIT | index into moments`.
    pub(crate) nodes: Box<[[u32; 4]]>,
    pub(crate) moments: Box<[AtomicMoments]>,
    /// Per leaf (same index as `moments`): the second-moment sums of its four quadrants, from
    /// the samples that landed in it (unfiltered).
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
    fn root() -> Self {
        Self::from_nodes(vec![[FREE; 4]], false)
    }

    /// Builds a tree from interior nodes whose leaf slots are marked `FREE`: numbers the
    /// leaves in node order and gives each a zeroed accumulator (and pending sums if `deferred`).
    fn from_nodes(mut nodes: Vec<[u32; 4]>, deferred: bool) -> Self {
        let mut leaves = 0u32;
        for slot in nodes.iter_mut().flatten() {
            if *slot == FREE {
                *slot = LEAF_BIT | leaves;
                leaves += 1;
            }
        }
        let mut tree = Self {
            nodes: nodes.into_boxed_slice(),
            moments: (0..leaves).map(|_| AtomicMoments::default()).collect(),
            quadrants: (0..leaves).map(|_| AtomicQuadrants::default()).collect(),
            pending: Box::default(),
        };
        if deferred {
            tree.defer();
        }
        tree
    }

    /// Gives every leaf pending sums, so that [`record_deferred`](Self::record_deferred) defers.
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
    fn locate(&self, s: Vec2) -> (usize, u32, usize) {
        self.descend(fixed(s), |_, _| {})
    }

    /// [`locate`](Self::locate) for the fixed-point point `p`, handing `visit(depth, node)`
    /// each interior node on the way.
    #[inline]
    fn descend(&self, p: [u32; 2], mut visit: impl FnMut(u32, u32)) -> (usize, u32, usize) {
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
    /// with its shares' leaves before the atomic adds (see [`Shares`]); the result means
    /// nothing.
    #[inline]
    fn touch(&self, k: usize, q: usize) -> u64 {
        self.moments[k].touch() ^ self.quadrants[k].touch(q)
    }

    /// The moments slot of the leaf that holds `s`, and the leaf's side.
    #[inline]
    fn leaf_of(&self, s: Vec2) -> (usize, f64) {
        let (k, depth, _) = self.locate(s);
        (k, cell_area(depth).sqrt())
    }

    /// Adds one sample of weights `(v/p, v²/p)` to the leaf that holds `s`.
    #[inline]
    pub(crate) fn record(&self, s: Vec2, weights: (f64, f64)) {
        let (k, _, q) = self.locate(s);
        self.moments[k].add(weights);
        self.quadrants[k].add(q, weights.1);
    }

    /// Adds weights to the leaf that holds `s` without counting a sample.
    #[inline]
    pub(crate) fn record_sums(&self, s: Vec2, weights: (f64, f64)) {
        self.moments[self.leaf_of(s).0].add_sums(weights);
    }

    /// Counts a sample in the leaf that holds `s`, and its second-moment weight `w2` in the
    /// leaf's quadrant that holds `s` (its sums go elsewhere: a filter spreads them).
    #[inline]
    pub(crate) fn count_sample(&self, s: Vec2, w2: f64) {
        let (k, _, q) = self.locate(s);
        self.moments[k].add_count();
        self.quadrants[k].add(q, w2);
    }

    /// Counts the sample where it landed, and adds its weights to the pending sums of the
    /// leaf's quadrant that holds `s`, for [`flush_pending`](Self::flush_pending) to spread
    /// (the deferred box filter). Without pending sums it spreads them at once, as
    /// [`record_box`](Self::record_box) does.
    #[inline]
    pub(crate) fn record_deferred(&self, s: Vec2, weights: (f64, f64)) {
        if self.pending.is_empty() {
            return self.record_box(s, weights);
        }
        let (k, _, q) = self.locate(s);
        self.moments[k].add_count();
        self.quadrants[k].add(q, weights.1);
        self.pending[k].add(q, weights);
    }

    /// [`record_deferred`](Self::record_deferred) without counting a sample.
    #[inline]
    pub(crate) fn record_deferred_sums(&self, s: Vec2, weights: (f64, f64)) {
        if self.pending.is_empty() {
            return self.record_box_sums(s, weights);
        }
        let (k, _, q) = self.locate(s);
        self.pending[k].add(q, weights);
    }

    /// Spreads every leaf's pending sums into the leaves' moments, as the box filter would
    /// have: each quadrant's sums over a square the size of its leaf, centred on the quadrant.
    /// Safe while other threads record (the sums are taken atomically, and what they add after
    /// waits for the next flush); the moments then hold what they will hold at refine.
    pub(crate) fn flush_pending(&self) {
        if self.pending.is_empty() {
            return;
        }
        self.spread_pending(|k| self.pending[k].take(), &mut |k, part| {
            self.moments[k].add_sums(part)
        });
    }

    /// [`flush_pending`](Self::flush_pending) with the tree to itself (at refine): plain loads
    /// and adds instead of atomic ones, which would be most of its cost.
    pub(crate) fn flush_pending_mut(&mut self) {
        if self.pending.is_empty() {
            return;
        }
        let mut pending = std::mem::take(&mut self.pending);
        let mut moments = std::mem::take(&mut self.moments);
        self.spread_pending(|k| pending[k].take_mut(), &mut |k, part| {
            moments[k].add_sums_mut(part)
        });
        (self.pending, self.moments) = (pending, moments);
    }

    /// Spreads each leaf's pending sums, as `take(leaf)` yields them, over a leaf-sized square
    /// centred on each quadrant, handing the shares to `add` (reads only the topology, so the
    /// sums may be moved out of the tree meanwhile).
    ///
    /// The shares are those the box filter hands out for a sample at each quadrant's centre.
    /// The leaves are visited depth first with the chain of nodes down to them at hand, so that
    /// each lookup starts at the deepest node of that chain that holds what it looks for, not
    /// at the root (see [`spread_square`](Self::spread_square)).
    fn spread_pending(
        &self,
        mut take: impl FnMut(usize) -> [(f64, f64); 4],
        add: &mut impl FnMut(usize, (f64, f64)),
    ) {
        let mut chain = Ancestry::new([0, 0]);
        self.spread_below(&mut chain, 0, 0, [0, 0], &mut take, add);
    }

    /// [`spread_pending`](Self::spread_pending) for the leaves below interior node `node`,
    /// whose cell at `depth` has the fixed-point corner `corner`; `chain` holds the nodes above.
    fn spread_below(
        &self,
        chain: &mut Ancestry,
        node: u32,
        depth: u32,
        corner: [u32; 2],
        take: &mut impl FnMut(usize) -> [(f64, f64); 4],
        add: &mut impl FnMut(usize, (f64, f64)),
    ) {
        chain.nodes[depth as usize] = node;
        let bit = FIXED_BITS - depth - 1;
        for (q, &slot) in self.nodes[node as usize].iter().enumerate() {
            let child = [
                corner[0] | ((q & 1) as u32) << bit,
                corner[1] | ((q >> 1) as u32) << bit,
            ];
            if slot & LEAF_BIT == 0 {
                self.spread_below(chain, slot, depth + 1, child, take, add);
                continue;
            }
            (chain.depth, chain.at) = (depth + 1, child);
            let k = (slot & !LEAF_BIT) as usize;
            let size = chain.side();
            let per_area = 1.0 / (size * size);
            let corner = chain.corner();
            let mut own = (0.0, 0.0);
            for (q, (w1, w2)) in take(k).into_iter().enumerate() {
                if w1 == 0.0 {
                    continue;
                }
                let centre = [
                    corner[0] + (0.25 + 0.5 * (q & 1) as f64) * size,
                    corner[1] + (0.25 + 0.5 * (q >> 1) as f64) * size,
                ];
                let o = self.spread_square(chain, centre, (w1 * per_area, w2 * per_area), add);
                own = (own.0 + o.0, own.1 + o.1);
            }
            if own.0 != 0.0 {
                add(k, own);
            }
        }
    }

    /// The box filter's shares of a square as large as the leaf at the end of `chain`,
    /// centred on `centre` in the leaf, with weights `per_area` per unit area: hands `add` the
    /// shares of the other leaves and returns the leaf's own.
    ///
    /// The square reaches at most half the leaf's side past it. Cut along the lines of the grid
    /// of cells of the leaf's size, it falls in at most four such cells: the leaf itself and
    /// three neighbours. Each part goes whole to the leaf that holds its centre: that is the
    /// leaf itself, a neighbour that is a leaf, the leaf that holds a neighbour, or, in a
    /// neighbour split finer than the square, the leaf the box filter gives a finer region's
    /// share. So the shares are the box filter's (tested against its walk from the root,
    /// `splat_into`), and each costs one descent from the deepest node of the chain that holds
    /// the part. Parts that the border folds elsewhere are walked as that walk goes, from the
    /// deepest node of the chain that holds them.
    fn spread_square(
        &self,
        chain: &Ancestry,
        centre: [f64; 2],
        (w1, w2): (f64, f64),
        add: &mut impl FnMut(usize, (f64, f64)),
    ) -> (f64, f64) {
        let size = chain.side();
        let h = 0.5 * size;
        let [inside, folded @ ..] = sphere::fold_box(
            [centre[0] - h, centre[0] + h],
            [centre[1] - h, centre[1] + h],
        );
        let mut own = (0.0, 0.0);
        if let Some([x, y]) = inside {
            for x in grid_cut(x, size).into_iter().flatten() {
                for y in grid_cut(y, size).into_iter().flatten() {
                    let area = (x[1] - x[0]) * (y[1] - y[0]);
                    let part = (w1 * area, w2 * area);
                    let mid = [0.5 * (x[0] + x[1]), 0.5 * (y[0] + y[1])];
                    if chain.leaf_holds(mid) {
                        own = (own.0 + part.0, own.1 + part.1);
                    } else {
                        add(chain.leaf_near(self, fixed_f64(mid)), part);
                    }
                }
            }
        }
        for [x, y] in folded.into_iter().flatten() {
            if x[1] > x[0] && y[1] > y[0] {
                self.splat_piece(chain.holding(x, y), x, y, size, (w1, w2), add);
            }
        }
        own
    }

    /// The box filter's shares of a sample at `s` with weights `(v/p, v²/p)`: hands `add` each
    /// leaf's share of a square the size of the leaf holding `s`, centred on `s`, in
    /// proportion to the overlap, and returns that leaf's moments slot and the quadrant of it
    /// that holds `s`.
    ///
    /// Where the square crosses the border of the unit square, the part outside is folded back
    /// in as the map folds the sphere ([`sphere::fold_box`]), so the sample reaches its
    /// neighbours on the sphere. A leaf gets its share; a region the square overlaps that is
    /// subdivided more finely than the square gets its share in the one leaf holding the centre
    /// of the overlap — the filter smooths at the scale of the sample's own leaf, so the work
    /// per sample is bounded (a few cells) however fine the neighbourhood. No allocation: the
    /// neighbours are found from the nodes the descent to the sample's leaf passed.
    #[inline]
    fn box_shares(
        &self,
        s: Vec2,
        (w1, w2): (f64, f64),
        add: &mut impl FnMut(usize, (f64, f64)),
    ) -> (usize, usize) {
        let p = fixed(s);
        let mut chain = Ancestry::new(p);
        let (k, depth, q) = self.descend(p, |d, node| chain.nodes[d as usize] = node);
        chain.depth = depth;
        if w1 != 0.0 {
            let per_area = 1.0 / cell_area(depth);
            let centre = [f64::from(s.x), f64::from(s.y)];
            let own = self.spread_square(&chain, centre, (w1 * per_area, w2 * per_area), add);
            add(k, own);
        }
        (k, q)
    }

    /// [`record_box_sums`](Self::record_box_sums), and counts the sample where it landed.
    pub(crate) fn record_box(&self, s: Vec2, weights: (f64, f64)) {
        let mut shares = Shares::new();
        let (k, q) = self.box_shares(s, weights, &mut |leaf, part| {
            shares.push(&self.moments, leaf, part)
        });
        std::hint::black_box(self.touch(k, q) ^ shares.touch(&self.moments));
        self.moments[k].add_count();
        self.quadrants[k].add(q, weights.1);
        shares.add(&self.moments);
    }

    /// Adds weights `(v/p, v²/p)` to the cells that a square the size of the leaf holding `s`,
    /// centred on `s`, overlaps, in proportion to the overlap (see
    /// [`box_shares`](Self::box_shares)).
    pub(crate) fn record_box_sums(&self, s: Vec2, weights: (f64, f64)) {
        let mut shares = Shares::new();
        self.box_shares(s, weights, &mut |leaf, part| {
            shares.push(&self.moments, leaf, part)
        });
        std::hint::black_box(shares.touch(&self.moments));
        shares.add(&self.moments);
    }

    /// The box filter walked from the root, handing each leaf's share to `add(leaf, (w1, w2))`
    /// (`size` is the side of the leaf holding `s`): the reference that the shortcuts of
    /// [`box_shares`](Self::box_shares) and [`spread_pending`](Self::spread_pending) are tested
    /// against.
    #[cfg(test)]
    fn splat_into(
        &self,
        s: Vec2,
        size: f64,
        (w1, w2): (f64, f64),
        add: &mut impl FnMut(usize, (f64, f64)),
    ) {
        if w1 == 0.0 {
            return;
        }
        let (sx, sy) = (f64::from(s.x), f64::from(s.y));
        let h = 0.5 * size;
        let area = size * size;
        // In f64, so that the shares of one sample sum to 1 within a few 1e-16.
        let per_area = (w1 / area, w2 / area);
        for [x, y] in sphere::fold_box([sx - h, sx + h], [sy - h, sy + h])
            .into_iter()
            .flatten()
        {
            if x[1] > x[0] && y[1] > y[0] {
                self.splat_piece(Walk::ROOT, x, y, size, per_area, add);
            }
        }
    }

    /// Hands `add` `per_area` times the overlapped area for each cell that the piece
    /// `[x0, x1) × [y0, y1)` of the unit square overlaps (see [`box_shares`](Self::box_shares);
    /// `size` is the filter's square's side), walking down from `start`, whose cell holds the
    /// piece.
    fn splat_piece(
        &self,
        start: Walk,
        [x0, x1]: [f64; 2],
        [y0, y1]: [f64; 2],
        size: f64,
        (w1, w2): (f64, f64),
        add: &mut impl FnMut(usize, (f64, f64)),
    ) {
        // 1. Down to the deepest node whose cell holds the whole piece.
        let (mut node, mut ox, mut oy, mut cell) = (start.node, start.x, start.y, start.cell);
        let mut depth = start.depth;
        loop {
            let half = 0.5 * cell;
            let (ix, iy) = (usize::from(x0 >= ox + half), usize::from(y0 >= oy + half));
            let (cx, cy) = (ox + ix as f64 * half, oy + iy as f64 * half);
            let slot = self.nodes[node as usize][ix | iy << 1];
            if x1 > cx + half || y1 > cy + half || slot & LEAF_BIT != 0 {
                break;
            }
            (node, ox, oy, cell) = (slot, cx, cy, half);
            depth += 1;
        }
        // 2. Level by level below it, down to cells of the square's size. The piece, no larger
        //    than the square, overlaps at most 2 × 2 cells of any level at least the square's
        //    size, so each level holds at most 4 cells.
        let mut level = [(node, ox, oy); 4];
        let mut cells = 1;
        while cells > 0 {
            let half = 0.5 * cell;
            let mut next = [(0u32, 0.0f64, 0.0f64); 4];
            let mut pending = 0;
            for &(node, ox, oy) in &level[..cells] {
                for (q, &slot) in self.nodes[node as usize].iter().enumerate() {
                    let (cx, cy) = (ox + (q & 1) as f64 * half, oy + (q >> 1) as f64 * half);
                    let fx = overlap(x0, x1, cx, cx + half);
                    let fy = overlap(y0, y1, cy, cy + half);
                    if fx <= 0.0 || fy <= 0.0 {
                        continue;
                    }
                    let part = (w1 * fx * fy, w2 * fx * fy);
                    if slot & LEAF_BIT != 0 {
                        add((slot & !LEAF_BIT) as usize, part);
                    } else if half <= size || pending == next.len() {
                        // Finer than the square (or, unreachably, a fifth cell): the leaf
                        // holding the overlap's centre, found from this cell down.
                        let centre = fixed_f64([
                            0.5 * (x0.max(cx) + x1.min(cx + half)),
                            0.5 * (y0.max(cy) + y1.min(cy + half)),
                        ]);
                        add(self.leaf_below(slot, depth + 1, centre), part);
                    } else {
                        next[pending] = (slot, cx, cy);
                        pending += 1;
                    }
                }
            }
            (level, cells, cell) = (next, pending, half);
            depth += 1;
        }
    }

    /// The moments slot of the leaf that holds the fixed-point point `p`, descending from
    /// interior node `node`, whose cell (which holds `p`) is at `depth`.
    #[inline]
    fn leaf_below(&self, mut node: u32, mut depth: u32, p: [u32; 2]) -> usize {
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
        self.visit_leaves(|k, cell| out.push((cell, self.moments[k].get())));
        out
    }

    /// Calls `f` with every leaf's moments index and cell, in depth-first order.
    fn visit_leaves(&self, mut f: impl FnMut(usize, DirectionalCell)) {
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

    /// Total samples recorded into the tree (saturating: counts loaded from a file or merged
    /// from many workers may be arbitrarily large).
    pub(crate) fn count(&self) -> u64 {
        self.moments
            .iter()
            .fold(0, |n, m| n.saturating_add(m.get().count))
    }

    pub(crate) fn bytes(&self) -> usize {
        std::mem::size_of_val(&*self.nodes)
            + std::mem::size_of_val(&*self.moments)
            + std::mem::size_of_val(&*self.quadrants)
            + std::mem::size_of_val(&*self.pending)
    }

    /// Each leaf's `(S1, S2)` shrunk toward its parent's: top-down, a cell's estimate is
    /// `w · (its own pooled sums) + (1 − w) · (its parent's estimate) / 4` with
    /// `w = n / (n + n0)`, `n` the samples that fell in the cell and `n0 = prior_samples`.
    ///
    /// Sums over a few samples of heavy-tailed values are mostly too small (and sometimes far
    /// too large); a leaf whose mass is underestimated costs `m_i/α_i`, without bound. Pooling
    /// a sparse leaf with its siblings — which estimate neighbouring parts of the same light —
    /// bounds that, and leaves well-sampled leaves (`n ≫ n0`) as they were. `n0 = 0` turns it off.
    ///
    /// Returns the estimates of every interior node (the root's is its pooled sums) and of
    /// every leaf.
    pub(crate) fn shrunk_moments(&self, prior_samples: f64) -> ShrunkMoments {
        self.shrink(prior_samples, |k| {
            let m = self.moments[k].get();
            (m.sum, m.sum_sq, m.count)
        })
    }

    /// [`shrunk_moments`](Self::shrunk_moments) of any per-leaf sums `(S1, S2, n)`.
    fn shrink(&self, prior_samples: f64, leaf: impl Fn(usize) -> (f64, f64, u64)) -> ShrunkMoments {
        let n = self.nodes.len();
        // Pooled sums per node, bottom-up (children have larger indices than their parents).
        let mut pooled = vec![(0.0f64, 0.0f64, 0u64); n];
        let slot_moments = |slot: u32, pooled: &[(f64, f64, u64)]| {
            if slot & LEAF_BIT != 0 {
                leaf((slot & !LEAF_BIT) as usize)
            } else {
                pooled[slot as usize]
            }
        };
        for i in (0..n).rev() {
            pooled[i] = self.nodes[i].iter().fold((0.0, 0.0, 0), |a, &slot| {
                let m = slot_moments(slot, &pooled);
                (a.0 + m.0, a.1 + m.1, a.2.saturating_add(m.2))
            });
        }
        // Shrunk estimates, top-down.
        let mut estimate = vec![(0.0f64, 0.0f64); n];
        let mut leaves = vec![(0.0f64, 0.0f64); self.moments.len()];
        estimate[0] = (pooled[0].0, pooled[0].1);
        for i in 0..n {
            let prior = (0.25 * estimate[i].0, 0.25 * estimate[i].1);
            for &slot in &self.nodes[i] {
                let (s1, s2, count) = slot_moments(slot, &pooled);
                let w = if prior_samples > 0.0 {
                    count as f64 / (count as f64 + prior_samples)
                } else {
                    1.0
                };
                let e = (w * s1 + (1.0 - w) * prior.0, w * s2 + (1.0 - w) * prior.1);
                if slot & LEAF_BIT != 0 {
                    leaves[(slot & !LEAF_BIT) as usize] = e;
                } else {
                    estimate[slot as usize] = e;
                }
            }
        }
        ShrunkMoments {
            nodes: estimate,
            leaves,
        }
    }

    /// Split keys for [`Refinement::VarianceGain`]: each cell's estimated gain
    /// `sqrt(m) − Σ_q sqrt(m_q)` (in units of `sqrt(|C|·S2)` of the shrunk sums), and the
    /// threshold `gain_threshold · Σ_leaves sqrt(m)`. Interior cells take their children's
    /// estimates, leaves their quadrant sums (see [`crate::refinement`]).
    fn gain_keys(&self, depth: &[u32], params: &RefineParams) -> SplitKeys {
        let quadrants: Vec<_> = self.quadrants.iter().map(|q| q.get()).collect();
        // Every cell's second moment from the same unfiltered samples as the quadrant sums, so
        // that a cell's gain means the same whether it was a leaf or interior.
        let shrunk = self.shrink(SPLIT_PRIOR_SAMPLES, |k| {
            quadrants[k]
                .iter()
                .fold((0.0, 0.0, 0), |(_, s2, n), &(s, c)| {
                    (0.0, s2 + s, n.saturating_add(c))
                })
        });
        let root_of = |s2: f64, d: u32| (cell_area(d) * s2.max(0.0)).sqrt();
        let node_root: Vec<f64> = (0..self.nodes.len())
            .map(|i| root_of(shrunk.nodes[i].1, depth[i]))
            .collect();
        let slot_root = |i: usize, s: u32| match s & LEAF_BIT {
            0 => node_root[s as usize],
            _ => root_of(shrunk.leaves[(s & !LEAF_BIT) as usize].1, depth[i] + 1),
        };
        // Each interior cell's gain, sqrt(m) − Σ_children sqrt(m). A cell's own sums are
        // shrunk toward a quarter of its parent's, and its children's toward a quarter of its
        // own. Where the parent holds a sharp lobe, that quarter is thousands of times a flat
        // sibling's sums, so the sibling's estimate grows while its children's barely do. The
        // sibling then shows a gain it does not have, and the tree refines a halo around the
        // lobe. Taking a cell's sums as the sum of its children's estimates removes the halo.
        // Measured in the quality harness, that raised the variance on every field at the
        // default thresholds, and at a node budget it lowered the partitions' oracle but not
        // below flux share's (docs/quality.md, "Why the gain partitions trail in those two
        // cells").
        let node_gain: Vec<f64> = self
            .nodes
            .iter()
            .enumerate()
            .map(|(i, slots)| {
                (node_root[i] - slots.iter().map(|&s| slot_root(i, s)).sum::<f64>()).max(0.0)
            })
            .collect();
        // What each interior cell's subtree gained in all, its interior nodes and the samples
        // that landed in it, bottom-up.
        let leaf_count = |k: usize| quadrants[k].iter().fold(0u64, |a, q| a.saturating_add(q.1));
        let mut subtree = vec![(0.0f64, 0.0f64, 0u64); self.nodes.len()];
        for i in (0..self.nodes.len()).rev() {
            let mut acc = (node_gain[i], 1.0, 0u64);
            for &s in &self.nodes[i] {
                if s & LEAF_BIT == 0 {
                    let c = subtree[s as usize];
                    acc = (acc.0 + c.0, acc.1 + c.1, acc.2.saturating_add(c.2));
                } else {
                    acc.2 = acc.2.saturating_add(leaf_count((s & !LEAF_BIT) as usize));
                }
            }
            subtree[i] = acc;
        }
        // A cell that saw fewer than `least` samples does not split: MIN_SPLIT_SAMPLES for
        // cells of the ended iteration, MIN_PREDICTED_SPLIT_SAMPLES for a leaf's quadrants.
        let enough = |n: u64, least: u64, key: f64| if n >= least { key } else { 0.0 };
        let mut slot = vec![[0.0f64; 4]; self.nodes.len()];
        let mut below_leaf = vec![[0.0f64; 4]; self.moments.len()];
        let mut total = 0.0;
        for (i, slots) in self.nodes.iter().enumerate() {
            // A leaf's relative gain is shrunk toward its parent's.
            let parent = if node_root[i] > 0.0 {
                node_gain[i] / node_root[i]
            } else {
                0.0
            };
            for (q, &s) in slots.iter().enumerate() {
                slot[i][q] = if s & LEAF_BIT == 0 {
                    // One level's gain, or what the whole known subtree gained per node spent
                    // if that is more: a split that pays only further down is kept.
                    let (gain, nodes, n) = subtree[s as usize];
                    enough(
                        n,
                        MIN_SPLIT_SAMPLES,
                        node_gain[s as usize].max(gain / nodes),
                    )
                } else {
                    let k = (s & !LEAF_BIT) as usize;
                    let e = split_gain(&quadrants[k], SPLIT_PRIOR_SAMPLES, parent);
                    let r = slot_root(i, s);
                    total += r;
                    below_leaf[k] = std::array::from_fn(|c| {
                        let key = r * e.fractions[c] * e.relative_gain;
                        enough(quadrants[k][c].1, MIN_PREDICTED_SPLIT_SAMPLES, key)
                    });
                    enough(leaf_count(k), MIN_SPLIT_SAMPLES, r * e.relative_gain)
                };
            }
        }
        SplitKeys {
            slot,
            below_leaf: Some(below_leaf),
            threshold: params.gain_threshold * total,
        }
    }

    /// The depth of every node (the root is 0), from one forward sweep.
    fn depths(&self) -> Vec<u32> {
        let mut depth = vec![0u32; self.nodes.len()];
        for i in 0..self.nodes.len() {
            for &slot in &self.nodes[i] {
                if slot & LEAF_BIT == 0 {
                    depth[slot as usize] = depth[i] + 1;
                }
            }
        }
        depth
    }
}

/// Shrunk `(S1, S2)` estimates of a recording tree's cells.
pub(crate) struct ShrunkMoments {
    /// Per interior node.
    pub(crate) nodes: Vec<(f64, f64)>,
    /// Per leaf (moments index).
    pub(crate) leaves: Vec<(f64, f64)>,
}

/// How the recorded statistics of one iteration become a distribution and a new topology.
#[derive(Clone, Copy, Debug)]
pub(crate) struct RefineParams {
    pub rule: LeafRule,
    pub uniform_fraction: f64,
    pub refinement: Refinement,
    pub subdivision_threshold: f64,
    pub gain_threshold: f64,
    pub max_depth: u32,
    pub max_nodes: u32,
    pub prior_samples: f64,
    /// Whether recording defers the directional box filter to refine (give leaves pending sums).
    pub deferred: bool,
}

/// What one directional refine did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct RefineOutcome {
    /// Samples the tree had recorded in the iteration that ended.
    pub samples: u64,
    /// Cells that qualified for a split but were refused by `max_nodes`.
    pub refused: u64,
}

/// A spatial leaf's directional knowledge: what queries sample, and what recording fills.
#[derive(Clone, Debug)]
pub(crate) struct DirectionalTree {
    pub(crate) sampling: SamplingTree,
    pub(crate) recording: RecordingTree,
    /// The spatial leaf's learned guide-vs-BSDF selection probability.
    pub(crate) selection: GuideSelection,
}

impl Default for DirectionalTree {
    fn default() -> Self {
        Self {
            sampling: SamplingTree::uniform(),
            recording: RecordingTree::root(),
            selection: GuideSelection::default(),
        }
    }
}

/// What a candidate cell was in the ended iteration's recording tree.
#[derive(Clone, Copy, Debug)]
enum Origin {
    /// Interior node `n`.
    Interior(u32),
    /// Leaf `k` (moments index).
    Leaf(u32),
    /// Below the ended iteration's leaves.
    New,
}

/// A candidate cell during refinement, ordered by its key (share of the mass, or gain).
struct Candidate {
    key: f64,
    cell_depth: u32,
    origin: Origin,
    /// The new node and quadrant that will point to this cell.
    parent: (u32, usize),
}

/// How refinement ranks the cells of the ended iteration and decides to split them: a cell
/// splits while its key exceeds `threshold`.
struct SplitKeys {
    /// Per interior node of the ended iteration and quadrant: the key of the cell in that slot.
    slot: Vec<[f64; 4]>,
    /// Variance gain: per leaf of the ended iteration, the predicted gains of its quadrants (and
    /// no split below them). Flux share: `None`, a cell below the old leaves has a quarter of
    /// its parent's share.
    below_leaf: Option<Vec<[f64; 4]>>,
    threshold: f64,
}

impl SplitKeys {
    /// The keys and origins of the four children of a cell.
    fn children(&self, old: &[[u32; 4]], origin: Origin, key: f64) -> [(f64, Origin); 4] {
        std::array::from_fn(|q| match origin {
            Origin::Interior(o) => {
                let slot = old[o as usize][q];
                let origin = if slot & LEAF_BIT != 0 {
                    Origin::Leaf(slot & !LEAF_BIT)
                } else {
                    Origin::Interior(slot)
                };
                (self.slot[o as usize][q], origin)
            }
            Origin::Leaf(k) => match &self.below_leaf {
                Some(gains) => (gains[k as usize][q], Origin::New),
                None => (0.25 * key, Origin::New),
            },
            Origin::New => match &self.below_leaf {
                Some(_) => (0.0, Origin::New),
                None => (0.25 * key, Origin::New),
            },
        })
    }
}

impl PartialEq for Candidate {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Candidate {}
impl PartialOrd for Candidate {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Candidate {
    fn cmp(&self, other: &Self) -> Ordering {
        self.key.total_cmp(&other.key)
    }
}

/// The cells refinement has still to decide on: a stack (depth first) or a max-heap by key.
trait Frontier {
    fn push(&mut self, c: Candidate);
    fn pop(&mut self) -> Option<Candidate>;
    /// Whether cells come out largest key first.
    fn ordered(&self) -> bool;
}

impl Frontier for Vec<Candidate> {
    fn push(&mut self, c: Candidate) {
        Vec::push(self, c);
    }
    fn pop(&mut self) -> Option<Candidate> {
        Vec::pop(self)
    }
    fn ordered(&self) -> bool {
        false
    }
}

impl Frontier for BinaryHeap<Candidate> {
    fn push(&mut self, c: Candidate) {
        BinaryHeap::push(self, c);
    }
    fn pop(&mut self) -> Option<Candidate> {
        BinaryHeap::pop(self)
    }
    fn ordered(&self) -> bool {
        true
    }
}

/// A grown topology: interior nodes with leaf slots `FREE`, and what the cap did.
struct Grown {
    nodes: Vec<[u32; 4]>,
    refused: u64,
    gave_up: bool,
}

impl DirectionalTree {
    /// Ends an iteration: builds the next sampling tree from the recorded moments and the next
    /// (empty) recording topology. A tree that counted no sample keeps what it had learned.
    pub(crate) fn refine(&mut self, params: &RefineParams) -> RefineOutcome {
        self.selection.step();
        self.recording.flush_pending_mut();
        let samples = self.recording.count();
        if samples == 0 {
            // Nothing landed here; shares a box filter spread in from neighbouring spatial
            // leaves are not enough to learn from (shrinkage weighs by counted samples), so
            // they are dropped with the iteration, and the distribution stays.
            for m in self.recording.moments.iter_mut() {
                *m = AtomicMoments::default();
            }
            return RefineOutcome::default();
        }
        let rec = &self.recording;
        let depth = rec.depths();

        // 1. Leaf shares by the rule, normalized: α_i = mass_i / Σ_j mass_j, from moments
        //    shrunk toward their parents' (see `shrunk_moments`).
        let shrunk = rec.shrunk_moments(params.prior_samples);
        let leaf_moments = &shrunk.leaves;
        let mut leaf_mass = vec![0.0f64; rec.moments.len()];
        for (i, slots) in rec.nodes.iter().enumerate() {
            for &slot in slots {
                if slot & LEAF_BIT != 0 {
                    let k = (slot & !LEAF_BIT) as usize;
                    let (s1, s2) = leaf_moments[k];
                    leaf_mass[k] = params.rule.mass(cell_area(depth[i] + 1), s1, s2);
                }
            }
        }
        let total: f64 = leaf_mass.iter().sum();
        let lit = total > 0.0 && total.is_finite();

        // 2. Per node and quadrant: the learned share α (drives refinement) and the sampled mass
        //    (1−ε)·α + ε·|C| (drives sampling), summed bottom-up in one reverse sweep.
        let eps = if lit { params.uniform_fraction } else { 1.0 };
        let mut share = vec![[0.0f64; 4]; rec.nodes.len()];
        let mut mass = vec![[0.0f64; 4]; rec.nodes.len()];
        for i in (0..rec.nodes.len()).rev() {
            let area = cell_area(depth[i] + 1);
            for (q, &slot) in rec.nodes[i].iter().enumerate() {
                let (s, m) = if slot & LEAF_BIT != 0 {
                    let a = if lit {
                        leaf_mass[(slot & !LEAF_BIT) as usize] / total
                    } else {
                        0.0
                    };
                    (a, (1.0 - eps) * a + eps * area)
                } else {
                    let c = slot as usize;
                    (share[c].iter().sum(), mass[c].iter().sum())
                };
                share[i][q] = s;
                mass[i][q] = m;
            }
        }
        let sampling = SamplingTree::new(
            rec.nodes
                .iter()
                .zip(&mass)
                .map(|(slots, &m)| {
                    // Interior indices fit: `max_nodes` is validated to at most `MAX_NODES`.
                    let child = slots.map(|s| {
                        if s & LEAF_BIT != 0 {
                            NO_CHILD
                        } else {
                            s as u16
                        }
                    });
                    SamplingNode::from_masses(m, child)
                })
                .collect(),
        );

        // 3. The next topology: split by share (from the same shares) or by variance gain.
        let keys = match params.refinement {
            Refinement::FluxShare => SplitKeys {
                slot: share,
                below_leaf: None,
                threshold: params.subdivision_threshold,
            },
            Refinement::VarianceGain => rec.gain_keys(&depth, params),
        };
        let (recording, refused) = self.refined_topology(&keys, params);
        self.sampling = sampling;
        self.recording = recording;
        RefineOutcome { samples, refused }
    }

    /// Grows a new topology from the root: a cell whose key exceeds the threshold becomes
    /// interior (its children's keys come from the ended iteration where it was interior or a
    /// leaf, and are predicted below — so one refine can add several levels); every other
    /// cell is a leaf, which collapses whatever lay below it.
    ///
    /// Depth first while the node cap is not reached; when it would be, the tree is grown again
    /// largest key first, so the cap refuses the least important splits.
    fn refined_topology(&self, keys: &SplitKeys, params: &RefineParams) -> (RecordingTree, u64) {
        let mut grown = self.grow(keys, params, Vec::new());
        if grown.gave_up {
            grown = self.grow(keys, params, BinaryHeap::new());
        }
        (
            RecordingTree::from_nodes(grown.nodes, params.deferred),
            grown.refused,
        )
    }

    /// Grows a topology, taking cells from `frontier`. At the node cap an ordered frontier
    /// refuses (and counts) further splits; an unordered one gives up.
    fn grow(&self, keys: &SplitKeys, params: &RefineParams, mut frontier: impl Frontier) -> Grown {
        let old = &self.recording.nodes;
        let mut out = Grown {
            nodes: vec![[FREE; 4]],
            refused: 0,
            gave_up: false,
        };
        let push_children = |frontier: &mut dyn Frontier, new: u32, c: &Candidate| {
            for (q, (key, origin)) in keys.children(old, c.origin, c.key).into_iter().enumerate() {
                frontier.push(Candidate {
                    key,
                    cell_depth: c.cell_depth + 1,
                    origin,
                    parent: (new, q),
                });
            }
        };
        let root = Candidate {
            key: f64::INFINITY,
            cell_depth: 0,
            origin: Origin::Interior(0),
            parent: (0, 0),
        };
        push_children(&mut frontier, 0, &root);
        while let Some(c) = frontier.pop() {
            if c.key <= keys.threshold || c.cell_depth >= params.max_depth {
                continue;
            }
            if out.nodes.len() >= params.max_nodes as usize {
                if !frontier.ordered() {
                    out.gave_up = true;
                    return out;
                }
                out.refused += 1;
                continue;
            }
            let new = out.nodes.len() as u32;
            out.nodes.push([FREE; 4]);
            out.nodes[c.parent.0 as usize][c.parent.1] = new;
            push_children(&mut frontier, new, &c);
        }
        out
    }

    /// Bytes held by both buffers.
    pub(crate) fn bytes(&self) -> usize {
        self.sampling.bytes() + self.recording.bytes()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::{HashMap, HashSet};

    #[test]
    fn a_node_costs_what_the_configuration_documents() {
        assert_eq!(leaf_bytes(false), 24 + 64);
        assert_eq!(std::mem::size_of::<Cuts>(), 24);
        assert_eq!(bytes_per_node(false), 336);
        assert_eq!(leaf_bytes(true), 24 + 64 + 64);
        assert_eq!(bytes_per_node(true), 528);
    }

    /// A xorshift generator of numbers in `[0, 1)`.
    fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut rng = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
        move || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// A random topology (children after their parents, leaf slots `FREE`): each cell splits
    /// with a probability that falls with its depth, down to depth 8, so coarse leaves border
    /// finely split regions.
    fn random_topology(next: &mut impl FnMut() -> f64) -> Vec<[u32; 4]> {
        let mut nodes = vec![[FREE; 4]];
        let mut open = vec![(0usize, 0u32)];
        while let Some((node, depth)) = open.pop() {
            for q in 0..4 {
                if depth < 7 && next() < 0.85 - 0.1 * f64::from(depth) {
                    nodes.push([FREE; 4]);
                    nodes[node][q] = (nodes.len() - 1) as u32;
                    open.push((nodes.len() - 1, depth + 1));
                }
            }
        }
        nodes
    }

    /// A recording tree with a random topology and pending sums in most leaf quadrants.
    fn random_tree(seed: u64) -> RecordingTree {
        let mut next = uniform(seed);
        let tree = RecordingTree::from_nodes(random_topology(&mut next), true);
        for (k, pending) in tree.pending.iter().enumerate() {
            for q in 0..4 {
                // A quarter of the quadrants saw nothing.
                if next() < 0.75 {
                    let w1 = 1.0 + next() * (k % 7) as f64;
                    pending.add(q, (w1, w1 * (1.0 + next())));
                }
            }
        }
        tree
    }

    /// A sampling tree with a random topology, and quadrant masses spread over nine orders
    /// of magnitude.
    fn random_sampling_tree(seed: u64) -> SamplingTree {
        let mut next = uniform(seed);
        let nodes = random_topology(&mut next)
            .iter()
            .map(|slots| {
                let masses = [(); 4].map(|_| 10f64.powf(-9.0 * next()));
                SamplingNode::from_masses(masses, slots.map(|s| s as u16))
            })
            .collect();
        SamplingTree::new(nodes)
    }

    #[test]
    fn sampling_by_cuts_is_the_descent_that_cuts_level_by_level() {
        // The reference: at each level, cut the interval `[a, a + w)` of `u` that leads to the
        // node by the node's probabilities. The cuts precompute exactly those values, so the
        // point, its density and the border flag are bit for bit the same.
        fn reference(t: &SamplingTree, u: Vec2) -> (Vec2, f32, bool) {
            let (mut a, mut w) = (Vec2::ZERO, Vec2::ONE);
            let (mut cell, mut depth, mut pdf, mut node) = ([0u32; 2], 0, 1.0, 0usize);
            loop {
                let n = &t.nodes[node];
                let left = w.x * n.px[0];
                let ix = usize::from(u.x >= a.x + left);
                let low = w.y * n.py[ix][0];
                let iy = usize::from(u.y >= a.y + low);
                a += Vec2::new(left * ix as f32, low * iy as f32);
                w *= Vec2::new(n.px[ix], n.py[ix][iy]);
                pdf *= n.density_factor(ix, iy);
                cell = [2 * cell[0] + ix as u32, 2 * cell[1] + iy as u32];
                depth += 1;
                match n.child[ix | iy << 1] {
                    NO_CHILD => break,
                    c => node = usize::from(c),
                }
            }
            let size = 0.5f32.powi(depth);
            let local = Vec2::new(unit((u.x - a.x) / w.x), unit((u.y - a.y) / w.y));
            let origin = Vec2::new(cell[0] as f32, cell[1] as f32) * size;
            let margin = ROUND_TRIP_BOUND / size;
            let near_border = local.min_element() <= margin || local.max_element() >= 1.0 - margin;
            (origin + local * size, pdf, near_border)
        }
        for seed in 1..=4 {
            let tree = random_sampling_tree(seed);
            assert!(
                tree.node_count() > 60,
                "seed {seed}: {} nodes",
                tree.node_count()
            );
            let mut next = uniform(seed + 100);
            for _ in 0..100_000 {
                let u = Vec2::new(next() as f32, next() as f32);
                let (s, pdf, near) = tree.sample(u);
                let (s_ref, pdf_ref, near_ref) = reference(&tree, u);
                assert_eq!(
                    s.to_array().map(f32::to_bits),
                    s_ref.to_array().map(f32::to_bits)
                );
                assert_eq!(
                    (pdf.to_bits(), near),
                    (pdf_ref.to_bits(), near_ref),
                    "u = {u}"
                );
                // And the density is the one `pdf` finds there (away from leaf borders).
                if !near {
                    assert_eq!(tree.pdf(s), pdf, "u = {u}");
                }
            }
        }
    }

    #[test]
    fn the_deferred_spread_hands_out_the_box_filter_shares() {
        // Spreading a leaf's pending sums part by part (the leaf's own part directly, each
        // neighbour's from the path) gives each leaf what the box filter's walk from the root
        // gives, for every quadrant: on trees where coarse leaves border fine ones, and across
        // the square's border, where the filter folds.
        for seed in 1..=8 {
            let tree = random_tree(seed);
            let leaves = tree.moments.len();
            assert!(leaves > 200, "seed {seed}: only {leaves} leaves");
            let sums: Vec<[(f64, f64); 4]> = tree.pending.iter().map(|p| p.take()).collect();
            let mut spread = vec![(0.0, 0.0); leaves];
            tree.spread_pending(|k| sums[k], &mut |k, (a, b)| {
                spread[k] = (spread[k].0 + a, spread[k].1 + b)
            });
            let mut walked = vec![(0.0, 0.0); leaves];
            tree.visit_leaves(|k, cell| {
                for (q, part) in sums[k].into_iter().enumerate() {
                    let quadrant = cell.child(q);
                    let centre = quadrant.origin + Vec2::splat(0.5 * quadrant.size);
                    tree.splat_into(centre, f64::from(cell.size), part, &mut |j, (a, b)| {
                        walked[j] = (walked[j].0 + a, walked[j].1 + b)
                    });
                }
            });
            let total: f64 = sums.iter().flatten().map(|s| s.0).sum();
            let total_sq: f64 = sums.iter().flatten().map(|s| s.1).sum();
            // Each share is a product of a few exact dyadic lengths and one weight, summed in
            // another order: equal within a few ulps of the total.
            for k in 0..leaves {
                assert!(
                    (spread[k].0 - walked[k].0).abs() <= 1e-14 * total,
                    "seed {seed}, {k}"
                );
                assert!(
                    (spread[k].1 - walked[k].1).abs() <= 1e-14 * total_sq,
                    "seed {seed}, {k}"
                );
            }
            let spread_total: f64 = spread.iter().map(|s| s.0).sum();
            assert!((spread_total - total).abs() <= 1e-12 * total);
        }
    }

    #[test]
    fn recording_through_the_box_filter_hands_out_the_walks_shares() {
        // A sample's shares found from the chain of nodes above its leaf (the grid cut) are
        // what the box filter's walk from the root gives, and `record_box` adds them (and
        // counts the sample in its leaf and quadrant): at random points, at points a hair from
        // the grid lines of every level, and near the square's border and corners, where the
        // filter folds and a sample has the most shares.
        let mut overflowed = 0;
        for seed in 1..=8 {
            let mut next = uniform(100 + seed);
            let tree = RecordingTree::from_nodes(random_topology(&mut next), false);
            let leaves = tree.moments.len();
            let mut expected = vec![(0.0, 0.0, 0u64); leaves];
            let mut quadrants = vec![[0u64; 4]; leaves];
            let mut total = 0.0;
            for i in 0..4000 {
                let mut u = || match i % 4 {
                    // Uniform.
                    0 => next(),
                    // Near the border: within a leaf's side or so of 0 or 1.
                    1 => {
                        let e = next() * 2f64.powi(-(1 + (next() * 8.0) as i32));
                        if next() < 0.5 { e } else { 1.0 - e }
                    }
                    // A hair from a grid line of some level.
                    _ => {
                        let level = 2f64.powi(1 + (next() * 8.0) as i32);
                        let line = (next() * level).floor() / level;
                        (line + (next() - 0.5) * 1e-6).clamp(0.0, 0.999_999)
                    }
                };
                let s = Vec2::new(u() as f32, u() as f32);
                let w1 = 0.5 + next();
                let w = (w1, w1 * (1.0 + next()));
                let mut from_chain = Vec::new();
                let (k, q) = tree.box_shares(s, w, &mut |j, part| from_chain.push((j, part)));
                let (lk, depth, lq) = tree.locate(s);
                assert_eq!((k, q), (lk, lq), "seed {seed}, {s}");
                let mut walked = HashMap::new();
                tree.splat_into(s, cell_area(depth).sqrt(), w, &mut |j, (a, b)| {
                    let e = walked.entry(j).or_insert((0.0, 0.0));
                    *e = (e.0 + a, e.1 + b);
                });
                let mut chained = HashMap::new();
                for &(j, (a, b)) in &from_chain {
                    let e = chained.entry(j).or_insert((0.0, 0.0));
                    *e = (e.0 + a, e.1 + b);
                }
                overflowed += usize::from(from_chain.len() > Shares::CAP);
                assert_eq!(
                    walked.keys().collect::<HashSet<_>>(),
                    chained.keys().collect::<HashSet<_>>(),
                    "seed {seed}, {s}"
                );
                // Products of exact dyadic lengths and one weight, summed in another order.
                for (j, a) in &walked {
                    let b = chained[j];
                    assert!(
                        (a.0 - b.0).abs() <= 1e-14 * w.0,
                        "seed {seed}, {s}, leaf {j}"
                    );
                    assert!(
                        (a.1 - b.1).abs() <= 1e-14 * w.1,
                        "seed {seed}, {s}, leaf {j}"
                    );
                    expected[*j].0 += b.0;
                    expected[*j].1 += b.1;
                }
                let sum: f64 = from_chain.iter().map(|(_, (a, _))| a).sum();
                assert!((sum - w.0).abs() <= 1e-12 * w.0, "seed {seed}, {s}");
                expected[k].2 += 1;
                quadrants[k][q] += 1;
                total += w.0;
                tree.record_box(s, w);
            }
            for (j, e) in expected.iter().enumerate() {
                let m = tree.moments[j].get();
                assert!(
                    (m.sum - e.0).abs() <= 1e-12 * total,
                    "seed {seed}, leaf {j}"
                );
                assert!(
                    (m.sum_sq - e.1).abs() <= 1e-12 * total,
                    "seed {seed}, leaf {j}"
                );
                assert_eq!(m.count, e.2, "seed {seed}, leaf {j}");
                let counts = tree.quadrants[j].get().map(|(_, n)| n);
                assert_eq!(counts, quadrants[j], "seed {seed}, leaf {j}");
            }
        }
        // Some samples had more shares than `Shares` holds, and took the direct adds.
        assert!(overflowed > 0);
    }

    #[test]
    fn node_is_half_a_cache_line() {
        assert_eq!(std::mem::size_of::<SamplingNode>(), 32);
    }

    #[test]
    fn uniform_tree_has_constant_density() {
        let t = SamplingTree::uniform();
        for s in [Vec2::ZERO, Vec2::new(0.7, 0.2), Vec2::splat(0.99)] {
            assert_eq!(t.pdf(s), 1.0);
        }
        let (p, pdf, near_border) = t.sample(Vec2::new(0.3, 0.8));
        assert_eq!(pdf, 1.0);
        assert!(!near_border);
        assert!((p - Vec2::new(0.3, 0.8)).abs().max_element() < 1e-6);
    }
}
