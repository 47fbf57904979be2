//! The path tracer, and the reference for wiring sdguide into one.
//!
//! A unidirectional path tracer with next-event estimation (unless the scene turns it off),
//! multiple importance sampling (power heuristic) and Russian roulette; smooth dielectrics are
//! delta vertices, passed through without a light sample or a guide lookup. With guiding, every
//! scattering direction is drawn from the **one-sample mixture**
//! `q = a·p_guide + (1 − a)·p_bsdf`, where `p_guide` is the field's distribution at the vertex
//! and `a` its learned guide probability. The wiring points are marked `GUIDING:` below; there
//! are four:
//!
//! 1. at a vertex, look up the distribution once, as its product with the clamped cosine about
//!    the shading normal (`field.distribution(x).at_surface(n)`: every guided material here
//!    reflects only, so nothing below the surface is worth a sample);
//! 2. sample from the mixture, and evaluate the *mixture* pdf `q` — for the direction sampled
//!    and for every next-event direction, since MIS must weigh the strategy actually used;
//! 3. keep, per vertex, what the path later adds to the radiance arriving along the sampled
//!    direction;
//! 4. once the path is finished, record every vertex: position, direction, the luminance of that
//!    incident radiance, the mixture pdf, and the mixture terms the guide probability learns
//!    from. Between training passes the caller refines the field (no thread may render then).
//!
//! With the `openpgl` feature, the same four points serve Intel Open PGL (`Guide::OpenPgl`):
//! the same mixture, MIS and recorded radiance, with the peer's distribution in the guide's
//! place, so that the two libraries are compared in one renderer.

use crate::geometry::{Frame, Ray};
use crate::material::{Material, luminance};
use crate::rng::Rng;
use crate::scene::Scene;
use glam::Vec2;
use glam::Vec3;
use sdguide::{GuidingField, Sample, SurfaceDistribution};

/// Longest path, in scattering events.
pub const MAX_DEPTH: usize = 10;
/// Russian roulette starts after this many scattering events.
const ROULETTE_DEPTH: usize = 3;

/// The guiding field a render samples: sdguide's, or the peer's.
#[derive(Clone, Copy)]
pub enum Guide<'a> {
    /// An sdguide field.
    Sdguide(&'a GuidingField),
    /// An Intel Open PGL field.
    #[cfg(feature = "openpgl")]
    OpenPgl(&'a crate::openpgl::Guide),
}

/// The probability of sampling Open PGL's guide instead of the BSDF: ½, Cycles' default
/// surface guiding probability (the peer learns none).
#[cfg(feature = "openpgl")]
pub const PEER_GUIDE_PROBABILITY: f32 = 0.5;

impl<'a> From<&'a GuidingField> for Guide<'a> {
    fn from(field: &'a GuidingField) -> Self {
        Guide::Sdguide(field)
    }
}

impl<'a> Guide<'a> {
    /// Whether a vertex's lookup draws a random number (Open PGL's stochastic spatial lookup).
    fn draws_lookup(self) -> bool {
        match self {
            Guide::Sdguide(_) => false,
            #[cfg(feature = "openpgl")]
            Guide::OpenPgl(_) => true,
        }
    }

    /// The guide's distribution at a vertex; `None` where it has none (the peer's before its
    /// first update).
    #[cfg_attr(not(feature = "openpgl"), allow(unused_variables))]
    fn at(self, position: Vec3, normal: Vec3, lookup: f32) -> Option<GuideView<'a>> {
        match self {
            // The product with the surface's clamped cosine: the BSDF is zero below it.
            Guide::Sdguide(field) => Some(GuideView::Sdguide(
                field.distribution(position).at_surface(normal),
            )),
            #[cfg(feature = "openpgl")]
            Guide::OpenPgl(field) => field
                .distribution(position, normal, lookup)
                .map(GuideView::OpenPgl),
        }
    }
}

/// How a render uses a guiding field.
#[derive(Clone, Copy)]
pub struct Guiding<'a> {
    /// The field to sample (and to record into when `record` is set).
    pub field: Guide<'a>,
    /// Whether finished paths are recorded into the field (training passes).
    pub record: bool,
    /// Probability of sampling the guide instead of the BSDF; `None` uses the field's learned
    /// probability at each vertex.
    pub guide_probability: Option<f32>,
}

/// A scattering direction drawn from a vertex's sampling mixture.
#[derive(Clone, Copy, Debug)]
pub struct DirectionSample {
    /// World-space unit direction.
    pub direction: Vec3,
    /// The pdfs of `direction`.
    pub pdf: MixturePdf,
}

