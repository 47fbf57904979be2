//! Tests of the directional box filter's shares: the shortcuts from the sample's leaf and the
//! deferred spreading against the walk from the root.

use super::*;
use crate::filter::DirectionalFilter;
use crate::quadtree::testing::{random_topology, random_tree, uniform};
use std::collections::{HashMap, HashSet};

#[test]
fn the_deferred_spread_hands_out_the_box_filter_shares() {
    // Spreading a leaf's pending sums part by part (the leaf's own part directly, each
    // neighbour's from the path) gives each leaf what the box filter's walk from the root
    // gives, for every quadrant: on trees where coarse leaves border fine ones, and across
    // the square's border, where the filter folds.
    for seed in 1..=8 {
        let tree = random_tree(seed);
        let leaves = tree.moments.len();
        assert!(leaves > 200, "seed {seed}: only {leaves} leaves");
        let sums: Vec<[(f64, f64); 4]> = tree.pending.iter().map(|p| p.take()).collect();
        let mut spread = vec![(0.0, 0.0); leaves];
        tree.spread_pending(|k| sums[k], &mut |k, (a, b)| {
            spread[k] = (spread[k].0 + a, spread[k].1 + b)
        });
        let mut walked = vec![(0.0, 0.0); leaves];
        tree.visit_leaves(|k, cell| {
            for (q, part) in sums[k].into_iter().enumerate() {
                let quadrant = cell.child(q);
                let centre = quadrant.origin + Vec2::splat(0.5 * quadrant.size);
                tree.splat_into(centre, f64::from(cell.size), part, &mut |j, (a, b)| {
                    walked[j] = (walked[j].0 + a, walked[j].1 + b)
                });
            }
        });
        let total: f64 = sums.iter().flatten().map(|s| s.0).sum();
        let total_sq: f64 = sums.iter().flatten().map(|s| s.1).sum();
        // Each share is a product of a few exact dyadic lengths and one weight, summed in
        // another order: equal within a few ulps of the total.
        for k in 0..leaves {
            assert!(
                (spread[k].0 - walked[k].0).abs() <= 1e-14 * total,
                "seed {seed}, {k}"
            );
            assert!(
                (spread[k].1 - walked[k].1).abs() <= 1e-14 * total_sq,
                "seed {seed}, {k}"
            );
        }
        let spread_total: f64 = spread.iter().map(|s| s.0).sum();
        assert!((spread_total - total).abs() <= 1e-12 * total);
    }
}

