//! How a directional tree ends an iteration: leaf moments shrunk toward their parents', leaf
//! masses by the active rule, the next sampling tree, and the next recording topology grown
//! from split keys (flux share, or variance gain from the quadrant sums).

use super::topology::{Candidate, SplitKeys, refined_topology};
use super::{LEAF_BIT, NO_CHILD, RecordingTree, SamplingNode, SamplingTree, cell_area};
use crate::moments::{Quadrants, own_sums};
use crate::refinement::Refinement;
use crate::refinement::{
    MIN_PREDICTED_SPLIT_SAMPLES, MIN_SPLIT_SAMPLES, SPLIT_PRIOR_SAMPLES, split_gain,
};
use crate::rule::LeafRule;

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
    /// `n_f` of [`GuidingConfig::filter_samples`](crate::GuidingConfig::filter_samples) when the
    /// l2 rules' masses blend a leaf's own second moment with the filtered one.
    pub filter_samples: Option<f64>,
    /// Whether recording defers the directional box filter to refine (give leaves pending sums).
    pub deferred: bool,
}

/// What one leaf recorded in the ended iteration, as floats: read once per refine, since a
/// read converts exact sums and the rule's masses and the split keys both need them.
struct LeafSums {
    sum: f64,
    sum_sq: f64,
    /// The leaf's quadrant sums (its own samples, unfiltered).
    quadrants: Quadrants,
    /// The leaf's samples: its quadrants' (saturating).
    count: u64,
}

/// Shrunk `(S1, S2)` estimates of a recording tree's cells.
#[derive(Default)]
struct ShrunkMoments {
    /// Per interior node.
    nodes: Vec<(f64, f64)>,
    /// Per leaf (moments index).
    leaves: Vec<(f64, f64)>,
    /// Working memory: per interior node, the pooled sums `(S1, S2, n)` below it.
    pooled: Vec<(f64, f64, u64)>,
}

/// The working memory of [`refine`], kept from one directional tree to the next: without it
/// each tree's refine allocates and frees some twenty vectors, about a tenth of its time in a
/// profile. Every vector is cleared and sized before use; nothing carries over.
#[derive(Default)]
pub(crate) struct RefineScratch {
    sums: Vec<LeafSums>,
    depth: Vec<u32>,
    shrunk: ShrunkMoments,
    leaf_mass: Vec<f64>,
    share: Vec<[f64; 4]>,
    mass: Vec<[f64; 4]>,
    gain: GainScratch,
    frontier: Vec<Candidate>,
}

/// [`RecordingTree::gain_keys`]'s part of [`RefineScratch`].
#[derive(Default)]
struct GainScratch {
    node_root: Vec<f64>,
    node_gain: Vec<f64>,
    subtree: Vec<(f64, f64, u64)>,
    slot: Vec<[f64; 4]>,
    below_leaf: Vec<[f64; 4]>,
}

/// `v` cleared and filled with `n` copies of `x`, keeping its allocation.
fn reset<T: Clone>(v: &mut Vec<T>, n: usize, x: T) -> &mut [T] {
    v.clear();
    v.resize(n, x);
    v
}

/// The trees an iteration's recording tree refines into.
pub(crate) struct Refined {
    /// The next distribution.
    pub sampling: SamplingTree,
    /// The next (empty) recording topology.
    pub recording: RecordingTree,
    /// Cells that qualified for a split but were refused by `max_nodes`.
    pub refused: u64,
    /// The samples the ended iteration counted.
    pub samples: u64,
}

