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
//! **The tally.** Each leaf has [`SLOTS`] slots. One sample in [`TALLY_EVERY`] (by a hash of
//! its position and direction, which also gives it two 32-bit priorities) has its normal
//! tallied.
//! A *held* slot belongs to a normal that earned a product at the last `refine` and counts that
//! normal's recordings. The other slots are *buckets*: a normal no slot holds goes to the
//! bucket its key picks, which counts every recording routed to it and keeps, of them, the
//! normal of the recording with the largest priority — by `fetch_max` on words that pack the
//! priority above the key and above each component, so whatever order the recordings come in,
//! every word ends the same, and a normal seen often is likely the one kept. A second word keeps
//! the key of the recording with the largest second priority: the two agree about as often as
//! the bucket's recordings are of one normal (`Σ share²`). At `refine` a held normal with at
//! least [`MIN_SHARE`] of the leaf's tallied recordings and [`MIN_COUNT`] of them keeps its
//! product; a bucket that reaches the same bar and whose two keys agree gives its kept normal
//! one (a bucket of many rare normals almost never agrees; where it does, the next iteration's
//! exact count takes the product back). The outcome depends on the set of samples only, never
//! on their order, and two tallies merge exactly.

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
/// [`TALLY_EVERY`], deterministically), and if so its two priorities in a bucket (the first
/// in the high half).
#[inline]
pub(crate) fn tally_priority(position: Vec3, direction: Vec3) -> Option<u64> {
    let [x, y, z] = position.to_array().map(|c| u64::from(c.to_bits()));
    let h = (x ^ y << 21 ^ z << 42 ^ u64::from(direction.x.to_bits()) << 11)
        .wrapping_mul(0x9e37_79b9_7f4a_7c15);
    let second = (h ^ h >> 29).wrapping_mul(0xbf58_476d_1ce4_e5b9) >> 32;
    ((h >> 58) % TALLY_EVERY == 0).then_some((h >> 26) << 32 | second)
}

/// Words a slot keeps (see [`Slot`]).
pub(crate) const WORDS: usize = 5;

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

/// One slot: held by a normal (`key` its key, `words[1..4]` its bits), or a bucket (`key` 0,
/// `words[..4]` the kept recording's first priority above its key's low half and above each
/// component, `words[4]` the witness: the second priority above its recording's key).
#[derive(Debug, Default)]
struct Slot {
    key: AtomicU64,
    words: [AtomicU64; WORDS],
    count: AtomicU32,
}

impl Slot {
    fn held(&self) -> Option<Vec3> {
        let k = self.key.load(Relaxed);
        (k != 0).then(|| self.normal())
    }

    /// The normal in the component words (their low halves).
    fn normal(&self) -> Vec3 {
        Vec3::from_array(std::array::from_fn(|i| {
            f32::from_bits(self.words[i + 1].load(Relaxed) as u32)
        }))
    }

    /// A bucket's kept normal, if its words agree: all from one recording, and the witness of
    /// the same normal. Two recordings of different normals with the same priority can mix
    /// their words; the mix is the same whatever the order, and keeps nothing.
    fn kept(&self) -> Option<Vec3> {
        let best = self.words[0].load(Relaxed);
        let n = self.normal();
        let same_priority = self.words[1..4]
            .iter()
            .all(|w| w.load(Relaxed) >> 32 == best >> 32);
        let witnessed = self.words[4].load(Relaxed) as u32 == best as u32;
        (best != 0 && same_priority && witnessed && short_key(n) == best as u32).then_some(n)
    }

    /// Records a normal of key `k` with priorities `priority` into a bucket.
    #[inline]
    fn offer(&self, k: u64, n: Vec3, priority: u64) {
        self.count.fetch_add(1, Relaxed);
        let (first, second) = (priority >> 32, priority & 0xffff_ffff);
        let short = k & 0xffff_ffff;
        // A recording whose priority is below the kept one's skips: every word ends the kept
        // one's, or a higher one's, whatever the order. Most recordings skip.
        if self.words[0].load(Relaxed) >> 32 <= first {
            self.words[0].fetch_max(first << 32 | short, Relaxed);
            for (w, c) in self.words[1..4].iter().zip(n.to_array()) {
                w.fetch_max(first << 32 | u64::from(c.to_bits()), Relaxed);
            }
        }
        if self.words[4].load(Relaxed) >> 32 <= second {
            self.words[4].fetch_max(second << 32 | short, Relaxed);
        }
    }