#[test]
fn recording_through_the_box_filter_hands_out_the_walks_shares() {
    // A sample's shares found from the chain of nodes above its leaf (the grid cut) are
    // what the box filter's walk from the root gives, and `record_box` adds them (and
    // counts the sample in its leaf and quadrant): at random points, at points a hair from
    // the grid lines of every level, and near the square's border and corners, where the
    // filter folds and a sample has the most shares.
    let mut overflowed = 0;
    for seed in 1..=8 {
        let mut next = uniform(100 + seed);
        let tree = RecordingTree::from_nodes(random_topology(&mut next), false);
        let leaves = tree.moments.len();
        let mut expected = vec![(0.0, 0.0, 0u64); leaves];
        let mut quadrants = vec![[0u64; 4]; leaves];
        let mut total = 0.0;
        for i in 0..4000 {
            let mut u = || match i % 4 {
                // Uniform.
                0 => next(),
                // Near the border: within a leaf's side or so of 0 or 1.
                1 => {
                    let e = next() * 2f64.powi(-(1 + (next() * 8.0) as i32));
                    if next() < 0.5 { e } else { 1.0 - e }
                }
                // A hair from a grid line of some level.
                _ => {
                    let level = 2f64.powi(1 + (next() * 8.0) as i32);
                    let line = (next() * level).floor() / level;
                    (line + (next() - 0.5) * 1e-6).clamp(0.0, 0.999_999)
                }
            };
            let s = Vec2::new(u() as f32, u() as f32);
            let w1 = 0.5 + next();
            let w = (w1, w1 * (1.0 + next()));
            let mut from_chain = Vec::new();
            let (k, q) = tree.box_shares(s, w, &mut |j, part| from_chain.push((j, part)));
            let (lk, depth, lq) = tree.locate(s);
            assert_eq!((k, q), (lk, lq), "seed {seed}, {s}");
            let mut walked = HashMap::new();
            tree.splat_into(s, cell_side(depth), w, &mut |j, (a, b)| {
                let e = walked.entry(j).or_insert((0.0, 0.0));
                *e = (e.0 + a, e.1 + b);
            });
            let mut chained = HashMap::new();
            for &(j, (a, b)) in &from_chain {
                let e = chained.entry(j).or_insert((0.0, 0.0));
                *e = (e.0 + a, e.1 + b);
            }
            overflowed += usize::from(from_chain.len() > Shares::CAP);
            assert_eq!(
                walked.keys().collect::<HashSet<_>>(),
                chained.keys().collect::<HashSet<_>>(),
                "seed {seed}, {s}"
            );
            // Products of exact dyadic lengths and one weight, summed in another order.
            for (j, a) in &walked {
                let b = chained[j];
                assert!(
                    (a.0 - b.0).abs() <= 1e-14 * w.0,
                    "seed {seed}, {s}, leaf {j}"
                );
                assert!(
                    (a.1 - b.1).abs() <= 1e-14 * w.1,
                    "seed {seed}, {s}, leaf {j}"
                );
                expected[*j].0 += b.0;
                expected[*j].1 += b.1;
            }
            let sum: f64 = from_chain.iter().map(|(_, (a, _))| a).sum();
            assert!((sum - w.0).abs() <= 1e-12 * w.0, "seed {seed}, {s}");
            expected[k].2 += 1;
            quadrants[k][q] += 1;
            total += w.0;
            tree.record(DirectionalFilter::Box, s, w, true);
        }
        for (j, e) in expected.iter().enumerate() {
            let m = tree.moments_of(j);
            assert!(
                (m.sum - e.0).abs() <= 1e-12 * total,
                "seed {seed}, leaf {j}"
            );
            assert!(
                (m.sum_sq - e.1).abs() <= 1e-12 * total,
                "seed {seed}, leaf {j}"
            );
            assert_eq!(m.count, e.2, "seed {seed}, leaf {j}");
            let counts = tree.quadrants[j].get().map(|(_, n)| n);
            assert_eq!(counts, quadrants[j], "seed {seed}, leaf {j}");
        }
    }
    // Some samples had more shares than `Shares` holds, and took the direct adds.
    assert!(overflowed > 0);
}

#[test]
fn the_interior_cut_gives_the_general_cuts_shares_to_the_bit() {
    // Where the square stays inside the unit square, the shortcut hands out the shares the
    // general cut does, to the bit (the same lengths, products and leaves): at random points,
    // a hair from grid lines of every level, and exactly on a leaf's midline (where the square
    // ends on the leaf's side and one axis is not cut). Where it leaves the square the shortcut
    // declines and adds nothing.
    let (mut checked, mut declined) = (0, 0);
    for seed in 1..=8 {
        let mut next = uniform(200 + seed);
        let tree = RecordingTree::from_nodes(random_topology(&mut next), false);
        for i in 0..4000 {
            let mut u = || {
                let level = 2f64.powi(1 + (next() * 8.0) as i32);
                let line = (next() * level).floor() / level;
                match i % 3 {
                    0 => next(),
                    1 => (line + (next() - 0.5) * 1e-6).clamp(0.0, 0.999_999),
                    _ => line + 0.5 / level,
                }
            };
            let s = Vec2::new(u() as f32, u() as f32);
            let p = fixed(s);
            let mut chain = Ancestry::new(p);
            let (_, depth, _) = tree.descend(p, |d, node| chain.nodes[d as usize] = node);
            chain.depth = depth;
            let centre = [f64::from(s.x), f64::from(s.y)];
            let w = (0.5 + next(), 1.0 + next());
            let bits = |(a, b): (f64, f64)| (a.to_bits(), b.to_bits());
            let mut fast = Vec::new();
            let Some(own) =
                tree.spread_interior(&chain, centre, w, &mut |k, part| fast.push((k, bits(part))))
            else {
                assert!(fast.is_empty(), "seed {seed}, {s}");
                declined += 1;
                continue;
            };
            let mut general = Vec::new();
            let general_own = tree.spread_folded(&chain, centre, w, &mut |k, part| {
                general.push((k, bits(part)))
            });
            fast.sort_unstable();
            general.sort_unstable();
            assert_eq!(fast, general, "seed {seed}, {s}");
            assert_eq!(bits(own), bits(general_own), "seed {seed}, {s}");
            checked += 1;
        }
    }
    assert!(
        checked > 20_000 && declined > 1000,
        "{checked} checked, {declined} declined"
    );
}
