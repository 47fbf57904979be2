//! Image statistics against hand-computed images: the smoothed pixel values, the relative
//! variance and cost per sample, the gate on samples per pixel, bad input; and the weights that
//! combine passes by inverse variance.

use sdguide::{
    ContinuationEstimate, ImageStatistics, PixelSums, Splitting, SplittingMode, pass_weights,
};

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1.0)
}

/// A 3×1 image: pixel values alternate `m ± d` per sample, `spp` samples, cost `c` each.
fn pass(image: &mut ImageStatistics, means: [f32; 3], d: f32, spp: u32, c: f32) {
    for i in 0..spp {
        for (p, &m) in means.iter().enumerate() {
            let v = if i % 2 == 0 { m - d } else { m + d };
            image.add(p, v, c);
        }
    }
    image.end_pass();
}

#[test]
fn the_terms_follow_their_definitions() {
    let mut image = ImageStatistics::new(3, 1);
    pass(&mut image, [1.0, 2.0, 4.0], 0.5, 8, 3.0);
    // Ĩ: each pixel's 3×3 neighbourhood, clipped to the image: (1+2)/2, (1+2+4)/3, (2+4)/2.
    let smoothed = [1.5f32, 7.0 / 3.0, 3.0];
    let eps = ImageStatistics::DEFAULT_EPSILON;
    for (p, i) in smoothed.iter().enumerate() {
        assert!(
            (image.pixel(p) - (i * i + eps).sqrt()).abs() < 1e-6,
            "pixel {p}"
        );
    }
    // V̄: the sample variance of ±0.5 over 8 samples is 8/7·0.25 in every pixel, over P².
    let var = 8.0 / 7.0 * 0.25;
    let expected = smoothed
        .iter()
        .map(|&i| var / f64::from(i * i + eps))
        .sum::<f64>()
        / 3.0;
    assert!(close(image.relative_variance().unwrap(), expected));
    assert_eq!(image.cost_per_sample(), Some(3.0));
    let policy = image
        .splitting(SplittingMode::RouletteAndSplitting)
        .unwrap();
    // The policy is the one built from those terms: the same factor for any cell.
    let mine = Splitting::new(SplittingMode::RouletteAndSplitting, expected, 3.0);
    let cell = ContinuationEstimate {
        sum: 32.0,
        sum_sq: 96.0,
        cost: 128.0,
        count: 32,
    };
    for throughput in [0.01, 0.1, 1.0] {
        let a = policy.factor(&cell, throughput, 1.0).unwrap();
        let b = mine.factor(&cell, throughput, 1.0).unwrap();
        assert!(
            (a - b).abs() <= 1e-6 * b,
            "throughput {throughput}: {a} against {b}"
        );
    }
}

#[test]
fn a_pass_with_few_samples_joins_the_estimate_but_sets_no_policy() {
    let mut image = ImageStatistics::new(3, 1);
    pass(&mut image, [1.0, 1.0, 1.0], 0.5, 2, 1.0);
    assert!(image.splitting(SplittingMode::Roulette).is_none());
    assert!((image.pixel(1) - 1.01f32.sqrt()).abs() < 1e-6);
    // A later pass with enough samples sets it; then a short pass keeps it.
    pass(&mut image, [3.0, 3.0, 3.0], 1.0, 6, 2.0);
    let v = image.relative_variance().unwrap();
    assert_eq!(image.cost_per_sample(), Some(2.0));
    // Ĩ is the mean of all 8 samples per pixel: (2·1 + 6·3)/8 = 2.5.
    assert!((image.pixel(0) - (2.5f32 * 2.5 + 0.01).sqrt()).abs() < 1e-6);
    pass(&mut image, [1.0, 1.0, 1.0], 0.5, 2, 9.0);
    assert_eq!(image.relative_variance(), Some(v));
    assert_eq!(image.passes(), 3);
    // A noiseless pass has nothing to gain: no policy.
    let mut flat = ImageStatistics::new(3, 1);
    pass(&mut flat, [1.0, 1.0, 1.0], 0.0, 8, 1.0);
    assert!(flat.splitting(SplittingMode::Roulette).is_none());
}

