//! Materials: a Lambertian base plus an optional rough (GGX) specular layer, and an emission.
//!
//! Everything is in the local shading frame, `z` along the normal, both directions pointing away
//! from the surface; `wo` toward the viewer, `wi` toward the light. Surfaces are two-sided (the
//! integrator flips the normal to the viewer's side).

use glam::{Vec2, Vec3};
use std::f32::consts::{FRAC_1_PI, PI};

/// A surface's reflectance and emission.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// Lambertian albedo.
    pub diffuse: Vec3,
    /// Specular reflectance at normal incidence (Schlick's `F0`); zero for none.
    pub specular: Vec3,
    /// GGX roughness `α` (0.05 glossy to 1 very rough).
    pub roughness: f32,
    /// Radiance emitted on the side the shape's normal points to (zero for none).
    pub emission: Vec3,
}

/// A direction drawn from a BSDF: the local direction and the full pdf of drawing it.
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    /// Local incident direction.
    pub wi: Vec3,
    /// Solid-angle pdf of `wi` under the material's whole sampling strategy.
    pub pdf: f32,
}

/// Luminance of a linear Rec. 709 colour.
pub fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

impl Material {
    /// A Lambertian surface.
    pub fn diffuse(albedo: Vec3) -> Self {
        Material {
            diffuse: albedo,
            specular: Vec3::ZERO,
            roughness: 1.0,
            emission: Vec3::ZERO,
        }
    }

    /// A Lambertian base under a rough specular layer.
    pub fn glossy(diffuse: Vec3, specular: Vec3, roughness: f32) -> Self {
        Material {
            diffuse,
            specular,
            roughness,
            emission: Vec3::ZERO,
        }
    }

    /// The same material, emitting `radiance`.
    pub fn emitting(self, radiance: Vec3) -> Self {
        Material {
            emission: radiance,
            ..self
        }
    }

    /// Probability of sampling the specular lobe rather than the diffuse one.
    pub fn specular_probability(&self) -> f32 {
        let (d, s) = (luminance(self.diffuse), luminance(self.specular));
        if s <= 0.0 {
            0.0
        } else if d <= 0.0 {
            1.0
        } else {
            s / (s + d)
        }
    }

    /// The BSDF value `f(wo, wi)` (cosine not included).
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return Vec3::ZERO;
        }
        let mut f = self.diffuse * FRAC_1_PI;
        if self.specular != Vec3::ZERO {
            let h = (wo + wi).normalize();
            let a2 = self.roughness * self.roughness;
            let fresnel =
                self.specular + (Vec3::ONE - self.specular) * (1.0 - wi.dot(h)).max(0.0).powi(5);
            let g = smith_g1(wo.z, a2) * smith_g1(wi.z, a2);
            f += fresnel * (ggx_d(h.z, a2) * g / (4.0 * wo.z * wi.z));
        }
        f
    }

    /// The solid-angle pdf with which [`Material::sample`] draws `wi`.
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return 0.0;
        }
        let ps = self.specular_probability();
        let mut pdf = (1.0 - ps) * wi.z * FRAC_1_PI;
        if ps > 0.0 {
            let h = (wo + wi).normalize();
            let a2 = self.roughness * self.roughness;
            pdf += ps * ggx_d(h.z, a2) * h.z / (4.0 * wo.dot(h));
        }
        pdf
    }

    /// Draws `wi` from the BSDF's sampling strategy (a cosine-weighted hemisphere for the
    /// diffuse lobe, the GGX normal distribution for the specular one), with `u` uniform in
    /// `[0, 1)³`. `None` when the draw leaves the hemisphere.
    pub fn sample(&self, wo: Vec3, lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let wi = if lobe < self.specular_probability() {
            let a2 = self.roughness * self.roughness;
            let cos2 = (1.0 - u.x) / (1.0 + (a2 - 1.0) * u.x);
            let (cos_t, sin_t) = (cos2.sqrt(), (1.0 - cos2).max(0.0).sqrt());
            let phi = 2.0 * PI * u.y;
            let h = Vec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t);
            2.0 * wo.dot(h) * h - wo
        } else {
            let r = u.x.sqrt();
            let phi = 2.0 * PI * u.y;
            Vec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u.x).max(0.0).sqrt())
        };
        let pdf = self.pdf(wo, wi);
        (pdf > 0.0).then_some(BsdfSample { wi, pdf })
    }
}

/// The GGX normal distribution `D(h)` for `cos θ_h` and `α²`.
fn ggx_d(cos_h: f32, a2: f32) -> f32 {
    if cos_h <= 0.0 {
        return 0.0;
    }
    let d = cos_h * cos_h * (a2 - 1.0) + 1.0;
    a2 / (PI * d * d)
}

/// Smith's masking term for GGX.
fn smith_g1(cos: f32, a2: f32) -> f32 {
    2.0 * cos / (cos + (a2 + (1.0 - a2) * cos * cos).sqrt())
}
