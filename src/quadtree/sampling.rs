//! The sampling tree: the read-only, piecewise-constant density on the square that `sample`
//! and `pdf` descend, each node's quadrant probabilities stored as conditionals (no division on
//! the way down) and turned, once per build, into the absolute cuts of `u` that `sample`
//! compares against.
//!
//! **The top, flattened.** A query's descent is a chain: each level waits for the load and the
//! choice of the level above, and most of a descent's levels are its first four. So each tree
//! also keeps its first [`GRID_DEPTH`] levels as a 16 × 16 grid ([`Grid`]):
//! `pdf` reads a point's density there in one load, and `sample` picks a row and then a cell by
//! two cumulative tables of sixteen entries, each one cache line, compared against `u` all at
//! once. Only where the tree goes deeper than the grid does the descent continue, from the
//! cell's node, by cuts taken relative to the cell.

use super::{DirectionalCell, FIXED_BITS, NO_CHILD, RESUME, fixed, quadrant_bits};
use crate::sphere::{ONE_MINUS_EPSILON, ROUND_TRIP_BOUND};
use glam::{Vec2, Vec4};
use std::cell::RefCell;
use std::sync::LazyLock;

/// The depth of the cells [`Grid`] flattens the tree into: 16 × 16 of them. Each level deeper
/// would take four times the memory (2.6 KB per tree at depth 4).
pub(super) const GRID_DEPTH: u32 = 4;

/// Cells along each side of the [`Grid`].
const GRID_SIDE: usize = 1 << GRID_DEPTH;

/// A sampling tree's first [`GRID_DEPTH`] levels as a grid of 16 × 16 cells, row `y` holding the
/// cells whose points have `floor(16·s.y) = y`. A cell inside a leaf of the tree has the leaf's
/// density; a cell the tree splits further has the density of its node and that node's index,
/// from which the descent goes on.
///
/// `sample` picks the row from `u.y` by where each row starts (its cumulative probability) and
/// the cell from `u.x` by where each cell starts within its row; a row or cell of probability
/// zero starts where the next one does, so no `u` picks it. Both tables end at exactly 1, which
/// `u < 1` never reaches.
#[derive(Clone, Debug, PartialEq)]
#[repr(C, align(64))]
pub(crate) struct Grid {
    /// Where row `y` starts in `u.y`; row 0 at 0.
    rows: [f32; GRID_SIDE],
    /// Per row, where each cell starts in `u.x`; cell 0 at 0.
    columns: [[f32; GRID_SIDE]; GRID_SIDE],
    /// Per cell (`16·y + x`), the density on the square.
    density: [f32; GRID_SIDE * GRID_SIDE],
    /// Per cell, the node that splits it further, or [`NO_CHILD`] inside a leaf.
    node: [u16; GRID_SIDE * GRID_SIDE],
    /// Per node, the thresholds the descent below the grid cuts `u` by.
    cuts: Box<[Cuts]>,
}

/// Bytes of a tree's [`Grid`] (besides its cuts, which count per node): a fixed cost of every
/// sampling tree, 2.6 KB.
pub(crate) const GRID_BYTES: usize = size_of::<Grid>();

const _: () = assert!(
    super::horizon::STORED_DEPTH > GRID_DEPTH,
    "a stored product's RESUME leaves lie below the grid, where the descent continues"
);

/// The index of the last of `starts` at or below `u`: the row or cell `u` falls in. `starts[0]`
/// is 0 and `u ≥ 0`, so at least one is. Sixteen compares without a jump (each is a coin flip
/// a predictor would miss).
#[inline(always)]
fn last_start(starts: &[f32; GRID_SIDE], u: f32) -> usize {
    starts.iter().map(|&s| usize::from(s <= u)).sum::<usize>() - 1
}

/// `starts[i + 1]`, or 1 past the last (the tables end at exactly 1).
#[inline(always)]
fn end(starts: &[f32; GRID_SIDE], i: usize) -> f32 {
    starts.get(i + 1).copied().unwrap_or(1.0)
}

