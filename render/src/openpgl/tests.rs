//! Tests of the Open PGL wrapper.

use super::*;

/// 20 000 records of light arriving from within about 17° of `axis`, at points spread over
/// the unit cube, inside a medium or not.
fn records_around(axis: Vec3, volume: bool) -> Vec<Record> {
    let (u, v) = axis.any_orthonormal_pair();
    (0..20_000u32)
        .map(|i| {
            let t = i as f32 / 20_000.0;
            let phi = t * 97.0;
            Record {
                position: Vec3::new(t, (t * 7.0).fract(), (t * 13.0).fract()),
                direction: (axis + 0.3 * (u * phi.cos() + v * phi.sin())).normalize(),
                radiance: 1.0,
                pdf: 1.0,
                distance: 1.0,
                outgoing: Vec3::Z,
                reflected: 0.5,
                volume,
            }
        })
        .collect()
}

fn record(radiance: f32, pdf: f32, distance: f32) -> Record {
    Record {
        position: Vec3::splat(0.5),
        direction: Vec3::Z,
        radiance,
        pdf,
        distance,
        outgoing: Vec3::Z,
        reflected: radiance,
        volume: false,
    }
}

#[test]
fn record_keeps_valid_samples_and_drops_what_open_pgl_would_assert_on() {
    let bounds = Aabb::new(Vec3::ZERO, Vec3::ONE);
    let guide = Guide::new(bounds, false, 1).unwrap();
    guide.record(&[
        record(1.0, 0.5, 2.0),
        record(0.0, 0.5, 2.0), // a zero-value sample, kept apart
        record(f32::NAN, 0.5, 2.0),
        record(1.0, 0.0, 2.0),
        record(1.0, -1.0, 2.0),
        record(-1.0, 0.5, 2.0),
        record(1.0, 0.5, f32::INFINITY),
        record(2.0, 0.25, 1.0),
        Record {
            reflected: f32::NAN,
            ..record(1.0, 0.5, 2.0)
        },
        Record {
            outgoing: Vec3::NAN,
            ..record(1.0, 0.5, 2.0)
        },
    ]);
    assert_eq!(guide.pending_samples(), 2);
}

#[test]
fn record_takes_batches_longer_than_a_path() {
    let bounds = Aabb::new(Vec3::ZERO, Vec3::ONE);
    let guide = Guide::new(bounds, false, 1).unwrap();
    let records = records_around(Vec3::Z, false);
    let n = 3 * crate::integrator::MAX_DEPTH + 1;
    guide.record(&records[..n]);
    assert_eq!(guide.pending_samples(), n);
}

#[test]
fn the_radiance_cache_learns_what_each_region_reflects_toward_each_direction() {
    let bounds = Aabb::new(Vec3::ZERO, Vec3::ONE);
    let mut guide = Guide::new(bounds, false, 1).unwrap();
    // Every vertex reflects 0.5 toward +z and nothing toward −z: the histogram of outgoing
    // radiance (a running mean per bin of outgoing directions) gives back each.
    let mut records = records_around(Vec3::Z, false);
    let dark: Vec<Record> = records
        .iter()
        .map(|r| Record {
            radiance: 0.0,
            outgoing: -Vec3::Z,
            reflected: 0.0,
            ..*r
        })
        .collect();
    records.extend(dark);
    for chunk in records.chunks(crate::integrator::MAX_DEPTH) {
        guide.record(chunk);
    }
    guide.update();
    let d = guide.distribution(Vec3::splat(0.5), Vec3::Z, 0.5).unwrap();
    let (up, down) = (d.outgoing_radiance(Vec3::Z), d.outgoing_radiance(-Vec3::Z));
    assert!((up - 0.5).abs() < 1e-4, "toward +z: {up}");
    assert_eq!(down, 0.0, "toward −z");
}

