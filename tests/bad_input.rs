//! Bad input is rejected and counted, never a panic, never a NaN in the field.

mod common;

use common::cell_integrals;
use glam::{Vec2, Vec3};
use sdguide::{Aabb, GuidingConfig, GuidingField, Rejections, Sample};
use sdguide_lab::synthetic::{LightField, Workload};

const NAN: f32 = f32::NAN;
const INF: f32 = f32::INFINITY;

fn field() -> GuidingField {
    GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), GuidingConfig::default()).unwrap()
}

#[test]
fn every_bad_sample_is_rejected_and_counted_by_reason() {
    let mut field = field();
    let p = Vec3::splat(0.5);
    let ok = Sample {
        position: p,
        direction: Vec3::Z,
        value: 1.0,
        pdf: 1.0,
        ..Sample::default()
    };
    let bad = [
        // (sample, which counter)
        (
            Sample {
                position: Vec3::new(NAN, 0.5, 0.5),
                ..ok
            },
            "position",
        ),
        (
            Sample {
                position: Vec3::new(0.5, INF, 0.5),
                ..ok
            },
            "position",
        ),
        (
            Sample {
                position: Vec3::new(0.5, 0.5, 1.5),
                ..ok
            },
            "bounds",
        ),
        (
            Sample {
                position: Vec3::new(-0.01, 0.5, 0.5),
                ..ok
            },
            "bounds",
        ),
        (
            Sample {
                direction: Vec3::ZERO,
                ..ok
            },
            "direction",
        ),
        (
            Sample {
                direction: Vec3::new(NAN, 0.0, 1.0),
                ..ok
            },
            "direction",
        ),
        (
            Sample {
                direction: Vec3::new(INF, 0.0, 1.0),
                ..ok
            },
            "direction",
        ),
        (Sample { value: NAN, ..ok }, "value"),
        (Sample { value: INF, ..ok }, "value"),
        (Sample { value: -1.0, ..ok }, "value"),
        (Sample { pdf: 0.0, ..ok }, "pdf"),
        (Sample { pdf: -0.0, ..ok }, "pdf"),
        (Sample { pdf: -2.0, ..ok }, "pdf"),
        (Sample { pdf: NAN, ..ok }, "pdf"),
        (Sample { pdf: INF, ..ok }, "pdf"),
        // Mixture terms are checked like the value and the pdf.
        (ok.with_mixture(NAN, 1.0, 1.0), "value"),
        (ok.with_mixture(-1.0, 1.0, 1.0), "value"),
        (ok.with_mixture(1.0, -1.0, 1.0), "pdf"),
        (ok.with_mixture(1.0, 1.0, INF), "pdf"),
        // So is the second moment.
        (
            Sample {
                second_moment: Some(NAN),
                ..ok
            },
            "value",
        ),
        (
            Sample {
                second_moment: Some(-1.0),
                ..ok
            },
            "value",
        ),
        (
            Sample {
                second_moment: Some(INF),
                ..ok
            },
            "value",
        ),
    ];
    let mut expected = Rejections::default();
    for (s, reason) in bad {
        field.record(&s);
        match reason {
            "position" => expected.non_finite_position += 1,
            "bounds" => expected.out_of_bounds += 1,
            "direction" => expected.bad_direction += 1,
            "value" => expected.bad_value += 1,
            _ => expected.bad_pdf += 1,
        }
    }
    // Extreme but valid samples are accepted: a subnormal pdf, a huge value, a point just
    // outside the bounds (within the tolerance), an unnormalized direction.
    let good = [
        Sample {
            value: f32::MAX,
            pdf: f32::from_bits(1),
            ..ok
        },
        Sample { value: 0.0, ..ok },
        Sample {
            position: Vec3::new(1.0005, 0.5, 0.5),
            ..ok
        },
        Sample {
            direction: Vec3::new(0.0, 3.0, 4.0),
            ..ok
        },
        Sample {
            direction: Vec3::splat(f32::MAX),
            ..ok
        },
        Sample {
            direction: Vec3::new(0.0, 1e-30, -1e-30),
            ..ok
        },
        // Mixture terms at their extremes: a zero BSDF pdf, huge values, a subnormal mixture pdf.
        ok.with_mixture(1.0, 0.0, 1.0),
        Sample {
            value: f32::MAX,
            pdf: f32::from_bits(1),
            ..ok
        }
        .with_mixture(f32::MAX, f32::MAX, 0.0),
        // A second moment at its extremes: zero, huge beside a tiny value, any beside a zero
        // value.
        Sample {
            second_moment: Some(0.0),
            ..ok
        },
        Sample {
            value: f32::from_bits(1),
            pdf: f32::from_bits(1),
            second_moment: Some(f32::MAX),
            ..ok
        },
        Sample {
            value: 0.0,
            second_moment: Some(5.0),
            ..ok
        },
    ];
    field.record_all(&good);
    let stats = field.stats();
    assert_eq!(stats.rejected, expected);
    assert_eq!(stats.samples_recorded, good.len() as u64);
    field.refine();
    // The field stays a valid distribution: finite, positive, integrating to 1; the guide
    // probability stays in its bounds.
    let dist = field.distribution(p);
    let a = dist.guide_probability();
    assert!((0.05..=0.95).contains(&a), "{a}");
    for (_, m) in dist.leaves() {
        assert!(m.is_finite() && m > 0.0);
    }
    let integral: f64 = cell_integrals(&dist, 8).iter().sum();
    assert!((integral - 1.0).abs() < 1e-5, "{integral}");
}

