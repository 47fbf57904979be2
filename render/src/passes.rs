//! The images of a render's passes, and their combination by inverse variance.
//!
//! A guided render spends part of its budget on training passes, whose images are as unbiased
//! as the final render's, only noisier (the guide was still learning). Averaging them in by
//! sample count would let the early, noisy passes spoil the final one; weighting each pass by
//! the inverse of its image's variance (Müller et al. 2019, "Practical path guiding in
//! production") is the combination that minimizes the variance of the weighted mean of
//! independent unbiased estimates, `Σ wᵢ·Iᵢ / Σ wᵢ` with `wᵢ = 1 / Vᵢ`.
//!
//! A pass's variance `Vᵢ` is estimated from its own samples: the mean over pixels of each
//! pixel mean's variance, from the pixel's sums of luminance and squared luminance. The
//! weights therefore depend on the images they weigh, but each is one number pooled over every
//! pixel of a pass, so its correlation with any one pixel — the bias it brings — falls as one
//! over the pixel count; the demo's "mean vs reference" column measures what remains. A pass of
//! one sample per pixel has no within-pixel variance to estimate and is left out (it is the
//! first training pass, under 1% of the training samples).
//!
//! The same passes give efficiency-aware roulette and splitting what it needs of the image
//! ([`splitting`]): each pixel's estimated value, the image's relative variance per sample and
//! the cost of a camera sample.

use crate::image::Image;
use crate::material::luminance;
use glam::Vec3;
use sdguide::{ImageStatistics, PixelSums, Splitting, SplittingMode};

/// The sums of one pass's samples, per pixel.
#[derive(Clone, Debug)]
pub struct PassImage {
    /// Sum of the radiance samples.
    pub sum: Image,
    /// Sum of the squared luminance of the samples.
    pub squares: Vec<f64>,
    /// Samples per pixel.
    pub spp: u32,
    /// Rays traced for the pass's samples, over all pixels.
    pub rays: f64,
}

impl PassImage {
    /// An empty pass at `width × height`.
    pub fn new(width: usize, height: usize) -> Self {
        PassImage {
            sum: Image::new(width, height),
            squares: vec![0.0; width * height],
            spp: 0,
            rays: 0.0,
        }
    }

    /// Adds one pixel's sample `l`.
    pub fn add(&mut self, pixel: usize, l: Vec3) {
        self.sum.pixels[pixel] += l;
        self.squares[pixel] += (luminance(l) as f64).powi(2);
    }

    /// The pass's image: the mean of its samples.
    pub fn mean(&self) -> Image {
        let mut image = self.sum.clone();
        let scale = 1.0 / self.spp.max(1) as f32;
        image.pixels.iter_mut().for_each(|p| *p *= scale);
        image
    }

    /// The variance of the pass's image, averaged over its pixels (luminance): the mean of
    /// `s² / n` with `s²` a pixel's sample variance and `n` the samples per pixel. `None` below
    /// two samples per pixel.
    pub fn variance(&self) -> Option<f64> {
        self.weighted_variance(None)
    }

    /// [`variance`](Self::variance) with each pixel weighed by `weights` (none: by 1).
    fn weighted_variance(&self, weights: Option<&[f64]>) -> Option<f64> {
        if self.spp < 2 {
            return None;
        }
        let n = self.spp as f64;
        let total: f64 = self
            .sum
            .pixels
            .iter()
            .zip(&self.squares)
            .enumerate()
            .map(|(p, (s, &q))| {
                let s = luminance(*s) as f64;
                let w = weights.map_or(1.0, |w| w[p]);
                w * ((q - s * s / n) / (n - 1.0)).max(0.0) / n
            })
            .sum();
        Some(total / self.squares.len().max(1) as f64)
    }
}

/// The passes' images combined by inverse variance; passes without a variance estimate, or
/// with a zero or non-finite one, are left out. `None` when no pass can be weighed.
///
/// The variances are relative, as the image's error is: each pixel's is divided by
/// `Ĩ² + ε`, with `Ĩ` the last pass's smoothed luminance, so that a pass noisy in the dark
/// pixels, which the relative error weighs most, is not weighed by its bright ones.
///
/// `passes` come oldest first, the last one the render's own (the most samples, in the demo).
/// The variance of every other pass is taken from how far its image lies from the last's:
/// `E[(Iᵢ − I_last)²] = Vᵢ + V_last` per pixel, so the mean over pixels of `(Iᵢ − I_last)²`
/// less `V_last` estimates `Vᵢ` — at least the pass's own estimate. The variance of a
/// path-traced pixel is heavy-tailed, and a pass of few samples mostly underestimates its own
/// from its samples, which would give it far more than its share; its distance from the last
/// pass counts the outliers it did draw (measured on `door` with splitting: combined with its
/// training passes by their own estimates, the final image's relMSE of 0.50 became 0.66–0.92).
pub fn combine(passes: &[PassImage]) -> Option<Image> {
    combine_all(passes)
}

