//! The demo path tracer of sdguide: a small, real, multi-threaded renderer that uses the library
//! exactly as a user would, and shows what guiding buys at equal time.
//!
//! The flow: a [`scene::Scene`] (built in code, [`scenes`]) is rendered by
//! [`method::render`] in passes of tiles ([`render`](mod@render)); every path is traced by
//! [`integrator::radiance`], generic over the guiding [`backend::Backend`], which is the
//! reference for wiring sdguide into a path tracer. A guided render's training
//! passes are not thrown away: [`passes`] combines them with the final one by inverse
//! variance. Images are compared with
//! [`image::Image::rel_mse`] against a stored reference ([`reference`](mod@reference)). The
//! `render` binary runs the comparison (see `docs/render.md`).

#![deny(missing_docs)]
// Safe code only, but for the FFI to the peer library (the `openpgl` feature).
#![deny(unsafe_code)]

pub mod backend;
pub mod bvh;
pub mod cost;
pub mod geometry;
pub mod image;
pub mod integrator;
pub mod material;
pub mod medium;
pub mod method;
#[cfg(feature = "openpgl")]
pub mod openpgl;
pub mod passes;
pub mod probe;
pub mod reference;
pub mod render;
pub mod sampler;
pub mod scene;
pub mod scenes;

/// The demo's random numbers: the workspace's SplitMix64 generator. Every pixel and pass draws
/// from a stream of its own (see [`render::render_pass`]); the stored references' seeds are
/// derived with it (`reference::seed`).
pub use sdguide_lab::rng;
