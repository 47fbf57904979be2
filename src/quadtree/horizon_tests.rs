//! Tests of `horizon`.

use super::*;
use crate::quadtree::product::tests::{assert_samples_the_product, final_cells};
use crate::quadtree::testing::{random_sampling_tree, uniform};
use crate::sphere::square_to_direction;

#[test]
fn every_direction_of_a_cell_lies_within_its_chord_radius() {
    // The cell's border bounds its image on the sphere; sample it densely.
    for depth in 1..=10u32 {
        let n = 1u32 << depth;
        let size = 1.0 / n as f64;
        let (mut worst, mut cells) = (0.0f64, 0);
        // All cells to depth 6; beyond, a spread of cells that includes the square's
        // border, its centre and its corners, where the map is most distorted.
        let picks: Vec<u32> = if depth <= 6 {
            (0..n).collect()
        } else {
            (0..n)
                .step_by((n / 16) as usize)
                .chain([n / 2 - 1, n - 1])
                .collect()
        };
        for &cx in &picks {
            for &cy in &picks {
                cells += 1;
                let c = square_to_direction(Vec2::new(
                    ((f64::from(cx) + 0.5) * size) as f32,
                    ((f64::from(cy) + 0.5) * size) as f32,
                ));
                for i in 0..=32 {
                    let t = f64::from(i) / 32.0;
                    for (bx, by) in [(t, 0.0), (t, 1.0), (0.0, t), (1.0, t)] {
                        let s = Vec2::new(
                            ((f64::from(cx) + bx) * size) as f32,
                            ((f64::from(cy) + by) * size) as f32,
                        );
                        worst = worst.max(f64::from((square_to_direction(s) - c).length()));
                    }
                }
            }
        }
        let bound = f64::from(chord_radius(depth) - COSINE_ERROR);
        assert!(
            worst <= bound,
            "depth {depth}: {worst} > {bound} ({cells} cells)"
        );
    }
}

#[test]
fn the_corner_cosines_follow_the_exact_map() {
    let mut next = uniform(3);
    for _ in 0..2000 {
        let n = random_normal(&mut next);
        let depth = (next() * 12.0) as u32;
        let side = 1u32 << depth;
        let cell = [
            (next() * f64::from(side)) as u32,
            (next() * f64::from(side)) as u32,
        ];
        let (lo, hi) = child_corner_range(n, cell, depth);
        for q in 0..4 {
            let (ix, iy) = ((q & 1) as u32, (q >> 1) as u32);
            let half = 0.5 / side as f32;
            let exact: Vec<f32> = [(0, 0), (1, 0), (0, 1), (1, 1)]
                .iter()
                .map(|&(a, b)| {
                    let s = Vec2::new((2 * cell[0] + ix + a) as f32, (2 * cell[1] + iy + b) as f32)
                        * half;
                    square_to_direction(s).dot(n)
                })
                .collect();
            let (elo, ehi) = exact
                .iter()
                .fold((2.0f32, -2.0f32), |(l, h), &x| (l.min(x), h.max(x)));
            assert!(
                (lo[q] - elo).abs() < COSINE_ERROR / 4.0,
                "{} vs {elo}",
                lo[q]
            );
            assert!(
                (hi[q] - ehi).abs() < COSINE_ERROR / 4.0,
                "{} vs {ehi}",
                hi[q]
            );
        }
    }
}