/// The pdfs of one direction under the mixture and under its two techniques.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MixturePdf {
    /// `q = a·guide + (1 − a)·bsdf`: what the direction was drawn with.
    pub mixture: f32,
    /// The BSDF sampling pdf.
    pub bsdf: f32,
    /// The guiding distribution's pdf (0 without guiding).
    pub guide: f32,
}

/// A guide's directional distribution at one vertex.
enum GuideView<'a> {
    Sdguide(SurfaceDistribution<'a>),
    #[cfg(feature = "openpgl")]
    OpenPgl(crate::openpgl::Distribution),
}

impl GuideView<'_> {
    /// A direction, and its pdf where the guide returns it with the draw (sdguide's is
    /// exactly what `pdf` would say, so no second descent is needed).
    fn sample(&self, u: Vec2) -> (Vec3, Option<f32>) {
        match self {
            GuideView::Sdguide(d) => {
                let (direction, pdf) = d.sample(u);
                (direction, Some(pdf))
            }
            #[cfg(feature = "openpgl")]
            GuideView::OpenPgl(d) => (d.sample(u), None),
        }
    }

    fn pdf(&self, direction: Vec3) -> f32 {
        match self {
            GuideView::Sdguide(d) => d.pdf(direction),
            #[cfg(feature = "openpgl")]
            GuideView::OpenPgl(d) => d.pdf(direction),
        }
    }

    fn guide_probability(&self) -> f32 {
        match self {
            GuideView::Sdguide(d) => d.guide_probability(),
            #[cfg(feature = "openpgl")]
            GuideView::OpenPgl(_) => PEER_GUIDE_PROBABILITY,
        }
    }
}

/// The directional sampling strategy at one vertex: the BSDF's, mixed with the guide's when
/// there is a guiding field.
pub struct VertexSampler<'a> {
    frame: Frame,
    wo: Vec3,
    material: &'a Material,
    guide: Option<GuideView<'a>>,
    /// Probability of drawing from the guide.
    a: f32,
}

impl<'a> VertexSampler<'a> {
    /// The strategy at `position`, with shading normal `normal` (facing the viewer), outgoing
    /// world direction `wo`, the surface's material, and the sdguide field if any.
    pub fn new(
        position: Vec3,
        normal: Vec3,
        wo: Vec3,
        material: &'a Material,
        field: Option<&'a GuidingField>,
    ) -> Self {
        Self::with_guide(position, normal, wo, material, field.map(Guide::from), 0.0)
    }

    /// The strategy with any guide; `lookup` is a uniform random number for a guide whose
    /// spatial lookup is stochastic (Open PGL's), unused by sdguide's.
    pub fn with_guide(
        position: Vec3,
        normal: Vec3,
        wo: Vec3,
        material: &'a Material,
        guide: Option<Guide<'a>>,
        lookup: f32,
    ) -> Self {
        let frame = Frame::new(normal);
        // GUIDING (1): one lookup per vertex; sdguide's distribution is a lock-free view.
        let guide = guide.and_then(|g| g.at(position, normal, lookup));
        let a = guide.as_ref().map_or(0.0, |g| g.guide_probability());
        VertexSampler {
            frame,
            wo: frame.to_local(wo),
            material,
            guide,
            a,
        }
    }

    /// The same strategy with the guide drawn with probability `a` instead of the learned one.
    pub fn with_guide_probability(self, a: f32) -> Self {
        VertexSampler { a, ..self }
    }

    /// The BSDF `f(wo, wi)·|cos θ_i|` for a world direction.
    pub fn bsdf_cos(&self, direction: Vec3) -> Vec3 {
        let wi = self.frame.to_local(direction);
        self.material.eval(self.wo, wi) * wi.z.abs()
    }

    /// The pdfs of drawing the world direction `direction`.
    pub fn pdf(&self, direction: Vec3) -> MixturePdf {
        // GUIDING (2): MIS and the estimator need the pdf of the whole mixture.
        let guide = self.guide.as_ref().map_or(0.0, |g| g.pdf(direction));
        self.mixture_pdf(direction, guide)
    }

    /// The pdfs of `direction`, whose guide pdf is `guide`.
    fn mixture_pdf(&self, direction: Vec3, guide: f32) -> MixturePdf {
        let bsdf = self.material.pdf(self.wo, self.frame.to_local(direction));
        MixturePdf {
            mixture: self.a * guide + (1.0 - self.a) * bsdf,
            bsdf,
            guide,
        }
    }

