//! A sampling tree's product with a lobe about an axis: the density `p(ω) ∝ p_guide(ω)·ĉ(ω)`,
//! where `ĉ`, cell by cell, estimates a factor that depends on `ω` only through `axis·ω` —
//! the clamped cosine about a surface normal ([`super::horizon`]) or a Henyey–Greenstein phase
//! function about the direction of travel ([`super::phase`]).
//!
//! The descent is the guide's: at every node each quadrant's probability is weighed by the
//! lobe's estimate over the quadrant and renormalized, and the lobe may carry the descent on
//! inside the guide's leaves, as if they were split into quadrants of equal guide probability.
//! The density is the product of the conditionals chosen on the way down, so `sample` and
//! `pdf` agree exactly whatever the estimate; the estimate only decides how closely the product
//! follows the lobe. The estimate of a child comes from the range `[lo, hi]` of `axis·ω` over
//! its four corners (the 3 × 3 grid over the node), which every lobe reads the same way.
//!
//! **What a level costs.** The levels form a chain: each level's corners depend on the quadrant
//! the level above chose. The children's corners of cells above [`TABLE_DEPTH`] (where almost
//! every descent spends its levels) are looked up in one table shared by every tree, laid out
//! so that a level's sixteen corner values are twelve vector multiply-adds, instead of mapped;
//! and the level keeps its quadrants' weights unnormalized, with one reciprocal of their total
//! (docs/performance.md measures both). The descent's choices are bit masks, never jumps (a
//! random choice is a coin flip that a branch predictor misses half the time), and the level is
//! computed inline in the descent. What is left is the chain itself: each level waits for the
//! one above.

use super::sampling::{pick, place, unit};
use super::{NO_CHILD, SamplingNode, SamplingTree, fixed, quadrant_bits};
use crate::sphere::square_to_direction;
use glam::{Vec2, Vec3, Vec4};
use std::f32::consts::FRAC_PI_4;
use std::sync::LazyLock;

/// A factor of the product: a positive function of `axis·ω` (zero allowed where the lobe ends
/// the descent), estimated over a cell from the range of `axis·ω` over its corners.
pub(super) trait Lobe: Copy {
    /// The unit axis the factor is a function of the cosine about.
    fn axis(&self) -> Vec3;

    /// The estimates of the factor over the four children of the cell `parent` (children at
    /// `depth`), lane `q` for child `q`, from the range `[lo, hi]` of `axis·ω` over each
    /// child's corners; and the ranges the descent goes on with (the lobe may widen them).
    fn children(&self, lo: Vec4, hi: Vec4, parent: [u32; 2], depth: u32) -> (Vec4, Vec4, Vec4);

    /// Whether a child of range `[lo, hi]` ends the descent even inside the guide's tree.
    fn ends(&self, lo: f32, hi: f32) -> bool;

    /// Whether the factor has settled over a child of range `[lo, hi]`: below it the product
    /// follows the guide's own conditionals. Must hold for `[1, 1]`.
    fn settles(&self, lo: f32, hi: f32) -> bool;

    /// Whether a child of range `[lo, hi]` at `depth`, a leaf of the guide's tree, is descended
    /// further. Must not hold for `[1, 1]`.
    fn descends_inside(&self, lo: f32, hi: f32, depth: u32) -> bool;
}

