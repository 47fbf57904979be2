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
//! One module per object: `config` (`sdg_config` and its one conversion each way), `types`
//! (vectors, samples, continuations, the splitting policy), `field` and `distribution` (the two
//! handles), `path` (the path recorder, one per render thread), `batch` (the field's queries over arrays, for wavefront renderers), `cache` (save,
//! load, merge), `lock` (the field's lock), `error` (status codes and the checks every entry
//! point shares). An optional field of a C struct is said to be present
//! one way only: its bit in the struct's `flags` (`SDG_SAMPLE_*`, `SDG_CONFIG_*`).
//!
//! This crate is the only place in sdguide with `unsafe` code: reading and writing through the
//! pointers C passes in. Each use states what it relies on.

#![allow(non_camel_case_types)]
#![deny(missing_docs)]

mod batch;
mod cache;
mod config;
mod distribution;
mod error;
mod field;
mod lock;
mod path;
mod types;

pub use batch::*;
pub use cache::*;
pub use config::*;
pub use distribution::*;
pub use error::*;
pub use field::*;
pub use path::*;
pub use types::*;