#[test]
fn queries_with_bad_arguments_stay_valid() {
    let mut field = field();
    Workload {
        light: LightField::standard(),
        lobe_noise: 1.0,
        seed: 1,
        bsdf: None,
    }
    .train(&mut field, 2, 20_000);
    for x in [
        Vec3::splat(NAN),
        Vec3::new(INF, -INF, 0.5),
        Vec3::splat(-100.0),
        Vec3::splat(1e30),
    ] {
        let dist = field.distribution(x);
        for u in [
            Vec2::splat(NAN),
            Vec2::new(-1.0, 2.0),
            Vec2::ONE,
            Vec2::new(INF, -INF),
        ] {
            let (d, pdf) = dist.sample(u);
            assert!(d.is_finite() && (d.length() - 1.0).abs() < 1e-5);
            assert!(pdf > 0.0 && pdf.is_finite());
            assert_eq!(pdf, dist.pdf(d));
        }
        for d in [Vec3::ZERO, Vec3::splat(NAN), Vec3::new(INF, 0.0, 0.0)] {
            assert_eq!(dist.pdf(d), 0.0);
        }
    }
}

#[test]
fn any_jitter_is_recorded_into_a_valid_cell() {
    // The stochastic filter's numbers are clamped (NaN and infinities included): every sample
    // lands somewhere and is counted once.
    let config = GuidingConfig {
        spatial_filter: sdguide::SpatialFilter::Stochastic,
        ..GuidingConfig::default()
    };
    let field = GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), config).unwrap();
    let s = Sample {
        position: Vec3::splat(0.5),
        direction: Vec3::Z,
        value: 1.0,
        pdf: 1.0,
        ..Sample::default()
    };
    let jitters = [
        Vec3::splat(NAN),
        Vec3::splat(INF),
        Vec3::splat(-INF),
        Vec3::new(2.0, -3.0, 0.5),
        Vec3::splat(f32::MAX),
    ];
    for j in jitters {
        assert!(field.try_record(&s.with_jitter(j)).is_ok());
    }
    assert_eq!(field.stats().samples_recorded, jitters.len() as u64);
}

