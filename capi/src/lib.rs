//! The C ABI of sdguide, for C and C++ path tracers.
//!
//! Opaque handles (`sdg_field`, `sdg_distribution`), plain C types (`sdg_vec3`, `sdg_config`,
//! `sdg_sample`, `sdg_stats`), and a status code from every fallible function; the message of
//! the last failure on the calling thread is `sdg_last_error()`. No panic crosses the boundary:
//! every entry point catches unwinding and reports `SDG_STATUS_PANIC`.
//!
//! Thread safety is enforced here, not left to the caller: a field lives behind a reader-writer
//! lock. Recording and queries (`sdg_field_record*`, `sdg_field_sample`, `sdg_field_pdf`,
//! `sdg_field_distribution`, `sdg_field_stats`, saving) take it shared and run from any number of
//! threads at once; `sdg_field_refine` and `sdg_field_merge` take it exclusively, waiting for
//! every shared user — including every live `sdg_distribution`, which holds the lock shared until
//! destroyed. The lock costs one atomic increment and decrement per call (tens of nanoseconds,
//! contended only by a refine).
//!
//! The lock is fair to writers: once a refine or merge waits, a new shared call blocks until it
//! is done, so render threads that record and query without pause cannot starve it; it waits
//! only for the calls in flight and the live distributions. The one exception keeps it free of
//! deadlock: a thread that holds a distribution is let in while a writer waits (the writer waits
//! for that distribution, so blocking its thread would wait forever). A render loop therefore
//! either destroys each distribution when its vertex is done (then `sdg_field_refine` can be
//! called at any time, from any thread, and pauses the workers for its duration), or stops its
//! workers between passes.
//!
//! This crate is the only place in sdguide with `unsafe` code: reading and writing through the
//! pointers C passes in. Each use states what it relies on.

#![allow(non_camel_case_types)]
#![deny(missing_docs)]

use glam::{Vec2, Vec3};
use parking_lot::lock_api::ArcRwLockReadGuard;
use parking_lot::{RawRwLock, RwLock};
use sdguide::{
    Aabb, Continuation, DirectionalFilter, GuidingConfig, GuidingField, LeafRule, Refinement,
    Sample, SpatialFilter, Splitting, SplittingMode,
};
use std::cell::{Cell, RefCell};
use std::ffi::{CStr, CString, c_char};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Arc;

/// What a call did. Negative values are errors; see `sdg_last_error()` for the message.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum sdg_status {
    /// Success.
    Ok = 0,
    /// The sample was rejected (bad value, pdf, direction or position) and counted in the
    /// field's statistics. Not an error: recording goes on.
    SampleRejected = 1,
    /// A required pointer was null.
    NullPointer = -1,
    /// An argument was out of range (NaN coordinates, a path that is not UTF-8, ...).
    InvalidArgument = -2,
    /// The configuration or the bounds were out of range.
    Config = -3,
    /// A file could not be read or written.
    Io = -4,
    /// A cache was malformed.
    Cache = -5,
    /// The fields cannot be merged.
    Merge = -6,
    /// The library panicked (a bug); the field may be in an unspecified but memory-safe state.
    Panic = -7,
}

/// Leaf rule `L1`: mass proportional to the mean.
pub const SDG_RULE_L1: u32 = 0;
/// Leaf rule `L2`: the variance-optimal rule (the default).
pub const SDG_RULE_L2: u32 = 1;
/// The L2 rule for the renderer's estimator inside the guide–BSDF mixture (samples recorded
/// with their mixture terms).
pub const SDG_RULE_L2_MIXTURE: u32 = 2;

/// Filter: record into the cell containing the sample only.
pub const SDG_FILTER_NEAREST: u32 = 0;
/// Spatial filter: move the position by a random offset within its leaf (hash-derived).
pub const SDG_FILTER_STOCHASTIC: u32 = 1;
/// Filter: spread the sample over the cells a cell-sized box around it overlaps.
pub const SDG_FILTER_BOX: u32 = 2;
/// Directional filter: the box filter applied at refine to each leaf quadrant's sums (records
/// in about half the time of `SDG_FILTER_BOX`).
pub const SDG_FILTER_DEFERRED_BOX: u32 = 3;

