//! The batch calls: a field's queries over arrays, one lane per path vertex, for wavefront
//! renderers (see the Rust `GuidingField::sample_batch`). Each lane is the one-vertex call's
//! result to the bit; the lanes run in parallel inside the library.

use crate::error::{Failure, arg, fail, guard, sdg_status};
use crate::field::sdg_field;
use crate::lock::shared;
use crate::types::sdg_vec3;
use glam::{Vec2, Vec3};

// `sdg_vec3` and glam's `Vec3` are both three `f32` fields in `repr(C)`: an array of one is an
// array of the other, which the casts below rely on.
const _: () = assert!(size_of::<sdg_vec3>() == size_of::<Vec3>());
const _: () = assert!(align_of::<sdg_vec3>() == align_of::<Vec3>());

/// `count` entries at `ptr`, or an empty slice for `count == 0` (the pointer may then be null).
///
/// # Safety
/// Unless `count` is 0, `ptr` must be null or point to `count` initialized `T`s that nothing
/// writes while the slice lives.
unsafe fn input<'a, T>(ptr: *const T, count: usize, name: &str) -> Result<&'a [T], Failure> {
    if count == 0 {
        return Ok(&[]);
    }
    if ptr.is_null() {
        return fail(sdg_status::NullPointer, format!("`{name}` is null"));
    }
    // SAFETY: non-null and valid for `count` elements (the caller's contract).
    Ok(unsafe { std::slice::from_raw_parts(ptr, count) })
}

/// [`input`] for an array the call writes.
///
/// # Safety
/// Unless `count` is 0, `ptr` must be null or valid for writing `count` `T`s, and nothing else
/// may access them while the slice lives.
unsafe fn output<'a, T>(ptr: *mut T, count: usize, name: &str) -> Result<&'a mut [T], Failure> {
    if count == 0 {
        return Ok(&mut []);
    }
    if ptr.is_null() {
        return fail(sdg_status::NullPointer, format!("`{name}` is null"));
    }
    // SAFETY: non-null, valid for `count` elements and not aliased (the caller's contract).
    Ok(unsafe { std::slice::from_raw_parts_mut(ptr, count) })
}

/// The vectors of a C array as glam's (the same layout, asserted above).
fn vectors(v: &[sdg_vec3]) -> &[Vec3] {
    // SAFETY: `sdg_vec3` and `Vec3` have the same size, alignment and fields.
    unsafe { std::slice::from_raw_parts(v.as_ptr().cast::<Vec3>(), v.len()) }
}

/// A lane whose entry is not finite, as an `SDG_STATUS_INVALID_ARGUMENT` failure.
fn all_finite(name: &str, finite: impl Iterator<Item = bool>) -> Result<(), Failure> {
    match finite.enumerate().find(|(_, ok)| !ok) {
        Some((lane, _)) => fail(
            sdg_status::InvalidArgument,
            format!("`{name}` of lane {lane} is not finite"),
        ),
        None => Ok(()),
    }
}

