//! The field handle: create, record, query, refine, statistics.

use crate::config::sdg_config;
use crate::error::{Failure, arg, fail, finite, finite_u, guard, put, sdg_status};
use crate::lock::shared;
use crate::types::{sdg_continuation, sdg_sample, sdg_splitting, sdg_vec3};
use glam::{Vec2, Vec3};
use parking_lot::RwLock;
use sdguide::{Aabb, GuidingField};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Arc;

/// A guiding field (opaque). Create with `sdg_field_create` or a load function; destroy with
/// `sdg_field_destroy`.
pub struct sdg_field {
    pub(crate) inner: Arc<RwLock<GuidingField>>,
}

pub(crate) fn new_handle(field: GuidingField) -> *mut sdg_field {
    Box::into_raw(Box::new(sdg_field {
        inner: Arc::new(RwLock::new(field)),
    }))
}

/// Creates a field over the box `[min, max]` with `config`, and stores its handle in `*out`.
///
/// # Safety
/// `config` must be null or point to an `sdg_config`; `out` must be null or valid for writing
/// a pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_create(
    config: *const sdg_config,
    min: sdg_vec3,
    max: sdg_vec3,
    out: *mut *mut sdg_field,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let c = unsafe { arg(config, "config") }?;
        let config = c.to_rust()?;
        if out.is_null() {
            return fail(sdg_status::NullPointer, "`out` is null");
        }
        let field = GuidingField::new(Aabb::new(min.into(), max.into()), config)
            .or_else(|e| fail(sdg_status::Config, e.to_string()))?;
        // SAFETY: checked non-null above; valid for writes by the caller's contract.
        unsafe { out.write(new_handle(field)) };
        Ok(sdg_status::Ok)
    })
}

/// Destroys a field. Null is ignored. Distributions taken from it stay valid until destroyed.
///
/// # Safety
/// `field` must be null or a handle from this library, not yet destroyed, that no other thread
/// is using.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_destroy(field: *mut sdg_field) {
    // SAFETY: created by `Box::into_raw` in `new_handle`, destroyed once (caller's contract).
    unsafe { destroy(field) }
}

/// Drops a handle C got from `Box::into_raw`; null is ignored, and a panic in the drop stays
/// on this side of the boundary.
///
/// # Safety
/// `handle` must be null or from `Box::into_raw`, and not yet destroyed.
pub(crate) unsafe fn destroy<T>(handle: *mut T) {
    if !handle.is_null() {
        // SAFETY: the caller's contract.
        let boxed = unsafe { Box::from_raw(handle) };
        let _ = catch_unwind(AssertUnwindSafe(move || drop(boxed)));
    }
}

/// Records one sample. Returns `SDG_STATUS_SAMPLE_REJECTED` (and counts it) for a sample the
/// field rejects; any number of threads may record at once.
///
/// # Safety
/// `field` and `sample` must be null or valid pointers.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_record(
    field: *const sdg_field,
    sample: *const sdg_sample,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (f, s) = unsafe { (arg(field, "field")?, arg(sample, "sample")?) };
        Ok(record(&shared(&f.inner), s))
    })
}

pub(crate) fn record(field: &GuidingField, s: &sdg_sample) -> sdg_status {
    let sample = s.to_rust();
    match field.try_record(&sample) {
        Ok(()) => sdg_status::Ok,
        Err(_) => sdg_status::SampleRejected,
    }
}

/// Records `count` samples. Rejected samples are counted in the statistics; the call returns
/// `SDG_STATUS_SAMPLE_REJECTED` if any was.
///
/// # Safety
/// `field` must be null or valid; `samples` must be null or point to `count` samples.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_record_batch(
    field: *const sdg_field,
    samples: *const sdg_sample,
    count: usize,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let f = unsafe { arg(field, "field") }?;
        if count == 0 {
            return Ok(sdg_status::Ok);
        }
        if samples.is_null() {
            return fail(sdg_status::NullPointer, "`samples` is null");
        }
        // SAFETY: non-null and pointing to `count` initialized samples (caller's contract).
        let batch = unsafe { std::slice::from_raw_parts(samples, count) };
        let field = shared(&f.inner);
        let mut status = sdg_status::Ok;
        for s in batch {
            if record(&field, s) != sdg_status::Ok {
                status = sdg_status::SampleRejected;
            }
        }
        Ok(status)
    })
}

