//! The spatial binary tree over the scene's bounding cube.
//!
//! A node is one `u32`: either `LEAF_BIT | index` of the directional tree it owns, or the index
//! of the first of its two children (stored side by side). Children split their parent at the
//! midpoint of one axis, cycling x → y → z with depth, so a node's box is never stored: the
//! descent halves the root cube as it goes. Four bytes per node keep the whole tree in cache.
//!
//! Positions are converted once to 24-bit fixed point per axis, so each level is a bit test.
//! The first 12 levels (4 per axis) are skipped through a 16³ lookup grid that stores, for each
//! grid cell, where the descent stands after them: a query then walks only the levels below.

use crate::bounds::Aabb;
use crate::filter::overlap;
use crate::spatial_split::{self, SplitPlan};
use glam::Vec3;
use std::collections::BinaryHeap;

pub(crate) const LEAF_BIT: u32 = 1 << 31;

/// Bits per axis of the fixed-point positions the descent uses.
const FIXED_BITS: u32 = 24;

/// Positions this far outside the bounding cube (relative to its side) are still recorded, into
/// the nearest cell: hit points offset along a normal, or rounded, land just outside the bounds.
const POSITION_TOLERANCE: f32 = 1e-3;

/// Levels per axis resolved by the lookup grid (16³ cells, 16 KiB).
const GRID_BITS: u32 = 4;

/// Deepest spatial level: 20 splits per axis, cells a millionth of the scene on a side. Also
/// keeps every level's bit within the `FIXED_BITS` of a coordinate.
pub(crate) const MAX_SPATIAL_DEPTH: u32 = 60;

/// A leaf of the spatial tree as inspection sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct SpatialLeaf {
    /// Index of the leaf's directional tree.
    pub leaf: usize,
    pub bounds: Aabb,
    pub depth: u32,
}

/// The binary tree and the cube it partitions.
#[derive(Clone, Debug)]
pub(crate) struct SpatialTree {
    cube: Aabb,
    /// The cube grown by `POSITION_TOLERANCE` of its side: where recorded positions are accepted.
    accepted: Aabb,
    /// `2^FIXED_BITS / side`: maps cube coordinates to fixed point.
    scale: f32,
    nodes: Vec<u32>,
    /// For each cell of the lookup grid, the node entry reached after `3·GRID_BITS` levels (or
    /// the leaf reached before).
    grid: Box<[u32]>,
}

impl SpatialTree {
    /// Whether a tree can partition `cube`: every side positive and normal, and the fixed-point
    /// scale `2^FIXED_BITS / side` finite. A box far smaller than a float's spacing at its
    /// position, or with a subnormal extent, has a cube whose sides round to zero or to a
    /// subnormal: every position would map to one corner.
    pub(crate) fn can_partition(cube: Aabb) -> bool {
        let side = cube.extent();
        side.cmpge(Vec3::splat(f32::MIN_POSITIVE)).all()
            && side.is_finite()
            && ((1u32 << FIXED_BITS) as f32 / side.x).is_finite()
    }

    /// A tree with one leaf (directional tree 0) covering `cube`.
    pub(crate) fn new(cube: Aabb) -> Self {
        Self::from_nodes(cube, vec![LEAF_BIT])
    }

    /// A tree over `cube` with the given (already validated) node entries.
    pub(crate) fn from_nodes(cube: Aabb, nodes: Vec<u32>) -> Self {
        let margin = Vec3::splat(POSITION_TOLERANCE * cube.extent().x);
        let mut tree = Self {
            cube,
            accepted: Aabb::new(cube.min - margin, cube.max + margin),
            scale: (1u32 << FIXED_BITS) as f32 / cube.extent().x,
            nodes,
            grid: vec![0; 1 << (3 * GRID_BITS)].into_boxed_slice(),
        };
        tree.build_grid();
        tree
    }

    /// The node entries: `LEAF_BIT | leaf` or the index of the first of two children.
    pub(crate) fn nodes(&self) -> &[u32] {
        &self.nodes
    }

