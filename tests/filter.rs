//! Filters spread a sample by exact overlap shares, keep its whole weight, count it once, and
//! stay deterministic.

use glam::{Vec2, Vec3};
use sdguide::sphere::square_to_direction;
use sdguide::{
    Aabb, DirectionalFilter, GuidingConfig, GuidingField, Moments, Sample, SpatialFilter,
};
use sdguide_lab::rng::Rng;
use sdguide_lab::synthetic::{LightField, Workload};

fn unit_box() -> Aabb {
    Aabb::new(Vec3::ZERO, Vec3::ONE)
}

fn config(spatial: SpatialFilter, directional: DirectionalFilter) -> GuidingConfig {
    GuidingConfig {
        spatial_filter: spatial,
        directional_filter: directional,
        ..GuidingConfig::default()
    }
}

/// Every recorded leaf of every spatial cell: `(cell index, leaf, moments)`.
fn recorded(field: &GuidingField) -> Vec<(usize, sdguide::DirectionalCell, Moments)> {
    field
        .cells()
        .enumerate()
        .flat_map(|(i, c)| c.recorded().into_iter().map(move |(l, m)| (i, l, m)))
        .collect()
}

/// A field over the unit cube whose root split once, at x = 0.5 (3 samples > c = 2; the halves,
/// 1 and 2, do not split again), with the initial four directional quadrants in each half.
fn split_once(spatial: SpatialFilter, directional: DirectionalFilter) -> GuidingField {
    let mut field = GuidingField::new(
        unit_box(),
        GuidingConfig {
            spatial_threshold: 2.0,
            ..config(spatial, directional)
        },
    )
    .unwrap();
    for x in [0.2, 0.4, 0.8] {
        field.record(&Sample {
            position: Vec3::new(x, 0.5, 0.5),
            direction: Vec3::Z,
            value: 0.0,
            pdf: 1.0,
            ..Sample::default()
        });
    }
    field.refine();
    assert_eq!(field.stats().spatial_leaves, 2);
    field
}

#[test]
fn every_filter_keeps_each_samples_whole_weight_and_counts_it_once() {
    let workload = Workload {
        light: LightField::standard(),
        lobe_noise: 1.0,
        seed: 3,
        bsdf: None,
    };
    for spatial in [
        SpatialFilter::Nearest,
        SpatialFilter::Stochastic,
        SpatialFilter::Box,
    ] {
        for directional in [
            DirectionalFilter::Nearest,
            DirectionalFilter::Box,
            DirectionalFilter::DeferredBox,
        ] {
            let mut field = GuidingField::new(
                sdguide_lab::synthetic::room_bounds(),
                GuidingConfig {
                    spatial_threshold: 200.0,
                    ..config(spatial, directional)
                },
            )
            .unwrap();
            // Two iterations so cells of many sizes exist, then a measured one.
            workload.train(&mut field, 2, 20_000);
            let mut rng = Rng::new(5);
            let samples: Vec<Sample> = (0..20_000)
                .map(|_| workload.draw(&field, &mut rng))
                .collect();
            field.record_all(&samples);
            let expected: f64 = samples
                .iter()
                .map(|s| f64::from(s.value) / f64::from(s.pdf))
                .sum();
            let leaves = recorded(&field);
            let sum: f64 = leaves.iter().map(|(_, _, m)| m.sum).sum();
            let count: u64 = leaves.iter().map(|(_, _, m)| m.count).sum();
            assert_eq!(count, samples.len() as u64, "{spatial:?} {directional:?}");
            // The same terms split into shares and summed in another order: within 1e-9.
            assert!(
                (sum / expected - 1.0).abs() < 1e-9,
                "{spatial:?} {directional:?}: {sum} vs {expected}"
            );
        }
    }
}

/// The recorded `S1` of each of the four initial quadrants of spatial cell `cell`, and which
/// quadrants counted a sample.
fn quadrants(field: &GuidingField, cell: usize) -> ([f64; 4], [u64; 4]) {
    let (mut s, mut n) = ([0.0; 4], [0; 4]);
    for (i, leaf, m) in recorded(field) {
        if i == cell {
            let q = usize::from(leaf.origin.x >= 0.5) | usize::from(leaf.origin.y >= 0.5) << 1;
            s[q] += m.sum;
            n[q] += m.count;
        }
    }
    (s, n)
}

