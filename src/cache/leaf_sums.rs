//! The optional `SELECTION`, `QUADRANTS`, `CONTINUATIONS` and `SURFACES` sections: each
//! spatial leaf's guide-probability sums, each directional leaf's quadrant sums, each spatial
//! leaf's continuation moments, and each spatial leaf's tally of normals. Files without them
//! load (older minors).

use super::*;

pub(super) fn encode_selection(trees: &[Region]) -> Vec<u8> {
    let mut out = Out(Vec::with_capacity(4 + SELECTION_LEN * trees.len()));
    out.u32(trees.len() as u32);
    for t in trees {
        let s = t.selection().sums();
        out.f32(t.selection().learned);
        out.u32(0);
        out.f64(s.gradient);
        out.f64(s.curvature);
        out.u64(s.count);
    }
    out.0
}

/// Reads the optional selection section into `trees` (already decoded).
pub(super) fn decode_selection(bytes: &[u8], trees: &mut [Region]) -> Result<(), CacheError> {
    let mut r = In {
        bytes,
        section: "selection",
    };
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
            gradient: r.f64()?,
            curvature: r.f64()?,
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

pub(super) fn encode_guide_cost(trees: &[Region]) -> Vec<u8> {
    let mut out = Out(Vec::with_capacity(4 + GUIDE_COST_LEN * trees.len()));
    out.u32(trees.len() as u32);
    for t in trees {
        let s = t.selection().sums();
        out.u32(u32::from(t.selection().off()));
        out.u32(0);
        out.f64(s.guided);
        out.f64(s.bsdf);
        out.f64(s.first);
        out.u64(s.uncovered);
    }
    out.0
}

/// Reads the optional guide-cost section into `trees` (already decoded, their selections
/// too).
pub(super) fn decode_guide_cost(bytes: &[u8], trees: &mut [Region]) -> Result<(), CacheError> {
    let mut r = In {
        bytes,
        section: "guide cost",
    };
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
            guided: r.f64()?,
            bsdf: r.f64()?,
            first: r.f64()?,
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

pub(super) fn encode_quadrants(trees: &[Region]) -> Vec<u8> {
    let mut out = Out(Vec::new());
    out.u32(trees.len() as u32);
    for t in trees {
        let q = &t.recording().quadrants;
        out.u32(q.len() as u32);
        for (s2, n) in q.iter().flat_map(|q| q.get()) {
            out.f64(s2);
            out.u64(n);
        }
    }
    out.0
}

/// Reads the optional quadrants section into `trees` (already decoded).
pub(super) fn decode_quadrants(bytes: &[u8], trees: &mut [Region]) -> Result<(), CacheError> {
    let section = "quadrants";
    let mut r = In { bytes, section };
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
            let mut q = [(0.0, 0); 4];
            for x in &mut q {
                *x = (r.f64()?, r.u64()?);
            }
            if !q.iter().all(|(s2, _)| s2.is_finite() && *s2 >= 0.0) {
                return Err(corrupt(
                    section,
                    format!("tree {i}, leaf {k}: quadrant sums {q:?}"),
                ));
            }
            *slot = AtomicQuadrants::from_quadrants(q);
        }
    }
    Ok(())
}

pub(super) fn encode_continuations(trees: &[Region]) -> Vec<u8> {
    let mut out = Out(Vec::with_capacity(4 + CONTINUATIONS_LEN * trees.len()));
    out.u32(trees.len() as u32);
    for t in trees {
        for e in [t.continuations().estimate, t.continuations().recorded()] {
            out.f64(e.sum);
            out.f64(e.sum_sq);
            out.f64(e.cost);
            out.u64(e.count);
        }
    }
    out.0
}

/// Reads the optional continuations section into `trees` (already decoded).
pub(super) fn decode_continuations(bytes: &[u8], trees: &mut [Region]) -> Result<(), CacheError> {
    let section = "continuations";
    let mut r = In { bytes, section };
    let n = r.count(CONTINUATIONS_LEN, "continuation estimates")?;
    if n != trees.len() {
        return Err(corrupt(
            section,
            format!("{n} continuation estimates for {} trees", trees.len()),
        ));
    }
    for (i, t) in trees.iter_mut().enumerate() {
        let mut read = || -> Result<ContinuationEstimate, CacheError> {
            Ok(ContinuationEstimate {
                sum: r.f64()?,
                sum_sq: r.f64()?,
                cost: r.f64()?,
                count: r.u64()?,
            })
        };
        let (estimate, recorded) = (read()?, read()?);
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
        let tallied = t.surfaces().tallied();
        out.u32(t.surfaces().others());
        out.u32(0);
        for k in 0..SLOTS {
            match tallied.get(k) {
                Some(s) => {
                    out.vec3(s.normal);
                    out.u32(s.count);
                    out.u32(SLOT_HELD | if s.product { SLOT_PRODUCT } else { 0 });
                }
                None => {
                    out.vec3(Vec3::ZERO);
                    out.u32(0);
                    out.u32(0);
                }
            }
        }
    }
    out.0
}

/// Reads the optional surfaces section into `trees` (already decoded, sampling trees
/// included): the tallies, and the products they ask for, rebuilt from the loaded guides.
pub(super) fn decode_surfaces(bytes: &[u8], trees: &mut [Region]) -> Result<(), CacheError> {
    let section = "surfaces";
    let mut r = In { bytes, section };
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
        let mut slots: Vec<Tallied> = Vec::with_capacity(SLOTS);
        for k in 0..SLOTS {
            let (normal, count, flags) = (r.vec3()?, r.u32()?, r.u32()?);
            if flags & SLOT_HELD == 0 {
                continue;
            }
            // A normal as `normalize` returns it: finite and of unit length to rounding, and
            // not one an earlier slot holds, bit for bit (a file written before the tally
            // folded the sign of zero may hold both signs of one normal: `0.0 == −0.0`).
            let unit = normal.is_finite() && (normal.length() - 1.0).abs() <= 1e-5;
            let bits = |n: Vec3| n.to_array().map(f32::to_bits);
            if !unit
                || flags > SLOT_HELD | SLOT_PRODUCT
                || slots.iter().any(|s| bits(s.normal) == bits(normal))
            {
                return Err(corrupt(
                    section,
                    format!("tree {i}, slot {k}: normal {normal}, flags {flags}"),
                ));
            }
            slots.push(Tallied {
                normal,
                count,
                product: flags & SLOT_PRODUCT != 0,
            });
        }
        t.set_tally(slots, others);
    }
    Ok(())
}