/// `n·ω` at four points of the square at once: the map of
/// [`crate::sphere::square_to_direction`], with polynomial sine and cosine (error below
/// 4·10⁻⁷).
#[inline]
fn cosines(n: Vec3, sx: Vec4, sy: Vec4) -> Vec4 {
    let (u, v) = (2.0 * sx - 1.0, 2.0 * sy - 1.0);
    let (up, vp) = (u.abs(), v.abs());
    let sd = 1.0 - (up + vp);
    // |(|v| − |u|)| ≤ r everywhere; the floor only keeps the quotient finite where r = 0 (the
    // square's centre and corners, where |v| − |u| = 0 too).
    let r = (1.0 - sd.abs()).max(Vec4::splat(1e-12));
    // φ = π/4·((|v| − |u|)/r + 1) = π/4 + ψ, |ψ| ≤ π/4; cos φ and sin φ from cos ψ and sin ψ.
    let psi = (vp - up) / r * FRAC_PI_4;
    let p2 = psi * psi;
    let sin_psi = psi * (1.0 + p2 * (-1.0 / 6.0 + p2 * (1.0 / 120.0 + p2 * (-1.0 / 5040.0))));
    let cos_psi =
        1.0 + p2 * (-0.5 + p2 * (1.0 / 24.0 + p2 * (-1.0 / 720.0 + p2 * (1.0 / 40320.0))));
    let cos_phi = (cos_psi - sin_psi) * std::f32::consts::FRAC_1_SQRT_2;
    let sin_phi = (cos_psi + sin_psi) * std::f32::consts::FRAC_1_SQRT_2;
    let z = (1.0 - r * r).copysign(sd);
    let k = r * (2.0 - r * r).max(Vec4::ZERO).sqrt();
    let x = cos_phi.copysign(u) * k;
    let y = sin_phi.copysign(v) * k;
    x * n.x + y * n.y + z * n.z
}

/// The depth of the finest grid of cell corners kept in [`CORNERS`]: the levels above it (where
/// almost every descent spends its levels) look their children's corners up instead of mapping
/// them, which takes the map's division, square root and polynomials off the chain of dependent
/// steps from one level to the next.
pub(super) const TABLE_DEPTH: u32 = 6;

/// The corners of a cell's four children, laid out for four dot products at once: `c[k]` holds
/// corner `k = i + 2·j` (corner `(i, j)` of the child's square) of child `q` in lane `q`, as
/// the three coordinates `[x, y, z]` of its direction.
type ChildCorners = [[Vec4; 3]; 4];

/// Where the cells of `depth` start in [`CORNERS`]: the cells above it come first.
#[inline]
fn table_offset(depth: u32) -> usize {
    ((1usize << (2 * depth)) - 1) / 3
}

/// [`ChildCorners`] of every cell above [`TABLE_DEPTH`], depth by depth and row-major within a
/// depth (cell `(x, y)` at `depth` is entry `table_offset(depth) + y·2^depth + x`), by the exact
/// map: 1365 cells, 262 KB, shared by every tree. A level reads one entry, 192 contiguous bytes,
/// and needs no gather or shuffle to turn it into its children's corner ranges.
static CORNERS: LazyLock<Box<[ChildCorners]>> = LazyLock::new(|| {
    let mut table = Vec::with_capacity(table_offset(TABLE_DEPTH));
    for depth in 0..TABLE_DEPTH {
        let side = 1u32 << depth;
        // Grid point (i, j) of the children's grid is (2·cell + (i, j))·2^-(depth + 1): exact.
        let half = f32::from_bits((126 - depth) << 23);
        for cy in 0..side {
            for cx in 0..side {
                let mut entry = [[Vec4::ZERO; 3]; 4];
                for (k, corner) in entry.iter_mut().enumerate() {
                    let mut lanes = [[0.0f32; 4]; 3];
                    for q in 0..4 {
                        let gx = 2 * cx + (q & 1) as u32 + (k & 1) as u32;
                        let gy = 2 * cy + (q >> 1) as u32 + (k >> 1) as u32;
                        let d = square_to_direction(Vec2::new(gx as f32, gy as f32) * half);
                        for (axis, lane) in lanes.iter_mut().enumerate() {
                            lane[q] = d[axis];
                        }
                    }
                    *corner = lanes.map(Vec4::from_array);
                }
                table.push(entry);
            }
        }
    }
    table.into_boxed_slice()
});