/// Records one sample of weight `v/p` at point `s` of the square into a fresh one-cell field with
/// the directional box filter; returns the quadrants' `S1` and counts.
fn box_recorded(s: Vec2, v: f32, p: f32) -> ([f64; 4], [u64; 4]) {
    let field = GuidingField::new(
        unit_box(),
        config(SpatialFilter::Nearest, DirectionalFilter::Box),
    )
    .unwrap();
    field.record(&Sample {
        position: Vec3::splat(0.5),
        direction: square_to_direction(s),
        value: v,
        pdf: p,
        ..Sample::default()
    });
    quadrants(&field, 0)
}

#[test]
fn directional_box_shares_follow_the_overlap_folded_at_the_border() {
    let close = |s: [f64; 4], expected: [f64; 4]| {
        for q in 0..4 {
            assert!(
                (s[q] - expected[q]).abs() < 1e-5,
                "q{q}: {s:?} vs {expected:?}"
            );
        }
    };
    // The leaf holding (0.3, 0.55) is the quadrant [0, 0.5) × [0.5, 1); the half-size square
    // around the point covers x ∈ [0.05, 0.55), y ∈ [0.3, 0.8). Shares: x 0.9 | 0.1,
    // y 0.4 | 0.6; v/p = 4.
    let (s, n) = box_recorded(Vec2::new(0.3, 0.55), 2.0, 0.5);
    close(
        s,
        [0.9 * 0.4, 0.1 * 0.4, 0.9 * 0.6, 0.1 * 0.6].map(|f| 4.0 * f),
    );
    assert_eq!(n, [0, 0, 1, 0]);
    // The square's border folds onto itself at each side's midpoint (see `sphere`): around
    // (0.3, 0.95) the square is [0.05, 0.55) × [0.7, 1.2). Inside, [0.7, 1) × x 0.45 | 0.05
    // (areas 0.135 | 0.015); the part past the top, [1, 1.2), folds to y ∈ [0.8, 1) with x
    // mirrored to [0.45, 0.95): x 0.05 | 0.45 (areas 0.01 | 0.09). Of 0.25: 0.58 | 0.42.
    let (s, _) = box_recorded(Vec2::new(0.3, 0.95), 2.0, 0.5);
    close(s, [0.0, 0.0, 4.0 * 0.58, 4.0 * 0.42]);
    // Past the left side: around (0.1, 0.4), [−0.15, 0.35) × [0.15, 0.65). Inside,
    // x ∈ [0, 0.35) with y 0.35 | 0.15 (areas 0.1225 | 0.0525); past the side, x ∈ [0, 0.15)
    // with y mirrored to [0.35, 0.85): 0.15 | 0.35 (0.0225 | 0.0525). Of 0.25: 0.58 | 0.42.
    let (s, _) = box_recorded(Vec2::new(0.1, 0.4), 1.0, 1.0);
    close(s, [0.58, 0.0, 0.42, 0.0]);
    // Past a corner (−z, where all four corners meet): around (0.95, 0.95), [0.7, 1.2)². Inside
    // 0.3 × 0.3 in q3; past the right side 0.2 × 0.3 folded to x ∈ [0.8, 1), y ∈ [0, 0.3) (q1);
    // past the top the same in q2; past the corner 0.2 × 0.2 at [0, 0.2)² (q0).
    let (s, _) = box_recorded(Vec2::new(0.95, 0.95), 1.0, 1.0);
    close(s, [0.04, 0.06, 0.06, 0.09].map(|a| a / 0.25));
}

#[test]
fn spatial_box_shares_follow_the_overlapped_volume() {
    let field = split_once(SpatialFilter::Box, DirectionalFilter::Nearest);
    // The point's leaf is x ∈ [0.5, 1]; a box as large around x = 0.6 spans [0.35, 0.85]:
    // 0.15 of its 0.5 in the left leaf, 0.35 in the right one (y and z are the whole cube).
    field.record(&Sample {
        position: Vec3::new(0.6, 0.5, 0.5),
        direction: Vec3::Z,
        value: 1.0,
        pdf: 1.0,
        ..Sample::default()
    });
    let per_cell: Vec<(f64, u64)> = field
        .cells()
        .map(|c| {
            let r = c.recorded();
            (
                r.iter().map(|(_, m)| m.sum).sum(),
                r.iter().map(|(_, m)| m.count).sum(),
            )
        })
        .collect();
    let left = field.cells().position(|c| c.bounds.max.x <= 0.5).unwrap();
    let right = 1 - left;
    assert!((per_cell[left].0 - 0.3).abs() < 1e-6, "{per_cell:?}");
    assert!((per_cell[right].0 - 0.7).abs() < 1e-6, "{per_cell:?}");
    assert_eq!((per_cell[left].1, per_cell[right].1), (0, 1));
}

