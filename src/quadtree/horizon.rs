//! The sampling tree's product with a surface's clamped cosine: the density
//! `p(ω) ∝ p_guide(ω)·ĉ(ω)`, with `ĉ`, cell by cell, a smoothed `max(0, n·ω)`.
//!
//! A guide learned from every vertex in a spatial cell knows nothing of which way each surface
//! in it faces, and at a vertex its samples below the surface are wasted: the BSDF is zero
//! there. The product descends the guide's tree and, at every node, weighs each quadrant's
//! probability by an estimate of the cosine over the quadrant, then renormalizes. The density
//! is the product of the conditionals chosen on the way down, so `sample` and `pdf` agree
//! exactly whatever the estimate; the estimate only decides how closely the product follows
//! the cosine.
//!
//! **The estimate.** For each child the descent evaluates `n·ω` at the child's four corners
//! (the 3 × 3 grid over the node, four points at a time) and takes their range `[lo, hi]`;
//! the estimate is the mean of `max(0, x)` for `x` uniform on it:
//!
//! ```text
//!   ĉ = (lo + hi)/2           lo ≥ 0        (the corners all above)
//!     = hi²/(2·(hi − lo))     lo < 0 < hi   (the horizon crosses the cell)
//!     = 10⁻⁵·ramp(hi, 2·r_d)  hi ≤ 0        (the corners all below)
//! ```
//!
//! The last line keeps the estimator unbiased: every direction of a cell at depth `d` lies
//! within chord distance `r_d = 4.5·2^-d` of the cell's centre (measured: at most `4.27·2^-d`;
//! a test checks the bound to depth 10), so within `2·r_d` of each corner, and a cell may hold
//! a direction above the horizon only if `hi > −2·r_d`. `ramp(t, r)`, the mean of `max(0, x)`
//! over `[t − r, t + r]`, is positive exactly then. So the product's density is positive
//! wherever `n·ω > 0`, and zero only on cells wholly below; cells whose corners are all below
//! keep a weight 10⁵ times smaller than the cosine would give them, so almost nothing is drawn
//! there.
//!
//! **Below the guide's leaves.** A leaf the horizon crosses is descended further, as if split
//! into four quadrants of equal guide probability, down to [`HORIZON_DEPTH`]; one over whose
//! corners the cosine varies by more than a factor of three, down to [`SURFACE_DEPTH`]. So what
//! is left below the horizon lies within a hair of it, and the cosine is followed inside
//! coarse leaves too. A cell whose corners are all below ends the descent, even inside the
//! guide's tree.
//!
//! **Where the cosine settles.** Once the descent enters a cell whose corners are all above the
//! horizon and within a factor [`SETTLED`] of each other, the levels below follow the guide's
//! own conditionals: the cosine would reweigh them by less than that factor, and they then cost
//! what the plain descent costs. Whether a cell has settled depends only on the cell and the
//! normal, so `sample` and `pdf` switch at the same place.
//!
//! **What a level costs.** The levels form a chain: each level's corners depend on the quadrant
//! the level above chose. The children's corners of cells above [`TABLE_DEPTH`] (where almost
//! every descent spends its levels) are looked up in one table shared by every tree, laid out
//! so that a level's sixteen corner cosines are twelve vector multiply-adds, instead of mapped;
//! and the level keeps its quadrants' weights unnormalized, with one reciprocal of their total
//! (docs/performance.md measures both). The descent's choices are bit masks, never jumps (a
//! random choice is a coin flip that a branch predictor misses half the time), and the level is
//! computed inline in the descent. What is left is the chain itself: each level waits for the
//! one above.
//!
//! **Stored.** For a normal a spatial cell sees often, [`SurfaceTree`] holds the same
//! conditionals computed once, as a sampling tree descended like the plain guide's, to
//! [`STORED_DEPTH`] inside the guide's leaves; the few draws that end where the product would
//! still descend go on with the per-query descent from there.

use super::sampling::{Descent, pick, place, unit};
use super::{FIXED_BITS, NO_CHILD, RESUME, SamplingNode, SamplingTree, fixed, quadrant_bits};
use crate::sphere::square_to_direction;
use glam::{Vec2, Vec3, Vec4};
use std::f32::consts::FRAC_PI_4;
use std::sync::LazyLock;

/// How deep the product follows the cosine inside the guide's leaves where the horizon does not
/// cross them (cells at this depth have chord radius 0.018).
pub(crate) const SURFACE_DEPTH: u32 = 8;

/// How deep the product descends into cells the horizon may cross: their chord radius is
/// 7·10⁻⁵, and their side (1.5·10⁻⁵) still fifteen times the map's round-trip error, so a
/// point at a cell's centre comes back to it.
pub(crate) const HORIZON_DEPTH: u32 = 16;