#[test]
fn the_estimate_is_the_mean_over_the_corners_range_and_positive_where_it_may_reach_above() {
    let r = 0.5;
    let c = ramp(Vec4::new(-0.6, -0.5, 0.0, 0.7), r).to_array();
    assert_eq!(c[..2], [0.0, 0.0]);
    // The mean of max(0, x) over [−½, ½] is 1/8.
    assert!((c[2] - 0.125).abs() < 1e-7);
    assert_eq!(c[3], 0.7);
    for depth in 1..=HORIZON_DEPTH {
        let reach = 2.0 * chord_radius(depth);
        let lo = Vec4::new(-0.5, -0.5, -0.2, 0.2);
        let hi = Vec4::new(-reach, (-reach).next_up(), 0.2, 0.6);
        let c = clamped_cosine(lo, hi, depth).to_array();
        // Farther below than any direction of the cell can be from a corner: nothing.
        assert_eq!(c[0], 0.0, "depth {depth}");
        // A corner within reach: positive, and tiny.
        assert!(c[1] > 0.0 && c[1] < 1e-4, "depth {depth}: {}", c[1]);
        // Crossed: the mean of max(0, x) over [−0.2, 0.2], 0.05; above: the mean, 0.4.
        assert!(
            (c[2] - 0.05).abs() < 1e-7 && (c[3] - 0.4).abs() < 1e-7,
            "{c:?}"
        );
    }
}

#[test]
fn below_a_settled_cell_the_product_follows_the_guide() {
    let mut next = uniform(21);
    let mut groups = 0;
    for seed in 1..=3 {
        let tree = random_sampling_tree(seed);
        for n in normals(&mut next) {
            // Within a settled cell, the product's density is the guide's times one factor.
            let mut factor = std::collections::HashMap::new();
            for c in final_cells(&tree, &ClampedCosine(n)) {
                let Some(key) = c.settled_at else { continue };
                let ratio =
                    f64::from(tree.pdf_surface(n, c.centre())) / f64::from(tree.pdf(c.centre()));
                let first = *factor.entry(key).or_insert(ratio);
                assert!(
                    (ratio / first - 1.0).abs() < 1e-5,
                    "seed {seed}, n = {n}, {key:?}: {ratio} vs {first}"
                );
            }
            groups += factor.len();
        }
    }
    assert!(groups > 10, "{groups} settled cells");
}

/// A random unit normal (not uniform over the sphere, which these tests do not need).
fn random_normal(next: &mut impl FnMut() -> f64) -> Vec3 {
    loop {
        let v = Vec3::new(next() as f32, next() as f32, next() as f32) * 2.0 - 1.0;
        if let Some(n) = v.try_normalize() {
            return n;
        }
    }
}

/// The axes, a diagonal, and two random normals.
fn normals(next: &mut impl FnMut() -> f64) -> Vec<Vec3> {
    let mut out = vec![Vec3::Z, -Vec3::Z, Vec3::X, Vec3::new(0.0, 0.6, -0.8)];
    out.extend([random_normal(next), random_normal(next)]);
    out
}

#[test]
fn the_product_integrates_to_one_and_pdf_is_each_cells_probability() {
    let mut next = uniform(13);
    for seed in 1..=3 {
        let tree = random_sampling_tree(seed);
        for n in normals(&mut next) {
            let cells = final_cells(&tree, &ClampedCosine(n));
            let total: f64 = cells.iter().map(|c| c.p).sum();
            assert!((total - 1.0).abs() < 1e-5, "seed {seed}, n = {n}: {total}");
            // The density `pdf` finds at each cell's centre, times the cell's area, is the
            // probability the descent gave it (so `pdf` integrates to 1 too).
            for c in &cells {
                let (cell, depth, p) = (c.cell, c.depth, c.p);
                let size = 0.5f32.powi(depth as i32);
                let mass = f64::from(tree.pdf_surface(n, c.centre())) * f64::from(size * size);
                // (The test trees' masses span 10⁻⁹ per level, so some densities are
                // `f32` subnormals, exact to an absolute 10⁻⁴⁵ only.)
                assert!(
                    (mass - p).abs() <= 1e-5 * p + 1e-38,
                    "{cell:?} at {depth}: {mass} vs {p}"
                );
                assert!(mass > 0.0 || p < 1e-38, "{cell:?} at {depth}");
            }
        }
    }
}

