//! The directional quadtree over the unit square (the sphere, through [`crate::sphere`]).
//!
//! Each spatial leaf (a [`Region`](crate::region::Region)) owns one directional quadtree,
//! double-buffered as the design asks:
//!
//! - a [`SamplingTree`] (`sampling`): read-only during an iteration, it holds for each node the
//!   probability of each of its four quadrants, its first four levels flattened into a grid
//!   that `pdf` reads in one load and `sample` picks from by two tables, and the cuts of `u`
//!   that `sample` descends by below the grid.
//!   `sample` and `pdf` descend it without locks or allocation.
//! - a [`RecordingTree`] (`recording`): the topology for the current iteration with atomic
//!   moments and quadrant sums per leaf. Recording descends it and adds to its leaves; interior
//!   sums are never kept. The directional box filter's shares, found from the sample's own leaf
//!   at `record` or from each leaf quadrant's pending sums at `refine`, are `splat`'s.
//!
//! [`refine`] ends an iteration: a function from the recording tree to the next sampling and
//! recording trees. It turns the leaf moments into
//! masses with the active [`LeafRule`](crate::LeafRule), mixes in the uniform floor, sums
//! interior masses bottom-up into the next sampling tree, and derives the next recording
//! topology by the active [`Refinement`](crate::Refinement): split the cells whose share of
//! those masses exceeds ρ (flux share), or whose split gain, estimated from the quadrant sums,
//! exceeds its threshold (variance gain); collapse the others.
//!
//! Quadrants are numbered `q = ix + 2·iy`, with `ix = [s.x ≥ ½]` and `iy = [s.y ≥ ½]` in the
//! node's local frame. Nodes are stored so that a child always comes after its parent, which
//! lets bottom-up passes run as one reverse sweep. Descents locate points in fixed point
//! ([`fixed`]), so that every descent agrees on which cell holds a point.

mod horizon;
mod phase;
mod product;
mod recording;
mod refine;
mod sampling;
mod splat;
mod surfaces;
mod topology;

pub(crate) use horizon::{HORIZON_DEPTH, SURFACE_DEPTH, SurfaceTree};
pub(crate) use phase::{MAX_G, PHASE_DEPTH, PhaseLobe};
pub(crate) use recording::RecordingTree;
pub(crate) use refine::{RefineParams, RefineScratch, refine};
pub(crate) use sampling::{GRID_BYTES, SamplingNode, SamplingTree};
pub(crate) use surfaces::{SLOTS, Surfaces, Tallied, WORDS, tally_priority};

use crate::moments::{AtomicPending, AtomicQuadrants, AtomicSums};
use glam::Vec2;
#[cfg(test)]
use recording::FREE;
use sampling::Cuts;

/// In a [`RecordingTree`] node, marks a child slot as a leaf; the low bits index its moments.
pub(crate) const LEAF_BIT: u32 = 1 << 31;

/// In a [`SamplingTree`] node, the child index of a leaf (the root is node 0, nobody's child).
pub(crate) const NO_CHILD: u16 = 0;

/// In a surface product's [`SamplingTree`], the child index of a leaf below which the product
/// goes on per query (see [`horizon`]). No node has it: indices stay below [`MAX_NODES`].
pub(crate) const RESUME: u16 = u16::MAX;

/// Most interior nodes a directional tree may have: sampling nodes index children with `u16`.
pub(crate) const MAX_NODES: u32 = u16::MAX as u32;

/// Bytes one recording leaf holds: its sums (32: two 16-byte exact sums) and its quadrants' sums
/// and counts (96), and under the deferred box filter its pending sums (128 more).
pub(crate) const fn leaf_bytes(deferred: bool) -> u64 {
    let pending = if deferred {
        size_of::<AtomicPending>()
    } else {
        0
    };
    (size_of::<AtomicSums>() + size_of::<AtomicQuadrants>() + pending) as u64
}

/// Upper bound on the bytes one interior node costs a directional tree: its sampling node (32)
/// and the cuts `sample` descends by (24), its recording node (16), and the three leaves it
/// adds net (456 in all; 840 under the deferred box filter).
pub(crate) const fn bytes_per_node(deferred: bool) -> u64 {
    (size_of::<SamplingNode>() + size_of::<Cuts>() + size_of::<[u32; 4]>()) as u64
        + 3 * leaf_bytes(deferred)
}

