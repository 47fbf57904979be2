//! Image statistics for roulette and splitting: per-pixel moments and cost of a render's camera
//! samples over its passes, and the image terms [`Splitting`] needs from them.
//!
//! The efficiency-aware factor (see [`Splitting`]) weighs a vertex's share of the image's
//! relative error, so it needs three things of the image: each pixel's value `P = sqrt(Ĩ² + ε)`
//! the error is relative to, the image's per-sample relative variance `V̄` and the cost `C̄` of
//! a camera sample. A pass's own samples give `V̄` and `C̄`; all passes so far give `Ĩ`, averaged
//! over each pixel's 3×3 neighbourhood (a cheap denoiser: a pixel's own few samples are too
//! noisy to divide by) and bounded by a multiple of the neighbourhood's median, so that a light
//! or a firefly beside a pixel does not raise its value.
//!
//! The same sums combine a render's passes into one image ([`pass_weights`]): by inverse
//! variance, so that training passes, unbiased but noisier, add to the final render instead of
//! being thrown away or spoiling it.

use crate::config::ConfigError;
use crate::splitting::{Splitting, SplittingMode};

/// How far above its neighbourhood's median a pixel's `Ĩ` may be (see
/// [`ImageStatistics::pixel`]).
const MEDIAN_BOUND: f32 = 3.0;

/// One pixel's sums over the camera samples of a pass.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PixelSums {
    /// `Σ v`, the samples' values (luminance, say).
    pub sum: f64,
    /// `Σ v²`.
    pub sum_sq: f64,
    /// `Σ c`, what the samples cost (rays, say: the unit of
    /// [`Continuation::cost`](crate::Continuation::cost)).
    pub cost: f64,
    /// How many samples.
    pub count: u32,
}

impl PixelSums {
    /// Adds one camera sample of value `value` (negative or non-finite: counted as 0, so that
    /// one bad path cannot poison the image's terms) and cost `cost` (likewise).
    #[inline]
    pub fn add(&mut self, value: f32, cost: f32) {
        let ok = |x: f32| {
            if x.is_finite() && x > 0.0 {
                f64::from(x)
            } else {
                0.0
            }
        };
        let v = ok(value);
        self.sum += v;
        self.sum_sq += v * v;
        self.cost += ok(cost);
        self.count = self.count.saturating_add(1);
    }
}

/// A render's camera samples, per pixel, over its passes; and the image terms of
/// efficiency-aware roulette and splitting they give for the next pass.
///
/// Each pass, the renderer adds every camera sample to its pixel ([`add`](Self::add), or
/// through [`pass_mut`](Self::pass_mut) from several threads, one row range each), then calls
/// [`end_pass`](Self::end_pass). From then on [`splitting`](Self::splitting) gives the policy
/// and [`pixel`](Self::pixel) each pixel's `P` for [`Splitting::factor`]:
///
/// - `Ĩ`: the mean of every sample of every pass so far (or the renderer's own estimate,
///   [`set_estimate`](Self::set_estimate)), averaged over the pixel's 3×3 neighbourhood and at
///   most 3 times the neighbourhood's median (a light beside a pixel does not raise it);
///   `P = sqrt(Ĩ² + ε)`, with `ε` the relative error's (default
///   [`DEFAULT_EPSILON`](Self::DEFAULT_EPSILON), for images of values about 1).
/// - `V̄`: the mean over pixels of each pixel's sample variance over `P²` (`P` from the
///   neighbourhood's mean alone, without the bound), from the last pass
///   with at least [`MIN_SAMPLES`](Self::MIN_SAMPLES) samples per pixel: the variance of a
///   path-traced pixel is heavy-tailed, and estimated from fewer samples it is mostly too low,
///   which makes every factor too large.
/// - `C̄`: the mean cost of that pass's camera samples.
///
/// ```
/// use sdguide::{ImageStatistics, SplittingMode};
/// let mut image = ImageStatistics::new(4, 3);
/// assert!(image.splitting(SplittingMode::Roulette).is_none()); // no pass yet
/// for i in 0..8 {
///     for pixel in 0..12 {
///         image.add(pixel, if i % 2 == 0 { 0.5 } else { 1.5 }, 6.0);
///     }
/// }
/// image.end_pass();
/// // Every pixel: mean 1, so P = sqrt(1 + 0.01); sample variance 8/7·0.25.
/// assert!((image.pixel(5) - 1.01f32.sqrt()).abs() < 1e-6);
/// let policy = image.splitting(SplittingMode::Roulette).unwrap();
/// assert_eq!(image.cost_per_sample(), Some(6.0));
/// # let _ = policy;
/// ```
#[derive(Clone, Debug)]
pub struct ImageStatistics {
    width: usize,
    height: usize,
    epsilon: f32,
    pass: Vec<PixelSums>,
    /// Every pass's sums of values and counts, for `Ĩ`.
    total: Vec<(f64, u64)>,
    /// The renderer's own estimate of the image, when it gave one.
    estimate: Option<Vec<f32>>,
    /// `P` per pixel, from the passes so far.
    pixels: Vec<f32>,
    /// `P` from the neighbourhood's mean alone, which `V̄` and [`pass_weights`] divide by (see
    /// [`smooth`](Self::smooth)).
    mean_pixels: Vec<f32>,
    /// `V̄` and `C̄`, from the last pass with enough samples.
    terms: Option<(f64, f64)>,
    passes: u32,
}