/// [`combine`] of passes held anywhere, oldest first.
pub fn combine_all<'a>(passes: impl IntoIterator<Item = &'a PassImage>) -> Option<Image> {
    let passes: Vec<&PassImage> = passes.into_iter().collect();
    let last = *passes.last()?;
    let last_mean = last.mean();
    let mut smoothed = ImageStatistics::new(last_mean.width, last_mean.height);
    smoothed.set_estimate(Some(&luminances(&last_mean)));
    let relative: Vec<f64> = (0..last_mean.pixels.len())
        .map(|p| 1.0 / f64::from(smoothed.pixel(p)).powi(2))
        .collect();
    let weights = Some(relative.as_slice());
    let last_variance = last.weighted_variance(weights);
    let weighed: Vec<(f64, &PassImage)> = passes
        .iter()
        .enumerate()
        .filter_map(|(i, &p)| {
            let own = p.weighted_variance(weights)?;
            let v = match last_variance {
                Some(v_last) if i + 1 < passes.len() => {
                    let mean = p.mean();
                    let distance = mean
                        .pixels
                        .iter()
                        .zip(&last_mean.pixels)
                        .zip(&relative)
                        .map(|((&a, &b), &w)| w * f64::from(luminance(a) - luminance(b)).powi(2))
                        .sum::<f64>()
                        / mean.pixels.len().max(1) as f64;
                    own.max(distance - v_last)
                }
                _ => own,
            };
            (v > 0.0 && v.is_finite()).then_some((1.0 / v, p))
        })
        .collect();
    let (_, first) = weighed.first()?;
    let total: f64 = weighed.iter().map(|(w, _)| w).sum();
    let mut combined = Image::new(first.sum.width, first.sum.height);
    for (w, pass) in &weighed {
        // The pass's weight, applied to its sums: its mean is the sum over its samples.
        let share = (w / total / f64::from(pass.spp)) as f32;
        for (c, s) in combined.pixels.iter_mut().zip(&pass.sum.pixels) {
            *c += *s * share;
        }
    }
    Some(combined)
}

/// Each pixel's luminance.
fn luminances(image: &Image) -> Vec<f32> {
    image.pixels.iter().map(|&c| luminance(c)).collect()
}

/// The image terms of efficiency-aware roulette and splitting: the policy for the next pass
/// (mode `mode`), and each pixel's `sqrt(Ĩ² + ε)`.
pub struct PixelEstimates {
    /// The policy, with the image's relative variance and cost per camera sample.
    pub splitting: Splitting,
    /// Per pixel, `sqrt(Ĩ² + ε)`, with `Ĩ` the luminance of the combined passes averaged over
    /// the pixel's 3×3 neighbourhood (a cheap denoiser: a pixel's own estimate is too noisy to
    /// divide by).
    pub pixels: Vec<f32>,
}

/// Samples per pixel a pass needs before its variance sets the splitting policy (the
/// library's gate, [`ImageStatistics::MIN_SAMPLES`]).
pub const POLICY_SPP: u32 = ImageStatistics::MIN_SAMPLES as u32;

/// Splits a vertex may make in the demo: on `door`, the largest factor of 8 spent 2–3× the
/// rays of 3 for the same error.
pub const MAX_SPLITS: f32 = 3.0;

/// What the passes so far (`passes`, oldest first) say about the image, for the next pass's
/// roulette and splitting, by the library's [`ImageStatistics`]: `Ĩ` from all of them
/// combined (by inverse variance: [`combine`]), the per-sample variance and cost from the most
/// recent pass with at least [`POLICY_SPP`] samples per pixel. `None` while no pass has.
pub fn splitting(passes: &[&PassImage], mode: SplittingMode) -> Option<PixelEstimates> {
    let latest = passes.iter().rev().find(|p| p.spp >= POLICY_SPP)?;
    let combined = combine_all(passes.iter().copied())?;
    let (width, height) = (combined.width, combined.height);
    let mut image = ImageStatistics::new(width, height);
    // The pass's sums, its rays spread evenly (only their mean per sample is used).
    let cost = latest.rays / (width * height).max(1) as f64;
    for (p, (s, &squares)) in image
        .pass_mut()
        .iter_mut()
        .zip(latest.sum.pixels.iter().zip(&latest.squares))
    {
        *p = PixelSums {
            sum: f64::from(luminance(*s)),
            sum_sq: squares,
            cost,
            count: latest.spp,
        };
    }
    image.set_estimate(Some(&luminances(&combined)));
    image.end_pass();
    let policy = image
        .splitting(mode)?
        .with_bounds(Splitting::DEFAULT_MIN_SURVIVAL, MAX_SPLITS)
        .ok()?;
    Some(PixelEstimates {
        splitting: policy,
        pixels: (0..width * height).map(|p| image.pixel(p)).collect(),
    })
}
