//! Leaf masses follow the closed form, and refinement splits, prunes and respects its caps.

use glam::{Vec2, Vec3};
use sdguide::sphere::{INV_SPHERE_AREA, square_to_direction};
use sdguide::{
    Aabb, DirectionalFilter, GuidingConfig, GuidingField, LeafRule, Refinement, Sample,
    SpatialSplit,
};

fn unit_box() -> Aabb {
    Aabb::new(Vec3::ZERO, Vec3::ONE)
}

/// A sample of value 1 from +z at `position`, drawn with pdf 1.
fn unit_sample(position: Vec3) -> Sample {
    Sample {
        position,
        direction: Vec3::Z,
        value: 1.0,
        pdf: 1.0,
        ..Sample::default()
    }
}

/// The centre of quadrant `q` (`q = ix + 2·iy`) of the square, as a direction.
fn quadrant_direction(q: usize) -> Vec3 {
    square_to_direction(Vec2::new(
        0.25 + 0.5 * (q & 1) as f32,
        0.25 + 0.5 * (q >> 1) as f32,
    ))
}

/// Records (quadrant, value, pdf) samples at the centre of the unit box.
fn record(field: &GuidingField, samples: &[(usize, f32, f32)]) {
    for &(q, v, p) in samples {
        field.record(&Sample {
            position: Vec3::splat(0.5),
            direction: quadrant_direction(q),
            value: v,
            pdf: p,
            ..Sample::default()
        });
    }
}

/// The hand-built case: one spatial leaf, the initial four quadrants, known moments.
///   q0: two samples v = 1, p = 1      → S1 = 2,   S2 = 2
///   q1: one sample  v = 2, p = 0.5    → S1 = 4,   S2 = 8
///   q2: one sample  v = 3, p = 2      → S1 = 1.5, S2 = 4.5
///   q3: one sample  v = 0             → S1 = 0,   S2 = 0
const HAND_BUILT: [(usize, f32, f32); 5] = [
    (0, 1.0, 1.0),
    (0, 1.0, 1.0),
    (1, 2.0, 0.5),
    (2, 3.0, 2.0),
    (3, 0.0, 1.0),
];

/// `S1` and `S2` of the hand-built quadrants.
const S1: [f64; 4] = [2.0, 4.0, 1.5, 0.0];
const S2: [f64; 4] = [2.0, 8.0, 4.5, 0.0];

/// Samples per hand-built quadrant.
const N: [f64; 4] = [2.0, 1.0, 1.0, 1.0];

/// One spatial leaf that recorded the hand-built case and refined once, without shrinkage.
fn hand_built(rule: LeafRule) -> GuidingField {
    hand_built_with(rule, 0.0)
}

fn hand_built_with(rule: LeafRule, prior_samples: f32) -> GuidingField {
    let config = GuidingConfig {
        rule,
        spatial_threshold: 1e9,
        prior_samples,
        refinement: Refinement::FluxShare,
        ..GuidingConfig::default()
    };
    let mut field = GuidingField::new(unit_box(), config).unwrap();
    record(&field, &HAND_BUILT);
    field.refine();
    field
}

#[test]
fn leaf_masses_follow_the_closed_form() {
    for rule in [LeafRule::L1, LeafRule::L2] {
        let field = hand_built(rule);
        let eps = f64::from(field.config().uniform_fraction);
        let raw: Vec<f64> = match rule {
            LeafRule::L1 => S1.to_vec(),
            LeafRule::L2 => S2.iter().map(|s| (0.25 * s).sqrt()).collect(),
            _ => unreachable!("a rule this test has no closed form for"),
        };
        assert_quadrant_masses(&field, &raw, eps);
    }
}

