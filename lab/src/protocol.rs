//! The directional learning protocol: one light field, one fixed sampler, every guiding library
//! trained on the same samples and judged by the same number.
//!
//! The light is three von Mises–Fisher lobes arriving from fixed directions (κ = 200, 50, 20:
//! a few degrees, a dozen and a broad one), the same at every point of the unit cube. Each
//! iteration draws its samples at uniform points of the cube, their directions from a fixed
//! mixture — ½ uniform over the sphere, ½ from the lobes themselves — whatever the library has
//! learned, so a library's result depends only on what it makes of the samples, not on how its
//! own guide steered them. Five iterations of 2²⁰ samples, the library updated after each.
//!
//! The score is the relative variance of the one-sample estimator `v/p` of `∫ v dω` with `ω`
//! drawn from the learned directional distribution alone (no BSDF, no mixture):
//!
//! ```text
//!   relvar(x) = ∫ v(ω)² / p(ω) dω / (∫ v dω)² − 1
//! ```
//!
//! integrated over the sphere by the midpoint rule on the equal-area square
//! ([`square_to_direction`]), for any `p` given only as a function of the direction, so a
//! library is measured through its public `pdf` alone. Averaged over held-out points of the
//! cube.

use crate::rng::{Rng, mix};
use crate::synthetic::{LightField, VmfLobe};
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use sdguide::sphere::{INV_SPHERE_AREA, SPHERE_AREA, square_to_direction};
use sdguide::{GuidingField, Sample};

/// The protocol's parameters: the light, the sampler and the budget.
#[derive(Clone, Debug, PartialEq)]
pub struct Protocol {
    /// The light every sample's value comes from; the same at every point of the cube when its
    /// lobes' targets are far away ([`Protocol::three_lobes`]).
    pub light: LightField,
    /// Probability of drawing a direction uniformly over the sphere; the rest are drawn from
    /// the lobes (each with probability proportional to its power).
    pub uniform_share: f32,
    /// Updates of the library, one after each iteration's samples.
    pub iterations: u32,
    /// Samples per iteration.
    pub samples: u64,
    /// Fixes every random number the protocol draws.
    pub seed: u64,
}

/// Samples per parallel chunk; fixed, so the samples do not depend on the thread count.
const CHUNK: u64 = 4096;

/// How far the lobes' targets are: the lobes' directions change by under 10⁻⁴ radians across
/// the unit cube.
const FAR: f32 = 1.0e4;

impl Default for Protocol {
    /// Three lobes, ½ uniform, 5 iterations of 2²⁰ samples, seed 1.
    fn default() -> Self {
        Self {
            light: Self::three_lobes(),
            uniform_share: 0.5,
            iterations: 5,
            samples: 1 << 20,
            seed: 1,
        }
    }
}

impl Protocol {
    /// The protocol's light: lobes of κ = 200, 50 and 20 carrying 0.5, 0.3 and 0.2 of the
    /// power, from fixed directions far apart, and no ambient light.
    pub fn three_lobes() -> LightField {
        let lobe = |direction: Vec3, kappa: f32, power: f32| VmfLobe {
            target: Vec3::splat(0.5) + FAR * direction.normalize(),
            kappa,
            power,
            falloff: 0.0,
        };
        LightField {
            lobes: vec![
                lobe(Vec3::new(0.3, 0.8, 0.5), 200.0, 0.5),
                lobe(Vec3::new(-0.7, 0.2, 0.6), 50.0, 0.3),
                lobe(Vec3::new(0.2, -0.5, -0.8), 20.0, 0.2),
            ],
            ambient: 0.0,
        }
    }

    /// The density the protocol draws directions at `x` with: `uniform_share/4π` plus the rest
    /// times the lobes' value over their total power (uniform where the lobes carry none).
    pub fn sampling_pdf(&self, x: Vec3, d: Vec3) -> f32 {
        let power = self.lobe_power(x);
        if power <= 0.0 {
            return INV_SPHERE_AREA;
        }
        let lobes: f32 = self.light.lobes.iter().map(|l| l.eval(x, d)).sum();
        self.uniform_share * INV_SPHERE_AREA + (1.0 - self.uniform_share) * lobes / power
    }

    fn lobe_power(&self, x: Vec3) -> f32 {
        self.light.lobes.iter().map(|l| l.power_at(x)).sum()
    }

    /// Iteration `k`'s samples, in a fixed order: points uniform in the unit cube, directions
    /// from the fixed mixture, exact values, recorded with the mixture's pdf.
    pub fn samples(&self, k: u32) -> Vec<Sample> {
        let chunks = self.samples.div_ceil(CHUNK);
        (0..chunks)
            .into_par_iter()
            .flat_map_iter(|chunk| {
                let mut rng = Rng::new(self.seed ^ mix(u64::from(k) << 40 | chunk));
                let n = CHUNK.min(self.samples - chunk * CHUNK);
                (0..n).map(move |_| self.draw(&mut rng))
            })
            .collect()
    }