/// Records one traced continuation of a path vertex, for roulette and splitting. Returns
/// `SDG_STATUS_SAMPLE_REJECTED` (and counts it) for one the field rejects (a position that is
/// not finite or out of bounds, a value or cost that is negative or not finite); any number of
/// threads may record at once.
///
/// # Safety
/// `field` and `continuation` must be null or valid pointers.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_record_continuation(
    field: *const sdg_field,
    continuation: *const sdg_continuation,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (f, c) = unsafe { (arg(field, "field")?, arg(continuation, "continuation")?) };
        Ok(
            match shared(&f.inner).try_record_continuation(&c.to_rust()) {
                Ok(()) => sdg_status::Ok,
                Err(_) => sdg_status::SampleRejected,
            },
        )
    })
}

/// Writes the splitting factor at `position` (see the Rust `Splitting::factor`): how many
/// continuations to trace in expectation (below 1, the survival probability), given the
/// path's throughput weight `throughput` and the pixel's `sqrt(I² + ε)` `pixel`. Writes 0 when
/// there is no factor (the cell's estimate is too thin, or an input is unusable): the renderer
/// then uses its own roulette. `SDG_STATUS_INVALID_ARGUMENT` for an unknown mode or bounds out
/// of range.
///
/// # Safety
/// `field` and `policy` must be null or valid; `factor` null or valid for writes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_splitting_factor(
    field: *const sdg_field,
    position: sdg_vec3,
    policy: *const sdg_splitting,
    throughput: f32,
    pixel: f32,
    factor: *mut f32,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (f, p) = unsafe { (arg(field, "field")?, arg(policy, "policy")?) };
        let splitting = p.to_rust()?;
        let estimate = shared(&f.inner).continuation(position.into());
        let q = splitting
            .factor(&estimate, throughput, pixel)
            .unwrap_or(0.0);
        // SAFETY: the caller's contract.
        unsafe { put(factor, "factor", q) }?;
        Ok(sdg_status::Ok)
    })
}

/// Draws a direction from the distribution at `position` with the uniform numbers `u0`, `u1`
/// (in [0, 1)): writes the unit direction and its solid-angle pdf.
///
/// # Safety
/// `field` must be null or valid; `direction` and `pdf` must be null or valid for writes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_sample(
    field: *const sdg_field,
    position: sdg_vec3,
    u0: f32,
    u1: f32,
    direction: *mut sdg_vec3,
    pdf: *mut f32,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let f = unsafe { arg(field, "field") }?;
        let x = finite(position.into(), "position")?;
        let (d, p) = sample(&shared(&f.inner), x, u0, u1)?;
        // SAFETY: the caller's contract.
        unsafe { write_sample(direction, pdf, d, p) }
    })
}

pub(crate) fn sample(
    field: &GuidingField,
    x: Vec3,
    u0: f32,
    u1: f32,
) -> Result<(Vec3, f32), Failure> {
    finite_u(u0, u1)?;
    Ok(field.distribution(x).sample(Vec2::new(u0, u1)))
}

/// # Safety
/// `direction` and `pdf` must be null or valid for writes.
pub(crate) unsafe fn write_sample(
    direction: *mut sdg_vec3,
    pdf: *mut f32,
    d: Vec3,
    p: f32,
) -> Result<sdg_status, Failure> {
    if direction.is_null() || pdf.is_null() {
        return fail(sdg_status::NullPointer, "`direction` or `pdf` is null");
    }
    // SAFETY: both non-null, valid for writes by the caller's contract.
    unsafe {
        direction.write(d.into());
        pdf.write(p);
    }
    Ok(sdg_status::Ok)
}

/// Writes the solid-angle pdf of drawing `direction` at `position` (0 for a zero direction).
///
/// # Safety
/// `field` must be null or valid; `pdf` must be null or valid for writes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_pdf(
    field: *const sdg_field,
    position: sdg_vec3,
    direction: sdg_vec3,
    pdf: *mut f32,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let f = unsafe { arg(field, "field") }?;
        let x = finite(position.into(), "position")?;
        let d = finite(direction.into(), "direction")?;
        let p = shared(&f.inner).distribution(x).pdf(d);
        // SAFETY: the caller's contract.
        unsafe { put(pdf, "pdf", p) }?;
        Ok(sdg_status::Ok)
    })
}

