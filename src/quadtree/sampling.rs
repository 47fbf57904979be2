//! The sampling tree: the read-only, piecewise-constant density on the square that `sample`
//! and `pdf` descend, each node's quadrant probabilities stored as conditionals (no division on
//! the way down) and turned, once per build, into the absolute cuts of `u` that `sample`
//! compares against.

use super::{DirectionalCell, NO_CHILD, RESUME, fixed, quadrant_bits};
use crate::sphere::{ONE_MINUS_EPSILON, ROUND_TRIP_BOUND};
use glam::{Vec2, Vec4};

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

    /// The four quadrants' probabilities, quadrant `q = ix + 2·iy` in lane `q`.
    #[inline]
    pub(crate) fn quadrants(&self) -> Vec4 {
        Vec4::new(
            self.px[0] * self.py[0][0],
            self.px[1] * self.py[1][0],
            self.px[0] * self.py[0][1],
            self.px[1] * self.py[1][1],
        )
    }

    /// The node for quadrant masses `m` (non-negative, with a positive total). A column of
    /// zero mass gets even conditionals within it; the descent never enters it (see
    /// [`SamplingTree::new`]).
    pub(super) fn from_masses(m: [f64; 4], child: [u16; 4]) -> Self {
        let col = [m[0] + m[2], m[1] + m[3]];
        let total = col[0] + col[1];
        Self {
            px: col.map(|c| (c / total) as f32),
            py: [0, 1].map(|ix| {
                if col[ix] > 0.0 {
                    [(m[ix] / col[ix]) as f32, (m[ix + 2] / col[ix]) as f32]
                } else {
                    [0.5; 2]
                }
            }),
            child,
        }
    }

    pub(super) const UNIFORM: SamplingNode = SamplingNode {
        px: [0.5; 2],
        py: [[0.5; 2]; 2],
        child: [NO_CHILD; 4],
    };
}

/// `if choice == 1 { b } else { a }` (`choice` is 0 or 1), by bit masks: in a descent each
/// choice is a coin flip, and the compiler turns an `if`, or `choice as f32`, into a jump that
/// is mispredicted half the time. (`std::hint::select_unpredictable` on `choice == 1` came out
/// slower here, measured: 87.5 against 66.8 ns per `sample` in a loop over one distribution.)
#[inline(always)]
pub(super) fn pick(choice: usize, a: f32, b: f32) -> f32 {
    let mask = 0u32.wrapping_sub(choice as u32);
    f32::from_bits(b.to_bits() & mask | a.to_bits() & !mask)
}

/// Clamps a sample coordinate into `[0, 1)`; NaN becomes 0 (which `clamp` would not do).
#[inline]
#[allow(clippy::manual_clamp, reason = "max/min map NaN to 0; clamp keeps NaN")]
pub(super) fn unit(x: f32) -> f32 {
    x.max(0.0).min(ONE_MINUS_EPSILON)
}

