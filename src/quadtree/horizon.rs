//! The sampling tree's product with a surface's clamped cosine: the density
//! `p(ω) ∝ p_guide(ω)·ĉ(ω)`, with `ĉ`, cell by cell, a smoothed `max(0, n·ω)`.
//!
//! A guide learned from every vertex in a spatial cell knows nothing of which way each surface
//! in it faces, and at a vertex its samples below the surface are wasted: the BSDF is zero
//! there. The product descends the guide's tree and, at every node, weighs each quadrant's
//! probability by an estimate of the cosine over the quadrant, then renormalizes. The density
//! is the product of the conditionals chosen on the way down, so `sample` and `pdf` agree
//! exactly whatever the estimate; the estimate only decides how closely the product follows
//! the cosine. The descent, shared with the phase function's product, is
//! [`super::product`]'s; this module gives it the cosine's estimate.
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
//! **Stored.** For a normal a spatial cell sees often, [`SurfaceTree`] holds the same
//! conditionals computed once, as a sampling tree descended like the plain guide's, to
//! [`STORED_DEPTH`] inside the guide's leaves; the few draws that end where the product would
//! still descend go on with the per-query descent from there.

#[cfg(test)]
use super::product::child_corner_range;
use super::product::{Cursor, Draw, Lobe};
use super::sampling::{Descent, place, unit};
use super::{FIXED_BITS, NO_CHILD, RESUME, SamplingNode, SamplingTree, fixed};
use glam::{Vec2, Vec3, Vec4};
use std::cell::RefCell;

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

/// The clamped cosine `max(0, n·ω)` about a unit normal, as a [`Lobe`]: `ĉ` of the module
/// comment, the descent ended on cells wholly below, settled where the corners' cosines stay
/// within [`SETTLED`], and leaves descended to [`HORIZON_DEPTH`] where the horizon crosses
/// them and to [`SURFACE_DEPTH`] where the cosine varies over them by more than a factor of
/// three. A cell whose corners are all below keeps its small weight whole: descending it would
/// multiply small conditionals level after level, toward densities `f32` cannot hold.
#[derive(Clone, Copy, Debug)]
pub(super) struct ClampedCosine(pub(super) Vec3);

impl Lobe for ClampedCosine {
    #[inline(always)]
    fn axis(&self) -> Vec3 {
        self.0
    }

    #[inline(always)]
    fn children(&self, lo: Vec4, hi: Vec4, _: [u32; 2], depth: u32) -> (Vec4, Vec4, Vec4) {
        (clamped_cosine(lo, hi, depth), lo, hi)
    }

    #[inline(always)]
    fn ends(&self, _: f32, hi: f32) -> bool {
        // Wholly below the horizon: the weight is the small positive one that keeps the
        // estimator unbiased, and the guide's shape within the cell does not matter.
        hi <= 0.0
    }

    #[inline(always)]
    fn settles(&self, lo: f32, hi: f32) -> bool {
        lo > 0.0 && hi <= SETTLED * lo
    }

    #[inline(always)]
    fn descends_inside(&self, lo: f32, hi: f32, depth: u32) -> bool {
        let crossed = lo < 0.0 && hi > 0.0;
        (crossed && depth < HORIZON_DEPTH) || (lo >= 0.0 && hi > 3.0 * lo && depth < SURFACE_DEPTH)
    }
}

impl SamplingTree {
    /// [`sample`](SamplingTree::sample) of the product with the clamped cosine about the unit
    /// normal `n`: the point, its density on the square, whether it may lie within rounding
    /// distance of its cell's border, and the centre of its cell.
    pub(crate) fn sample_surface(&self, n: Vec3, u: Vec2) -> (Vec2, f32, bool, Vec2) {
        self.sample_product(&ClampedCosine(n), u)
    }

    /// [`pdf`](SamplingTree::pdf) of the product with the clamped cosine about the unit
    /// normal `n`, at `s ∈ [0,1)²`.
    pub(crate) fn pdf_surface(&self, n: Vec3, s: Vec2) -> f32 {
        self.pdf_product(&ClampedCosine(n), s)
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

thread_local! {
    /// [`SurfaceTree::build`]'s working memory, kept per thread (`refine` builds the stored
    /// products of every spatial leaf on rayon's threads): the nodes, as many as the largest
    /// product the thread built had (at most [`MAX_SURFACE_NODES`], 2 MB), and the cells still
    /// to visit (a depth-first stack, a few per level).
    #[allow(clippy::type_complexity, reason = "two vectors, named where they are used")]
    static BUILD: RefCell<(Vec<SamplingNode>, Vec<(usize, Cursor)>)> =
        const { RefCell::new((Vec::new(), Vec::new())) };
}

/// At most this many nodes in a [`SurfaceTree`]; a guide too large for it gets none (the
/// per-query product serves its queries).
const MAX_SURFACE_NODES: usize = RESUME as usize;

impl SurfaceTree {
    /// The product of `guide` with the clamped cosine about the unit normal `n`; `None` if it
    /// would exceed the node limit.
    pub(crate) fn build(guide: &SamplingTree, n: Vec3) -> Option<Self> {
        BUILD.with_borrow_mut(|(nodes, open)| {
            let nodes = Self::nodes(guide, n, nodes, open)?;
            Some(Self {
                normal: n,
                tree: SamplingTree::new(nodes.into()),
            })
        })
    }

    /// The nodes of [`build`](Self::build), built in `nodes` (`open` is working memory).
    fn nodes<'a>(
        guide: &SamplingTree,
        n: Vec3,
        nodes: &'a mut Vec<SamplingNode>,
        open: &mut Vec<(usize, Cursor)>,
    ) -> Option<&'a [SamplingNode]> {
        nodes.clear();
        nodes.push(SamplingNode::UNIFORM);
        open.clear();
        open.push((0, Cursor::ROOT));
        let lobe = ClampedCosine(n);
        while let Some((i, at)) = open.pop() {
            let level = at.level(guide, &lobe);
            let mut child = [NO_CHILD; 4];
            for (q, slot) in child.iter_mut().enumerate() {
                let mut next = at;
                if !next.enter(guide, &level, &lobe, (q & 1, q >> 1)) {
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
        Some(nodes)
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
        self.tree
            .sample_product_from(&ClampedCosine(self.normal), d.u, draw, at)
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
        self.tree
            .pdf_product_from(&ClampedCosine(self.normal), p, pdf, at)
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
