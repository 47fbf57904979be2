//! A guiding backend: what the integrator asks of a guiding library, and the three the demo
//! runs — sdguide's [`GuidingField`], Intel Open PGL's field (the `openpgl` feature), and
//! [`Unguided`].
//!
//! The integrator is generic over [`Backend`]: it looks up a vertex's distribution once
//! ([`Backend::at`]), samples and evaluates it through [`VertexGuide`], records each vertex
//! ([`Backend::record`]), and between training passes the render refines it
//! ([`Backend::refine`]).

use glam::{Vec2, Vec3};
use sdguide::{ContinuationEstimate, GuidingField, PhaseDistribution, Sample, SurfaceDistribution};

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

    /// The distribution at a vertex inside a medium whose phase function has asymmetry `g`,
    /// reached travelling along `travel`: the backend's volume guide (its product with the
    /// phase function); `None` where there is none.
    fn in_medium(
        &self,
        position: Vec3,
        travel: Vec3,
        g: f32,
        lookup: f32,
    ) -> Option<Self::Vertex<'_>>;

    /// Whether a vertex's lookup draws a random number.
    fn draws_lookup(&self) -> bool {
        false
    }

    /// Records one vertex of a training path: its sample (as the path recorder builds it),
    /// and what the integrator knows of its two segments.
    fn record(&self, sample: &Sample, segment: Segment);

    /// Rebuilds the distributions from what was recorded (between passes).
    fn refine(&mut self);

    /// The backend as an sdguide field, whose cells also learn continuation estimates for
    /// roulette and splitting (`None` for the others).
    fn as_field(&self) -> Option<&GuidingField> {
        None
    }
}

/// What the integrator knows of a recorded vertex beyond its [`Sample`]: what Open PGL's
/// parallax compensation and radiance cache need.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Segment {
    /// How far the vertex's direction reached before it hit something (infinite if nothing).
    pub distance: f32,
    /// The unit direction from the vertex back along the path, toward the camera.
    pub outgoing: Vec3,
}

impl Segment {
    /// A vertex whose segments were not kept: its direction reached nothing, and no direction
    /// leads back (a zero vector, which Open PGL's cache files under one bin).
    pub const UNKNOWN: Segment = Segment {
        distance: f32::INFINITY,
        outgoing: Vec3::ZERO,
    };
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
    /// The luminance of the radiance the vertex's cell is estimated to send toward `direction`
    /// (unit, away from the vertex), where the backend keeps a radiance cache (Open PGL's).
    fn outgoing_radiance(&self, _direction: Vec3) -> Option<f32> {
        None
    }
}

/// sdguide's distribution at a vertex: at a surface, the product with its clamped cosine; in a
/// medium, the volume guide's product with the phase function.
#[derive(Clone, Copy, Debug)]
pub enum FieldVertex<'a> {
    /// At a surface.
    Surface(SurfaceDistribution<'a>),
    /// In a medium.
    Medium(PhaseDistribution<'a>),
}

impl Backend for GuidingField {
    type Vertex<'a> = FieldVertex<'a>;

    fn at(&self, position: Vec3, normal: Vec3, _lookup: f32) -> Option<Self::Vertex<'_>> {
        // The product with the surface's clamped cosine: the BSDF is zero below it.
        Some(FieldVertex::Surface(
            self.distribution(position).at_surface(normal),
        ))
    }

    fn in_medium(&self, position: Vec3, travel: Vec3, g: f32, _: f32) -> Option<FieldVertex<'_>> {
        Some(FieldVertex::Medium(
            self.volume_distribution(position).with_phase(travel, g),
        ))
    }

    fn record(&self, sample: &Sample, _: Segment) {
        GuidingField::record(self, sample);
    }

    fn refine(&mut self) {
        GuidingField::refine(self);
    }

    fn as_field(&self) -> Option<&GuidingField> {
        Some(self)
    }
}

impl VertexGuide for FieldVertex<'_> {
    fn sample(&self, u: Vec2) -> (Vec3, Option<f32>) {
        let (direction, pdf) = match self {
            FieldVertex::Surface(d) => d.sample(u),
            FieldVertex::Medium(d) => d.sample(u),
        };
        (direction, Some(pdf))
    }

    fn pdf(&self, direction: Vec3) -> f32 {
        match self {
            FieldVertex::Surface(d) => d.pdf(direction),
            FieldVertex::Medium(d) => d.pdf(direction),
        }
    }

    fn guide_probability(&self) -> f32 {
        match self {
            FieldVertex::Surface(d) => d.guide_probability(),
            FieldVertex::Medium(d) => d.guide_probability(),
        }
    }

    fn continuation(&self) -> Option<ContinuationEstimate> {
        Some(match self {
            FieldVertex::Surface(d) => d.continuation(),
            FieldVertex::Medium(d) => d.continuation(),
        })
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

    fn in_medium(&self, _: Vec3, _: Vec3, _: f32, _: f32) -> Option<NoGuide> {
        None
    }

    fn record(&self, _: &Sample, _: Segment) {}

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
