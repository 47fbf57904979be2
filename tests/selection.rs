//! The learned guide-vs-BSDF selection probability converges to the minimizer of the mixture
//! estimator's second moment, found by brute force.

use glam::Vec3;
use sdguide::{Aabb, GuidingConfig, GuidingField, Sample};
use sdguide::{INITIAL_GUIDE_PROBABILITY, MAX_GUIDE_PROBABILITY, MIN_GUIDE_PROBABILITY};
use sdguide_lab::quality::golden_section_min;
use sdguide_lab::rng::Rng;
use sdguide_lab::synthetic::{Bsdf, vmf_density};

const X: Vec3 = Vec3::splat(0.5);
const BSDF: Bsdf = Bsdf {
    axis: Vec3::Z,
    kappa: 10.0,
};

/// Incident light: a constant plus a lobe 60° away from the BSDF's axis, which BSDF sampling
/// reaches only through its tail.
fn light(d: Vec3) -> f32 {
    let lobe = Vec3::new(60f32.to_radians().sin(), 0.0, 60f32.to_radians().cos());
    0.3 + 20.0 * vmf_density(30.0, lobe.dot(d))
}

/// The integrand of the mixture estimator: light times `f_s·|cos|`, which is the BSDF's pdf.
fn integrand(d: Vec3) -> f32 {
    light(d) * BSDF.pdf(d)
}

/// `M(a) = ∫ f²/(a·p_g + (1 − a)·p_b)` with the uniform guide `p_g = 1/4π`, by the midpoint rule
/// on an equal-area grid (uniform in cos θ and φ), fine for lobes of κ ≤ 30.
fn second_moment(a: f64) -> f64 {
    let (nt, np) = (800, 1600);
    let cell = 4.0 * std::f64::consts::PI / (nt * np) as f64;
    let pg = 1.0 / (4.0 * std::f64::consts::PI);
    let mut m = 0.0;
    for i in 0..nt {
        let z = -1.0 + 2.0 * (i as f32 + 0.5) / nt as f32;
        let r = (1.0 - z * z).max(0.0).sqrt();
        for j in 0..np {
            let phi = std::f32::consts::TAU * (j as f32 + 0.5) / np as f32;
            let d = Vec3::new(r * phi.cos(), r * phi.sin(), z);
            let f = f64::from(integrand(d));
            let pb = f64::from(BSDF.pdf(d));
            m += f * f / (a * pg + (1.0 - a) * pb) * cell;
        }
    }
    m
}

#[test]
fn the_guide_probability_converges_to_the_brute_force_minimizer() {
    // The Newton steps are tested with the widest bound, where this problem's optimum is inside.
    let best = golden_section_min(
        f64::from(MIN_GUIDE_PROBABILITY),
        f64::from(MAX_GUIDE_PROBABILITY),
        second_moment,
    );
    assert!(
        best > 0.15 && best < 0.85,
        "the problem should have an interior optimum: {best}"
    );
    // One spatial leaf whose guide stays uniform (the recorded radiance is 0), so only the
    // selection learns.
    let config = GuidingConfig {
        spatial_threshold: 1e9,
        max_guide_probability: MAX_GUIDE_PROBABILITY,
        guide_cost: None,
        ..GuidingConfig::default()
    };
    let mut field = GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), config).unwrap();
    assert_eq!(
        field.distribution(X).guide_probability(),
        INITIAL_GUIDE_PROBABILITY
    );
    let mut rng = Rng::new(17);
    let n = 40_000;
    let (mut gradient, mut curvature, mut squares) = (0.0f64, 0.0f64, 0.0f64);
    let mut last = 0.0;
    for _ in 0..10 {
        let dist = field.distribution(X);
        let a = dist.guide_probability();
        last = f64::from(a);
        (gradient, curvature, squares) = (0.0, 0.0, 0.0);
        for _ in 0..n {
            let u = rng.next_vec2();
            let d = if rng.next_f32() < a {
                dist.sample(u).0
            } else {
                BSDF.sample(u)
            };
            let (pg, pb) = (dist.pdf(d), BSDF.pdf(d));
            let q0 = a * pg + (1.0 - a) * pb;
            let f = integrand(d);
            field.record(
                &Sample {
                    position: X,
                    direction: d,
                    value: 0.0,
                    pdf: q0,
                    ..Sample::default()
                }
                .with_mixture(f, pb, pg),
            );
            // The terms of the Newton step (see `sdguide::guide_probability`), for its error bar.
            let (pg, pb, f2) = (f64::from(pg), f64::from(pb), f64::from(f) * f64::from(f));
            let (q, diff) = (last * pg + (1.0 - last) * pb, pg - pb);
            let g = f2 * diff / (q * q * f64::from(q0));
            gradient += g;
            squares += g * g;
            curvature += g * diff / q;
        }
        field.refine();
    }
    let learned = f64::from(field.distribution(X).guide_probability());
    // The last step is a + G/(2H); its noise is that of G over 2H, with G's standard error
    // sqrt(n·Var[g]) estimated from the same samples. 5σ, plus the second-order remainder of a
    // Newton step that already started at the optimum (negligible: 1e-3).
    let variance = squares - gradient * gradient / n as f64;
    let sigma = variance.sqrt() / (2.0 * curvature);
    assert!(
        (learned - best).abs() < 5.0 * sigma + 1e-3,
        "learned {learned} (last step from {last}) vs brute force {best} (σ = {sigma})"
    );
    // And it pays: the second moment at the learned probability is below that at ½ and within
    // 0.1% of the best.
    let (m_learned, m_half, m_best) = (
        second_moment(learned),
        second_moment(0.5),
        second_moment(best),
    );
    assert!(m_learned < m_half, "{m_learned} vs {m_half}");
    assert!(m_learned < 1.001 * m_best, "{m_learned} vs {m_best}");
}
