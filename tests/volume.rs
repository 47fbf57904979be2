//! Volume guides: medium samples learn apart from surface samples in the same spatial leaf,
//! have a guide-vs-phase probability of their own, and travel through caches, merges and the
//! path recorder exactly like the surface guides.

use common::{assemble, parts};
use glam::Vec3;
use sdguide::{
    CacheError, DirectionalFilter, GuidingConfig, GuidingField, MergeError, PathRecorder,
    PathVertex, RejectReason, Sample, SpatialFilter,
};
use sdguide_lab::rng::Rng;
use std::f32::consts::PI;

mod common;

/// Where surface light comes from, and where the light medium vertices see comes from.
const SURFACE_LIGHT: Vec3 = Vec3::Z;
const MEDIUM_LIGHT: Vec3 = Vec3::NEG_X;

fn config(volumes: bool) -> GuidingConfig {
    GuidingConfig {
        spatial_threshold: 1_500.0,
        volumes,
        ..GuidingConfig::default()
    }
}

fn unit_cube() -> sdguide::Aabb {
    sdguide::Aabb::new(Vec3::ZERO, Vec3::ONE)
}

/// The Henyey–Greenstein phase function at `cos = d·ω`.
fn hg(cos: f32, g: f32) -> f32 {
    (1.0 - g * g) / (4.0 * PI * (1.0 + g * g - 2.0 * g * cos).powf(1.5))
}

/// A uniform direction.
fn uniform_direction(rng: &mut Rng) -> Vec3 {
    sdguide::sphere::square_to_direction(rng.next_vec2())
}

/// A sample as a renderer records it: at a medium vertex (`volume`) the light comes from
/// around `MEDIUM_LIGHT`, the direction is drawn from the mixture of the volume guide's
/// product with the phase function and the phase function itself, and the mixture terms are
/// recorded; at a surface vertex the light comes from around `SURFACE_LIGHT` and the
/// direction is drawn uniformly.
fn draw(field: &GuidingField, rng: &mut Rng, volume: bool) -> Sample {
    let x = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
    if !volume {
        let d = uniform_direction(rng);
        let value = 8.0 * d.dot(SURFACE_LIGHT).max(0.0).powi(8) + 0.05 * rng.next_f32();
        return Sample {
            position: x,
            direction: d,
            value,
            pdf: 0.25 / PI,
            normal: Some(Vec3::Z),
            ..Sample::default()
        };
    }
    let travel = uniform_direction(rng);
    let g = 0.6;
    let guide = field.volume_distribution(x).with_phase(travel, g);
    let a = guide.guide_probability();
    // The phase function is drawn here by rejection against its maximum (a test needs no
    // faster sampler): any exact sampler of it serves.
    let d = if rng.next_f32() < a {
        guide.sample(rng.next_vec2()).0
    } else {
        loop {
            let d = uniform_direction(rng);
            if rng.next_f32() * hg(1.0, g) <= hg(travel.dot(d), g) {
                break d;
            }
        }
    };
    let (guide_pdf, phase_pdf) = (guide.pdf(d), hg(travel.dot(d), g));
    let q = a * guide_pdf + (1.0 - a) * phase_pdf;
    let value = 8.0 * d.dot(MEDIUM_LIGHT).max(0.0).powi(8) + 0.05 * rng.next_f32();
    Sample {
        position: x,
        direction: d,
        value,
        pdf: q,
        volume: true,
        ..Sample::default()
    }
    .with_mixture(value * phase_pdf, phase_pdf, guide_pdf)
}

/// An iteration's samples: a third of them at medium vertices.
fn samples(field: &GuidingField, seed: u64, n: usize) -> Vec<Sample> {
    let mut rng = Rng::new(seed);
    (0..n).map(|i| draw(field, &mut rng, i % 3 == 0)).collect()
}

fn trained(config: GuidingConfig, iterations: u64) -> GuidingField {
    let mut field = GuidingField::new(unit_cube(), config).unwrap();
    for it in 0..iterations {
        field.record_all(&samples(&field, it, 12_000 << it));
        field.refine();
    }
    field
}

