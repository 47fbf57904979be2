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

/// The section table of a cache: (kind, flags, offset, length).
pub fn sections(bytes: &[u8]) -> Vec<(u32, u32, u64, u64)> {
    let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
    let u64_at = |o: usize| u64::from_le_bytes(bytes[o..o + 8].try_into().unwrap());
    (0..u32_at(16) as usize)
        .map(|k| {
            let e = 32 + 24 * k;
            (u32_at(e), u32_at(e + 4), u64_at(e + 8), u64_at(e + 16))
        })
        .collect()
}

/// Rebuilds a cache from a version and sections, with a correct length and checksum: how a
/// newer writer, or a forger, would.
pub fn assemble(version: (u16, u16), parts: &[(u32, u32, Vec<u8>)]) -> Vec<u8> {
    let table_end = 32 + 24 * parts.len();
    let total = table_end + parts.iter().map(|p| p.2.len()).sum::<usize>() + 4;
    let mut out = sdguide::MAGIC.to_vec();
    out.extend_from_slice(&version.0.to_le_bytes());
    out.extend_from_slice(&version.1.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&(parts.len() as u32).to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&(total as u64).to_le_bytes());
    let mut offset = table_end as u64;
    for (kind, flags, body) in parts {
        out.extend_from_slice(&kind.to_le_bytes());
        out.extend_from_slice(&flags.to_le_bytes());
        out.extend_from_slice(&offset.to_le_bytes());
        out.extend_from_slice(&(body.len() as u64).to_le_bytes());
        offset += body.len() as u64;
    }
    for (_, _, body) in parts {
        out.extend_from_slice(body);
    }
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

/// The sections of a real cache as (kind, flags, body).
pub fn parts(bytes: &[u8]) -> Vec<(u32, u32, Vec<u8>)> {
    sections(bytes)
        .into_iter()
        .map(|(k, f, o, l)| (k, f, bytes[o as usize..(o + l) as usize].to_vec()))
        .collect()
}