/// Bits of the fixed-point square coordinates descents use: deeper than any tree (20 levels).
const FIXED_BITS: u32 = 24;

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

/// `2^-depth`, the side of a cell at `depth` (exactly `cell_area(depth).sqrt()`).
#[inline]
fn cell_side(depth: u32) -> f64 {
    f64::from_bits(u64::from(1023 - depth) << 52)
}

/// `4^depth`, the cells of `depth` per unit area (exactly `1 / cell_area(depth)`).
#[inline]
fn cells_per_area(depth: u32) -> f64 {
    f64::from_bits(u64::from(1023 + 2 * depth) << 52)
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

    /// The cell's quadrant `q` (0–3: bit 0 the upper half in x, bit 1 in y), one level down.
    ///
    /// ```
    /// use glam::Vec2;
    /// use sdguide::DirectionalCell;
    /// let root = DirectionalCell { origin: Vec2::ZERO, size: 1.0, depth: 0 };
    /// assert_eq!(root.child(3), DirectionalCell { origin: Vec2::splat(0.5), size: 0.5, depth: 1 });
    /// ```
    pub fn child(&self, q: usize) -> DirectionalCell {
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

/// Random trees for the tests of the submodules.
#[cfg(test)]
mod testing {
    use super::{FREE, RecordingTree, SamplingNode, SamplingTree};

    /// A xorshift generator of numbers in `[0, 1)`.
    pub(super) fn uniform(seed: u64) -> impl FnMut() -> f64 {
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
    pub(super) fn random_topology(next: &mut impl FnMut() -> f64) -> Vec<[u32; 4]> {
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
    pub(super) fn random_tree(seed: u64) -> RecordingTree {
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

    /// Asserts that `observed` counts of `draws` draws fit bin probabilities `expected` by
    /// Pearson's chi-square, over at least `min_bins` bins: the bins expecting fewer than 5
    /// draws pooled into one, as the approximation asks, and the bound one a correct sampler
    /// exceeds with probability about 10⁻⁶ (Wilson–Hilferty, z = 4.75).
    pub(super) fn assert_chi_square(
        observed: &[u64],
        expected: &[f64],
        draws: u64,
        min_bins: usize,
        what: &str,
    ) {
        let (mut chi2, mut dof, mut pooled) = (0.0, 0usize, (0.0, 0.0));
        for (&o, &p) in observed.iter().zip(expected) {
            let e = p * draws as f64;
            if e < 5.0 {
                pooled = (pooled.0 + o as f64, pooled.1 + e);
            } else {
                chi2 += (o as f64 - e).powi(2) / e;
                dof += 1;
            }
        }
        if pooled.1 >= 5.0 {
            chi2 += (pooled.0 - pooled.1).powi(2) / pooled.1;
            dof += 1;
        } else {
            // A Poisson count of mean below 5 exceeds 20 with probability below 1e-6.
            assert!(pooled.0 <= 20.0, "{what}: {pooled:?}");
        }
        assert!(dof > min_bins, "{what}: {dof} bins");
        let k = (dof - 1) as f64;
        let a = 2.0 / (9.0 * k);
        let bound = k * (1.0 - a + 4.75 * a.sqrt()).powi(3);
        assert!(
            chi2 < bound,
            "{what}: chi2 = {chi2}, bound = {bound}, {dof} bins"
        );
    }

    /// A sampling tree with a random topology, and quadrant masses spread over nine orders
    /// of magnitude.
    pub(super) fn random_sampling_tree(seed: u64) -> SamplingTree {
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
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_node_costs_what_the_configuration_documents() {
        assert_eq!(leaf_bytes(false), 32 + 96);
        assert_eq!(std::mem::size_of::<Cuts>(), 24);
        assert_eq!(bytes_per_node(false), 456);
        assert_eq!(leaf_bytes(true), 32 + 96 + 128);
        assert_eq!(bytes_per_node(true), 840);
    }
}