    fn draw(&self, rng: &mut Rng) -> Sample {
        let x = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        let pick = rng.next_f32();
        let u = rng.next_vec2();
        let power = self.lobe_power(x);
        let d = if pick < self.uniform_share || power <= 0.0 {
            square_to_direction(u)
        } else {
            // A lobe with probability proportional to its power (the last if rounding leaves
            // `t` over).
            let mut t = rng.next_f32() * power;
            let lobes = &self.light.lobes;
            let lobe = lobes
                .iter()
                .find(|l| {
                    t -= l.power_at(x);
                    t < 0.0
                })
                .or(lobes.last());
            lobe.map_or(square_to_direction(u), |l| l.sample(x, u))
        };
        Sample {
            position: x,
            direction: d,
            value: self.light.radiance(x, d),
            pdf: self.sampling_pdf(x, d),
            ..Sample::default()
        }
    }

    /// Trains `field` by the protocol: every iteration's samples recorded, then `refine`.
    pub fn train(&self, field: &mut GuidingField) {
        for k in 0..self.iterations {
            field.record_all(&self.samples(k));
            field.refine();
        }
    }

    /// `n` held-out points, uniform in the unit cube (drawn apart from the training samples).
    pub fn positions(&self, n: usize) -> Vec<Vec3> {
        let mut rng = Rng::new(mix(self.seed ^ 0x9e37_79b9_7f4a_7c15));
        (0..n)
            .map(|_| Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()))
            .collect()
    }

    /// `relvar(x)` of the density `pdf` (of unit directions, per steradian) at `x`, by the
    /// midpoint rule on a `resolution × resolution` grid over the equal-area square. Infinite
    /// where `pdf` is zero or not finite where light arrives.
    pub fn relative_variance(&self, x: Vec3, pdf: impl Fn(Vec3) -> f32, resolution: u32) -> f64 {
        let n = resolution.max(1);
        let step = 1.0 / n as f32;
        let mut second = 0.0f64;
        for i in 0..n {
            for j in 0..n {
                let s = Vec2::new((i as f32 + 0.5) * step, (j as f32 + 0.5) * step);
                let d = square_to_direction(s);
                let v = f64::from(self.light.radiance(x, d));
                if v > 0.0 {
                    let p = f64::from(pdf(d));
                    second += if p > 0.0 && p.is_finite() {
                        v * v / p
                    } else {
                        f64::INFINITY
                    };
                }
            }
        }
        let second = second * f64::from(SPHERE_AREA) / f64::from(n).powi(2);
        let mu = self.light.integral(x);
        second / (mu * mu) - 1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// For one lobe, `relvar` of uniform sampling is `4π ∫ v² / μ² − 1` in closed form, and
    /// the lobe's own normalized density has none.
    #[test]
    fn quadrature_matches_the_closed_form_for_one_lobe() {
        let lobe = Protocol::three_lobes().lobes[0];
        let protocol = Protocol {
            light: LightField {
                lobes: vec![lobe],
                ambient: 0.0,
            },
            ..Protocol::default()
        };
        let x = Vec3::splat(0.5);
        let uniform = protocol.relative_variance(x, |_| INV_SPHERE_AREA, 1024);
        let p = f64::from(lobe.power_at(x));
        let exact = f64::from(SPHERE_AREA) * lobe.integral_of_square(x) / (p * p) - 1.0;
        assert!(
            (uniform - exact).abs() < 1e-3 * exact,
            "{uniform} vs {exact}"
        );
        // The light's own normalized density is the zero-variance one.
        let perfect = protocol.relative_variance(x, |d| lobe.eval(x, d) / lobe.power_at(x), 1024);
        assert!(perfect.abs() < 1e-3, "{perfect}");
    }

    #[test]
    fn the_sampling_pdf_is_normalized_and_draws_what_it_says() {
        let protocol = Protocol {
            samples: 200_000,
            ..Protocol::default()
        };
        let x = Vec3::splat(0.5);
        // ∫ p dω = 1, by the midpoint rule the score uses.
        let n = 1024u32;
        let mut total = 0.0f64;
        for i in 0..n {
            for j in 0..n {
                let s = Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
                total += f64::from(protocol.sampling_pdf(x, square_to_direction(s)));
            }
        }
        let total = total * f64::from(SPHERE_AREA) / f64::from(n * n);
        assert!((total - 1.0).abs() < 1e-3, "{total}");
        // The samples' `value/pdf` average to ∫ v = 1 (the lobes' total power): the pdf
        // recorded is the one the directions were drawn from. 5σ of the mean.
        let samples = protocol.samples(0);
        let w: Vec<f64> = samples
            .iter()
            .map(|s| f64::from(s.value) / f64::from(s.pdf))
            .collect();
        let mean = w.iter().sum::<f64>() / w.len() as f64;
        let var = w.iter().map(|w| (w - mean).powi(2)).sum::<f64>() / (w.len() - 1) as f64;
        let sigma = (var / w.len() as f64).sqrt();
        assert!((mean - 1.0).abs() < 5.0 * sigma, "{mean} ± {sigma}");
        assert_eq!(samples.len(), 200_000);
        assert_eq!(
            samples,
            protocol.samples(0),
            "the samples are fixed by the seed"
        );
    }
}
