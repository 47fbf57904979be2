//! The path tracer, and the reference for wiring sdguide into one.
//!
//! A unidirectional path tracer with next-event estimation (unless the scene turns it off),
//! multiple importance sampling (power heuristic), and Russian roulette — classic, by the
//! path's throughput, none, or efficiency-aware roulette and splitting from the field's
//! continuation estimates. Paths are traced depth first, recursively, so that a vertex may have
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
//! 3. a continuation's value is the radiance arriving along its direction, every later
//!    roulette and splitting weight included: what the recursive call returns;
//! 4. when it returns, record the vertex: position, direction, the luminance of that incident
//!    radiance, the mixture pdf, and the mixture terms the guide probability learns from.
//!    Between training passes the caller refines the field (no thread may render then).
//!
//! With roulette and splitting ([`Continuations`]), each vertex asks the factor of its cell's
//! continuation estimate, traces that many continuations in expectation, weighs each by its
//! inverse, and records every one it traced as a `Continuation` (its estimate of the reflected
//! light and the rays it cost).
//!
//! The integrator is generic over the guiding [`Backend`]: with the `openpgl` feature the same
//! four points serve Intel Open PGL:
//! the same mixture, MIS and recorded radiance, with the peer's distribution in the guide's
//! place, so that the two libraries are compared in one renderer.

use crate::backend::{Backend, Recorded, VertexGuide};
use crate::geometry::{Frame, Ray};
use crate::material::luminance;
use crate::rng::Rng;
use crate::sampler::VertexSampler;
use crate::scene::Scene;
use glam::Vec3;
use sdguide::{Continuation, GuidingField, Splitting, continuations};

/// Longest path, in scattering events.
pub const MAX_DEPTH: usize = 10;
/// Russian roulette starts after this many scattering events.
const ROULETTE_DEPTH: usize = 3;

/// Whether a path plays classic throughput roulette where no efficiency-aware policy decides.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Roulette {
    /// Survive with probability `min(β, 0.95)`, `β` the throughput, from the third bounce.
    #[default]
    Classic,
    /// Never: every path goes on to [`MAX_DEPTH`] unless it leaves the scene. Costs more rays
    /// per sample, and keeps the guide's samples: classic roulette ends the paths a guide aims
    /// where its density is high, since their throughput `f/q` is low.
    Off,
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

/// How the paths of a pass decide how many continuations to trace from a vertex: by classic
/// throughput roulette, or efficiency-aware roulette and splitting from the continuation
/// estimates of a field ([`sdguide::Splitting`]).
#[derive(Clone, Copy)]
pub struct Continuations<'a> {
    /// The field whose cells hold the continuation estimates (and learn them when `record`).
    pub field: &'a GuidingField,
    /// This pass's policy; `None` until the image has estimates (classic roulette meanwhile).
    pub splitting: Option<Splitting>,
    /// Per pixel, the value its relative error is taken against, `sqrt(I² + ε)` (empty
    /// without a policy).
    pub pixels: &'a [f32],
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

/// The radiance arriving along `ray` (one path sample), guided when `guiding` is given, with
/// classic roulette.
pub fn radiance<B: Backend>(
    scene: &Scene,
    guiding: Option<Guiding<'_, B>>,
    ray: Ray,
    rng: &mut Rng,
) -> Vec3 {
    path_sample(scene, guiding, (Roulette::Classic, None), ray, rng).radiance
}

