//! The path tracer, and the reference for wiring sdguide into one.
//!
//! A unidirectional path tracer with next-event estimation (unless the scene turns it off),
//! multiple importance sampling (power heuristic), and Russian roulette — classic, by the
//! path's throughput, none, efficiency-aware roulette and splitting from the field's
//! continuation estimates, or (for the peer) Open PGL's guided roulette. Paths are traced depth first, recursively, so that a vertex may have
//! several continuations. Smooth dielectrics are delta vertices, passed through without a light
//! sample or a guide lookup. With guiding, every scattering direction is drawn from the
//! **one-sample mixture** `q = a·p_guide + (1 − a)·p_bsdf`, where `p_guide` is the field's
//! distribution at the vertex and `a` its learned guide probability. The wiring points are
//! marked `GUIDING:` below; there are four:
//!
//! 1. at a vertex, look up the distribution once, as its product with the clamped cosine about
//!    the shading normal (`field.distribution(x).at_surface(n)`: every guided material here
//!    reflects only, so nothing below the surface is worth a sample); where its guide
//!    probability is 0 (the field turned the guide off there) a pass that does not record
//!    samples the BSDF alone;
//! 2. sample from the mixture, and evaluate the *mixture* pdf `q` — for the direction sampled
//!    and for every next-event direction, since MIS must weigh the strategy actually used;
//! 3. tell the path recorder ([`sdguide::PathRecorder`], one per thread) what happens, as it
//!    happens: each vertex's direction (`push`: position, normal, direction, `f·cos`, the
//!    mixture pdf and the two techniques' pdfs), the radiance arriving along a vertex's ray
//!    (`add_radiance`: emission with its MIS weight, next-event contributions), the roulette
//!    or splitting played (`roulette`, `split`), and the rays traced (`add_cost`);
//! 4. once the camera sample is done, `finish` gives its estimate and the recorder every
//!    vertex's training sample — the radiance that arrived along its direction with every
//!    later weight, its square without roulette, the mixture terms — and its continuation,
//!    which go into the field. Between training passes the caller refines the field (no
//!    thread may render then).
//!
//! With roulette and splitting ([`Continuations`]), each vertex asks the factor of its cell's
//! continuation estimate, traces that many continuations in expectation, weighs each by its
//! inverse (the recorder applies the weights), and records every one it traced as a
//! `Continuation` (its estimate of the reflected light and the rays it cost).
//!
//! The integrator is generic over the guiding [`Backend`]: with the `openpgl` feature the same
//! four points serve Intel Open PGL:
//! the same mixture, MIS and recorded radiance, with the peer's distribution in the guide's
//! place, so that the two libraries are compared in one renderer.

use crate::backend::{Backend, Segment, VertexGuide};
use crate::geometry::{Frame, Ray};
use crate::material::luminance;
use crate::rng::Rng;
use crate::sampler::VertexSampler;
use crate::scene::Scene;
use glam::Vec3;
use sdguide::{GuidingField, PathRecorder, PathVertex, Splitting, VertexId, continuations};

pub use crate::scene::MAX_DEPTH;
/// Russian roulette starts after this many scattering events.
const ROULETTE_DEPTH: usize = 3;

/// The roulette a path plays where no efficiency-aware policy decides.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Roulette {
    /// Survive with probability `min(β, 0.95)`, `β` the throughput, from the third bounce.
    #[default]
    Classic,
    /// Never: every path goes on to [`MAX_DEPTH`] unless it leaves the scene. Costs more rays
    /// per sample, and keeps the guide's samples: classic roulette ends the paths a guide aims
    /// where its density is high, since their throughput `f/q` is low.
    Off,
    /// Intel Open PGL's guided Russian roulette, as its pbrt-v4 integration plays it: from the
    /// second vertex on, survive with [`guided_survival`] of the throughput arriving at the
    /// vertex, the radiance the backend's cache estimates the vertex sends back along the path
    /// (the adjoint), and the pixel's estimate. Classic where the pass has no pixel estimates
    /// yet; no roulette where the backend keeps no cache (or it holds nothing there).
    Guided,
}

