//! `sdguide.ImageStatistics` and `continuations`: the library's efficiency-aware roulette and
//! splitting for a wavefront renderer (the factor itself is `GuidingField.splitting_factor`).
//!
//! Each pass, the renderer adds its camera samples (pixel, luminance, rays) and ends the pass;
//! from then on `GuidingField.splitting_factor` gives each vertex's factor `q` from its cell's
//! continuation estimate, its throughput and its pixel, and `continuations` rounds it to a
//! number of continuations and their weight. See the Rust `Splitting` for the derivation.
//!
//! `pass_weights` combines a render's passes (training passes with the final render) into one
//! image by inverse variance, from the same per-pixel sums.

use crate::arrays::{Input, input, optional};
use crate::errors::config_error;
use numpy::PyArray1;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use sdguide::{ImageStatistics, PixelSums, SplittingMode};

/// A render's camera samples per pixel over its passes, and the image terms of the
/// efficiency-aware factor they give for the next pass.
#[pyclass(name = "ImageStatistics", module = "sdguide")]
pub struct PyImageStatistics {
    pub(crate) inner: ImageStatistics,
    pixels: usize,
}

#[pymethods]
impl PyImageStatistics {
    /// Empty statistics of a `width × height` image (pixels indexed `y·width + x`), with the
    /// relative error's `epsilon` (finite and positive; `ConfigError` otherwise).
    #[new]
    #[pyo3(signature = (width, height, epsilon = ImageStatistics::DEFAULT_EPSILON))]
    fn new(width: usize, height: usize, epsilon: f32) -> PyResult<Self> {
        let inner = ImageStatistics::new(width, height)
            .with_epsilon(epsilon)
            .map_err(|e| config_error(e.to_string()))?;
        Ok(Self {
            inner,
            pixels: width.saturating_mul(height),
        })
    }

    /// Adds camera samples: `values[i]` (a luminance) that cost `costs[i]` (rays) in pixel
    /// `pixels[i]` (`uint32`); negative or non-finite values and costs count as 0, pixels
    /// outside the image are ignored.
    fn add(
        &mut self,
        pixels: &Bound<'_, PyAny>,
        values: &Bound<'_, PyAny>,
        costs: &Bound<'_, PyAny>,
    ) -> PyResult<()> {
        let pixels: Input<u32> = input(pixels, "pixels", None, None)?;
        let n = pixels.slice().len();
        let values: Input<f32> = input(values, "values", Some(n), None)?;
        let costs: Input<f32> = input(costs, "costs", Some(n), None)?;
        for ((&p, &v), &c) in pixels.slice().iter().zip(values.slice()).zip(costs.slice()) {
            self.inner.add(p as usize, v, c);
        }
        Ok(())
    }

    /// Ends the pass: its samples join the pixel estimates, and with at least 4 samples per
    /// pixel its variance and cost set the next pass's factors.
    fn end_pass(&mut self) {
        self.inner.end_pass();
    }

    /// Replaces the pixels' estimated values with `estimate` (`(H·W,)` float32, a denoised
    /// image's luminance, say), or with `None` goes back to the samples' mean.
    #[pyo3(signature = (estimate = None))]
    fn set_estimate(&mut self, estimate: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
        let estimate: Option<Input<f32>> = optional(estimate, "estimate", self.pixels, None)?;
        self.inner
            .set_estimate(estimate.as_ref().map(|e| e.slice()));
        Ok(())
    }

    /// `P = sqrt(Ĩ² + ε)` of every pixel, `(H·W,)`.
    fn pixel_values<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f32>> {
        PyArray1::from_vec(py, (0..self.pixels).map(|p| self.inner.pixel(p)).collect())
    }

    /// `V̄`, the image's per-sample relative variance averaged over pixels (`None` before a
    /// pass with enough samples).
    #[getter]
    fn relative_variance(&self) -> Option<f64> {
        self.inner.relative_variance()
    }

