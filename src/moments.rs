//! Per-cell sample moments: `S1 = Σ v/p`, `S2 = Σ v²/p` and the count `n`.
//!
//! These three sums are all the field learns from. [`Moments`] is a plain snapshot;
//! [`AtomicMoments`] is what a directional leaf holds while render threads record into it:
//! lock-free adds, so any number of threads can record at once. The sums are exact fixed-point
//! integers ([`crate::exact`]): the same bits whatever order the samples arrive in; they are read
//! as `f64`, where `v²/p` of any finite `f32` input is finite.

use crate::exact::{AtomicSum, Sum};
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicU64, Ordering};

/// A snapshot of one cell's recorded statistics.
///
/// ```
/// use sdguide::Moments;
/// let mut m = Moments::default();
/// m.add(2.0, 0.5); // v = 2, p = 0.5
/// assert_eq!((m.sum, m.sum_sq, m.count), (4.0, 8.0, 1));
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Moments {
    /// `S1 = Σ v/p`: estimates `N·∫ v dω` over the cell.
    pub sum: f64,
    /// `S2 = Σ v²/p`: estimates `N·∫ v² dω` over the cell, noise of `v` included.
    pub sum_sq: f64,
    /// `n`: the number of samples, zero-valued ones included.
    pub count: u64,
}

impl Moments {
    /// Adds one sample of value `v` drawn with solid-angle density `p`.
    pub fn add(&mut self, v: f32, p: f32) {
        let (w1, w2) = weights(v, p);
        self.sum += w1;
        self.sum_sq += w2;
        self.count += 1;
    }
}

/// `(v/p, v²/p)` in `f64`.
#[inline]
pub(crate) fn weights(v: f32, p: f32) -> (f64, f64) {
    let w1 = f64::from(v) / f64::from(p);
    (w1, w1 * f64::from(v))
}

/// A cell's sums as they are kept: exact (see [`crate::exact`]), for caches and merges.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct ExactMoments {
    pub(crate) sum: Sum,
    pub(crate) sum_sq: Sum,
    pub(crate) count: u64,
}

impl ExactMoments {
    /// The sums as floats.
    pub(crate) fn moments(&self) -> Moments {
        Moments {
            sum: self.sum.value(),
            sum_sq: self.sum_sq.value(),
            count: self.count,
        }
    }
}

/// A directional leaf's `(Σ v/p, Σ v²/p)`, updated in place by recording threads: 32 bytes,
/// aligned so that a box filter's share writes one cache line. The leaf's count lives with its
/// quadrants' ([`AtomicQuadrants`]), which `record` writes for the sample's own leaf only.
#[derive(Debug, Default)]
#[repr(align(32))]
pub(crate) struct AtomicSums {
    sum: AtomicSum,
    sum_sq: AtomicSum,
}

impl AtomicSums {
    /// Adds weights `(v/p, v²/p)`.
    #[inline]
    pub(crate) fn add_sums(&self, (w1, w2): (f64, f64)) {
        self.sum.add(w1);
        self.sum_sq.add(w2);
    }

    /// [`add_sums`](Self::add_sums) with exclusive access (no atomic instructions).
    #[inline]
    pub(crate) fn add_sums_mut(&mut self, (w1, w2): (f64, f64)) {
        self.sum.add_mut(w1);
        self.sum_sq.add_mut(w2);
    }

    /// Loads a word by a plain load, which brings the sums' line in without waiting for the
    /// others a sample touches (see `quadtree::splat::Shares`); the result means nothing.
    #[inline]
    pub(crate) fn touch(&self) -> u64 {
        self.sum.touch()
    }

    /// The exact `(Σ v/p, Σ v²/p)`.
    pub(crate) fn exact(&self) -> (Sum, Sum) {
        (self.sum.sum(), self.sum_sq.sum())
    }

