//! The product with a surface's clamped cosine (`DirectionalDistribution::at_surface`) on a
//! trained field, through the public API: it keeps almost nothing below the horizon, its
//! estimates stay unbiased, and bad normals get the documented answer. (That it integrates to
//! 1 and samples what its pdf says, cell by cell, is tested beside the descent.)

mod common;

use common::trained;
use glam::Vec3;
use sdguide::LeafRule;
use sdguide_lab::rng::Rng;

fn normals() -> Vec<Vec3> {
    let mut rng = Rng::new(23);
    let mut out = vec![
        Vec3::Z,
        -Vec3::Z,
        Vec3::X,
        Vec3::new(0.0, 1.0, 1.0).normalize(),
    ];
    while out.len() < 8 {
        let v = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - Vec3::ONE;
        if let Some(n) = v.try_normalize() {
            out.push(n);
        }
    }
    out
}

#[test]
fn little_mass_is_left_below_the_horizon() {
    // The documented shares: on average over cells and normals below 0.1%, and below 5% even
    // where the guide's light lies just under the horizon; each with a 5-sigma binomial
    // margin on the count.
    let field = trained(LeafRule::L2, 20, 4, 100_000);
    let mut rng = Rng::new(41);
    let samples = 50_000u32;
    let (mut below, mut plain_below, mut total) = (0u64, 0u64, 0u64);
    for cell in field.cells() {
        let plain = cell.distribution();
        for n in normals() {
            let surface = plain.at_surface(n);
            let mut here = 0u32;
            for _ in 0..samples {
                let u = rng.next_vec2();
                let (d, _) = surface.sample(u);
                here += u32::from(d.dot(n) < 0.0);
                plain_below += u64::from(plain.sample(u).0.dot(n) < 0.0);
            }
            let sigma = (0.05 * 0.95 / f64::from(samples)).sqrt();
            let share = f64::from(here) / f64::from(samples);
            assert!(share < 0.05 + 5.0 * sigma, "n = {n}: {share}");
            below += u64::from(here);
            total += u64::from(samples);
        }
    }
    let share = below as f64 / total as f64;
    let sigma = (0.001 * 0.999 / total as f64).sqrt();
    assert!(share < 0.001 + 5.0 * sigma, "{share}");
    // The plain guide, on the same numbers, sends a large share below (so the cut is real).
    assert!(
        plain_below as f64 > 0.3 * total as f64,
        "{plain_below} of {total}"
    );
}

#[test]
fn estimates_of_the_cosine_integral_are_unbiased() {
    // ∫ max(0, n·ω) dω = π. A product with zero density where the cosine is positive would
    // bias the estimate low; one that is wrong about its own density would bias it anywhere.
    let field = trained(LeafRule::L2, 20, 4, 100_000);
    let mut rng = Rng::new(43);
    let k = 200_000;
    for cell in field.cells().take(8) {
        for n in normals() {
            let dist = cell.distribution().at_surface(n);
            let (mut sum, mut sum2) = (0.0f64, 0.0f64);
            for _ in 0..k {
                let (d, pdf) = dist.sample(rng.next_vec2());
                let f = f64::from(d.dot(n).max(0.0)) / f64::from(pdf);
                sum += f;
                sum2 += f * f;
            }
            let mean = sum / f64::from(k);
            let sigma = ((sum2 / f64::from(k) - mean * mean) / f64::from(k)).sqrt();
            let pi = std::f64::consts::PI;
            assert!(
                (mean - pi).abs() < 5.0 * sigma + 1e-6,
                "n = {n}: {mean} ± {sigma}"
            );
        }
    }
}

#[test]
fn bad_normals_get_the_documented_answer() {
    let field = trained(LeafRule::L2, 20, 3, 50_000);
    let plain = field.cells().next().unwrap().distribution();
    let mut rng = Rng::new(47);
    for bad in [
        Vec3::ZERO,
        Vec3::NAN,
        Vec3::new(f32::INFINITY, 0.0, 0.0),
        Vec3::new(0.0, f32::NEG_INFINITY, 1.0),
    ] {
        let surface = plain.at_surface(bad);
        assert_eq!(surface.normal(), None, "{bad}");
        for _ in 0..1000 {
            let u = rng.next_vec2();
            assert_eq!(surface.sample(u), plain.sample(u), "{bad}");
            let d = plain.sample(u).0;
            assert_eq!(surface.pdf(d), plain.pdf(d), "{bad}");
        }
    }
    // Unnormalized normals, tiny or huge, are normalized: the product is the one with the
    // unit normal.
    let n = Vec3::new(0.2, -0.4, 0.9).normalize();
    let unit = plain.at_surface(n);
    for scale in [1e-30, 3.0, 1e30] {
        let scaled = plain.at_surface(n * scale);
        let m = scaled.normal().unwrap();
        assert!((m - n).length() < 1e-6, "{scale}: {m}");
        let same = plain.at_surface(m);
        for _ in 0..1000 {
            let u = rng.next_vec2();
            let (d, pdf) = scaled.sample(u);
            assert_eq!((d, pdf), same.sample(u));
            assert_eq!(pdf, scaled.pdf(d));
        }
    }
    assert_eq!(unit.guide_probability(), plain.guide_probability());
    // Degenerate directions have density 0, as the plain distribution's.
    assert_eq!(unit.pdf(Vec3::ZERO), 0.0);
    assert_eq!(unit.pdf(Vec3::NAN), 0.0);
}