impl Grid {
    /// The grid of the tree of `nodes` (root first).
    fn new(nodes: &[SamplingNode], cuts: Box<[Cuts]>) -> Box<Self> {
        const CELLS: usize = GRID_SIDE * GRID_SIDE;
        let mut grid = Box::new(Grid {
            rows: [0.0; GRID_SIDE],
            columns: [[0.0; GRID_SIDE]; GRID_SIDE],
            density: [0.0; CELLS],
            node: [NO_CHILD; CELLS],
            cuts,
        });
        let mut mass = [0.0f64; CELLS];
        // (node, its cell's x and y at its depth, the depth, the cell's mass)
        // At most three siblings wait at each of the levels above the grid's depth, and the
        // four children of the node taken: a stack on the stack.
        let mut open = [(0usize, 0usize, 0usize, 0u32, 1.0f64); 4 * GRID_DEPTH as usize];
        let mut len = 1;
        while len > 0 {
            len -= 1;
            let (i, x, y, depth, m) = open[len];
            let n = &nodes[i];
            for (q, &child) in n.child.iter().enumerate() {
                let (ix, iy) = (q & 1, q >> 1);
                let mq = m * f64::from(n.px[ix]) * f64::from(n.py[ix][iy]);
                let (cx, cy, d) = (2 * x + ix, 2 * y + iy, depth + 1);
                // No RESUME this shallow (STORED_DEPTH > GRID_DEPTH).
                if child != NO_CHILD && d < GRID_DEPTH {
                    open[len] = (usize::from(child), cx, cy, d, mq);
                    len += 1;
                    continue;
                }
                // The quadrant is a leaf, or a node at the grid's depth: it covers `span²` cells,
                // each with its density (mass over area).
                let span = 1usize << (GRID_DEPTH - d);
                let density = (mq * f64::from(1u32 << (2 * d))) as f32;
                let below = if d == GRID_DEPTH { child } else { NO_CHILD };
                for gy in cy * span..(cy + 1) * span {
                    for gx in cx * span..(cx + 1) * span {
                        let k = gy * GRID_SIDE + gx;
                        mass[k] = mq / (span * span) as f64;
                        grid.density[k] = density;
                        grid.node[k] = below;
                    }
                }
            }
        }
        let (rows, _) = mass.as_chunks::<GRID_SIDE>();
        grid.rows = starts(&std::array::from_fn(|y| rows[y].iter().sum()));
        for (columns, row) in grid.columns.iter_mut().zip(rows) {
            *columns = starts(row);
        }
        grid
    }
}

/// Where each of sixteen parts of masses `m` starts, as a share of their total; evenly spaced
/// if the total is zero (a row no `u` picks).
fn starts(m: &[f64; GRID_SIDE]) -> [f32; GRID_SIDE] {
    let total: f64 = m.iter().sum();
    let mut out = [0.0f32; GRID_SIDE];
    let mut before = 0.0;
    for (i, (o, &mi)) in out.iter_mut().zip(m).enumerate() {
        *o = if total > 0.0 {
            (before / total) as f32
        } else {
            i as f32 / GRID_SIDE as f32
        };
        before += mi;
    }
    out
}

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
    /// `u` rescaled to the [`Grid`] cell the descent started from, whose `[0, 1)²` the
    /// interval `[a, a + w)` lies in.
    pub(super) u: Vec2,
    pub(super) a: Vec2,
    pub(super) w: Vec2,
    pub(super) cell: [u32; 2],
    pub(super) depth: u32,
    pub(super) pdf: f32,
    pub(super) resume: bool,
}

thread_local! {
    /// [`SamplingTree::new`]'s working memory, kept per thread: `refine` builds hundreds of
    /// trees (a guide and its stored surface products per spatial leaf) on rayon's threads.
    /// It holds 20 bytes per node of the largest tree the thread built.
    static PATHS: RefCell<Vec<(Vec2, Vec2, u32)>> = const { RefCell::new(Vec::new()) };
}

/// The read-only, piecewise-constant density on the square that queries use.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct SamplingTree {
    nodes: Box<[SamplingNode]>,
    /// What queries descend, derived from `nodes`: the first [`GRID_DEPTH`] levels as a grid,
    /// and the cuts below it. (One pointer: the tree's pointers share a cache line with what
    /// else a query reads, see [`Region`](crate::region::Region).)
    grid: Box<Grid>,
}

impl SamplingTree {
    /// The uniform density: one root with four equal leaves.
    pub(crate) fn uniform() -> Self {
        Self::new(Box::new([SamplingNode::UNIFORM]))
    }