/// For each of `count` lanes `i`, draws a direction from the distribution at `positions[i]`
/// (with `normals` not null, its product with the cosine about `normals[i]`; a zero normal
/// gives the plain distribution) with the uniform numbers `u[2i]`, `u[2i + 1]`: writes the unit
/// direction into `directions[i]` and its solid-angle pdf into `pdfs[i]`.
/// `SDG_STATUS_INVALID_ARGUMENT` (and nothing written) when a position, normal or number is not
/// finite.
///
/// # Safety
/// `field` must be null or valid; unless `count` is 0, `positions`, `directions` and `pdfs`
/// must be null or point to `count` entries, `u` to `2·count`, and `normals` be null or point
/// to `count`; the outputs must not overlap the inputs.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_sample_batch(
    field: *const sdg_field,
    count: usize,
    positions: *const sdg_vec3,
    normals: *const sdg_vec3,
    u: *const f32,
    directions: *mut sdg_vec3,
    pdfs: *mut f32,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract, for each array.
        let (f, x, uu, d, p) = unsafe {
            (
                arg(field, "field")?,
                input(positions, count, "positions")?,
                input(u, count.saturating_mul(2), "u")?,
                output(directions, count, "directions")?,
                output(pdfs, count, "pdfs")?,
            )
        };
        let n = (!normals.is_null())
            // SAFETY: non-null, so `count` entries (the caller's contract).
            .then(|| unsafe { input(normals, count, "normals") })
            .transpose()?;
        let (x, n) = (vectors(x), n.map(vectors));
        all_finite("positions", x.iter().map(|v| v.is_finite()))?;
        all_finite(
            "normals",
            n.iter().flat_map(|n| n.iter().map(|v| v.is_finite())),
        )?;
        all_finite("u", uu.iter().map(|v| v.is_finite()))?;
        // SAFETY: `2·count` floats are `count` pairs of the same layout as `Vec2`.
        let uu = unsafe { std::slice::from_raw_parts(uu.as_ptr().cast::<Vec2>(), count) };
        // SAFETY: the output vectors have `Vec3`'s layout (asserted above).
        let d = unsafe { std::slice::from_raw_parts_mut(d.as_mut_ptr().cast::<Vec3>(), count) };
        shared(&f.inner)
            .sample_batch(x, n, uu, d, p)
            .or_else(|e| fail(sdg_status::InvalidArgument, e.to_string()))?;
        Ok(sdg_status::Ok)
    })
}

/// For each of `count` lanes `i`, writes into `pdfs[i]` the solid-angle pdf of
/// `directions[i]` under the distribution at `positions[i]` (with `normals` not null, its
/// product with the cosine about `normals[i]`). `SDG_STATUS_INVALID_ARGUMENT` (and nothing
/// written) when a position, normal or direction is not finite.
///
/// # Safety
/// `field` must be null or valid; unless `count` is 0, `positions`, `directions` and `pdfs`
/// must be null or point to `count` entries, and `normals` be null or point to `count`; `pdfs`
/// must not overlap the inputs.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_pdf_batch(
    field: *const sdg_field,
    count: usize,
    positions: *const sdg_vec3,
    normals: *const sdg_vec3,
    directions: *const sdg_vec3,
    pdfs: *mut f32,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract, for each array.
        let (f, x, d, p) = unsafe {
            (
                arg(field, "field")?,
                input(positions, count, "positions")?,
                input(directions, count, "directions")?,
                output(pdfs, count, "pdfs")?,
            )
        };
        let n = (!normals.is_null())
            // SAFETY: non-null, so `count` entries (the caller's contract).
            .then(|| unsafe { input(normals, count, "normals") })
            .transpose()?;
        let (x, d, n) = (vectors(x), vectors(d), n.map(vectors));
        all_finite("positions", x.iter().map(|v| v.is_finite()))?;
        all_finite("directions", d.iter().map(|v| v.is_finite()))?;
        all_finite(
            "normals",
            n.iter().flat_map(|n| n.iter().map(|v| v.is_finite())),
        )?;
        shared(&f.inner)
            .pdf_batch(x, n, d, p)
            .or_else(|e| fail(sdg_status::InvalidArgument, e.to_string()))?;
        Ok(sdg_status::Ok)
    })
}

/// For each of `count` lanes `i`, writes into `probabilities[i]` the guide probability at
/// `positions[i]` (see `sdg_distribution_guide_probability`). `SDG_STATUS_INVALID_ARGUMENT`
/// (and nothing written) when a position is not finite.
///
/// # Safety
/// `field` must be null or valid; unless `count` is 0, `positions` and `probabilities` must be
/// null or point to `count` entries that do not overlap.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_guide_probability_batch(
    field: *const sdg_field,
    count: usize,
    positions: *const sdg_vec3,
    probabilities: *mut f32,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract, for each array.
        let (f, x, a) = unsafe {
            (
                arg(field, "field")?,
                input(positions, count, "positions")?,
                output(probabilities, count, "probabilities")?,
            )
        };
        let x = vectors(x);
        all_finite("positions", x.iter().map(|v| v.is_finite()))?;
        shared(&f.inner)
            .guide_probability_batch(x, a)
            .or_else(|e| fail(sdg_status::InvalidArgument, e.to_string()))?;
        Ok(sdg_status::Ok)
    })
}