#[test]
fn absurd_configs_and_bounds_are_typed_errors() {
    let ok = GuidingConfig::default();
    let cases: [(GuidingConfig, &str); 20] = [
        (
            GuidingConfig {
                spatial_threshold: NAN,
                ..ok.clone()
            },
            "spatial_threshold",
        ),
        (
            GuidingConfig {
                spatial_threshold: 0.5,
                ..ok.clone()
            },
            "spatial_threshold",
        ),
        (
            GuidingConfig {
                subdivision_threshold: 0.0,
                ..ok.clone()
            },
            "subdivision_threshold",
        ),
        (
            GuidingConfig {
                subdivision_threshold: NAN,
                ..ok.clone()
            },
            "subdivision_threshold",
        ),
        (
            GuidingConfig {
                max_directional_depth: 0,
                ..ok.clone()
            },
            "max_directional_depth",
        ),
        (
            GuidingConfig {
                max_directional_depth: 21,
                ..ok.clone()
            },
            "max_directional_depth",
        ),
        (
            GuidingConfig {
                uniform_fraction: 0.0,
                ..ok.clone()
            },
            "uniform_fraction",
        ),
        (
            GuidingConfig {
                uniform_fraction: 1.5,
                ..ok.clone()
            },
            "uniform_fraction",
        ),
        (
            GuidingConfig {
                uniform_fraction: 1e-10,
                ..ok.clone()
            },
            "uniform_fraction",
        ),
        (
            GuidingConfig {
                max_directional_nodes: 0,
                ..ok.clone()
            },
            "max_directional_nodes",
        ),
        (
            GuidingConfig {
                max_spatial_nodes: 0,
                ..ok.clone()
            },
            "max_spatial_nodes",
        ),
        (
            GuidingConfig {
                max_memory_bytes: 10,
                ..ok.clone()
            },
            "max_memory_bytes",
        ),
        (
            GuidingConfig {
                prior_samples: NAN,
                ..ok.clone()
            },
            "prior_samples",
        ),
        (
            GuidingConfig {
                prior_samples: -1.0,
                ..ok.clone()
            },
            "prior_samples",
        ),
        (
            GuidingConfig {
                max_guide_probability: 0.4,
                ..ok.clone()
            },
            "max_guide_probability",
        ),
        (
            GuidingConfig {
                max_guide_probability: 1.0,
                ..ok.clone()
            },
            "max_guide_probability",
        ),
        (
            GuidingConfig {
                max_guide_probability: NAN,
                ..ok.clone()
            },
            "max_guide_probability",
        ),
        (
            GuidingConfig {
                guide_cost: Some(-0.1),
                ..ok.clone()
            },
            "guide_cost",
        ),
        (
            GuidingConfig {
                guide_cost: Some(101.0),
                ..ok.clone()
            },
            "guide_cost",
        ),
        (
            GuidingConfig {
                guide_cost: Some(NAN),
                ..ok.clone()
            },
            "guide_cost",
        ),
    ];
    // The ends of the guide cost's range, and no cost at all, are accepted.
    for guide_cost in [None, Some(0.0), Some(100.0)] {
        let config = GuidingConfig {
            guide_cost,
            ..ok.clone()
        };
        assert!(GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), config).is_ok());
    }
    let bounds = Aabb::new(Vec3::ZERO, Vec3::ONE);
    for (config, field) in cases {
        let err = GuidingField::new(bounds, config).unwrap_err();
        assert_eq!(err.field, field);
        assert!(err.to_string().contains(field));
    }
    for bad in [
        Aabb::new(Vec3::ONE, Vec3::ZERO),
        Aabb::new(Vec3::ZERO, Vec3::ZERO),
        Aabb::new(Vec3::ZERO, Vec3::new(1.0, NAN, 1.0)),
        Aabb::new(Vec3::splat(-INF), Vec3::ONE),
        Aabb::new(Vec3::splat(-3e38), Vec3::splat(3e38)),
        // A subnormal extent: its cube's side rounds to zero.
        Aabb::new(Vec3::ZERO, Vec3::new(f32::from_bits(1), 0.0, 0.0)),
        Aabb::new(Vec3::ZERO, Vec3::splat(1e-39)),
        // A normal extent too small for the fixed-point scale (2^24 / side overflows).
        Aabb::new(Vec3::ZERO, Vec3::new(4.0 * f32::MIN_POSITIVE, 0.0, 0.0)),
        // A box far below the float spacing where it lies.
        Aabb::new(Vec3::splat(1e7), Vec3::new(1e7, 1e7 + 1.0, 1e7)),
    ] {
        assert_eq!(
            GuidingField::new(bad, ok.clone()).unwrap_err().field,
            "bounds"
        );
    }
    // A flat box (a single wall) is fine: the field covers its bounding cube.
    assert!(GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::new(1.0, 1.0, 0.0)), ok).is_ok());
}