/// The four quadrants' probabilities are `(1 − ε)·raw_q/Σ raw + ε/4`, and the pdf inside each is
/// its probability over its solid angle (π for a quarter sphere).
fn assert_quadrant_masses(field: &GuidingField, raw: &[f64], eps: f64) {
    let total: f64 = raw.iter().sum();
    let dist = field.distribution(Vec3::splat(0.5));
    let leaves = dist.leaves();
    assert_eq!(leaves.len(), 4);
    for (cell, p) in leaves {
        let q = usize::from(cell.origin.x > 0.0) | usize::from(cell.origin.y > 0.0) << 1;
        let expected = (1.0 - eps) * raw[q] / total + eps * 0.25;
        assert!(
            (f64::from(p) - expected).abs() < 1e-6,
            "q{q}: {p} vs {expected}"
        );
        let pdf = dist.pdf(quadrant_direction(q));
        assert!((f64::from(pdf) - expected / std::f64::consts::PI).abs() < 1e-6);
    }
}

#[test]
fn sparse_leaves_are_shrunk_toward_their_parent() {
    // With n0 = 2, each quadrant's sums become w·own + (1 − w)·root/4, w = n/(n + n0), where the
    // root's sums pool all quadrants. The dark quadrant q3 (one sample of 0) borrows mass.
    let n0 = 2.0;
    let field = hand_built_with(LeafRule::L2, n0 as f32);
    let eps = f64::from(field.config().uniform_fraction);
    let root: f64 = S2.iter().sum();
    let shrunk: Vec<f64> = (0..4)
        .map(|q| {
            let w = N[q] / (N[q] + n0);
            w * S2[q] + (1.0 - w) * 0.25 * root
        })
        .collect();
    let raw: Vec<f64> = shrunk.iter().map(|s| (0.25 * s).sqrt()).collect();
    assert_quadrant_masses(&field, &raw, eps);
    // Without shrinkage q3 would have the floor only.
    assert!(raw[3] / raw.iter().sum::<f64>() > 0.1);
}

#[test]
fn one_refine_splits_several_levels_and_leaves_dark_cells_whole() {
    let field = hand_built(LeafRule::L2);
    let rho = f64::from(field.config().subdivision_threshold);
    // L2 shares of the four quadrants; a cell of share s splits while s/4^k > ρ.
    let raw = S2.map(|s| (0.25 * s).sqrt());
    let total: f64 = raw.iter().sum();
    let cell = field.cells().next().unwrap();
    for (leaf, _) in cell.recorded() {
        let q = usize::from(leaf.origin.x >= 0.5) | usize::from(leaf.origin.y >= 0.5) << 1;
        let mut depth = 1;
        let mut share = raw[q] / total;
        while share > rho {
            share /= 4.0;
            depth += 1;
        }
        assert_eq!(leaf.depth, depth, "quadrant {q}");
    }
}

/// A field at one point that has learned a small light (see [`record_spot`]) over `iterations`
/// iterations.
fn trained_on_spot(config: GuidingConfig, iterations: u32) -> GuidingField {
    let mut field = GuidingField::new(unit_box(), config).unwrap();
    for _ in 0..iterations {
        record_spot(&field, 200);
        field.refine();
    }
    field
}

/// Records samples on an `n × n` grid of the square (uniformly drawn) at the centre of the box,
/// of value `light(direction)`.
fn record_grid(field: &GuidingField, n: usize, light: impl Fn(Vec3) -> f32) {
    for i in 0..n * n {
        let s = Vec2::new(
            ((i % n) as f32 + 0.5) / n as f32,
            ((i / n) as f32 + 0.5) / n as f32,
        );
        let d = square_to_direction(s);
        field.record(&Sample {
            position: Vec3::splat(0.5),
            direction: d,
            value: light(d),
            pdf: INV_SPHERE_AREA,
            ..Sample::default()
        });
    }
}

/// The direction of the small light: `(1, 2, 2)/3`, inside a quadrant of the square
/// (at about (0.585, 0.70)), away from the map's special points.
fn spot() -> Vec3 {
    Vec3::new(1.0, 2.0, 2.0) / 3.0
}

