//! The images of a render's passes, and their combination by inverse variance.
//!
//! A guided render spends part of its budget on training passes, whose images are as unbiased
//! as the final render's, only noisier (the guide was still learning). The library's
//! [`pass_weights`] weighs each by the inverse of its variance (Müller et al. 2019), the
//! combination of independent unbiased estimates with the least variance; a pass of one sample
//! per pixel has no variance to estimate and is left out (the first training pass, under 1% of
//! the training samples). The "mean vs reference" column of the demo's report measures what
//! bias the weights' dependence on the images brings.
//!
//! The same passes give efficiency-aware roulette and splitting what it needs of the image
//! ([`splitting`]): each pixel's estimated value, the image's relative variance per sample and
//! the cost of a camera sample.

use crate::image::Image;
use crate::material::luminance;
use glam::Vec3;
use sdguide::{ImageStatistics, PixelSums, Splitting, SplittingMode, pass_weights};

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

    /// The pass's sums per pixel in luminance, as the library's image statistics take them.
    pub fn pixel_sums(&self) -> Vec<PixelSums> {
        self.sum
            .pixels
            .iter()
            .zip(&self.squares)
            .map(|(s, &sum_sq)| PixelSums {
                sum: f64::from(luminance(*s)),
                sum_sq,
                cost: 0.0,
                count: self.spp,
            })
            .collect()
    }
}

/// The passes' images (oldest first, the last the render's own) combined by inverse variance,
/// by the library's [`pass_weights`] on their luminance (see it for how each pass's variance
/// is estimated). `None` when no pass can be weighed.
///
/// Measured on `door` with splitting: combined with its training passes by their own variance
/// estimates alone, without the distance from the last pass, the final image's relMSE of 0.50
/// became 0.66–0.92.
pub fn combine(passes: &[PassImage]) -> Option<Image> {
    combine_all(passes)
}

/// [`combine`] of passes held anywhere, oldest first.
pub fn combine_all<'a>(passes: impl IntoIterator<Item = &'a PassImage>) -> Option<Image> {
    let passes: Vec<&PassImage> = passes.into_iter().collect();
    let sums: Vec<Vec<PixelSums>> = passes.iter().map(|p| p.pixel_sums()).collect();
    let views: Vec<&[PixelSums]> = sums.iter().map(Vec::as_slice).collect();
    let last = passes.last()?;
    let weights = pass_weights(last.sum.width, last.sum.height, &views)?;
    let mut combined = Image::new(last.sum.width, last.sum.height);
    for (w, pass) in weights.iter().zip(&passes) {
        if *w > 0.0 {
            // The pass's weight, applied to its sums: its mean is the sum over its samples.
            let share = (w / f64::from(pass.spp)) as f32;
            for (c, s) in combined.pixels.iter_mut().zip(&pass.sum.pixels) {
                *c += *s * share;
            }
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
    for (p, sums) in image.pass_mut().iter_mut().zip(latest.pixel_sums()) {
        *p = PixelSums { cost, ..sums };
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
