//! When a spatial leaf splits: by its sample count (the SD-tree's rule), or by what a split
//! would gain — whether the leaf's halves see different light.
//!
//! **The cost of a cell.** Take a spatial cell `C` and a partition of the square into `J`
//! directional bins of areas `a_j`. `S_j` is the sum of `v²/p` over the cell's samples in bin
//! `j` (`n` samples in all). The l2-optimal piecewise-constant guide on those bins (the paper's
//! l2 rule applied to the bins) gives the one-sample estimator the second moment
//! `(Σ_j sqrt(a_j·S_j))² / n`. Over a leaf whose samples fall into children `L` and `R`, the
//! second moment averaged over the leaf's vertices is, with one guide for the whole leaf,
//! `V(C) / n` with the cost `V(C) = (Σ_j sqrt(a_j·(S_j(L) + S_j(R))))²`, and with a guide per
//! child `(V(L) + V(R)) / n`. By the triangle inequality `V(L) + V(R) ≤ V(C)`, with equality
//! exactly when the children's directional distributions are proportional: the split gains
//! `V(C) − V(L) − V(R)`, which is zero where the light does not change across the split and
//! large where it does.
//!
//! **What a leaf records** under [`SpatialSplit::Gain`]: its own samples' `v²/p` by direction
//! (`J` = 16 [`Bins`], fine where the leaf's guide is concentrated) and by which of the 8 cells
//! of its next three levels they fell in (one split per axis, in the tree's x → y → z order),
//! and each cell's count; exact sums, so the decision is deterministic. Since the triangle
//! inequality makes any split gain on noisy sums, a null split measures the noise: the same
//! bins over the leaf's samples grouped by a bit of their position far below any cell (the
//! lowest bit of the fixed-point coordinates), which sorts samples into two groups that see
//! the same light.
//! Its relative gain `g₀` is what noise alone gains on `n/2` samples per side; on a cell of
//! `m` samples noise gains about `g₀·n/m` (the bias of a square root of a sum falls as `1/m`).
//!
//! **The decision** ([`SplitPlan`]): over the three recorded levels, bottom up, a cell's best
//! cost is `B(C) = min(V(C), B(L) + B(R) + (g₀·n/m_C + τ)·V(C))` — a split must pay the noise
//! it would fit and the relative threshold `τ`
//! ([`spatial_gain_threshold`](crate::GuidingConfig::spatial_gain_threshold)), and its cell
//! must have seen at least a quarter of the count rule's threshold. A cell splits where its
//! best cost is a split; so a leaf whose light changes only along z splits x and y first,
//! because the z splits below them pay for the three levels. Below the recorded levels a
//! split cell's children go on splitting by count, as under [`SpatialSplit::Count`].

use crate::config::GuidingConfig;
use crate::exact::{AtomicSum, Sum};
use crate::quadtree::{NO_CHILD, SamplingTree};
use glam::Vec2;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};

/// How refinement decides which spatial leaves split.
///
/// ```
/// use sdguide::{GuidingConfig, SpatialSplit};
/// let config = GuidingConfig { spatial_split: SpatialSplit::Gain, ..GuidingConfig::default() };
/// assert!(config.validate().is_ok());
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[non_exhaustive]
pub enum SpatialSplit {
    /// The SD-tree's rule: a leaf that received more than
    /// [`spatial_threshold`](crate::GuidingConfig::spatial_threshold)` · sqrt(2^k)` samples in
    /// iteration `k` splits, and its children again while half the count still exceeds it.
    #[default]
    Count,
    /// A leaf splits where its halves' directional distributions differ enough to lower the
    /// estimator's second moment by more than
    /// [`spatial_gain_threshold`](crate::GuidingConfig::spatial_gain_threshold) of it beyond
    /// what noise gains, up to three levels per refine (see the module documentation), given a
    /// quarter of the count rule's samples. Each leaf keeps 144 more exact sums (about 2.4 KB).
    Gain,
}