#[test]
fn surface_and_medium_samples_in_one_leaf_learn_apart() {
    let field = trained(config(true), 4);
    let stats = field.stats();
    assert!(stats.spatial_leaves > 1);
    assert!(stats.volume_directional_nodes > 0);
    let mut rng = Rng::new(9);
    for _ in 0..50 {
        let x = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        let (surface, medium) = (field.distribution(x), field.volume_distribution(x));
        // Each guide favours its own light by far, and the other's direction not at all.
        assert!(
            surface.pdf(SURFACE_LIGHT) > 20.0 * surface.pdf(MEDIUM_LIGHT),
            "{x}"
        );
        assert!(
            medium.pdf(MEDIUM_LIGHT) > 20.0 * medium.pdf(SURFACE_LIGHT),
            "{x}"
        );
    }
    // The counts of the iteration in progress: a third of the samples are medium ones.
    field.record_all(&samples(&field, 99, 3_000));
    let stats = field.stats();
    assert_eq!(stats.samples_recorded, 3_000);
    assert_eq!(stats.volume_samples_recorded, 1_000);
}

#[test]
fn the_guide_versus_phase_probability_is_learned_apart() {
    // Medium samples carry mixture terms, surface samples none: the volume guides' probability
    // moves away from ½ (the light is far narrower than the phase function, so it rises), the
    // surface guides' stays.
    let field = trained(config(true), 4);
    let mut rng = Rng::new(4);
    for _ in 0..20 {
        let x = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        assert_eq!(field.distribution(x).guide_probability(), 0.5);
        let a = field.volume_distribution(x).guide_probability();
        assert!(a > 0.6, "{x}: {a}");
        let phase = field.volume_distribution(x).with_phase(Vec3::X, 0.3);
        assert_eq!(phase.guide_probability(), a);
    }
}

#[test]
fn without_volumes_a_medium_sample_is_rejected_and_medium_queries_get_the_phase_function() {
    let field = GuidingField::new(unit_cube(), config(false)).unwrap();
    let s = Sample {
        position: Vec3::splat(0.5),
        direction: Vec3::Z,
        value: 1.0,
        pdf: 1.0,
        volume: true,
        ..Sample::default()
    };
    assert_eq!(field.try_record(&s), Err(RejectReason::NoVolumeGuide));
    let stats = field.stats();
    assert_eq!(stats.rejected.no_volume_guide, 1);
    assert_eq!(stats.samples_recorded, 0);
    // Through a cache round trip, the count stays.
    let loaded = GuidingField::from_bytes(&field.to_bytes()).unwrap();
    assert_eq!(loaded.stats().rejected.no_volume_guide, 1);
    let medium = field.volume_distribution(Vec3::splat(0.5));
    assert_eq!(medium.guide_probability(), 0.0);
    for d in [Vec3::Z, -Vec3::X, Vec3::new(0.3, 0.4, -0.5)] {
        assert!((medium.pdf(d) - 0.25 / PI).abs() < 1e-6);
    }
}

#[test]
fn a_field_with_volumes_round_trips_bit_for_bit() {
    for filter in [DirectionalFilter::Box, DirectionalFilter::DeferredBox] {
        let field = trained(
            GuidingConfig {
                directional_filter: filter,
                spatial_filter: SpatialFilter::Stochastic,
                ..config(true)
            },
            3,
        );
        // Statistics of an iteration in progress travel too.
        let s = samples(&field, 31, 5_000);
        field.record_all(&s);
        let bytes = field.to_bytes();
        let loaded = GuidingField::from_bytes(&bytes).unwrap();
        assert_eq!(loaded.to_bytes(), bytes, "{filter:?}");
        assert_eq!(loaded.stats(), field.stats());
        let mut rng = Rng::new(3);
        for _ in 0..500 {
            let x = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            let travel = uniform_direction(&mut rng);
            let (a, b) = (
                field.volume_distribution(x).with_phase(travel, 0.8),
                loaded.volume_distribution(x).with_phase(travel, 0.8),
            );
            let u = rng.next_vec2();
            assert_eq!(a.sample(u), b.sample(u));
            assert_eq!(a.guide_probability(), b.guide_probability());
        }
        // And training goes on identically.
        let (mut a, mut b) = (field, loaded);
        a.refine();
        b.refine();
        assert_eq!(a.to_bytes(), b.to_bytes());
    }
}