    /// The cube the tree partitions.
    pub(crate) fn cube(&self) -> Aabb {
        self.cube
    }

    /// Whether a recorded position is close enough to the cube to be recorded (into the
    /// nearest cell): within `POSITION_TOLERANCE` of its side. NaN is not.
    #[inline]
    pub(crate) fn accepts(&self, p: Vec3) -> bool {
        self.accepted.contains(p)
    }

    /// The directional tree of the leaf containing `p`. Points outside the cube go to the
    /// nearest leaf along each split; NaN coordinates go to the low side.
    #[inline]
    pub(crate) fn leaf_at(&self, p: Vec3) -> usize {
        let c = self.fixed(p);
        let g = c.map(|v| v >> (FIXED_BITS - GRID_BITS));
        let cell = (g[0] | g[1] << GRID_BITS | g[2] << (2 * GRID_BITS)) as usize;
        self.descend(c, self.grid[cell], FIXED_BITS - 1 - GRID_BITS)
    }

    /// The leaf containing `p` with its box and depth (what `leaf_at` finds, for inspection).
    pub(crate) fn locate(&self, p: Vec3) -> SpatialLeaf {
        let c = self.fixed(p);
        let (mut node, mut bounds, mut depth) = (self.nodes[0], self.cube, 0u32);
        while node & LEAF_BIT == 0 {
            let axis = (depth % 3) as usize;
            let bit = (c[axis] >> (FIXED_BITS - 1 - depth / 3)) & 1;
            let mid = bounds.center()[axis];
            if bit == 1 {
                bounds.min[axis] = mid;
            } else {
                bounds.max[axis] = mid;
            }
            node = self.nodes[(node + bit) as usize];
            depth += 1;
        }
        SpatialLeaf {
            leaf: (node & !LEAF_BIT) as usize,
            bounds,
            depth,
        }
    }