#[test]
fn stochastic_filter_moves_by_the_callers_jitter_or_a_deterministic_hash() {
    let field = split_once(SpatialFilter::Stochastic, DirectionalFilter::Nearest);
    let left = field.cells().position(|c| c.bounds.max.x <= 0.5).unwrap();
    let counts = |f: &GuidingField| -> Vec<u64> {
        f.cells()
            .map(|c| c.recorded().iter().map(|(_, m)| m.count).sum())
            .collect()
    };
    // x = 0.55 in the right leaf (extent 0.5 in x): jitter 0 moves it by −0.25, into the left.
    let s = Sample {
        position: Vec3::new(0.55, 0.5, 0.5),
        direction: Vec3::Z,
        value: 1.0,
        pdf: 1.0,
        ..Sample::default()
    };
    field.record(&s.with_jitter(Vec3::new(0.0, 0.5, 0.5)));
    assert_eq!(counts(&field)[left], 1);
    field.record(&s.with_jitter(Vec3::new(0.5, 0.5, 0.5)));
    assert_eq!(counts(&field)[1 - left], 1);
    // Without a jitter, the same samples land in the same cells every time.
    let a = split_once(SpatialFilter::Stochastic, DirectionalFilter::Nearest);
    let b = split_once(SpatialFilter::Stochastic, DirectionalFilter::Nearest);
    let mut rng = Rng::new(9);
    for _ in 0..1000 {
        let x = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        let s = Sample {
            position: x,
            direction: square_to_direction(rng.next_vec2()),
            value: 1.0,
            pdf: 1.0,
            ..Sample::default()
        };
        a.record(&s);
        b.record(&s);
    }
    assert_eq!(counts(&a), counts(&b));
    // Jittering uniform points by their leaf's extent keeps them uniform (clamped at the
    // cube's faces): each half holds 500 of 1000 within 5σ (σ = sqrt(1000/4) ≈ 15.8).
    assert!(counts(&a)[left].abs_diff(500) < 79, "{:?}", counts(&a));
}

#[test]
fn directional_box_gives_a_finer_neighbourhood_its_share_in_one_leaf() {
    // Light only in [0.75, 1) × [0, 0.5) (so that no square spills into other quadrants), and
    // no shrinkage: after one refine the quadrant [0.5, 1) × [0, 0.5) is subdivided, the dark
    // quadrant [0, 0.5)² stays one leaf.
    let mut field = GuidingField::new(
        unit_box(),
        GuidingConfig {
            prior_samples: 0.0,
            ..config(SpatialFilter::Nearest, DirectionalFilter::Box)
        },
    )
    .unwrap();
    let mut rng = Rng::new(2);
    for _ in 0..4000 {
        let s = Vec2::new(0.75 + 0.25 * rng.next_f32(), 0.5 * rng.next_f32());
        field.record(&Sample {
            position: Vec3::splat(0.5),
            direction: square_to_direction(s),
            value: 1.0,
            pdf: 1.0,
            ..Sample::default()
        });
    }
    field.refine();
    // A sample at (0.45, 0.2) in the dark quadrant: the square [0.2, 0.7) × [−0.05, 0.45)
    // lies 0.135 in its own leaf and 0.09 in the subdivided quadrant, which takes it in the leaf
    // that holds the overlap's centre (0.6, 0.225). The part past the bottom folds to
    // [0.3, 0.8) × [0, 0.05): 0.01 in its own leaf, 0.015 in the leaf holding (0.65, 0.025) — the
    // same dark leaf [0.5, 0.75) × [0, 0.25). Of 0.25: 58% and 42%.
    let d = square_to_direction(Vec2::new(0.45, 0.2));
    field.record(&Sample {
        position: Vec3::splat(0.5),
        direction: d,
        value: 1.0,
        pdf: 1.0,
        ..Sample::default()
    });
    let cell = field.cells().next().unwrap();
    let contains = |l: &sdguide::DirectionalCell, x, y| l.contains(Vec2::new(x, y));
    let mut found = 0;
    for (leaf, m) in cell.recorded() {
        if m.sum == 0.0 {
            continue;
        }
        found += 1;
        if contains(&leaf, 0.45, 0.2) {
            assert_eq!(leaf.size, 0.5, "the dark quadrant is one leaf");
            assert!(
                (m.sum - 0.58).abs() < 1e-6 && m.count == 1,
                "{leaf:?} {m:?}"
            );
        } else {
            assert!(leaf.size < 0.5 && contains(&leaf, 0.6, 0.225), "{leaf:?}");
            assert!(contains(&leaf, 0.65, 0.025), "{leaf:?}");
            assert!(
                (m.sum - 0.42).abs() < 1e-6 && m.count == 0,
                "{leaf:?} {m:?}"
            );
        }
    }
    assert_eq!(found, 2);
}