/// Refinement: split directional cells by their share of the mass (`subdivision_threshold`).
pub const SDG_REFINEMENT_FLUX_SHARE: u32 = 0;
/// Refinement: split directional cells by the variance the split removes (`gain_threshold`;
/// the default).
pub const SDG_REFINEMENT_VARIANCE_GAIN: u32 = 1;

/// A 3D vector (world space).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct sdg_vec3 {
    /// x
    pub x: f32,
    /// y
    pub y: f32,
    /// z
    pub z: f32,
}

impl From<sdg_vec3> for Vec3 {
    fn from(v: sdg_vec3) -> Vec3 {
        Vec3::new(v.x, v.y, v.z)
    }
}

impl From<Vec3> for sdg_vec3 {
    fn from(v: Vec3) -> sdg_vec3 {
        sdg_vec3 {
            x: v.x,
            y: v.y,
            z: v.z,
        }
    }
}

/// The field's configuration; `sdg_config_default` fills in the defaults. Fields mean what the
/// same-named fields of the Rust `GuidingConfig` mean.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct sdg_config {
    /// `SDG_RULE_L1`, `SDG_RULE_L2` or `SDG_RULE_L2_MIXTURE`.
    pub rule: u32,
    /// `c`: spatial leaves split past `c·sqrt(2^k)` samples in iteration `k`.
    pub spatial_threshold: f32,
    /// `ρ`: directional cells split while their share of the mass exceeds it.
    pub subdivision_threshold: f32,
    /// Deepest directional level, 1..=20.
    pub max_directional_depth: u32,
    /// Share of every distribution spread uniformly, in [1e-9, 1].
    pub uniform_fraction: f32,
    /// Interior nodes per directional tree, 1..=65535.
    pub max_directional_nodes: u32,
    /// Spatial tree nodes.
    pub max_spatial_nodes: u32,
    /// Memory budget in bytes.
    pub max_memory_bytes: u64,
    /// `n0`: samples' worth of weight a directional cell's estimate gives its parent's in the
    /// leaf masses; >= 0.
    pub prior_samples: f32,
    /// `SDG_FILTER_NEAREST`, `SDG_FILTER_STOCHASTIC` or `SDG_FILTER_BOX`.
    pub spatial_filter: u32,
    /// `SDG_FILTER_NEAREST`, `SDG_FILTER_BOX` or `SDG_FILTER_DEFERRED_BOX`.
    pub directional_filter: u32,
    /// `SDG_REFINEMENT_FLUX_SHARE` or `SDG_REFINEMENT_VARIANCE_GAIN`.
    pub refinement: u32,
    /// `τ`: directional cells split while the split lowers `Σ sqrt(m)` by more than `τ` times it.
    pub gain_threshold: f32,
    /// The largest guide probability a leaf learns, in [0.5, 0.95].
    pub max_guide_probability: f32,
    /// What sampling the guide adds to a path vertex's cost, relative, in [0, 100]: a leaf
    /// whose guide does not lower the variance below `1/(1 + guide_cost)` of BSDF sampling's
    /// turns it off (guide probability 0). Negative: the guide never turns off.
    pub guide_cost: f32,
}

