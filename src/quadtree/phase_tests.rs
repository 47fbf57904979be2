//! Tests of `phase`.

use super::*;
use crate::quadtree::product::tests::{assert_samples_the_product, final_cells};
use crate::quadtree::testing::{random_sampling_tree, uniform};

/// Asymmetries over the whole range, both signs, the ends included.
const GS: [f32; 7] = [-0.99, -0.6, -0.1, 0.2, 0.7, 0.9, 0.99];

/// Directions of travel: the axes, the square's corners' and border's directions (where the
/// map folds), and a random one.
fn travels(next: &mut impl FnMut() -> f64) -> Vec<Vec3> {
    let random = Vec3::new(next() as f32, next() as f32, next() as f32) * 2.0 - 1.0;
    vec![
        Vec3::Z,
        -Vec3::Z,
        Vec3::X,
        Vec3::new(1.0, 1.0, 0.0).normalize(),
        Vec3::new(0.3, -0.5, -0.8).normalize(),
        random.normalize(),
    ]
}

#[test]
fn the_product_integrates_to_one_is_positive_and_pdf_is_each_cells_probability() {
    let mut next = uniform(41);
    for seed in 1..=3 {
        let tree = random_sampling_tree(seed);
        for d in travels(&mut next) {
            for g in GS {
                let lobe = PhaseLobe::new(d, g).unwrap();
                let cells = final_cells(&tree, &lobe);
                let total: f64 = cells.iter().map(|c| c.p).sum();
                assert!(
                    (total - 1.0).abs() < 1e-5,
                    "seed {seed}, d {d}, g {g}: {total}"
                );
                for c in &cells {
                    let size = 0.5f64.powi(c.depth as i32);
                    let mass = f64::from(tree.pdf_phase(&lobe, c.centre())) * size * size;
                    // Positive wherever the phase function is: everywhere.
                    assert!(mass > 0.0, "seed {seed}, d {d}, g {g}: {:?}", c.cell);
                    // (The test trees' masses span 10⁻⁹ per level: some densities are
                    // subnormal, exact to an absolute 10⁻⁴⁵ only.)
                    assert!(
                        (mass - c.p).abs() <= 1e-5 * c.p + 1e-38,
                        "seed {seed}, d {d}, g {g}, {:?} at {}: {mass} vs {}",
                        c.cell,
                        c.depth,
                        c.p
                    );
                }
            }
        }
    }
}

#[test]
fn the_product_integrates_to_one_numerically() {
    // Midpoints of the 1024 × 1024 grid: one per cell of the deepest level the product
    // reaches (PHASE_DEPTH), so the sum is the integral up to f32 rounding of the densities.
    const N: u32 = 1 << PHASE_DEPTH;
    let tree = random_sampling_tree(2);
    let mut next = uniform(43);
    for (d, g) in travels(&mut next)
        .into_iter()
        .zip([-0.99, 0.99, 0.9, -0.4, 0.05, 0.6])
    {
        let lobe = PhaseLobe::new(d, g).unwrap();
        let mut total = 0.0f64;
        for j in 0..N {
            for i in 0..N {
                let s = Vec2::new((i as f32 + 0.5) / N as f32, (j as f32 + 0.5) / N as f32);
                total += f64::from(tree.pdf_phase(&lobe, s));
            }
        }
        let total = total / f64::from(N * N);
        assert!((total - 1.0).abs() < 1e-4, "d {d}, g {g}: {total}");
    }
}

#[test]
fn the_product_samples_its_cells_chi_square() {
    let mut next = uniform(47);
    let tree = random_sampling_tree(3);
    for (d, g) in [
        (Vec3::Z, 0.99),
        (Vec3::new(0.3, -0.8, 0.2), -0.7),
        (-Vec3::X, 0.3),
    ] {
        let lobe = PhaseLobe::new(d, g).unwrap();
        assert_samples_the_product(&tree, &lobe, &format!("d {d}, g {g}"), || {
            tree.sample_phase(&lobe, Vec2::new(next() as f32, next() as f32))
                .0
        });
    }
}