#[test]
fn deferred_box_spreads_each_quadrant_as_the_box_filter_spreads_a_sample_at_its_centre() {
    // On the first iteration's four leaves (side ½) the quadrant centres are the points
    // ((2i + 1)/8, (2j + 1)/8). Both filters spread a sample there over the same ½-sided
    // square, the box filter at once and the deferred one from the quadrant's sums, so the
    // recorded moments agree but for the order of the additions and the direction's round
    // trip through the sphere (a few 1e-7 of the square: shares move by 1e-6 of the square's
    // side at most), and so do the next distributions.
    let fields = [DirectionalFilter::Box, DirectionalFilter::DeferredBox]
        .map(|d| GuidingField::new(unit_box(), config(SpatialFilter::Nearest, d)).unwrap());
    let mut rng = Rng::new(12);
    // 20000 samples: a leaf's quadrants hold enough (> 512) to predict a split.
    for _ in 0..20_000 {
        let [i, j] = [0, 1].map(|_| (rng.next_f32() * 4.0).min(3.0) as u32);
        let s = Vec2::new((2 * i + 1) as f32, (2 * j + 1) as f32) / 8.0;
        // One quadrant far brighter than the others, so that its leaf splits.
        let bright = if (i, j) == (3, 1) { 30.0 } else { 1.0 };
        let (v, p) = (bright * (0.1 + rng.next_f32()), 0.5 + rng.next_f32());
        let sample = Sample {
            position: Vec3::splat(0.5),
            direction: square_to_direction(s),
            value: v,
            pdf: p,
            ..Sample::default()
        };
        for f in &fields {
            f.record(&sample);
        }
    }
    let (boxed, deferred) = (recorded(&fields[0]), recorded(&fields[1]));
    assert_eq!(boxed.len(), 4);
    for ((_, lb, mb), (_, ld, md)) in boxed.iter().zip(&deferred) {
        assert_eq!((lb, mb.count), (ld, md.count));
        assert!((md.sum / mb.sum - 1.0).abs() < 1e-5, "{mb:?} {md:?}");
        assert!((md.sum_sq / mb.sum_sq - 1.0).abs() < 1e-5, "{mb:?} {md:?}");
    }
    let [mut a, mut b] = fields;
    a.refine();
    b.refine();
    let (la, lb) = (
        a.cells().next().unwrap().distribution().leaves(),
        b.cells().next().unwrap().distribution().leaves(),
    );
    assert_eq!(la.len(), lb.len());
    for ((ca, pa), (cb, pb)) in la.iter().zip(&lb) {
        assert_eq!(ca, cb);
        assert!((pa / pb - 1.0).abs() < 1e-5, "{pa} {pb}");
    }
    // The next recording topologies are the same, split where the light is bright.
    let topology = |f: &GuidingField| -> Vec<_> {
        let cell = f.cells().next().unwrap();
        cell.recorded().into_iter().map(|(l, _)| l).collect()
    };
    assert_eq!(topology(&a), topology(&b));
    assert!(topology(&a).len() > 4, "{:?}", topology(&a));
}