    /// Draws a direction: from the guide with probability `a`, else from the BSDF. `None` when
    /// the BSDF draw fails (leaves the hemisphere).
    pub fn sample(&self, rng: &mut Rng) -> Option<DirectionSample> {
        let choice = rng.next_f32();
        let lobe = rng.next_f32();
        let u = rng.next_vec2();
        let (direction, guide_pdf) = match &self.guide {
            Some(guide) if choice < self.a => guide.sample(u),
            _ => {
                let s = self.material.sample(self.wo, lobe, u)?;
                (self.frame.to_world(s.wi), None)
            }
        };
        let pdf = match guide_pdf {
            Some(guide) => self.mixture_pdf(direction, guide),
            None => self.pdf(direction),
        };
        (pdf.mixture > 0.0).then_some(DirectionSample { direction, pdf })
    }
}

/// What one vertex of a path needs for recording into the field.
#[derive(Clone, Copy, Debug, Default)]
struct GuideVertex {
    position: Vec3,
    direction: Vec3,
    pdf: f32,
    bsdf_pdf: f32,
    guide_pdf: f32,
    bsdf_cos: Vec3,
    /// Distance to the next vertex along `direction` (infinite until it is found).
    distance: f32,
    /// Throughput from the radiance arriving at this vertex to the path's current end.
    throughput: Vec3,
    /// Radiance that arrived along `direction` so far.
    radiance: Vec3,
}

/// The vertices of one path, on the stack.
struct PathLog {
    vertices: [GuideVertex; MAX_DEPTH],
    len: usize,
}

impl PathLog {
    fn new() -> Self {
        PathLog {
            vertices: [GuideVertex::default(); MAX_DEPTH],
            len: 0,
        }
    }

    /// Radiance `c` (before the current vertex's throughput) reached the path's end: it arrives
    /// at every earlier vertex, scaled by what lies in between.
    fn add(&mut self, c: Vec3) {
        for v in &mut self.vertices[..self.len] {
            v.radiance += v.throughput * c;
        }
    }

    /// The path scattered with weight `factor` at its end: earlier vertices see through it.
    fn scale(&mut self, factor: Vec3) {
        for v in &mut self.vertices[..self.len] {
            v.throughput *= factor;
        }
    }

    fn push(&mut self, v: GuideVertex) {
        self.vertices[self.len] = v;
        self.len += 1;
    }

    /// The path hit something `distance` past its last vertex (or past a dielectric after it):
    /// the first hit after a vertex is the one its direction reaches.
    fn reached(&mut self, distance: f32) {
        if let Some(v) = self.vertices[..self.len].last_mut()
            && v.distance.is_infinite()
        {
            v.distance = distance;
        }
    }

    /// GUIDING (4): records every vertex, once the path is finished.
    fn record(&self, guide: Guide<'_>) {
        let vertices = &self.vertices[..self.len];
        match guide {
            Guide::Sdguide(field) => {
                for v in vertices {
                    let sample = Sample {
                        position: v.position,
                        direction: v.direction,
                        value: luminance(v.radiance),
                        pdf: v.pdf,
                        ..Sample::default()
                    }
                    .with_mixture(
                        luminance(v.radiance * v.bsdf_cos),
                        v.bsdf_pdf,
                        v.guide_pdf,
                    );
                    field.record(&sample);
                }
            }
            #[cfg(feature = "openpgl")]
            Guide::OpenPgl(field) => {
                let mut records = [crate::openpgl::Record::default(); MAX_DEPTH];
                for (r, v) in records.iter_mut().zip(vertices) {
                    *r = crate::openpgl::Record {
                        position: v.position,
                        direction: v.direction,
                        radiance: luminance(v.radiance),
                        pdf: v.pdf,
                        distance: v.distance,
                    };
                }
                field.record(&records[..vertices.len()]);
            }
        }
    }
}

/// MIS weight of a strategy with pdf `a` against one with pdf `b` (power heuristic, β = 2).
fn power_heuristic(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 { a2 / (a2 + b2) } else { 0.0 }
}