/// The range `[lo, hi]` of `n·ω` over the corners of each of the four children of the cell
/// `cell` at `depth` (child `q = ix + 2·iy` in lane `q`): the children's corners are the 3 × 3
/// grid over the cell, looked up in [`CORNERS`] above [`TABLE_DEPTH`] and mapped, as three
/// groups of four, below it.
#[inline]
pub(super) fn child_corner_range(n: Vec3, cell: [u32; 2], depth: u32) -> (Vec4, Vec4) {
    if depth < TABLE_DEPTH {
        let index = table_offset(depth) + ((cell[1] as usize) << depth) + cell[0] as usize;
        let table: &[ChildCorners] = &CORNERS;
        if let Some(corners) = table.get(index) {
            let (nx, ny, nz) = (Vec4::splat(n.x), Vec4::splat(n.y), Vec4::splat(n.z));
            let [a, b, c, d] = corners.map(|[x, y, z]| x * nx + y * ny + z * nz);
            return (a.min(b).min(c.min(d)), a.max(b).max(c.max(d)));
        }
    }
    let g = mapped_grid(n, cell, depth);
    // Child q's corners: its lower-left grid point k = iy·3 + ix, and k+1, k+3, k+4.
    let at = |k: usize| Vec4::new(g[k], g[k + 1], g[k + 3], g[k + 4]);
    let (a, b, c, d) = (at(0), at(1), at(3), at(4));
    (a.min(b).min(c.min(d)), a.max(b).max(c.max(d)))
}

/// `n·ω` at the 3 × 3 grid over the cell `cell` at `depth`, row-major, by the polynomial map.
#[inline]
fn mapped_grid(n: Vec3, cell: [u32; 2], depth: u32) -> [f32; 9] {
    // Grid point (i, j) is (2·cell + (i, j))·2^-(depth + 1): exact in f32.
    let half = f32::from_bits((126 - depth) << 23);
    let (x0, y0) = ((2 * cell[0]) as f32, (2 * cell[1]) as f32);
    let g0 = cosines(
        n,
        Vec4::new(x0, x0 + 1.0, x0 + 2.0, x0) * half,
        Vec4::new(y0, y0, y0, y0 + 1.0) * half,
    );
    let g1 = cosines(
        n,
        Vec4::new(x0 + 1.0, x0 + 2.0, x0, x0 + 1.0) * half,
        Vec4::new(y0 + 1.0, y0 + 1.0, y0 + 2.0, y0 + 2.0) * half,
    );
    let g2 = cosines(
        n,
        Vec4::splat(x0 + 2.0) * half,
        Vec4::splat(y0 + 2.0) * half,
    );
    [g0.x, g0.y, g0.z, g0.w, g1.x, g1.y, g1.z, g1.w, g2.x]
}

/// One level of the product's descent: each quadrant's weight (the guide's probability times
/// the lobe's estimate), the reciprocal of their total, and the range of `axis·ω` over each
/// child's corners. The product's conditionals are the weights over their total; sample
/// and pdf both take a quadrant's density factor as `4·w_q·(1/total)`, so they multiply the
/// same factors. Arrays, not vectors: the descent picks lanes by the quadrant it chose, and an
/// array is indexed by a load where a vector's lane is picked by a jump on the index, which
/// random choices mispredict.
pub(super) struct Level {
    pub(super) w: [f32; 4],
    inv_total: f32,
    lo: [f32; 4],
    hi: [f32; 4],
}

impl Level {
    /// The level at the node `guide` (the guide's own, or uniform inside a leaf) whose cell is
    /// `cell` at `depth`. Where every quadrant's estimate is zero (a cell wholly below the
    /// horizon, entered only through the estimate's slack) the guide's own probabilities stand,
    /// so the conditionals always sum to 1.
    #[inline]
    fn new(guide: &SamplingNode, lobe: &impl Lobe, cell: [u32; 2], depth: u32) -> Self {
        let (lo, hi) = child_corner_range(lobe.axis(), cell, depth);
        let (estimate, lo, hi) = lobe.children(lo, hi, cell, depth + 1);
        let p = guide.quadrants();
        let w = p * estimate;
        let w = if w.element_sum() > 0.0 { w } else { p };
        Self::of(w, lo, hi)
    }

