//! The smooth dielectric: Fresnel's reflectance, Snell's law, total internal reflection, and the
//! choice between the two lobes in proportion to what each carries. That energy is conserved
//! through it is the glass furnace's test (`furnace.rs`).

use glam::Vec3;
use sdguide_render::material::{Material, fresnel_dielectric};
use sdguide_render::rng::Rng;

const IOR: f32 = 1.5;

/// A unit direction in the upper hemisphere at polar cosine `cos` and azimuth `phi`.
fn upper(cos: f32, phi: f32) -> Vec3 {
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    Vec3::new(sin * phi.cos(), sin * phi.sin(), cos)
}

#[test]
fn fresnel_reflectance_has_its_textbook_values() {
    // Normal incidence: ((η − 1)/(η + 1))², from either side.
    let normal = ((IOR - 1.0) / (IOR + 1.0)).powi(2);
    assert!((fresnel_dielectric(1.0, IOR) - normal).abs() < 1e-6);
    assert!((fresnel_dielectric(1.0, 1.0 / IOR) - normal).abs() < 1e-6);
    // Grazing incidence reflects everything; past the critical angle inside, too.
    assert!(fresnel_dielectric(0.0, IOR) > 0.999);
    let critical_cos = (1.0 - 1.0 / (IOR * IOR)).sqrt();
    assert_eq!(fresnel_dielectric(critical_cos - 1e-3, 1.0 / IOR), 1.0);
    // Brewster's angle (tan θ = η): the parallel polarization is not reflected, so the mean is
    // half the perpendicular one, (cos θ_i − η cos θ_t)² / (cos θ_i + η cos θ_t)² / 2.
    let brewster = IOR.atan();
    let (ci, ct) = (brewster.cos(), brewster.sin());
    let perpendicular = ((ci - IOR * ct) / (ci + IOR * ct)).powi(2);
    assert!((fresnel_dielectric(ci, IOR) - 0.5 * perpendicular).abs() < 1e-5);
    // Reciprocity: the reflectance is the same for light going either way through a pair of
    // directions related by Snell's law.
    for i in 1..20 {
        let cos_i = i as f32 / 20.0;
        let sin_t = (1.0 - cos_i * cos_i).sqrt() / IOR;
        let cos_t = (1.0 - sin_t * sin_t).sqrt();
        let (a, b) = (
            fresnel_dielectric(cos_i, IOR),
            fresnel_dielectric(cos_t, 1.0 / IOR),
        );
        assert!((a - b).abs() < 1e-5, "cos {cos_i}: {a} vs {b}");
    }
}

#[test]
fn refraction_obeys_snell_and_retraces_its_path() {
    let glass = Material::glass(IOR);
    for i in 1..40 {
        let wo = upper(i as f32 / 40.0, 0.3 * i as f32);
        for entering in [true, false] {
            let eta = if entering { IOR } else { 1.0 / IOR };
            // u = 1 − ε picks refraction wherever it exists.
            let wi = glass.sample_dielectric(wo, entering, 1.0 - 1e-7);
            assert!((wi.length() - 1.0).abs() < 1e-5);
            let sin_i = (1.0 - wo.z * wo.z).sqrt();
            if sin_i / eta >= 1.0 {
                // Total internal reflection: the mirror direction.
                assert!(!entering);
                assert!((wi - Vec3::new(-wo.x, -wo.y, wo.z)).length() < 1e-6);
                continue;
            }
            assert!(wi.z < 0.0, "{wo} → {wi}");
            let sin_t = (1.0 - wi.z * wi.z).sqrt();
            assert!(
                (sin_i - eta * sin_t).abs() < 1e-5,
                "{sin_i} vs {eta}·{sin_t}"
            );
            // The same plane of incidence, on the other side of the normal.
            assert!((wo.x * wi.y - wo.y * wi.x).abs() < 1e-5);
            assert!(wo.x * wi.x + wo.y * wi.y <= 0.0);
            // Light coming back along −wi, on the other side, leaves along wo.
            let flipped = Vec3::new(wi.x, wi.y, -wi.z);
            let back = glass.sample_dielectric(flipped, !entering, 1.0 - 1e-7);
            let back = Vec3::new(back.x, back.y, -back.z);
            assert!((back - wo).length() < 1e-4, "{wo} → {wi} → {back}");
        }
    }
}

#[test]
fn the_mirror_lobe_is_drawn_with_the_fresnel_reflectance() {
    let glass = Material::glass(IOR);
    let mut rng = Rng::new(5);
    let n = 200_000;
    for (cos, entering) in [
        (1.0, true),
        (0.3, true),
        (0.1, true),
        (0.9, false),
        (0.8, false),
    ] {
        let wo = upper(cos, 1.0);
        let eta = if entering { IOR } else { 1.0 / IOR };
        let f = fresnel_dielectric(cos, eta) as f64;
        let reflected = (0..n)
            .filter(|_| glass.sample_dielectric(wo, entering, rng.next_f32()).z > 0.0)
            .count();
        // A binomial count: 5σ.
        let sigma = (n as f64 * f * (1.0 - f)).sqrt();
        assert!(
            (reflected as f64 - n as f64 * f).abs() <= 5.0 * sigma + 1.0,
            "cos {cos}, entering {entering}: {reflected} of {n}, F = {f}"
        );
    }
}

#[test]
fn a_dielectric_has_no_lobe_other_methods_could_evaluate() {
    let glass = Material::glass(IOR);
    let (wo, wi) = (upper(0.7, 0.0), upper(0.7, std::f32::consts::PI));
    assert_eq!(glass.eval(wo, wi), Vec3::ZERO);
    assert_eq!(glass.pdf(wo, wi), 0.0);
    assert!(glass.sample(wo, 0.5, glam::Vec2::splat(0.5)).is_none());
    // Its description says what it is; an opaque material's does not change with the field.
    assert!(format!("{glass:?}").contains("ior: 1.5"));
    assert!(!format!("{:?}", Material::diffuse(Vec3::ONE)).contains("ior"));
}