/// One recorded path vertex (see the Rust `Sample`): at `position`, light of `value` arrived
/// from `direction`, which was drawn with solid-angle density `pdf` (the full mixture pdf).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct sdg_sample {
    /// Where the light arrived.
    pub position: sdg_vec3,
    /// Where it came from (need not be normalized).
    pub direction: sdg_vec3,
    /// Non-negative estimate of what arrived (luminance).
    pub value: f32,
    /// Solid-angle density the direction was drawn with (the full mixture pdf).
    pub pdf: f32,
    /// Mixture terms for learning the guide probability (see
    /// `sdg_distribution_guide_probability`): the integrand `L·f_s·|cos|` at the direction, and
    /// the BSDF's and the guide's pdfs of it. All three 0: no mixture terms.
    pub integrand: f32,
    /// The BSDF sampling pdf of the direction.
    pub bsdf_pdf: f32,
    /// The guide's pdf of the direction.
    pub guide_pdf: f32,
    /// The shading normal at `position`, the one set with `sdg_distribution_set_normal` there
    /// (see the Rust `Sample::normal`: a cell stores the product with the cosine for its most
    /// frequent normals, which makes those queries about as cheap as plain ones). Zero or not
    /// finite: none.
    pub normal: sdg_vec3,
    /// An estimate of `value²` without the variance the renderer's Russian roulette added to
    /// `value` (see the Rust `Sample::second_moment`: with throughput roulette, `value²` rises
    /// with the pdf, and the l2 rule would keep directions the guide already favours). 0: none,
    /// `value²` is used (a positive value's estimate is never 0).
    pub second_moment: f32,
}

/// Splitting mode: Russian roulette only (factors up to 1).
pub const SDG_SPLITTING_ROULETTE: u32 = 0;
/// Splitting mode: roulette and splitting (factors up to `max_splits`).
pub const SDG_SPLITTING_ROULETTE_AND_SPLITTING: u32 = 1;

/// One traced continuation of a path vertex (see the Rust `Continuation`): at `position`, the
/// continuation's estimate `value` of the light the vertex reflects (`f·cos·L_i/p`, with every
/// roulette and splitting weight below the vertex and not the vertex's own), and its `cost`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct sdg_continuation {
    /// The vertex.
    pub position: sdg_vec3,
    /// Non-negative estimate of the reflected light (luminance).
    pub value: f32,
    /// Non-negative cost of tracing the continuation (rays, say).
    pub cost: f32,
}

/// The image-wide terms of efficiency-aware roulette and splitting (see the Rust `Splitting`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct sdg_splitting {
    /// `SDG_SPLITTING_ROULETTE` or `SDG_SPLITTING_ROULETTE_AND_SPLITTING`.
    pub mode: u32,
    /// The image's per-sample relative variance, averaged over pixels.
    pub relative_variance: f64,
    /// The mean cost of a camera sample, in the unit of `sdg_continuation::cost`.
    pub cost: f64,
    /// The smallest survival probability, in (0, 1] (0.05 is the library's default).
    pub min_survival: f32,
    /// The largest factor, finite and at least 1 (8 is the library's default).
    pub max_splits: f32,
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
}

/// A guiding field (opaque). Create with `sdg_field_create` or a load function; destroy with
/// `sdg_field_destroy`.
pub struct sdg_field {
    inner: Arc<RwLock<GuidingField>>,
}

/// The distribution of one position (opaque), from `sdg_field_distribution`. It holds the
/// field's lock shared: destroy it with `sdg_distribution_destroy` before refining, or the
/// refine waits for it.
pub struct sdg_distribution {
    field: ArcRwLockReadGuard<RawRwLock, GuidingField>,
    position: Vec3,
    /// The surface normal set by `sdg_distribution_set_normal` (zero: none).
    normal: Vec3,
    /// The thread that made it, whose count of held distributions it is in.
    owner: std::thread::ThreadId,
}

impl Drop for sdg_distribution {
    fn drop(&mut self) {
        // Destroyed on another thread, the owner's count stays up: its calls keep re-entering,
        // which can delay a writer but never deadlock.
        if std::thread::current().id() == self.owner {
            HELD.with(|h| h.set(h.get().saturating_sub(1)));
        }
    }
}

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
    /// Live distributions this thread made: while any is held, its shared calls re-enter.
    static HELD: Cell<u32> = const { Cell::new(0) };
}

/// Whether this thread's shared acquisitions re-enter past a waiting writer: it holds a
/// distribution, which the writer waits for (see the crate documentation).
fn reentrant() -> bool {
    HELD.with(Cell::get) > 0
}

/// Shared access for one call: behind a waiting writer (fair), unless [`reentrant`].
fn shared(lock: &RwLock<GuidingField>) -> parking_lot::RwLockReadGuard<'_, GuidingField> {
    if reentrant() {
        lock.read_recursive()
    } else {
        lock.read()
    }
}