    fn set_held(&mut self, n: Vec3, count: u32) {
        *self.key.get_mut() = key(n);
        let bits = n.to_array().map(|c| u64::from(c.to_bits()));
        for (w, x) in self.words.iter_mut().zip([0, bits[0], bits[1], bits[2], 0]) {
            *w.get_mut() = x;
        }
        *self.count.get_mut() = count;
    }

    fn set_bucket(&mut self, words: [u64; WORDS], count: u32) {
        *self.key.get_mut() = 0;
        for (w, x) in self.words.iter_mut().zip(words) {
            *w.get_mut() = x;
        }
        *self.count.get_mut() = count;
    }

    fn snapshot(&self) -> Tallied {
        let count = self.count.load(Relaxed);
        match self.held() {
            Some(normal) => Tallied::Held {
                normal,
                count,
                product: false,
            },
            None => Tallied::Bucket {
                words: self.words.each_ref().map(|w| w.load(Relaxed)),
                count,
            },
        }
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
    /// Recorded normals that found every slot held by others.
    others: AtomicU32,
    /// How many slots are held: the first ones; the others are buckets.
    held: u8,
}

impl Surfaces {
    /// A tally with nothing in it and no products, shared (what a guide of medium vertices
    /// reads: they have no normal).
    pub(crate) fn none() -> &'static Surfaces {
        static NONE: std::sync::LazyLock<Surfaces> = std::sync::LazyLock::new(Surfaces::default);
        &NONE
    }
}

impl Clone for Surfaces {
    fn clone(&self) -> Self {
        let mut out = Surfaces {
            keys: self.keys,
            others: AtomicU32::new(self.others.load(Relaxed)),
            products: self.products.clone(),
            ..Surfaces::default()
        };
        out.set_slots(self.slots.iter().map(Slot::snapshot));
        out
    }
}

/// One slot's content, as the cache stores it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Tallied {
    /// A held slot.
    Held {
        /// The unit normal.
        normal: Vec3,
        /// How often it was recorded this iteration.
        count: u32,
        /// Whether it has a stored product.
        product: bool,
    },
    /// A bucket: its words (see [`Slot`]) and count.
    Bucket { words: [u64; WORDS], count: u32 },
}

impl Surfaces {
    /// Counts one recording of the unit normal `n` (as [`crate::sphere::normalize`] returns
    /// it), of priorities `priority` (from [`tally_priority`]). Safe from any number of
    /// threads.
    #[inline]
    pub(crate) fn record(&self, n: Vec3, priority: u64) {
        let k = key(n);
        for slot in &self.slots {
            // Held keys change only at `refine`.
            if slot.key.load(Relaxed) == k {
                slot.count.fetch_add(1, Relaxed);
                return;
            }
        }
        let held = usize::from(self.held);
        match SLOTS - held {
            0 => {
                self.others.fetch_add(1, Relaxed);
            }
            buckets => self.slots[held + (k % buckets as u64) as usize].offer(k, n, priority),
        }
    }

    /// The stored product for the unit normal `n`, if it has one.
    #[inline]
    pub(crate) fn product(&self, n: Vec3) -> Option<&SurfaceTree> {
        let k = short_key(n);
        let i = self.keys.iter().position(|&held| held == k)?;
        // The key is a hash: the normal itself decides.
        self.products.get(i).filter(|p| p.normal == n)
    }

