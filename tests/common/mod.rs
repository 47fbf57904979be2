//! Helpers shared by the integration tests.
#![allow(dead_code)]

use glam::{Vec2, Vec3};
use sdguide::{DirectionalDistribution, GuidingConfig, GuidingField, LeafRule};
use sdguide_lab::synthetic::{LightField, Workload};

/// A field trained on the standard light with the given rule and maximum directional depth.
pub fn trained(rule: LeafRule, max_depth: u32, iterations: u32, first_budget: u64) -> GuidingField {
    let config = GuidingConfig {
        rule,
        max_directional_depth: max_depth,
        ..GuidingConfig::default()
    };
    let mut field = GuidingField::new(sdguide_lab::synthetic::room_bounds(), config).unwrap();
    Workload {
        light: LightField::standard(),
        lobe_noise: 1.0,
        seed: 11,
        bsdf: None,
    }
    .train(&mut field, iterations, first_budget);
    field
}

/// Midpoint quadrature of the distribution's density on the unit square over a `2^m × 2^m`
/// grid, returning the integral of each grid cell. When no leaf is deeper than `m`, every grid
/// cell lies inside one leaf and the rule is exact: the only error is `f32`/`f64` rounding.
pub fn cell_integrals(dist: &DirectionalDistribution<'_>, m: u32) -> Vec<f64> {
    let n = 1usize << m;
    let area = 1.0 / (n * n) as f64;
    let mut out = Vec::with_capacity(n * n);
    for j in 0..n {
        for i in 0..n {
            let s = Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
            let d = sdguide::sphere::square_to_direction(s);
            out.push(f64::from(dist.pdf(d)) * f64::from(sdguide::sphere::SPHERE_AREA) * area);
        }
    }
    out
}

/// The chi-square value with `dof` degrees of freedom exceeded with probability about
/// `Φ(-z)`, by the Wilson–Hilferty approximation.
pub fn chi_square_bound(dof: f64, z: f64) -> f64 {
    let a = 2.0 / (9.0 * dof);
    dof * (1.0 - a + z * a.sqrt()).powi(3)
}

/// Held-out query points: not on the room's surfaces the workload trains on, but inside it.
pub fn held_out_points() -> [Vec3; 3] {
    [
        Vec3::new(0.3, 0.02, 0.7),
        Vec3::new(0.6, 0.4, 0.02),
        Vec3::new(0.02, 0.8, 0.25),
    ]
}
