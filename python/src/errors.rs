//! The package's exceptions: `ConfigError` and `MergeError` are `ValueError`s (bad arguments),
//! `CacheError` an `OSError`'s sibling for caches that cannot be read or written. Shape and
//! dtype mistakes in batch calls are plain `ValueError`s.

use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyValueError};
use pyo3::prelude::*;

create_exception!(
    sdguide,
    ConfigError,
    PyValueError,
    "A configuration value out of its documented range, an unknown keyword, or bad bounds."
);
create_exception!(
    sdguide,
    CacheError,
    PyException,
    "A cache that cannot be written or read: I/O, a bad magic or checksum, an unsupported version, inconsistent contents."
);
create_exception!(
    sdguide,
    MergeError,
    PyValueError,
    "Fields that cannot be merged: different bounds, configurations or states."
);

pub fn config_error(message: String) -> PyErr {
    ConfigError::new_err(message)
}

pub fn cache_error(e: sdguide::CacheError) -> PyErr {
    CacheError::new_err(e.to_string())
}

pub fn merge_error(e: sdguide::MergeError) -> PyErr {
    MergeError::new_err(e.to_string())
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("ConfigError", py.get_type::<ConfigError>())?;
    m.add("CacheError", py.get_type::<CacheError>())?;
    m.add("MergeError", py.get_type::<MergeError>())?;
    Ok(())
}
