//! Scenes: shapes with materials, a camera, and the emitters with their sampling distribution.
//! The built-in scenes are made in code, so nothing is downloaded and a scene's description is
//! also its fingerprint (the stored reference images are checked against it).

use crate::bvh::Bvh;
use crate::geometry::{Ray, Shape};
use crate::material::{Material, luminance};
use crate::medium::{Media, Medium};
use glam::{Vec2, Vec3};

/// Longest path, in scattering events, unless the scene sets its own ([`Scene::max_depth`]).
pub const MAX_DEPTH: usize = 10;

/// A pinhole camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position.
    pub eye: Vec3,
    /// Point looked at.
    pub target: Vec3,
    /// Vertical field of view, degrees.
    pub fov_degrees: f32,
}

impl Camera {
    /// The primary ray through `film` (in `[0, 1]²`, y down) for an image of `aspect` = w/h.
    pub fn ray(&self, film: Vec2, aspect: f32) -> Ray {
        let forward = (self.target - self.eye).normalize();
        let right = forward.cross(Vec3::Y).normalize();
        let up = right.cross(forward);
        let h = (self.fov_degrees.to_radians() * 0.5).tan();
        let x = (2.0 * film.x - 1.0) * h * aspect;
        let y = (1.0 - 2.0 * film.y) * h;
        Ray {
            origin: self.eye,
            direction: (forward + right * x + up * y).normalize(),
            t_max: f32::INFINITY,
        }
    }
}

/// A scene ready to render.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The scene's name (one of [`scenes::BUILT_IN`](crate::scenes::BUILT_IN), or a test scene's).
    pub name: String,
    /// The shapes.
    pub shapes: Vec<Shape>,
    /// Material index of every shape.
    pub shape_material: Vec<u16>,
    /// The materials.
    pub materials: Vec<Material>,
    /// The camera.
    pub camera: Camera,
    /// Exposure applied before tone mapping (a scene property: how bright it is meant to look).
    pub exposure: f32,
    /// Whether paths rendered in it sample the lights at every vertex (next-event estimation,
    /// weighed by MIS against the scattering direction; on by default). Without it, light is
    /// found only by the paths' own directions: what a guide has to learn is then all of it.
    pub next_event: bool,
    /// The participating media (none by default): paths scatter in them, and next-event
    /// estimation is attenuated by their transmittance.
    pub media: Media,
    /// Longest path, in scattering events (surface and medium).
    pub max_depth: usize,
    bvh: Bvh,
    /// Emitting triangles, with the cumulative distribution that picks one ∝ area × luminance.
    lights: Vec<u32>,
    light_cdf: Vec<f32>,
    /// For every shape, the probability of picking it as a light (0 if it is not one).
    light_probability: Vec<f32>,
}

/// A surface hit.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    /// Distance along the ray.
    pub t: f32,
    /// Position.
    pub position: Vec3,
    /// Unit geometric normal of the shape (not flipped toward the ray).
    pub normal: Vec3,
    /// Shape index.
    pub shape: u32,
}

impl Hit {
    /// The normal on the side that `wo` (pointing away from the surface, toward the viewer)
    /// leaves from: the shading normal of the two-sided surfaces here.
    pub fn normal_toward(&self, wo: Vec3) -> Vec3 {
        if self.normal.dot(wo) >= 0.0 {
            self.normal
        } else {
            -self.normal
        }
    }
}

/// A point drawn on an emitter, seen from a shading point.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    /// Unit direction from the shading point to the light point.
    pub direction: Vec3,
    /// Distance to the light point.
    pub distance: f32,
    /// Emitted radiance toward the shading point.
    pub radiance: Vec3,
    /// Solid-angle pdf of `direction`.
    pub pdf: f32,
}

/// Builds scenes from quads and spheres.
#[derive(Default)]
pub struct SceneBuilder {
    shapes: Vec<Shape>,
    shape_material: Vec<u16>,
    materials: Vec<Material>,
    media: Media,
}

impl SceneBuilder {
    /// Registers a material, returning its index.
    pub fn material(&mut self, m: Material) -> u16 {
        self.materials.push(m);
        (self.materials.len() - 1) as u16
    }

    /// The quad `p, p + u, p + u + v, p + v` (two triangles); its normal is `u × v`.
    pub fn quad(&mut self, p: Vec3, u: Vec3, v: Vec3, material: u16) -> &mut Self {
        for shape in [
            Shape::Triangle {
                p0: p,
                e1: u,
                e2: u + v,
            },
            Shape::Triangle {
                p0: p,
                e1: u + v,
                e2: v,
            },
        ] {
            self.shapes.push(shape);
            self.shape_material.push(material);
        }
        self
    }

    /// An axis-aligned box `[lo, hi]`, its normals outward (or inward, for a closed room).
    pub fn cuboid(&mut self, lo: Vec3, hi: Vec3, inward: bool, material: u16) -> &mut Self {
        let d = hi - lo;
        let (x, y, z) = (Vec3::X * d.x, Vec3::Y * d.y, Vec3::Z * d.z);
        // (corner, u, v) with u × v pointing out of the box.
        let faces = [
            (lo, x, z),     // −y
            (lo + y, z, x), // +y
            (lo, z, y),     // −x
            (lo + x, y, z), // +x
            (lo, y, x),     // −z
            (lo + z, x, y), // +z
        ];
        for (p, u, v) in faces {
            if inward {
                self.quad(p, v, u, material);
            } else {
                self.quad(p, u, v, material);
            }
        }
        self
    }

    /// The box `[lo, hi]` filled with `medium` (its boundary does not refract; a shape there is
    /// added apart, if any).
    pub fn medium_box(&mut self, lo: Vec3, hi: Vec3, medium: Medium) -> &mut Self {
        self.media.boxes.push((lo, hi, medium));
        self
    }

