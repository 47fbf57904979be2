//! Image statistics against hand-computed images: the smoothed pixel values, the relative
//! variance and cost per sample, the gate on samples per pixel, and bad input.

use sdguide::{ContinuationEstimate, ImageStatistics, Splitting, SplittingMode};

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
