//! A guiding backend: what the integrator asks of a guiding library, and the three the demo
//! runs — sdguide's [`GuidingField`], Intel Open PGL's field (the `openpgl` feature), and
//! [`Unguided`].
//!
//! The integrator is generic over [`Backend`]: it looks up a vertex's distribution once
//! ([`Backend::at`]), samples and evaluates it through [`VertexGuide`], records each vertex
//! ([`Backend::record`]), and between training passes the render refines it
//! ([`Backend::refine`]).

use glam::{Vec2, Vec3};
use sdguide::{ContinuationEstimate, GuidingField, Sample, SurfaceDistribution};

/// A guiding library, as the demo's integrator and training schedule use it.
pub trait Backend: Sync {
    /// Its distribution at one vertex.
    type Vertex<'a>: VertexGuide
    where
        Self: 'a;

    /// The distribution at a vertex with shading normal `normal` (facing the viewer); `None`
    /// where there is none. `lookup` is a uniform random number for a backend whose spatial
    /// lookup is stochastic ([`draws_lookup`](Self::draws_lookup)).
    fn at(&self, position: Vec3, normal: Vec3, lookup: f32) -> Option<Self::Vertex<'_>>;

    /// Whether a vertex's lookup draws a random number.
    fn draws_lookup(&self) -> bool {
        false
    }

    /// Records one vertex of a training path: its sample (as the path recorder builds it),
    /// and how far its direction reached before it hit something (infinite if nothing).
    fn record(&self, sample: &Sample, distance: f32);

    /// Rebuilds the distributions from what was recorded (between passes).
    fn refine(&mut self);

    /// The backend as an sdguide field, whose cells also learn continuation estimates for
    /// roulette and splitting (`None` for the others).
    fn as_field(&self) -> Option<&GuidingField> {
        None
    }
}

/// A backend's directional distribution at one vertex.
pub trait VertexGuide {
    /// A direction, and its pdf where the backend returns it with the draw (sdguide's is
    /// exactly what `pdf` would say, so no second descent is needed).
    fn sample(&self, u: Vec2) -> (Vec3, Option<f32>);
    /// The solid-angle density of `direction`.
    fn pdf(&self, direction: Vec3) -> f32;
    /// The probability of drawing from the guide rather than the BSDF.
    fn guide_probability(&self) -> f32;
    /// The continuation estimate of the vertex's cell, where the backend learns one.
    fn continuation(&self) -> Option<ContinuationEstimate> {
        None
    }
}

impl Backend for GuidingField {
    type Vertex<'a> = SurfaceDistribution<'a>;

    fn at(&self, position: Vec3, normal: Vec3, _lookup: f32) -> Option<Self::Vertex<'_>> {
        // The product with the surface's clamped cosine: the BSDF is zero below it.
        Some(self.distribution(position).at_surface(normal))
    }

    fn record(&self, sample: &Sample, _distance: f32) {
        GuidingField::record(self, sample);
    }

    fn refine(&mut self) {
        GuidingField::refine(self);
    }

    fn as_field(&self) -> Option<&GuidingField> {
        Some(self)
    }
}

impl VertexGuide for SurfaceDistribution<'_> {
    fn sample(&self, u: Vec2) -> (Vec3, Option<f32>) {
        let (direction, pdf) = SurfaceDistribution::sample(self, u);
        (direction, Some(pdf))
    }

    fn pdf(&self, direction: Vec3) -> f32 {
        SurfaceDistribution::pdf(self, direction)
    }

    fn guide_probability(&self) -> f32 {
        SurfaceDistribution::guide_probability(self)
    }

    fn continuation(&self) -> Option<ContinuationEstimate> {
        Some(SurfaceDistribution::continuation(self))
    }
}

/// No guiding: path tracing with BSDF sampling (and next-event estimation).
#[derive(Clone, Copy, Debug, Default)]
pub struct Unguided;

/// The distribution [`Unguided`] never returns.
#[derive(Clone, Copy, Debug)]
pub enum NoGuide {}

impl Backend for Unguided {
    type Vertex<'a> = NoGuide;

    fn at(&self, _: Vec3, _: Vec3, _: f32) -> Option<NoGuide> {
        None
    }

    fn record(&self, _: &Sample, _: f32) {}

    fn refine(&mut self) {}
}

impl VertexGuide for NoGuide {
    fn sample(&self, _: Vec2) -> (Vec3, Option<f32>) {
        match *self {}
    }

    fn pdf(&self, _: Vec3) -> f32 {
        match *self {}
    }

    fn guide_probability(&self) -> f32 {
        match *self {}
    }
}
