//! Analytic light fields and a standard training workload, for tests, benchmarks and for
//! checking an integration before a renderer is wired in.
//!
//! A [`LightField`] is a sum of von Mises–Fisher lobes, each aimed from the query point at a
//! fixed target (so the light changes with position, as it does in a scene), plus a constant
//! ambient term. Its integral over the sphere is known in closed form at every point, which is
//! what unbiasedness and variance tests need. [`Workload`] trains a field on such a light the way
//! a path tracer would: points on surfaces of a unit room, directions drawn half from the uniform
//! sphere and half from the learned distribution, recorded with the mixture pdf.

use crate::rng::{Rng, mix};
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use sdguide::sphere::{INV_SPHERE_AREA, SPHERE_AREA, square_to_direction};
use sdguide::{GuidingField, Sample};
use std::f32::consts::TAU;

/// A von Mises–Fisher lobe of light arriving from the direction of `target`.
///
/// At a point `x` its mean direction is `μ = normalize(target − x)` and its strength is
/// `P(x) = power / (1 + falloff·|target − x|²)`; its value in direction `ω` is
/// `P(x) · κ / (2π(1 − e^{−2κ})) · e^{κ(μ·ω − 1)}`, which integrates to `P(x)` over the sphere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VmfLobe {
    /// The point the light comes from.
    pub target: Vec3,
    /// Concentration: larger is sharper (κ = 800 is a lobe a few degrees wide).
    pub kappa: f32,
    /// The lobe's integral over the sphere where it does not fall off (`falloff = 0`, or at
    /// `target`).
    pub power: f32,
    /// How fast the strength falls off with squared distance from `target` (0: constant).
    pub falloff: f32,
}

impl VmfLobe {
    /// The lobe's mean direction at `x`.
    pub fn mean(&self, x: Vec3) -> Vec3 {
        (self.target - x).try_normalize().unwrap_or(Vec3::Z)
    }

    /// The lobe's strength at `x`: its integral over the sphere there.
    pub fn power_at(&self, x: Vec3) -> f32 {
        self.power / (1.0 + self.falloff * (self.target - x).length_squared())
    }

    /// The lobe's value at `x` in direction `d` (a unit vector).
    pub fn eval(&self, x: Vec3, d: Vec3) -> f32 {
        self.power_at(x) * self.density(self.mean(x).dot(d))
    }

    /// `∫ eval(x, ω)² dω`: the normalized density squared integrates to
    /// `κ / (4π) · (1 − e^{−4κ}) / (1 − e^{−2κ})²`.
    pub fn integral_of_square(&self, x: Vec3) -> f64 {
        let k = f64::from(self.kappa);
        let p = f64::from(self.power_at(x));
        let e2 = -(-2.0 * k).exp_m1();
        let e4 = -(-4.0 * k).exp_m1();
        p * p * k / (4.0 * std::f64::consts::PI) * e4 / (e2 * e2)
    }

    /// The normalized vMF density for `cos = μ·ω`.
    fn density(&self, cos: f32) -> f32 {
        vmf_density(self.kappa, cos)
    }

    /// Draws a direction from the lobe at `x` (density `eval / power`).
    pub fn sample(&self, x: Vec3, u: Vec2) -> Vec3 {
        vmf_sample(self.mean(x), self.kappa, u)
    }
}

/// The von Mises–Fisher density `κ / (2π(1 − e^{−2κ})) · e^{κ(cos − 1)}` of concentration `κ`
/// at `cos = μ·ω`, written to stay finite for any κ.
pub fn vmf_density(kappa: f32, cos: f32) -> f32 {
    let k = kappa;
    k / (TAU * (1.0 - (-2.0 * k).exp())) * (k * (cos - 1.0)).exp()
}

/// Draws a direction from the vMF distribution of mean `mean` (a unit vector) and concentration
/// `kappa`, from `u ∈ [0,1)²`.
pub fn vmf_sample(mean: Vec3, kappa: f32, u: Vec2) -> Vec3 {
    let k = kappa;
    let cos = (1.0 + (u.x + (1.0 - u.x) * (-2.0 * k).exp()).ln() / k).clamp(-1.0, 1.0);
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    let (s, c) = (TAU * u.y).sin_cos();
    let (t, b) = mean.any_orthonormal_pair();
    (sin * c) * t + (sin * s) * b + cos * mean
}