/// Every point of accepted bounds is inside the field, whatever the rounding of its bounding
/// cube: boxes whose centre ± half side rounds inward, tiny normal extents, boxes far from the
/// origin. A sample at each of the eight corners is recorded, none refused as out of bounds.
#[test]
fn every_corner_of_accepted_bounds_is_recorded() {
    let boxes = [
        Aabb::new(Vec3::ZERO, Vec3::ONE),
        Aabb::new(Vec3::ZERO, Vec3::new(1e-30, 0.0, 0.0)),
        // Centre ± half side rounds to the centre: the cube must be widened to the box.
        Aabb::new(Vec3::splat(1e7), Vec3::splat(1e7 + 1.0)),
        Aabb::new(Vec3::splat(1e-30), Vec3::splat(3e-30)),
        Aabb::new(
            Vec3::splat(1.0),
            Vec3::new(1.0 + 3.0 * f32::EPSILON, 1.0, 1.0),
        ),
        Aabb::new(Vec3::splat(1e7), Vec3::new(1e7 + 3.0, 1e7 + 1.0, 1e7)),
        Aabb::new(Vec3::new(-1e30, 0.0, 7.0), Vec3::new(1e30, 1.0, 7.5)),
        Aabb::new(Vec3::splat(0.1), Vec3::splat(0.1 + 1e-6)),
    ];
    for bounds in boxes {
        let field = GuidingField::new(bounds, GuidingConfig::default())
            .unwrap_or_else(|e| panic!("{bounds:?}: {e}"));
        for corner in 0..8 {
            let pick = |bit: u32, lo: f32, hi: f32| if corner >> bit & 1 == 0 { lo } else { hi };
            let p = Vec3::new(
                pick(0, bounds.min.x, bounds.max.x),
                pick(1, bounds.min.y, bounds.max.y),
                pick(2, bounds.min.z, bounds.max.z),
            );
            assert!(
                field
                    .try_record(&Sample {
                        position: p,
                        direction: Vec3::Z,
                        value: 1.0,
                        pdf: 1.0,
                        ..Sample::default()
                    })
                    .is_ok(),
                "{bounds:?}: corner {p} refused"
            );
        }
        assert_eq!(field.stats().rejected.total(), 0);
    }
}

