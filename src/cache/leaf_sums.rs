//! The optional `SELECTION`, `QUADRANTS`, `CONTINUATIONS`, `SURFACES`, `GUIDE_COST` and
//! `PENDING` sections: each spatial leaf's guide-probability sums, each directional leaf's
//! quadrant sums, each spatial leaf's continuation moments and tally of normals, whether its
//! guide is off, and each directional leaf's sums the deferred filter has yet to spread. Files
//! without them load (older minors). Sums are exact (16 bytes each) from 3.0, `f64` in 2.x.

use super::*;

pub(super) fn encode_selection(trees: &[impl GuideView]) -> Vec<u8> {
    let mut out = Out(Vec::with_capacity(4 + SELECTION_LEN * trees.len()));
    out.u32(trees.len() as u32);
    for t in trees {
        let s = t.selection().sums();
        out.f32(t.selection().learned);
        out.u32(0);
        out.signed(s.gradient);
        out.sum(s.curvature);
        out.u64(s.count);
    }
    out.0
}

/// Reads the optional selection section into `trees` (already decoded).
pub(super) fn decode_selection(
    bytes: &[u8],
    trees: &mut [impl GuideViewMut],
    major: u16,
) -> Result<(), CacheError> {
    let mut r = In::with_sums(bytes, "selection", major);
    let n = r.count(SELECTION_LEN, "selections")?;
    if n != trees.len() {
        return Err(corrupt(
            "selection",
            format!("{n} selections for {} trees", trees.len()),
        ));
    }
    for (i, t) in trees.iter_mut().enumerate() {
        let probability = r.f32()?;
        r.u32()?;
        let sums = SelectionSums {
            gradient: r.signed()?,
            curvature: r.sum()?,
            count: r.u64()?,
            ..SelectionSums::default()
        };
        let in_range = (MIN_GUIDE_PROBABILITY..=MAX_GUIDE_PROBABILITY).contains(&probability);
        if !(in_range && sums.valid()) {
            return Err(corrupt(
                "selection",
                format!("tree {i}: probability {probability}, sums {sums:?}"),
            ));
        }
        t.set_selection(GuideSelection::from_parts(probability, false, sums));
    }
    Ok(())
}

pub(super) fn encode_guide_cost(trees: &[impl GuideView]) -> Vec<u8> {
    let mut out = Out(Vec::with_capacity(4 + GUIDE_COST_LEN * trees.len()));
    out.u32(trees.len() as u32);
    for t in trees {
        let s = t.selection().sums();
        out.u32(u32::from(t.selection().off()));
        out.u32(0);
        out.sum(s.guided);
        out.sum(s.bsdf);
        out.signed(s.first);
        out.u64(s.uncovered);
    }
    out.0
}

/// Reads the optional guide-cost section into `trees` (already decoded, their selections
/// too).
pub(super) fn decode_guide_cost(
    bytes: &[u8],
    trees: &mut [impl GuideViewMut],
    major: u16,
) -> Result<(), CacheError> {
    let mut r = In::with_sums(bytes, "guide cost", major);
    let n = r.count(GUIDE_COST_LEN, "guide costs")?;
    if n != trees.len() {
        return Err(corrupt(
            "guide cost",
            format!("{n} entries for {} trees", trees.len()),
        ));
    }
    for (i, t) in trees.iter_mut().enumerate() {
        let flags = r.u32()?;
        r.u32()?;
        let sums = SelectionSums {
            guided: r.sum()?,
            bsdf: r.sum()?,
            first: r.signed()?,
            uncovered: r.u64()?,
            ..t.selection().sums()
        };
        if flags > 1 || !sums.valid() {
            return Err(corrupt(
                "guide cost",
                format!("tree {i}: flags {flags}, sums {sums:?}"),
            ));
        }
        t.set_selection(GuideSelection::from_parts(
            t.selection().learned,
            flags == 1,
            sums,
        ));
    }
    Ok(())
}

pub(super) fn encode_quadrants(trees: &[impl GuideView]) -> Vec<u8> {
    let mut out = Out(Vec::new());
    out.u32(trees.len() as u32);
    for t in trees {
        let q = &t.recording().quadrants;
        out.u32(q.len() as u32);
        for (s2, n) in q.iter().flat_map(|q| q.exact()) {
            out.sum(s2);
            out.u64(n);
        }
    }
    out.0
}