#[test]
fn every_truncation_and_byte_flip_of_a_volume_cache_is_an_error() {
    let field = trained(
        GuidingConfig {
            spatial_threshold: 4_000.0,
            ..config(true)
        },
        2,
    );
    let bytes = field.to_bytes();
    for len in (0..bytes.len()).step_by(7) {
        assert!(
            matches!(
                GuidingField::from_bytes(&bytes[..len]),
                Err(CacheError::Truncated { .. })
            ),
            "truncated to {len}"
        );
    }
    let mut flipped = bytes.clone();
    for i in 0..bytes.len() {
        flipped[i] ^= 0x10;
        assert!(GuidingField::from_bytes(&flipped).is_err(), "byte {i}");
        flipped[i] ^= 0x10;
    }
    // Forged with valid checksums: the volume guides' trees dropped, or the META's flag
    // cleared while they are there, or an unknown flag, are refused as corrupt.
    let corrupt = |p: &[(u32, u32, Vec<u8>)]| {
        matches!(
            GuidingField::from_bytes(&assemble((3, 2), p)),
            Err(CacheError::Corrupt { .. })
        )
    };
    let without: Vec<_> = parts(&bytes).into_iter().filter(|p| p.0 != 10).collect();
    assert!(corrupt(&without));
    for flags in [0u8, 2, 0xff] {
        let mut p = parts(&bytes);
        p[0].2[216] = flags;
        assert!(corrupt(&p), "flags {flags}");
    }
    // A volume tree whose probabilities do not sum to 1.
    let mut p = parts(&bytes);
    let volume = p.iter_mut().find(|p| p.0 == 10).unwrap();
    volume.2[8..12].copy_from_slice(&2.0f32.to_le_bytes());
    assert!(corrupt(&p));
    // Without the volume guides' optional sections, the file loads: the guides as saved, the
    // selection at ½, no recorded sums.
    let optional: Vec<_> = parts(&bytes)
        .into_iter()
        .filter(|p| !(11..=14).contains(&p.0))
        .collect();
    let loaded = GuidingField::from_bytes(&assemble((3, 2), &optional)).unwrap();
    let x = Vec3::splat(0.4);
    assert_eq!(loaded.volume_distribution(x).guide_probability(), 0.5);
    assert_eq!(
        loaded.volume_distribution(x).pdf(MEDIUM_LIGHT),
        field.volume_distribution(x).pdf(MEDIUM_LIGHT)
    );
}

#[test]
fn merged_workers_give_the_bytes_of_one_field_and_volume_fields_merge_only_with_their_kind() {
    let base = trained(config(true), 2);
    let all = samples(&base, 77, 30_000);
    let one = base.clone();
    one.record_all(&all);
    let shards: Vec<GuidingField> = all
        .chunks(7_000)
        .map(|chunk| {
            let w = base.clone();
            w.record_all(chunk);
            w
        })
        .collect();
    for order in [[0, 1, 2, 3, 4], [4, 2, 0, 3, 1]] {
        let mut merged = shards[order[0]].clone();
        for &k in &order[1..] {
            merged.merge(&shards[k]).unwrap();
        }
        assert_eq!(merged.to_bytes(), one.to_bytes(), "{order:?}");
        merged.refine();
        let mut reference = one.clone();
        reference.refine();
        assert_eq!(merged.to_bytes(), reference.to_bytes(), "{order:?}");
    }
    let mut surface_only = trained(config(false), 2);
    assert!(matches!(
        surface_only.merge(&base),
        Err(MergeError::ConfigDiffers)
    ));
}

#[test]
fn recording_from_many_threads_gives_the_bytes_of_one() {
    use rayon::prelude::*;
    let base = trained(config(true), 2);
    let all = samples(&base, 5, 40_000);
    let one = base.clone();
    one.record_all(&all);
    let many = base.clone();
    let mut shuffled = all.clone();
    let mut rng = Rng::new(1);
    for i in (1..shuffled.len()).rev() {
        shuffled.swap(i, (rng.next_f32() * (i + 1) as f32) as usize % (i + 1));
    }
    shuffled.par_chunks(97).for_each(|c| many.record_all(c));
    assert_eq!(many.to_bytes(), one.to_bytes());
}

#[test]
fn the_path_recorder_records_medium_vertices_into_the_volume_guides() {
    let field = GuidingField::new(unit_cube(), config(true)).unwrap();
    let mut path = PathRecorder::new();
    let camera = path.start();
    let x = Vec3::splat(0.5);
    let v = path.push(
        camera,
        PathVertex::new(x, Vec3::X, Vec3::splat(0.1), 0.2)
            .with_normal(Vec3::Y)
            .with_mixture(0.15, 0.3)
            .in_volume(),
    );
    path.add_radiance(v, Vec3::splat(2.0));
    path.finish();
    let record = path.records().next().unwrap();
    assert!(record.sample.volume);
    assert_eq!(record.sample.normal, None);
    path.record(&field);
    let stats = field.stats();
    assert_eq!(
        (stats.samples_recorded, stats.volume_samples_recorded),
        (1, 1)
    );
}