/// The message of the last failed call on this thread (empty if none failed). The pointer stays
/// valid until the next failing call on this thread.
#[unsafe(no_mangle)]
pub extern "C" fn sdg_last_error() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

/// A failure: its status and message.
struct Failure(sdg_status, String);

fn fail<T>(status: sdg_status, message: impl Into<String>) -> Result<T, Failure> {
    Err(Failure(status, message.into()))
}

/// Runs an entry point: catches panics, records the message of a failure, returns the status.
fn guard(f: impl FnOnce() -> Result<sdg_status, Failure>) -> sdg_status {
    let Failure(status, message) = match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(status)) => return status,
        Ok(Err(failure)) => failure,
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            Failure(sdg_status::Panic, format!("internal error: {what}"))
        }
    };
    let message = CString::new(message.replace('\0', " ")).unwrap_or_default();
    LAST_ERROR.with(|e| *e.borrow_mut() = message);
    status
}

/// The referent of a pointer C passed in, or a `NullPointer` failure naming the argument.
///
/// # Safety
/// `ptr` must be null or point to a live, properly aligned `T` for the returned lifetime.
unsafe fn arg<'a, T>(ptr: *const T, name: &str) -> Result<&'a T, Failure> {
    // SAFETY: the caller's contract; null is checked here.
    match unsafe { ptr.as_ref() } {
        Some(r) => Ok(r),
        None => fail(sdg_status::NullPointer, format!("`{name}` is null")),
    }
}

/// Writes `value` through an out-pointer, or fails if it is null.
///
/// # Safety
/// `ptr` must be null or valid for a write of a `T`.
unsafe fn put<T>(ptr: *mut T, name: &str, value: T) -> Result<(), Failure> {
    if ptr.is_null() {
        return fail(sdg_status::NullPointer, format!("`{name}` is null"));
    }
    // SAFETY: non-null, and valid for writes by the caller's contract; `write` does not read
    // or drop the (possibly uninitialized) old value.
    unsafe { ptr.write(value) };
    Ok(())
}

fn finite(v: Vec3, name: &str) -> Result<Vec3, Failure> {
    if v.is_finite() {
        Ok(v)
    } else {
        fail(
            sdg_status::InvalidArgument,
            format!("`{name}` is not finite: {v}"),
        )
    }
}

/// What `sdg_config_default` says of a default this C API has no constant for (the library's
/// enums may grow; this crate is built with the library, so it does not happen).
const UNEXPRESSED: &str = "the library's default has no constant in this version of the C API";

/// Fills `out` with the default configuration.
///
/// # Safety
/// `out` must be null or valid for writing an `sdg_config`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_config_default(out: *mut sdg_config) -> sdg_status {
    guard(|| {
        let c = GuidingConfig::default();
        let config = sdg_config {
            rule: match c.rule {
                LeafRule::L1 => SDG_RULE_L1,
                LeafRule::L2 => SDG_RULE_L2,
                LeafRule::L2Mixture => SDG_RULE_L2_MIXTURE,
                _ => return fail(sdg_status::Config, UNEXPRESSED),
            },
            spatial_threshold: c.spatial_threshold,
            subdivision_threshold: c.subdivision_threshold,
            max_directional_depth: c.max_directional_depth,
            uniform_fraction: c.uniform_fraction,
            max_directional_nodes: c.max_directional_nodes,
            max_spatial_nodes: c.max_spatial_nodes,
            max_memory_bytes: c.max_memory_bytes,
            prior_samples: c.prior_samples,
            spatial_filter: match c.spatial_filter {
                SpatialFilter::Nearest => SDG_FILTER_NEAREST,
                SpatialFilter::Stochastic => SDG_FILTER_STOCHASTIC,
                SpatialFilter::Box => SDG_FILTER_BOX,
                _ => return fail(sdg_status::Config, UNEXPRESSED),
            },
            directional_filter: match c.directional_filter {
                DirectionalFilter::Nearest => SDG_FILTER_NEAREST,
                DirectionalFilter::Box => SDG_FILTER_BOX,
                DirectionalFilter::DeferredBox => SDG_FILTER_DEFERRED_BOX,
                _ => return fail(sdg_status::Config, UNEXPRESSED),
            },
            refinement: match c.refinement {
                Refinement::FluxShare => SDG_REFINEMENT_FLUX_SHARE,
                Refinement::VarianceGain => SDG_REFINEMENT_VARIANCE_GAIN,
                _ => return fail(sdg_status::Config, UNEXPRESSED),
            },
            gain_threshold: c.gain_threshold,
            max_guide_probability: c.max_guide_probability,
            guide_cost: c.guide_cost.unwrap_or(-1.0),
        };
        // SAFETY: the caller's contract.
        unsafe { put(out, "out", config) }?;
        Ok(sdg_status::Ok)
    })
}

