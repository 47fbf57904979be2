//! The pdf the integrator uses — in the estimator and in MIS — must be the density of the
//! directions it draws. For any region B of the sphere, `E[1{ω ∈ B} / q(ω)] = |B|` exactly when
//! `q` is that density (and positive on B); the test checks it on 200 equal-area regions and on
//! at vertices of a trained field, with a 5σ bound from the sample variance.

mod common;

use common::trained_door;
use glam::Vec3;
use sdguide_render::backend::Backend;
use sdguide_render::geometry::Frame;
use sdguide_render::material::Material;
use sdguide_render::rng::Rng;
use sdguide_render::sampler::VertexSampler;
use std::f64::consts::PI;

const Z_BINS: usize = 10;
const PHI_BINS: usize = 20;

fn bin(d: Vec3) -> usize {
    let z = (((d.z + 1.0) * 0.5 * Z_BINS as f32) as usize).min(Z_BINS - 1);
    let phi = d.y.atan2(d.x).rem_euclid(std::f32::consts::TAU);
    let p = ((phi / std::f32::consts::TAU * PHI_BINS as f32) as usize).min(PHI_BINS - 1);
    z * PHI_BINS + p
}

/// Draws `n` directions and checks `E[1_B/q] = |B|` on every bin wholly above the surface of
/// normal `normal` (bins are taken in a frame whose +z is the normal). Below it both the BSDF
/// and the surface-aware guide draw (almost) nothing: the integrand is zero there. Bins the
/// mixture reaches only through the guide's uniform floor get few samples, so `n` is large
/// enough for the 5σ bound's variance estimate to hold there too.
fn check_sampler<B: Backend>(sampler: &VertexSampler<'_, B>, normal: Vec3, n: usize, seed: u64) {
    let frame = Frame::new(normal);
    let bins = Z_BINS * PHI_BINS;
    let (mut sum, mut sum2) = (vec![0f64; bins], vec![0f64; bins]);
    let mut rng = Rng::new(seed);
    let mut drawn = 0;
    for _ in 0..n {
        let Some(s) = sampler.sample(&mut rng) else {
            continue;
        };
        drawn += 1;
        // What is sampled is what the pdf says, recomputed independently of the draw.
        assert_eq!(s.pdf, sampler.pdf(s.direction));
        let w = 1.0 / s.pdf.mixture as f64;
        let b = bin(frame.to_local(s.direction));
        sum[b] += w;
        sum2[b] += w * w;
    }
    assert!(drawn > n / 2);
    let area = 4.0 * PI / bins as f64;
    let nf = n as f64;
    for b in 0..bins {
        let mean = sum[b] / nf;
        let se = ((sum2[b] / nf - mean * mean).max(0.0) / nf).sqrt();
        let z0 = -1.0 + 2.0 * (b / PHI_BINS) as f64 / Z_BINS as f64;
        if z0 < 0.0 {
            continue;
        }
        assert!(
            (mean - area).abs() < 5.0 * se + 1e-3 * area,
            "bin {b}: E[1/q] = {mean} ± {se}, area {area}"
        );
    }
}

#[test]
fn bsdf_sampling_pdf_matches_its_draws() {
    for material in [
        Material::diffuse(Vec3::splat(0.5)),
        Material::glossy(Vec3::splat(0.3), Vec3::splat(0.4), 0.1),
        Material::glossy(Vec3::ZERO, Vec3::splat(0.9), 0.3),
    ] {
        let wo = Vec3::new(0.6, 0.0, 0.8);
        let sampler = VertexSampler::new(Vec3::ZERO, Vec3::Z, wo, &material, None);
        check_sampler(&sampler, Vec3::Z, 1_000_000, 5);
    }
}

#[test]
fn guided_mixture_pdf_matches_its_draws() {
    let (_, field) = trained_door();
    let floor = Material::glossy(Vec3::splat(0.3), Vec3::splat(0.35), 0.12);
    let wall = Material::diffuse(Vec3::splat(0.7));
    // A point on the camera room's floor and one on its back wall; the guide is mixed in with
    // its learned probability, or ½ where the field turned it off (the mixture's pdf is what
    // is tested), so every bin above the surface is reachable by both.
    for (position, normal, material) in [
        (Vec3::new(3.0, 0.0, 2.5), Vec3::Y, &floor),
        (Vec3::new(0.0, 1.2, 2.5), Vec3::X, &wall),
    ] {
        let a = field.distribution(position).guide_probability();
        assert!((0.0..1.0).contains(&a));
        let a = if a > 0.0 { a } else { 0.5 };
        let wo = (Vec3::new(0.4, 1.5, 0.4) - position).normalize();
        let sampler = VertexSampler::new(position, normal, wo, material, Some(&field))
            .with_guide_probability(a);
        check_sampler(&sampler, normal, 4_000_000, 9);
    }
}

/// The same identity for the peer's mixture: Open PGL's distribution (with and without its
/// cosine product) mixed with the BSDF at probability ½, at the same two points of `door`.
#[cfg(feature = "openpgl")]
#[test]
fn open_pgl_mixture_pdf_matches_its_draws() {
    use sdguide_render::method::field_bounds;
    use sdguide_render::openpgl;
    use sdguide_render::render::training_pass;
    use sdguide_render::scenes::door;
    let scene = door();
    let floor = Material::glossy(Vec3::splat(0.3), Vec3::splat(0.35), 0.12);
    let wall = Material::diffuse(Vec3::splat(0.7));
    for cosine_product in [false, true] {
        let mut guide = openpgl::Guide::new(field_bounds(&scene), cosine_product, 2).unwrap();
        for pass in 0..4 {
            training_pass(&scene, &mut guide, (48, 36), 2 << pass, 11, pass, None);
        }
        for (position, normal, material) in [
            (Vec3::new(3.0, 0.0, 2.5), Vec3::Y, &floor),
            (Vec3::new(0.0, 1.2, 2.5), Vec3::X, &wall),
        ] {
            let wo = (Vec3::new(0.4, 1.5, 0.4) - position).normalize();
            let guide = Some(&guide);
            let sampler = VertexSampler::with_guide(position, normal, wo, material, guide, 0.37);
            check_sampler(&sampler, normal, 4_000_000, 9);
        }
    }
}
