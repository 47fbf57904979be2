use glam::{Vec2, Vec3};
use sdguide::synthetic::{LightField, Rng, Workload, room_bounds, room_point};
use sdguide::{GuidingConfig, GuidingField};
use std::hint::black_box;
use std::time::Instant;
fn main() {
    let mut field = GuidingField::new(room_bounds(), GuidingConfig::default()).unwrap();
    Workload {
        light: LightField::standard(),
        seed: 1,
    }
    .train(&mut field, 5, 200_000);
    let mut rng = Rng::new(3);
    let n = 1 << 16;
    let q: Vec<(Vec3, Vec2, Vec3)> = (0..n)
        .map(|_| {
            (
                room_point([rng.next_f32(), rng.next_f32(), rng.next_f32()]),
                rng.next_vec2(),
                sdguide::sphere::square_to_direction(rng.next_vec2()),
            )
        })
        .collect();
    let dist = field.distribution(Vec3::new(0.5, 0.0, 0.5));
    println!("depth {}", field.stats().directional_depth);
    for _ in 0..3 {
        let t = Instant::now();
        let mut acc = 0.0;
        for _ in 0..20 {
            for &(_, u, _) in &q {
                acc += dist.sample(black_box(u)).1;
            }
        }
        let s = t.elapsed().as_nanos() as f64 / (20 * n) as f64;
        let t = Instant::now();
        for _ in 0..20 {
            for &(_, _, d) in &q {
                acc += dist.pdf(black_box(d));
            }
        }
        let p = t.elapsed().as_nanos() as f64 / (20 * n) as f64;
        let t = Instant::now();
        for _ in 0..20 {
            for &(_, _, d) in &q {
                acc += sdguide::sphere::direction_to_square(black_box(d)).x;
            }
        }
        let m = t.elapsed().as_nanos() as f64 / (20 * n) as f64;
        let t = Instant::now();
        for _ in 0..20 {
            for &(_, u, _) in &q {
                acc += sdguide::sphere::square_to_direction(black_box(u)).x;
            }
        }
        let m2 = t.elapsed().as_nanos() as f64 / (20 * n) as f64;
        println!(
            "sample {s:.1} ns  pdf {p:.1} ns  dir->square {m:.1} ns  square->dir {m2:.1} ns {acc}"
        );
    }
}