fn new_handle(field: GuidingField) -> *mut sdg_field {
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
        let rule = match c.rule {
            SDG_RULE_L1 => LeafRule::L1,
            SDG_RULE_L2 => LeafRule::L2,
            SDG_RULE_L2_MIXTURE => LeafRule::L2Mixture,
            other => return fail(sdg_status::Config, format!("unknown rule {other}")),
        };
        let config = GuidingConfig {
            rule,
            spatial_threshold: c.spatial_threshold,
            subdivision_threshold: c.subdivision_threshold,
            max_directional_depth: c.max_directional_depth,
            uniform_fraction: c.uniform_fraction,
            max_directional_nodes: c.max_directional_nodes,
            max_spatial_nodes: c.max_spatial_nodes,
            max_memory_bytes: c.max_memory_bytes,
            prior_samples: c.prior_samples,
            spatial_filter: match c.spatial_filter {
                SDG_FILTER_NEAREST => SpatialFilter::Nearest,
                SDG_FILTER_STOCHASTIC => SpatialFilter::Stochastic,
                SDG_FILTER_BOX => SpatialFilter::Box,
                other => {
                    return fail(
                        sdg_status::Config,
                        format!("unknown spatial filter {other}"),
                    );
                }
            },
            directional_filter: match c.directional_filter {
                SDG_FILTER_NEAREST => DirectionalFilter::Nearest,
                SDG_FILTER_BOX => DirectionalFilter::Box,
                SDG_FILTER_DEFERRED_BOX => DirectionalFilter::DeferredBox,
                other => {
                    return fail(
                        sdg_status::Config,
                        format!("unknown directional filter {other}"),
                    );
                }
            },
            refinement: match c.refinement {
                SDG_REFINEMENT_FLUX_SHARE => Refinement::FluxShare,
                SDG_REFINEMENT_VARIANCE_GAIN => Refinement::VarianceGain,
                other => return fail(sdg_status::Config, format!("unknown refinement {other}")),
            },
            gain_threshold: c.gain_threshold,
            max_guide_probability: c.max_guide_probability,
            // NaN is not negative: it reaches validation, which refuses it.
            guide_cost: Some(c.guide_cost).filter(|g| *g >= 0.0 || g.is_nan()),
        };
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
    if !field.is_null() {
        // SAFETY: created by `Box::into_raw` in `new_handle`, destroyed once (caller's contract).
        let handle = unsafe { Box::from_raw(field) };
        let _ = catch_unwind(AssertUnwindSafe(move || drop(handle)));
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

fn record(field: &GuidingField, s: &sdg_sample) -> sdg_status {
    let mut sample = Sample {
        position: s.position.into(),
        direction: s.direction.into(),
        value: s.value,
        pdf: s.pdf,
        normal: Some(s.normal.into()),
        second_moment: (s.second_moment != 0.0).then_some(s.second_moment),
        ..Sample::default()
    };
    if [s.integrand, s.bsdf_pdf, s.guide_pdf] != [0.0; 3] {
        sample = sample.with_mixture(s.integrand, s.bsdf_pdf, s.guide_pdf);
    }
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
        let c = Continuation {
            position: c.position.into(),
            value: c.value,
            cost: c.cost,
        };
        Ok(match shared(&f.inner).try_record_continuation(&c) {
            Ok(()) => sdg_status::Ok,
            Err(_) => sdg_status::SampleRejected,
        })
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
        let mode = match p.mode {
            SDG_SPLITTING_ROULETTE => SplittingMode::Roulette,
            SDG_SPLITTING_ROULETTE_AND_SPLITTING => SplittingMode::RouletteAndSplitting,
            m => return fail(sdg_status::InvalidArgument, format!("unknown mode {m}")),
        };
        let splitting = Splitting::new(mode, p.relative_variance, p.cost)
            .with_bounds(p.min_survival, p.max_splits)
            .or_else(|e| fail(sdg_status::InvalidArgument, e.to_string()))?;
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

fn sample(field: &GuidingField, x: Vec3, u0: f32, u1: f32) -> Result<(Vec3, f32), Failure> {
    finite_u(u0, u1)?;
    Ok(field.distribution(x).sample(Vec2::new(u0, u1)))
}

/// Refuses non-finite sample coordinates.
fn finite_u(u0: f32, u1: f32) -> Result<(), Failure> {
    if !(u0.is_finite() && u1.is_finite()) {
        return fail(
            sdg_status::InvalidArgument,
            format!("u = ({u0}, {u1}) is not finite"),
        );
    }
    Ok(())
}

/// # Safety
/// `direction` and `pdf` must be null or valid for writes.
unsafe fn write_sample(
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

/// Takes the distribution at `position`, for several `sdg_distribution_sample` /
/// `sdg_distribution_pdf` calls. It holds the field's lock shared until destroyed.
///
/// # Safety
/// `field` must be null or valid; `out` must be null or valid for writing a pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_distribution(
    field: *const sdg_field,
    position: sdg_vec3,
    out: *mut *mut sdg_distribution,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let f = unsafe { arg(field, "field") }?;
        let position = finite(position.into(), "position")?;
        if out.is_null() {
            return fail(sdg_status::NullPointer, "`out` is null");
        }
        // A thread holding a distribution may take another while a refine waits.
        let field = if reentrant() {
            f.inner.read_arc_recursive()
        } else {
            f.inner.read_arc()
        };
        HELD.with(|h| h.set(h.get().saturating_add(1)));
        let dist = Box::new(sdg_distribution {
            field,
            position,
            normal: Vec3::ZERO,
            owner: std::thread::current().id(),
        });
        // SAFETY: non-null, valid for writes by the caller's contract.
        unsafe { out.write(Box::into_raw(dist)) };
        Ok(sdg_status::Ok)
    })
}

/// Makes the distribution its product with the clamped cosine `max(0, n·ω)` about the surface
/// normal `normal` (any length; it is normalized), for a vertex on a surface that only
/// reflects: later `sdg_distribution_sample` and `sdg_distribution_pdf` calls sample and
/// evaluate the product (see the Rust `DirectionalDistribution::at_surface`). A zero normal
/// restores the plain distribution; a non-finite one is refused (`SDG_STATUS_INVALID_ARGUMENT`)
/// and leaves the distribution as it was.
///
/// # Safety
/// `dist` must be null or a live distribution, not used by another thread during the call.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_distribution_set_normal(
    dist: *mut sdg_distribution,
    normal: sdg_vec3,
) -> sdg_status {
    guard(|| {
        if dist.is_null() {
            return fail(sdg_status::NullPointer, "`dist` is null");
        }
        let n = finite(normal.into(), "normal")?;
        // SAFETY: non-null, live and not shared during the call by the caller's contract.
        unsafe { (*dist).normal = n };
        Ok(sdg_status::Ok)
    })
}

