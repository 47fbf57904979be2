//! Variance-optimal technique selection (the paper's section 3) on a 1D mixture with closed forms.
//!
//! On [0, 1], with mixture weights α = (½, ½):
//!   technique 0: f₀ = 3x², sampled exactly (g₀ = 3x²): weight w = α₀ f₀/g₀ = ½, m₀ = ¼;
//!   technique 1: f₁ = 3x², sampled uniformly (g₁ = 1): w = 3x²/2, m₁ = (9/4)·E[x⁴] = 9/20.
//! The integral is μ = ½·1 + ½·1 = 1, and the one-sample estimator's variance with selection
//! probabilities α̃ is V(α̃) = m₀/α̃₀ + m₁/α̃₁ − μ² (eq. 30).

use sdguide::{MIN_TECHNIQUE_SAMPLES, TechniqueError, TechniqueProbabilities};
use sdguide_lab::rng::Rng;

const M: [f64; 2] = [0.25, 0.45];

/// Draws from technique `i`: returns x and the weight α_i f_i(x)/g_i(x).
fn draw(i: usize, rng: &mut Rng) -> f64 {
    let u = f64::from(rng.next_f32());
    match i {
        0 => 0.5,         // f₀/g₀ = 1 everywhere
        _ => 1.5 * u * u, // x = u uniform: ½ · 3x²
    }
}

fn variance(p: [f64; 2]) -> f64 {
    M[0] / p[0] + M[1] / p[1] - 1.0
}

#[test]
fn learned_probabilities_match_the_closed_form() {
    let floor = 0.02;
    let selection = TechniqueProbabilities::new(2, floor).unwrap();
    let mut rng = Rng::new(3);
    let n = 1_000_000;
    for i in 0..2 {
        for _ in 0..n {
            selection.record(i, draw(i, &mut rng) as f32).unwrap();
        }
    }
    let roots = M.map(f64::sqrt);
    let expected0 = floor + (1.0 - 2.0 * floor) * roots[0] / (roots[0] + roots[1]);
    let p = selection.probabilities();
    // m̂₀ is exact (constant weights); m̂₁ has relative standard error sqrt(Var(w²)/n)/m₁ with
    // Var(w²) = (3/2)⁴·E[x⁸] − m₁² = 0.36: 1.3e-3. A share s = a/(a+b) of square roots moves
    // by s(1−s)·½·rel(m₁) ≈ 1.7e-4 at 1σ; 1e-3 is about 6σ.
    assert!((p[0] - expected0).abs() < 1e-3, "{p:?} vs {expected0}");
    assert!((p[0] + p[1] - 1.0).abs() < 1e-12);
    let m = selection.second_moments();
    assert!((m[1].unwrap() - M[1]).abs() < 5.0 * 0.6 / (n as f64).sqrt());
}

#[test]
fn optimal_selection_lowers_the_estimator_variance() {
    let selection = TechniqueProbabilities::new(2, 0.01).unwrap();
    let mut rng = Rng::new(5);
    for i in 0..2 {
        for _ in 0..200_000 {
            selection.record(i, draw(i, &mut rng) as f32).unwrap();
        }
    }
    let learned = selection.probabilities();
    let learned = [learned[0], learned[1]];
    // Closed forms: 0.4 with α̃ = α, 0.371 at the optimum (the floor costs a little).
    let (v_alpha, v_learned) = (variance([0.5, 0.5]), variance(learned));
    assert!((v_alpha - 0.4).abs() < 1e-12);
    assert!(v_learned < 0.372 && v_learned < v_alpha);
    // And the one-sample estimator, run with each choice, shows it: empirical variances agree
    // with the closed forms within 5σ, and differ from each other by more than 5σ.
    let run = |p: [f64; 2], seed: u64| {
        let mut rng = Rng::new(seed);
        let n = 2_000_000;
        let (mut s1, mut s2, mut s4) = (0.0, 0.0, 0.0);
        for _ in 0..n {
            let i = usize::from(f64::from(rng.next_f32()) >= p[0]);
            let w = draw(i, &mut rng) / p[i];
            s1 += w;
            s2 += w * w;
            s4 += w * w * w * w;
        }
        let n = n as f64;
        let (mean, second) = (s1 / n, s2 / n);
        let var = second - mean * mean;
        // Standard error of the variance estimate: sqrt((E[w⁴] − E[w²]²)/n), near enough for
        // an estimator whose mean is 1.
        (mean, var, ((s4 / n - second * second) / n).sqrt())
    };
    let (mean_a, var_a, se_a) = run([0.5, 0.5], 11);
    let (mean_l, var_l, se_l) = run(learned, 12);
    for (mean, var, se, closed) in [
        (mean_a, var_a, se_a, v_alpha),
        (mean_l, var_l, se_l, v_learned),
    ] {
        assert!(
            (mean - 1.0).abs() < 5.0 * (var / 2e6).sqrt(),
            "unbiased: {mean}"
        );
        assert!((var - closed).abs() < 5.0 * se, "{var} vs {closed} ± {se}");
    }
    assert!(var_a - var_l > 5.0 * (se_a * se_a + se_l * se_l).sqrt());
}

#[test]
fn probabilities_stay_within_the_floor_and_unknown_techniques_keep_being_tried() {
    let selection = TechniqueProbabilities::new(3, 0.05).unwrap();
    assert_eq!(selection.probabilities(), vec![1.0 / 3.0; 3]);
    for _ in 0..MIN_TECHNIQUE_SAMPLES {
        selection.record(0, 2.0).unwrap();
        selection.record(1, 0.0).unwrap();
    }
    // Technique 2 has no samples: it is treated like the best one so far (sqrt m = 2).
    let p = selection.probabilities();
    assert!(
        (p[1] - 0.05).abs() < 1e-12,
        "a dark technique keeps the floor: {p:?}"
    );
    assert!((p[0] - p[2]).abs() < 1e-12);
    assert!(p.iter().all(|&x| (0.05..=1.0).contains(&x)));
    assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    // Bad weights and indices are rejected, not recorded.
    assert!(matches!(
        selection.record(0, f32::NAN),
        Err(TechniqueError::BadWeight { .. })
    ));
    assert!(selection.record(0, -1.0).is_err());
    assert!(selection.record(0, f32::INFINITY).is_err());
    assert_eq!(
        selection.record(7, 1.0),
        Err(TechniqueError::UnknownTechnique {
            technique: 7,
            techniques: 3
        })
    );
    assert_eq!(selection.probabilities(), p);
    // Bad construction.
    assert_eq!(
        TechniqueProbabilities::new(0, 0.1).unwrap_err(),
        TechniqueError::NoTechniques
    );
    let floor_error = |floor: f64| TechniqueProbabilities::new(3, floor).unwrap_err();
    assert!(matches!(
        floor_error(0.5),
        TechniqueError::FloorOutOfRange { .. }
    ));
    assert!(matches!(
        floor_error(f64::NAN),
        TechniqueError::FloorOutOfRange { .. }
    ));
    let mut s = TechniqueProbabilities::new(2, 0.5).unwrap();
    s.record(0, 1.0).unwrap();
    s.reset();
    assert_eq!(s.second_moments(), vec![None, None]);
}
