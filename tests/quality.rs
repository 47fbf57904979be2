//! The quality harness's claims, as tests: the learned estimator is unbiased, the exact second
//! moment agrees with Monte Carlo, the l2 rule beats the l1 rule on every light field (clearly
//! on the noisy ones), no density beats the oracle, the l2 density comes within 1.15× of it,
//! refinement by variance gain beats refinement by flux share at equal node counts, and the
//! learned guide-vs-BSDF selection beats the fixed ½, and with a BSDF the mixture rule beats l1
//! on the estimator a renderer computes (and l2 on three fields of four).
//!
//! Fixed seeds; a smaller budget than the harness's default (5 iterations from 100k samples),
//! but for the distance to the oracle, which is a claim about the default budget. The harness's
//! own table (`cargo run --release --example quality`) uses the default budget.
//!
//! Each claim but unbiasedness takes about a minute of training and exact evaluation (seven
//! in all on 2 cores), so they are the long statistical harness: `cargo test` skips them, and
//! `cargo test --test quality -- --ignored` runs them (CI does, on every change).

use sdguide::{GuidingConfig, GuidingField, LeafRule, Refinement};
use sdguide_lab::quality::{self, Budget, Holdout, Report, TestField, cell_integrals};
use sdguide_lab::rng::Rng;

const BUDGET: Budget = Budget {
    iterations: 5,
    first: 100_000,
};

/// A field trained on `field` with `rule`. Every guide stays on (`guide_cost: None`): the
/// harness measures variance, and a guide turned off for its cost trades variance for time.
fn trained(field: &TestField, rule: LeafRule) -> (GuidingField, Report) {
    trained_with(
        field,
        GuidingConfig {
            rule,
            guide_cost: None,
            ..GuidingConfig::default()
        },
    )
}

fn trained_with(field: &TestField, config: GuidingConfig) -> (GuidingField, Report) {
    let trained = quality::train(field, config, BUDGET).unwrap();
    let report = trained.evaluate(field, Holdout::default());
    (trained.field, report)
}

/// Training seeds the equal-node comparison averages over.
const SEEDS: [u64; 4] = [1, 2, 3, 4];

#[test]
#[ignore = "long statistical harness: cargo test --test quality -- --ignored (CI runs it)"]
fn variance_gain_beats_flux_share_at_equal_node_counts() {
    // Both criteria split as much as a node budget per directional tree allows (thresholds far
    // below anything the light reaches), so both spend the same nodes; what differs is where.
    //
    // The claim is about the criteria, not one training run: on the noisy sharp lobe one run's
    // relvar moves by 10–25% between training seeds (a few leaves are decided by a handful of
    // rare large values), more than the criteria differ. So each side is the mean over four
    // seeds, evaluated at 64 held-out positions per cell (the same positions for both; the
    // oracle, which needs more, is not compared here).
    let holdout = Holdout {
        positions: 64,
        ..Holdout::default()
    };
    for nodes in [60, 120] {
        for field in TestField::all() {
            let mean = |refinement| {
                let config = GuidingConfig {
                    refinement,
                    subdivision_threshold: 1e-6,
                    gain_threshold: 1e-6,
                    max_directional_nodes: nodes,
                    ..GuidingConfig::default()
                };
                let (mut relvar, mut leaves) = (0.0, 0.0);
                for seed in SEEDS {
                    let mut field = field.clone();
                    field.workload.seed = seed;
                    let trained = quality::train(&field, config.clone(), BUDGET).unwrap();
                    let report = trained.evaluate(&field, holdout);
                    relvar += report.variances.learned / SEEDS.len() as f64;
                    leaves += report.directional_leaves / SEEDS.len() as f64;
                }
                (relvar, leaves)
            };
            let (flux, gain) = (mean(Refinement::FluxShare), mean(Refinement::VarianceGain));
            assert!(
                gain.1 <= flux.1,
                "{}, {nodes} nodes: leaves {gain:?} vs {flux:?}",
                field.name
            );
            assert!(
                gain.0 < flux.0,
                "{}, {nodes} nodes: relvar and leaves, gain {gain:?} vs flux {flux:?}",
                field.name
            );
        }
    }
}

#[test]
#[ignore = "long statistical harness: cargo test --test quality -- --ignored (CI runs it)"]
fn l2_beats_l1_on_every_field_and_clearly_on_the_noisy_ones() {
    for field in TestField::all() {
        let (_, l1) = trained(&field, LeafRule::L1);
        let (_, l2) = trained(&field, LeafRule::L2);
        let (v1, v2) = (l1.variances, l2.variances);
        // The variances are exact (quadrature) for the trained fields; what varies is the
        // training, which the fixed seed pins. The margins are far outside the quadrature's
        // error (< 0.1%, tested in the library).
        let bound = if field.workload.lobe_noise > 1.0 {
            0.8
        } else {
            1.0
        };
        assert!(
            v2.learned < bound * v1.learned,
            "{}: L2 {} vs L1 {}",
            field.name,
            v2.learned,
            v1.learned
        );
        // No piecewise-constant density on the partition beats the oracle, and learning beats
        // uniform sampling by far.
        for v in [v1, v2] {
            assert!(v.oracle <= v.learned, "{}: {v:?}", field.name);
            assert!(v.learned < 0.2 * v.uniform, "{}: {v:?}", field.name);
        }
    }
}

