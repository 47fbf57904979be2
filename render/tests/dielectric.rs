//! The smooth dielectric: Fresnel's reflectance, Snell's law, total internal reflection, the
//! choice between the two lobes in proportion to what each carries, and a furnace with a glass
//! sphere in it that converges to the radiance it had without one (energy is conserved through
//! the glass, guided or not).

use glam::Vec3;
use sdguide::{GuidingConfig, GuidingField};
use sdguide_render::image::Image;
use sdguide_render::integrator::{Guide, Guiding};
use sdguide_render::material::{Material, fresnel_dielectric};
use sdguide_render::render::{field_bounds, render_pass, training_pass};
use sdguide_render::rng::Rng;
use sdguide_render::scene::Scene;
use sdguide_render::scenes::glass_furnace;

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

const ALBEDO: f32 = 0.3;
const EMISSION: f32 = 1.0;
const SIZE: (usize, usize) = (40, 30);
const SPP: u32 = 32;

/// The pixel mean and its standard error (pixels are independent estimates).
fn mean_and_error(image: &Image) -> (f64, f64) {
    let values: Vec<f64> = image
        .pixels
        .iter()
        .map(|p| (p.x as f64 + p.y as f64 + p.z as f64) / 3.0)
        .collect();
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

fn render_in(scene: &Scene, field: Option<&GuidingField>) -> Image {
    let mut sum = Image::new(SIZE.0, SIZE.1);
    let guiding = field.map(|field| Guiding {
        field: Guide::Sdguide(field),
        record: false,
        guide_probability: None,
    });
    render_pass(scene, guiding, &mut sum, SPP, 11, 0);
    sum.pixels.iter_mut().for_each(|p| *p /= SPP as f32);
    sum
}

/// Converges to `emission / (1 − albedo)`. Paths are cut after 10 scattering events, glass
/// ones included: a path that reaches the cut has met at least `10 − 2k` diffuse walls for `k`
/// crossings of the sphere, and the part lost is far below the statistical error.
fn assert_converges(image: &Image, what: &str) {
    let expected = (EMISSION / (1.0 - ALBEDO)) as f64;
    let (mean, error) = mean_and_error(image);
    assert!(
        error > 0.0 && error < 0.01 * expected,
        "{what}: error {error}"
    );
    assert!(
        (mean - expected).abs() < 4.0 * error,
        "{what}: mean {mean} vs {expected} (standard error {error})"
    );
}

#[test]
fn a_glass_sphere_leaves_the_furnace_radiance_as_it_was() {
    for next_event in [true, false] {
        let mut scene = glass_furnace(ALBEDO, EMISSION);
        scene.next_event = next_event;
        assert_converges(
            &render_in(&scene, None),
            &format!("unguided, NEE {next_event}"),
        );
        let config = GuidingConfig {
            spatial_threshold: 1000.0,
            ..GuidingConfig::default()
        };
        let mut field = GuidingField::new(field_bounds(&scene), config).unwrap();
        for pass in 0..5 {
            training_pass(&scene, &mut field, SIZE, 1 << pass, 3, pass, None);
        }
        let stats = field.stats();
        assert_eq!(stats.rejected.total(), 0, "{stats:?}");
        assert!(stats.spatial_leaves > 1, "{stats:?}");
        assert_converges(
            &render_in(&scene, Some(&field)),
            &format!("guided, NEE {next_event}"),
        );
    }
}

/// The camera sees the sphere: a sizeable share of the pixels' paths go through glass, so the
/// furnace test above tests it.
#[test]
fn the_glass_furnace_camera_sees_the_sphere() {
    let scene = glass_furnace(ALBEDO, EMISSION);
    let aspect = SIZE.0 as f32 / SIZE.1 as f32;
    let mut through = 0;
    for j in 0..SIZE.1 {
        for i in 0..SIZE.0 {
            let film = glam::Vec2::new(
                (i as f32 + 0.5) / SIZE.0 as f32,
                (j as f32 + 0.5) / SIZE.1 as f32,
            );
            let hit = scene.intersect(&scene.camera.ray(film, aspect)).unwrap();
            through += usize::from(scene.material(&hit).is_dielectric());
        }
    }
    let share = through as f64 / (SIZE.0 * SIZE.1) as f64;
    assert!(share > 0.1 && share < 0.9, "{share}");
}
