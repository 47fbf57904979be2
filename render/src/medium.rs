//! Participating media: homogeneous and grey, inside axis-aligned boxes (closed shapes whose
//! boundary does not refract: the medium changes, the ray goes straight on) and one global
//! medium filling the rest of the scene; and the Henyey–Greenstein phase function they scatter
//! by.
//!
//! Along a ray the media are piecewise constant, so free flights are sampled and transmittance
//! evaluated exactly, segment by segment: a free flight is drawn with density `σ_t(t)·T(t)`
//! (`T` the transmittance from the ray's origin), so a scattering event weighs `σ_s/σ_t`, the
//! medium's albedo, and a ray that reaches its surface weighs 1 (the probability of getting
//! there is `T`, which is what the surface's light is attenuated by).

use crate::geometry::Ray;
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// A homogeneous, grey medium.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Medium {
    /// Extinction coefficient `σ_t` (per metre).
    pub sigma_t: f32,
    /// Single-scattering albedo `σ_s/σ_t`, in `[0, 1]`.
    pub albedo: f32,
    /// The Henyey–Greenstein asymmetry `g`, in `(−1, 1)`: positive scatters forward.
    pub g: f32,
}

/// Most medium boxes a scene has (the walk along a ray keeps their crossings on the stack).
pub const MAX_BOXES: usize = 4;

/// A scene's media: boxes (the last one holding a point wins) and a global medium elsewhere
/// inside the scene's bounds (outside them, where a ray that slipped through a crack between
/// shapes would go on forever, is vacuum).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Media {
    /// The medium outside every box; `None`: vacuum.
    pub global: Option<Medium>,
    /// Boxes `[lo, hi]` filled with a medium, at most [`MAX_BOXES`].
    pub boxes: Vec<(Vec3, Vec3, Medium)>,
    /// The scene's bounds, which the global medium fills.
    pub bounds: (Vec3, Vec3),
}

/// A point where a free flight ends inside a medium.
#[derive(Clone, Copy, Debug)]
pub struct Scatter {
    /// Distance along the ray.
    pub t: f32,
    /// The medium there.
    pub medium: Medium,
}

impl Media {
    /// Whether the scene has any medium.
    pub fn is_empty(&self) -> bool {
        self.global.is_none() && self.boxes.is_empty()
    }

    /// The medium at `p`, if any.
    pub fn at(&self, p: Vec3) -> Option<Medium> {
        let inside = |lo: Vec3, hi: Vec3| p.cmpge(lo).all() && p.cmple(hi).all();
        self.boxes
            .iter()
            .rev()
            .find(|(lo, hi, _)| inside(*lo, *hi))
            .map(|&(_, _, m)| m)
            .or(self.global.filter(|_| inside(self.bounds.0, self.bounds.1)))
    }

    /// Calls `f(t0, t1, medium)` for the segments of `[0, t_max)` along `ray` over which the
    /// medium is constant, in order, until `f` returns `true` (found).
    fn walk(&self, ray: &Ray, t_max: f32, mut f: impl FnMut(f32, f32, Option<Medium>) -> bool) {
        // The boxes' crossings cut the ray into segments; each segment's medium is the one at
        // its middle.
        let mut cuts = [0.0f32; 2 * MAX_BOXES + 4];
        let mut n = 1;
        let bounds = std::iter::once(self.bounds).filter(|_| self.global.is_some());
        let boxes = self
            .boxes
            .iter()
            .take(MAX_BOXES)
            .map(|&(lo, hi, _)| (lo, hi));
        let inv = ray.direction.recip();
        for (lo, hi) in boxes.chain(bounds) {
            let (a, b) = ((lo - ray.origin) * inv, (hi - ray.origin) * inv);
            let (near, far) = (a.min(b).max_element(), a.max(b).min_element());
            for t in [near, far] {
                if t > 0.0 && t < t_max {
                    cuts[n] = t;
                    n += 1;
                }
            }
        }
        cuts[n] = t_max;
        n += 1;
        let cuts = &mut cuts[..n];
        cuts.sort_unstable_by(f32::total_cmp);
        for w in cuts.windows(2) {
            let (t0, t1) = (w[0], w[1]);
            if t1 <= t0 {
                continue;
            }
            // The middle of an infinite segment: a point well inside it.
            let middle = if t1.is_finite() {
                0.5 * (t0 + t1)
            } else {
                t0 + 1.0
            };
            if f(t0, t1, self.at(ray.at(middle))) {
                return;
            }
        }
    }

    /// Where a free flight along `ray` from its origin ends before `t_max`, drawn from the
    /// uniform number `u` with density `σ_t(t)·T(t)`; `None` if it reaches `t_max` (with
    /// probability `T(t_max)`).
    pub fn sample_scatter(&self, ray: &Ray, t_max: f32, u: f32) -> Option<Scatter> {
        // The optical depth the flight travels: exponential with mean 1.
        let mut tau = -(1.0 - u).ln();
        let mut found = None;
        self.walk(ray, t_max, |t0, t1, medium| {
            let Some(m) = medium.filter(|m| m.sigma_t > 0.0) else {
                return false;
            };
            let depth = m.sigma_t * (t1 - t0);
            if tau < depth {
                found = Some(Scatter {
                    t: t0 + tau / m.sigma_t,
                    medium: m,
                });
                return true;
            }
            tau -= depth;
            false
        });
        found
    }

