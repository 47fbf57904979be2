//! Per-cell sample moments: `S1 = Σ v/p`, `S2 = Σ v²/p` and the count `n`.
//!
//! These three sums are all the field learns from. [`Moments`] is a plain snapshot;
//! [`AtomicMoments`] is what a directional leaf holds while render threads record into it:
//! lock-free adds, so any number of threads can record at once. The sums are `f64` — inputs are
//! `f32`, so `v²/p` of any finite input is finite in `f64`, and long iterations do not stall the
//! way an `f32` sum does once it passes 2²⁴ times the typical increment.

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

/// An `f64` that threads can add to concurrently (a compare-and-swap loop on its bits).
#[derive(Debug, Default)]
pub(crate) struct AtomicF64(AtomicU64);

impl AtomicF64 {
    pub(crate) fn new(x: f64) -> Self {
        Self(AtomicU64::new(x.to_bits()))
    }

    #[inline]
    pub(crate) fn add(&self, x: f64) {
        // Relaxed suffices: the sums are only read after `refine` has taken `&mut self`, which
        // synchronizes with every recording thread through whatever joined them.
        let mut old = self.0.load(Ordering::Relaxed);
        loop {
            let new = (f64::from_bits(old) + x).to_bits();
            match self
                .0
                .compare_exchange_weak(old, new, Ordering::Relaxed, Ordering::Relaxed)
            {
                Ok(_) => return,
                Err(current) => old = current,
            }
        }
    }

    pub(crate) fn get(&self) -> f64 {
        f64::from_bits(self.0.load(Ordering::Relaxed))
    }

    /// The value's bits, by a plain load.
    #[inline]
    fn bits(&self) -> u64 {
        self.0.load(Ordering::Relaxed)
    }

    /// Reads the value and leaves zero in its place, in one atomic step: an add racing with it
    /// lands either in what is returned or in what stays.
    pub(crate) fn take(&self) -> f64 {
        f64::from_bits(self.0.swap(0.0f64.to_bits(), Ordering::Relaxed))
    }

    /// [`add`](Self::add) with exclusive access: a plain add, no atomic instruction.
    #[inline]
    pub(crate) fn add_mut(&mut self, x: f64) {
        let bits = self.0.get_mut();
        *bits = (f64::from_bits(*bits) + x).to_bits();
    }

    /// [`take`](Self::take) with exclusive access.
    #[inline]
    pub(crate) fn take_mut(&mut self) -> f64 {
        f64::from_bits(std::mem::replace(self.0.get_mut(), 0.0f64.to_bits()))
    }
}

/// The moments of one directional leaf, updated in place by recording threads.
#[derive(Debug, Default)]
pub(crate) struct AtomicMoments {
    sum: AtomicF64,
    sum_sq: AtomicF64,
    count: AtomicU64,
}

impl AtomicMoments {
    /// Adds one sample with precomputed weights `(v/p, v²/p)`.
    #[inline]
    pub(crate) fn add(&self, weights: (f64, f64)) {
        self.add_sums(weights);
        self.add_count();
    }

    /// Adds weights without counting a sample (a filter's share of a sample counted elsewhere).
    #[inline]
    pub(crate) fn add_sums(&self, (w1, w2): (f64, f64)) {
        // Skipping the float adds for zero values keeps dark cells cheap.
        if w1 != 0.0 {
            self.sum.add(w1);
            self.sum_sq.add(w2);
        }
    }

    /// [`add_sums`](Self::add_sums) with exclusive access (no atomic instructions).
    #[inline]
    pub(crate) fn add_sums_mut(&mut self, (w1, w2): (f64, f64)) {
        if w1 != 0.0 {
            self.sum.add_mut(w1);
            self.sum_sq.add_mut(w2);
        }
    }

    /// Loads the first and last words by plain loads, which bring the cell's cache lines in
    /// without waiting for each other (see `quadtree::splat::Shares`); the result means nothing.
    #[inline]
    pub(crate) fn touch(&self) -> u64 {
        self.sum.bits() ^ self.count.load(Ordering::Relaxed)
    }

    /// Counts one sample.
    #[inline]
    pub(crate) fn add_count(&self) {
        self.count.fetch_add(1, Ordering::Relaxed);
    }

    /// Adds another cell's sums (merging workers' statistics), saturating: the count at
    /// `u64::MAX` and the sums at `f64::MAX`, so a merged field always saves a loadable cache.
    pub(crate) fn add_moments(&mut self, m: Moments) {
        let mine = self.get();
        *self = Self::from_moments(Moments {
            sum: (mine.sum + m.sum).min(f64::MAX),
            sum_sq: (mine.sum_sq + m.sum_sq).min(f64::MAX),
            count: mine.count.saturating_add(m.count),
        });
    }