#[test]
fn the_product_samples_its_cells_chi_square() {
    let mut next = uniform(17);
    let tree = random_sampling_tree(2);
    for n in [Vec3::Z, Vec3::new(0.3, -0.8, 0.2).normalize()] {
        assert_samples_the_product(&tree, &ClampedCosine(n), &format!("n = {n}"), || {
            tree.sample_surface(n, Vec2::new(next() as f32, next() as f32))
                .0
        });
    }
}

#[test]
fn the_stored_product_samples_the_products_cells_chi_square() {
    let mut next = uniform(19);
    let tree = random_sampling_tree(2);
    for n in [Vec3::Z, Vec3::new(0.3, -0.8, 0.2).normalize()] {
        let stored = SurfaceTree::build(&tree, n).unwrap();
        assert_samples_the_product(&tree, &ClampedCosine(n), &format!("n = {n}"), || {
            stored.sample(Vec2::new(next() as f32, next() as f32)).0
        });
    }
}

#[test]
fn the_stored_product_is_the_per_query_product() {
    // At the centre of every final cell of the per-query product, the stored product has
    // the same density to f32 rounding (a few 10⁻⁷ per level, 16 levels at most), so it
    // integrates to 1 and is positive wherever the cosine is; and some of those cells are
    // reached through resumed descents.
    let mut next = uniform(31);
    let mut resumed = 0;
    for seed in 1..=3 {
        let tree = random_sampling_tree(seed);
        for n in normals(&mut next) {
            let stored = SurfaceTree::build(&tree, n).unwrap();
            resumed += stored
                .tree
                .nodes()
                .iter()
                .flat_map(|node| node.child)
                .filter(|&c| c == RESUME)
                .count();
            let cells = final_cells(&tree, &ClampedCosine(n));
            let total: f64 = cells
                .iter()
                .map(|c| {
                    let size = 0.5f64.powi(c.depth as i32);
                    f64::from(stored.pdf(c.centre())) * size * size
                })
                .sum();
            assert!((total - 1.0).abs() < 1e-4, "seed {seed}, n = {n}: {total}");
            for c in &cells {
                let (ours, theirs) = (stored.pdf(c.centre()), tree.pdf_surface(n, c.centre()));
                assert!(
                    (f64::from(ours) - f64::from(theirs)).abs() <= 1e-4 * f64::from(theirs) + 1e-38,
                    "seed {seed}, n = {n}, {:?} at {}: {ours} vs {theirs}",
                    c.cell,
                    c.depth
                );
            }
        }
    }
    assert!(resumed > 100, "{resumed} resumed leaves");
}

#[test]
fn stored_sample_returns_the_pdf_of_its_point() {
    let mut next = uniform(37);
    for seed in 1..=4 {
        let tree = random_sampling_tree(seed);
        for _ in 0..10 {
            let n = random_normal(&mut next);
            let stored = SurfaceTree::build(&tree, n).unwrap();
            for _ in 0..2000 {
                let u = Vec2::new(next() as f32, next() as f32);
                let (s, pdf, near, _) = stored.sample(u);
                assert!(pdf > 0.0 && pdf.is_finite(), "pdf {pdf}");
                if !near {
                    assert_eq!(stored.pdf(s).to_bits(), pdf.to_bits(), "u = {u}");
                }
            }
        }
    }
}

#[test]
fn surface_sample_returns_the_pdf_of_its_point() {
    let mut next = uniform(9);
    for seed in 1..=4 {
        let tree = random_sampling_tree(seed);
        for _ in 0..20 {
            let n = random_normal(&mut next);
            for _ in 0..2000 {
                let u = Vec2::new(next() as f32, next() as f32);
                let (s, pdf, near, _) = tree.sample_surface(n, u);
                assert!(pdf > 0.0 && pdf.is_finite(), "pdf {pdf}");
                if !near {
                    assert_eq!(tree.pdf_surface(n, s).to_bits(), pdf.to_bits(), "u = {u}");
                }
            }
        }
    }
}