/// `L2 / oracle` of `field` trained with the default configuration for `budget`, measured as
/// the harness's tables are (the default held-out positions).
fn ratio_to_the_oracle(field: &TestField, budget: Budget) -> f64 {
    let trained = quality::train(field, GuidingConfig::default(), budget).unwrap();
    let v = trained.evaluate(field, Holdout::default()).variances;
    assert!(v.oracle <= v.learned, "{}: {v:?}", field.name);
    v.learned / v.oracle
}

/// How far the learned l2 density may stay from the oracle on its own partition: the target
/// the harness holds the library to.
const WITHIN_ORACLE: f64 = 1.15;

#[test]
#[ignore = "long statistical harness: cargo test --test quality -- --ignored (CI runs it)"]
fn l2_is_within_1_15_of_the_oracle_at_the_default_budget() {
    // The harness's default budget (5 iterations of 250k·2^k samples), training seed 1, 256
    // held-out positions per cell: the protocol of docs/quality.md's leaf-rules table. The
    // variances are exact for the trained field, so the bound is the target itself, with no
    // allowance for evaluation noise.
    //
    // Not on the noisy sharp lobe: there the ratio is 1.17–1.23 over training seeds at this
    // budget. Its gap sits in leaves whose sums rest on a few of the lobe's rare non-zero
    // values, and it closes with samples (next test); docs/quality.md lists what was tried.
    for field in &TestField::all()[..3] {
        let ratio = ratio_to_the_oracle(field, Budget::default());
        assert!(
            ratio <= WITHIN_ORACLE,
            "{}: L2 / oracle {ratio}",
            field.name
        );
    }
}

#[test]
#[ignore = "long statistical harness: cargo test --test quality -- --ignored (CI runs it)"]
fn on_the_held_out_sun_and_sky_l2_with_filter_samples_beats_l1_and_nears_the_oracle() {
    // A tiny sun some 3000 times brighter than the sky: the directional box filter hands the
    // sun's neighbours a share of its second moment, and the square root of the l2 mass
    // magnifies it; `filter_samples` weighs a well-sampled leaf's own second moment instead
    // (opt-in, at the value measured). The default budget and held-out positions, as
    // docs/quality.md's table.
    let field = TestField::sun_and_sky();
    let train = |config: GuidingConfig| {
        let trained = quality::train(&field, config, Budget::default()).unwrap();
        trained.evaluate(&field, Holdout::default()).variances
    };
    let l1 = train(GuidingConfig {
        rule: LeafRule::L1,
        ..GuidingConfig::default()
    });
    let l2 = train(GuidingConfig {
        filter_samples: Some(128.0),
        ..GuidingConfig::default()
    });
    assert!(l2.learned < l1.learned, "L2 {l2:?} vs L1 {l1:?}");
    assert!(l2.oracle <= l2.learned, "{l2:?}");
    let ratio = l2.learned / l2.oracle;
    assert!(ratio <= WITHIN_ORACLE, "L2 / oracle {ratio}");
}

#[test]
#[ignore = "long statistical harness: cargo test --test quality -- --ignored (CI runs it)"]
fn the_noisy_sharp_lobes_gap_to_the_oracle_closes_with_samples() {
    // Four times the default budget (5 iterations of 1M·2^k samples), otherwise as above.
    let field = &TestField::all()[3];
    assert!(field.workload.lobe_noise > 1.0 && field.name.starts_with("sharp"));
    let budget = Budget {
        first: 4 * Budget::default().first,
        ..Budget::default()
    };
    let ratio = ratio_to_the_oracle(field, budget);
    assert!(
        ratio <= WITHIN_ORACLE,
        "{}: L2 / oracle {ratio}",
        field.name
    );
}