    pub(crate) fn from_exact((sum, sum_sq): (Sum, Sum)) -> Self {
        Self {
            sum: AtomicSum::new(sum.units()),
            sum_sq: AtomicSum::new(sum_sq.units()),
        }
    }

    /// Adds another leaf's sums (merging workers), saturating.
    pub(crate) fn add_exact(&mut self, (s1, s2): (Sum, Sum)) {
        let (a, b) = self.exact();
        *self = Self::from_exact((a.plus(s1), b.plus(s2)));
    }

    /// The sums, leaving zeros behind, with exclusive access.
    pub(crate) fn take_mut(&mut self) -> (Sum, Sum) {
        (self.sum.take_mut(), self.sum_sq.take_mut())
    }
}

impl Clone for AtomicSums {
    fn clone(&self) -> Self {
        Self::from_exact(self.exact())
    }
}

/// The moments of one cell with their count, updated in place by recording threads (the
/// technique sums of [`crate::TechniqueProbabilities`]).
#[derive(Debug, Default)]
pub(crate) struct AtomicMoments {
    sums: AtomicSums,
    count: AtomicU64,
}

impl AtomicMoments {
    /// Adds one sample with precomputed weights `(v/p, v²/p)`.
    #[inline]
    pub(crate) fn add(&self, weights: (f64, f64)) {
        self.sums.add_sums(weights);
        self.count.fetch_add(1, Ordering::Relaxed);
    }

    /// The exact sums.
    pub(crate) fn exact(&self) -> ExactMoments {
        let (sum, sum_sq) = self.sums.exact();
        ExactMoments {
            sum,
            sum_sq,
            count: self.count.load(Ordering::Relaxed),
        }
    }

    /// The sums as floats.
    pub(crate) fn get(&self) -> Moments {
        self.exact().moments()
    }
}

/// One quadrant of a directional leaf: `Σ v²/p` and the count of the samples that landed in it.
#[derive(Debug, Default)]
struct AtomicQuadrant {
    sum_sq: AtomicSum,
    count: AtomicU64,
}

/// Second-moment sums one level below a directional leaf: `Σ v²/p` and the count of the
/// samples that landed in each of its four quadrants. They are what refinement by variance gain
/// needs to estimate how much splitting the leaf would lower the optimal variance (see
/// [`crate::refinement`]), and their counts add up to the leaf's. Only a sample's own leaf
/// records them, unfiltered, so the four quadrants of a leaf are always compared on the same
/// samples. A quadrant's sum and count are adjacent: a sample writes one place.
#[derive(Debug, Default)]
pub(crate) struct AtomicQuadrants([AtomicQuadrant; 4]);

/// A snapshot of [`AtomicQuadrants`]: per quadrant `q = ix + 2·iy`, `(Σ v²/p, n)`.
pub(crate) type Quadrants = [(f64, u64); 4];

/// A leaf's own samples pooled from its quadrants: `(Σ v²/p, n)` (the count saturating).
pub(crate) fn own_sums(q: &Quadrants) -> (f64, u64) {
    q.iter().fold((0.0, 0u64), |(s2, n), &(s, c)| {
        (s2 + s, n.saturating_add(c))
    })
}

/// [`Quadrants`] as kept, exact.
pub(crate) type ExactQuadrants = [(Sum, u64); 4];

impl AtomicQuadrants {
    /// Counts one sample of second-moment weight `w2` in quadrant `q` (and so in the leaf).
    #[inline]
    pub(crate) fn add(&self, q: usize, w2: f64) {
        self.0[q].sum_sq.add(w2);
        self.0[q].count.fetch_add(1, Ordering::Relaxed);
    }

    /// [`AtomicSums::touch`] for quadrant `q`'s words.
    #[inline]
    pub(crate) fn touch(&self, q: usize) -> u64 {
        self.0[q].sum_sq.touch() ^ self.0[q].count.load(Ordering::Relaxed)
    }