/// Whether `d` is lit by the small light: within ~8° of [`spot`].
fn in_spot(d: Vec3) -> bool {
    d.dot(spot()) > 0.99
}

/// Uniformly spread samples on a `n × n` grid with light only within ~8° of [`spot`].
fn record_spot(field: &GuidingField, n: usize) {
    record_grid(field, n, |d| if in_spot(d) { 100.0 } else { 0.0 });
}

#[test]
fn refinement_prunes_when_the_light_goes_away() {
    let config = GuidingConfig {
        spatial_threshold: 1e9,
        ..GuidingConfig::default()
    };
    let mut field = trained_on_spot(config, 4);
    let before = field.stats();
    assert!(before.directional_depth >= 5, "{before:?}");
    // Now the light is uniform: one iteration of flat values collapses the tree.
    for i in 0..40_000 {
        let s = Vec2::new((i % 200) as f32 / 200.0, (i / 200) as f32 / 200.0);
        field.record(&Sample {
            position: Vec3::splat(0.5),
            direction: square_to_direction(s),
            value: 1.0,
            pdf: INV_SPHERE_AREA,
            ..Sample::default()
        });
    }
    field.refine();
    // Flat light over the spot-refined partition: every leaf's share is its area, so only cells
    // larger than ρ = 0.01 stay split (4^-3 > 0.01 > 4^-4): leaves at depth 4 at the most.
    let cell = field.cells().next().unwrap();
    let max_depth = cell.recorded().iter().map(|(c, _)| c.depth).max().unwrap();
    assert!(max_depth <= 4, "depth {max_depth}");
    // A refine with no samples keeps the learned distribution as it was.
    let leaves_before = cell.distribution().leaves();
    field.refine();
    assert_eq!(
        field.cells().next().unwrap().distribution().leaves(),
        leaves_before
    );
}

#[test]
fn directional_node_cap_is_respected_and_reported() {
    let config = GuidingConfig {
        spatial_threshold: 1e9,
        max_directional_nodes: 5,
        ..GuidingConfig::default()
    };
    let field = trained_on_spot(config, 3);
    let stats = field.stats();
    assert!(stats.directional_nodes <= 5, "{stats:?}");
    assert!(stats.directional_splits_refused > 0);
    for cell in field.cells() {
        assert!(cell.recorded().len() <= 1 + 3 * 5);
    }
}

#[test]
fn spatial_split_follows_the_sample_count_rule() {
    // 1000 samples at c = 100 in iteration 0 (threshold c·sqrt(2^0) = 100): counts halve at
    // each split, 1000 → 500 → 250 → 125 → 62.5, so four levels: 16 leaves of depth 4.
    let config = GuidingConfig {
        spatial_threshold: 100.0,
        ..GuidingConfig::default()
    };
    let mut field = GuidingField::new(unit_box(), config).unwrap();
    for i in 0..1000 {
        let p = Vec3::new(i as f32 / 1000.0, 0.5, 0.5);
        field.record(&unit_sample(p));
    }
    field.refine();
    let stats = field.stats();
    assert_eq!(
        (stats.spatial_leaves, stats.spatial_depth),
        (16, 4),
        "{stats:?}"
    );
    // In iteration 1 the threshold is 100·sqrt(2): 141 samples in one leaf do not split it.
    let before = stats.spatial_leaves;
    for _ in 0..141 {
        field.record(&unit_sample(Vec3::splat(0.01)));
    }
    field.refine();
    assert_eq!(field.stats().spatial_leaves, before);
    // In iteration 2 the threshold is 100·2 = 200: 201 samples split the leaf.
    for _ in 0..201 {
        field.record(&unit_sample(Vec3::splat(0.01)));
    }
    field.refine();
    assert_eq!(field.stats().spatial_leaves, before + 1);
    // Split children start from copies of their parent's distribution: every leaf answers a
    // valid (positive, finite) pdf.
    let pdfs: Vec<f32> = field
        .cells()
        .map(|c| c.distribution().pdf(Vec3::Z))
        .collect();
    assert!(pdfs.iter().all(|&p| p > 0.0 && p.is_finite()));
}

