//! sdguide's lab: what the tests, benchmarks, examples and the quality tables measure the
//! library with, kept out of its public API.
//!
//! - [`rng`]: the deterministic random number generator every crate of the workspace draws
//!   from (SplitMix64).
//! - [`synthetic`]: analytic light fields (sums of von Mises–Fisher lobes, with their integrals
//!   in closed form), and the standard training workload that trains a field the way a path
//!   tracer would.
//! - [`protocol`]: the directional learning protocol — three fixed lobes, a fixed sampler,
//!   five updates — that compares guiding libraries on the same samples through their `pdf`.
//! - [`quality`]: the quality harness — the exact variance of the estimator a trained field
//!   gives, against the best any density on the same partition could do (`docs/quality.md`).

#![deny(missing_docs)]
#![forbid(unsafe_code)]

pub mod protocol;
pub mod quality;
pub mod rng;
pub mod synthetic;