#[test]
fn config_round_trips_through_serde_and_fills_missing_fields() {
    let config = GuidingConfig {
        rule: sdguide::LeafRule::L1,
        spatial_threshold: 4000.0,
        ..GuidingConfig::default()
    };
    let json = serde_json::to_string(&config).unwrap();
    assert_eq!(
        serde_json::from_str::<GuidingConfig>(&json).unwrap(),
        config
    );
    let partial: GuidingConfig = serde_json::from_str(r#"{"rule":"L1"}"#).unwrap();
    assert_eq!(partial.rule, sdguide::LeafRule::L1);
    assert_eq!(
        partial.spatial_threshold,
        GuidingConfig::default().spatial_threshold
    );
    assert!(serde_json::from_str::<GuidingConfig>(r#"{"rho":0.5}"#).is_err());
}

#[test]
fn the_smallest_uniform_fraction_leaves_no_drawn_direction_at_zero_density() {
    // All light from one direction, refined seven levels deep around it, with the smallest
    // uniform share: the cells away from the light hold about ε·4⁻ᵈ of the mass, and
    // draws at the edges of `[0,1)²` (where rounding picks the last quadrant of a node) must
    // still get a positive density that `pdf` agrees with.
    let config = GuidingConfig {
        uniform_fraction: sdguide::MIN_UNIFORM_FRACTION,
        refinement: sdguide::Refinement::FluxShare,
        directional_filter: sdguide::DirectionalFilter::Nearest,
        spatial_threshold: 1e9,
        ..GuidingConfig::default()
    };
    let mut field = GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), config).unwrap();
    let (x, light) = (Vec3::splat(0.5), Vec3::new(0.3, -0.5, 0.81).normalize());
    for _ in 0..16 {
        for _ in 0..2000 {
            field.record(&Sample {
                position: x,
                direction: light,
                value: 1.0,
                pdf: 1.0,
                ..Sample::default()
            });
        }
        field.refine();
    }
    assert!(field.stats().directional_depth >= 7, "{:?}", field.stats());
    let edge = [0.0, 1e-7, 0.5, 1.0 - f32::EPSILON / 2.0, 1.0, 9.0];
    let dist = field.distribution(x);
    for &ux in &edge {
        for &uy in &edge {
            let (d, pdf) = dist.sample(Vec2::new(ux, uy));
            assert!(pdf > 0.0 && pdf.is_finite(), "u = ({ux}, {uy}): pdf {pdf}");
            assert_eq!(pdf.to_bits(), dist.pdf(d).to_bits(), "u = ({ux}, {uy})");
        }
    }
}

#[test]
fn weights_at_the_ends_of_the_exact_sums_range_are_counted_and_keep_the_field_valid() {
    // The sums are fixed point (2^-40 to 2^86, a term clamped at 2^48): tiny weights (1e-30,
    // subnormals) add nothing, huge ones (1e30, a subnormal pdf) are clamped and counted, and
    // many clamped samples into one cell keep it finite.
    let p = Vec3::splat(0.3);
    let at = |d: Vec3, value: f32, pdf: f32| Sample {
        position: p,
        direction: d,
        value,
        pdf,
        normal: Some(Vec3::Z),
        ..Sample::default()
    };
    let tiny = f32::from_bits(1);
    let mut field = field();
    let huge = [
        at(Vec3::Z, 1e30, 1.0),
        at(Vec3::Z, 1.0, tiny),
        at(Vec3::X, f32::MAX, 1e-30),
        at(Vec3::Y, 1e20, 1.0).with_mixture(1e20, 1.0, 1.0),
    ];
    let small = [
        at(Vec3::Z, 1e-30, 1.0),
        at(Vec3::X, tiny, 1.0),
        at(Vec3::Y, tiny, f32::MAX),
    ];
    field.record_all(&huge);
    field.record_all(&small);
    // Many samples at the largest weight into one cell: 2^20 of 2^48 each, 2^68 in all.
    let many = vec![at(-Vec3::Z, 1e30, 1.0); 1 << 20];
    field.record_all(&many);
    let continuation = sdguide::Continuation {
        position: p,
        value: f32::MAX,
        cost: 1.0,
    };
    field.record_continuation(&continuation);
    let stats = field.stats();
    assert_eq!(stats.rejected.total(), 0);
    assert_eq!(stats.clamped_samples, 4 + (1 << 20) + 1);
    field.refine();
    assert_eq!(field.stats().clamped_samples, 4 + (1 << 20) + 1);
    // The learned guide is a density: finite, positive, integrating to 1.
    let dist = field.distribution(p);
    for (_, m) in dist.leaves() {
        assert!(m.is_finite() && m > 0.0);
    }
    let integral: f64 = cell_integrals(&dist, 8).iter().sum();
    assert!((integral - 1.0).abs() < 1e-5, "{integral}");
    for u in [Vec2::ZERO, Vec2::splat(0.5), Vec2::splat(0.999)] {
        let (d, pdf) = dist.sample(u);
        assert!(d.is_finite() && pdf.is_finite() && pdf > 0.0);
        assert_eq!(pdf.to_bits(), dist.pdf(d).to_bits());
    }
    // It saves, loads and merges as it is.
    let loaded = GuidingField::from_bytes(&field.to_bytes()).unwrap();
    assert_eq!(loaded.stats(), field.stats());
}