impl sdg_distribution {
    /// What the distribution samples: the field's at its position, times the cosine if a
    /// normal is set (a zero normal gives the plain distribution).
    fn view(&self) -> sdguide::SurfaceDistribution<'_> {
        self.field
            .distribution(self.position)
            .at_surface(self.normal)
    }
}

/// Draws a direction from a distribution (see `sdg_field_sample`; with a normal set, from its
/// product with the cosine).
///
/// # Safety
/// `dist` must be null or a live distribution; `direction` and `pdf` null or valid for writes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_distribution_sample(
    dist: *const sdg_distribution,
    u0: f32,
    u1: f32,
    direction: *mut sdg_vec3,
    pdf: *mut f32,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let d = unsafe { arg(dist, "dist") }?;
        finite_u(u0, u1)?;
        let (dir, p) = d.view().sample(Vec2::new(u0, u1));
        // SAFETY: the caller's contract.
        unsafe { write_sample(direction, pdf, dir, p) }
    })
}

/// The solid-angle pdf of `direction` under a distribution (see `sdg_field_pdf`; with a
/// normal set, under its product with the cosine).
///
/// # Safety
/// `dist` must be null or a live distribution; `pdf` null or valid for writes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_distribution_pdf(
    dist: *const sdg_distribution,
    direction: sdg_vec3,
    pdf: *mut f32,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let d = unsafe { arg(dist, "dist") }?;
        let dir = finite(direction.into(), "direction")?;
        let p = d.view().pdf(dir);
        // SAFETY: the caller's contract.
        unsafe { put(pdf, "pdf", p) }?;
        Ok(sdg_status::Ok)
    })
}