/// The count rule's threshold at the end of iteration `k`: `c·sqrt(2^k)`.
pub(crate) fn count_threshold(config: &GuidingConfig, k: u32) -> f64 {
    f64::from(config.spatial_threshold) * 2f64.powf(0.5 * f64::from(k))
}

/// Directional bins of a signature: the leaves of a 16-leaf quadtree (five splits).
const BINS: usize = 16;
/// Interior nodes of the bins' quadtree.
const BIN_SPLITS: usize = (BINS - 1) / 3;
/// A bin's entry in [`Bins::nodes`]: this bit and the bin's index.
const BIN_BIT: u8 = 0x80;
/// Spatial levels a signature resolves below its leaf.
pub(crate) const LEVELS: u32 = 3;
/// Cells of the last resolved level.
pub(crate) const CELLS: usize = 1 << LEVELS;
/// Slots of a plan: the leaf is slot 1, slot `s` splits into `2s` and `2s + 1`; the resolved
/// cells are slots `CELLS..2·CELLS`.
pub(crate) const SLOTS: usize = 2 * CELLS;
/// The fraction of the count rule's threshold a cell must have seen to split by gain.
pub(crate) const FLOOR_FRACTION: f64 = 0.25;

/// Exact sums per signature: the cells' bins, then the null group's.
pub(crate) const SIGNATURE_SUMS: usize = (CELLS + 1) * BINS;
/// Counts per signature: the cells', then the null group's.
pub(crate) const SIGNATURE_COUNTS: usize = CELLS + 1;

/// The bytes of a [`SplitSignature`].
pub(crate) const SIGNATURE_BYTES: u64 =
    (SIGNATURE_SUMS * size_of::<AtomicSum>() + size_of::<SplitSignature>()) as u64;

/// What a spatial leaf records for splits by gain (see the module documentation).
#[derive(Debug)]
pub(crate) struct SplitSignature {
    /// The directional bins of the iteration.
    bins: Bins,
    /// `Σ v²/p` by cell (`cell·BINS + bin`), then the null group's by bin.
    sums: Box<[AtomicSum]>,
    /// Samples by cell, then the null group's.
    counts: [AtomicU64; SIGNATURE_COUNTS],
}

/// A snapshot of a [`SplitSignature`]'s sums, exact.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct SignatureSums {
    pub sums: Vec<Sum>,
    pub counts: [u64; SIGNATURE_COUNTS],
}

impl Default for SignatureSums {
    fn default() -> Self {
        Self {
            sums: vec![Sum::ZERO; SIGNATURE_SUMS],
            counts: [0; SIGNATURE_COUNTS],
        }
    }
}

impl Clone for SplitSignature {
    fn clone(&self) -> Self {
        Self::new(self.bins, &self.get())
    }
}

/// The directional bins of a signature: a quadtree of [`BINS`] leaves cut from the region's
/// sampling tree by splitting, five times, the cell of largest mass (below the sampling
/// tree's leaves, a leaf's mass spreads evenly). Fine where the guide is concentrated, so
/// that a sharp lobe whose direction moves across a leaf shows in the bins; a uniform guide
/// gives the 4 × 4 grid. A function of the sampling tree alone, so workers that start an
/// iteration from the same field bin alike.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Bins {
    /// Per interior node and quadrant: the child node, or `BIN_BIT | bin`.
    nodes: [[u8; 4]; BIN_SPLITS],
    /// Per bin, its depth: its area is `4^-depth`.
    depth: [u8; BINS],
}

