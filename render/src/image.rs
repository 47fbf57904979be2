//! Images: linear RGB buffers, the error metric, and the files a run writes (tone-mapped PNG,
//! linear EXR, and the side-by-side comparison with false-colour error).

use glam::Vec3;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

/// A linear RGB image, row-major, top row first.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `width × height` pixels.
    pub pixels: Vec<Vec3>,
}

/// Errors reading or writing image files.
#[derive(Debug)]
pub enum ImageError {
    /// The file system refused.
    Io(std::io::Error),
    /// The EXR library refused or the file is not an RGB EXR.
    Exr(String),
    /// The PNG encoder refused.
    Png(String),
}

impl std::fmt::Display for ImageError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ImageError::Io(e) => write!(f, "{e}"),
            ImageError::Exr(e) => write!(f, "EXR: {e}"),
            ImageError::Png(e) => write!(f, "PNG: {e}"),
        }
    }
}

impl std::error::Error for ImageError {}

impl From<std::io::Error> for ImageError {
    fn from(e: std::io::Error) -> Self {
        ImageError::Io(e)
    }
}

impl Image {
    /// A black image.
    pub fn new(width: usize, height: usize) -> Self {
        Image {
            width,
            height,
            pixels: vec![Vec3::ZERO; width * height],
        }
    }

    /// Mean over pixels and channels.
    pub fn mean(&self) -> f64 {
        self.pixels
            .iter()
            .map(|p| (p.x + p.y + p.z) as f64)
            .sum::<f64>()
            / (3 * self.pixels.len()) as f64
    }

    /// How far this image's mean lies from `reference`'s, in standard errors: the mean over
    /// pixels of the difference of their channel means, divided by its standard error. Pixels
    /// are independent estimates (each has random streams of its own, and the reference has
    /// others), so the standard error is the differences' sample deviation over √N. An unbiased
    /// render gives a standard normal number; |z| > 3 flags a bias.
    pub fn mean_deviation(&self, reference: &Image) -> f64 {
        assert_eq!(
            (self.width, self.height),
            (reference.width, reference.height)
        );
        let d: Vec<f64> = self
            .pixels
            .iter()
            .zip(&reference.pixels)
            .map(|(i, r)| (*i - *r).element_sum() as f64 / 3.0)
            .collect();
        let n = d.len() as f64;
        let mean = d.iter().sum::<f64>() / n;
        let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
        let se = (var / n).sqrt();
        match (se > 0.0, mean == 0.0) {
            (true, _) => mean / se,
            (false, true) => 0.0,
            (false, false) => mean.signum() * f64::INFINITY,
        }
    }

    /// The relative mean squared error against `reference`:
    /// `mean over pixels and channels of (I − R)² / (R² + 0.01)`.
    pub fn rel_mse(&self, reference: &Image) -> f64 {
        assert_eq!(
            (self.width, self.height),
            (reference.width, reference.height)
        );
        let sum: f64 = self
            .pixels
            .iter()
            .zip(&reference.pixels)
            .map(|(i, r)| rel_se(*i, *r) as f64)
            .sum();
        sum / self.pixels.len() as f64
    }

    /// Writes the image as a 32-bit float RGB OpenEXR file.
    ///
    /// # Errors
    ///
    /// [`ImageError::Exr`] when the file cannot be written.
    pub fn write_exr(&self, path: &Path) -> Result<(), ImageError> {
        exr::prelude::write_rgb_file(path, self.width, self.height, |x, y| {
            let p = self.pixels[y * self.width + x];
            (p.x, p.y, p.z)
        })
        .map_err(|e| ImageError::Exr(e.to_string()))
    }

    /// Reads the first RGB(A) layer of an OpenEXR file.
    ///
    /// # Errors
    ///
    /// [`ImageError::Exr`] when the file cannot be read or has no RGB layer.
    pub fn read_exr(path: &Path) -> Result<Image, ImageError> {
        let image = exr::prelude::read_first_rgba_layer_from_file(
            path,
            |resolution, _| Image::new(resolution.width(), resolution.height()),
            |image: &mut Image, position, (r, g, b, _a): (f32, f32, f32, f32)| {
                let w = image.width;
                image.pixels[position.y() * w + position.x()] = Vec3::new(r, g, b);
            },
        )
        .map_err(|e| ImageError::Exr(e.to_string()))?;
        Ok(image.layer_data.channel_data.pixels)
    }

    /// 8-bit sRGB pixels after `exposure` and Reinhard's `x / (1 + x)` per channel.
    pub fn to_srgb8(&self, exposure: f32) -> Vec<[u8; 3]> {
        self.pixels
            .iter()
            .map(|&p| tone_map(p * exposure))
            .collect()
    }