#[test]
fn spatial_caps_stop_splitting_and_say_so() {
    for config in [
        GuidingConfig {
            spatial_threshold: 1.0,
            max_spatial_nodes: 7,
            ..GuidingConfig::default()
        },
        GuidingConfig {
            spatial_threshold: 1.0,
            max_memory_bytes: 64 * 1024,
            ..GuidingConfig::default()
        },
    ] {
        let budget = config.max_memory_bytes;
        let nodes = config.max_spatial_nodes;
        let mut field = GuidingField::new(unit_box(), config).unwrap();
        for i in 0..100_000 {
            let p = Vec3::new(
                (i % 47) as f32 / 47.0,
                (i % 31) as f32 / 31.0,
                (i % 13) as f32 / 13.0,
            );
            field.record(&unit_sample(p));
        }
        field.refine();
        let stats = field.stats();
        assert!(stats.spatial_splits_refused > 0, "{stats:?}");
        assert!(stats.spatial_nodes <= u64::from(nodes));
        assert!(stats.bytes <= budget, "{stats:?}");
    }
}

#[test]
fn the_memory_budget_bounds_directional_growth_too() {
    // The deferred box filter's leaves are larger (pending sums): the budget holds for both.
    for directional_filter in [DirectionalFilter::Box, DirectionalFilter::DeferredBox] {
        memory_budget_bounds_directional_growth(directional_filter);
    }
}

fn memory_budget_bounds_directional_growth(directional_filter: DirectionalFilter) {
    // An absurd but valid configuration: every cell with any light wants to split, as deep and
    // as wide as allowed. The budget (64 KiB) must still hold.
    let config = GuidingConfig {
        refinement: Refinement::FluxShare,
        subdivision_threshold: 1e-30,
        max_directional_nodes: 65535,
        spatial_threshold: 50.0,
        max_memory_bytes: 64 * 1024,
        directional_filter,
        ..GuidingConfig::default()
    };
    let budget = config.max_memory_bytes;
    let mut field = GuidingField::new(unit_box(), config).unwrap();
    for _ in 0..4 {
        for i in 0..20_000 {
            let p = Vec3::new(
                (i % 7) as f32 / 7.0,
                (i % 11) as f32 / 11.0,
                (i % 5) as f32 / 5.0,
            );
            let s = Vec2::new((i % 97) as f32 / 97.0, (i % 89) as f32 / 89.0);
            field.record(&Sample {
                position: p,
                direction: square_to_direction(s),
                value: 1.0,
                pdf: INV_SPHERE_AREA,
                ..Sample::default()
            });
        }
        field.refine();
        let stats = field.stats();
        assert!(stats.bytes <= budget, "{stats:?}");
    }
    let stats = field.stats();
    assert!(
        stats.directional_splits_refused > 0 && stats.spatial_splits_refused > 0,
        "{stats:?}"
    );
}

/// Uniformly spread samples on a `n × n` grid with light of 1 everywhere.
fn record_flat(field: &GuidingField, n: usize) {
    record_grid(field, n, |_| 1.0);
}

fn with_refinement(refinement: Refinement) -> GuidingConfig {
    GuidingConfig {
        refinement,
        spatial_threshold: 1e9,
        ..GuidingConfig::default()
    }
}