impl Bins {
    /// The bins of `tree`.
    pub(crate) fn of(tree: &SamplingTree) -> Self {
        let nodes = tree.nodes();
        // Open cells: (mass, the sampling node at the cell if the tree goes that deep, the
        // interior node and quadrant that hold it, depth).
        let children = |mass: f64, at: Option<usize>, parent: usize, depth: u8| {
            (0..4).map(move |q| {
                let (m, below) = match at {
                    Some(i) => {
                        let n = &nodes[i];
                        let p = f64::from(n.px[q & 1]) * f64::from(n.py[q & 1][q >> 1]);
                        let c = usize::from(n.child[q]);
                        (
                            mass * p,
                            (c != usize::from(NO_CHILD) && c < nodes.len()).then_some(c),
                        )
                    }
                    None => (0.25 * mass, None),
                };
                (m, below, parent, q, depth + 1)
            })
        };
        let mut bins = Bins {
            nodes: [[0; 4]; BIN_SPLITS],
            depth: [0; BINS],
        };
        let mut open: Vec<_> = children(1.0, Some(0), 0, 0).collect();
        for split in 1..BIN_SPLITS {
            // The first open cell of largest mass.
            let k = (0..open.len())
                .reduce(|a, b| if open[b].0 > open[a].0 { b } else { a })
                .unwrap_or(0);
            let (mass, at, parent, q, depth) = open.remove(k);
            bins.nodes[parent][q] = split as u8;
            open.extend(children(mass, at, split, depth));
        }
        for (bin, &(_, _, parent, q, depth)) in open.iter().enumerate() {
            bins.nodes[parent][q] = BIN_BIT | bin as u8;
            bins.depth[bin] = depth;
        }
        bins
    }

    /// The bin of a point of the square.
    #[inline]
    fn bin(&self, square: Vec2) -> usize {
        let mut p = square.clamp(Vec2::ZERO, Vec2::ONE);
        let mut node = 0;
        loop {
            let (ix, iy) = (usize::from(p.x >= 0.5), usize::from(p.y >= 0.5));
            let entry = self.nodes[node][ix + 2 * iy];
            if entry & BIN_BIT != 0 {
                return usize::from(entry & !BIN_BIT);
            }
            // Exact: doubling and subtracting 1 from a float in [0.5, 1).
            p = 2.0 * p - Vec2::new(ix as f32, iy as f32);
            node = usize::from(entry);
        }
    }

    /// The area of bin `b`, as a fraction of the square.
    fn area(&self, b: usize) -> f64 {
        0.25f64.powi(i32::from(self.depth[b]))
    }
}

impl SplitSignature {
    /// A signature over `bins` that holds the sums `s`.
    pub(crate) fn new(bins: Bins, s: &SignatureSums) -> Self {
        Self {
            bins,
            sums: s.sums.iter().map(|x| AtomicSum::new(x.units())).collect(),
            counts: s.counts.map(AtomicU64::new),
        }
    }

    /// Records a sample of second-moment weight `w2` at `square`, in resolved cell `cell`
    /// (`0..CELLS`, in slot order) and null group `group`.
    #[inline]
    pub(crate) fn record(&self, cell: usize, group: bool, square: Vec2, w2: f64) {
        let b = self.bins.bin(square);
        self.sums[cell * BINS + b].add(w2);
        self.counts[cell].fetch_add(1, Relaxed);
        if group {
            self.sums[CELLS * BINS + b].add(w2);
            self.counts[CELLS].fetch_add(1, Relaxed);
        }
    }

    /// The bins.
    pub(crate) fn bins(&self) -> &Bins {
        &self.bins
    }

    /// The sums, exact.
    pub(crate) fn get(&self) -> SignatureSums {
        SignatureSums {
            sums: self.sums.iter().map(|s| Sum::from_units(s.raw())).collect(),
            counts: std::array::from_fn(|i| self.counts[i].load(Relaxed)),
        }
    }

    /// Adds another leaf's sums (a merge), exactly.
    pub(crate) fn add(&mut self, other: &SignatureSums) {
        let mut s = self.get();
        s.add(other);
        *self = Self::new(self.bins, &s);
    }

    /// Starts the next iteration's sums, over `bins`.
    pub(crate) fn restart(&mut self, bins: Bins) {
        *self = Self::new(bins, &SignatureSums::default());
    }

    /// The heap bytes of the signature.
    pub(crate) fn bytes(&self) -> usize {
        SIGNATURE_BYTES as usize
    }
}

impl SignatureSums {
    /// Adds `other`, exactly (saturating).
    pub(crate) fn add(&mut self, other: &SignatureSums) {
        for (a, &b) in self.sums.iter_mut().zip(&other.sums) {
            *a = a.plus(b);
        }
        for (a, &b) in self.counts.iter_mut().zip(&other.counts) {
            *a = a.saturating_add(b);
        }
    }

