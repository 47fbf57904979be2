//! The Python extension module `sdguide._sdguide`: the library's field and path recorder over
//! numpy arrays, for wavefront renderers and Mitsuba 3. The Python package `sdguide` re-exports
//! it (`python/sdguide/__init__.py`); its documentation is `python/README.md`.
//!
//! - `arrays`: what a batch call accepts (C-contiguous `float32` arrays of documented shapes)
//!   and returns.
//! - `field`: `GuidingField` — queries and `record` over lanes, refine, cache, merge, stats.
//! - `path`: `PathRecorderBatch` — one path recorder per lane, driven a bounce at a time.
//! - `image`: `ImageStatistics`, the splitting factor over lanes and `continuations`: the
//!   efficiency-aware roulette and splitting; `pass_weights`: passes combined by inverse
//!   variance.
//! - `errors`: the typed exceptions.

mod arrays;
mod errors;
mod field;
mod image;
mod path;

use pyo3::prelude::*;

#[pymodule]
fn _sdguide(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<field::PyGuidingField>()?;
    m.add_class::<path::PyPathRecorderBatch>()?;
    m.add_class::<image::PyImageStatistics>()?;
    m.add_function(wrap_pyfunction!(image::continuations, m)?)?;
    m.add_function(wrap_pyfunction!(image::pass_weights, m)?)?;
    errors::register(m)?;
    m.add(
        "FORMAT_VERSION",
        (sdguide::FORMAT_MAJOR, sdguide::FORMAT_MINOR),
    )?;
    m.add("NO_VERTEX", u32::MAX)?;
    Ok(())
}