    /// Writes the tone-mapped image as an 8-bit sRGB PNG.
    ///
    /// # Errors
    ///
    /// As [`write_png`](fn@write_png).
    pub fn write_png(&self, path: &Path, exposure: f32) -> Result<(), ImageError> {
        write_png(path, self.width, self.height, &self.to_srgb8(exposure))
    }
}

/// Per-pixel relative squared error, averaged over channels.
pub fn rel_se(i: Vec3, r: Vec3) -> f32 {
    let d = i - r;
    ((d * d) / (r * r + Vec3::splat(0.01))).element_sum() / 3.0
}

/// Reinhard per channel, then the sRGB transfer curve.
fn tone_map(c: Vec3) -> [u8; 3] {
    let encode = |x: f32| {
        let x = if x.is_finite() { x.max(0.0) } else { 0.0 };
        let x = x / (1.0 + x);
        let s = if x <= 0.003_130_8 {
            12.92 * x
        } else {
            1.055 * x.powf(1.0 / 2.4) - 0.055
        };
        (s * 255.0 + 0.5).clamp(0.0, 255.0) as u8
    };
    [encode(c.x), encode(c.y), encode(c.z)]
}

/// A perceptually ordered false-colour ramp (black → purple → orange → yellow) for `t` in
/// `[0, 1]`.
pub fn false_colour(t: f32) -> [u8; 3] {
    const STOPS: [[f32; 3]; 5] = [
        [0.0, 0.0, 0.02],
        [0.32, 0.07, 0.48],
        [0.74, 0.22, 0.33],
        [0.98, 0.56, 0.04],
        [0.99, 0.99, 0.75],
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        1.0
    } * (STOPS.len() - 1) as f32;
    let i = (t as usize).min(STOPS.len() - 2);
    let f = t - i as f32;
    let mut out = [0u8; 3];
    for (c, o) in out.iter_mut().enumerate() {
        *o = ((STOPS[i][c] * (1.0 - f) + STOPS[i + 1][c] * f) * 255.0 + 0.5) as u8;
    }
    out
}

/// Writes 8-bit RGB pixels as a PNG.
///
/// # Errors
///
/// An [`ImageError`] when the file cannot be created or encoded.
pub fn write_png(
    path: &Path,
    width: usize,
    height: usize,
    pixels: &[[u8; 3]],
) -> Result<(), ImageError> {
    let mut encoder = png::Encoder::new(
        BufWriter::new(File::create(path)?),
        width as u32,
        height as u32,
    );
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder
        .write_header()
        .map_err(|e| ImageError::Png(e.to_string()))?;
    writer
        .write_image_data(pixels.as_flattened())
        .map_err(|e| ImageError::Png(e.to_string()))
}

/// The comparison sheet: the reference and every method's image on the top row, each image's
/// per-pixel relative squared error below it in false colour (log scale, 10⁻⁴ to 10, black to
/// yellow). Columns are separated by a 4-pixel gap.
pub fn side_by_side(
    reference: &Image,
    images: &[&Image],
    exposure: f32,
) -> (usize, usize, Vec<[u8; 3]>) {
    const GAP: usize = 4;
    let (w, h) = (reference.width, reference.height);
    let columns = 1 + images.len();
    let (sheet_w, sheet_h) = (columns * w + (columns - 1) * GAP, 2 * h + GAP);
    let mut sheet = vec![[255u8; 3]; sheet_w * sheet_h];
    let mut blit = |column: usize, row: usize, pixels: &[[u8; 3]]| {
        let (x0, y0) = (column * (w + GAP), row * (h + GAP));
        for y in 0..h {
            let dst = (y0 + y) * sheet_w + x0;
            sheet[dst..dst + w].copy_from_slice(&pixels[y * w..(y + 1) * w]);
        }
    };
    blit(0, 0, &reference.to_srgb8(exposure));
    for (k, image) in images.iter().enumerate() {
        blit(k + 1, 0, &image.to_srgb8(exposure));
        let error: Vec<[u8; 3]> = image
            .pixels
            .iter()
            .zip(&reference.pixels)
            .map(|(&i, &r)| false_colour((rel_se(i, r).max(1e-4).log10() + 4.0) / 5.0))
            .collect();
        blit(k + 1, 1, &error);
    }
    // Under the reference: the colour ramp, as a legend.
    let legend: Vec<[u8; 3]> = (0..w * h)
        .map(|i| false_colour((i % w) as f32 / (w - 1).max(1) as f32))
        .collect();
    blit(0, 1, &legend);
    (sheet_w, sheet_h, sheet)
}