/// Reads the optional quadrants section into `trees` (already decoded).
pub(super) fn decode_quadrants(
    bytes: &[u8],
    trees: &mut [impl GuideViewMut],
    major: u16,
) -> Result<(), CacheError> {
    let section = "quadrants";
    let mut r = In::with_sums(bytes, section, major);
    let n = r.count(4, "trees")?;
    if n != trees.len() {
        return Err(corrupt(
            section,
            format!("{n} trees of quadrant sums for {} trees", trees.len()),
        ));
    }
    for (i, t) in trees.iter_mut().enumerate() {
        let leaves = r.count(QUADRANTS_LEN, "leaves")?;
        if leaves != t.recording().moments.len() {
            return Err(corrupt(
                section,
                format!(
                    "tree {i}: {leaves} leaves of quadrant sums for {} leaves",
                    t.recording().moments.len()
                ),
            ));
        }
        for (k, slot) in t.recording_mut().quadrants.iter_mut().enumerate() {
            let mut q = [(Sum::ZERO, 0); 4];
            for x in &mut q {
                *x = (r.sum()?, r.u64()?);
            }
            let replaced = std::mem::replace(slot, AtomicQuadrants::from_exact(&q));
            // The leaf's count (`DIRECTIONAL`'s) is its quadrants'.
            if slot.count() != replaced.count() {
                return Err(corrupt(
                    section,
                    format!(
                        "tree {i}, leaf {k}: quadrant counts {} for a leaf count of {}",
                        slot.count(),
                        replaced.count()
                    ),
                ));
            }
        }
    }
    Ok(())
}

pub(super) fn encode_continuations(trees: &[Region]) -> Vec<u8> {
    let mut out = Out(Vec::with_capacity(4 + CONTINUATIONS_LEN * trees.len()));
    out.u32(trees.len() as u32);
    for t in trees {
        let e = t.continuations().estimate;
        out.f64(e.sum);
        out.f64(e.sum_sq);
        out.f64(e.cost);
        out.u64(e.count);
        let r = t.continuations().recorded();
        out.sum(r.sum);
        out.sum(r.sum_sq);
        out.sum(r.cost);
        out.u64(r.count);
    }
    out.0
}

/// Reads the optional continuations section into `trees` (already decoded).
pub(super) fn decode_continuations(
    bytes: &[u8],
    trees: &mut [Region],
    major: u16,
) -> Result<(), CacheError> {
    let section = "continuations";
    let mut r = In::with_sums(bytes, section, major);
    let n = r.count(CONTINUATIONS_LEN, "continuation estimates")?;
    if n != trees.len() {
        return Err(corrupt(
            section,
            format!("{n} continuation estimates for {} trees", trees.len()),
        ));
    }
    for (i, t) in trees.iter_mut().enumerate() {
        let estimate = ContinuationEstimate {
            sum: r.f64()?,
            sum_sq: r.f64()?,
            cost: r.f64()?,
            count: r.u64()?,
        };
        let recorded = ContinuationSums {
            sum: r.sum()?,
            sum_sq: r.sum()?,
            cost: r.sum()?,
            count: r.u64()?,
        };
        if !(estimate.is_valid() && recorded.is_valid()) {
            return Err(corrupt(
                section,
                format!("tree {i}: estimate {estimate:?}, recorded {recorded:?}"),
            ));
        }
        t.set_continuations(ContinuationStats::from_parts(estimate, recorded));
    }
    Ok(())
}

/// Flag of a `SURFACES` slot: it holds a normal.
const SLOT_HELD: u32 = 1;
/// Flag of a `SURFACES` slot: its normal has a stored product.
const SLOT_PRODUCT: u32 = 2;

pub(super) fn encode_surfaces(trees: &[Region]) -> Vec<u8> {
    let mut out = Out(Vec::with_capacity(4 + SURFACES_LEN * trees.len()));
    out.u32(trees.len() as u32);
    for t in trees {
        out.u32(t.surfaces().others());
        out.u32(0);
        for slot in t.surfaces().tallied() {
            match slot {
                Tallied::Held {
                    normal,
                    count,
                    product,
                } => {
                    out.u32(SLOT_HELD | if product { SLOT_PRODUCT } else { 0 });
                    out.u32(count);
                    out.u64(0);
                    for c in normal.to_array() {
                        out.u64(u64::from(c.to_bits()));
                    }
                    out.u64(0);
                }
                Tallied::Bucket { words, count } => {
                    out.u32(0);
                    out.u32(count);
                    for w in words {
                        out.u64(w);
                    }
                }
            }
        }
    }
    out.0
}