/// Where the cosine over a cell's corners varies by at most this factor (and stays above the
/// horizon), the product stops weighing the cell's descendants: over such a cell the cosine
/// changes the guide's density by less than this, and the levels below cost what the plain
/// descent costs.
const SETTLED: f32 = 1.25;

/// `r_d·2^d`: the bound on the chord from a cell's centre direction to any of its directions.
const CHORD_PER_SIDE: f32 = 4.5;

/// Added to every chord radius: what the polynomial map of [`child_cosines`] and the rounding
/// of `n·c` may move `t` by (a few 10⁻⁷), with room.
const COSINE_ERROR: f32 = 4e-6;

/// The chord radius of a cell at `depth`: `min(2, 4.5·2^-depth)`, plus the estimate's error.
#[inline]
fn chord_radius(depth: u32) -> f32 {
    // 2^-depth from exponent bits (depth ≤ 24 + a few: a normal f32).
    let side = f32::from_bits((127 - depth) << 23);
    (CHORD_PER_SIDE * side).min(2.0) + COSINE_ERROR
}

/// The weight of a cell whose corners are all below the horizon but which may still reach
/// above it between them, relative to the ramp of twice its chord radius: such a cell holds
/// almost none of the cosine's integral, but must keep a positive weight.
const CORNER_WEIGHT: f32 = 1.0e-5;

/// The ramp's mean: `max(0, x)` averaged over `x` uniform on `[t − r, t + r]`.
#[inline]
fn ramp(t: Vec4, r: f32) -> Vec4 {
    let crossing = (t + r) * (t + r) * (0.25 / r);
    let above = t.cmpge(Vec4::splat(r));
    let below = t.cmple(Vec4::splat(-r));
    Vec4::select(below, Vec4::ZERO, Vec4::select(above, t, crossing))
}

