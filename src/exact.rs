//! Exact sums: fixed-point integers that add the same bits whatever order the terms come in.
//!
//! Every statistic a field learns from is a sum over samples that render threads add to at
//! once. Floating-point addition is not associative, so an `f64` sum depends on the order the
//! samples arrive in, and with it every split and mass decided at `refine`. These sums are
//! integers instead: a term `x` is rounded once, on its own, to the nearest multiple of
//! `2^-FRACTION_BITS` ([`units`]), and integer addition is associative and commutative, so the
//! total is the same whatever the threads, their timing, or how many fields a farm splits the
//! samples over and merges in which order.
//!
//! **Range.** A sum is 128 bits, counted in units of `2^-40` (≈ 9.1e-13): a term below half a
//! unit adds nothing, and a term is clamped at `2^48` (≈ 2.8e14) — the field counts samples whose
//! weights were clamped in [`FieldStats::clamped_samples`](crate::FieldStats::clamped_samples).
//! A non-negative sum reads as saturated, `2^86` (≈ 7.7e25), from there on; it cannot wrap
//! unless more than `2^40` clamped terms land in one cell in one iteration. A signed sum
//! (the guide probability's gradient) adds in two's complement and is exact while its
//! magnitude stays below `2^87`. Rounding and clamping change a sum, not the estimator: the
//! guide they shape may be any density, and the uniform floor keeps it positive.
//!
//! **Cost.** A term below `2^24` adds with one `fetch_add` on the low word (its carry into the
//! high word is rare), where an `f64` sum needs a load and a compare-and-swap loop.

use std::sync::atomic::{AtomicU64, Ordering::Relaxed};

/// Fraction bits of a sum: one unit is `2^-40`.
pub(crate) const FRACTION_BITS: i32 = 40;
/// Units per 1.0.
const SCALE: f64 = (1u64 << FRACTION_BITS) as f64;
/// `1 / SCALE`, exact (a power of 2): a multiply where a division would cost more.
const UNIT: f64 = 1.0 / SCALE;
/// The largest term, in units (`2^88`, a value of `2^48`).
const MAX_TERM_UNITS: u128 = 1 << 88;
/// The largest term as a value (`2^48`): a weight above it is clamped.
pub(crate) const MAX_TERM: f64 = (1u64 << 48) as f64;
/// Where a non-negative sum saturates, in units (`2^126`).
const SATURATED_UNITS: u128 = 1 << 126;

/// `2^64`, the weight of a sum's high word.
const WORD: f64 = 18_446_744_073_709_551_616.0;

/// `2^52`: added to a float below it, rounds it to an integer in the mantissa's low bits.
const ROUNDER: f64 = 4_503_599_627_370_496.0;

/// `x` in units as `(low, high)` words, rounded to the nearest (ties to even), clamped to
/// `[0, 2^88]` (NaN gives 0). Most terms take the first branch: one multiply, one add and the
/// bits; `f64::round` and `f64 → u128` would be library calls on x86-64 without SSE4.1, and
/// this is the hot path of `record`.
#[inline]
pub(crate) fn unit_words(x: f64) -> (u64, u64) {
    let y = x * SCALE;
    if (0.0..ROUNDER).contains(&y) {
        ((y + ROUNDER).to_bits() - ROUNDER.to_bits(), 0)
    } else if (ROUNDER..WORD).contains(&y) {
        // At or above 2^52 a float is an integer.
        (y as u64, 0)
    } else {
        high_unit_words(y)
    }
}

/// [`unit_words`] of `y = x·2^40` outside `[0, 2^64)`.
#[inline(never)]
fn high_unit_words(y: f64) -> (u64, u64) {
    if y.is_nan() || y < 0.0 {
        (0, 0)
    } else if y < MAX_TERM_UNITS as f64 {
        // `y − high·2^64` is exact: a multiple of `y`'s ulp below 2^64.
        let high = (y / WORD) as u64;
        ((y - high as f64 * WORD) as u64, high)
    } else {
        (0, 1 << 24)
    }
}

