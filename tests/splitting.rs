//! Roulette and splitting from the field's continuation estimates: a renderer that follows
//! the factors stays unbiased on a problem with a known answer, whether the estimates make it
//! split or kill; the estimates it learns are what the continuations returned; bad input is
//! rejected and counted.

use glam::Vec3;
use sdguide::continuations;
use sdguide::{
    Aabb, Continuation, ContinuationEstimate, GuidingConfig, GuidingField, RejectReason, Splitting,
    SplittingMode,
};
use sdguide_lab::rng::Rng;

/// Emission at every vertex, and the share of what arrives that a vertex passes on.
const EMISSION: f64 = 1.0;
const ALBEDO: f64 = 0.5;
const MAX_DEPTH: u32 = 24;

/// The expected value of a walk: `e·Σ_{k ≤ MAX_DEPTH} a^k`.
fn expected() -> f64 {
    EMISSION * (1.0 - ALBEDO.powi(MAX_DEPTH as i32 + 1)) / (1.0 - ALBEDO)
}

/// A uniform point of the unit cube.
fn point(rng: &mut Rng) -> Vec3 {
    Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32())
}

/// A walk in a "furnace" of vertices scattered through the unit cube: each vertex emits
/// `EMISSION` and passes on `ALBEDO` of one continuation's value (`f/p = a`), from a new
/// random point. The number of continuations comes from `policy` where the vertex's cell has
/// an estimate (classic survival with probability `a` elsewhere). Returns the walk's value
/// and its cost (vertices), recording every continuation into `field` when `record`.
fn walk(
    field: &GuidingField,
    policy: &Splitting,
    rng: &mut Rng,
    throughput: f32,
    depth: u32,
    record: bool,
) -> (f64, f32) {
    let x = point(rng);
    let mut value = EMISSION;
    let mut cost = 1.0;
    if depth == MAX_DEPTH {
        return (value, cost);
    }
    let estimate = field.continuation(x);
    let pixel = expected() as f32;
    let (n, weight) = match policy.factor(&estimate, throughput, pixel) {
        Some(q) => continuations(q, rng.next_f32()),
        None => continuations(ALBEDO as f32, rng.next_f32()),
    };
    for _ in 0..n {
        let (v, c) = walk(
            field,
            policy,
            rng,
            throughput * weight * ALBEDO as f32,
            depth + 1,
            record,
        );
        let reflected = ALBEDO * v;
        if record {
            field.record_continuation(&Continuation {
                position: x,
                value: reflected as f32,
                cost: c,
            });
        }
        value += f64::from(weight) * reflected;
        cost += c;
    }
    (value, cost)
}

fn field() -> GuidingField {
    let config = GuidingConfig {
        spatial_threshold: 500.0,
        ..GuidingConfig::default()
    };
    GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), config).unwrap()
}

/// A field whose cells have learned the walk's continuations; the spatial tree is grown by
/// guide samples the walk's vertices would record.
fn trained(policy: &Splitting) -> GuidingField {
    let mut field = field();
    let mut rng = Rng::new(0x5eed);
    for iteration in 0..4 {
        for _ in 0..4000 << iteration {
            let x = point(&mut rng);
            field.record(&sdguide::Sample {
                position: x,
                direction: Vec3::Z,
                value: 1.0,
                pdf: 1.0,
                ..Default::default()
            });
        }
        for _ in 0..2000 {
            walk(&field, policy, &mut rng, 1.0, 0, true);
        }
        field.refine();
    }
    field
}

/// Mean of `n` walks and its standard error.
fn mean_of_walks(field: &GuidingField, policy: &Splitting, n: usize, seed: u64) -> (f64, f64, f64) {
    let mut rng = Rng::new(seed);
    let (mut sum, mut sum_sq, mut cost) = (0.0, 0.0, 0.0);
    for _ in 0..n {
        let (v, c) = walk(field, policy, &mut rng, 1.0, 0, false);
        sum += v;
        sum_sq += v * v;
        cost += f64::from(c);
    }
    let n = n as f64;
    let mean = sum / n;
    let var = (sum_sq / n - mean * mean) * n / (n - 1.0);
    (mean, (var / n).sqrt(), cost / n)
}

