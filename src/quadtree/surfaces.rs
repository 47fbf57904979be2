//! The surfaces a spatial leaf sees most: a tally of the shading normals recorded with its
//! samples, and for the few most frequent ones the guide's product with the clamped cosine,
//! stored ([`SurfaceTree`]).
//!
//! A query's product with the cosine costs a chain of per-level cosine estimates (about 3× the
//! plain query in the benches). But most vertices lie on planar geometry, where every vertex
//! of a wall or a floor in a spatial leaf has the same shading normal, bit for bit: for such a
//! normal the product can be computed once per iteration, at `refine`, and a query with it
//! descends a plain sampling tree. A query whose normal has no stored product (curved
//! surfaces, rare normals) takes the per-query product; both are the same distribution.
//!
//! **The tally.** Each leaf has [`SLOTS`] slots, each a normal and a count. One sample in
//! [`TALLY_EVERY`] (by a hash of its position and direction) has its normal tallied: it adds to
//! the slot holding it, or claims an empty one (by compare-and-swap of a hash of its
//! bits), or, when all are taken, counts among the others; lock-free, a few atomic operations
//! per tallied sample. At `refine` a normal with at least [`MIN_SHARE`] of the leaf's normals and
//! [`MIN_COUNT`] of them gets a product, and keeps its slot for the next iteration (its count
//! restarts); the other slots are freed. So slots taken by one-off normals of a curved surface
//! free up every iteration, and a wall's normal, seen in most samples, soon holds one.

use super::SamplingTree;
use super::horizon::SurfaceTree;
use glam::Vec3;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering::Relaxed};

/// Normals a spatial leaf tallies, and so at most how many products it stores.
pub(crate) const SLOTS: usize = 4;

/// The share of a leaf's recorded normals one must have to get a product.
pub(crate) const MIN_SHARE: f64 = 0.05;

/// The fewest tallied recordings of a normal (about [`TALLY_EVERY`] times as many samples)
/// that get it a product.
pub(crate) const MIN_COUNT: u32 = 16;

/// One recorded sample in this many has its normal tallied, picked by a hash of its position
/// and direction: the tally lives on cache lines `record` does not otherwise touch, and a
/// share is what it estimates.
pub(crate) const TALLY_EVERY: u64 = 8;

/// Whether the sample at `position` from `direction` has its normal tallied (one in
/// [`TALLY_EVERY`], deterministically).
#[inline]
pub(crate) fn tallies(position: Vec3, direction: Vec3) -> bool {
    let [x, y, z] = position.to_array().map(|c| u64::from(c.to_bits()));
    let h = (x ^ y << 21 ^ z << 42 ^ u64::from(direction.x.to_bits()) << 11)
        .wrapping_mul(0x9e37_79b9_7f4a_7c15);
    (h >> 58) % TALLY_EVERY == 0
}

/// The key of a normal's slot: a hash of its bits, never 0 (0 marks a free slot). A zero
/// component's sign is folded first (`−0.0 + 0.0` is `+0.0`): a renderer that flips a normal to
/// face the viewer hands the same wall's normal with either sign, and it is one normal, for one
/// slot and one product.
fn key(n: Vec3) -> u64 {
    let [x, y, z] = (n + Vec3::ZERO).to_array().map(|c| u64::from(c.to_bits()));
    let h = (x | y << 32) ^ z.wrapping_mul(0x9e37_79b9_7f4a_7c15);
    let h = (h ^ h >> 31).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    (h ^ h >> 29) | 1
}

/// [`key`]'s low 32 bits, never 0: what a query compares.
#[inline]
fn short_key(n: Vec3) -> u32 {
    key(n) as u32
}

#[derive(Debug, Default)]
struct Slot {
    key: AtomicU64,
    bits: [AtomicU32; 3],
    count: AtomicU32,
}

impl Slot {
    /// The normal the slot holds, if any. A slot claimed by a `record` running at the same
    /// time may not show its bits yet; its key then does not match them, and it counts as
    /// free (what a snapshot taken while threads record holds of their samples is theirs to
    /// race).
    fn held(&self) -> Option<Vec3> {
        let k = self.key.load(Relaxed);
        let n = Vec3::from_array(
            self.bits
                .each_ref()
                .map(|b| f32::from_bits(b.load(Relaxed))),
        );
        (k != 0 && key(n) == k).then_some(n)
    }

    fn set(&mut self, n: Vec3, count: u32) {
        *self.key.get_mut() = key(n);
        for (b, c) in self.bits.iter_mut().zip(n.to_array()) {
            *b.get_mut() = c.to_bits();
        }
        *self.count.get_mut() = count;
    }
}