/// `x` in units, rounded to the nearest, clamped to `[0, 2^88]` (NaN gives 0).
#[inline]
pub(crate) fn units(x: f64) -> u128 {
    let (lo, hi) = unit_words(x);
    u128::from(hi) << 64 | u128::from(lo)
}

/// `x` in units with its sign, clamped to `±2^88`, as a two's complement `u128`.
#[inline]
pub(crate) fn signed_units(x: f64) -> u128 {
    if x < 0.0 {
        units(-x).wrapping_neg()
    } else {
        units(x)
    }
}

/// Units as a float: the high word's part and the low word's, each rounded (one rounding when
/// the high word is 0; within an ulp otherwise, and a function of the integer alone).
#[inline]
fn units_value(u: u128) -> f64 {
    // Below 2^63 units (2^23 in value: nearly every sum) one signed conversion, a single
    // instruction on x86-64, gives the same value as the two words' (0·2^64 adds nothing).
    if let Ok(small) = i64::try_from(u) {
        return small as f64 * UNIT;
    }
    ((u >> 64) as u64 as f64 * WORD + u as u64 as f64) * UNIT
}

/// A non-negative exact sum, in units of `2^-40`, saturating at `2^126` units.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub(crate) struct Sum(u128);

impl Sum {
    pub(crate) const ZERO: Sum = Sum(0);

    /// The sum of raw recorded units (reads past the saturation point as saturated).
    pub(crate) fn from_units(u: u128) -> Self {
        Self(u.min(SATURATED_UNITS))
    }

    /// The sum holding `x`, rounded to units; what a term adds.
    #[cfg(test)]
    pub(crate) fn of(x: f64) -> Self {
        Self(units(x))
    }

    /// The units, as a cache stores them.
    pub(crate) fn units(self) -> u128 {
        self.0
    }

    /// The sum as a float.
    pub(crate) fn value(self) -> f64 {
        units_value(self.0)
    }

    pub(crate) fn is_zero(self) -> bool {
        self.0 == 0
    }

    /// Whether the sum reached its range's end.
    #[cfg(test)]
    pub(crate) fn saturated(self) -> bool {
        self.0 == SATURATED_UNITS
    }

    /// Both sums (merging fields), saturating: exact, associative and commutative.
    pub(crate) fn plus(self, other: Sum) -> Sum {
        Self((self.0 + other.0).min(SATURATED_UNITS))
    }

    /// The units read from a cache, if in range.
    pub(crate) fn checked(u: u128) -> Option<Self> {
        (u <= SATURATED_UNITS).then_some(Self(u))
    }

    /// `x` as a sum if it is one exactly: a multiple of a unit in range (converting a cache
    /// whose sums were floating point; zero always is).
    pub(crate) fn exactly(x: f64) -> Option<Self> {
        let y = x * SCALE;
        (y >= 0.0 && y.fract() == 0.0 && y <= SATURATED_UNITS as f64).then_some(Self(y as u128))
    }
}

/// A signed exact sum, in units of `2^-40`, in two's complement (exact while below `2^127`
/// units in magnitude, which takes more than `2^38` clamped terms).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub(crate) struct Signed(i128);

impl Signed {
    pub(crate) fn from_units(u: u128) -> Self {
        Self(u as i128)
    }

    /// The units, as a cache stores them (two's complement).
    pub(crate) fn units(self) -> u128 {
        self.0 as u128
    }

    pub(crate) fn value(self) -> f64 {
        if self.0 < 0 {
            -units_value(self.0.unsigned_abs())
        } else {
            units_value(self.0 as u128)
        }
    }

    pub(crate) fn is_zero(self) -> bool {
        self.0 == 0
    }

    /// Both sums (merging fields): two's complement, exact, associative and commutative.
    pub(crate) fn plus(self, other: Signed) -> Signed {
        Self(self.0.wrapping_add(other.0))
    }

    /// `x` as a signed sum if it is one exactly (see [`Sum::exactly`]).
    pub(crate) fn exactly(x: f64) -> Option<Self> {
        let y = x * SCALE;
        (y.fract() == 0.0 && y.abs() <= SATURATED_UNITS as f64).then_some(Self(y as i128))
    }
}