    /// The plan these sums give, with the count rule's `threshold` for the iteration and the
    /// relative gain threshold `tau`.
    pub(crate) fn plan(&self, binning: &Bins, threshold: f64, tau: f64) -> SplitPlan {
        // Per slot: counts and bins, summed up from the resolved cells.
        let mut counts = [0u64; SLOTS];
        let mut bins = [[0f64; BINS]; SLOTS];
        for c in 0..CELLS {
            counts[CELLS + c] = self.counts[c];
            for (b, x) in bins[CELLS + c].iter_mut().enumerate() {
                *x = self.sums[c * BINS + b].value();
            }
        }
        for s in (1..CELLS).rev() {
            counts[s] = counts[2 * s].saturating_add(counts[2 * s + 1]);
            bins[s] = std::array::from_fn(|b| bins[2 * s][b] + bins[2 * s + 1][b]);
        }
        let area: [f64; BINS] = std::array::from_fn(|b| binning.area(b));
        let cost = |b: &[f64; BINS]| {
            b.iter()
                .zip(&area)
                .map(|(x, a)| (x * a).sqrt())
                .sum::<f64>()
                .powi(2)
        };
        let n = counts[1];
        let null: [f64; BINS] = std::array::from_fn(|b| self.sums[CELLS * BINS + b].value());
        let rest: [f64; BINS] = std::array::from_fn(|b| (bins[1][b] - null[b]).max(0.0));
        let whole = cost(&bins[1]);
        let noise: f64 = if whole > 0.0 {
            (1.0 - (cost(&null) + cost(&rest)) / whole).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let floor = FLOOR_FRACTION * threshold;
        let mut best = [0f64; SLOTS];
        let mut splits = 0u8;
        for s in (1..SLOTS).rev() {
            let v = cost(&bins[s]);
            best[s] = v;
            if s >= CELLS || v <= 0.0 || (counts[s] as f64) < floor {
                continue;
            }
            let penalty = (noise * n as f64 / counts[s] as f64 + tau) * v;
            let split = best[2 * s] + best[2 * s + 1] + penalty;
            if split < v {
                best[s] = split;
                splits |= 1 << s;
            }
        }
        SplitPlan { counts, splits }
    }
}

/// Which of a leaf's first three levels of cells split, and their counts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct SplitPlan {
    /// Samples per slot (slot 1: the leaf).
    pub counts: [u64; SLOTS],
    /// Bit `s`: slot `s` (in `1..CELLS`) splits.
    pub splits: u8,
}

impl SplitPlan {
    /// The count rule's plan for a leaf of `count` samples: a slot splits when its count (half
    /// its parent's) exceeds `threshold`.
    pub(crate) fn by_count(count: u64, threshold: f64) -> Self {
        let mut counts = [0u64; SLOTS];
        counts[1] = count;
        let mut splits = 0u8;
        for s in 1..CELLS {
            if counts[s] as f64 > threshold {
                splits |= 1 << s;
            }
            counts[2 * s] = counts[s] / 2;
            counts[2 * s + 1] = counts[s] - counts[s] / 2;
        }
        Self { counts, splits }
    }

    /// Whether slot `s` splits: by the plan in the resolved levels, by `count > threshold`
    /// below them.
    pub(crate) fn splits(&self, s: usize, count: u64, threshold: f64) -> bool {
        if s < CELLS {
            self.splits & (1 << s) != 0
        } else {
            count as f64 > threshold
        }
    }