#[test]
fn the_renderers_estimate_replaces_the_mean() {
    let mut image = ImageStatistics::new(3, 1).with_epsilon(0.25).unwrap();
    image.set_estimate(Some(&[2.0, 2.0, 2.0]));
    assert!((image.pixel(2) - (4.0f32 + 0.25).sqrt()).abs() < 1e-6);
    image.set_estimate(Some(&[1.0])); // the wrong length: ignored
    assert!((image.pixel(2) - (4.0f32 + 0.25).sqrt()).abs() < 1e-6);
    image.set_estimate(None);
    assert!((image.pixel(2) - 0.5).abs() < 1e-6);
    assert!(ImageStatistics::new(1, 1).with_epsilon(0.0).is_err());
    assert!(ImageStatistics::new(1, 1).with_epsilon(f32::NAN).is_err());
}

#[test]
fn a_bright_neighbour_raises_a_pixels_value_at_most_threefold_its_neighbourhoods_median() {
    // A 4×4 image of 0.1 with a 2×2 light of 60 in its corner. The mean over the neighbourhood
    // alone would give the pixel diagonal to the light (60 + 8·0.1)/9 ≈ 6.8, 68 times its value.
    let mut image = ImageStatistics::new(4, 4);
    let light = |x: usize, y: usize| x < 2 && y < 2;
    let values: Vec<f32> = (0..16)
        .map(|p| if light(p % 4, p / 4) { 60.0 } else { 0.1 })
        .collect();
    image.set_estimate(Some(&values));
    let p = |v: f32| (v * v + ImageStatistics::DEFAULT_EPSILON).sqrt();
    let near = |a: f32, b: f32| (a - b).abs() <= 1e-6 * b;
    // Beside the light: its neighbourhood's median is 0.1 (the lower middle value where the
    // border leaves an even count), so Ĩ = 3 · 0.1.
    for (x, y) in [(2, 2), (2, 0), (2, 1), (0, 2)] {
        assert!(
            near(image.pixel(y * 4 + x), p(3.0 * 0.1)),
            "pixel ({x}, {y})"
        );
    }
    // Away from it, the mean: 0.1.
    assert!(near(image.pixel(15), p(0.1)));
    // Inside the light: 4 of its corner pixel's 4 neighbours are the light (the mean, 60), 4
    // of its edge pixel's 6 (median 60, mean 40.03).
    assert!(near(image.pixel(0), p(60.0)));
    assert!(near(image.pixel(1), p((4.0 * 60.0 + 2.0 * 0.1) / 6.0)));
    // V̄ divides by P from the neighbourhood's mean alone: a pass of ±0.05 about each value,
    // 8 samples a pixel (sample variance 8/7·0.0025 everywhere).
    for i in 0..8 {
        for (pixel, &v) in values.iter().enumerate() {
            image.add(pixel, if i % 2 == 0 { v - 0.05 } else { v + 0.05 }, 1.0);
        }
    }
    image.end_pass();
    let mean = |x: usize, y: usize| {
        let (mut sum, mut n) = (0.0f32, 0.0f32);
        for yy in y.saturating_sub(1)..(y + 2).min(4) {
            for xx in x.saturating_sub(1)..(x + 2).min(4) {
                sum += values[yy * 4 + xx];
                n += 1.0;
            }
        }
        sum / n
    };
    let var = 8.0 / 7.0 * 0.0025;
    let expected = (0..16)
        .map(|q| var / f64::from(p(mean(q % 4, q / 4)).powi(2)))
        .sum::<f64>()
        / 16.0;
    let got = image.relative_variance().unwrap();
    assert!(
        (got - expected).abs() <= 1e-4 * expected,
        "{got} {expected}"
    );
}

