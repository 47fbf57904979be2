//! The directional sampling strategy at one path vertex: the BSDF's (at a surface) or the phase
//! function's (in a medium), mixed with a guide's.
//!
//! With a guide, a direction is drawn from the **one-sample mixture**
//! `q = a·p_guide + (1 − a)·p_bsdf`, `a` the guide probability and `p_bsdf` the BSDF's or the
//! phase function's pdf; MIS and the estimator use the mixture's pdf `q`, for the direction
//! sampled and for every next-event direction.

use crate::backend::{Backend, VertexGuide};
use crate::geometry::Frame;
use crate::material::Material;
use crate::medium::{Medium, henyey_greenstein, sample_henyey_greenstein};
use crate::rng::Rng;
use glam::Vec3;
use sdguide::GuidingField;

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
    /// The BSDF's (or phase function's) sampling pdf.
    pub bsdf: f32,
    /// The guiding distribution's pdf (0 without guiding).
    pub guide: f32,
}

/// What scatters at a vertex.
#[derive(Clone, Copy)]
enum Scatterer<'a> {
    /// A surface's BSDF, its shading frame, and the outgoing direction in that frame.
    Surface {
        material: &'a Material,
        frame: Frame,
        wo: Vec3,
    },
    /// A medium's phase function about the direction the path arrived along, and its albedo
    /// (the weight of a scattering event under free-flight sampling).
    Medium { travel: Vec3, g: f32, albedo: f32 },
}

/// The directional sampling strategy at one vertex: the BSDF's (or phase function's), mixed
/// with the guide's when there is a guiding field.
pub struct VertexSampler<'a, B: Backend + 'a = GuidingField> {
    scatterer: Scatterer<'a>,
    pub(crate) guide: Option<B::Vertex<'a>>,
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
        Self::with_guide(position, normal, wo, material, field, 0.0)
    }
}

