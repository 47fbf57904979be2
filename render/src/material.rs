//! Materials: a Lambertian base plus an optional rough (GGX) specular layer, and an emission;
//! or a smooth dielectric (glass), which reflects and refracts in one direction each.
//!
//! Everything is in the local shading frame, `z` along the normal, both directions pointing away
//! from the surface; `wo` toward the viewer, `wi` toward the light. Opaque surfaces are
//! two-sided (the integrator flips the normal to the viewer's side); a dielectric's shape must
//! be closed with its normals outward, so that a hit knows whether the ray enters or leaves.

use glam::{Vec2, Vec3};
use std::f32::consts::{FRAC_1_PI, PI};

/// A surface's reflectance and emission.
#[derive(Clone, Copy, PartialEq)]
pub struct Material {
    /// Lambertian albedo.
    pub diffuse: Vec3,
    /// Specular reflectance at normal incidence (Schlick's `F0`); zero for none.
    pub specular: Vec3,
    /// GGX roughness `α` (0.05 glossy to 1 very rough).
    pub roughness: f32,
    /// Radiance emitted on the side the shape's normal points to (zero for none).
    pub emission: Vec3,
    /// Index of refraction of a smooth dielectric inside the shape (air outside); zero for an
    /// opaque surface, whose reflectance the fields above give.
    pub ior: f32,
}

impl std::fmt::Debug for Material {
    /// The fields of an opaque surface, and `ior` for a dielectric only: a scene's fingerprint is
    /// its description printed, and an opaque scene's stays what it was before dielectrics.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("Material");
        d.field("diffuse", &self.diffuse)
            .field("specular", &self.specular)
            .field("roughness", &self.roughness)
            .field("emission", &self.emission);
        if self.is_dielectric() {
            d.field("ior", &self.ior);
        }
        d.finish()
    }
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
            ior: 0.0,
        }
    }

    /// Smooth glass of index of refraction `ior` (1.5 for window glass), clear: it reflects
    /// and transmits everything, in the proportions Fresnel's equations give.
    pub fn glass(ior: f32) -> Self {
        Material {
            ior,
            ..Material::diffuse(Vec3::ZERO)
        }
    }

    /// Whether this is a smooth dielectric: its scattering is a delta distribution (two
    /// directions), which [`Material::sample_dielectric`] draws and no other method evaluates.
    pub fn is_dielectric(&self) -> bool {
        self.ior > 0.0
    }

    /// A Lambertian base under a rough specular layer.
    pub fn glossy(diffuse: Vec3, specular: Vec3, roughness: f32) -> Self {
        Material {
            diffuse,
            specular,
            roughness,
            emission: Vec3::ZERO,
            ior: 0.0,
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

    /// The BSDF value `f(wo, wi)` (cosine not included); zero for a dielectric, whose delta
    /// lobes no direction drawn elsewhere hits.
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if wo.z <= 0.0 || wi.z <= 0.0 || self.is_dielectric() {
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
        if wo.z <= 0.0 || wi.z <= 0.0 || self.is_dielectric() {
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
        if wo.z <= 0.0 || self.is_dielectric() {
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

    /// Draws the direction a dielectric scatters `wo` into (`wo.z > 0`; `entering` when `wo`
    /// lies outside the shape): the mirror direction with the Fresnel reflectance `F`, else the
    /// refracted one (Snell's law), with `u` uniform in `[0, 1)`. Chosen in proportion to what
    /// each carries, the path's weight `f·|cos|/pdf` is 1 either way, and the returned
    /// direction is all the caller needs.
    ///
    /// The radiance scaling by `(η_i/η_t)²` on refraction is left out: it cancels on every path
    /// that enters the glass and leaves it again, and the camera, every emitter and every other
    /// surface of the scenes here lie outside it.
    pub fn sample_dielectric(&self, wo: Vec3, entering: bool, u: f32) -> Vec3 {
        let eta = if entering { self.ior } else { 1.0 / self.ior };
        let cos_i = wo.z.clamp(0.0, 1.0);
        match refracted_cosine(cos_i, eta) {
            Some(cos_t) if u >= fresnel_dielectric(cos_i, eta) => {
                Vec3::new(-wo.x / eta, -wo.y / eta, -cos_t)
            }
            _ => Vec3::new(-wo.x, -wo.y, wo.z),
        }
    }
}

/// The cosine of the refracted direction for incidence `cos_i` (`≥ 0`) on an interface of
/// relative index `eta = η_t/η_i`; `None` past the critical angle (total internal reflection).
fn refracted_cosine(cos_i: f32, eta: f32) -> Option<f32> {
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
    (sin2_t < 1.0).then(|| (1.0 - sin2_t).sqrt())
}

/// Fresnel reflectance of a smooth dielectric interface for unpolarized light, incidence
/// `cos_i` (`≥ 0`), relative index `eta = η_t/η_i`: the mean of the two polarizations'
/// reflectances, 1 under total internal reflection.
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    let Some(cos_t) = refracted_cosine(cos_i, eta) else {
        return 1.0;
    };
    let parallel = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let perpendicular = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    0.5 * (parallel * parallel + perpendicular * perpendicular)
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