impl ImageStatistics {
    /// The relative error's `ε` by default.
    pub const DEFAULT_EPSILON: f32 = 0.01;
    /// Samples per pixel a pass needs (on average) before its variance sets the policy.
    pub const MIN_SAMPLES: f64 = 4.0;

    /// Empty statistics of a `width × height` image, pixels indexed `y·width + x`.
    pub fn new(width: usize, height: usize) -> Self {
        let n = width.saturating_mul(height);
        ImageStatistics {
            width,
            height,
            epsilon: Self::DEFAULT_EPSILON,
            pass: vec![PixelSums::default(); n],
            total: vec![(0.0, 0); n],
            estimate: None,
            pixels: vec![Self::DEFAULT_EPSILON.sqrt(); n],
            mean_pixels: vec![Self::DEFAULT_EPSILON.sqrt(); n],
            terms: None,
            passes: 0,
        }
    }

    /// The statistics with the relative error's `ε` (finite and positive: it keeps `P` from 0
    /// in black pixels; about 1% of the image's typical value squared).
    ///
    /// # Errors
    ///
    /// A [`ConfigError`] for an `ε` that is not finite and positive.
    pub fn with_epsilon(mut self, epsilon: f32) -> Result<Self, ConfigError> {
        if !(epsilon.is_finite() && epsilon > 0.0) {
            return Err(ConfigError {
                field: "epsilon",
                value: epsilon.to_string(),
                requirement: "finite and positive",
            });
        }
        self.epsilon = epsilon;
        self.smooth();
        Ok(self)
    }

    /// Adds a camera sample of value `value` (its luminance, say) and cost `cost` to pixel
    /// `pixel` of the current pass; a pixel outside the image is ignored.
    #[inline]
    pub fn add(&mut self, pixel: usize, value: f32, cost: f32) {
        if let Some(p) = self.pass.get_mut(pixel) {
            p.add(value, cost);
        }
    }

    /// The current pass's sums, row after row: for render threads that each add to their own
    /// rows (`chunks_mut(width)`).
    pub fn pass_mut(&mut self) -> &mut [PixelSums] {
        &mut self.pass
    }

    /// Replaces `Ĩ`, the pixels' estimated values, with the renderer's own (one per pixel, a
    /// denoised or better-combined image, say) from now on; `None` goes back to the mean of
    /// the samples. Values that are negative or not finite count as 0; a slice of the wrong
    /// length is ignored.
    pub fn set_estimate(&mut self, estimate: Option<&[f32]>) {
        match estimate {
            Some(e) if e.len() == self.pass.len() => self.estimate = Some(e.to_vec()),
            Some(_) => return,
            None => self.estimate = None,
        }
        self.smooth();
    }

    /// Ends a pass: its samples join `Ĩ`, and if it has enough samples per pixel its variance
    /// and cost become `V̄` and `C̄`. Starts the next pass empty.
    pub fn end_pass(&mut self) {
        for (t, p) in self.total.iter_mut().zip(&self.pass) {
            t.0 += p.sum;
            t.1 += u64::from(p.count);
        }
        self.passes += 1;
        self.smooth();
        let pixels = self.pass.len().max(1) as f64;
        let samples: f64 = self.pass.iter().map(|p| f64::from(p.count)).sum();
        if samples / pixels >= Self::MIN_SAMPLES {
            let variance: f64 = self
                .pass
                .iter()
                .zip(&self.mean_pixels)
                .filter(|(p, _)| p.count >= 2)
                .map(|(p, &big_p)| {
                    let n = f64::from(p.count);
                    let var = ((p.sum_sq - p.sum * p.sum / n) / (n - 1.0)).max(0.0);
                    var / f64::from(big_p * big_p)
                })
                .sum::<f64>()
                / pixels;
            let cost = self.pass.iter().map(|p| p.cost).sum::<f64>() / samples;
            self.terms = Some((variance, cost));
        }
        self.pass.fill(PixelSums::default());
    }