    /// The counts of slot `s`'s children (`count`: the slot's own, for slots below the
    /// resolved levels).
    pub(crate) fn children(&self, s: usize, count: u64) -> (u64, u64) {
        if s < CELLS {
            (self.counts[2 * s], self.counts[2 * s + 1])
        } else {
            (count / 2, count - count / 2)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quadtree::SamplingNode;

    /// The bins of the uniform guide.
    fn uniform() -> Bins {
        Bins::of(&SamplingTree::uniform())
    }

    #[test]
    fn a_uniform_guide_bins_the_four_by_four_grid() {
        let bins = uniform();
        assert_eq!(bins.depth, [2; BINS]);
        let mut seen = [0; BINS];
        for y in 0..4 {
            for x in 0..4 {
                let b = bins.bin(Vec2::new(x as f32 + 0.5, y as f32 + 0.5) / 4.0);
                seen[b] += 1;
                // Every point of the cell, its corners included, is in the same bin.
                for (dx, dy) in [(0.0, 0.0), (0.999, 0.0), (0.0, 0.999), (0.999, 0.999)] {
                    let s = Vec2::new(x as f32 + dx, y as f32 + dy) / 4.0;
                    assert_eq!(bins.bin(s), b);
                }
            }
        }
        assert_eq!(seen, [1; BINS]);
    }

    #[test]
    fn a_concentrated_guide_bins_finely_where_its_mass_is() {
        // All but 1% of the mass in the lowest quadrant, all the way down.
        let node = |child| SamplingNode {
            px: [0.99, 0.01],
            py: [[0.99, 0.01], [0.5, 0.5]],
            child: [child, 0, 0, 0],
        };
        let tree = SamplingTree::new(Box::new([node(1), node(2), node(3), node(4), node(0)]));
        let bins = Bins::of(&tree);
        // Five splits, each of the corner cell: bins down to depth 5 there.
        assert_eq!(bins.depth.iter().max(), Some(&5));
        let area: f64 = (0..BINS).map(|b| bins.area(b)).sum();
        assert_eq!(area, 1.0);
        assert_ne!(bins.bin(Vec2::splat(0.01)), bins.bin(Vec2::splat(0.04)));
    }

    /// A signature with `per` samples of weight `w(cell, bin)` in every cell and bin, half of
    /// them in the null group.
    fn signature(per: u64, w: impl Fn(usize, usize) -> f64) -> SignatureSums {
        let sig = SplitSignature::new(uniform(), &SignatureSums::default());
        for cell in 0..CELLS {
            for b in 0..BINS {
                let square = Vec2::new((b % 4) as f32 + 0.5, (b / 4) as f32 + 0.5) / 4.0;
                for i in 0..per {
                    sig.record(cell, i % 2 == 0, square, w(cell, b));
                }
            }
        }
        sig.get()
    }

    #[test]
    fn light_that_does_not_change_does_not_split() {
        let s = signature(200, |_, b| 1.0 + b as f64);
        let plan = s.plan(&uniform(), 100.0, 0.01);
        assert_eq!(plan.splits, 0);
        assert_eq!(plan.counts[1], 200 * 16 * 8);
    }

    #[test]
    fn light_that_changes_along_z_splits_down_to_z() {
        // Cells in slot order: bit 0 of the cell index is the third level's (z) half.
        let s = signature(
            200,
            |cell, b| if (cell & 1 == 0) == (b < 8) { 1.0 } else { 0.0 },
        );
        let plan = s.plan(&uniform(), 100.0, 0.01);
        // Every slot of the first two levels splits, so that the third can.
        assert_eq!(plan.splits, 0b1111_1110);
    }

    #[test]
    fn a_split_needs_the_floor() {
        let s = signature(2, |cell, b| {
            if (cell >> 2 == 0) == (b < 8) {
                1.0
            } else {
                0.0
            }
        });
        // 256 samples in the leaf: splits with a threshold of 1000, not of 2000.
        assert_ne!(s.plan(&uniform(), 1000.0, 0.01).splits & 2, 0);
        assert_eq!(s.plan(&uniform(), 2000.0, 0.01).splits, 0);
    }

    #[test]
    fn the_count_plan_is_the_count_rule() {
        let plan = SplitPlan::by_count(1000, 200.0);
        // 1000 > 200, 500 > 200, 250 > 200; 125 is not.
        assert_eq!(plan.splits, 0b1111_1110);
        assert!(!plan.splits(8, 125, 200.0));
        let plan = SplitPlan::by_count(300, 200.0);
        assert_eq!(plan.splits, 0b10);
    }
}