/// Ends an iteration of one directional tree: builds the next sampling tree from the moments
/// `rec` recorded (pending sums already spread) and the next (empty) recording topology;
/// `None` if it counted no sample. `scratch` is working memory (see [`RefineScratch`]).
pub(crate) fn refine(
    rec: &RecordingTree,
    params: &RefineParams,
    scratch: &mut RefineScratch,
) -> Option<Refined> {
    // The leaves' sums are read once, here: a field's sums do not fit in a cache, so every
    // pass over a tree's costs a trip to memory.
    let sums = &mut scratch.sums;
    rec.leaf_sums(sums);
    let samples = sums.iter().fold(0u64, |n, m| n.saturating_add(m.count));
    if samples == 0 {
        return None;
    }
    let depth = rec.depths(&mut scratch.depth);

    // 1. Leaf shares by the rule, normalized: α_i = mass_i / Σ_j mass_j, from moments
    //    shrunk toward their parents' (see `shrunk_moments`).
    let shrunk = &mut scratch.shrunk;
    rec.shrunk_moments(sums, params.prior_samples, params.filter_samples, shrunk);
    let leaf_moments = &shrunk.leaves;
    let leaf_mass = reset(&mut scratch.leaf_mass, rec.moments.len(), 0.0);
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
    let share = reset(&mut scratch.share, rec.nodes.len(), [0.0; 4]);
    let mass = reset(&mut scratch.mass, rec.nodes.len(), [0.0; 4]);
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
            .zip(mass.iter())
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
        Refinement::VarianceGain => rec.gain_keys(sums, depth, params, shrunk, &mut scratch.gain),
    };
    let (recording, refused) = refined_topology(&rec.nodes, &keys, params, &mut scratch.frontier);
    Some(Refined {
        sampling,
        recording,
        refused,
        samples,
    })
}

