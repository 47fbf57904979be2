//! Tests of `sampling`.

use super::*;
use crate::quadtree::testing::{assert_chi_square, random_sampling_tree, random_topology, uniform};

#[test]
fn leaf_count_and_depth_match_the_listed_leaves() {
    for seed in 0..20 {
        let tree = random_sampling_tree(seed);
        let leaves = tree.leaves();
        let deepest = leaves.iter().map(|(c, _)| c.depth).max().unwrap();
        assert_eq!(
            tree.leaf_count_and_depth(),
            (leaves.len(), deepest),
            "seed {seed}"
        );
    }
    assert_eq!(SamplingTree::uniform().leaf_count_and_depth(), (4, 1));
}

/// The density at `s` by the tree's levels: the product of the conditionals from the root,
/// and the leaf's depth.
fn density_by_levels(t: &SamplingTree, s: Vec2) -> (f32, u32) {
    let p = fixed(s);
    let (mut pdf, mut node, mut depth) = (1.0f32, 0usize, 1);
    loop {
        let n = t.node(node);
        let (ix, iy) = quadrant_bits(p, depth);
        pdf *= n.density_factor(ix, iy);
        match n.child[ix | iy << 1] {
            NO_CHILD => return (pdf, depth),
            c => node = usize::from(c),
        }
        depth += 1;
    }
}

#[test]
fn the_grid_holds_each_cells_density() {
    // The grid's densities are each leaf's mass in `f64`, rounded once; the levels' product
    // rounds at most three times a level (eight levels): within 4·10⁻⁶ of each other.
    for seed in 1..=4 {
        let tree = random_sampling_tree(seed);
        let mut next = uniform(seed + 200);
        for _ in 0..100_000 {
            let s = Vec2::new(next() as f32, next() as f32);
            let (expected, depth) = density_by_levels(&tree, s);
            let pdf = tree.pdf(s);
            assert!(
                (pdf - expected).abs() <= 4e-6 * expected,
                "seed {seed}, s = {s}, depth {depth}: {pdf} against {expected}"
            );
        }
    }
}

#[test]
fn sample_draws_each_leaf_with_its_probability_and_returns_its_density() {
    // The grid picks a row and a cell by cumulative tables, and a cell the tree splits
    // further goes on by cuts relative to the cell: together they must draw each leaf with
    // its probability, put the point in it, and return the density `pdf` finds there.
    // Masses within a factor of five of each other, so that most leaves expect enough
    // draws to be bins of their own.
    let draws = 1_000_000u64;
    for seed in 1..=3 {
        let mut next = uniform(seed);
        let nodes = random_topology(&mut next)
            .iter()
            .map(|slots| {
                let masses = [(); 4].map(|_| 0.2 + 0.8 * next());
                SamplingNode::from_masses(masses, slots.map(|s| s as u16))
            })
            .collect();
        let tree = SamplingTree::new(nodes);
        assert!(
            tree.node_count() > 60,
            "seed {seed}: {} nodes",
            tree.node_count()
        );
        let leaves = tree.leaves();
        let index: std::collections::HashMap<(u32, [u32; 2]), usize> = leaves
            .iter()
            .enumerate()
            .map(|(i, (c, _))| {
                let at = (c.origin / c.size).round();
                ((c.depth, [at.x as u32, at.y as u32]), i)
            })
            .collect();
        let mut observed = vec![0u64; leaves.len()];
        let mut next = uniform(seed + 100);
        for _ in 0..draws {
            let u = Vec2::new(next() as f32, next() as f32);
            let (s, pdf, near) = tree.sample(u);
            let (expected, depth) = density_by_levels(&tree, s);
            let p = fixed(s);
            let shift = FIXED_BITS - depth;
            let leaf = index[&(depth, [p[0] >> shift, p[1] >> shift])];
            observed[leaf] += 1;
            if !near {
                assert_eq!(tree.pdf(s), pdf, "u = {u}");
                assert!((pdf - expected).abs() <= 4e-6 * expected, "u = {u}");
            }
        }
        let expected: Vec<f64> = leaves.iter().map(|&(_, m)| f64::from(m)).collect();
        assert_chi_square(&observed, &expected, draws, 150, &format!("seed {seed}"));
    }
}

#[test]
fn parts_of_probability_zero_are_never_drawn() {
    // A root whose right column and whose lower-left cell have mass zero: every draw lands
    // in the upper-left quadrant, even for `u` at the top of the range, where rounding
    // of the interval's end could otherwise pass a cut.
    let tree = SamplingTree::new(Box::new([SamplingNode::from_masses(
        [0.0, 0.0, 3.0, 0.0],
        [NO_CHILD; 4],
    )]));
    let mut next = uniform(5);
    let edges = [0.0, 0.5, ONE_MINUS_EPSILON, 1.0];
    for k in 0..10_000 {
        let u = if k < 16 {
            Vec2::new(edges[k % 4], edges[k / 4])
        } else {
            Vec2::new(next() as f32, next() as f32)
        };
        let (s, pdf, _) = tree.sample(u);
        assert!(s.x < 0.5 && s.y >= 0.5, "u = {u}: {s}");
        assert_eq!(pdf, 4.0);
    }
    assert_eq!(tree.pdf(Vec2::new(0.7, 0.2)), 0.0);
}

#[test]
fn node_is_half_a_cache_line() {
    assert_eq!(std::mem::size_of::<SamplingNode>(), 32);
}

#[test]
fn uniform_tree_has_constant_density() {
    let t = SamplingTree::uniform();
    for s in [Vec2::ZERO, Vec2::new(0.7, 0.2), Vec2::splat(0.99)] {
        assert_eq!(t.pdf(s), 1.0);
    }
    let (p, pdf, near_border) = t.sample(Vec2::new(0.3, 0.8));
    assert_eq!(pdf, 1.0);
    assert!(!near_border);
    assert!((p - Vec2::new(0.3, 0.8)).abs().max_element() < 1e-6);
}
