//! The directional box filter: a sample's weights spread over a square the size of its leaf,
//! folded across the border of the unit square as the map folds the sphere. `record` hands out
//! the shares at once from the sample's own leaf (`box_shares`); the deferred filter spreads
//! each leaf quadrant's pending sums at `refine` (`spread_pending`). Both cut the square along
//! the grid of leaf-sized cells and look each part up from the chain of nodes down to the leaf.

use super::{FIXED_BITS, LEAF_BIT, RecordingTree, cell_side, cells_per_area, fixed, fixed_f64};
use crate::filter::overlap;
use crate::moments::AtomicSums;
use crate::sphere;
use glam::Vec2;

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

/// Weights `(w1, w2)` per unit area times the area of the piece `x × y`.
#[inline]
fn share((w1, w2): (f64, f64), x: [f64; 2], y: [f64; 2]) -> (f64, f64) {
    let area = (x[1] - x[0]) * (y[1] - y[0]);
    (w1 * area, w2 * area)
}

/// The centre of the piece `x × y`.
#[inline]
fn middle(x: [f64; 2], y: [f64; 2]) -> [f64; 2] {
    [0.5 * (x[0] + x[1]), 0.5 * (y[0] + y[1])]
}

/// One axis of a leaf-sized square `[c − size/2, c + size/2)` centred in the leaf whose side
/// starts at `corner`, cut where [`grid_cut`] cuts it: the leaf's part, and its neighbour's
/// (none when the square ends on the leaf's side). `None` where the square leaves the unit
/// square, which only the fold handles.
#[inline]
fn interior_cut(c: f64, corner: f64, size: f64) -> Option<([f64; 2], Option<[f64; 2]>)> {
    let h = 0.5 * size;
    let (a, b) = (c - h, c + h);
    if a < 0.0 || b > 1.0 {
        return None;
    }
    Some(if a < corner {
        ([corner, b], Some([a, corner]))
    } else {
        let line = corner + size;
        if line < b {
            ([a, line], Some([line, b]))
        } else {
            ([a, b], None)
        }
    })
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
        cell_side(self.depth)
    }

    /// The leaf's cell: its corner with the smallest coordinates.
    fn corner(&self) -> [f64; 2] {
        self.corner_at(self.depth)
    }

    /// The corner of the cell at depth `d` that holds the leaf (`d` at most the leaf's depth).
    fn corner_at(&self, d: u32) -> [f64; 2] {
        let shift = FIXED_BITS - d;
        self.at.map(|c| f64::from(c >> shift) * cell_side(d))
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
                    cell: cell_side(d),
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

    fn push(&mut self, moments: &[AtomicSums], leaf: usize, part: (f64, f64)) {
        if self.len < Self::CAP {
            self.parts[self.len] = (leaf, part);
            self.len += 1;
        } else {
            moments[leaf].add_sums(part);
        }
    }

    /// Loads the targets' words (see the type's doc); the result means nothing.
    fn touch(&self, moments: &[AtomicSums]) -> u64 {
        self.parts[..self.len]
            .iter()
            .fold(0, |t, &(leaf, _)| t ^ moments[leaf].touch())
    }

    fn add(&self, moments: &[AtomicSums]) {
        for &(leaf, part) in &self.parts[..self.len] {
            moments[leaf].add_sums(part);
        }
    }
}

impl RecordingTree {
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
        weights: (f64, f64),
        add: &mut impl FnMut(usize, (f64, f64)),
    ) -> (f64, f64) {
        self.spread_interior(chain, centre, weights, add)
            .unwrap_or_else(|| self.spread_folded(chain, centre, weights, add))
    }

    /// [`spread_square`](Self::spread_square) for a square inside the unit square (`None`
    /// and nothing added otherwise), nearly every sample's: each axis cut in at most two at
    /// the leaf's side, as [`spread_folded`](Self::spread_folded) cuts it, with the leaf's own
    /// part known without a test and nothing folded: the same shares, to the bit, without the
    /// fold, the floors of the grid cut or the point-in-leaf tests.
    #[inline]
    fn spread_interior(
        &self,
        chain: &Ancestry,
        centre: [f64; 2],
        weights: (f64, f64),
        add: &mut impl FnMut(usize, (f64, f64)),
    ) -> Option<(f64, f64)> {
        let (size, corner) = (chain.side(), chain.corner());
        let (own_x, next_x) = interior_cut(centre[0], corner[0], size)?;
        let (own_y, next_y) = interior_cut(centre[1], corner[1], size)?;
        let mut near = |x: [f64; 2], y: [f64; 2]| {
            let k = chain.leaf_near(self, fixed_f64(middle(x, y)));
            add(k, share(weights, x, y));
        };
        if let Some(x) = next_x {
            near(x, own_y);
            if let Some(y) = next_y {
                near(x, y);
            }
        }
        if let Some(y) = next_y {
            near(own_x, y);
        }
        Some(share(weights, own_x, own_y))
    }

    /// [`spread_square`](Self::spread_square) for any square: its part inside the unit square
    /// cut along the grid of leaf-sized cells, the parts past the border folded back in and
    /// walked from the deepest node of the chain that holds them.
    fn spread_folded(
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
                    let part = share((w1, w2), x, y);
                    let mid = middle(x, y);
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
            let per_area = cells_per_area(depth);
            let centre = [f64::from(s.x), f64::from(s.y)];
            let own = self.spread_square(&chain, centre, (w1 * per_area, w2 * per_area), add);
            add(k, own);
        }
        (k, q)
    }

    /// Adds weights `(v/p, v²/p)` to the cells that a square the size of the leaf holding `s`,
    /// centred on `s`, overlaps, in proportion to the overlap (see
    /// [`box_shares`](Self::box_shares)); `counted`: and counts the sample where it landed.
    /// The shares' leaves are loaded before any atomic add (see `Shares`).
    #[inline]
    pub(super) fn record_box(&self, s: Vec2, weights: (f64, f64), counted: bool) {
        let mut shares = Shares::new();
        let (k, q) = self.box_shares(s, weights, &mut |leaf, part| {
            shares.push(&self.moments, leaf, part)
        });
        if counted {
            std::hint::black_box(self.touch(k, q) ^ shares.touch(&self.moments));
            self.quadrants[k].add(q, weights.1);
        } else {
            std::hint::black_box(shares.touch(&self.moments));
        }
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
}

#[cfg(test)]
#[path = "splat_tests.rs"]
mod tests;