    /// Passes ended so far.
    pub fn passes(&self) -> u32 {
        self.passes
    }

    /// `P = sqrt(Ĩ² + ε)` of a pixel, for [`Splitting::factor`] (`sqrt(ε)` before the first
    /// pass and outside the image).
    #[inline]
    pub fn pixel(&self, pixel: usize) -> f32 {
        self.p_in(&self.pixels, pixel)
    }

    /// `P` of a pixel from its neighbourhood's mean alone, without the median's bound: what
    /// `V̄` and [`pass_weights`] divide by.
    fn mean_pixel(&self, pixel: usize) -> f32 {
        self.p_in(&self.mean_pixels, pixel)
    }

    /// Pixel `pixel`'s `P` in `values`, `sqrt(ε)` outside the image.
    #[inline]
    fn p_in(&self, values: &[f32], pixel: usize) -> f32 {
        values
            .get(pixel)
            .copied()
            .unwrap_or_else(|| self.epsilon.sqrt())
    }

    /// `V̄`: the image's per-sample relative variance, averaged over pixels (`None` before a
    /// pass with enough samples).
    pub fn relative_variance(&self) -> Option<f64> {
        self.terms.map(|(v, _)| v)
    }

    /// `C̄`: the mean cost of a camera sample (`None` before a pass with enough samples).
    pub fn cost_per_sample(&self) -> Option<f64> {
        self.terms.map(|(_, c)| c)
    }

    /// The policy for the next pass, with the default bounds: `None` before a pass with
    /// enough samples, or when its variance or cost is zero (a black image, or one without
    /// noise, has nothing to gain).
    pub fn splitting(&self, mode: SplittingMode) -> Option<Splitting> {
        let (v, c) = self.terms?;
        (v > 0.0 && v.is_finite() && c > 0.0 && c.is_finite()).then(|| Splitting::new(mode, v, c))
    }

    /// Recomputes `P` from `Ĩ`: the estimate (the renderer's, or the samples' mean), averaged
    /// over each pixel's 3×3 neighbourhood, and at most [`MEDIAN_BOUND`] times the
    /// neighbourhood's median (the lower of the two middle values where the image's border
    /// leaves an even count).
    ///
    /// The mean alone carries a bright neighbour into `P`: a pixel beside a light, or beside a
    /// firefly of an earlier pass, takes `P` many times its own value, its paths are rouletted
    /// at the least survival, and the few that survive weigh `1/q` times more — the fireflies
    /// of the next pass (measured on `glossy-box`: a pixel at the light's corner with `P` 100×
    /// its value gave one sample worth 72% of the image's relMSE). The bound leaves the mean
    /// wherever a minority of neighbours does not dominate it.
    ///
    /// `V̄` (and [`pass_weights`]) divide by `P` from the mean alone: where a pixel's estimates
    /// are spikes of rare paths (a room lit through a gap) the median is far below the mean,
    /// and a bounded `P` there inflates `V̄`, which roulettes every other pixel harder
    /// (measured with the recommended configuration: `door` 1.36×, `caustic` 1.50× the relMSE
    /// per sample when `V̄` used it).
    fn smooth(&mut self) {
        let (w, h) = (self.width, self.height);
        let value = |i: usize| -> f32 {
            let v = match &self.estimate {
                Some(e) => e[i],
                None => {
                    let (sum, n) = self.total[i];
                    if n > 0 { (sum / n as f64) as f32 } else { 0.0 }
                }
            };
            if v.is_finite() { v.max(0.0) } else { 0.0 }
        };
        let lum: Vec<f32> = (0..w * h).map(value).collect();
        for y in 0..h {
            for x in 0..w {
                let mut near = [0.0f32; 9];
                let mut n = 0;
                for yy in y.saturating_sub(1)..(y + 2).min(h) {
                    for xx in x.saturating_sub(1)..(x + 2).min(w) {
                        near[n] = lum[yy * w + xx];
                        n += 1;
                    }
                }
                let near = &mut near[..n];
                let mean = near.iter().sum::<f32>() / n as f32;
                near.sort_unstable_by(f32::total_cmp);
                let i = mean.min(MEDIAN_BOUND * near[(n - 1) / 2]);
                self.mean_pixels[y * w + x] = (mean * mean + self.epsilon).sqrt();
                self.pixels[y * w + x] = (i * i + self.epsilon).sqrt();
            }
        }
    }
}