    /// Calls `f(leaf, volume)` for every leaf that the box `[lo, hi]` overlaps, with the
    /// overlapped volume. No allocation: the depth-first walk keeps its stack in an array.
    pub(crate) fn overlapping(&self, lo: Vec3, hi: Vec3, mut f: impl FnMut(usize, f64)) {
        let mut stack = [(0u32, self.cube, 0u32); MAX_SPATIAL_DEPTH as usize + 2];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let (node, bounds, depth) = stack[top];
            let volume = (0..3)
                .map(|a| {
                    let [a0, a1, b0, b1] = [lo[a], hi[a], bounds.min[a], bounds.max[a]];
                    overlap(a0.into(), a1.into(), b0.into(), b1.into())
                })
                .product::<f64>();
            if volume <= 0.0 {
                continue;
            }
            let n = self.nodes[node as usize];
            if n & LEAF_BIT != 0 {
                f((n & !LEAF_BIT) as usize, volume);
                continue;
            }
            let (low, high) = halves(bounds, depth);
            // Depth-first: at most one pending sibling per level.
            if top + 2 <= stack.len() {
                stack[top] = (n, low, depth + 1);
                stack[top + 1] = (n + 1, high, depth + 1);
                top += 2;
            }
        }
    }

    /// `p` in fixed point: `FIXED_BITS` bits per axis over the cube. `as` saturates (NaN and
    /// the near side become 0) and `min` clamps the far side.
    #[inline]
    fn fixed(&self, p: Vec3) -> [u32; 3] {
        let max = (1u32 << FIXED_BITS) - 1;
        ((p - self.cube.min) * self.scale)
            .to_array()
            .map(|v| (v as u32).min(max))
    }

    /// Walks down from node entry `node`, whose children split the x axis at bit `shift`:
    /// at depth d the split bit is bit (FIXED_BITS − 1 − d/3) of axis d % 3.
    #[inline]
    fn descend(&self, c: [u32; 3], mut node: u32, mut shift: u32) -> usize {
        let mut axis = 0;
        while node & LEAF_BIT == 0 {
            let bit = (c[axis] >> shift) & 1;
            node = self.nodes[(node + bit) as usize];
            if axis == 2 {
                axis = 0;
                shift -= 1;
            } else {
                axis += 1;
            }
        }
        (node & !LEAF_BIT) as usize
    }

    /// Recomputes the lookup grid: where the descent of each grid cell stands after
    /// `3·GRID_BITS` levels. One walk down the tree's top levels: a node that is a leaf above
    /// the grid's depth fills the block of cells it covers at once.
    fn build_grid(&mut self) {
        let n = 1usize << GRID_BITS;
        // (node entry, depth, the block's lowest cell and its extent in cells per axis)
        let mut stack = vec![(self.nodes[0], 0u32, [0usize; 3], [n; 3])];
        while let Some((node, depth, lo, size)) = stack.pop() {
            if node & LEAF_BIT != 0 || depth == 3 * GRID_BITS {
                for z in lo[2]..lo[2] + size[2] {
                    for y in lo[1]..lo[1] + size[1] {
                        let row = (z * n + y) * n;
                        self.grid[row + lo[0]..row + lo[0] + size[0]].fill(node);
                    }
                }
                continue;
            }
            // Depth d splits axis d % 3 at the next bit: the low half is child 0.
            let axis = (depth % 3) as usize;
            let mut half = size;
            half[axis] /= 2;
            let mut high = lo;
            high[axis] += half[axis];
            stack.push((self.nodes[node as usize], depth + 1, lo, half));
            stack.push((self.nodes[node as usize + 1], depth + 1, high, half));
        }
    }

    /// The grid as the descent of each cell, one by one: what `build_grid` must equal.
    #[cfg(test)]
    fn grid_by_cells(&self) -> Vec<u32> {
        let n = 1u32 << GRID_BITS;
        (0..self.grid.len() as u32)
            .map(|i| {
                let g = [i % n, (i / n) % n, i / (n * n)];
                let c = g.map(|v| v << (FIXED_BITS - GRID_BITS));
                let mut node = self.nodes[0];
                for depth in 0..3 * GRID_BITS {
                    if node & LEAF_BIT != 0 {
                        break;
                    }
                    let bit = (c[(depth % 3) as usize] >> (FIXED_BITS - 1 - depth / 3)) & 1;
                    node = self.nodes[(node + bit) as usize];
                }
                node
            })
            .collect()
    }

    /// Splits leaves by their plans (`plans[leaf]`, see [`SplitPlan`]): under the count rule a
    /// leaf with more than `threshold` samples splits in two, each child taking half the count
    /// and splitting again while that still exceeds the threshold; a plan by gain decides its
    /// first levels itself. The busiest cells go first; a split is refused when the tree would
    /// pass `max_nodes` or when `new_leaf(parent)` (which creates the right child's directional
    /// tree) returns `None`. The left child keeps the parent's directional tree. Returns the
    /// number of refusals.
    pub(crate) fn split(
        &mut self,
        plans: &[SplitPlan],
        threshold: f64,
        max_nodes: usize,
        mut new_leaf: impl FnMut(usize) -> Option<usize>,
    ) -> u64 {
        // (count, node, depth, the leaf's plan, the cell's slot in it)
        let mut heap: BinaryHeap<(u64, usize, u32, usize, usize)> = self
            .leaf_nodes()
            .map(|(node, leaf, depth)| (plans[leaf].counts[1], node, depth, leaf, 1))
            .filter(|&(count, _, _, leaf, slot)| plans[leaf].splits(slot, count, threshold))
            .collect();
        let mut refused = 0;
        while let Some((count, node, depth, plan, slot)) = heap.pop() {
            let leaf = (self.nodes[node] & !LEAF_BIT) as usize;
            let room = self.nodes.len() + 2 <= max_nodes && depth < MAX_SPATIAL_DEPTH;
            let right = if room { new_leaf(leaf) } else { None };
            let Some(right) = right else {
                refused += 1;
                continue;
            };
            let first = self.nodes.len() as u32;
            self.nodes.push(LEAF_BIT | leaf as u32);
            self.nodes.push(LEAF_BIT | right as u32);
            self.nodes[node] = first;
            let (low, high) = plans[plan].children(slot, count);
            for (i, count) in [low, high].into_iter().enumerate() {
                let child = (2 * slot + i).min(spatial_split::SLOTS);
                if plans[plan].splits(child, count, threshold) {
                    heap.push((count, first as usize + i, depth + 1, plan, child));
                }
            }
        }
        self.build_grid();
        refused
    }

    /// The cell of `p` among the `2^levels` cells of the `levels` levels below a leaf at depth
    /// `depth` (the low half first, level by level: slot order), and a bit of `p` far below
    /// any cell (the parity of its fixed-point coordinates' lowest bits).
    #[inline]
    pub(crate) fn cell_below(&self, p: Vec3, depth: u32, levels: u32) -> (usize, bool) {
        let c = self.fixed(p);
        let mut cell = 0;
        for d in depth..depth + levels {
            let level = d / 3;
            let bit = if level < FIXED_BITS {
                (c[(d % 3) as usize] >> (FIXED_BITS - 1 - level)) & 1
            } else {
                0
            };
            cell = 2 * cell + bit as usize;
        }
        (cell, (c[0] ^ c[1] ^ c[2]) & 1 == 1)
    }

    /// Every leaf with its box and depth.
    pub(crate) fn leaves(&self) -> Vec<SpatialLeaf> {
        let mut out = Vec::new();
        self.walk(|_, leaf, bounds, depth| {
            out.push(SpatialLeaf {
                leaf,
                bounds,
                depth,
            })
        });
        out
    }

    /// `(node, leaf, depth)` of every leaf.
    fn leaf_nodes(&self) -> impl Iterator<Item = (usize, usize, u32)> {
        let mut out = Vec::new();
        self.walk(|node, leaf, _, depth| out.push((node, leaf, depth)));
        out.into_iter()
    }

    /// Calls `f(node, leaf, bounds, depth)` for every leaf, depth first.
    fn walk(&self, mut f: impl FnMut(usize, usize, Aabb, u32)) {
        let mut stack = vec![(0usize, self.cube, 0u32)];
        while let Some((node, bounds, depth)) = stack.pop() {
            let n = self.nodes[node];
            if n & LEAF_BIT != 0 {
                f(node, (n & !LEAF_BIT) as usize, bounds, depth);
                continue;
            }
            let (lo, hi) = halves(bounds, depth);
            stack.push((n as usize, lo, depth + 1));
            stack.push((n as usize + 1, hi, depth + 1));
        }
    }

    pub(crate) fn node_count(&self) -> usize {
        self.nodes.len()
    }

    pub(crate) fn bytes(&self) -> usize {
        std::mem::size_of_val(self.nodes.as_slice()) + std::mem::size_of_val(&*self.grid)
    }
}