/// A synthetic BSDF for mixture tests: a glossy vMF lobe about a fixed axis, perfectly importance
/// sampled, with `f_s·|cos θ| = pdf` (albedo 1). The integrand of a vertex is then
/// `L(ω)·pdf(ω)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bsdf {
    /// The lobe's axis (a unit vector).
    pub axis: Vec3,
    /// The lobe's concentration.
    pub kappa: f32,
}

impl Bsdf {
    /// The sampling pdf (and `f_s·|cos θ|`) of direction `d`.
    pub fn pdf(&self, d: Vec3) -> f32 {
        vmf_density(self.kappa, self.axis.dot(d))
    }

    /// Draws a direction.
    pub fn sample(&self, u: Vec2) -> Vec3 {
        vmf_sample(self.axis, self.kappa, u)
    }
}

/// Incident light at every point of space: vMF lobes plus a constant ambient term.
#[derive(Clone, Debug, PartialEq)]
pub struct LightField {
    /// The lobes.
    pub lobes: Vec<VmfLobe>,
    /// Radiance arriving equally from every direction.
    pub ambient: f32,
}

impl LightField {
    /// The standard field of the benchmarks: a sharp lobe (κ = 800) from a small light near the
    /// ceiling, a broad lobe (κ = 60) from a window, and a small ambient term.
    pub fn standard() -> Self {
        Self {
            lobes: vec![
                VmfLobe {
                    target: Vec3::new(0.75, 0.95, 0.6),
                    kappa: 800.0,
                    power: 10.0,
                    falloff: 0.0,
                },
                VmfLobe {
                    target: Vec3::new(-0.5, 0.6, 0.5),
                    kappa: 60.0,
                    power: 4.0,
                    falloff: 0.0,
                },
            ],
            ambient: 0.05,
        }
    }

    /// The value arriving at `x` from direction `d` (a unit vector).
    pub fn radiance(&self, x: Vec3, d: Vec3) -> f32 {
        self.ambient + self.lobes.iter().map(|l| l.eval(x, d)).sum::<f32>()
    }

    /// `∫ radiance(x, ω) dω` over the sphere.
    pub fn integral(&self, x: Vec3) -> f64 {
        f64::from(self.ambient) * f64::from(SPHERE_AREA)
            + self
                .lobes
                .iter()
                .map(|l| f64::from(l.power_at(x)))
                .sum::<f64>()
    }
}

/// The standard scene of the benchmarks: the unit room `[0,1]³`, with points on the floor, the
/// back wall, the left wall, and a sphere of radius 0.2 standing in the middle.
pub fn room_point(u: [f32; 3]) -> Vec3 {
    room_vertex(u).0
}

/// [`room_point`] with the surface's normal there (facing into the room, outward on the
/// sphere).
pub fn room_vertex(u: [f32; 3]) -> (Vec3, Vec3) {
    let [a, b, c] = u;
    let pick = (a * 4.0).min(3.999);
    let surface = pick as u32;
    match surface {
        0 => (Vec3::new(b, 0.0, c), Vec3::Y),
        1 => (Vec3::new(b, c, 0.0), Vec3::Z),
        2 => (Vec3::new(0.0, b, c), Vec3::X),
        _ => {
            let n = square_to_direction(Vec2::new(b, c));
            (Vec3::new(0.5, 0.3, 0.5) + 0.2 * n, n)
        }
    }
}

/// The room's bounds.
pub fn room_bounds() -> sdguide::Aabb {
    sdguide::Aabb::new(Vec3::ZERO, Vec3::ONE)
}

