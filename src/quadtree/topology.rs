//! The next recording topology, grown from the root by split keys: a cell whose key exceeds
//! the threshold splits, depth first until the node cap would bind, then largest key first so
//! that the cap refuses the least important splits.

use super::refine::RefineParams;
use super::{LEAF_BIT, RecordingTree, recording::FREE};
use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// What a candidate cell was in the ended iteration's recording tree.
#[derive(Clone, Copy, Debug)]
enum Origin {
    /// Interior node `n`.
    Interior(u32),
    /// Leaf `k` (moments index).
    Leaf(u32),
    /// Below the ended iteration's leaves.
    New,
}

/// A candidate cell during refinement, ordered by its key (share of the mass, or gain).
pub(super) struct Candidate {
    key: f64,
    cell_depth: u32,
    origin: Origin,
    /// The new node and quadrant that will point to this cell.
    parent: (u32, usize),
}

/// How refinement ranks the cells of the ended iteration and decides to split them: a cell
/// splits while its key exceeds `threshold`.
pub(super) struct SplitKeys<'a> {
    /// Per interior node of the ended iteration and quadrant: the key of the cell in that slot.
    pub(super) slot: &'a [[f64; 4]],
    /// Variance gain: per leaf of the ended iteration, the predicted gains of its quadrants (and
    /// no split below them). Flux share: `None`, a cell below the old leaves has a quarter of
    /// its parent's share.
    pub(super) below_leaf: Option<&'a [[f64; 4]]>,
    pub(super) threshold: f64,
}

impl SplitKeys<'_> {
    /// The keys and origins of the four children of a cell.
    fn children(&self, old: &[[u32; 4]], origin: Origin, key: f64) -> [(f64, Origin); 4] {
        std::array::from_fn(|q| match origin {
            Origin::Interior(o) => {
                let slot = old[o as usize][q];
                let origin = if slot & LEAF_BIT != 0 {
                    Origin::Leaf(slot & !LEAF_BIT)
                } else {
                    Origin::Interior(slot)
                };
                (self.slot[o as usize][q], origin)
            }
            Origin::Leaf(k) => match self.below_leaf {
                Some(gains) => (gains[k as usize][q], Origin::New),
                None => (0.25 * key, Origin::New),
            },
            Origin::New => match self.below_leaf {
                Some(_) => (0.0, Origin::New),
                None => (0.25 * key, Origin::New),
            },
        })
    }
}

impl PartialEq for Candidate {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Candidate {}
impl PartialOrd for Candidate {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Candidate {
    fn cmp(&self, other: &Self) -> Ordering {
        self.key.total_cmp(&other.key)
    }
}

/// The cells refinement has still to decide on: a stack (depth first) or a max-heap by key.
trait Frontier {
    fn push(&mut self, c: Candidate);
    fn pop(&mut self) -> Option<Candidate>;
    /// Whether cells come out largest key first.
    fn ordered(&self) -> bool;
}

impl Frontier for &mut Vec<Candidate> {
    fn push(&mut self, c: Candidate) {
        Vec::push(self, c);
    }
    fn pop(&mut self) -> Option<Candidate> {
        Vec::pop(self)
    }
    fn ordered(&self) -> bool {
        false
    }
}

impl Frontier for BinaryHeap<Candidate> {
    fn push(&mut self, c: Candidate) {
        BinaryHeap::push(self, c);
    }
    fn pop(&mut self) -> Option<Candidate> {
        BinaryHeap::pop(self)
    }
    fn ordered(&self) -> bool {
        true
    }
}

/// A grown topology: interior nodes with leaf slots `FREE`, and what the cap did.
struct Grown {
    nodes: Vec<[u32; 4]>,
    refused: u64,
    gave_up: bool,
}

/// Grows a new topology from the root: a cell whose key exceeds the threshold becomes
/// interior (its children's keys come from the ended iteration where it was interior or a
/// leaf, and are predicted below — so one refine can add several levels); every other
/// cell is a leaf, which collapses whatever lay below it.
///
/// Depth first while the node cap is not reached; when it would be, the tree is grown again
/// largest key first, so the cap refuses the least important splits.
pub(super) fn refined_topology(
    old: &[[u32; 4]],
    keys: &SplitKeys,
    params: &RefineParams,
    stack: &mut Vec<Candidate>,
) -> (RecordingTree, u64) {
    stack.clear();
    let mut grown = grow(old, keys, params, stack);
    if grown.gave_up {
        grown = grow(old, keys, params, BinaryHeap::new());
    }
    (
        RecordingTree::from_nodes(grown.nodes, params.deferred),
        grown.refused,
    )
}

/// Grows a topology, taking cells from `frontier`. At the node cap an ordered frontier
/// refuses (and counts) further splits; an unordered one gives up.
fn grow(
    old: &[[u32; 4]],
    keys: &SplitKeys,
    params: &RefineParams,
    mut frontier: impl Frontier,
) -> Grown {
    // Room for the ended iteration's nodes and a quarter more: a refine mostly keeps a
    // topology and grows it a little, and growing the vector node by node costs reallocations.
    let mut nodes = Vec::with_capacity(old.len() + old.len() / 4 + 1);
    nodes.push([FREE; 4]);
    let mut out = Grown {
        nodes,
        refused: 0,
        gave_up: false,
    };
    let push_children = |frontier: &mut dyn Frontier, new: u32, c: &Candidate| {
        for (q, (key, origin)) in keys.children(old, c.origin, c.key).into_iter().enumerate() {
            frontier.push(Candidate {
                key,
                cell_depth: c.cell_depth + 1,
                origin,
                parent: (new, q),
            });
        }
    };
    let root = Candidate {
        key: f64::INFINITY,
        cell_depth: 0,
        origin: Origin::Interior(0),
        parent: (0, 0),
    };
    push_children(&mut frontier, 0, &root);
    while let Some(c) = frontier.pop() {
        if c.key <= keys.threshold || c.cell_depth >= params.max_depth {
            continue;
        }
        if out.nodes.len() >= params.max_nodes as usize {
            if !frontier.ordered() {
                out.gave_up = true;
                return out;
            }
            out.refused += 1;
            continue;
        }
        let new = out.nodes.len() as u32;
        out.nodes.push([FREE; 4]);
        out.nodes[c.parent.0 as usize][c.parent.1] = new;
        push_children(&mut frontier, new, &c);
    }
    out
}
