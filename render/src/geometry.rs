//! Rays, the two shapes the scenes are made of (triangles and spheres), and a shading frame.

use glam::Vec3;

/// A ray `origin + t·direction`, `t` in `(t_min, t_max)`; `direction` is unit length.
#[derive(Clone, Copy, Debug)]
pub struct Ray {
    /// Where the ray starts.
    pub origin: Vec3,
    /// Unit direction.
    pub direction: Vec3,
    /// Farthest distance of interest.
    pub t_max: f32,
}

/// How far [`Ray::leaving`] pushes a ray's origin off its surface.
pub const SURFACE_OFFSET: f32 = 1e-4;

/// Distance below which a hit is taken for self-intersection.
pub const T_MIN: f32 = 1e-4;

impl Ray {
    /// A ray leaving a surface point `p` with geometric normal `n` in `direction`: the origin is
    /// pushed off the surface to the side the ray goes.
    pub fn leaving(p: Vec3, n: Vec3, direction: Vec3, t_max: f32) -> Self {
        let offset = if n.dot(direction) >= 0.0 { n } else { -n };
        Ray {
            origin: p + offset * SURFACE_OFFSET,
            direction,
            t_max,
        }
    }

    /// The shadow ray from a surface point `p` (geometric normal `n`) toward a point `distance`
    /// away along `direction`: it leaves `p` as [`Ray::leaving`] does, is aimed again from
    /// there at the target, and stops short of it, so neither surface blocks it.
    ///
    /// Aimed again, because an origin pushed off along `n` with the direction kept meets the
    /// target's plane earlier by up to `SURFACE_OFFSET / |cos θ_L|` (`θ_L` the angle at the
    /// target): a light that faces the receiver across a short, grazing gap (a ceiling over an
    /// upward-facing lamp) would block half its own shadow rays. From the new origin the
    /// target is exactly `|target − origin|` away, and the segment ends a relative 10⁻⁴ and
    /// [`SURFACE_OFFSET`] before it.
    pub fn shadow(p: Vec3, n: Vec3, direction: Vec3, distance: f32) -> Self {
        let origin = Ray::leaving(p, n, direction, 0.0).origin;
        let to_target = p + direction * distance - origin;
        let length = to_target.length();
        if length.is_nan() || length <= 0.0 {
            return Ray {
                origin,
                direction,
                t_max: 0.0,
            };
        }
        Ray {
            origin,
            direction: to_target / length,
            t_max: length * (1.0 - 1e-4) - SURFACE_OFFSET,
        }
    }

    /// The point at distance `t`.
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.direction * t
    }
}

/// A shape: a triangle (stored as a vertex and two edges) or a sphere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// Triangle `p0, p0 + e1, p0 + e2`; its normal is `normalize(e1 × e2)` (emitters emit on
    /// that side).
    Triangle {
        /// First vertex.
        p0: Vec3,
        /// Edge to the second vertex.
        e1: Vec3,
        /// Edge to the third vertex.
        e2: Vec3,
    },
    /// Sphere.
    Sphere {
        /// Centre.
        center: Vec3,
        /// Radius.
        radius: f32,
    },
}

impl Shape {
    /// Distance to the first hit in `(T_MIN, ray.t_max)`, if any.
    pub fn intersect(&self, ray: &Ray) -> Option<f32> {
        match *self {
            // Möller–Trumbore.
            Shape::Triangle { p0, e1, e2 } => {
                let pv = ray.direction.cross(e2);
                let det = e1.dot(pv);
                if det.abs() < 1e-12 {
                    return None;
                }
                let inv = 1.0 / det;
                let tv = ray.origin - p0;
                let u = tv.dot(pv) * inv;
                if !(0.0..=1.0).contains(&u) {
                    return None;
                }
                let qv = tv.cross(e1);
                let v = ray.direction.dot(qv) * inv;
                if v < 0.0 || u + v > 1.0 {
                    return None;
                }
                let t = e2.dot(qv) * inv;
                (t > T_MIN && t < ray.t_max).then_some(t)
            }
            Shape::Sphere { center, radius } => {
                let oc = ray.origin - center;
                let b = oc.dot(ray.direction);
                let c = oc.length_squared() - radius * radius;
                let disc = b * b - c;
                if disc < 0.0 {
                    return None;
                }
                let s = disc.sqrt();
                [-b - s, -b + s]
                    .into_iter()
                    .find(|&t| t > T_MIN && t < ray.t_max)
            }
        }
    }

    /// Unit geometric normal at a point `p` on the shape (outward for spheres).
    pub fn normal(&self, p: Vec3) -> Vec3 {
        match *self {
            Shape::Triangle { e1, e2, .. } => e1.cross(e2).normalize(),
            Shape::Sphere { center, .. } => (p - center).normalize(),
        }
    }

    /// Surface area.
    pub fn area(&self) -> f32 {
        match *self {
            Shape::Triangle { e1, e2, .. } => 0.5 * e1.cross(e2).length(),
            Shape::Sphere { radius, .. } => 4.0 * std::f32::consts::PI * radius * radius,
        }
    }

    /// Axis-aligned bounds `(min, max)`.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        match *self {
            Shape::Triangle { p0, e1, e2 } => {
                let (p1, p2) = (p0 + e1, p0 + e2);
                (p0.min(p1).min(p2), p0.max(p1).max(p2))
            }
            Shape::Sphere { center, radius } => (center - radius, center + radius),
        }
    }
}

/// An orthonormal frame around a normal `n` (Duff et al. 2017): local `z` is `n`.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    s: Vec3,
    t: Vec3,
    n: Vec3,
}

impl Frame {
    /// The frame's `z` axis.
    pub fn normal(&self) -> Vec3 {
        self.n
    }

    /// The frame whose `z` axis is the unit vector `n`.
    pub fn new(n: Vec3) -> Self {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        Frame {
            s: Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
            t: Vec3::new(b, sign + n.y * n.y * a, -n.y),
            n,
        }
    }

    /// World → local.
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }

    /// Local → world.
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.s * v.x + self.t * v.y + self.n * v.z
    }
}