    /// `C̄`, the mean cost of a camera sample (`None` before a pass with enough samples).
    #[getter]
    fn cost_per_sample(&self) -> Option<f64> {
        self.inner.cost_per_sample()
    }

    /// Passes ended so far.
    #[getter]
    fn passes(&self) -> u32 {
        self.inner.passes()
    }
}

pub(crate) fn parse_mode(text: &str) -> PyResult<SplittingMode> {
    match text.to_ascii_lowercase().as_str() {
        "roulette" => Ok(SplittingMode::Roulette),
        "splitting" | "roulette_and_splitting" => Ok(SplittingMode::RouletteAndSplitting),
        _ => Err(PyValueError::new_err(format!(
            "`mode` is {text:?}: \"roulette\" or \"splitting\""
        ))),
    }
}

/// What `continuations` returns: the counts `(N,)` and the weights `(N,)`.
type Rounded<'py> = (Bound<'py, PyArray1<u32>>, Bound<'py, PyArray1<f32>>);

/// `(traced, weights)`: how many continuations each factor traces, by stochastic rounding
/// with the uniform numbers `u` (`⌊q⌋ + 1` with probability `q − ⌊q⌋`, else `⌊q⌋`), and the
/// weight `1/q` each carries; a factor that is not finite and positive (NaN: no factor)
/// traces one with weight 1.
#[pyfunction]
pub fn continuations<'py>(
    py: Python<'py>,
    factors: &Bound<'py, PyAny>,
    u: &Bound<'py, PyAny>,
) -> PyResult<Rounded<'py>> {
    let factors: Input<f32> = input(factors, "factors", None, None)?;
    let n = factors.slice().len();
    let u: Input<f32> = input(u, "u", Some(n), None)?;
    let (traced, weights): (Vec<u32>, Vec<f32>) = factors
        .slice()
        .iter()
        .zip(u.slice())
        .map(|(&q, &u)| sdguide::continuations(q, u))
        .unzip();
    Ok((
        PyArray1::from_vec(py, traced),
        PyArray1::from_vec(py, weights),
    ))
}

/// The weights `(K,)` float64 that combine `K` passes of a `width × height` image by inverse
/// variance (`Σₖ wₖ · sumsₖ/countsₖ` per pixel, `Σ wₖ = 1`; see the Rust `pass_weights`), or
/// `None` when no pass can be weighed. `sums` and `squares` are `(K, H·W)` float64: each
/// pass's per-pixel sums of its samples' luminance and squared luminance; `counts` is
/// `(K, H·W)` uint32, the samples per pixel. Passes come oldest first, the final render last.
/// A pass with a pixel of fewer than two samples, or with a NaN in its sums, gets weight 0.
#[pyfunction]
pub fn pass_weights<'py>(
    py: Python<'py>,
    width: usize,
    height: usize,
    sums: &Bound<'py, PyAny>,
    squares: &Bound<'py, PyAny>,
    counts: &Bound<'py, PyAny>,
) -> PyResult<Option<Bound<'py, PyArray1<f64>>>> {
    let pixels = width.saturating_mul(height);
    let sums: Input<f64> = input(sums, "sums", None, Some(pixels))?;
    let passes = sums.slice().len() / pixels.max(1);
    let squares: Input<f64> = input(squares, "squares", Some(passes), Some(pixels))?;
    let counts: Input<u32> = input(counts, "counts", Some(passes), Some(pixels))?;
    let sums: Vec<PixelSums> = sums
        .slice()
        .iter()
        .zip(squares.slice())
        .zip(counts.slice())
        .map(|((&sum, &sum_sq), &count)| PixelSums {
            sum,
            sum_sq,
            cost: 0.0,
            count,
        })
        .collect();
    let views: Vec<&[PixelSums]> = sums.chunks(pixels.max(1)).take(passes).collect();
    Ok(sdguide::pass_weights(width, height, &views).map(|w| PyArray1::from_vec(py, w)))
}