/// The weights that combine a render's passes into one image by inverse variance: pixel
/// `Σₖ wₖ · sumₖ/countₖ`, with `Σₖ wₖ = 1` (Müller et al. 2019, "Practical path guiding in
/// production": the weighted mean of independent unbiased estimates with the least variance
/// weighs each by `1/Vₖ`).
///
/// `passes` holds each pass's sums per pixel (`width × height`, row after row, values in
/// luminance), oldest first; the last is the render's own, the one with the most samples.
/// A pass's `Vₖ` is the mean over pixels of its pixel means' variances, each relative to the
/// last pass's image (divided by `P² = Ĩ² + ε`, `Ĩ` its luminance over the pixel's 3×3
/// neighbourhood, as [`ImageStatistics`]'s `V̄`), so that a pass noisy in dark pixels, which
/// a relative error weighs most, is not weighed by its bright ones. For every pass but the
/// last, `Vₖ` is at least the distance of its image from the last's less the last's variance
/// (`E[(Iₖ − I_last)²] = Vₖ + V_last`): a pass of few samples mostly underestimates its own
/// heavy-tailed variance, and its distance counts the outliers it did draw.
///
/// A pass is left out (weight 0) when one of its pixels has fewer than two samples (no
/// variance to estimate), when its sums have another length than the image, or when its
/// variance is zero or not finite (a NaN in its sums). `None` when no pass is left, or when
/// the last pass has another length than the image.
///
/// The weights depend on the images they weigh, but each pools every pixel of a pass, so its
/// correlation with any one pixel, the bias it brings, falls as one over the pixel count.
///
/// ```
/// use sdguide::{pass_weights, PixelSums};
/// // Two passes of a one-pixel image, `n` samples of 0 and 2 each: 4 and 12 samples. A pass's
/// // pixel mean has variance `1/(n − 1)`, so the weights are ∝ 3 and 11.
/// let pass = |n: u32| {
///     let n_f = f64::from(n);
///     vec![PixelSums { sum: n_f, sum_sq: 2.0 * n_f, cost: 0.0, count: n }]
/// };
/// let (early, last) = (pass(4), pass(12));
/// let w = pass_weights(1, 1, &[&early, &last]).unwrap();
/// assert!((w[0] - 3.0 / 14.0).abs() < 1e-12 && (w[1] - 11.0 / 14.0).abs() < 1e-12);
/// ```
pub fn pass_weights(width: usize, height: usize, passes: &[&[PixelSums]]) -> Option<Vec<f64>> {
    let n = width.saturating_mul(height);
    let mean = |p: &PixelSums| {
        if p.count > 0 {
            p.sum / f64::from(p.count)
        } else {
            0.0
        }
    };
    let last = passes.last().filter(|p| p.len() == n)?;
    let last_index = passes.len() - 1;
    let last_mean: Vec<f64> = last.iter().map(mean).collect();
    let mut smoothed = ImageStatistics::new(width, height);
    let estimate: Vec<f32> = last_mean.iter().map(|&m| m as f32).collect();
    smoothed.set_estimate(Some(&estimate));
    let relative: Vec<f64> = (0..n)
        .map(|p| 1.0 / f64::from(smoothed.mean_pixel(p)).powi(2))
        .collect();
    // The mean over pixels of each pixel mean's relative variance; `None` below 2 samples.
    let variance = |pass: &[PixelSums]| -> Option<f64> {
        let mut total = 0.0;
        for (p, &w) in pass.iter().zip(&relative) {
            if p.count < 2 {
                return None;
            }
            let k = f64::from(p.count);
            total += w * ((p.sum_sq - p.sum * p.sum / k) / (k - 1.0)).max(0.0) / k;
        }
        Some(total / n.max(1) as f64)
    };
    let last_variance = variance(last);
    let mut weights: Vec<f64> = passes
        .iter()
        .enumerate()
        .map(|(i, pass)| {
            if pass.len() != n {
                return 0.0;
            }
            let Some(own) = variance(pass).filter(|v| v.is_finite()) else {
                return 0.0;
            };
            let v = match last_variance {
                Some(v_last) if i < last_index => {
                    let distance = pass
                        .iter()
                        .zip(&last_mean)
                        .zip(&relative)
                        .map(|((p, &b), &w)| w * (mean(p) - b).powi(2))
                        .sum::<f64>()
                        / n.max(1) as f64;
                    own.max(distance - v_last)
                }
                _ => own,
            };
            if v > 0.0 && v.is_finite() {
                1.0 / v
            } else {
                0.0
            }
        })
        .collect();
    let total: f64 = weights.iter().sum();
    if !(total > 0.0 && total.is_finite()) {
        return None;
    }
    weights.iter_mut().for_each(|w| *w /= total);
    Some(weights)
}