#[test]
fn a_split_below_the_recorded_leaves_is_predicted_only_from_enough_samples() {
    // The library's `refinement::MIN_PREDICTED_SPLIT_SAMPLES` (crate-private).
    const MIN_PREDICTED_SPLIT_SAMPLES: u64 = 512;
    // A point light in the depth-2 cell [0.25, 0.5)²: after one refine, the depth-1 leaf that
    // holds it splits (it saw more than MIN_SPLIT_SAMPLES), and its quadrant that holds the light
    // is predicted to split too, to depth 3, only if the quadrant saw
    // MIN_PREDICTED_SPLIT_SAMPLES samples.
    let deepest_after_one_refine = |n: u64| {
        let mut field =
            GuidingField::new(unit_box(), with_refinement(Refinement::VarianceGain)).unwrap();
        let d = square_to_direction(Vec2::new(0.3, 0.3));
        for _ in 0..n {
            field.record(&Sample {
                position: Vec3::splat(0.5),
                direction: d,
                value: 1.0,
                pdf: INV_SPHERE_AREA,
                ..Sample::default()
            });
        }
        field.refine();
        let cell = field.cells().next().unwrap();
        let leaves = cell.recorded();
        let holder = leaves.iter().find(|(c, _)| c.contains(Vec2::new(0.3, 0.3)));
        (
            holder.unwrap().0.depth,
            leaves.iter().map(|(c, _)| c.depth).max(),
        )
    };
    let n = MIN_PREDICTED_SPLIT_SAMPLES;
    assert_eq!(deepest_after_one_refine(n - 1), (2, Some(2)));
    assert_eq!(deepest_after_one_refine(n), (3, Some(3)));
}

#[test]
fn variance_gain_spends_no_node_on_flat_light() {
    // Flat light: every quadrant of every leaf has the same second moment, so no split gains
    // anything. Flux share splits every cell whose area exceeds ρ (down to depth 4).
    let leaves = |refinement| {
        let mut field = GuidingField::new(unit_box(), with_refinement(refinement)).unwrap();
        record_flat(&field, 200);
        field.refine();
        let cell = field.cells().next().unwrap();
        cell.recorded().len()
    };
    assert_eq!(leaves(Refinement::VarianceGain), 4);
    assert_eq!(leaves(Refinement::FluxShare), 4 + 12 + 48 + 192);
}

#[test]
fn variance_gain_refines_toward_the_light_and_collapses_when_it_goes_away() {
    let mut field = trained_on_spot(with_refinement(Refinement::VarianceGain), 4);
    let stats = field.stats();
    assert!(stats.directional_depth >= 5, "{stats:?}");
    let cell = field.cells().next().unwrap();
    // Whether the cell of side `size` that holds `leaf` holds some of the light (on a grid as
    // fine as the one recorded).
    let lit = |leaf: &sdguide::DirectionalCell, size: f32| {
        let corner = (leaf.origin / size).floor() * size;
        (0..=32 * 32).any(|i| {
            let t = Vec2::new((i % 33) as f32, (i / 33) as f32) / 32.0;
            in_spot(square_to_direction(corner + t * size))
        })
    };
    for (leaf, _) in cell.distribution().leaves() {
        // Every split cell (the leaf's parent) holds some of the light, or is the child of one
        // that does: a cell's relative gain is shrunk toward its parent's (the guard against
        // sparse sums), so a dark child of a lit cell may split once; a dark child of a dark
        // cell never does.
        assert!(
            leaf.depth <= 2 || lit(&leaf, 2.0 * leaf.size) || lit(&leaf, 4.0 * leaf.size),
            "a dark cell was split: {leaf:?}"
        );
    }
    // Flux share spends more than twice the leaves on the same light.
    let flux = trained_on_spot(with_refinement(Refinement::FluxShare), 4).stats();
    assert!(
        flux.directional_leaves > 2 * stats.directional_leaves,
        "{flux:?}"
    );
    // The light turns flat: one iteration collapses the tree to the root's four leaves.
    record_flat(&field, 200);
    field.refine();
    assert_eq!(field.cells().next().unwrap().recorded().len(), 4);
}

