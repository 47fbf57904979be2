//! Status codes, the last error's message, and the checks every entry point shares: no
//! panic crosses the boundary, null pointers and non-finite inputs are failures with a message.

use glam::Vec3;
use std::cell::RefCell;
use std::ffi::{CString, c_char};
use std::panic::{AssertUnwindSafe, catch_unwind};

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

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

/// The message of the last failed call on this thread (empty if none failed). The pointer stays
/// valid until the next failing call on this thread.
#[unsafe(no_mangle)]
pub extern "C" fn sdg_last_error() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

/// A failure: its status and message.
pub(crate) struct Failure(pub(crate) sdg_status, pub(crate) String);

pub(crate) fn fail<T>(status: sdg_status, message: impl Into<String>) -> Result<T, Failure> {
    Err(Failure(status, message.into()))
}

/// Runs an entry point: catches panics, records the message of a failure, returns the status.
pub(crate) fn guard(f: impl FnOnce() -> Result<sdg_status, Failure>) -> sdg_status {
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
pub(crate) unsafe fn arg<'a, T>(ptr: *const T, name: &str) -> Result<&'a T, Failure> {
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
pub(crate) unsafe fn put<T>(ptr: *mut T, name: &str, value: T) -> Result<(), Failure> {
    if ptr.is_null() {
        return fail(sdg_status::NullPointer, format!("`{name}` is null"));
    }
    // SAFETY: non-null, and valid for writes by the caller's contract; `write` does not read
    // or drop the (possibly uninitialized) old value.
    unsafe { ptr.write(value) };
    Ok(())
}

pub(crate) fn finite(v: Vec3, name: &str) -> Result<Vec3, Failure> {
    if v.is_finite() {
        Ok(v)
    } else {
        fail(
            sdg_status::InvalidArgument,
            format!("`{name}` is not finite: {v}"),
        )
    }
}

/// Refuses non-finite sample coordinates.
pub(crate) fn finite_u(u0: f32, u1: f32) -> Result<(), Failure> {
    if !(u0.is_finite() && u1.is_finite()) {
        return fail(
            sdg_status::InvalidArgument,
            format!("u = ({u0}, {u1}) is not finite"),
        );
    }
    Ok(())
}