#[test]
fn the_second_moment_replaces_the_squared_value_and_leaves_the_mean() {
    // Nearest filters: the one leaf the sample lands in holds exactly its weights.
    let field = GuidingField::new(
        unit_box(),
        config(SpatialFilter::Nearest, DirectionalFilter::Nearest),
    )
    .unwrap();
    let base = Sample {
        position: Vec3::splat(0.5),
        direction: Vec3::Z,
        value: 2.0,
        pdf: 0.5,
        ..Sample::default()
    };
    let moments = |s: Sample| {
        let f = field.clone();
        f.record(&s);
        let r = recorded(&f);
        let m: Vec<_> = r.iter().filter(|(_, _, m)| m.count > 0).collect();
        assert_eq!(m.len(), 1);
        (m[0].2.sum, m[0].2.sum_sq)
    };
    assert_eq!(moments(base), (4.0, 8.0));
    // A roulette-free estimate of the square of 1.5 instead of 4: Σ v²/p becomes 3.
    let with = Sample {
        second_moment: Some(1.5),
        ..base
    };
    assert_eq!(moments(with), (4.0, 3.0));
    // With a zero value nothing is recorded, whatever the second moment says.
    assert_eq!(moments(Sample { value: 0.0, ..with }), (0.0, 0.0));
}

/// A single-cell field with `directional` and `filter_samples`, no shrinkage, after one refine
/// of: 4000 samples of value 1 spread evenly over the square, and 1000 of value 100 at the
/// point (0.3, 0.3) of the square — a bright point source in the first of the four initial
/// quadrants, whose leaf-sized box reaches 10% into each neighbour per axis.
fn point_source(directional: DirectionalFilter, filter_samples: Option<f32>) -> GuidingField {
    let field = GuidingField::new(
        unit_box(),
        GuidingConfig {
            spatial_threshold: 1e9,
            prior_samples: 0.0,
            filter_samples,
            ..config(SpatialFilter::Nearest, directional)
        },
    )
    .unwrap();
    let sample = |s: Vec2, value: f32| Sample {
        position: Vec3::splat(0.5),
        direction: square_to_direction(s),
        value,
        pdf: 1.0 / (4.0 * std::f32::consts::PI),
        ..Sample::default()
    };
    for i in 0..4000 {
        let s = Vec2::new(
            ((i % 64) as f32 + 0.5) / 64.0,
            ((i / 64) as f32 + 0.5) / 62.5,
        );
        field.record(&sample(s, 1.0));
    }
    for _ in 0..1000 {
        field.record(&sample(Vec2::new(0.3, 0.3), 100.0));
    }
    field
}

#[test]
fn the_l2_masses_blend_a_leafs_own_second_moment_with_the_filtered_one_by_its_count() {
    // Own second moments are what the nearest filter records; filtered ones the box filter's.
    let own = recorded(&point_source(DirectionalFilter::Nearest, None));
    let filtered = recorded(&point_source(DirectionalFilter::Box, None));
    assert_eq!(own.len(), 4);
    // The box hands each neighbour of the source's leaf 9% of its second moment, the far one 1%.
    assert!(filtered[1].2.sum_sq > 50.0 * own[1].2.sum_sq);
    let eps = f64::from(GuidingConfig::default().uniform_fraction);
    for n_f in [None, Some(0.0f32), Some(128.0), Some(1e6)] {
        let mut field = point_source(DirectionalFilter::Box, n_f);
        field.refine();
        let learned = field.distribution(Vec3::splat(0.5)).leaves();
        // mass_i = sqrt(|C_i|·S2_i), S2_i = w·own + (1 − w)·filtered, w = n/(n + n_f).
        let mass: Vec<f64> = own
            .iter()
            .zip(&filtered)
            .map(|((_, cell, o), (_, _, f))| {
                let n = o.count as f64;
                let w = n_f.map_or(0.0, |n_f| n / (n + f64::from(n_f)));
                (cell.area() * (w * o.sum_sq + (1.0 - w) * f.sum_sq)).sqrt()
            })
            .collect();
        let total: f64 = mass.iter().sum();
        for ((cell, p), ((_, own_cell, _), m)) in learned.iter().zip(own.iter().zip(&mass)) {
            assert_eq!(cell, own_cell);
            let expected = (1.0 - eps) * m / total + eps * cell.area();
            assert!(
                (f64::from(*p) - expected).abs() < 1e-5 * expected,
                "n_f {n_f:?}, {cell:?}: {p} vs {expected}"
            );
        }
    }
}