    /// The leaf's count: its quadrants' (saturating: counts merged from many workers may be
    /// arbitrarily large).
    pub(crate) fn count(&self) -> u64 {
        self.0
            .iter()
            .fold(0, |n, q| n.saturating_add(q.count.load(Ordering::Relaxed)))
    }

    /// The sums as floats.
    pub(crate) fn get(&self) -> Quadrants {
        self.exact().map(|(s, n)| (s.value(), n))
    }

    pub(crate) fn exact(&self) -> ExactQuadrants {
        std::array::from_fn(|q| {
            (
                self.0[q].sum_sq.sum(),
                self.0[q].count.load(Ordering::Relaxed),
            )
        })
    }

    pub(crate) fn from_exact(q: &ExactQuadrants) -> Self {
        Self(q.map(|(s, n)| AtomicQuadrant {
            sum_sq: AtomicSum::new(s.units()),
            count: AtomicU64::new(n),
        }))
    }

    /// Adds another leaf's quadrant sums (saturating).
    pub(crate) fn add_exact(&mut self, other: &ExactQuadrants) {
        let mine = self.exact();
        *self = Self::from_exact(&std::array::from_fn(|q| {
            (
                mine[q].0.plus(other[q].0),
                mine[q].1.saturating_add(other[q].1),
            )
        }));
    }
}

impl Clone for AtomicQuadrants {
    fn clone(&self) -> Self {
        Self::from_exact(&self.exact())
    }
}

/// Sums one level below a directional leaf that [`DirectionalFilter::DeferredBox`] has yet to
/// spread: per quadrant `q`, `(Σ v/p, Σ v²/p)` of the samples recorded there since the last
/// spreading. A quadrant's two sums share 32 aligned bytes, so that recording a sample writes
/// one cache line for them.
///
/// [`DirectionalFilter::DeferredBox`]: crate::DirectionalFilter::DeferredBox
#[derive(Clone, Debug, Default)]
#[repr(align(64))]
pub(crate) struct AtomicPending([AtomicSums; 4]);

impl AtomicPending {
    /// Adds weights `(v/p, v²/p)` to quadrant `q`.
    #[inline]
    pub(crate) fn add(&self, q: usize, w: (f64, f64)) {
        self.0[q].add_sums(w);
    }

    /// Each quadrant's `(Σ v/p, Σ v²/p)`, leaving zeros behind. Exact when no thread records
    /// meanwhile (an add racing with it lands whole in neither, but in the two together).
    pub(crate) fn take(&self) -> [(f64, f64); 4] {
        std::array::from_fn(|q| {
            (
                take(&self.0[q].sum).value(),
                take(&self.0[q].sum_sq).value(),
            )
        })
    }

    /// Each quadrant's exact `(Σ v/p, Σ v²/p)`.
    pub(crate) fn exact(&self) -> [(Sum, Sum); 4] {
        std::array::from_fn(|q| self.0[q].exact())
    }

    pub(crate) fn from_exact(p: &[(Sum, Sum); 4]) -> Self {
        Self(p.map(AtomicSums::from_exact))
    }

    /// Adds another leaf's pending sums (merging workers), exactly.
    pub(crate) fn add_exact(&mut self, other: &[(Sum, Sum); 4]) {
        for (mine, &theirs) in self.0.iter_mut().zip(other) {
            mine.add_exact(theirs);
        }
    }

    /// [`take`](Self::take) with exclusive access (no atomic instructions).
    pub(crate) fn take_mut(&mut self) -> [(f64, f64); 4] {
        std::array::from_fn(|q| {
            let (s1, s2) = self.0[q].take_mut();
            (s1.value(), s2.value())
        })
    }
}

/// A shared sum read and zeroed (see [`AtomicPending::take`]).
fn take(s: &AtomicSum) -> Sum {
    let taken = s.sum();
    // Subtracting what was read keeps what raced in: integers, so nothing is lost or doubled.
    s.add_units(taken.units().wrapping_neg());
    taken
}