/// The radiance arriving along `ray` (one path sample), guided when `guiding` is given.
pub fn radiance(scene: &Scene, guiding: Option<Guiding<'_>>, mut ray: Ray, rng: &mut Rng) -> Vec3 {
    let guide = guiding.map(|g| g.field);
    let mut log = PathLog::new();
    let mut l = Vec3::ZERO;
    let mut beta = Vec3::ONE;
    // The pdf the current ray's direction was drawn with (None for the camera ray) and where.
    let mut previous: Option<(Vec3, f32)> = None;
    for depth in 0..=MAX_DEPTH {
        let Some(hit) = scene.intersect(&ray) else {
            break;
        };
        log.reached(hit.t);
        let wo = -ray.direction;
        let emitted = scene.emitted(&hit, wo);
        if emitted != Vec3::ZERO {
            let weight = match previous {
                Some((x, pdf)) if scene.next_event => {
                    power_heuristic(pdf, scene.light_pdf(x, &hit, ray.direction))
                }
                _ => 1.0,
            };
            l += beta * emitted * weight;
            log.add(emitted * weight);
        }
        if depth == MAX_DEPTH {
            break;
        }
        let material = scene.material(&hit);
        let normal = hit.normal_toward(wo);
        if material.is_dielectric() {
            // A delta vertex: no light sample reaches through it and no guide can sample it, so
            // the path goes on in the one direction Fresnel picks, with weight 1, and the vertex
            // is not recorded; the vertex before it records the radiance arriving through the
            // glass, which is what a guide there learns to aim at.
            let frame = Frame::new(normal);
            let entering = hit.normal.dot(wo) > 0.0;
            let local = material.sample_dielectric(frame.to_local(wo), entering, rng.next_f32());
            // What the path finds next was reached by no strategy a light sample competes with.
            previous = None;
            ray = Ray::leaving(
                hit.position,
                hit.normal,
                frame.to_world(local),
                f32::INFINITY,
            );
            continue;
        }
        let lookup = match guide {
            Some(g) if g.draws_lookup() => rng.next_f32(),
            _ => 0.0,
        };
        let mut sampler =
            VertexSampler::with_guide(hit.position, normal, wo, material, guide, lookup);
        if let Some(a) = guiding.and_then(|g| g.guide_probability) {
            sampler = sampler.with_guide_probability(a);
        }

        // Next-event estimation, weighed against the mixture that would also find the light.
        let (pick, u) = (rng.next_f32(), rng.next_vec2());
        let light = scene
            .next_event
            .then(|| scene.sample_light(hit.position, pick, u))
            .flatten();
        if let Some(light) = light {
            let f = sampler.bsdf_cos(light.direction);
            if f != Vec3::ZERO {
                let shadow = Ray::shadow(hit.position, hit.normal, light.direction, light.distance);
                if !scene.occluded(&shadow) {
                    let weight = power_heuristic(light.pdf, sampler.pdf(light.direction).mixture);
                    let c = f * light.radiance * (weight / light.pdf);
                    l += beta * c;
                    log.add(c);
                }
            }
        }

        // Scatter.
        let Some(s) = sampler.sample(rng) else {
            break;
        };
        let f = sampler.bsdf_cos(s.direction);
        let factor = f / s.pdf.mixture;
        beta *= factor;
        log.scale(factor);
        if guiding.is_some_and(|g| g.record) {
            // GUIDING (3): this vertex now waits for the radiance along `s.direction`. A guide
            // direction below the surface (f = 0) ends the path, and is recorded too, with zero
            // radiance: the field learns that nothing this vertex can use comes from there.
            // Not recording it would leave those cells without samples, and a cell without
            // samples borrows its parent's estimate (the field's shrinkage), which would keep
            // sending half the guide's samples into the surface.
            log.push(GuideVertex {
                position: hit.position,
                direction: s.direction,
                pdf: s.pdf.mixture,
                bsdf_pdf: s.pdf.bsdf,
                guide_pdf: s.pdf.guide,
                bsdf_cos: f,
                distance: f32::INFINITY,
                throughput: Vec3::ONE,
                radiance: Vec3::ZERO,
            });
        }
        if f == Vec3::ZERO {
            break;
        }
        if depth + 1 >= ROULETTE_DEPTH {
            let survive = beta.max_element().min(0.95);
            if rng.next_f32() >= survive {
                break;
            }
            beta /= survive;
            // The survivors' radiance is divided by the survival probability, for every
            // vertex's estimate too (including the one just pushed), so they stay unbiased.
            log.scale(Vec3::splat(1.0 / survive));
        }
        previous = Some((hit.position, s.pdf.mixture));
        ray = Ray::leaving(hit.position, hit.normal, s.direction, f32::INFINITY);
    }
    if let Some(g) = guiding.filter(|g| g.record) {
        log.record(g.field);
    }
    l
}