#[test]
fn sample_returns_the_pdf_of_its_point() {
    let mut next = uniform(53);
    for seed in 1..=4 {
        let tree = random_sampling_tree(seed);
        for d in travels(&mut next) {
            for g in GS {
                let lobe = PhaseLobe::new(d, g).unwrap();
                for _ in 0..500 {
                    let u = Vec2::new(next() as f32, next() as f32);
                    let (s, pdf, near) = tree.sample_phase(&lobe, u);
                    assert!(pdf > 0.0 && pdf.is_finite(), "pdf {pdf}");
                    if !near {
                        assert_eq!(tree.pdf_phase(&lobe, s).to_bits(), pdf.to_bits(), "u = {u}");
                    }
                }
            }
        }
    }
}

#[test]
fn over_a_uniform_guide_the_product_follows_the_phase_function() {
    // The exact ratio of the phase function's peak to its opposite is ((1 + g)/(1 − g))³.
    // The product averages the phase function over cells, so its ratio is smaller but must
    // keep most of the lobe: forward scattering favours d, backward scattering −d.
    let tree = SamplingTree::uniform();
    for d in [Vec3::Z, Vec3::new(0.6, 0.0, -0.8)] {
        let at = |lobe: &PhaseLobe, w: Vec3| tree.pdf_phase(lobe, sphere::square_of(w).unwrap());
        for g in [0.5f32, 0.9, 0.99] {
            let exact = ((1.0 + g) / (1.0 - g)).powi(3);
            let forward = PhaseLobe::new(d, g).unwrap();
            let backward = PhaseLobe::new(d, -g).unwrap();
            assert!(
                at(&forward, d) / at(&forward, -d) > exact.sqrt(),
                "d {d}, g {g}"
            );
            assert!(
                at(&backward, -d) / at(&backward, d) > exact.sqrt(),
                "d {d}, g {g}"
            );
        }
        // At the peak, g = 0.99: within a factor of 2 of the phase function's density there,
        // on the square (×4π), where its lobe is as narrow as the deepest cells.
        let lobe = PhaseLobe::new(d, 0.99).unwrap();
        let peak = 4.0 * std::f64::consts::PI * henyey_greenstein(1.0, 0.99);
        let ours = f64::from(at(&lobe, d));
        assert!(ours > 0.5 * peak && ours < 2.0 * peak, "{ours} vs {peak}");
    }
}

#[test]
fn bad_asymmetries_and_directions_have_documented_answers() {
    assert!(PhaseLobe::new(Vec3::Z, f32::NAN).is_none());
    assert!(PhaseLobe::new(Vec3::Z, 0.0).is_none());
    assert!(PhaseLobe::new(Vec3::ZERO, 0.5).is_none());
    assert!(PhaseLobe::new(Vec3::new(f32::NAN, 0.0, 1.0), 0.5).is_none());
    // |g| ≥ 1 (and infinities) are clamped to ±MAX_G.
    let tree = random_sampling_tree(1);
    let s = Vec2::new(0.3, 0.7);
    for (g, clamped) in [
        (1.0, MAX_G),
        (7.0, MAX_G),
        (f32::INFINITY, MAX_G),
        (-1.0, -MAX_G),
    ] {
        let a = PhaseLobe::new(Vec3::X, g).unwrap();
        let b = PhaseLobe::new(Vec3::X, clamped).unwrap();
        assert_eq!(tree.pdf_phase(&a, s), tree.pdf_phase(&b, s), "g {g}");
    }
}

#[test]
fn the_reference_phase_function_integrates_to_one() {
    // ∫ p_HG dω = 2π ∫_{-1}^{1} p_HG(μ) dμ, by the midpoint rule on 10⁶ intervals.
    for g in [-0.9, 0.0, 0.5, 0.99] {
        let n = 1_000_000;
        let h = 2.0 / f64::from(n);
        let total: f64 = (0..n)
            .map(|i| henyey_greenstein(-1.0 + (f64::from(i) + 0.5) * h, g) * h)
            .sum::<f64>()
            * 2.0
            * std::f64::consts::PI;
        assert!((total - 1.0).abs() < 1e-3, "g {g}: {total}");
    }
}