#[test]
fn learned_estimates_are_the_continuations_mean_and_second_moment() {
    let policy = Splitting::new(SplittingMode::RouletteAndSplitting, 1.0, 2.0);
    let field = trained(&policy);
    assert!(field.stats().spatial_leaves > 4, "{:?}", field.stats());
    // A continuation returns a·V on average, V the walk's value from the next depth: within
    // a few percent of a·expected() (deeper walks are shorter by the depth cap only).
    let mut pooled = ContinuationEstimate::default();
    for cell in field.cells() {
        let e = field.continuation(cell.bounds.center());
        assert!(e.count >= 16, "{e:?}");
        pooled = ContinuationEstimate {
            sum: pooled.sum + e.sum,
            sum_sq: pooled.sum_sq + e.sum_sq,
            cost: pooled.cost + e.cost,
            count: pooled.count + e.count,
        };
    }
    let mean = pooled.mean().unwrap();
    let target = ALBEDO * expected();
    assert!((mean - target).abs() < 0.05 * target, "{mean} vs {target}");
    assert!(pooled.second_moment().unwrap() >= mean * mean);
    assert!(pooled.mean_cost().unwrap() >= 1.0);
}

#[test]
fn walks_that_split_or_kill_by_the_factors_stay_unbiased() {
    let expected = expected();
    // The factors of the image's own terms; a tiny image variance, which makes every vertex
    // split (to a bound low enough for the tree to stay small); a huge one, which makes every
    // vertex play roulette at the floor (high enough for the variance to stay finite:
    // a²/q < 1); and roulette alone.
    let fair = Splitting::new(SplittingMode::RouletteAndSplitting, 0.5, 4.0);
    let field = trained(&fair);
    let splitting = Splitting::new(SplittingMode::RouletteAndSplitting, 1e-6, 4.0)
        .with_bounds(0.05, 1.15)
        .unwrap();
    let killing = Splitting::new(SplittingMode::RouletteAndSplitting, 1e6, 4.0)
        .with_bounds(0.3, 3.0)
        .unwrap();
    let roulette = Splitting::new(SplittingMode::Roulette, 0.5, 4.0);
    let mut costs = Vec::new();
    for (name, policy, n) in [
        ("fair", fair, 40_000),
        ("splitting", splitting, 4_000),
        ("killing", killing, 200_000),
        ("roulette only", roulette, 40_000),
    ] {
        let (mean, error, cost) = mean_of_walks(&field, &policy, n, 99);
        assert!(
            error > 0.0 && error < 0.02 * expected,
            "{name}: error {error}"
        );
        assert!(
            (mean - expected).abs() < 4.0 * error,
            "{name}: mean {mean} vs {expected} (standard error {error})"
        );
        costs.push(cost);
    }
    // The policies did what they were made to: more vertices when splitting, fewer killing.
    assert!(costs[1] > 2.0 * costs[0], "{costs:?}");
    assert!(costs[2] < 0.7 * costs[0], "{costs:?}");
}

#[test]
fn bad_continuations_are_rejected_and_counted() {
    let field = field();
    let ok = Continuation {
        position: Vec3::splat(0.5),
        value: 1.0,
        cost: 3.0,
    };
    assert_eq!(field.try_record_continuation(&ok), Ok(()));
    let bad = [
        (
            Continuation {
                position: Vec3::NAN,
                ..ok
            },
            RejectReason::NonFinitePosition,
        ),
        (
            Continuation {
                position: Vec3::splat(7.0),
                ..ok
            },
            RejectReason::OutOfBounds,
        ),
        (
            Continuation {
                value: f32::NAN,
                ..ok
            },
            RejectReason::BadValue,
        ),
        (Continuation { value: -1.0, ..ok }, RejectReason::BadValue),
        (
            Continuation {
                cost: f32::INFINITY,
                ..ok
            },
            RejectReason::BadValue,
        ),
        (Continuation { cost: -0.5, ..ok }, RejectReason::BadValue),
    ];
    for (c, reason) in bad {
        assert_eq!(field.try_record_continuation(&c), Err(reason), "{c:?}");
    }
    let stats = field.stats();
    assert_eq!(stats.continuations_recorded, 1);
    assert_eq!(stats.rejected.non_finite_position, 1);
    assert_eq!(stats.rejected.out_of_bounds, 1);
    assert_eq!(stats.rejected.bad_value, 4);
    // Nothing bad reached the sums.
    let mut field = field;
    field.refine();
    let e = field.continuation(Vec3::splat(0.5));
    assert_eq!((e.sum, e.sum_sq, e.cost, e.count), (1.0, 1.0, 3.0, 1));
}