/// Trains a field on a light field the way a path tracer would.
///
/// Iteration `k` records `first_budget · 2^k` samples at [`room_point`]s, in parallel: each
/// direction is drawn with probability ½ from the uniform sphere and ½ from the field's current
/// distribution, and recorded with the mixture's pdf and the light's value.
///
/// The value may be noisy as a path tracer's radiance estimates are: with `lobe_noise = K > 1`
/// the lobes' contribution is multiplied by `ξ`, which is `K` with probability `1/K` and 0
/// otherwise (`E[ξ] = 1`, `E[ξ²] = K`: rare large values), while the ambient term stays exact.
/// The noise thus differs between directions, which is where the l2 rule departs from l1.
#[derive(Clone, Debug)]
pub struct Workload {
    /// The light the field learns.
    pub light: LightField,
    /// `E[ξ²]` of the lobes' multiplicative noise; 1 for exact values.
    pub lobe_noise: f32,
    /// Fixes every random number the workload draws.
    pub seed: u64,
    /// `None`: directions are drawn ½ from the uniform sphere and ½ from the guide. `Some`: from
    /// the one-sample mixture of the guide (with the cell's learned
    /// [`guide_probability`](sdguide::DirectionalDistribution::guide_probability)) and this BSDF,
    /// recorded with mixture terms whose integrand is `value · bsdf.pdf`.
    pub bsdf: Option<Bsdf>,
}

/// Samples per parallel chunk; fixed, so results do not depend on the thread count.
const CHUNK: u64 = 4096;

impl Workload {
    /// Records one iteration of `budget` samples into `field` (iteration number `k` seeds it).
    pub fn record_iteration(&self, field: &GuidingField, k: u32, budget: u64) {
        let chunks = budget.div_ceil(CHUNK);
        (0..chunks).into_par_iter().for_each(|chunk| {
            let mut rng = Rng::new(self.seed ^ mix(u64::from(k) << 40 | chunk));
            for _ in (chunk * CHUNK)..((chunk + 1) * CHUNK).min(budget) {
                field.record(&self.draw(field, &mut rng));
            }
        });
    }

    /// One sample as a renderer would record it: a point and its surface's normal, a direction
    /// from the ½–½ mixture of uniform and guided sampling, the light's value and the mixture
    /// pdf.
    pub fn draw(&self, field: &GuidingField, rng: &mut Rng) -> Sample {
        let vertex = room_vertex([rng.next_f32(), rng.next_f32(), rng.next_f32()]);
        self.draw_at(field, vertex, self.bsdf, rng)
    }

    /// [`draw`](Self::draw) at the vertex `(x, normal)`, with `bsdf` in place of the
    /// workload's.
    pub fn draw_at(
        &self,
        field: &GuidingField,
        (x, normal): (Vec3, Vec3),
        bsdf: Option<Bsdf>,
        rng: &mut Rng,
    ) -> Sample {
        let dist = field.distribution(x);
        let a = match bsdf {
            Some(_) => dist.guide_probability(),
            None => 0.5,
        };
        let guided = rng.next_f32() < a;
        let u = rng.next_vec2();
        let d = match (guided, &bsdf) {
            (true, _) => dist.sample(u).0,
            (false, Some(b)) => b.sample(u),
            (false, None) => square_to_direction(u),
        };
        let guide_pdf = dist.pdf(d);
        let other_pdf = bsdf.map_or(INV_SPHERE_AREA, |b| b.pdf(d));
        let pdf = a * guide_pdf + (1.0 - a) * other_pdf;
        let v = self.value(x, d, rng);
        let sample = Sample {
            position: x,
            direction: d,
            value: v,
            pdf,
            normal: Some(normal),
            ..Sample::default()
        };
        match bsdf {
            Some(_) => sample.with_mixture(v * other_pdf, other_pdf, guide_pdf),
            None => sample,
        }
    }

    /// One (possibly noisy) estimate of the light arriving at `x` from `d`; its expectation is
    /// `light.radiance(x, d)`.
    pub fn value(&self, x: Vec3, d: Vec3, rng: &mut Rng) -> f32 {
        let lobes: f32 = self.light.lobes.iter().map(|l| l.eval(x, d)).sum();
        let xi = if self.lobe_noise > 1.0 {
            let hit = rng.next_f32() < 1.0 / self.lobe_noise;
            if hit { self.lobe_noise } else { 0.0 }
        } else {
            1.0
        };
        self.light.ambient + lobes * xi
    }