    /// An accumulator holding `m` (loading a cache).
    pub(crate) fn from_moments(m: Moments) -> Self {
        Self {
            sum: AtomicF64::new(m.sum),
            sum_sq: AtomicF64::new(m.sum_sq),
            count: AtomicU64::new(m.count),
        }
    }

    pub(crate) fn get(&self) -> Moments {
        Moments {
            sum: self.sum.get(),
            sum_sq: self.sum_sq.get(),
            count: self.count.load(Ordering::Relaxed),
        }
    }
}

impl Clone for AtomicMoments {
    fn clone(&self) -> Self {
        Self::from_moments(self.get())
    }
}

/// Second-moment sums one level below a directional leaf: `Σ v²/p` and the count of the
/// samples that landed in each of its four quadrants. They are what refinement by variance gain
/// needs to estimate how much splitting the leaf would lower the optimal variance (see
/// [`crate::refinement`]). Only a sample's own leaf records them, unfiltered, so the four
/// quadrants of a leaf are always compared on the same samples.
#[derive(Debug, Default)]
pub(crate) struct AtomicQuadrants {
    sum_sq: [AtomicF64; 4],
    count: [AtomicU64; 4],
}

/// A snapshot of [`AtomicQuadrants`]: per quadrant `q = ix + 2·iy`, `(Σ v²/p, n)`.
pub(crate) type Quadrants = [(f64, u64); 4];

impl AtomicQuadrants {
    /// Counts one sample of second-moment weight `w2` in quadrant `q`.
    #[inline]
    pub(crate) fn add(&self, q: usize, w2: f64) {
        if w2 != 0.0 {
            self.sum_sq[q].add(w2);
        }
        self.count[q].fetch_add(1, Ordering::Relaxed);
    }

    /// [`AtomicMoments::touch`] for quadrant `q`'s words.
    #[inline]
    pub(crate) fn touch(&self, q: usize) -> u64 {
        self.sum_sq[q].bits() ^ self.count[q].load(Ordering::Relaxed)
    }

    pub(crate) fn get(&self) -> Quadrants {
        std::array::from_fn(|q| (self.sum_sq[q].get(), self.count[q].load(Ordering::Relaxed)))
    }

    pub(crate) fn from_quadrants(q: Quadrants) -> Self {
        Self {
            sum_sq: q.map(|(s, _)| AtomicF64::new(s)),
            count: q.map(|(_, n)| AtomicU64::new(n)),
        }
    }

    /// Adds another leaf's quadrant sums (saturating, like [`AtomicMoments::add_moments`]).
    pub(crate) fn add_quadrants(&mut self, other: Quadrants) {
        let mine = self.get();
        *self = Self::from_quadrants(std::array::from_fn(|q| {
            (
                (mine[q].0 + other[q].0).min(f64::MAX),
                mine[q].1.saturating_add(other[q].1),
            )
        }));
    }
}

impl Clone for AtomicQuadrants {
    fn clone(&self) -> Self {
        Self::from_quadrants(self.get())
    }
}

/// Sums one level below a directional leaf that [`DirectionalFilter::DeferredBox`] has yet to
/// spread: per quadrant `q`, `(Σ v/p, Σ v²/p)` of the samples recorded there since the last
/// spreading. One cache line per leaf, so that recording a sample touches one line for them.
///
/// [`DirectionalFilter::DeferredBox`]: crate::DirectionalFilter::DeferredBox
#[derive(Debug, Default)]
#[repr(align(64))]
pub(crate) struct AtomicPending {
    sum: [AtomicF64; 4],
    sum_sq: [AtomicF64; 4],
}

impl AtomicPending {
    /// Adds weights `(v/p, v²/p)` to quadrant `q`.
    #[inline]
    pub(crate) fn add(&self, q: usize, (w1, w2): (f64, f64)) {
        if w1 != 0.0 {
            self.sum[q].add(w1);
            self.sum_sq[q].add(w2);
        }
    }

    /// Each quadrant's `(Σ v/p, Σ v²/p)`, leaving zeros behind.
    pub(crate) fn take(&self) -> [(f64, f64); 4] {
        std::array::from_fn(|q| (self.sum[q].take(), self.sum_sq[q].take()))
    }

    /// [`take`](Self::take) with exclusive access (no atomic instructions).
    pub(crate) fn take_mut(&mut self) -> [(f64, f64); 4] {
        std::array::from_fn(|q| (self.sum[q].take_mut(), self.sum_sq[q].take_mut()))
    }
}

impl Clone for AtomicPending {
    fn clone(&self) -> Self {
        Self {
            sum: std::array::from_fn(|q| AtomicF64::new(self.sum[q].get())),
            sum_sq: std::array::from_fn(|q| AtomicF64::new(self.sum_sq[q].get())),
        }
    }
}