/// A 128-bit sum that threads add to at once: a low and a high word, the low word's carry
/// added to the high one by the thread whose add produced it. Reads are exact once the adds
/// are done (a read racing with an add may see its low word without its carry).
#[derive(Debug, Default)]
pub(crate) struct AtomicSum {
    lo: AtomicU64,
    hi: AtomicU64,
}

impl AtomicSum {
    pub(crate) fn new(units: u128) -> Self {
        Self {
            lo: AtomicU64::new(units as u64),
            hi: AtomicU64::new((units >> 64) as u64),
        }
    }

    /// Adds `units` (two's complement for a signed term).
    #[inline]
    pub(crate) fn add_units(&self, units: u128) {
        self.add_words(units as u64, (units >> 64) as u64);
    }

    /// Adds the units `(lo, hi)`.
    #[inline]
    fn add_words(&self, lo: u64, hi: u64) {
        // Relaxed suffices: sums are read after `refine` has taken `&mut self`, which
        // synchronizes with every recording thread through whatever joined them.
        let carry = lo != 0 && {
            let old = self.lo.fetch_add(lo, Relaxed);
            old.overflowing_add(lo).1
        };
        let hi = hi.wrapping_add(u64::from(carry));
        if hi != 0 {
            self.hi.fetch_add(hi, Relaxed);
        }
    }

    /// Adds the non-negative term `x`.
    #[inline]
    pub(crate) fn add(&self, x: f64) {
        let (lo, hi) = unit_words(x);
        self.add_words(lo, hi);
    }

    /// Adds the signed term `x`.
    #[inline]
    pub(crate) fn add_signed(&self, x: f64) {
        self.add_units(signed_units(x));
    }

    /// [`add`](Self::add) with exclusive access: no atomic instruction.
    #[inline]
    pub(crate) fn add_mut(&mut self, x: f64) {
        let (lo, hi) = unit_words(x);
        let (sum, carry) = self.lo.get_mut().overflowing_add(lo);
        *self.lo.get_mut() = sum;
        let h = self.hi.get_mut();
        *h = h.wrapping_add(hi).wrapping_add(u64::from(carry));
    }

    /// The raw units (two's complement for a signed sum).
    #[inline]
    pub(crate) fn raw(&self) -> u128 {
        u128::from(self.hi.load(Relaxed)) << 64 | u128::from(self.lo.load(Relaxed))
    }

    fn raw_mut(&mut self) -> u128 {
        u128::from(*self.hi.get_mut()) << 64 | u128::from(*self.lo.get_mut())
    }

    /// The low word by a plain load, to bring the line in (see `quadtree::splat::Shares`).
    #[inline]
    pub(crate) fn touch(&self) -> u64 {
        self.lo.load(Relaxed)
    }

    /// The sum, read as non-negative.
    pub(crate) fn sum(&self) -> Sum {
        Sum::from_units(self.raw())
    }

    /// The sum, read as signed.
    pub(crate) fn signed(&self) -> Signed {
        Signed::from_units(self.raw())
    }

    /// The non-negative sum, leaving zero behind, with exclusive access.
    pub(crate) fn take_mut(&mut self) -> Sum {
        let s = Sum::from_units(self.raw_mut());
        *self = Self::default();
        s
    }
}