#[test]
fn the_learned_estimator_is_unbiased_and_its_exact_variance_matches_monte_carlo() {
    for field in TestField::all() {
        let guiding = quality::train(&field, GuidingConfig::default(), BUDGET)
            .unwrap()
            .field;
        let w = &field.workload;
        let mut rng = Rng::new(41);
        for _ in 0..3 {
            let x = sdguide_lab::synthetic::room_point([
                rng.next_f32(),
                rng.next_f32(),
                rng.next_f32(),
            ]);
            let dist = guiding.distribution(x);
            let n = 200_000;
            let nf = n as f64;
            let truth = w.light.integral(x);
            // Unbiased: the mean of v/p, drawn as a renderer draws it, within 4σ of the integral.
            let (mut s1, mut s2) = (0.0f64, 0.0f64);
            for _ in 0..n {
                let (d, p) = dist.sample(rng.next_vec2());
                let v = f64::from(w.value(x, d, &mut rng)) / f64::from(p) - truth;
                s1 += v;
                s2 += v * v;
            }
            let se_mean = ((s2 / nf - (s1 / nf).powi(2)) / nf).sqrt();
            assert!(
                (s1 / nf).abs() < 4.0 * se_mean,
                "{}: bias {} ± {se_mean}",
                field.name,
                s1 / nf
            );
            // The exact second moment E_p[(v/p)²] = Σ_i 4π|C_i|·I2_i/α_i, against Monte Carlo.
            // Draws from p itself cannot check it where a leaf with a tiny α_i holds light: the
            // draws that show its m_i/α_i are a handful in a million, so a sample variance and
            // its standard error both miss them (at the tests' budget such a leaf carries half
            // the second moment at one of these positions). So the check draws from
            // q = ½·p + ½·r, r putting on each leaf a share ∝ sqrt of its exact second moment
            // (uniform within it), which sees every leaf that matters, and weighs by p/q:
            // E_q[(v/p)²·p/q] = E_p[(v/p)²], with a standard error from the same draws.
            let leaves = dist.leaves();
            let cells: Vec<_> = leaves.iter().map(|(c, _)| *c).collect();
            let integrals = cell_integrals(w, x, &cells);
            let four_pi = 4.0 * std::f64::consts::PI;
            let m: Vec<f64> = cells
                .iter()
                .zip(&integrals)
                .map(|(c, i)| four_pi * c.area() * i.second)
                .collect();
            let exact_second: f64 = m
                .iter()
                .zip(&leaves)
                .map(|(m, (_, a))| m / f64::from(*a))
                .sum();
            let roots: Vec<f64> = m.iter().map(|m| m.sqrt()).collect();
            let total: f64 = roots.iter().sum();
            // r's solid-angle density in the leaf holding `d`.
            let r_density = |d: glam::Vec3| {
                let s = sdguide::sphere::direction_to_square(d);
                let k = cells.iter().position(|c| c.contains(s)).unwrap();
                roots[k] / total / (four_pi * cells[k].area())
            };
            let (mut t1, mut t2) = (0.0f64, 0.0f64);
            for _ in 0..n {
                let d = if rng.next_f32() < 0.5 {
                    dist.sample(rng.next_vec2()).0
                } else {
                    let mut u = f64::from(rng.next_f32()) * total;
                    let k = roots.iter().position(|r| {
                        u -= r;
                        u < 0.0
                    });
                    let c = cells[k.unwrap_or(cells.len() - 1)];
                    sdguide::sphere::square_to_direction(c.origin + rng.next_vec2() * c.size)
                };
                let p = f64::from(dist.pdf(d));
                let q = 0.5 * p + 0.5 * r_density(d);
                let v = f64::from(w.value(x, d, &mut rng));
                let t = v * v / (p * q);
                t1 += t;
                t2 += t * t;
            }
            let estimate = t1 / nf;
            let se = ((t2 / nf - estimate * estimate) / nf).sqrt();
            assert!(
                (estimate - exact_second).abs() < 5.0 * se,
                "{}: Monte Carlo second moment {estimate} ± {se} vs exact {exact_second}",
                field.name
            );
        }
    }
}

#[test]
#[ignore = "long statistical harness: cargo test --test quality -- --ignored (CI runs it)"]
fn the_learned_guide_probability_beats_a_fixed_half() {
    for field in TestField::all() {
        let field = field.with_bsdf();
        let (_, report) = trained(&field, LeafRule::L2);
        let s = report.selection.unwrap();
        // Exact variances of the same trained guide with two selection probabilities. (How
        // close the learned one comes to the best is measured, not asserted: the guide changes
        // every iteration, and with it the optimum the Newton steps chase. Convergence on a
        // fixed problem is `tests/selection.rs`.)
        assert!(s.best <= s.learned, "{}: {s:?}", field.name);
        assert!(s.learned < s.half, "{}: {s:?}", field.name);
    }
}

#[test]
#[ignore = "long statistical harness: cargo test --test quality -- --ignored (CI runs it)"]
fn the_mixture_rule_beats_l1_everywhere_and_l2_but_on_the_noisy_sharp_lobe() {
    for field in TestField::all() {
        let field = field.with_bsdf();
        // The exact variance of the estimator a renderer computes, f/q with each cell's
        // learned guide probability, for a guide trained with each rule.
        let learned = |rule| trained(&field, rule).1.selection.unwrap().learned;
        let (l1, l2, mixture) = (
            learned(LeafRule::L1),
            learned(LeafRule::L2),
            learned(LeafRule::L2Mixture),
        );
        eprintln!(
            "{}: l1 {l1:.4}, l2 {l2:.4}, l2 mixture {mixture:.4}",
            field.name
        );
        assert!(mixture < l1, "{}: {mixture} vs l1 {l1}", field.name);
        // On the noisy sharp lobe the multiplicative update carries each iteration's noise
        // into the next (docs/quality.md): there it stays within 15% of l2, elsewhere below.
        let bound = if field.name == "sharp lobe + ambient, noisy" {
            1.15
        } else {
            1.0
        };
        assert!(mixture < bound * l2, "{}: {mixture} vs l2 {l2}", field.name);
    }
}