/// The two children of a node's box at `depth`: split at the midpoint of axis `depth mod 3`.
fn halves(bounds: Aabb, depth: u32) -> (Aabb, Aabb) {
    let axis = (depth % 3) as usize;
    let mid = bounds.center()[axis];
    let (mut low, mut high) = (bounds, bounds);
    low.max[axis] = mid;
    high.min[axis] = mid;
    (low, high)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The count rule's plans for leaves of these counts.
    fn by_count(counts: &[u64], threshold: f64) -> Vec<SplitPlan> {
        counts
            .iter()
            .map(|&n| SplitPlan::by_count(n, threshold))
            .collect()
    }

    #[test]
    fn split_cycles_axes_and_descends_to_the_right_leaf() {
        let mut t = SpatialTree::new(Aabb::new(Vec3::ZERO, Vec3::ONE));
        let mut next = 1;
        // One leaf with 8 samples, threshold 1.5: splits until each leaf holds at most 1.
        let refused = t.split(&by_count(&[8], 1.5), 1.5, usize::MAX, |_| {
            next += 1;
            Some(next - 1)
        });
        assert_eq!(refused, 0);
        let leaves = t.leaves();
        assert_eq!(leaves.len(), 8);
        for l in &leaves {
            assert_eq!(l.depth, 3);
            assert!((l.bounds.extent() - Vec3::splat(0.5)).abs().max_element() < 1e-6);
            assert_eq!(t.leaf_at(l.bounds.center()), l.leaf);
        }
    }

    #[test]
    fn grid_lookup_agrees_with_a_full_descent() {
        let mut t = SpatialTree::new(Aabb::new(Vec3::splat(-2.0), Vec3::splat(3.0)));
        let mut next = 1;
        // Uneven counts: some leaves stop above the grid's depth, some go far below it.
        let counts: Vec<u64> = (0..1).map(|_| 1 << 20).collect();
        t.split(&by_count(&counts, 1000.0), 1000.0, usize::MAX, |_| {
            next += 1;
            Some(next - 1)
        });
        let counts: Vec<u64> = (0..next)
            .map(|i| if i % 3 == 0 { 1 << 14 } else { 0 })
            .collect();
        t.split(&by_count(&counts, 100.0), 100.0, usize::MAX, |_| {
            next += 1;
            Some(next - 1)
        });
        let mut u = crate::test_uniforms(7);
        for _ in 0..100_000 {
            let mut r = || u() * 5.0 - 2.0;
            let p = Vec3::new(r(), r(), r());
            let full = t.descend(t.fixed(p), t.nodes[0], FIXED_BITS - 1);
            assert_eq!(t.leaf_at(p), full);
            let located = t.locate(p);
            assert_eq!(located.leaf, full);
            assert!(
                located.bounds.contains(p),
                "{p} outside {:?}",
                located.bounds
            );
        }
        let depths: Vec<u32> = t.leaves().iter().map(|l| l.depth).collect();
        assert!(depths.iter().any(|&d| d < 12) && depths.iter().any(|&d| d > 12));
        // The grid, built by one walk of the top levels, is each cell's own descent.
        assert_eq!(&*t.grid, t.grid_by_cells().as_slice());
        let single = SpatialTree::new(Aabb::new(Vec3::ZERO, Vec3::ONE));
        assert_eq!(&*single.grid, single.grid_by_cells().as_slice());
    }

    #[test]
    fn node_cap_refuses_splits() {
        let mut t = SpatialTree::new(Aabb::new(Vec3::ZERO, Vec3::ONE));
        let mut next = 1;
        let refused = t.split(&by_count(&[1000], 1.0), 1.0, 3, |_| {
            next += 1;
            Some(next - 1)
        });
        assert_eq!(t.node_count(), 3);
        assert_eq!(refused, 2);
    }

    #[test]
    fn a_cell_below_a_leaf_is_the_leaf_its_split_would_give() {
        let mut t = SpatialTree::new(Aabb::new(Vec3::ZERO, Vec3::ONE));
        let mut next = 1;
        t.split(&by_count(&[64], 1.0), 1.0, usize::MAX, |_| {
            next += 1;
            Some(next - 1)
        });
        let mut r = crate::test_uniforms(3);
        let root = SpatialTree::new(Aabb::new(Vec3::ZERO, Vec3::ONE));
        for _ in 0..10_000 {
            let p = Vec3::new(r(), r(), r());
            // The six-level tree's leaf at p, as the root's cells two levels below and the
            // depth-3 leaf's cells three levels below say.
            let leaf = t.locate(p);
            assert_eq!(leaf.depth, 6);
            let (top, _) = root.cell_below(p, 0, 3);
            let (bottom, _) = root.cell_below(p, 3, 3);
            let (all, _) = root.cell_below(p, 0, 6);
            assert_eq!(all, top * 8 + bottom);
            let lo = leaf.bounds.min;
            let (again, _) = root.cell_below(lo + Vec3::splat(1e-4), 0, 6);
            assert_eq!(all, again);
        }
    }
}