#[test]
fn the_masses_shrinkage_does_not_move_the_variance_gain_splits() {
    // `prior_samples` shrinks the leaf masses only; the gain estimates that decide the splits
    // shrink with their own `SPLIT_PRIOR_SAMPLES`. The same samples, recorded and refined with
    // three values of `prior_samples`, give the same partitions and different masses.
    let refined = |prior_samples: f32| {
        let mut field = GuidingField::new(
            unit_box(),
            GuidingConfig {
                prior_samples,
                ..with_refinement(Refinement::VarianceGain)
            },
        )
        .unwrap();
        // The samples do not come from the learned density, so each iteration records the same
        // ones whatever the masses. After the first refine the leaves near the light are small
        // and see few samples, so shrinkage moves their masses.
        for _ in 0..2 {
            record_spot(&field, 40);
            field.refine();
        }
        let cell = field.cells().next().unwrap();
        let cells: Vec<_> = cell.recorded().iter().map(|(c, _)| *c).collect();
        let masses: Vec<f32> = cell
            .distribution()
            .leaves()
            .into_iter()
            .map(|(_, p)| p)
            .collect();
        (cells, masses)
    };
    let (cells, masses) = refined(0.0);
    assert!(
        cells.len() > 4,
        "the light was not refined toward: {cells:?}"
    );
    for n0 in [0.5, 8.0] {
        let (other_cells, other_masses) = refined(n0);
        assert_eq!(other_cells, cells, "n0 = {n0}");
        let moved = masses
            .iter()
            .zip(&other_masses)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max);
        assert!(moved > 1e-3, "n0 = {n0} left the masses as they were");
    }
}

/// `n` samples at positions and directions spread over the unit box and the sphere (a
/// low-discrepancy sequence), drawn uniformly, with the value `light(position, direction)`.
fn spread_samples(n: u32, light: impl Fn(Vec3, Vec3) -> f32) -> Vec<Sample> {
    let frac = |i: u32, a: f64| ((f64::from(i) * a).fract()) as f32;
    (0..n)
        .map(|i| {
            let position = Vec3::new(
                frac(i, 0.7548776662),
                frac(i, 0.5698402910),
                frac(i, 0.4301597090),
            );
            let u = Vec2::new(frac(i, 0.3176721961), frac(i, 0.8823278039));
            let direction = square_to_direction(u);
            Sample {
                position,
                direction,
                value: light(position, direction),
                pdf: INV_SPHERE_AREA,
                ..Sample::default()
            }
        })
        .collect()
}

#[test]
fn by_gain_a_leaf_splits_where_the_light_changes_and_not_where_samples_pile_up() {
    let config = GuidingConfig {
        spatial_threshold: 2_000.0,
        spatial_split: SpatialSplit::Gain,
        ..GuidingConfig::default()
    };
    let leaves = |light: &dyn Fn(Vec3, Vec3) -> f32| {
        let mut field = GuidingField::new(unit_box(), config.clone()).unwrap();
        field.record_all(&spread_samples(200_000, light));
        field.refine();
        field.cells().map(|c| c.bounds).collect::<Vec<_>>()
    };
    // The same light everywhere: 100 times the count rule's threshold, and no split.
    assert_eq!(leaves(&|_, d| 1.0 + d.z).len(), 1);
    // Light from above for x < ½ and from below beyond: the first split, at x = ½, splits the
    // light; splits beyond it (y, z) gain nothing.
    let split = leaves(&|p, d| {
        if (p.x < 0.5) == (d.z > 0.0) {
            1.0
        } else {
            0.01
        }
    });
    assert_eq!(split.len(), 2, "{split:?}");
    assert!(split.iter().all(|b| (b.max.x - b.min.x - 0.5).abs() < 1e-6));
    // The count rule splits both, by their count.
    let count = GuidingConfig {
        spatial_split: SpatialSplit::Count,
        ..config
    };
    let mut field = GuidingField::new(unit_box(), count).unwrap();
    field.record_all(&spread_samples(200_000, |_, d| 1.0 + d.z));
    field.refine();
    assert!(field.stats().spatial_leaves > 50);
}