    /// Ends an iteration: the held normals and the buckets' kept normals with enough
    /// recordings get a product of the new `guide` and hold their slots; the other slots
    /// become buckets and every count restarts. A leaf that recorded no normal keeps the
    /// normals it had, with products of the new guide.
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
                .filter_map(|s| Some((s.held().or_else(|| s.kept())?, count(s))))
                .collect()
        };
        // Most frequent first; ties by key, so that the order is the samples' alone.
        kept.sort_by_key(|&(n, c)| (std::cmp::Reverse(c), key(n)));
        self.set(
            kept.iter().map(|&(normal, _)| Tallied::Held {
                normal,
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
            .map(|s| match s.snapshot() {
                Tallied::Held { normal, count, .. } => Tallied::Held {
                    normal,
                    count,
                    product: self.product(normal).is_some(),
                },
                bucket => bucket,
            })
            .collect()
    }

    /// Recorded normals that found every slot held.
    pub(crate) fn others(&self) -> u32 {
        self.others.load(Relaxed)
    }

    /// The held normals' keys, slot by slot (0 for a bucket): what a merge requires equal.
    pub(crate) fn held_keys(&self) -> [u64; SLOTS] {
        self.slots.each_ref().map(|s| s.key.load(Relaxed))
    }

    /// Replaces the slots (at most [`SLOTS`]: held ones, distinct unit normals, then buckets;
    /// empty buckets past them).
    fn set_slots(&mut self, slots: impl IntoIterator<Item = Tallied>) {
        for s in &mut self.slots {
            *s = Slot::default();
        }
        self.held = 0;
        for (slot, t) in self.slots.iter_mut().zip(slots) {
            match t {
                Tallied::Held { normal, count, .. } => {
                    slot.set_held(normal, count);
                    self.held += 1;
                }
                Tallied::Bucket { words, count } => slot.set_bucket(words, count),
            }
        }
    }

    /// Replaces the tally with `slots` (at most [`SLOTS`]; the held ones distinct unit normals;
    /// slots past them are empty buckets) and `others`, and builds the products of `guide` the
    /// held slots ask for.
    pub(crate) fn set(
        &mut self,
        slots: impl IntoIterator<Item = Tallied>,
        others: u32,
        guide: &SamplingTree,
    ) {
        let slots: Vec<Tallied> = slots.into_iter().take(SLOTS).collect();
        let mut products = Vec::new();
        for t in &slots {
            if let Tallied::Held {
                normal,
                product: true,
                ..
            } = *t
            {
                products.extend(SurfaceTree::build(guide, normal));
            }
        }
        self.set_slots(slots);
        *self.others.get_mut() = others;
        self.keys = [0; SLOTS];
        for (k, p) in self.keys.iter_mut().zip(&products) {
            *k = short_key(p.normal);
        }
        self.products = products.into_boxed_slice();
    }

    /// Adds the tally of `other`, which started the iteration with the same held slots (a
    /// merge): held counts add, buckets keep the larger words and add their counts.
    pub(crate) fn add_tally(&mut self, other: &Surfaces) {
        for (mine, theirs) in self.slots.iter_mut().zip(&other.slots) {
            let c = mine.count.get_mut();
            *c = c.saturating_add(theirs.count.load(Relaxed));
            if *mine.key.get_mut() == 0 {
                for (w, x) in mine.words.iter_mut().zip(&theirs.words) {
                    let w = w.get_mut();
                    *w = (*w).max(x.load(Relaxed));
                }
            }
        }
        let o = self.others.get_mut();
        *o = o.saturating_add(other.others());
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

    /// The recordings of a leaf: a wall's normal 2400 times, a floor's 400, and 200 one-off
    /// normals of a curved surface, each with its own priorities (from the iteration's samples:
    /// `seed`).
    fn recordings(seed: u64) -> Vec<(Vec3, u64)> {
        let (wall, floor) = (Vec3::X, Vec3::new(0.0, 0.6, 0.8));
        let priority = |i: u64| {
            let h = (i + 1 + (seed << 20)).wrapping_mul(0x9e37_79b9_7f4a_7c15);
            h ^ h >> 31
        };
        (0..3000u64)
            .map(|i| {
                let n = match i % 15 {
                    0..=11 => wall,
                    12 | 13 => floor,
                    _ => {
                        let a = 0.1 + (i / 15) as f32 * 0.01;
                        Vec3::new(a.cos(), a.sin(), 0.0)
                    }
                };
                (n, priority(i))
            })
            .collect()
    }

    fn record_from_threads(surfaces: &Surfaces, recordings: &[(Vec3, u64)], threads: usize) {
        std::thread::scope(|s| {
            for part in recordings.chunks(recordings.len().div_ceil(threads)) {
                s.spawn(move || part.iter().for_each(|&(n, p)| surfaces.record(n, p)));
            }
        });
    }

    #[test]
    fn the_tally_is_the_same_whatever_the_order_and_keeps_the_frequent_normals() {
        let (wall, floor) = (Vec3::X, Vec3::new(0.0, 0.6, 0.8));
        let all = recordings(0);
        let reference = Surfaces::default();
        all.iter().for_each(|&(n, p)| reference.record(n, p));
        let mut reversed = all.clone();
        reversed.reverse();
        for (order, threads) in [(&all, 4), (&reversed, 3), (&reversed, 1)] {
            let s = Surfaces::default();
            record_from_threads(&s, order, threads);
            assert_eq!(s.tallied(), reference.tallied(), "{threads} threads");
        }
        // Split in two tallies and merged, the same again.
        let (mut a, b) = (Surfaces::default(), Surfaces::default());
        record_from_threads(&a, &all[..1234], 2);
        record_from_threads(&b, &all[1234..], 2);
        a.add_tally(&b);
        assert_eq!(a.tallied(), reference.tallied());
        // Every recording counts once, in a bucket (no slot is held yet).
        let total: u32 = reference
            .tallied()
            .iter()
            .map(|t| match *t {
                Tallied::Held { count, .. } | Tallied::Bucket { count, .. } => count,
            })
            .sum();
        assert_eq!(total, 3000);
        // At refine the wall (80%) gets a product: its bucket's count is at least its own, and
        // of its bucket's recordings it has most of the priorities.
        let mut surfaces = reference;
        let guide = random_sampling_tree(3);
        surfaces.refine(&guide);
        assert_eq!(surfaces.products[0].normal, wall);
        assert!(surfaces.product(wall).is_some() && surfaces.product(-wall).is_none());
        // The next iterations count the held normals exactly; the floor (13%) earns its
        // product once its bucket's two keys agree on it (85% of the bucket's recordings are
        // the floor's: each iteration, with its new samples, about 72% of the time), and the
        // one-offs none.
        for seed in 1..=3 {
            record_from_threads(&surfaces, &recordings(seed), 4);
            surfaces.refine(&guide);
        }
        let normals: Vec<Vec3> = surfaces.products.iter().map(|p| p.normal).collect();
        assert_eq!(normals, [wall, floor]);
        let kept = surfaces.tallied();
        assert!(matches!(
            kept[0],
            Tallied::Held {
                count: 0,
                product: true,
                ..
            }
        ));
        assert_eq!(surfaces.others(), 0);
        // An iteration that records no normal keeps the products (rebuilt for the new guide).
        surfaces.refine(&random_sampling_tree(4));
        assert_eq!(surfaces.products.len(), 2);
        // One where the floor falls under the share loses the floor's.
        for i in 0..400 {
            surfaces.record(wall, i);
        }
        surfaces.record(floor, 7);
        surfaces.refine(&guide);
        let normals: Vec<Vec3> = surfaces.products.iter().map(|p| p.normal).collect();
        assert_eq!(normals, [wall]);
    }

    #[test]
    fn a_bucket_whose_words_mix_two_normals_keeps_nothing() {
        // Two normals recorded with the same priority: each word keeps its larger half, the
        // words disagree whatever the order, and the bucket keeps no normal.
        let (a, b) = (Vec3::X, Vec3::Y);
        for order in [[a, b], [b, a]] {
            let s = Surfaces::default();
            for n in order {
                for _ in 0..40 {
                    s.slots[0].offer(key(n), n, 77 << 32 | 5);
                }
            }
            assert_eq!(s.slots[0].kept(), None);
        }
    }
}