/// Reads the optional surfaces section into `trees` (already decoded, sampling trees
/// included): the tallies, and the products they ask for, rebuilt from the loaded guides.
pub(super) fn decode_surfaces(
    bytes: &[u8],
    trees: &mut [Region],
    major: u16,
) -> Result<(), CacheError> {
    let section = "surfaces";
    let mut r = In::with_sums(bytes, section, major);
    let n = r.count(SURFACES_LEN, "surface tallies")?;
    if n != trees.len() {
        return Err(corrupt(
            section,
            format!("{n} surface tallies for {} trees", trees.len()),
        ));
    }
    for (i, t) in trees.iter_mut().enumerate() {
        let others = r.u32()?;
        r.u32()?;
        let mut held: Vec<Tallied> = Vec::with_capacity(SLOTS);
        let mut buckets: Vec<Tallied> = Vec::with_capacity(SLOTS);
        for k in 0..SLOTS {
            let (flags, count, words) = if r.legacy {
                let (normal, count, flags) = (r.vec3()?, r.u32()?, r.u32()?);
                let bits = normal.to_array().map(|c| u64::from(c.to_bits()));
                (flags, count, [0, bits[0], bits[1], bits[2], 0])
            } else {
                let (flags, count) = (r.u32()?, r.u32()?);
                let mut words = [0; WORDS];
                for w in &mut words {
                    *w = r.u64()?;
                }
                (flags, count, words)
            };
            let bad = |what: String| corrupt(section, format!("tree {i}, slot {k}: {what}"));
            if flags > SLOT_HELD | SLOT_PRODUCT || flags == SLOT_PRODUCT {
                return Err(bad(format!("flags {flags}")));
            }
            if flags & SLOT_HELD == 0 {
                if r.legacy && count > 0 {
                    // A 2.x slot without a product, mid-iteration: which normal a 3.0 bucket
                    // would keep depends on priorities the file does not have.
                    return Err(CacheError::Inexact {
                        section,
                        value: f64::from(count),
                    });
                }
                let words = if r.legacy { [0; WORDS] } else { words };
                buckets.push(Tallied::Bucket { words, count });
                continue;
            }
            if r.legacy && flags & SLOT_PRODUCT == 0 {
                return Err(CacheError::Inexact {
                    section,
                    value: f64::from(count),
                });
            }
            // The normal's bits in the words' low halves, their high halves and the first word
            // zero; a normal as `normalize` returns it: finite, of unit length to rounding, and
            // not one an earlier slot holds, bit for bit.
            let normal = Vec3::from_array([1, 2, 3].map(|j| f32::from_bits(words[j] as u32)));
            let unit = normal.is_finite() && (normal.length() - 1.0).abs() <= 1e-5;
            let bits = |n: Vec3| n.to_array().map(f32::to_bits);
            let packed = words[0] == 0 && words[4] == 0 && words[1..4].iter().all(|w| w >> 32 == 0);
            let repeated = held
                .iter()
                .any(|s| matches!(s, Tallied::Held { normal: m, .. } if bits(*m) == bits(normal)));
            if !unit || !packed || repeated {
                return Err(bad(format!("normal {normal}, words {words:?}")));
            }
            held.push(Tallied::Held {
                normal,
                count,
                product: flags & SLOT_PRODUCT != 0,
            });
        }
        if r.legacy && others > 0 && held.len() < SLOTS {
            return Err(CacheError::Inexact {
                section,
                value: f64::from(others),
            });
        }
        held.extend(buckets);
        t.set_tally(held, others);
    }
    Ok(())
}

pub(super) fn encode_pending(trees: &[impl GuideView]) -> Vec<u8> {
    let mut out = Out(Vec::new());
    out.u32(trees.len() as u32);
    for t in trees {
        let p = &t.recording().pending;
        out.u32(p.len() as u32);
        for (s1, s2) in p.iter().flat_map(AtomicPending::exact) {
            out.sum(s1);
            out.sum(s2);
        }
    }
    out.0
}

/// Reads the optional pending section into `trees` (already decoded, their pending sums
/// prepared for the configured filter: a leaf count of 0 or the tree's).
pub(super) fn decode_pending(
    bytes: &[u8],
    trees: &mut [impl GuideViewMut],
) -> Result<(), CacheError> {
    let section = "pending";
    let mut r = In::new(bytes, section);
    let n = r.count(4, "trees")?;
    if n != trees.len() {
        return Err(corrupt(
            section,
            format!("{n} trees of pending sums for {} trees", trees.len()),
        ));
    }
    for (i, t) in trees.iter_mut().enumerate() {
        let leaves = r.count(128, "leaves")?;
        let pending = &mut t.recording_mut().pending;
        if leaves != pending.len() && leaves != 0 {
            return Err(corrupt(
                section,
                format!(
                    "tree {i}: {leaves} leaves of pending sums for {}",
                    pending.len()
                ),
            ));
        }
        for slot in pending.iter_mut().take(leaves) {
            let mut p = [(Sum::ZERO, Sum::ZERO); 4];
            for x in &mut p {
                *x = (r.sum()?, r.sum()?);
            }
            *slot = AtomicPending::from_exact(&p);
        }
    }
    Ok(())
}

pub(super) fn encode_signatures(trees: &[Region]) -> Vec<u8> {
    let mut out = Out(Vec::with_capacity(4 + SIGNATURE_LEN * trees.len()));
    out.u32(trees.len() as u32);
    for t in trees {
        let s = t.signature().unwrap_or_default();
        for &c in &s.counts {
            out.u64(c);
        }
        for &x in &s.sums {
            out.sum(x);
        }
    }
    out.0
}

/// Reads the optional signatures section into `trees` (already decoded, each with an empty
/// signature).
pub(super) fn decode_signatures(bytes: &[u8], trees: &mut [Region]) -> Result<(), CacheError> {
    let section = "signatures";
    let mut r = In::new(bytes, section);
    let n = r.count(SIGNATURE_LEN, "split signatures")?;
    if n != trees.len() {
        return Err(corrupt(
            section,
            format!("{n} split signatures for {} trees", trees.len()),
        ));
    }
    for t in trees.iter_mut() {
        let mut s = SignatureSums::default();
        for c in &mut s.counts {
            *c = r.u64()?;
        }
        for x in &mut s.sums {
            *x = r.sum()?;
        }
        t.set_signature_sums(&s);
    }
    Ok(())
}