/// The radiance arriving along `ray` and its cost, guided when `guiding` is given, with
/// roulette and splitting by `continuations` when given (`pixel`: the pixel's index into its
/// `pixels`), else with `roulette`.
pub fn path_sample<B: Backend>(
    scene: &Scene,
    guiding: Option<Guiding<'_, B>>,
    (roulette, continuations): (Roulette, Option<(&Continuations<'_>, usize)>),
    ray: Ray,
    rng: &mut Rng,
) -> PathSample {
    let policy = continuations.and_then(|(c, pixel)| {
        let splitting = c.splitting?;
        Some((splitting, *c.pixels.get(pixel)?))
    });
    let mut path = Path {
        scene,
        guiding,
        continuations: continuations.map(|(c, _)| *c),
        policy,
        roulette,
        rng,
        rays: 0,
    };
    let radiance = path.trace(ray, 0, Vec3::ONE, None).radiance;
    PathSample {
        radiance,
        rays: path.rays,
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
    rng: &'s mut Rng,
    rays: u32,
}

/// What a ray brought back.
struct Traced {
    /// The radiance arriving along it.
    radiance: Vec3,
    /// Distance to its first hit (infinite if none).
    distance: f32,
    /// The first roulette the path played below the ray.
    roulette: FirstRoulette,
}

/// The first Russian roulette a path played below a ray or a direction (classic, or by an
/// efficiency-aware factor below 1), and the part of the radiance that arrived along it before
/// that roulette: what a vertex needs for the estimate of its value's square without that
/// roulette (`Sample::second_moment`).
#[derive(Clone, Copy, Debug)]
struct FirstRoulette {
    /// The radiance added before the roulette (all of it where none was played).
    before: Vec3,
    /// The probability of going on (1 where none was played).
    probability: f32,
    /// Whether the path went on.
    survived: bool,
}

impl FirstRoulette {
    /// No roulette below: all of `radiance` came before it.
    fn none(radiance: Vec3) -> Self {
        FirstRoulette {
            before: radiance,
            probability: 1.0,
            survived: true,
        }
    }

    /// An unbiased estimate of what the square of `value` (a luminance that this roulette, if
    /// any, weighed) would be without the roulette: `(Y² − (1 − s)·A²)/s` where the path
    /// survived, `Y = A + s·(value − A)` the value without the roulette's `1/s`, and `A²` where
    /// it ended (`A` what came before, `s` the probability). Its expectation over the
    /// roulette's coin is `(A + B)²`, with `B` what the path would have brought after it.
    fn second_moment(self, value: f32) -> f32 {
        let (a, s) = (luminance(self.before), self.probability);
        if s >= 1.0 {
            return value * value;
        }
        if !self.survived {
            return a * a;
        }
        let y = a + s * (value - a);
        ((y * y - (1.0 - s) * a * a) / s).max(0.0)
    }
}

impl<'a, B: Backend> Path<'_, 'a, B> {
    /// The radiance arriving along `ray`, which leaves the path's `depth`-th scattering event
    /// with throughput `beta` from the camera (every roulette and splitting weight included);
    /// `previous` is the pdf the ray's direction was drawn with and where (`None` for a camera
    /// ray or after a dielectric).
    fn trace(
        &mut self,
        mut ray: Ray,
        mut depth: usize,
        beta: Vec3,
        mut previous: Option<(Vec3, f32)>,
    ) -> Traced {
        let scene = self.scene;
        let guide = self.guiding.map(|g| g.field);
        let mut first_hit = None;
        let mut l = Vec3::ZERO;
        loop {
            self.rays += 1;
            let Some(hit) = scene.intersect(&ray) else {
                return Traced {
                    radiance: l,
                    distance: first_hit.unwrap_or(f32::INFINITY),
                    roulette: FirstRoulette::none(l),
                };
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
                l += emitted * weight;
            }
            if depth == MAX_DEPTH {
                return Traced {
                    radiance: l,
                    distance,
                    roulette: FirstRoulette::none(l),
                };
            }
            let material = scene.material(&hit);
            let normal = hit.normal_toward(wo);
            if material.is_dielectric() {
                // A delta vertex: no light sample reaches through it and no guide can sample
                // it, so the path goes on in the one direction Fresnel picks, with weight 1,
                // and the vertex is not recorded; the vertex before it records the radiance
                // arriving through the glass, which is what a guide there learns to aim at.
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
            let lookup = match guide {
                Some(g) if g.draws_lookup() => self.rng.next_f32(),
                _ => 0.0,
            };
            let fixed = self.guiding.and_then(|g| g.guide_probability);
            // A guide that is never drawn is not looked up (the field then only learns).
            let guide = guide.filter(|_| fixed != Some(0.0));
            let mut sampler =
                VertexSampler::with_guide(hit.position, normal, wo, material, guide, lookup);
            if let Some(a) = fixed {
                sampler = sampler.with_guide_probability(a);
            }
            if !self.guiding.is_some_and(|g| g.record) {
                sampler = sampler.without_idle_guide();
            }

            // Next-event estimation, weighed against the mixture that would also find the
            // light.
            let (pick, u) = (self.rng.next_f32(), self.rng.next_vec2());
            let light = scene
                .next_event
                .then(|| scene.sample_light(hit.position, pick, u))
                .flatten();
            if let Some(light) = light {
                let f = sampler.bsdf_cos(light.direction);
                if f != Vec3::ZERO {
                    let shadow =
                        Ray::shadow(hit.position, hit.normal, light.direction, light.distance);
                    self.rays += 1;
                    if !scene.occluded(&shadow) {
                        let weight =
                            power_heuristic(light.pdf, sampler.pdf(light.direction).mixture);
                        l += f * light.radiance * (weight / light.pdf);
                    }
                }
            }

            // How many continuations, each weighed by 1/q: the efficiency-aware factor where
            // the cell has an estimate, else one, under classic roulette.
            let factor = self.policy.and_then(|(splitting, pixel)| {
                let field = self.continuations?.field;
                // The guide's view of the same field already holds its cell's estimate: no
                // second lookup.
                let same = guide
                    .and_then(Backend::as_field)
                    .is_some_and(|f| std::ptr::eq(f, field));
                let estimate = sampler
                    .guide
                    .as_ref()
                    .filter(|_| same)
                    .and_then(VertexGuide::continuation)
                    .unwrap_or_else(|| field.continuation(hit.position));
                let q = splitting.factor(&estimate, luminance(beta), pixel)?;
                // The camera vertex only plays roulette: there the rest of the image, which the
                // factor takes to be the whole image, is mostly this vertex's own continuations,
                // so every factor is its own fixed point and estimation noise alone sets it
                // (measured on `door`: 90% of camera vertices at the largest factor). Its split
                // would save only the camera ray.
                Some(if depth == 0 || self.rays >= MAX_RAYS_PER_SAMPLE {
                    q.min(1.0)
                } else {
                    q
                })
            });
            let (n, weight) = match factor {
                Some(q) => continuations(q, self.rng.next_f32()),
                None => (1, 1.0),
            };
            let before = l;
            let mut below = None;
            for _ in 0..n {
                let (reflected, roulette) =
                    self.continue_from(&hit, &sampler, depth, beta * weight, factor.is_none());
                l += weight * reflected;
                below = Some(roulette);
            }
            // The first roulette below the ray: this vertex's own where its factor played
            // one, with all it gathered before; else, below its one continuation of weight 1,
            // the first one below that. Below a split vertex none is tracked.
            let roulette = match (factor, below) {
                (Some(q), _) if q < 1.0 => FirstRoulette {
                    before,
                    probability: q,
                    survived: n == 1,
                },
                (q, Some(r)) if q.is_none_or(|q| q == 1.0) => FirstRoulette {
                    before: before + r.before,
                    ..r
                },
                _ => FirstRoulette::none(l),
            };
            return Traced {
                radiance: l,
                distance,
                roulette,
            };
        }
    }

    /// One continuation from a vertex: a direction from its sampler and the radiance along it;
    /// returns the continuation's estimate of the light the vertex reflects, `f·L_i/q`, and the
    /// first roulette below it (what it reflected before that, in the same units).
    /// With `classic` (no splitting policy decides), the path then meets the path's
    /// [`Roulette`].
    /// The guide's sample and the continuation are recorded when the pass records.
    fn continue_from(
        &mut self,
        hit: &crate::scene::Hit,
        sampler: &VertexSampler<'_, B>,
        depth: usize,
        beta: Vec3,
        classic: bool,
    ) -> (Vec3, FirstRoulette) {
        let rays_before = self.rays;
        let Some(s) = sampler.sample(self.rng) else {
            return (Vec3::ZERO, FirstRoulette::none(Vec3::ZERO));
        };
        let f = sampler.bsdf_cos(s.direction);
        let factor = f / s.pdf.mixture;
        let beta = beta * factor;
        // Classic roulette decides after the direction is drawn, so a vertex it ends still
        // records its direction (with zero radiance): the recorded radiance, 1/survive times
        // what arrived or nothing, is unbiased whatever the direction.
        let survive =
            if classic && self.roulette == Roulette::Classic && depth + 1 >= ROULETTE_DEPTH {
                beta.max_element().min(0.95)
            } else {
                1.0
            };
        // GUIDING (3): a guide direction below the surface (f = 0) ends the continuation, and
        // is recorded too, with zero radiance: the field learns that nothing this vertex can
        // use comes from there. Not recording it would leave those cells without samples, and
        // a cell without samples borrows its parent's estimate (the field's shrinkage), which
        // would keep sending half the guide's samples into the surface.
        // The roulette below the direction, as seen from this vertex: its own, if it played
        // one, with nothing before it; else the first one the traced path played.
        let own = |survived| FirstRoulette {
            before: Vec3::ZERO,
            probability: survive,
            survived,
        };
        let (incident, distance, roulette) = if f == Vec3::ZERO {
            (Vec3::ZERO, f32::INFINITY, FirstRoulette::none(Vec3::ZERO))
        } else if self.rng.next_f32() >= survive {
            (Vec3::ZERO, f32::INFINITY, own(false))
        } else {
            let ray = Ray::leaving(hit.position, hit.normal, s.direction, f32::INFINITY);
            let t = self.trace(
                ray,
                depth + 1,
                beta / survive,
                Some((hit.position, s.pdf.mixture)),
            );
            let roulette = if survive < 1.0 { own(true) } else { t.roulette };
            (t.radiance / survive, t.distance, roulette)
        };
        let reflected = factor * incident;
        if let Some(g) = self.guiding.filter(|g| g.record) {
            // GUIDING (4): record the vertex: position, direction, the luminance of the
            // incident radiance, the mixture pdf, and the mixture terms the guide probability
            // learns from.
            let integrand = luminance(f * incident);
            let value = luminance(incident);
            g.field.record(&Recorded {
                position: hit.position,
                normal: sampler.frame.normal(),
                direction: s.direction,
                pdf: s.pdf,
                incident: value,
                second_moment: roulette.second_moment(value),
                integrand,
                distance,
            });
        }
        if let Some(c) = self.continuations.filter(|c| c.record) {
            c.field.record_continuation(&Continuation {
                position: hit.position,
                value: luminance(reflected),
                cost: (self.rays - rays_before) as f32,
            });
        }
        let roulette = FirstRoulette {
            before: factor * roulette.before,
            ..roulette
        };
        (reflected, roulette)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Over the roulette's coin, the estimate of the square has the expectation of the square
    /// without the roulette, `(A + B)²`, whatever the probability: the property that keeps the
    /// guide's second moment from following its own pdf.
    #[test]
    fn the_roulette_free_square_is_unbiased() {
        for (a, b) in [(0.0f32, 2.0f32), (0.7, 0.0), (0.4, 1.3), (3.0, 0.05)] {
            for s in [0.05f32, 0.3, 0.5, 0.95] {
                let roulette = |survived| FirstRoulette {
                    before: Vec3::splat(a),
                    probability: s,
                    survived,
                };
                // What the vertex records: everything before, and `1/s` times what came after.
                let survived = roulette(true).second_moment(a + b / s);
                let ended = roulette(false).second_moment(a);
                let expected = (a + b) * (a + b);
                let mean = s * survived + (1.0 - s) * ended;
                assert!(
                    (mean - expected).abs() <= 1e-5 * expected.max(1.0),
                    "A = {a}, B = {b}, s = {s}: {mean} against {expected}"
                );
            }
        }
        // Without a roulette the square is the value's.
        assert_eq!(FirstRoulette::none(Vec3::ONE).second_moment(3.0), 9.0);
    }
}