/// The learned probability of sampling the guide rather than the BSDF at the distribution's
/// position, for the one-sample mixture `a·p_guide + (1 − a)·p_bsdf`: between 0.05 and the
/// configuration's `max_guide_probability`, 0.5 until learned from samples recorded with
/// mixture terms; 0 where the field turned the guide off (`guide_cost`): sample the BSDF
/// alone there, and skip the guide's pdf unless the pass records.
///
/// # Safety
/// `dist` must be null or a live distribution; `probability` null or valid for writes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_distribution_guide_probability(
    dist: *const sdg_distribution,
    probability: *mut f32,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let d = unsafe { arg(dist, "dist") }?;
        let a = d.field.distribution(d.position).guide_probability();
        // SAFETY: the caller's contract.
        unsafe { put(probability, "probability", a) }?;
        Ok(sdg_status::Ok)
    })
}

/// Destroys a distribution, releasing its hold on the field. Null is ignored.
///
/// # Safety
/// `dist` must be null or a distribution from this library, not yet destroyed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_distribution_destroy(dist: *mut sdg_distribution) {
    if !dist.is_null() {
        // SAFETY: created by `Box::into_raw` in `sdg_field_distribution`, destroyed once.
        let d = unsafe { Box::from_raw(dist) };
        let _ = catch_unwind(AssertUnwindSafe(move || drop(d)));
    }
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
        };
        // SAFETY: the caller's contract.
        unsafe { put(out, "out", stats) }?;
        Ok(sdg_status::Ok)
    })
}

/// The UTF-8 path C passed in.
///
/// # Safety
/// `path` must be null or a NUL-terminated string.
unsafe fn path_arg<'a>(path: *const c_char) -> Result<&'a str, Failure> {
    if path.is_null() {
        return fail(sdg_status::NullPointer, "`path` is null");
    }
    // SAFETY: non-null and NUL-terminated (caller's contract).
    unsafe { CStr::from_ptr(path) }
        .to_str()
        .or_else(|_| fail(sdg_status::InvalidArgument, "`path` is not UTF-8"))
}

fn cache_failure(e: sdguide::CacheError) -> Failure {
    let status = match e {
        sdguide::CacheError::Io(_) => sdg_status::Io,
        _ => sdg_status::Cache,
    };
    Failure(status, e.to_string())
}

/// Saves the field to `path` atomically (temporary file, flush, rename).
///
/// # Safety
/// `field` must be null or valid; `path` null or a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_save(
    field: *const sdg_field,
    path: *const c_char,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (f, path) = unsafe { (arg(field, "field")?, path_arg(path)?) };
        shared(&f.inner).save_to_path(path).map_err(cache_failure)?;
        Ok(sdg_status::Ok)
    })
}