/// A field trained on the standard workload whose samples carry their surfaces' normals (or
/// not, with `normals` false), otherwise on the same numbers.
fn trained_with_normals(normals: bool) -> sdguide::GuidingField {
    let mut field = sdguide::GuidingField::new(
        sdguide_lab::synthetic::room_bounds(),
        sdguide::GuidingConfig::default(),
    )
    .unwrap();
    let workload = sdguide_lab::synthetic::Workload {
        light: sdguide_lab::synthetic::LightField::standard(),
        lobe_noise: 1.0,
        seed: 13,
        bsdf: None,
    };
    let mut rng = Rng::new(59);
    for k in 0..4 {
        let batch: Vec<_> = (0..(20_000u32 << k))
            .map(|_| {
                let s = workload.draw(&field, &mut rng);
                sdguide::Sample {
                    normal: s.normal.filter(|_| normals),
                    ..s
                }
            })
            .collect();
        field.record_all(&batch);
        field.refine();
    }
    field
}

#[test]
fn recorded_normals_get_stored_products_of_the_same_distribution() {
    // The room's floor and walls have one normal each: every cell that sees one of them in
    // most of its samples stores its product, and that product is the per-query one (the
    // field trained without normals, on the same samples, has the same guide).
    let with = trained_with_normals(true);
    let without = trained_with_normals(false);
    let stats = with.stats();
    assert!(
        stats.surface_products >= stats.spatial_leaves / 2,
        "{} products in {} cells",
        stats.surface_products,
        stats.spatial_leaves
    );
    assert_eq!(without.stats().surface_products, 0);
    assert!(stats.bytes > without.stats().bytes);
    let mut rng = Rng::new(61);
    for _ in 0..20_000 {
        let (x, n) =
            sdguide_lab::synthetic::room_vertex([rng.next_f32(), rng.next_f32(), rng.next_f32()]);
        let (a, b) = (
            with.distribution(x).at_surface(n),
            without.distribution(x).at_surface(n),
        );
        let (d, pdf) = a.sample(rng.next_vec2());
        assert!(pdf > 0.0, "{pdf}");
        assert_eq!(pdf.to_bits(), a.pdf(d).to_bits());
        for d in [d, sdguide::sphere::square_to_direction(rng.next_vec2())] {
            let (p, q) = (a.pdf(d), b.pdf(d));
            assert!(
                (f64::from(p) - f64::from(q)).abs() <= 1e-4 * f64::from(q) + 1e-30,
                "x = {x}, n = {n}, d = {d}: {p} vs {q}"
            );
        }
    }
}

#[test]
fn bad_recorded_normals_are_ignored() {
    // A sample whose normal is zero or not finite is recorded as one without a normal.
    let field = trained(LeafRule::L2, 20, 1, 10_000);
    let before = field.stats();
    let good = sdguide::Sample {
        position: Vec3::splat(0.5),
        direction: Vec3::Z,
        value: 1.0,
        pdf: 0.5,
        ..sdguide::Sample::default()
    };
    for bad in [Vec3::ZERO, Vec3::NAN, Vec3::new(0.0, f32::INFINITY, 1.0)] {
        let s = sdguide::Sample {
            normal: Some(bad),
            ..good
        };
        assert_eq!(field.try_record(&s), Ok(()), "{bad}");
    }
    let after = field.stats();
    assert_eq!(after.samples_recorded, before.samples_recorded + 3);
    assert_eq!(after.rejected.total(), before.rejected.total());
}

#[test]
fn a_normal_with_either_sign_of_zero_is_one_normal_and_its_cache_loads() {
    // A renderer that flips a normal to face the viewer hands the floor's normal as (0, 1, 0)
    // and as (−0, 1, −0): different bits, one normal. It takes one slot and one product, and
    // the saved field loads (a loader comparing normals with `==`, where 0.0 == −0.0, would
    // call two such slots duplicates and refuse the file).
    let bounds = sdguide::Aabb::new(Vec3::ZERO, Vec3::ONE);
    let mut field = sdguide::GuidingField::new(bounds, sdguide::GuidingConfig::default()).unwrap();
    let mut rng = Rng::new(3);
    let floor = [Vec3::Y, Vec3::new(-0.0, 1.0, -0.0)];
    let samples: Vec<_> = (0..4000)
        .map(|i| sdguide::Sample {
            position: Vec3::new(rng.next_f32(), 0.0, rng.next_f32()),
            direction: sdguide::sphere::square_to_direction(rng.next_vec2()),
            value: 1.0,
            pdf: 0.25,
            normal: Some(floor[i % 2]),
            ..sdguide::Sample::default()
        })
        .collect();
    field.record_all(&samples);
    field.refine();
    assert_eq!(field.stats().surface_products, 1);
    let loaded = sdguide::GuidingField::from_bytes(&field.to_bytes()).expect("the cache loads");
    assert_eq!(loaded.stats(), field.stats());
    // Both signs find the stored product, the same distribution.
    let x = Vec3::new(0.5, 0.0, 0.5);
    let d = Vec3::new(0.3, 0.8, -0.2);
    let [a, b] = floor.map(|n| loaded.distribution(x).at_surface(n).pdf(d));
    assert_eq!(a, b);
    assert!(a > 0.0);
}
