//! Saving, loading and merging caches: to and from files and memory buffers.

use crate::error::{Failure, arg, fail, guard, sdg_status};
use crate::field::{new_handle, sdg_field};
use crate::lock::shared;
use sdguide::GuidingField;
use std::ffi::{CStr, c_char};
use std::sync::Arc;

/// The UTF-8 path C passed in.
///
/// # Safety
/// `path` must be null or a NUL-terminated string.
pub(crate) unsafe fn path_arg<'a>(path: *const c_char) -> Result<&'a str, Failure> {
    if path.is_null() {
        return fail(sdg_status::NullPointer, "`path` is null");
    }
    // SAFETY: non-null and NUL-terminated (caller's contract).
    unsafe { CStr::from_ptr(path) }
        .to_str()
        .or_else(|_| fail(sdg_status::InvalidArgument, "`path` is not UTF-8"))
}

pub(crate) fn cache_failure(e: sdguide::CacheError) -> Failure {
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