    /// The transmittance along `ray` from its origin to `t_max` (1 in a scene without media).
    pub fn transmittance(&self, ray: &Ray, t_max: f32) -> f32 {
        if self.is_empty() {
            return 1.0;
        }
        let mut depth = 0.0f32;
        self.walk(ray, t_max, |t0, t1, medium| {
            if let Some(m) = medium {
                depth += m.sigma_t * (t1 - t0);
            }
            false
        });
        (-depth).exp()
    }
}

/// The Henyey–Greenstein phase function at `cos = travel·ω` (per steradian): `ω` the scattered
/// direction, `travel` the direction the path arrived along.
pub fn henyey_greenstein(cos: f32, g: f32) -> f32 {
    let denom = 1.0 + g * g - 2.0 * g * cos;
    (1.0 - g * g) / (4.0 * PI * denom * denom.max(1e-12).sqrt())
}

/// A direction drawn from the Henyey–Greenstein phase function about `travel` (unit), from
/// `u ∈ [0, 1)²`; its pdf is [`henyey_greenstein`] of its cosine with `travel`.
pub fn sample_henyey_greenstein(travel: Vec3, g: f32, u: Vec2) -> Vec3 {
    // The inverse of the cosine's distribution (pbrt's, with g > 0 scattering forward).
    let cos = if g.abs() < 1e-3 {
        1.0 - 2.0 * u.x
    } else {
        let s = (1.0 - g * g) / (1.0 + g - 2.0 * g * u.x);
        ((1.0 + g * g - s * s) / (2.0 * g)).clamp(-1.0, 1.0)
    };
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    let (t, b) = travel.any_orthonormal_pair();
    (t * (sin * phi.cos()) + b * (sin * phi.sin()) + travel * cos).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_phase_function_integrates_to_one_and_its_sampler_follows_it() {
        for g in [-0.8f32, 0.0, 0.5, 0.95] {
            // ∫ p dω = 2π ∫ p(μ) dμ, midpoint rule.
            let n = 200_000;
            let total: f64 = (0..n)
                .map(|i| {
                    let mu = -1.0 + (i as f64 + 0.5) * 2.0 / n as f64;
                    f64::from(henyey_greenstein(mu as f32, g)) * 2.0 / n as f64
                })
                .sum::<f64>()
                * 2.0
                * std::f64::consts::PI;
            assert!((total - 1.0).abs() < 2e-3, "g {g}: {total}");
            // The sampled cosines' mean is g (the phase function's mean cosine), within
            // 4 standard errors (the cosine's variance is at most 1).
            let travel = Vec3::new(0.3, -0.2, 0.9).normalize();
            let m = 100_000;
            let mut rng = crate::rng::Rng::new(5);
            let mean = (0..m)
                .map(|_| {
                    f64::from(sample_henyey_greenstein(travel, g, rng.next_vec2()).dot(travel))
                })
                .sum::<f64>()
                / m as f64;
            assert!(
                (mean - f64::from(g)).abs() < 4.0 / (m as f64).sqrt(),
                "g {g}: {mean}"
            );
        }
    }

    #[test]
    fn free_flights_and_transmittance_agree_over_boxes_and_a_global_medium() {
        let thin = Medium {
            sigma_t: 0.2,
            albedo: 0.9,
            g: 0.0,
        };
        let thick = Medium {
            sigma_t: 1.5,
            albedo: 0.5,
            g: 0.3,
        };
        let media = Media {
            global: Some(thin),
            boxes: vec![(Vec3::new(1.0, -1.0, -1.0), Vec3::new(2.0, 1.0, 1.0), thick)],
            bounds: (Vec3::splat(-5.0), Vec3::splat(5.0)),
        };
        let ray = Ray {
            origin: Vec3::ZERO,
            direction: Vec3::X,
            t_max: f32::INFINITY,
        };
        // Optical depth to x = 3: 0.2 + 1.5 + 0.2.
        let expected = (-1.9f32).exp();
        assert!((media.transmittance(&ray, 3.0) - expected).abs() < 1e-6);
        // The fraction of free flights that pass x = 3 is the transmittance there (4σ).
        let n = 200_000;
        let mut rng = crate::rng::Rng::new(8);
        let passed = (0..n)
            .filter(|_| media.sample_scatter(&ray, 3.0, rng.next_f32()).is_none())
            .count() as f32
            / n as f32;
        let sigma = (expected * (1.0 - expected) / n as f32).sqrt();
        assert!(
            (passed - expected).abs() < 4.0 * sigma,
            "{passed} vs {expected}"
        );
        // Inside the box the medium is the box's.
        assert_eq!(media.at(Vec3::new(1.5, 0.0, 0.0)), Some(thick));
        assert_eq!(media.at(Vec3::new(2.5, 0.0, 0.0)), Some(thin));
        // Past the bounds, vacuum: from x = 5 on nothing attenuates.
        assert_eq!(media.at(Vec3::new(6.0, 0.0, 0.0)), None);
        let far = media.transmittance(&ray, 100.0);
        assert!((far - (-(0.2 * 4.0 + 1.5f32)).exp()).abs() < 1e-6, "{far}");
    }
}