/// A spatial leaf's tally of recorded normals, and its stored products.
///
/// What a query reads comes first, 32 bytes: [`Region`](crate::region::Region) puts them on the cache
/// line of its sampling tree, so a query whose normal has no product touches no other line.
#[derive(Debug, Default)]
#[repr(C)]
pub(crate) struct Surfaces {
    /// Per product, the 32 low bits of its normal's key (never 0); 0 past the last product.
    keys: [u32; SLOTS],
    /// The products for the normals that earned one at the last `refine`, most frequent first.
    pub(crate) products: Box<[SurfaceTree]>,
    slots: [Slot; SLOTS],
    /// Recorded normals that found every slot taken by others.
    others: AtomicU32,
}

impl Clone for Surfaces {
    fn clone(&self) -> Self {
        let mut out = Surfaces {
            keys: self.keys,
            others: AtomicU32::new(self.others.load(Relaxed)),
            products: self.products.clone(),
            ..Surfaces::default()
        };
        for (to, from) in out.slots.iter_mut().zip(&self.slots) {
            if let Some(n) = from.held() {
                to.set(n, from.count.load(Relaxed));
            }
        }
        out
    }
}

/// One slot's content, as the cache stores it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Tallied {
    /// The unit normal.
    pub(crate) normal: Vec3,
    /// How often it was recorded this iteration.
    pub(crate) count: u32,
    /// Whether it has a stored product.
    pub(crate) product: bool,
}

impl Surfaces {
    /// Counts one recording of the unit normal `n` (as [`crate::sphere::normalize`] returns
    /// it). Safe from any number of threads.
    #[inline]
    pub(crate) fn record(&self, n: Vec3) {
        let k = key(n);
        for slot in &self.slots {
            let mut held = slot.key.load(Relaxed);
            if held == 0 {
                match slot.key.compare_exchange(0, k, Relaxed, Relaxed) {
                    Ok(_) => {
                        // Only the thread whose swap claimed the slot writes its bits; readers
                        // check them against the key (see `Slot::held`).
                        for (b, c) in slot.bits.iter().zip(n.to_array()) {
                            b.store(c.to_bits(), Relaxed);
                        }
                        held = k;
                    }
                    Err(other) => held = other,
                }
            }
            if held == k {
                slot.count.fetch_add(1, Relaxed);
                return;
            }
        }
        self.others.fetch_add(1, Relaxed);
    }

    /// The stored product for the unit normal `n`, if it has one.
    #[inline]
    pub(crate) fn product(&self, n: Vec3) -> Option<&SurfaceTree> {
        let k = short_key(n);
        let i = self.keys.iter().position(|&held| held == k)?;
        // The key is a hash: the normal itself decides.
        self.products.get(i).filter(|p| p.normal == n)
    }

    /// Ends an iteration: the normals with enough recordings get a product of the new `guide`
    /// and keep their slots; the other slots are freed and every count restarts. A leaf that
    /// recorded no normal keeps the normals it had, with products of the new guide.
    pub(crate) fn refine(&mut self, guide: &SamplingTree) {
        let count = |s: &Slot| s.count.load(Relaxed);
        let total =
            self.slots.iter().map(|s| u64::from(count(s))).sum::<u64>() + u64::from(self.others());
        let mut kept: Vec<(Vec3, u32)> = if total == 0 {
            self.products.iter().map(|p| (p.normal, 0)).collect()
        } else {
            let bar = (MIN_SHARE * total as f64).max(f64::from(MIN_COUNT));
            self.slots
                .iter()
                .filter(|s| f64::from(count(s)) >= bar)
                .filter_map(|s| Some((s.held()?, count(s))))
                .collect()
        };
        kept.sort_by_key(|k| std::cmp::Reverse(k.1));
        self.set(
            kept.iter().map(|&(n, _)| Tallied {
                normal: n,
                count: 0,
                product: true,
            }),
            0,
            guide,
        );
    }

    /// The slots' contents, for the cache.
    pub(crate) fn tallied(&self) -> Vec<Tallied> {
        self.slots
            .iter()
            .filter_map(|s| {
                let normal = s.held()?;
                Some(Tallied {
                    normal,
                    count: s.count.load(Relaxed),
                    product: self.product(normal).is_some(),
                })
            })
            .collect()
    }

    /// Recorded normals that found no slot.
    pub(crate) fn others(&self) -> u32 {
        self.others.load(Relaxed)
    }