/// Ends an iteration (see the Rust `GuidingField::refine`). Takes the field exclusively: waits
/// for the calls in flight and until every distribution is destroyed; meanwhile new calls from
/// threads that hold no distribution wait behind it, so threads that keep recording cannot
/// starve it.
///
/// # Safety
/// `field` must be null or valid.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_refine(field: *mut sdg_field) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let f = unsafe { arg(field, "field") }?;
        f.inner.write().refine();
        Ok(sdg_status::Ok)
    })
}

/// A snapshot of a field's shape and bookkeeping.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct sdg_stats {
    /// Completed iterations.
    pub iteration: u32,
    /// Depth of the deepest spatial leaf.
    pub spatial_depth: u32,
    /// Depth of the deepest directional leaf.
    pub directional_depth: u32,
    /// Spatial tree nodes.
    pub spatial_nodes: u64,
    /// Spatial tree leaves.
    pub spatial_leaves: u64,
    /// Interior nodes over all sampling quadtrees.
    pub directional_nodes: u64,
    /// Leaves over all sampling quadtrees.
    pub directional_leaves: u64,
    /// Samples recorded in the current iteration.
    pub samples_recorded: u64,
    /// Samples recorded over the field's life.
    pub samples_recorded_total: u64,
    /// Continuations recorded in the current iteration (`sdg_field_record_continuation`).
    pub continuations_recorded: u64,
    /// Samples and continuations rejected over the field's life: non-finite position, out of
    /// bounds, bad direction, bad value, bad pdf.
    pub rejected: [u64; 5],
    /// Spatial splits refused by the caps.
    pub spatial_splits_refused: u64,
    /// Directional splits refused by the caps.
    pub directional_splits_refused: u64,
    /// Bytes held by the trees.
    pub bytes: u64,
    /// Samples and continuations recorded with a weight clamped to the range of the field's
    /// exact sums (above 2^48), over the field's life.
    pub clamped_samples: u64,
    /// Medium samples (`SDG_SAMPLE_VOLUME`) rejected over the field's life because it keeps no
    /// volume guides (`SDG_CONFIG_VOLUMES`).
    pub rejected_no_volume_guide: u64,
    /// Medium samples recorded in the current iteration (counted in `samples_recorded` too).
    pub volume_samples_recorded: u64,
    /// Interior nodes over the volume guides' quadtrees (counted in `directional_nodes` too).
    pub volume_directional_nodes: u64,
}

/// Writes the field's statistics to `*out`.
///
/// # Safety
/// `field` must be null or valid; `out` null or valid for writes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_stats(
    field: *const sdg_field,
    out: *mut sdg_stats,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let f = unsafe { arg(field, "field") }?;
        let s = shared(&f.inner).stats();
        let r = s.rejected;
        let stats = sdg_stats {
            iteration: s.iteration,
            spatial_depth: s.spatial_depth,
            directional_depth: s.directional_depth,
            spatial_nodes: s.spatial_nodes,
            spatial_leaves: s.spatial_leaves,
            directional_nodes: s.directional_nodes,
            directional_leaves: s.directional_leaves,
            samples_recorded: s.samples_recorded,
            samples_recorded_total: s.samples_recorded_total,
            continuations_recorded: s.continuations_recorded,
            rejected: [
                r.non_finite_position,
                r.out_of_bounds,
                r.bad_direction,
                r.bad_value,
                r.bad_pdf,
            ],
            spatial_splits_refused: s.spatial_splits_refused,
            directional_splits_refused: s.directional_splits_refused,
            bytes: s.bytes,
            clamped_samples: s.clamped_samples,
            rejected_no_volume_guide: r.no_volume_guide,
            volume_samples_recorded: s.volume_samples_recorded,
            volume_directional_nodes: s.volume_directional_nodes,
        };
        // SAFETY: the caller's contract.
        unsafe { put(out, "out", stats) }?;
        Ok(sdg_status::Ok)
    })
}