// What `refine` reads off the ended iteration. Each is called once per refine and
// marked `#[inline]`: left out of line, as the split into modules left them, `refine` took 1–2%
// longer.
impl RecordingTree {
    /// Every leaf's sums as floats, by moments index, into `out`.
    #[inline]
    fn leaf_sums(&self, out: &mut Vec<LeafSums>) {
        out.clear();
        out.extend(
            self.moments
                .iter()
                .zip(self.quadrants.iter())
                .map(|(m, q)| {
                    let (sum, sum_sq) = m.exact();
                    let quadrants = q.get();
                    LeafSums {
                        sum: sum.value(),
                        sum_sq: sum_sq.value(),
                        count: own_sums(&quadrants).1,
                        quadrants,
                    }
                }),
        );
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
    ///
    /// With `filter_samples = Some(n_f)` a leaf's second moment is first blended with its own
    /// samples' (the quadrant sums, which only a sample's own leaf records):
    /// `w·own + (1 − w)·filtered`, `w = n/(n + n_f)` (see
    /// [`GuidingConfig::filter_samples`](crate::GuidingConfig::filter_samples)). Without a
    /// filter that spreads, the two are equal; only the l2 rules' masses read the second
    /// moment, so l1's are unaffected.
    #[inline]
    fn shrunk_moments(
        &self,
        sums: &[LeafSums],
        prior_samples: f64,
        filter_samples: Option<f64>,
        out: &mut ShrunkMoments,
    ) {
        self.shrink(prior_samples, out, |k| {
            let m = &sums[k];
            let sum_sq = match filter_samples {
                Some(nf) if m.count > 0 => {
                    let (own, _) = own_sums(&m.quadrants);
                    let n = m.count as f64;
                    let w = n / (n + nf);
                    w * own + (1.0 - w) * m.sum_sq
                }
                _ => m.sum_sq,
            };
            (m.sum, sum_sq, m.count)
        })
    }

    /// [`shrunk_moments`](Self::shrunk_moments) of any per-leaf sums `(S1, S2, n)`, into `out`.
    fn shrink(
        &self,
        prior_samples: f64,
        out: &mut ShrunkMoments,
        leaf: impl Fn(usize) -> (f64, f64, u64),
    ) {
        let n = self.nodes.len();
        // Pooled sums per node, bottom-up (children have larger indices than their parents).
        let pooled = reset(&mut out.pooled, n, (0.0, 0.0, 0));
        let slot_moments = |slot: u32, pooled: &[(f64, f64, u64)]| {
            if slot & LEAF_BIT != 0 {
                leaf((slot & !LEAF_BIT) as usize)
            } else {
                pooled[slot as usize]
            }
        };
        for i in (0..n).rev() {
            pooled[i] = self.nodes[i].iter().fold((0.0, 0.0, 0), |a, &slot| {
                let m = slot_moments(slot, pooled);
                (a.0 + m.0, a.1 + m.1, a.2.saturating_add(m.2))
            });
        }
        // Shrunk estimates, top-down.
        let estimate = reset(&mut out.nodes, n, (0.0, 0.0));
        let leaves = reset(&mut out.leaves, self.moments.len(), (0.0, 0.0));
        estimate[0] = (pooled[0].0, pooled[0].1);
        for i in 0..n {
            let prior = (0.25 * estimate[i].0, 0.25 * estimate[i].1);
            for &slot in &self.nodes[i] {
                let (s1, s2, count) = slot_moments(slot, pooled);
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
    }

    /// Split keys for [`Refinement::VarianceGain`]: each cell's estimated gain
    /// `sqrt(m) − Σ_q sqrt(m_q)` (in units of `sqrt(|C|·S2)` of the shrunk sums), and the
    /// threshold `gain_threshold · Σ_leaves sqrt(m)`. Interior cells take their children's
    /// estimates, leaves their quadrant sums (see [`crate::refinement`]). `shrunk` and
    /// `scratch` are working memory; the keys live in `scratch`.
    #[inline]
    fn gain_keys<'a>(
        &self,
        sums: &[LeafSums],
        depth: &[u32],
        params: &RefineParams,
        shrunk: &mut ShrunkMoments,
        scratch: &'a mut GainScratch,
    ) -> SplitKeys<'a> {
        // Every cell's second moment from the same unfiltered samples as the quadrant sums, so
        // that a cell's gain means the same whether it was a leaf or interior.
        self.shrink(SPLIT_PRIOR_SAMPLES, shrunk, |k| {
            let (s2, n) = own_sums(&sums[k].quadrants);
            (0.0, s2, n)
        });
        let root_of = |s2: f64, d: u32| (cell_area(d) * s2.max(0.0)).sqrt();
        let node_root = &mut scratch.node_root;
        node_root.clear();
        node_root.extend((0..self.nodes.len()).map(|i| root_of(shrunk.nodes[i].1, depth[i])));
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
        let node_gain = &mut scratch.node_gain;
        node_gain.clear();
        node_gain.extend(self.nodes.iter().enumerate().map(|(i, slots)| {
            (node_root[i] - slots.iter().map(|&s| slot_root(i, s)).sum::<f64>()).max(0.0)
        }));
        // What each interior cell's subtree gained in all, its interior nodes and the samples
        // that landed in it, bottom-up.
        let leaf_count = |k: usize| sums[k].count;
        let subtree = reset(&mut scratch.subtree, self.nodes.len(), (0.0, 0.0, 0));
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
        let slot = reset(&mut scratch.slot, self.nodes.len(), [0.0; 4]);
        let below_leaf = reset(&mut scratch.below_leaf, self.moments.len(), [0.0; 4]);
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
                    let r = slot_root(i, s);
                    total += r;
                    if leaf_count(k) < MIN_SPLIT_SAMPLES.min(MIN_PREDICTED_SPLIT_SAMPLES) {
                        // Neither the leaf nor a quadrant (which counts no more) saw enough
                        // to split, so every key is 0 (`below_leaf` is reset to 0): most
                        // leaves, and the estimate was a tenth of `refine`.
                        0.0
                    } else {
                        let quadrants = &sums[k].quadrants;
                        let e = split_gain(quadrants, SPLIT_PRIOR_SAMPLES, parent);
                        below_leaf[k] = std::array::from_fn(|c| {
                            let key = r * e.fractions[c] * e.relative_gain;
                            enough(quadrants[c].1, MIN_PREDICTED_SPLIT_SAMPLES, key)
                        });
                        enough(leaf_count(k), MIN_SPLIT_SAMPLES, r * e.relative_gain)
                    }
                };
            }
        }
        SplitKeys {
            slot,
            below_leaf: Some(&*below_leaf),
            threshold: params.gain_threshold * total,
        }
    }

    /// The depth of every node (the root is 0), from one forward sweep, in `depth`.
    #[inline]
    fn depths<'a>(&self, depth: &'a mut Vec<u32>) -> &'a [u32] {
        let depth = reset(depth, self.nodes.len(), 0);
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