    /// `medium` everywhere outside the medium boxes.
    pub fn global_medium(&mut self, medium: Medium) -> &mut Self {
        self.media.global = Some(medium);
        self
    }

    /// A sphere.
    pub fn sphere(&mut self, center: Vec3, radius: f32, material: u16) -> &mut Self {
        self.shapes.push(Shape::Sphere { center, radius });
        self.shape_material.push(material);
        self
    }

    /// The finished scene.
    pub fn build(mut self, name: &str, camera: Camera, exposure: f32) -> Scene {
        let bvh = Bvh::new(&self.shapes);
        let mut lights = Vec::new();
        let mut light_cdf = Vec::new();
        let mut total = 0.0;
        for (i, shape) in self.shapes.iter().enumerate() {
            let power = luminance(self.materials[self.shape_material[i] as usize].emission);
            if power > 0.0 && matches!(shape, Shape::Triangle { .. }) {
                total += power * shape.area();
                lights.push(i as u32);
                light_cdf.push(total);
            }
        }
        let mut light_probability = vec![0.0; self.shapes.len()];
        let mut previous = 0.0;
        for (c, &i) in light_cdf.iter_mut().zip(&lights) {
            light_probability[i as usize] = (*c - previous) / total;
            previous = *c;
            *c /= total;
        }
        if !self.media.is_empty() {
            self.media.bounds = self
                .shapes
                .iter()
                .map(Shape::bounds)
                .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), (a, b)| {
                    (lo.min(a), hi.max(b))
                });
        }
        Scene {
            name: name.to_string(),
            shapes: self.shapes,
            shape_material: self.shape_material,
            materials: self.materials,
            camera,
            exposure,
            next_event: true,
            media: self.media,
            max_depth: MAX_DEPTH,
            bvh,
            lights,
            light_cdf,
            light_probability,
        }
    }
}

impl Scene {
    /// The closest hit along `ray`.
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        let (t, shape) = self.bvh.intersect(&self.shapes, ray)?;
        let position = ray.at(t);
        Some(Hit {
            t,
            position,
            normal: self.shapes[shape as usize].normal(position),
            shape,
        })
    }

    /// Whether the segment `ray` (up to `ray.t_max`) is blocked.
    pub fn occluded(&self, ray: &Ray) -> bool {
        self.bvh.occluded(&self.shapes, ray)
    }

    /// The material of a hit.
    pub fn material(&self, hit: &Hit) -> &Material {
        &self.materials[self.shape_material[hit.shape as usize] as usize]
    }

    /// Radiance the hit surface emits toward `toward` (a unit direction away from it).
    pub fn emitted(&self, hit: &Hit, toward: Vec3) -> Vec3 {
        if hit.normal.dot(toward) > 0.0 {
            self.material(hit).emission
        } else {
            Vec3::ZERO
        }
    }

    /// Whether the scene has emitters to sample.
    pub fn has_lights(&self) -> bool {
        !self.lights.is_empty()
    }

    /// Draws a point on an emitter (one ∝ area × luminance, then uniform on its area) as seen
    /// from `x`; `None` if there is none or it faces away.
    pub fn sample_light(&self, x: Vec3, pick: f32, u: Vec2) -> Option<LightSample> {
        let k = self
            .light_cdf
            .partition_point(|&c| c <= pick)
            .min(self.lights.len().checked_sub(1)?);
        let index = self.lights[k] as usize;
        let Shape::Triangle { p0, e1, e2 } = self.shapes[index] else {
            return None;
        };
        let s = u.x.sqrt();
        let p = p0 + e1 * (s * (1.0 - u.y)) + e2 * (s * u.y);
        let d = p - x;
        let distance2 = d.length_squared();
        let distance = distance2.sqrt();
        let direction = d / distance;
        let cos_light = -self.shapes[index].normal(p).dot(direction);
        if cos_light <= 0.0 || distance2 <= 0.0 {
            return None;
        }
        let pdf_area = self.light_probability[index] / self.shapes[index].area();
        Some(LightSample {
            direction,
            distance,
            radiance: self.materials[self.shape_material[index] as usize].emission,
            pdf: pdf_area * distance2 / cos_light,
        })
    }

    /// The solid-angle pdf with which [`Scene::sample_light`] would have drawn the point `hit`
    /// from `x` (for multiple importance sampling of emitters hit by a scattered ray).
    pub fn light_pdf(&self, x: Vec3, hit: &Hit, direction: Vec3) -> f32 {
        let p = self.light_probability[hit.shape as usize];
        let cos_light = -hit.normal.dot(direction);
        if p == 0.0 || cos_light <= 0.0 {
            return 0.0;
        }
        p / self.shapes[hit.shape as usize].area() * (hit.position - x).length_squared() / cos_light
    }

    /// Bounds of all shapes.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.shapes.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), s| {
                let (l, h) = s.bounds();
                (lo.min(l), hi.max(h))
            },
        )
    }

    /// A 64-bit fingerprint of everything that decides the image (shapes, materials, camera),
    /// so a stored reference can be checked against the scene it claims to show.
    pub fn fingerprint(&self) -> u64 {
        let mut text = format!(
            "{:?}{:?}{:?}{:?}",
            self.shapes, self.shape_material, self.materials, self.camera
        );
        // Scenes without media keep the fingerprint they had before media existed.
        if !self.media.is_empty() || self.max_depth != MAX_DEPTH {
            text += &format!("{:?}{}", self.media, self.max_depth);
        }
        // FNV-1a.
        text.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
            (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3)
        })
    }
}