impl Clone for AtomicSum {
    fn clone(&self) -> Self {
        Self::new(self.raw())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn terms_round_to_units_and_clamp() {
        assert_eq!(units(1.0), 1 << 40);
        assert_eq!(units(0.0), 0);
        assert_eq!(units(f64::NAN), 0);
        assert_eq!(units(-3.0), 0);
        // Below half a unit adds nothing; ties go to even.
        assert_eq!(units(0.4 / SCALE), 0);
        assert_eq!(units(0.5 / SCALE), 0);
        assert_eq!(units(1.5 / SCALE), 2);
        assert_eq!(units(0.6 / SCALE), 1);
        assert_eq!(units(-0.0), 0);
        assert_eq!(units(1e-30), 0);
        assert_eq!(units(f64::from(f32::MIN_POSITIVE) * 1e-3), 0);
        assert_eq!(units(1e30), MAX_TERM_UNITS);
        // Across the words: 2^70 units, and 2^64 + 2^20.
        assert_eq!(units(1073741824.0), 1 << 70);
        assert_eq!(units((WORD + 1048576.0) / SCALE), (1 << 64) + (1 << 20));
        assert_eq!(units(MAX_TERM * 0.75), 3 << 86);
        assert_eq!(units(f64::INFINITY), MAX_TERM_UNITS);
        assert_eq!(units(MAX_TERM), MAX_TERM_UNITS);
        assert_eq!(signed_units(-1.0) as i128, -(1i128 << 40));
    }

    #[test]
    fn a_small_sum_reads_as_the_two_words_would() {
        let words = |u: u128| ((u >> 64) as u64 as f64 * WORD + u as u64 as f64) * UNIT;
        let edge = 1u128 << 63;
        for u in [
            0,
            1,
            3 << 40,
            (1 << 53) + 1,
            edge - 1,
            edge,
            edge + 1,
            1 << 64,
            u128::MAX >> 2,
        ] {
            assert_eq!(units_value(u).to_bits(), words(u).to_bits(), "{u}");
        }
    }

    #[test]
    fn sums_carry_into_the_high_word_and_read_back() {
        let s = AtomicSum::default();
        for _ in 0..1000 {
            s.add(1e13); // ≈ 2^83 units: every add carries.
        }
        let expected = 1000 * units(1e13);
        assert_eq!(s.sum().units(), expected);
        assert!((s.sum().value() / (expected as f64 / SCALE) - 1.0).abs() < 1e-15);
        let mut m = AtomicSum::default();
        for _ in 0..1000 {
            m.add_mut(1e13);
        }
        assert_eq!(m.sum(), s.sum());
        let g = AtomicSum::default();
        g.add_signed(-2.5);
        g.add_signed(1.0);
        assert_eq!(g.signed().value(), -1.5);
        g.add_signed(1.5);
        assert!(g.signed().is_zero());
    }

    #[test]
    fn a_sum_saturates_where_the_range_ends_and_merges_stay_there() {
        // 2^38 clamped terms of 2^88 units reach 2^126: added as one merged sum.
        let near = Sum::from_units(SATURATED_UNITS - 1);
        assert!(!near.saturated());
        assert!(near.plus(Sum::of(MAX_TERM)).saturated());
        let s = AtomicSum::new(SATURATED_UNITS - 1);
        s.add(MAX_TERM);
        assert!(s.sum().saturated());
        assert!(s.sum().value().is_finite());
        // Saturating addition of non-negative sums is associative.
        let (a, b, c) = (near, Sum::of(MAX_TERM), Sum::of(1.0));
        assert_eq!(a.plus(b).plus(c), a.plus(b.plus(c)));
    }

    #[test]
    fn concurrent_adds_give_the_same_bits_in_any_order() {
        let terms: Vec<f64> = (0..4000u32)
            .map(|i| {
                f64::from(i.wrapping_mul(2_654_435_761) % 1000) * 1.37e-3 + 1e11 * f64::from(i % 7)
            })
            .collect();
        let sequential = AtomicSum::default();
        for &t in terms.iter().rev() {
            sequential.add(t);
        }
        let shared = AtomicSum::default();
        std::thread::scope(|s| {
            for chunk in terms.chunks(500) {
                let shared = &shared;
                s.spawn(move || chunk.iter().for_each(|&t| shared.add(t)));
            }
        });
        assert_eq!(shared.sum(), sequential.sum());
    }

    #[test]
    fn floats_convert_exactly_only_on_the_grid() {
        assert_eq!(Sum::exactly(0.0), Some(Sum::ZERO));
        assert_eq!(Sum::exactly(2.5), Some(Sum::of(2.5)));
        assert_eq!(Sum::exactly(0.1), None);
        assert_eq!(Sum::exactly(-1.0), None);
        assert_eq!(Sum::exactly(f64::NAN), None);
        assert_eq!(Signed::exactly(-2.5).map(Signed::value), Some(-2.5));
        assert_eq!(Signed::exactly(1e-20), None);
    }
}
