//! Probes of a trained field: at the first surface seen through a few pixels, where the guide
//! sends its samples — below the surface (wasted: every material here only reflects) and
//! straight to an emitter — with the plain distribution and with its product with the clamped
//! cosine (`at_surface`), which the integrator samples.

use crate::geometry::Ray;
use crate::rng::Rng;
use crate::scene::Scene;
use glam::{Vec2, Vec3};
use sdguide::GuidingField;

/// What one probe found.
#[derive(Clone, Copy, Debug)]
pub struct Probe {
    /// The film point the probe's camera ray went through (`[0, 1]²`, y down).
    pub film: Vec2,
    /// The surface point it hit, and the shading normal there (facing the camera).
    pub position: Vec3,
    /// The shading normal.
    pub normal: Vec3,
    /// Share of the plain distribution's draws below the surface.
    pub plain_below: f64,
    /// Share of the surface-aware distribution's draws below the surface.
    pub surface_below: f64,
    /// Share of the plain distribution's draws whose ray reaches an emitter directly.
    pub plain_to_light: f64,
    /// The same for the surface-aware distribution.
    pub surface_to_light: f64,
}

/// The film points probed: a 3 × 3 grid over the image.
pub const FILM: [f32; 3] = [0.2, 0.5, 0.8];

/// Probes `field` at the first hits through the [`FILM`] grid, with `draws` draws per
/// distribution and point (fixed seed). Film points that see no surface are skipped.
pub fn probe(scene: &Scene, field: &GuidingField, aspect: f32, draws: u32) -> Vec<Probe> {
    let mut rng = Rng::new(0x5eed);
    let mut out = Vec::new();
    for &y in &FILM {
        for &x in &FILM {
            let film = Vec2::new(x, y);
            let ray = scene.camera.ray(film, aspect);
            let Some(hit) = scene.intersect(&ray) else {
                continue;
            };
            let normal = hit.normal_toward(-ray.direction);
            let plain = field.distribution(hit.position);
            let surface = plain.at_surface(normal);
            let (mut below, mut light) = ([0u32; 2], [0u32; 2]);
            for _ in 0..draws {
                let u = rng.next_vec2();
                for (k, d) in [plain.sample(u).0, surface.sample(u).0]
                    .into_iter()
                    .enumerate()
                {
                    if d.dot(normal) <= 0.0 {
                        below[k] += 1;
                        continue;
                    }
                    let next = Ray::leaving(hit.position, hit.normal, d, f32::INFINITY);
                    let lit = scene
                        .intersect(&next)
                        .is_some_and(|h| scene.emitted(&h, -d) != Vec3::ZERO);
                    light[k] += u32::from(lit);
                }
            }
            let share = |c: u32| f64::from(c) / f64::from(draws);
            out.push(Probe {
                film,
                position: hit.position,
                normal,
                plain_below: share(below[0]),
                surface_below: share(below[1]),
                plain_to_light: share(light[0]),
                surface_to_light: share(light[1]),
            });
        }
    }
    out
}