/// Open PGL's guided Russian roulette (`openpgl::cpp::util::GuidedRussianRoulette`: the
/// weight window of Vorba and Křivánek 2016, "Adjoint-driven Russian roulette and splitting in
/// light transport simulation", without its splitting): the window's centre is the pixel's
/// estimate over the adjoint, `C = Ĩ/A`, its lower bound `2C/(1 + s)` with `s = 5`, and the
/// path survives with the mean of its throughput `β` over that bound, within `[0.1, 1]`. 1 where
/// the adjoint is not positive and finite.
pub fn guided_survival(beta: Vec3, adjoint: f32, pixel: f32) -> f32 {
    const S: f32 = 5.0;
    const MIN_SURVIVAL: f32 = 0.1;
    if !(adjoint.is_finite() && adjoint > 0.0) {
        return 1.0;
    }
    let lower = 2.0 * (pixel / adjoint) / (1.0 + S);
    let mean = (beta.x + beta.y + beta.z) / 3.0;
    let survival = if lower > 0.0 { mean / lower } else { 1.0 };
    if survival.is_nan() {
        return 1.0;
    }
    survival.clamp(MIN_SURVIVAL, 1.0)
}

/// How a render uses a guiding backend.
pub struct Guiding<'a, B: Backend> {
    /// The field to sample (and to record into when `record` is set).
    pub field: &'a B,
    /// Whether finished paths are recorded into the field (training passes).
    pub record: bool,
    /// Probability of sampling the guide instead of the BSDF; `None` uses the field's learned
    /// probability at each vertex.
    pub guide_probability: Option<f32>,
}

// Not derived: a derive would ask `B: Copy`, and only the reference is copied.
impl<B: Backend> Clone for Guiding<'_, B> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<B: Backend> Copy for Guiding<'_, B> {}

/// MIS weight of a strategy with pdf `a` against one with pdf `b` (power heuristic, β = 2).
fn power_heuristic(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 { a2 / (a2 + b2) } else { 0.0 }
}

/// How the paths of a pass decide how many continuations to trace from a vertex: by a
/// [`Roulette`], or efficiency-aware roulette and splitting from the continuation estimates of
/// a field ([`sdguide::Splitting`]) where it has a policy.
#[derive(Clone, Copy, Default)]
pub struct Continuing<'a> {
    /// The roulette where no splitting policy decides.
    pub roulette: Roulette,
    /// Efficiency-aware roulette and splitting.
    pub continuations: Option<Continuations<'a>>,
    /// Per pixel, the value its relative error is taken against, `sqrt(Ĩ² + ε)`, which the
    /// efficiency-aware and guided roulettes weigh a path against (empty until the passes
    /// give one).
    pub pixels: &'a [f32],
}

impl Continuing<'_> {
    /// Classic throughput roulette alone.
    pub const CLASSIC: Continuing<'static> = Continuing {
        roulette: Roulette::Classic,
        continuations: None,
        pixels: &[],
    };
}

/// Efficiency-aware roulette and splitting from the continuation estimates of a field.
#[derive(Clone, Copy)]
pub struct Continuations<'a> {
    /// The field whose cells hold the continuation estimates (and learn them when `record`).
    pub field: &'a GuidingField,
    /// This pass's policy; `None` until the image has estimates (the roulette meanwhile).
    pub splitting: Option<Splitting>,
    /// Whether every traced continuation is recorded into `field` (training passes).
    pub record: bool,
}

/// Most rays one camera sample may trace before its vertices stop splitting (they may still
/// end by roulette): a bound on the work a wrong estimate can cause, which keeps the estimate
/// unbiased (each vertex weighs its continuations by the factor it used).
pub const MAX_RAYS_PER_SAMPLE: u32 = 256;