#[test]
fn bad_samples_count_as_zero_and_stray_pixels_are_ignored() {
    let mut image = ImageStatistics::new(2, 1);
    for v in [f32::NAN, f32::INFINITY, -1.0, 2.0] {
        image.add(0, v, f32::NAN);
        image.add(1, 2.0, 1.0);
        image.add(7, 1.0, 1.0);
    }
    image.end_pass();
    // Pixel 0 saw 0, 0, 0, 2: mean 0.5; pixel 1 saw 2 four times. Smoothed over both: 1.25.
    assert!((image.pixel(0) - (1.25f32 * 1.25 + 0.01).sqrt()).abs() < 1e-6);
    assert!(image.relative_variance().unwrap().is_finite());
    assert_eq!(image.cost_per_sample(), Some(0.5));
    assert_eq!(image.pixel(99), 0.01f32.sqrt());
    // A zero-sized image answers too.
    let mut empty = ImageStatistics::new(0, 5);
    empty.end_pass();
    assert!(empty.splitting(SplittingMode::Roulette).is_none());
}

/// A one-pixel pass of the samples `values`.
fn one_pixel(values: &[f32]) -> Vec<PixelSums> {
    let mut p = PixelSums::default();
    values.iter().for_each(|&v| p.add(v, 1.0));
    vec![p]
}

fn weights_close(w: &[f64], expected: &[f64]) -> bool {
    w.len() == expected.len() && w.iter().zip(expected).all(|(&a, &b)| close(a, b))
}

#[test]
fn passes_are_weighed_by_their_inverse_variances() {
    // The last pass: samples 1 and 3, mean 2, sample variance 2, the mean's variance 1. An
    // earlier one with the same mean: 0, 0, 2, 6, sample variance 8, the mean's 2. A pixel's
    // relative factor is the same for every pass, so the weights are ∝ 1/2 and 1.
    let last = one_pixel(&[1.0, 3.0]);
    let same_mean = one_pixel(&[0.0, 0.0, 2.0, 6.0]);
    let w = pass_weights(1, 1, &[&same_mean, &last]).unwrap();
    assert!(weights_close(&w, &[1.0 / 3.0, 2.0 / 3.0]), "{w:?}");
    // An earlier pass far from the last: 3 and 7, mean 5, its own variance 4, but by its
    // distance 3² − 1 = 8, which counts: weights ∝ 1/8 and 1.
    let far = one_pixel(&[3.0, 7.0]);
    let w = pass_weights(1, 1, &[&far, &last]).unwrap();
    assert!(weights_close(&w, &[1.0 / 9.0, 8.0 / 9.0]), "{w:?}");
    // The last pass is weighed by its own variance only: last 3, 7 (variance 4); the earlier
    // 1, 3 at distance 9 − 4 = 5 > 1. Weights ∝ 1/5 and 1/4.
    let w = pass_weights(1, 1, &[&last, &far]).unwrap();
    assert!(weights_close(&w, &[4.0 / 9.0, 5.0 / 9.0]), "{w:?}");
    // Pixels are averaged: a second, constant pixel halves a pass's variance, in every pass
    // alike (the relative factors are equal: the 3×3 smoothing spans the 2×1 image).
    let two = |a: &[f32]| {
        let mut p = one_pixel(a);
        p.extend(one_pixel(&vec![7.0; a.len()]));
        p
    };
    let w = pass_weights(2, 1, &[&two(&[0.0, 0.0, 2.0, 6.0]), &two(&[1.0, 3.0])]).unwrap();
    assert!(weights_close(&w, &[1.0 / 3.0, 2.0 / 3.0]), "{w:?}");
}