    /// The uniform density, shared (what a field without volume guides gives medium queries).
    pub(crate) fn uniform_ref() -> &'static Self {
        static UNIFORM: LazyLock<SamplingTree> = LazyLock::new(SamplingTree::uniform);
        &UNIFORM
    }

    /// The tree of `nodes` (children after their parents, the root first).
    ///
    /// Each node's interval of `u` is `[a, a + w)`, with `a` and `w` what the descent has
    /// accumulated on the way down from the grid cell it continues from (where the interval
    /// is `[0, 1)²`), in the same `f32` operations in the same order as a descent that cuts the
    /// interval level by level; so the cuts are bit for bit the values that descent would
    /// compare against. (Nodes above the grid's depth get cuts no descent reads.)
    pub(crate) fn new(nodes: Box<[SamplingNode]>) -> Self {
        let cuts = PATHS.with_borrow_mut(|paths| Self::cuts(&nodes, paths));
        let grid = Grid::new(&nodes, cuts);
        Self { nodes, grid }
    }

    /// The cuts of [`new`](Self::new); `paths` is working memory, per node the interval of
    /// `u` that leads to it and its depth.
    fn cuts(nodes: &[SamplingNode], paths: &mut Vec<(Vec2, Vec2, u32)>) -> Box<[Cuts]> {
        paths.clear();
        paths.resize(nodes.len(), (Vec2::ZERO, Vec2::ONE, 0));
        let mut cuts = Vec::with_capacity(nodes.len());
        for (i, n) in nodes.iter().enumerate() {
            let (a, w, depth) = paths[i];
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
                if let Some(slot) = paths.get_mut(usize::from(c)).filter(|_| c != NO_CHILD) {
                    let d = depth + 1;
                    *slot = if d == GRID_DEPTH {
                        (Vec2::ZERO, Vec2::ONE, d)
                    } else {
                        (
                            Vec2::new(a.x + left * ix as f32, a.y + low[ix] * iy as f32),
                            Vec2::new(w.x * n.px[ix], w.y * n.py[ix][iy]),
                            d,
                        )
                    };
                }
            }
        }
        cuts.into_boxed_slice()
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
        let (point, near_border) = place(d.u, d.a, d.w, d.cell, d.depth);
        (point, d.pdf, near_border)
    }

    /// The descent of [`sample`](Self::sample) to a leaf, for `u` already in `[0,1)²`: the
    /// grid's row and cell, then, where the cell is split further, the cuts from its node on,
    /// with `u` taken relative to the cell. With `RESUMABLE` it also stops at a [`RESUME`]
    /// child (a surface product's leaf below which the product goes on per query) and says so;
    /// without, the check is compiled out of the plain descent.
    #[inline(always)]
    pub(super) fn descend<const RESUMABLE: bool>(&self, u: Vec2) -> Descent {
        let grid = &*self.grid;
        let y = last_start(&grid.rows, u.y);
        let columns = &grid.columns[y];
        let x = last_start(columns, u.x);
        let (x0, y0) = (columns[x], grid.rows[y]);
        // Past the start of the cell `u` picked, and before the next one's: a positive width.
        let u = Vec2::new(
            unit((u.x - x0) / (end(columns, x) - x0)),
            unit((u.y - y0) / (end(&grid.rows, y) - y0)),
        );
        let k = y * GRID_SIDE + x;
        let (mut a, mut w) = (Vec2::ZERO, Vec2::ONE);
        let mut cell = [x as u32, y as u32];
        let mut depth = GRID_DEPTH;
        let mut pdf = grid.density[k];
        let mut node = usize::from(grid.node[k]);
        let resume = node != usize::from(NO_CHILD)
            && loop {
                // The chain from one level to the next: load the cuts (with the children),
                // compare, shift out the child.
                // Branch-free: with random `u` each choice is a coin flip no predictor can learn,
                // so choices become indices and selects, never jumps. The lower/upper choice is
                // made for both columns at once, off the x chain. `a`, `w` and the density follow
                // off the chain.
                let c = &grid.cuts[node];
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
            u,
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
        let cell = |c: u32| (c >> (FIXED_BITS - GRID_DEPTH)) as usize & (GRID_SIDE - 1);
        let k = cell(p[1]) * GRID_SIDE + cell(p[0]);
        let mut pdf = self.grid.density[k];
        let mut node = usize::from(self.grid.node[k]);
        if node == usize::from(NO_CHILD) {
            return (pdf, GRID_DEPTH, false);
        }
        let mut depth = GRID_DEPTH + 1;
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
        std::mem::size_of_val(&*self.nodes) + std::mem::size_of_val(&*self.grid.cuts) + GRID_BYTES
    }
}

#[cfg(test)]
#[path = "sampling_tests.rs"]
mod tests;
