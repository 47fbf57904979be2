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

use crate::image::Image;
use crate::material::luminance;
use glam::Vec3;

/// The sums of one pass's samples, per pixel.
#[derive(Clone, Debug)]
pub struct PassImage {
    /// Sum of the radiance samples.
    pub sum: Image,
    /// Sum of the squared luminance of the samples.
    pub squares: Vec<f64>,
    /// Samples per pixel.
    pub spp: u32,
}

impl PassImage {
    /// An empty pass at `width × height`.
    pub fn new(width: usize, height: usize) -> Self {
        PassImage {
            sum: Image::new(width, height),
            squares: vec![0.0; width * height],
            spp: 0,
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
        if self.spp < 2 {
            return None;
        }
        let n = self.spp as f64;
        let total: f64 = self
            .sum
            .pixels
            .iter()
            .zip(&self.squares)
            .map(|(s, &q)| {
                let s = luminance(*s) as f64;
                ((q - s * s / n) / (n - 1.0)).max(0.0) / n
            })
            .sum();
        Some(total / self.squares.len().max(1) as f64)
    }
}

/// The passes' images combined by inverse variance; passes without a variance estimate, or
/// with a zero or non-finite one, are left out. `None` when no pass can be weighed.
pub fn combine(passes: &[PassImage]) -> Option<Image> {
    let weighed: Vec<(f64, &PassImage)> = passes
        .iter()
        .filter_map(|p| {
            let v = p.variance()?;
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