impl<'a, B: Backend + 'a> VertexSampler<'a, B> {
    /// The strategy with any backend's guide; `lookup` is a uniform random number for a
    /// backend whose spatial lookup is stochastic (Open PGL's), unused by sdguide's.
    pub fn with_guide(
        position: Vec3,
        normal: Vec3,
        wo: Vec3,
        material: &'a Material,
        guide: Option<&'a B>,
        lookup: f32,
    ) -> Self {
        let frame = Frame::new(normal);
        // GUIDING (1): one lookup per vertex; sdguide's distribution is a lock-free view.
        let guide = guide.and_then(|g| g.at(position, normal, lookup));
        let a = guide.as_ref().map_or(0.0, |g| g.guide_probability());
        VertexSampler {
            scatterer: Scatterer::Surface {
                material,
                frame,
                wo: frame.to_local(wo),
            },
            guide,
            a,
        }
    }

    /// The strategy at `position` inside `medium`, for a path that arrived travelling along
    /// `travel` (unit): the phase function mixed with the backend's volume guide (its product
    /// with the phase function, where the backend has one).
    pub fn in_medium(
        position: Vec3,
        travel: Vec3,
        medium: &Medium,
        guide: Option<&'a B>,
        lookup: f32,
    ) -> Self {
        // GUIDING (1), in a medium: the volume guide's product with the phase function.
        let guide = guide.and_then(|g| g.in_medium(position, travel, medium.g, lookup));
        let a = guide.as_ref().map_or(0.0, |g| g.guide_probability());
        VertexSampler {
            scatterer: Scatterer::Medium {
                travel,
                g: medium.g,
                albedo: medium.albedo,
            },
            guide,
            a,
        }
    }

    /// The shading normal, at a surface (`None` in a medium).
    pub fn normal(&self) -> Option<Vec3> {
        match self.scatterer {
            Scatterer::Surface { frame, .. } => Some(frame.normal()),
            Scatterer::Medium { .. } => None,
        }
    }

    /// The unit direction back along the path, toward the camera: `wo` at a surface, against
    /// the direction of travel in a medium.
    pub fn outgoing(&self) -> Vec3 {
        match self.scatterer {
            Scatterer::Surface { frame, wo, .. } => frame.to_world(wo),
            Scatterer::Medium { travel, .. } => -travel,
        }
    }

    /// The radiance the guide's cache estimates the vertex sends back along the path
    /// (luminance), where the backend keeps one: the adjoint of guided Russian roulette.
    pub fn outgoing_radiance(&self) -> Option<f32> {
        self.guide.as_ref()?.outgoing_radiance(self.outgoing())
    }

    /// The same strategy with the guide drawn with probability `a` instead of the learned one.
    pub fn with_guide_probability(self, a: f32) -> Self {
        VertexSampler { a, ..self }
    }

    /// The same strategy without its guide where the guide is never drawn (`a = 0`: the field
    /// turned it off in this cell): BSDF sampling alone, with no guide pdf to evaluate. A
    /// training pass keeps it, since the recorded mixture terms need the guide's pdf for the
    /// cell to tell whether the guide pays again.
    pub fn without_idle_guide(self) -> Self {
        let guide = self.guide.filter(|_| self.a > 0.0);
        VertexSampler { guide, ..self }
    }

    /// The BSDF `f(wo, wi)·|cos θ_i|` for a world direction; in a medium, the phase function
    /// times the albedo.
    pub fn bsdf_cos(&self, direction: Vec3) -> Vec3 {
        match self.scatterer {
            Scatterer::Surface {
                material,
                frame,
                wo,
            } => {
                let wi = frame.to_local(direction);
                material.eval(wo, wi) * wi.z.abs()
            }
            Scatterer::Medium { travel, g, albedo } => {
                Vec3::splat(albedo * henyey_greenstein(travel.dot(direction), g))
            }
        }
    }

    /// The BSDF's (or phase function's) own sampling pdf of `direction`.
    fn technique_pdf(&self, direction: Vec3) -> f32 {
        match self.scatterer {
            Scatterer::Surface {
                material,
                frame,
                wo,
            } => material.pdf(wo, frame.to_local(direction)),
            Scatterer::Medium { travel, g, .. } => henyey_greenstein(travel.dot(direction), g),
        }
    }

    /// The pdfs of drawing the world direction `direction`.
    pub fn pdf(&self, direction: Vec3) -> MixturePdf {
        // GUIDING (2): MIS and the estimator need the pdf of the whole mixture.
        let guide = self.guide.as_ref().map_or(0.0, |g| g.pdf(direction));
        self.mixture_pdf(direction, guide)
    }

    /// The pdfs of `direction`, whose guide pdf is `guide`.
    fn mixture_pdf(&self, direction: Vec3, guide: f32) -> MixturePdf {
        let bsdf = self.technique_pdf(direction);
        MixturePdf {
            mixture: self.a * guide + (1.0 - self.a) * bsdf,
            bsdf,
            guide,
        }
    }

    /// Draws a direction: from the guide with probability `a`, else from the BSDF (or phase
    /// function). `None` when the BSDF draw fails (leaves the hemisphere).
    pub fn sample(&self, rng: &mut Rng) -> Option<DirectionSample> {
        let choice = rng.next_f32();
        let lobe = rng.next_f32();
        let u = rng.next_vec2();
        let (direction, guide_pdf) = match &self.guide {
            Some(guide) if choice < self.a => guide.sample(u),
            _ => match self.scatterer {
                Scatterer::Surface {
                    material,
                    frame,
                    wo,
                } => {
                    let s = material.sample(wo, lobe, u)?;
                    (frame.to_world(s.wi), None)
                }
                Scatterer::Medium { travel, g, .. } => {
                    (sample_henyey_greenstein(travel, g, u), None)
                }
            },
        };
        let pdf = match guide_pdf {
            Some(guide) => self.mixture_pdf(direction, guide),
            None => self.pdf(direction),
        };
        (pdf.mixture > 0.0).then_some(DirectionSample { direction, pdf })
    }
}