    /// `E[v]` and `E[v²]` of the value [`value`](Self::value) returns at `x` from `d`: with
    /// lobe radiance `l` and ambient `a`, `a + l` and `a² + 2al + E[ξ²]·l²`. Their integrals
    /// over a cell are what the l1 and l2 rules estimate.
    pub fn value_moments(&self, x: Vec3, d: Vec3) -> (f64, f64) {
        let a = f64::from(self.light.ambient);
        let l: f64 = self
            .light
            .lobes
            .iter()
            .map(|l| f64::from(l.eval(x, d)))
            .sum();
        let noise = f64::from(self.lobe_noise.max(1.0));
        (a + l, a * a + 2.0 * a * l + noise * l * l)
    }

    /// Estimates `∫ L(x, ω) dω` at `x` with `n` samples from `sample` (which maps two uniform
    /// numbers to a direction and its solid-angle pdf), with the workload's noisy values, and
    /// measures the estimator's relative variance against the exact integral.
    pub fn estimate(
        &self,
        x: Vec3,
        n: u64,
        rng: &mut Rng,
        mut sample: impl FnMut(Vec2) -> (Vec3, f32),
    ) -> Estimate {
        let (mut s1, mut s2) = (0.0f64, 0.0f64);
        for _ in 0..n {
            let (d, p) = sample(rng.next_vec2());
            let w = f64::from(self.value(x, d, rng)) / f64::from(p);
            s1 += w;
            s2 += w * w;
        }
        let n = n as f64;
        let mean = s1 / n;
        let var = (s2 / n - mean * mean).max(0.0) * n / (n - 1.0);
        let truth = self.light.integral(x);
        Estimate {
            mean,
            relative_variance: var / (truth * truth),
            standard_error: (var / n).sqrt(),
        }
    }

    /// Trains `iterations` iterations with budgets `first_budget · 2^k`, refining after each.
    pub fn train(&self, field: &mut GuidingField, iterations: u32, first_budget: u64) {
        for k in 0..iterations {
            self.record_iteration(field, k, first_budget << k);
            field.refine();
        }
    }
}

/// Mean and relative variance `Var[w]/E[w]²` of the one-sample estimator `w = L(x,ω)/p(ω)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Estimate {
    /// The sample mean of `w`.
    pub mean: f64,
    /// The sample variance of `w` divided by the squared true integral.
    pub relative_variance: f64,
    /// The standard error of `mean`.
    pub standard_error: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vmf_lobe_integrates_to_its_power() {
        // Midpoint quadrature on the equal-area square, fine enough for κ = 800 (lobe ~2°).
        let lobe = VmfLobe {
            target: Vec3::new(0.3, 0.2, 0.9),
            kappa: 800.0,
            power: 3.0,
            falloff: 0.0,
        };
        let n = 2000;
        let x = Vec3::new(0.1, 0.5, 0.4);
        let mut sum = 0.0f64;
        for i in 0..n {
            for j in 0..n {
                let s = Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
                sum += f64::from(lobe.eval(x, square_to_direction(s)));
            }
        }
        let integral = sum * f64::from(SPHERE_AREA) / (n * n) as f64;
        assert!((integral - 3.0).abs() < 3e-3, "{integral}");
    }

    #[test]
    fn vmf_samples_concentrate_around_the_mean() {
        let lobe = VmfLobe {
            target: Vec3::new(0.0, 0.0, 5.0),
            kappa: 60.0,
            power: 1.0,
            falloff: 0.0,
        };
        let mut rng = Rng::new(3);
        let n = 100_000;
        // E[μ·ω] = coth κ − 1/κ for a vMF distribution on the sphere.
        let mut mean_cos = 0.0f64;
        for _ in 0..n {
            mean_cos += f64::from(lobe.sample(Vec3::ZERO, rng.next_vec2()).z);
        }
        mean_cos /= f64::from(n);
        let expected = 1.0 / 60f64.tanh() - 1.0 / 60.0;
        // Var[μ·ω] ≈ 1/κ² for large κ; 5σ of the mean of n samples.
        assert!((mean_cos - expected).abs() < 5.0 / 60.0 / f64::from(n).sqrt());
    }
}