    /// The level of weights `w` (positive total) and corner ranges `[lo, hi]`.
    #[inline]
    fn of(w: Vec4, lo: Vec4, hi: Vec4) -> Self {
        Self {
            w: w.to_array(),
            inv_total: 1.0 / w.element_sum(),
            lo: lo.to_array(),
            hi: hi.to_array(),
        }
    }

    /// The guide's own probabilities, below a cell where the lobe has settled. The corner
    /// range it reports, `[1, 1]`, keeps the descent going exactly where the guide's tree does.
    #[inline]
    fn settled(guide: &SamplingNode) -> Self {
        Self::of(guide.quadrants(), Vec4::ONE, Vec4::ONE)
    }

    /// `4·P(q)`: sample and pdf multiply the same factors.
    #[inline]
    pub(super) fn density_factor(&self, q: usize) -> f32 {
        4.0 * self.w[q] * self.inv_total
    }
}

/// Where a descent stands: the guide's node (or none, inside one of its leaves), the cell and
/// its depth, and whether the lobe has settled there.
#[derive(Clone, Copy)]
pub(super) struct Cursor {
    pub(super) node: Option<usize>,
    pub(super) cell: [u32; 2],
    pub(super) depth: u32,
    /// The lobe has settled over the cell (see [`Lobe::settles`]): below it the product follows
    /// the guide's own conditionals.
    pub(super) settled: bool,
}

impl Cursor {
    pub(super) const ROOT: Cursor = Cursor {
        node: Some(0),
        cell: [0, 0],
        depth: 0,
        settled: false,
    };

    /// The cursor at `cell` of `depth` inside one of the guide's leaves, where the lobe has
    /// not settled: where a stored product's descent resumes per query.
    #[inline]
    pub(super) fn inside(cell: [u32; 2], depth: u32) -> Cursor {
        Cursor {
            node: None,
            cell,
            depth,
            settled: false,
        }
    }

    /// The centre of the cursor's cell on the square.
    #[inline]
    pub(super) fn centre(&self) -> Vec2 {
        let size = f32::from_bits((127 - self.depth) << 23);
        (Vec2::new(self.cell[0] as f32, self.cell[1] as f32) + 0.5) * size
    }

    /// The level at the cursor's node.
    #[inline(always)]
    pub(super) fn level(&self, tree: &SamplingTree, lobe: &impl Lobe) -> Level {
        let guide = match self.node {
            Some(i) => tree.node(i),
            None => &SamplingNode::UNIFORM,
        };
        if self.settled {
            return Level::settled(guide);
        }
        Level::new(guide, lobe, self.cell, self.depth)
    }

    /// Moves into quadrant `(ix, iy)`; `false` when the descent ends there.
    #[inline]
    pub(super) fn enter(
        &mut self,
        tree: &SamplingTree,
        level: &Level,
        lobe: &impl Lobe,
        (ix, iy): (usize, usize),
    ) -> bool {
        let q = ix | iy << 1;
        self.cell = [2 * self.cell[0] + ix as u32, 2 * self.cell[1] + iy as u32];
        self.depth += 1;
        let (lo, hi) = (level.lo[q], level.hi[q]);
        if lobe.ends(lo, hi) {
            return false;
        }
        self.settled |= lobe.settles(lo, hi);
        self.node = self
            .node
            .map(|i| tree.node(i).child[q])
            .filter(|&c| c != NO_CHILD)
            .map(usize::from);
        self.node.is_some() || lobe.descends_inside(lo, hi, self.depth)
    }
}