/// `ĉ` of the module comment, lane by lane, for cells at `depth` whose corners' cosines range
/// over `[lo, hi]`.
#[inline]
fn clamped_cosine(lo: Vec4, hi: Vec4, depth: u32) -> Vec4 {
    let zero = Vec4::ZERO;
    let above = (lo + hi) * 0.5;
    let crossing = hi * hi / (2.0 * (hi - lo)).max(Vec4::splat(f32::MIN_POSITIVE));
    let corners = ramp(hi, 2.0 * chord_radius(depth)) * CORNER_WEIGHT;
    Vec4::select(
        lo.cmpge(zero),
        above,
        Vec4::select(hi.cmpgt(zero), crossing, corners),
    )
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
const TABLE_DEPTH: u32 = 6;

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
fn child_corner_range(n: Vec3, cell: [u32; 2], depth: u32) -> (Vec4, Vec4) {
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
/// the estimate of the cosine), the reciprocal of their total, and the range of the cosine over
/// each child's corners. The product's conditionals are the weights over their total; sample
/// and pdf both take a quadrant's density factor as `4·w_q·(1/total)`, so they multiply the
/// same factors. Arrays, not vectors: the descent picks lanes by the quadrant it chose, and an
/// array is indexed by a load where a vector's lane is picked by a jump on the index, which
/// random choices mispredict.
struct Level {
    w: [f32; 4],
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
    fn new(guide: &SamplingNode, n: Vec3, cell: [u32; 2], depth: u32) -> Self {
        let (lo, hi) = child_corner_range(n, cell, depth);
        let p = guide.quadrants();
        let w = p * clamped_cosine(lo, hi, depth + 1);
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

    /// The guide's own probabilities, below a cell where the cosine has settled. The corner
    /// range it reports, `[1, 1]`, keeps the descent going exactly where the guide's tree does.
    #[inline]
    fn settled(guide: &SamplingNode) -> Self {
        Self::of(guide.quadrants(), Vec4::ONE, Vec4::ONE)
    }

    /// `4·P(q)`: sample and pdf multiply the same factors.
    #[inline]
    fn density_factor(&self, q: usize) -> f32 {
        4.0 * self.w[q] * self.inv_total
    }

    /// Whether the child `q`, a leaf of the guide's tree at `depth`, is descended further:
    /// to [`HORIZON_DEPTH`] if the horizon crosses it between its corners, to
    /// [`SURFACE_DEPTH`] if the cosine varies over its corners by more than a factor of three.
    /// A cell whose corners are all below keeps its small weight whole: descending it would
    /// multiply small conditionals level after level, toward densities `f32` cannot hold.
    #[inline]
    fn descend_inside(&self, q: usize, depth: u32) -> bool {
        let (lo, hi) = (self.lo[q], self.hi[q]);
        let crossed = lo < 0.0 && hi > 0.0;
        (crossed && depth < HORIZON_DEPTH) || (lo >= 0.0 && hi > 3.0 * lo && depth < SURFACE_DEPTH)
    }
}

/// Where a descent stands: the guide's node (or none, inside one of its leaves), the cell and
/// its depth, and whether the cosine has settled there.
#[derive(Clone, Copy)]
struct Cursor {
    node: Option<usize>,
    cell: [u32; 2],
    depth: u32,
    /// The cell's corners are all above the horizon and their cosines within [`SETTLED`] of
    /// each other: below it the product follows the guide's own conditionals.
    settled: bool,
}

impl Cursor {
    const ROOT: Cursor = Cursor {
        node: Some(0),
        cell: [0, 0],
        depth: 0,
        settled: false,
    };

    /// The cursor at `cell` of `depth` inside one of the guide's leaves, where the cosine has
    /// not settled: where a stored product's descent resumes per query.
    #[inline]
    fn inside(cell: [u32; 2], depth: u32) -> Cursor {
        Cursor {
            node: None,
            cell,
            depth,
            settled: false,
        }
    }

    /// The centre of the cursor's cell on the square.
    #[inline]
    fn centre(&self) -> Vec2 {
        let size = f32::from_bits((127 - self.depth) << 23);
        (Vec2::new(self.cell[0] as f32, self.cell[1] as f32) + 0.5) * size
    }

    /// The level at the cursor's node.
    #[inline(always)]
    fn level(&self, tree: &SamplingTree, n: Vec3) -> Level {
        let guide = match self.node {
            Some(i) => tree.node(i),
            None => &SamplingNode::UNIFORM,
        };
        if self.settled {
            return Level::settled(guide);
        }
        Level::new(guide, n, self.cell, self.depth)
    }

    /// Moves into quadrant `(ix, iy)`; `false` when the descent ends there.
    #[inline]
    fn enter(&mut self, tree: &SamplingTree, level: &Level, ix: usize, iy: usize) -> bool {
        let q = ix | iy << 1;
        self.cell = [2 * self.cell[0] + ix as u32, 2 * self.cell[1] + iy as u32];
        self.depth += 1;
        // A cell whose corners are all below the horizon ends the descent even inside the
        // guide's tree: its weight is the small positive one that keeps the estimator
        // unbiased, and the guide's shape within it does not matter.
        let (lo, hi) = (level.lo[q], level.hi[q]);
        if hi <= 0.0 {
            return false;
        }
        self.settled |= lo > 0.0 && hi <= SETTLED * lo;
        self.node = self
            .node
            .map(|i| tree.node(i).child[q])
            .filter(|&c| c != NO_CHILD)
            .map(usize::from);
        self.node.is_some() || level.descend_inside(q, self.depth)
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
struct Draw {
    a: Vec2,
    w: Vec2,
    pdf: f32,
}

impl SamplingTree {
    /// [`sample`](SamplingTree::sample) of the product with the clamped cosine about the unit
    /// normal `n`: the point, its density on the square, whether it may lie within rounding
    /// distance of its cell's border, and the centre of its cell.
    pub(crate) fn sample_surface(&self, n: Vec3, u: Vec2) -> (Vec2, f32, bool, Vec2) {
        let u = Vec2::new(unit(u.x), unit(u.y));
        let start = Draw {
            a: Vec2::ZERO,
            w: Vec2::ONE,
            pdf: 1.0,
        };
        self.sample_surface_from(n, u, start, Cursor::ROOT)
    }

    /// The product's descent of `sample_surface` from the cursor `at` on, for `u` in `[0,1)²`.
    #[inline(always)]
    fn sample_surface_from(
        &self,
        n: Vec3,
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
            let level = at.level(self, n);
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
            if !at.enter(self, &level, ix, iy) {
                break;
            }
        }
        let (point, near_border) = place(u, a, w, at.cell, at.depth);
        (point, pdf, near_border, at.centre())
    }

    /// [`pdf`](SamplingTree::pdf) of the product with the clamped cosine about the unit
    /// normal `n`, at `s ∈ [0,1)²`.
    pub(crate) fn pdf_surface(&self, n: Vec3, s: Vec2) -> f32 {
        self.pdf_surface_from(n, fixed(s), 1.0, Cursor::ROOT)
    }

    /// The product's density at the fixed-point point `p`, from the cursor `at` (reached with
    /// density `pdf`) on.
    #[inline(always)]
    fn pdf_surface_from(&self, n: Vec3, p: [u32; 2], mut pdf: f32, mut at: Cursor) -> f32 {
        loop {
            let level = at.level(self, n);
            let (ix, iy) = quadrant_bits(p, at.depth + 1);
            pdf *= level.density_factor(ix | iy << 1);
            if pdf == 0.0 || !at.enter(self, &level, ix, iy) {
                return pdf;
            }
        }
    }
}

/// How deep a [`SurfaceTree`] holds the product inside the guide's leaves. Below, a cell the
/// product would still descend (the horizon crosses it, or the cosine varies over it by more
/// than a factor of three: a few percent of the draws) is a [`RESUME`] leaf, and the query goes
/// on there per query. Deeper would hold more of those descents but cost memory: the cells the
/// horizon crosses double with every level.
pub(crate) const STORED_DEPTH: u32 = 5;

/// The product with the clamped cosine about one normal, computed once for a spatial leaf's
/// guide and stored as a sampling tree of its own: the nodes of the guide's tree and of the
/// cells the product descends inside its leaves down to [`STORED_DEPTH`], each with the
/// product's conditionals (the weights of [`Level`] over their total). A query with that normal
/// descends it as the plain guide is descended; where it ends on a [`RESUME`] leaf it goes on
/// with the per-query product from there. The density is the product of the conditionals
/// chosen, as for the per-query product, so `sample` and `pdf` agree exactly; and the
/// conditionals are the per-query product's to `f32` rounding, so it is the same distribution.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct SurfaceTree {
    /// The unit normal (as [`crate::sphere::normalize`] returns it).
    pub(crate) normal: Vec3,
    tree: SamplingTree,
}

/// At most this many nodes in a [`SurfaceTree`]; a guide too large for it gets none (the
/// per-query product serves its queries).
const MAX_SURFACE_NODES: usize = RESUME as usize;

impl SurfaceTree {
    /// The product of `guide` with the clamped cosine about the unit normal `n`; `None` if it
    /// would exceed the node limit.
    pub(crate) fn build(guide: &SamplingTree, n: Vec3) -> Option<Self> {
        let mut nodes = vec![SamplingNode::UNIFORM];
        let mut open = vec![(0usize, Cursor::ROOT)];
        while let Some((i, at)) = open.pop() {
            let level = at.level(guide, n);
            let mut child = [NO_CHILD; 4];
            for (q, slot) in child.iter_mut().enumerate() {
                let mut next = at;
                if !next.enter(guide, &level, q & 1, q >> 1) {
                    continue;
                }
                if next.node.is_none() && !next.settled && next.depth >= STORED_DEPTH {
                    *slot = RESUME;
                    continue;
                }
                if nodes.len() >= MAX_SURFACE_NODES {
                    return None;
                }
                *slot = nodes.len() as u16;
                nodes.push(SamplingNode::UNIFORM);
                open.push((nodes.len() - 1, next));
            }
            nodes[i] = SamplingNode::from_masses(level.w.map(f64::from), child);
        }
        Some(Self {
            normal: n,
            tree: SamplingTree::new(nodes.into_boxed_slice()),
        })
    }

    /// [`SamplingTree::sample_surface`] for this normal, through the stored product.
    #[inline]
    pub(crate) fn sample(&self, u: Vec2) -> (Vec2, f32, bool, Vec2) {
        let u = Vec2::new(unit(u.x), unit(u.y));
        let d = self.tree.descend::<true>(u);
        let at = Cursor::inside(d.cell, d.depth);
        if d.resume {
            return self.sample_resumed(d, at);
        }
        let (point, near_border) = place(d.u, d.a, d.w, d.cell, d.depth);
        (point, d.pdf, near_border, at.centre())
    }

    /// The rest of a draw that reached a [`RESUME`] leaf: the per-query product below it.
    /// (Inside the guide's leaf, so the guide's tree is not read.)
    #[cold]
    #[inline(never)]
    fn sample_resumed(&self, d: Descent, at: Cursor) -> (Vec2, f32, bool, Vec2) {
        let draw = Draw {
            a: d.a,
            w: d.w,
            pdf: d.pdf,
        };
        self.tree.sample_surface_from(self.normal, d.u, draw, at)
    }

    /// [`SamplingTree::pdf_surface`] for this normal, through the stored product.
    #[inline]
    pub(crate) fn pdf(&self, s: Vec2) -> f32 {
        let p = fixed(s);
        let (pdf, depth, resume) = self.tree.pdf_descend::<true>(p);
        if resume && pdf > 0.0 {
            return self.pdf_resumed(p, pdf, depth);
        }
        pdf
    }

    #[cold]
    #[inline(never)]
    fn pdf_resumed(&self, p: [u32; 2], pdf: f32, depth: u32) -> f32 {
        let shift = FIXED_BITS - depth;
        let at = Cursor::inside([p[0] >> shift, p[1] >> shift], depth);
        self.tree.pdf_surface_from(self.normal, p, pdf, at)
    }

    /// The nodes stored.
    pub(crate) fn node_count(&self) -> usize {
        self.tree.node_count()
    }

    /// Bytes held.
    pub(crate) fn bytes(&self) -> usize {
        self.tree.bytes()
    }
}

#[cfg(test)]
#[path = "horizon_tests.rs"]
mod tests;