/// Loads a field from a cache file and stores its handle in `*out`.
///
/// # Safety
/// `path` must be null or a NUL-terminated string; `out` null or valid for writing a pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_load(
    path: *const c_char,
    out: *mut *mut sdg_field,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let path = unsafe { path_arg(path) }?;
        if out.is_null() {
            return fail(sdg_status::NullPointer, "`out` is null");
        }
        let field = GuidingField::load_from_path(path).map_err(cache_failure)?;
        // SAFETY: non-null, valid for writes by the caller's contract.
        unsafe { out.write(new_handle(field)) };
        Ok(sdg_status::Ok)
    })
}

/// Saves the field into a new buffer: `*data` and `*len` receive it. Free it with
/// `sdg_buffer_free(data, len)`.
///
/// # Safety
/// `field` must be null or valid; `data` and `len` null or valid for writes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_save_to_buffer(
    field: *const sdg_field,
    data: *mut *mut u8,
    len: *mut usize,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let f = unsafe { arg(field, "field") }?;
        if data.is_null() || len.is_null() {
            return fail(sdg_status::NullPointer, "`data` or `len` is null");
        }
        let bytes = shared(&f.inner).to_bytes().into_boxed_slice();
        let n = bytes.len();
        // SAFETY: both non-null, valid for writes (caller's contract). The box is given to C and
        // comes back, with its length, in `sdg_buffer_free`.
        unsafe {
            len.write(n);
            data.write(Box::into_raw(bytes).cast::<u8>());
        }
        Ok(sdg_status::Ok)
    })
}

/// Frees a buffer from `sdg_field_save_to_buffer`. Null is ignored.
///
/// # Safety
/// `data` and `len` must be exactly what `sdg_field_save_to_buffer` returned, freed once.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_buffer_free(data: *mut u8, len: usize) {
    if !data.is_null() {
        // SAFETY: `data`/`len` describe a boxed slice leaked by `sdg_field_save_to_buffer`.
        drop(unsafe { Box::from_raw(std::ptr::slice_from_raw_parts_mut(data, len)) });
    }
}

/// Loads a field from `len` bytes at `data` and stores its handle in `*out`.
///
/// # Safety
/// `data` must be null or valid for reading `len` bytes; `out` null or valid for writing a
/// pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_load_from_buffer(
    data: *const u8,
    len: usize,
    out: *mut *mut sdg_field,
) -> sdg_status {
    guard(|| {
        if data.is_null() || out.is_null() {
            return fail(sdg_status::NullPointer, "`data` or `out` is null");
        }
        // SAFETY: non-null and valid for `len` bytes (caller's contract).
        let bytes = unsafe { std::slice::from_raw_parts(data, len) };
        let field = GuidingField::from_bytes(bytes).map_err(cache_failure)?;
        // SAFETY: non-null, valid for writes (caller's contract).
        unsafe { out.write(new_handle(field)) };
        Ok(sdg_status::Ok)
    })
}

/// Adds what `other` recorded in the current iteration to `field` (see the Rust
/// `GuidingField::merge`). Takes `field` exclusively and `other` shared.
///
/// # Safety
/// `field` and `other` must be null or valid.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_merge(
    field: *mut sdg_field,
    other: *const sdg_field,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (f, o) = unsafe { (arg(field, "field")?, arg(other, "other")?) };
        if Arc::ptr_eq(&f.inner, &o.inner) {
            return fail(
                sdg_status::InvalidArgument,
                "a field cannot be merged into itself",
            );
        }
        // Lock in address order, so two merges in opposite directions cannot deadlock.
        let (mut ours, theirs) = if Arc::as_ptr(&f.inner) < Arc::as_ptr(&o.inner) {
            let w = f.inner.write();
            (w, shared(&o.inner))
        } else {
            let r = shared(&o.inner);
            (f.inner.write(), r)
        };
        ours.merge(&theirs)
            .or_else(|e| fail(sdg_status::Merge, e.to_string()))?;
        Ok(sdg_status::Ok)
    })
}