#[test]
fn update_consumes_the_samples_and_gives_distributions_that_integrate_to_one() {
    let bounds = Aabb::new(Vec3::ZERO, Vec3::ONE);
    let mut guide = Guide::new(bounds, false, 1).unwrap();
    // Before the first update there is nothing to sample.
    assert!(guide.distribution(Vec3::splat(0.5), Vec3::Z, 0.5).is_none());
    // Light from around +z, from points spread over the cube.
    let records = records_around(Vec3::Z, false);
    for chunk in records.chunks(crate::integrator::MAX_DEPTH) {
        guide.record(chunk);
    }
    assert_eq!(guide.pending_samples(), records.len());
    guide.update();
    assert_eq!(guide.pending_samples(), 0);
    assert_eq!(guide.iteration(), 1);
    let d = guide.distribution(Vec3::splat(0.5), Vec3::Z, 0.5).unwrap();
    // The mixture of von Mises–Fisher lobes integrates to one, up to the grid's error at its
    // sharpest lobe.
    let integral = integral_over_sphere(&d);
    assert!((integral - 1.0).abs() < 0.02, "integral {integral}");
    // The learned distribution favours the light's direction.
    assert!(d.pdf(Vec3::Z) > 4.0 * d.pdf(-Vec3::Z));
}

/// `∫ pdf dω` over a 256 × 512 equal-area grid (z uniform, φ uniform).
fn integral_over_sphere(d: &Distribution) -> f64 {
    let (nz, nphi) = (256, 512);
    let mut integral = 0.0f64;
    for i in 0..nz {
        for j in 0..nphi {
            let z = -1.0 + 2.0 * (i as f32 + 0.5) / nz as f32;
            let phi = std::f32::consts::TAU * (j as f32 + 0.5) / nphi as f32;
            let r = (1.0 - z * z).max(0.0).sqrt();
            integral += d.pdf(Vec3::new(r * phi.cos(), r * phi.sin(), z)) as f64;
        }
    }
    integral * 4.0 * std::f64::consts::PI / (nz * nphi) as f64
}

#[test]
fn every_directional_distribution_and_leaf_size_trains_to_a_normalized_guide() {
    let bounds = Aabb::new(Vec3::ZERO, Vec3::ONE);
    let records = records_around(Vec3::Z, false);
    for directional in [
        Directional::Vmm,
        Directional::ParallaxAwareVmm,
        Directional::QuadTree,
    ] {
        for max_samples_per_leaf in [2_000, usize::MAX / 4] {
            let arguments = Arguments {
                directional,
                max_samples_per_leaf,
            };
            let mut guide = Guide::with_arguments(bounds, arguments, false, 1).unwrap();
            for chunk in records.chunks(crate::integrator::MAX_DEPTH) {
                guide.record(chunk);
            }
            guide.update();
            let d = guide.distribution(Vec3::splat(0.5), Vec3::Z, 0.5).unwrap();
            let integral = integral_over_sphere(&d);
            let case = format!("{arguments:?}");
            assert!((integral - 1.0).abs() < 0.02, "{case}: integral {integral}");
            assert!(d.pdf(Vec3::Z) > 4.0 * d.pdf(-Vec3::Z), "{case}");
        }
    }
}

#[test]
fn volume_samples_train_the_volume_field_and_its_phase_product() {
    let bounds = Aabb::new(Vec3::ZERO, Vec3::ONE);
    let mut guide = Guide::new(bounds, true, 2).unwrap();
    // Inside a medium, light from around −x.
    let records = records_around(-Vec3::X, true);
    for chunk in records.chunks(crate::integrator::MAX_DEPTH) {
        guide.record(chunk);
    }
    guide.update();
    let x = Vec3::splat(0.5);
    let volume = guide.volume_distribution(x, Vec3::Y, 0.0, 0.5).unwrap();
    assert!(volume.pdf(-Vec3::X) > 10.0 * volume.pdf(Vec3::X));
    // With a forward-scattering phase function along +y, the product leans toward it.
    let product = guide.volume_distribution(x, Vec3::Y, 0.8, 0.5).unwrap();
    let lean = Vec3::new(-1.0, 1.0, 0.0).normalize();
    assert!(product.pdf(lean) / product.pdf(-Vec3::X) > volume.pdf(lean) / volume.pdf(-Vec3::X));
    for k in 0..32 {
        let u = Vec2::new((k as f32 + 0.5) / 32.0, 0.37);
        let d = product.sample(u);
        assert!(product.pdf(d) > 0.0);
    }
}