#[test]
fn passes_without_a_variance_are_left_out() {
    let last = one_pixel(&[1.0, 3.0]);
    // One sample a pixel, zero variance, a NaN, or another size: weight 0.
    let single = one_pixel(&[5.0]);
    let flat = one_pixel(&[2.0, 2.0]);
    let mut nan = one_pixel(&[1.0, 3.0]);
    nan[0].sum_sq = f64::NAN;
    let mut sum_nan = one_pixel(&[1.0, 3.0]);
    sum_nan[0].sum = f64::NAN;
    let wrong = one_pixel(&[1.0, 3.0]).repeat(2);
    let passes = [&single, &flat, &nan, &sum_nan, &wrong, &last].map(Vec::as_slice);
    let w = pass_weights(1, 1, &passes).unwrap();
    assert!(weights_close(&w, &[0.0, 0.0, 0.0, 0.0, 0.0, 1.0]), "{w:?}");
    // Nothing to weigh: no pass, no pass with a variance, a last pass of another size, an
    // empty image.
    assert!(pass_weights(1, 1, &[]).is_none());
    assert!(pass_weights(1, 1, &[&single, &flat]).is_none());
    assert!(pass_weights(1, 1, &[&last, &wrong]).is_none());
    assert!(pass_weights(0, 0, &[&[]]).is_none());
}

/// A small generator for the statistical test (SplitMix64).
struct Rng(u64);

impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
}

#[test]
fn passes_of_equal_samples_are_weighed_by_their_sample_counts_and_combine_unbiased() {
    // 32×32 pixels of exponentially distributed samples (mean μₚ varying over the image);
    // passes of 4, 8, 16 and 64 samples a pixel, all of the same per-sample variance: the
    // ideal weights are ∝ the counts. Each pass's pooled variance has a relative standard
    // deviation of about sqrt((κ − 1)/(n·P)) (κ = 9, the exponential's kurtosis; P = 1024
    // pixels): ≤ 0.044 at n = 4; the earlier passes' `max(own, distance − V_last)` adds at
    // most about half of that. A ratio of two weights is then within 25% of the ideal at
    // five standard deviations.
    let (width, height) = (32, 32);
    let counts = [4u32, 8, 16, 64];
    let mu = |p: usize| 0.2 + (p % width) as f64 / width as f64 + (p / width) as f64 / 16.0;
    let mut rng = Rng(7);
    let passes: Vec<Vec<PixelSums>> = counts
        .iter()
        .map(|&n| {
            (0..width * height)
                .map(|p| {
                    let mut s = PixelSums::default();
                    for _ in 0..n {
                        s.add((-mu(p) * (1.0 - rng.uniform()).ln()) as f32, 1.0);
                    }
                    s
                })
                .collect()
        })
        .collect();
    let views: Vec<&[PixelSums]> = passes.iter().map(Vec::as_slice).collect();
    let w = pass_weights(width, height, &views).unwrap();
    let total: f64 = counts.iter().map(|&n| f64::from(n)).sum();
    for (k, &n) in counts.iter().enumerate() {
        let ideal = f64::from(n) / total;
        assert!(
            (w[k] / ideal - 1.0).abs() < 0.25,
            "pass {k}: {} vs {ideal}",
            w[k]
        );
    }
    assert!(close(w.iter().sum(), 1.0));
    // The combined image's mean over pixels is within 4σ of the true mean, σ the combined
    // image's (each pass's pixel mean has variance μₚ²/n).
    let combined_mean: f64 = (0..width * height)
        .map(|p| {
            views
                .iter()
                .zip(&w)
                .map(|(pass, &wk)| wk * pass[p].sum / f64::from(pass[p].count))
                .sum::<f64>()
        })
        .sum::<f64>()
        / (width * height) as f64;
    let truth: f64 = (0..width * height).map(mu).sum::<f64>() / (width * height) as f64;
    let variance: f64 = (0..width * height)
        .map(|p| {
            counts
                .iter()
                .zip(&w)
                .map(|(&n, &wk)| wk * wk * mu(p).powi(2) / f64::from(n))
                .sum::<f64>()
        })
        .sum::<f64>()
        / ((width * height) as f64).powi(2);
    assert!(
        (combined_mean - truth).abs() < 4.0 * variance.sqrt(),
        "{combined_mean} vs {truth} ± {}",
        variance.sqrt()
    );
}