/// One camera sample's radiance, and what it cost.
#[derive(Clone, Copy, Debug)]
pub struct PathSample {
    /// The radiance arriving along the camera ray.
    pub radiance: Vec3,
    /// Rays traced: intersections and shadow rays.
    pub rays: u32,
}

/// A render thread's scratch: the path recorder, and each recorded vertex's segments (what
/// Open PGL's parallax compensation and radiance cache need), by vertex.
#[derive(Default)]
pub struct Scratch {
    path: PathRecorder,
    segments: Vec<Segment>,
}

/// The radiance arriving along `ray` (one path sample), guided when `guiding` is given, with
/// classic roulette.
pub fn radiance<B: Backend>(
    scene: &Scene,
    guiding: Option<Guiding<'_, B>>,
    ray: Ray,
    rng: &mut Rng,
) -> Vec3 {
    let mut scratch = Scratch::default();
    path_sample(
        scene,
        guiding,
        (&Continuing::CLASSIC, 0),
        ray,
        (rng, &mut scratch),
    )
    .radiance
}

/// The radiance arriving along `ray` and its cost, guided when `guiding` is given, the path
/// continuing as `continuing` says (`pixel`: the pixel's index into its `pixels`).
pub fn path_sample<B: Backend>(
    scene: &Scene,
    guiding: Option<Guiding<'_, B>>,
    (continuing, pixel): (&Continuing<'_>, usize),
    ray: Ray,
    (rng, scratch): (&mut Rng, &mut Scratch),
) -> PathSample {
    let estimate = continuing.pixels.get(pixel).copied();
    let continuations = continuing.continuations;
    let policy = continuations.and_then(|c| Some((c.splitting?, estimate?)));
    // Guided roulette plays classic roulette until the passes give the pixel an estimate.
    let roulette = match (continuing.roulette, estimate) {
        (Roulette::Guided, None) => Roulette::Classic,
        (roulette, _) => roulette,
    };
    let camera = scratch.path.start();
    scratch.segments.clear();
    let mut path = Path {
        scene,
        guiding,
        continuations,
        policy,
        roulette,
        estimate: estimate.unwrap_or(0.0),
        rng,
        scratch,
        rays: 0,
    };
    path.trace(ray, 0, Vec3::ONE, None, camera);
    let rays = path.rays;
    // GUIDING (4): the path is done; the recorder hands back every vertex's training sample
    // (the radiance that arrived along its direction, its second moment without roulette,
    // the mixture terms) and its continuation.
    let Scratch { path, segments } = scratch;
    let radiance = path.finish();
    let samples = guiding.filter(|g| g.record);
    let continuations = continuations.filter(|c| c.record);
    if samples.is_some() || continuations.is_some() {
        for r in path.records() {
            if let Some(g) = samples {
                let segment = segments.get(r.id.index()).copied();
                g.field
                    .record(&r.sample, segment.unwrap_or(Segment::UNKNOWN));
            }
            if let Some(c) = continuations {
                c.field.record_continuation(&r.continuation);
            }
        }
    }
    PathSample { radiance, rays }
}

/// Where a path scatters: a surface hit, or a point inside a medium.
struct At {
    position: Vec3,
    /// The surface's geometric normal, which rays leave offset along; `None` in a medium.
    normal: Option<Vec3>,
}

impl At {
    /// The ray leaving the vertex along `direction`.
    fn leaving(&self, direction: Vec3) -> Ray {
        match self.normal {
            Some(n) => Ray::leaving(self.position, n, direction, f32::INFINITY),
            None => Ray {
                origin: self.position,
                direction,
                t_max: f32::INFINITY,
            },
        }
    }

    /// The shadow ray toward a point `distance` away along `direction`.
    fn shadow(&self, direction: Vec3, distance: f32) -> Ray {
        match self.normal {
            Some(n) => Ray::shadow(self.position, n, direction, distance),
            None => Ray {
                origin: self.position,
                direction,
                t_max: distance * (1.0 - 1e-4),
            },
        }
    }
}

/// One camera sample's tree of continuations, traced depth first.
struct Path<'s, 'a, B: Backend> {
    scene: &'s Scene,
    guiding: Option<Guiding<'a, B>>,
    continuations: Option<Continuations<'a>>,
    /// The splitting policy and the pixel's `sqrt(I² + ε)`, when there is a policy.
    policy: Option<(Splitting, f32)>,
    /// The roulette where no policy decides.
    roulette: Roulette,
    /// The pixel's `sqrt(Ĩ² + ε)` (0 without one).
    estimate: f32,
    rng: &'s mut Rng,
    scratch: &'s mut Scratch,
    rays: u32,
}

impl<'a, B: Backend> Path<'_, 'a, B> {
    /// Traces `ray`, the ray of the recorded vertex `owner`, which leaves the path's
    /// `depth`-th scattering event with throughput `beta` from the camera (every roulette and
    /// splitting weight included), and tells the recorder what arrives along it; `previous`
    /// is the pdf the ray's direction was drawn with and where (`None` for a camera ray or
    /// after a dielectric). Returns the distance to its first hit (infinite if none).
    fn trace(
        &mut self,
        mut ray: Ray,
        mut depth: usize,
        beta: Vec3,
        mut previous: Option<(Vec3, f32)>,
        owner: VertexId,
    ) -> f32 {
        let scene = self.scene;
        let mut first_hit = None;
        loop {
            self.ray(owner);
            let hit = scene.intersect(&ray);
            // In a medium, a free flight may end before the surface (a scene without media
            // draws no number for it, so its paths stay what they were).
            let scatter = (!scene.media.is_empty())
                .then(|| {
                    let t_max = hit.as_ref().map_or(f32::INFINITY, |h| h.t);
                    scene.media.sample_scatter(&ray, t_max, self.rng.next_f32())
                })
                .flatten();
            if let Some(scatter) = scatter {
                let distance = *first_hit.get_or_insert(scatter.t);
                if depth == scene.max_depth {
                    return distance;
                }
                let (guide, lookup) = self.guide_lookup();
                let at = At {
                    position: ray.at(scatter.t),
                    normal: None,
                };
                let sampler = VertexSampler::in_medium(
                    at.position,
                    ray.direction,
                    &scatter.medium,
                    guide,
                    lookup,
                );
                self.scatter(&at, self.tune(sampler), depth, beta, owner);
                return distance;
            }
            let Some(hit) = hit else {
                return first_hit.unwrap_or(f32::INFINITY);
            };
            let distance = *first_hit.get_or_insert(hit.t);
            let wo = -ray.direction;
            let emitted = scene.emitted(&hit, wo);
            if emitted != Vec3::ZERO {
                let weight = match previous {
                    Some((x, pdf)) if scene.next_event => {
                        power_heuristic(pdf, scene.light_pdf(x, &hit, ray.direction))
                    }
                    _ => 1.0,
                };
                self.scratch.path.add_radiance(owner, emitted * weight);
            }
            if depth == scene.max_depth {
                return distance;
            }
            let material = scene.material(&hit);
            let normal = hit.normal_toward(wo);
            if material.is_dielectric() {
                // A delta vertex: no light sample reaches through it and no guide can sample
                // it, so the path goes on in the one direction Fresnel picks, with weight 1,
                // and the vertex is not recorded; what arrives through the glass arrives along
                // `owner`'s ray, which is what a guide there learns to aim at.
                let frame = Frame::new(normal);
                let entering = hit.normal.dot(wo) > 0.0;
                let local =
                    material.sample_dielectric(frame.to_local(wo), entering, self.rng.next_f32());
                // What the path finds next was reached by no strategy a light sample competes
                // with.
                previous = None;
                ray = Ray::leaving(
                    hit.position,
                    hit.normal,
                    frame.to_world(local),
                    f32::INFINITY,
                );
                depth += 1;
                continue;
            }
            let (guide, lookup) = self.guide_lookup();
            let sampler =
                VertexSampler::with_guide(hit.position, normal, wo, material, guide, lookup);
            let at = At {
                position: hit.position,
                normal: Some(hit.normal),
            };
            self.scatter(&at, self.tune(sampler), depth, beta, owner);
            return distance;
        }
    }

    /// The guide to look up at a vertex (none where it is never drawn: the field then only
    /// learns), and the random number a stochastic lookup draws.
    fn guide_lookup(&mut self) -> (Option<&'a B>, f32) {
        let guide = self.guiding.map(|g| g.field);
        let lookup = match guide {
            Some(g) if g.draws_lookup() => self.rng.next_f32(),
            _ => 0.0,
        };
        let fixed = self.guiding.and_then(|g| g.guide_probability);
        (guide.filter(|_| fixed != Some(0.0)), lookup)
    }

    /// A vertex's sampler with the render's fixed guide probability, if any, and without an
    /// idle guide outside training passes.
    fn tune<'v>(&self, mut sampler: VertexSampler<'v, B>) -> VertexSampler<'v, B> {
        if let Some(a) = self.guiding.and_then(|g| g.guide_probability) {
            sampler = sampler.with_guide_probability(a);
        }
        if !self.guiding.is_some_and(|g| g.record) {
            sampler = sampler.without_idle_guide();
        }
        sampler
    }

    /// Scattering at the vertex `at` that the ray of `owner` reached, with `sampler`:
    /// next-event estimation, the continuations' factor, and the continuations.
    fn scatter(
        &mut self,
        at: &At,
        sampler: VertexSampler<'_, B>,
        depth: usize,
        beta: Vec3,
        owner: VertexId,
    ) {
        let scene = self.scene;
        // Next-event estimation, weighed against the mixture that would also find the light,
        // and attenuated by the media the shadow ray crosses.
        let (pick, u) = (self.rng.next_f32(), self.rng.next_vec2());
        let light = scene
            .next_event
            .then(|| scene.sample_light(at.position, pick, u))
            .flatten();
        if let Some(light) = light {
            let f = sampler.bsdf_cos(light.direction);
            if f != Vec3::ZERO {
                let shadow = at.shadow(light.direction, light.distance);
                self.ray(owner);
                if !scene.occluded(&shadow) {
                    let weight = power_heuristic(light.pdf, sampler.pdf(light.direction).mixture);
                    let transmittance = scene.media.transmittance(&shadow, shadow.t_max);
                    let l = f * light.radiance * (transmittance * weight / light.pdf);
                    self.scratch.path.add_radiance(owner, l);
                }
            }
        }

        // How many continuations, each weighed by 1/q: the efficiency-aware factor where the
        // cell has an estimate, else one, under classic roulette.
        let guide = self.guiding.map(|g| g.field);
        let policy = self.policy.zip(self.continuations.map(|c| c.field));
        let factor = policy.and_then(|((splitting, pixel), field)| {
            // The guide's view of the same field already holds its cell's estimate: no second
            // lookup.
            let same = guide
                .and_then(Backend::as_field)
                .is_some_and(|f| std::ptr::eq(f, field));
            let estimate = sampler
                .guide
                .as_ref()
                .filter(|_| same)
                .and_then(VertexGuide::continuation)
                .unwrap_or_else(|| field.continuation(at.position));
            let path = &mut self.scratch.path;
            let q = path.factor(&splitting, &estimate, luminance(beta), pixel)?;
            // The camera vertex only plays roulette: there the rest of the image, which the
            // factor takes to be the whole image, is mostly this vertex's own continuations, so
            // every factor is its own fixed point and estimation noise alone sets it (measured
            // on `door`: 90% of camera vertices at the largest factor). Its split would save
            // only the camera ray.
            Some(if depth == 0 || self.rays >= MAX_RAYS_PER_SAMPLE {
                q.min(1.0)
            } else {
                q
            })
        });
        let (n, weight) = match factor {
            Some(q) => {
                let (n, weight) = continuations(q, self.rng.next_f32());
                self.scratch.path.split(owner, q, n);
                (n, weight)
            }
            None => (1, 1.0),
        };
        for _ in 0..n {
            self.continue_from(at, &sampler, depth, beta * weight, factor.is_none(), owner);
        }
    }

    /// One ray traced for `owner`: counted, and its cost recorded.
    fn ray(&mut self, owner: VertexId) {
        self.rays += 1;
        self.scratch.path.add_cost(owner, 1.0);
    }

    /// One continuation from the vertex that the ray of `owner` reached: a direction from its
    /// sampler, pushed to the recorder, and the radiance along it. With `classic` (no
    /// splitting policy decides), the path then meets the path's [`Roulette`].
    fn continue_from(
        &mut self,
        at: &At,
        sampler: &VertexSampler<'_, B>,
        depth: usize,
        beta: Vec3,
        classic: bool,
        owner: VertexId,
    ) {
        let Some(s) = sampler.sample(self.rng) else {
            return;
        };
        let f = sampler.bsdf_cos(s.direction);
        let arriving = beta;
        let beta = beta * (f / s.pdf.mixture);
        // GUIDING (3): push the vertex — its position and normal (or that it lies in a
        // medium), the direction, `f·cos`, the mixture pdf and the two techniques' pdfs.
        let vertex = PathVertex::new(at.position, s.direction, f, s.pdf.mixture)
            .with_mixture(s.pdf.bsdf, s.pdf.guide);
        let vertex = match sampler.normal() {
            Some(n) => vertex.with_normal(n),
            None => vertex.in_volume(),
        };
        let v = self.scratch.path.push(owner, vertex);
        // Its segments, for the backends that record them: the direction back along the path
        // now (a vertex that ends below holds it too), how far its ray reached once traced.
        let segments = &mut self.scratch.segments;
        if segments.len() <= v.index() {
            segments.resize(v.index() + 1, Segment::UNKNOWN);
        }
        segments[v.index()] = Segment {
            distance: f32::INFINITY,
            outgoing: sampler.outgoing(),
        };
        // Roulette decides after the direction is drawn, so a vertex it ends still records its
        // direction (with zero radiance): the recorded radiance, 1/survive times what arrived
        // or nothing, is unbiased whatever the direction.
        let survive = match self.roulette {
            _ if !classic => 1.0,
            Roulette::Classic if depth + 1 >= ROULETTE_DEPTH => beta.max_element().min(0.95),
            // The throughput arriving at the vertex, against what it sends back.
            Roulette::Guided if depth >= 1 => sampler.outgoing_radiance().map_or(1.0, |adjoint| {
                guided_survival(arriving, adjoint, self.estimate)
            }),
            _ => 1.0,
        };
        // A guide direction below the surface (f = 0) ends the continuation, and is recorded
        // too, with zero radiance: the field learns that nothing this vertex can use comes
        // from there. Not recording it would leave those cells without samples, and a cell
        // without samples borrows its parent's estimate (the field's shrinkage), which would
        // keep sending half the guide's samples into the surface.
        if f == Vec3::ZERO {
            return;
        }
        if self.rng.next_f32() >= survive {
            self.scratch.path.roulette(v, survive, false);
            return;
        }
        self.scratch.path.roulette(v, survive, true);
        let distance = self.trace(
            at.leaving(s.direction),
            depth + 1,
            beta / survive,
            Some((at.position, s.pdf.mixture)),
            v,
        );
        if let Some(segment) = self.scratch.segments.get_mut(v.index()) {
            segment.distance = distance;
        }
    }
}

#[cfg(test)]
mod tests;
