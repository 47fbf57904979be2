//! A minimal guided path tracer, wired from the README alone: no next-event estimation, no
//! roulette (paths end at 10 bounces), the guide sampled times the cosine in the one-sample
//! mixture with the BSDF, every camera sample recorded through the path recorder. It renders
//! the demo's `covered` scene (its lamp hidden above a panel) unguided and guided at the same
//! samples per pixel and compares both with the stored reference:
//!
//! ```sh
//! cargo run --release -p sdguide-render --example minimal -- [SEED]
//! ```
//!
//! It exits with an error unless the guided render's relMSE is at most a quarter of the
//! unguided one's and both means lie within 3 standard errors of the reference's.

use rayon::prelude::*;
use sdguide::glam::{Vec2, Vec3};
use sdguide::{Aabb, GuidingConfig, GuidingField, PathRecorder, PathVertex};
use sdguide_render::geometry::{Frame, Ray};
use sdguide_render::image::Image;
use sdguide_render::rng::Rng;
use sdguide_render::scene::Scene;
use sdguide_render::{reference, scenes};

const MAX_DEPTH: usize = 10;
const WIDTH: usize = 320;
const HEIGHT: usize = 240;
/// Samples per pixel of the final renders; training takes 1 + 2 + … + 32 = 63 more.
const SPP: u32 = 64;

/// One camera sample along `ray`: its radiance, recorded into `field` when `train`.
fn radiance(
    scene: &Scene,
    guide: Option<(&GuidingField, bool)>,
    path: &mut PathRecorder,
    mut ray: Ray,
    rng: &mut Rng,
) -> Vec3 {
    let mut v = path.start(); // the camera ray
    for depth in 0..=MAX_DEPTH {
        let Some(hit) = scene.intersect(&ray) else {
            break;
        };
        let wo = -ray.direction;
        // Emission along the ray arrives at the vertex that drew it (no light sampling: no
        // MIS weight).
        path.add_radiance(v, scene.emitted(&hit, wo));
        if depth == MAX_DEPTH {
            break;
        }
        let material = scene.material(&hit);
        // The normal facing the side the path arrived from (the scene's quads are two-sided).
        let n = hit.normal_toward(wo);
        let frame = Frame::new(n);
        if material.is_dielectric() {
            break; // `covered` has no glass; a renderer with some pushes a delta vertex
        }
        let (wo_local, train) = (frame.to_local(wo), guide.is_some_and(|(_, t)| t));
        // The guide times the cosine about the shading normal, and its learned probability.
        let dist = guide.map(|(f, _)| f.distribution(hit.position).at_surface(n));
        let a = dist.as_ref().map_or(0.0, |d| d.guide_probability());
        // Where the probability is 0 the field turned the guide off: sample the BSDF alone,
        // but while training still evaluate the guide's pdf, so the cell can learn it pays.
        let dist = dist.filter(|_| a > 0.0 || train);
        let (choice, lobe, u) = (rng.next_f32(), rng.next_f32(), rng.next_vec2());
        let (direction, guide_pdf) = match &dist {
            Some(d) if choice < a => d.sample(u),
            _ => match material.sample(wo_local, lobe, u) {
                Some(s) => {
                    let d = frame.to_world(s.wi);
                    (d, dist.as_ref().map_or(0.0, |g| g.pdf(d)))
                }
                None => break,
            },
        };
        let wi = frame.to_local(direction);
        let bsdf = material.eval(wo_local, wi) * wi.z.abs(); // 0 below the surface
        let bsdf_pdf = material.pdf(wo_local, wi);
        let q = a * guide_pdf + (1.0 - a) * bsdf_pdf; // the mixture pdf
        if q <= 0.0 {
            break;
        }
        // Push every direction drawn, below the surface too (it records value 0).
        let vertex = PathVertex::new(hit.position, direction, bsdf, q)
            .with_normal(n)
            .with_mixture(bsdf_pdf, guide_pdf);
        v = path.push(v, vertex);
        if bsdf == Vec3::ZERO {
            break;
        }
        ray = Ray::leaving(hit.position, hit.normal, direction, f32::INFINITY);
    }
    let l = path.finish();
    if let Some((field, true)) = guide {
        path.record(field);
    }
    l
}

/// `spp` samples per pixel (pass `pass`, seed `seed`), recorded into the field when `train`.
fn render(
    scene: &Scene,
    guide: Option<(&GuidingField, bool)>,
    spp: u32,
    (seed, pass): (u64, u64),
) -> Image {
    let mut image = Image::new(WIDTH, HEIGHT);
    let aspect = WIDTH as f32 / HEIGHT as f32;
    image
        .pixels
        .par_chunks_mut(WIDTH)
        .enumerate()
        .for_each_init(PathRecorder::new, |path, (y, row)| {
            for (x, pixel) in row.iter_mut().enumerate() {
                let index = (y * WIDTH + x) as u64;
                let mut rng = Rng::new(seed ^ (pass << 32 | index)); // a stream per pixel and pass
                for _ in 0..spp {
                    let film = (Vec2::new(x as f32, y as f32) + rng.next_vec2())
                        / Vec2::new(WIDTH as f32, HEIGHT as f32);
                    let ray = scene.camera.ray(film, aspect);
                    *pixel += radiance(scene, guide, path, ray, &mut rng) / spp as f32;
                }
            }
        });
    image
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let seed: u64 = std::env::args().nth(1).map_or(Ok(1), |s| s.parse())?;
    let seed = Rng::new(seed).next_u64();
    let scene = scenes::covered();
    let (truth, _) = reference::load(&reference::directory(), &scene, WIDTH, HEIGHT, seed)?;

    // Train: passes of 1, 2, 4, … 32 spp, refining between (budgets doubling).
    let (lo, hi) = scene.bounds();
    let mut field = GuidingField::new(Aabb::new(lo, hi), GuidingConfig::default())?;
    for k in 0..6 {
        render(&scene, Some((&field, true)), 1 << k, (seed, 100 + k));
        field.refine();
    }
    // The final renders, the field frozen.
    let guided = render(&scene, Some((&field, false)), SPP, (seed, 1));
    let unguided = render(&scene, None, SPP, (seed, 2));

    let (g, u) = (guided.rel_mse(&truth), unguided.rel_mse(&truth));
    let (zg, zu) = (
        guided.mean_deviation(&truth),
        unguided.mean_deviation(&truth),
    );
    println!("covered, {SPP} spp, no next-event estimation, no roulette");
    println!("unguided  relMSE {u:.4}  mean vs reference {zu:+.2} σ");
    println!("guided l2 relMSE {g:.4}  mean vs reference {zg:+.2} σ");
    println!("guided / unguided per sample: {:.3}", g / u);
    let rejected = field.stats().rejected.total();
    if g > 0.25 * u || zg.abs() > 3.0 || zu.abs() > 3.0 || rejected > 0 {
        return Err(format!("claim not met (rejected samples: {rejected})").into());
    }
    Ok(())
}