    /// Replaces the tally with `slots` (at most [`SLOTS`], distinct unit normals) and `others`,
    /// and builds the products of `guide` the slots ask for.
    pub(crate) fn set(
        &mut self,
        slots: impl IntoIterator<Item = Tallied>,
        others: u32,
        guide: &SamplingTree,
    ) {
        let mut products = Vec::new();
        for s in &mut self.slots {
            *s = Slot::default();
        }
        for (slot, t) in self.slots.iter_mut().zip(slots) {
            slot.set(t.normal, t.count);
            if t.product {
                products.extend(SurfaceTree::build(guide, t.normal));
            }
        }
        *self.others.get_mut() = others;
        self.keys = [0; SLOTS];
        for (k, p) in self.keys.iter_mut().zip(&products) {
            *k = short_key(p.normal);
        }
        self.products = products.into_boxed_slice();
    }

    /// Adds the normals `other` tallied (a merge): each to the slot that holds it here, or to a
    /// free one, or to the others.
    pub(crate) fn add_tally(&mut self, other: &Surfaces) {
        for t in other.tallied() {
            self.add(t.normal, t.count);
        }
        let o = self.others.get_mut();
        *o = o.saturating_add(other.others());
    }

    /// Adds `count` recordings of the unit normal `n`.
    fn add(&mut self, n: Vec3, count: u32) {
        let k = key(n);
        for slot in &mut self.slots {
            if *slot.key.get_mut() == 0 {
                slot.set(n, count);
                return;
            }
            if *slot.key.get_mut() == k {
                let c = slot.count.get_mut();
                *c = c.saturating_add(count);
                return;
            }
        }
        let o = self.others.get_mut();
        *o = o.saturating_add(count);
    }

    /// Drops the stored products (the tally stays); returns the bytes freed.
    pub(crate) fn drop_products(&mut self) -> usize {
        let freed = self.bytes();
        self.products = Box::default();
        self.keys = [0; SLOTS];
        freed
    }

    /// Nodes of the stored products.
    pub(crate) fn node_count(&self) -> usize {
        self.products.iter().map(SurfaceTree::node_count).sum()
    }

    /// Bytes held by the stored products.
    pub(crate) fn bytes(&self) -> usize {
        self.products.iter().map(SurfaceTree::bytes).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quadtree::testing::random_sampling_tree;

    #[test]
    fn the_tally_counts_every_normal_and_keeps_the_frequent_ones() {
        // Four threads record a wall's normal 600 times each, a floor's 100 times, and 50
        // one-off normals each (a curved surface); the first two take slots whatever the
        // order, since the other slots fill with at most two one-offs.
        let (wall, floor) = (Vec3::X, Vec3::new(0.0, 0.6, 0.8));
        let mut surfaces = Surfaces::default();
        surfaces.record(wall);
        surfaces.record(floor);
        std::thread::scope(|s| {
            for t in 0..4 {
                let surfaces = &surfaces;
                s.spawn(move || {
                    for i in 0..600 {
                        surfaces.record(wall);
                        if i % 6 == 0 {
                            surfaces.record(floor);
                        }
                        if i % 12 == 0 {
                            let a = 0.1 + (t * 50 + i / 12) as f32 * 0.01;
                            surfaces.record(Vec3::new(a.cos(), a.sin(), 0.0));
                        }
                    }
                });
            }
        });
        let tallied = surfaces.tallied();
        assert_eq!(
            tallied[..2].iter().map(|t| t.count).collect::<Vec<_>>(),
            [2401, 401]
        );
        let total: u32 = tallied.iter().map(|t| t.count).sum::<u32>() + surfaces.others();
        assert_eq!(total, 2401 + 401 + 200);
        // At refine, the wall (80%) and the floor (13%) get products, the one-offs (each a
        // single recording) do not; the kept normals hold their slots with counts restarted.
        let guide = random_sampling_tree(3);
        surfaces.refine(&guide);
        let normals: Vec<Vec3> = surfaces.products.iter().map(|p| p.normal).collect();
        assert_eq!(normals, [wall, floor]);
        assert!(surfaces.product(wall).is_some() && surfaces.product(-wall).is_none());
        let kept = surfaces.tallied();
        assert_eq!(kept.len(), 2);
        assert!(kept.iter().all(|t| t.count == 0 && t.product));
        assert_eq!(surfaces.others(), 0);
        // An iteration that records no normal keeps the products (rebuilt for the new guide).
        surfaces.refine(&random_sampling_tree(4));
        assert_eq!(surfaces.products.len(), 2);
        // One where the floor falls under the share loses the floor's.
        for _ in 0..400 {
            surfaces.record(wall);
        }
        surfaces.record(floor);
        surfaces.refine(&guide);
        let normals: Vec<Vec3> = surfaces.products.iter().map(|p| p.normal).collect();
        assert_eq!(normals, [wall]);
    }
}