/// Which of two parts of weights `a` and `b` (not both zero) the point `u` of an interval falls
/// in, given the cut between them; never one of weight zero (rounding at the end of an interval
/// could otherwise pick it). Branch-free: with random `u` the choice is a coin flip no predictor
/// can learn.
#[inline]
fn choose(a: f32, b: f32, u: f32, cut: f32) -> usize {
    usize::from((u >= cut) & (b != 0.0) | (a == 0.0))
}

/// Where the product's descent stands while sampling: the interval `[a, a + w)` of `u` that
/// leads to the cursor's cell, and the density so far.
pub(super) struct Draw {
    pub(super) a: Vec2,
    pub(super) w: Vec2,
    pub(super) pdf: f32,
}

impl SamplingTree {
    /// [`sample`](SamplingTree::sample) of the product with `lobe`: the point, its density on
    /// the square, whether it may lie within rounding distance of its cell's border, and the
    /// centre of its cell.
    #[inline(always)]
    pub(super) fn sample_product(&self, lobe: &impl Lobe, u: Vec2) -> (Vec2, f32, bool, Vec2) {
        let u = Vec2::new(unit(u.x), unit(u.y));
        let start = Draw {
            a: Vec2::ZERO,
            w: Vec2::ONE,
            pdf: 1.0,
        };
        self.sample_product_from(lobe, u, start, Cursor::ROOT)
    }

    /// The product's descent of `sample_product` from the cursor `at` on, for `u` in `[0,1)²`.
    #[inline(always)]
    pub(super) fn sample_product_from(
        &self,
        lobe: &impl Lobe,
        u: Vec2,
        draw: Draw,
        mut at: Cursor,
    ) -> (Vec2, f32, bool, Vec2) {
        let Draw {
            mut a,
            mut w,
            mut pdf,
        } = draw;
        loop {
            let level = at.level(self, lobe);
            let m = level.w;
            // The column by its share of the total, then the cell by its share of the column;
            // every choice picks by bit masks, never by a jump.
            let col = [m[0] + m[2], m[1] + m[3]];
            let left = w.x * (col[0] * level.inv_total);
            let ix = choose(col[0], col[1], u.x, a.x + left);
            let (lower, upper) = (pick(ix, m[0], m[1]), pick(ix, m[2], m[3]));
            let column = pick(ix, col[0], col[1]);
            let low = w.y * (lower / column);
            let iy = choose(lower, upper, u.y, a.y + low);
            let q = ix | iy << 1;
            a += Vec2::new(pick(ix, 0.0, left), pick(iy, 0.0, low));
            w *= Vec2::new(column * level.inv_total, m[q] / column);
            pdf *= level.density_factor(q);
            if !at.enter(self, &level, lobe, (ix, iy)) {
                break;
            }
        }
        let (point, near_border) = place(u, a, w, at.cell, at.depth);
        (point, pdf, near_border, at.centre())
    }

    /// [`pdf`](SamplingTree::pdf) of the product with `lobe`, at `s ∈ [0,1)²`.
    #[inline(always)]
    pub(super) fn pdf_product(&self, lobe: &impl Lobe, s: Vec2) -> f32 {
        self.pdf_product_from(lobe, fixed(s), 1.0, Cursor::ROOT)
    }

    /// The product's density at the fixed-point point `p`, from the cursor `at` (reached with
    /// density `pdf`) on.
    #[inline(always)]
    pub(super) fn pdf_product_from(
        &self,
        lobe: &impl Lobe,
        p: [u32; 2],
        mut pdf: f32,
        mut at: Cursor,
    ) -> f32 {
        loop {
            let level = at.level(self, lobe);
            let (ix, iy) = quadrant_bits(p, at.depth + 1);
            pdf *= level.density_factor(ix | iy << 1);
            if pdf == 0.0 || !at.enter(self, &level, lobe, (ix, iy)) {
                return pdf;
            }
        }
    }
}

#[cfg(test)]
#[path = "product_tests.rs"]
pub(super) mod tests;