/// Where `u` lands in the leaf `cell` at `depth` that a descent reached with the interval
/// `[a, a + w)` of `u`: the point, placed uniformly in the leaf by `(u − a)/w`, and whether it
/// may lie within rounding distance of the leaf's border (where the round trip through the
/// sphere may move it into the neighbour).
#[inline(always)]
pub(super) fn place(u: Vec2, a: Vec2, w: Vec2, cell: [u32; 2], depth: u32) -> (Vec2, bool) {
    // 2^∓depth from exponent bits (depth ≤ 24: both are normal f32), not `powi` calls.
    let size = f32::from_bits((127 - depth) << 23);
    let inv_size = f32::from_bits((127 + depth) << 23);
    let local = Vec2::new(unit((u.x - a.x) / w.x), unit((u.y - a.y) / w.y));
    let origin = Vec2::new(cell[0] as f32, cell[1] as f32) * size;
    let margin = ROUND_TRIP_BOUND * inv_size;
    let near_border = local.min_element() <= margin || local.max_element() >= 1.0 - margin;
    (origin + local * size, near_border)
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

/// Where a descent of [`SamplingTree::sample`] ended: the interval `[a, a + w)` of `u` that
/// leads to the leaf, the leaf's cell and depth, the density, and whether the leaf is a
/// [`RESUME`] child.
#[derive(Clone, Copy, Debug)]
pub(super) struct Descent {
    pub(super) a: Vec2,
    pub(super) w: Vec2,
    pub(super) cell: [u32; 2],
    pub(super) depth: u32,
    pub(super) pdf: f32,
    pub(super) resume: bool,
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
            // A part of probability zero is never taken: `u ≥ a` holds exactly along the
            // descent, so a zero left or lower part (cut at `a`) loses every comparison, and a
            // zero right or upper part gets a cut no `u` reaches (rounding of `a + w` could
            // otherwise let `u` past it). Only the surface products have such parts.
            let cut = |at: f32, upper: f32| if upper > 0.0 { at } else { f32::INFINITY };
            cuts.push(Cuts {
                x: cut(a.x + left, n.px[1]),
                y: [cut(a.y + low[0], n.py[0][1]), cut(a.y + low[1], n.py[1][1])],
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

    /// Node `i`.
    #[inline(always)]
    pub(crate) fn node(&self, i: usize) -> &SamplingNode {
        &self.nodes[i]
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
        let d = self.descend::<false>(u);
        let (point, near_border) = place(u, d.a, d.w, d.cell, d.depth);
        (point, d.pdf, near_border)
    }

    /// The descent of [`sample`](Self::sample) from the root to a leaf, for `u` already in
    /// `[0,1)²`. With `RESUMABLE` it also stops at a [`RESUME`] child (a surface product's
    /// leaf below which the product goes on per query) and says so; without, the check is
    /// compiled out of the plain descent.
    #[inline(always)]
    pub(super) fn descend<const RESUMABLE: bool>(&self, u: Vec2) -> Descent {
        let (mut a, mut w) = (Vec2::ZERO, Vec2::ONE);
        let mut cell = [0u32; 2];
        let mut depth = 0;
        let mut pdf = 1.0;
        let mut node = 0usize;
        let resume = loop {
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
                NO_CHILD => break false,
                RESUME if RESUMABLE => break true,
                c => node = usize::from(c),
            }
        };
        Descent {
            a,
            w,
            cell,
            depth,
            pdf,
            resume,
        }
    }

    /// The density on the square at `s ∈ [0,1)²`.
    #[inline]
    pub(crate) fn pdf(&self, s: Vec2) -> f32 {
        self.pdf_descend::<false>(fixed(s)).0
    }

    /// The descent of [`pdf`](Self::pdf) at the fixed-point point `p`: the density, the leaf's
    /// depth, and (with `RESUMABLE`) whether the leaf is a [`RESUME`] child.
    #[inline(always)]
    pub(super) fn pdf_descend<const RESUMABLE: bool>(&self, p: [u32; 2]) -> (f32, u32, bool) {
        let mut pdf = 1.0;
        let mut node = 0usize;
        let mut depth = 1;
        loop {
            let n = self.node(node);
            let (ix, iy) = quadrant_bits(p, depth);
            pdf *= n.density_factor(ix, iy);
            match n.child[ix | iy << 1] {
                NO_CHILD => return (pdf, depth, false),
                RESUME if RESUMABLE => return (pdf, depth, true),
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
            let n = self.node(node);
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

    /// The number of leaves and the deepest leaf's depth: what [`leaves`](Self::leaves) would
    /// list, counted without listing (statistics need no masses).
    pub(crate) fn leaf_count_and_depth(&self) -> (usize, u32) {
        let (mut count, mut deepest) = (0, 0);
        let mut stack = vec![(0usize, 0u32)];
        while let Some((node, depth)) = stack.pop() {
            for &child in &self.node(node).child {
                match child {
                    NO_CHILD => {
                        count += 1;
                        deepest = deepest.max(depth + 1);
                    }
                    c => stack.push((usize::from(c), depth + 1)),
                }
            }
        }
        (count, deepest)
    }

    pub(crate) fn node_count(&self) -> usize {
        self.nodes.len()
    }

    pub(crate) fn bytes(&self) -> usize {
        std::mem::size_of_val(&*self.nodes) + std::mem::size_of_val(&*self.cuts)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quadtree::testing::{random_sampling_tree, uniform};

    #[test]
    fn leaf_count_and_depth_match_the_listed_leaves() {
        for seed in 0..20 {
            let tree = random_sampling_tree(seed);
            let leaves = tree.leaves();
            let deepest = leaves.iter().map(|(c, _)| c.depth).max().unwrap();
            assert_eq!(
                tree.leaf_count_and_depth(),
                (leaves.len(), deepest),
                "seed {seed}"
            );
        }
        assert_eq!(SamplingTree::uniform().leaf_count_and_depth(), (4, 1));
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
                let n = t.node(node);
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
    fn parts_of_probability_zero_are_never_drawn() {
        // A root whose right column and whose lower-left cell have mass zero: every draw lands
        // in the upper-left quadrant, even for `u` at the top of the range, where rounding
        // of the interval's end could otherwise pass a cut.
        let tree = SamplingTree::new(Box::new([SamplingNode::from_masses(
            [0.0, 0.0, 3.0, 0.0],
            [NO_CHILD; 4],
        )]));
        let mut next = uniform(5);
        let edges = [0.0, 0.5, ONE_MINUS_EPSILON, 1.0];
        for k in 0..10_000 {
            let u = if k < 16 {
                Vec2::new(edges[k % 4], edges[k / 4])
            } else {
                Vec2::new(next() as f32, next() as f32)
            };
            let (s, pdf, _) = tree.sample(u);
            assert!(s.x < 0.5 && s.y >= 0.5, "u = {u}: {s}");
            assert_eq!(pdf, 4.0);
        }
        assert_eq!(tree.pdf(Vec2::new(0.7, 0.2)), 0.0);
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
