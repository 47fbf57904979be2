//! A small log–log line plot written as PNG: a grid of panels, each with a few labelled series.
//! Text is drawn with the 8×8 bitmap font of `font8x8`, so the plot needs no system fonts.

use font8x8::UnicodeFonts;

/// One panel: a title and named series of `(x, y)` points (both axes logarithmic).
pub struct Panel {
    pub title: String,
    pub series: Vec<(&'static str, Vec<(f64, f64)>)>,
}

const PANEL_W: usize = 520;
const PANEL_H: usize = 380;
const COLUMNS: usize = 2;
/// Plot area inside a panel: left, top, right, bottom margins.
const MARGIN: [usize; 4] = [78, 34, 16, 44];
const COLOURS: [[u8; 3]; 4] = [[230, 120, 20], [30, 100, 220], [40, 40, 40], [40, 160, 60]];

struct Canvas {
    w: usize,
    h: usize,
    rgb: Vec<u8>,
}

impl Canvas {
    fn set(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < self.w && (y as usize) < self.h {
            let i = 3 * (y as usize * self.w + x as usize);
            self.rgb[i..i + 3].copy_from_slice(&c);
        }
    }

    /// A line `width` pixels thick (a square brush moved along the DDA steps).
    fn line(&mut self, a: (f64, f64), b: (f64, f64), c: [u8; 3], width: i64) {
        let steps = (b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil().max(1.0) as usize;
        for i in 0..=steps {
            let t = i as f64 / steps as f64;
            let (x, y) = (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
            for dx in 0..width {
                for dy in 0..width {
                    self.set(x as i64 + dx - width / 2, y as i64 + dy - width / 2, c);
                }
            }
        }
    }

    fn text(&mut self, x: usize, y: usize, s: &str, c: [u8; 3]) {
        for (k, ch) in s.chars().enumerate() {
            let glyph = font8x8::BASIC_FONTS.get(ch).unwrap_or([0; 8]);
            for (row, bits) in glyph.iter().enumerate() {
                for col in 0..8 {
                    if bits >> col & 1 == 1 {
                        self.set((x + 8 * k + col) as i64, (y + row) as i64, c);
                    }
                }
            }
        }
    }
}

/// Tick values for a logarithmic axis over `[lo, hi]`: 1, 2 and 5 times powers of ten when the
/// range is short, powers of ten otherwise.
fn ticks(lo: f64, hi: f64) -> Vec<f64> {
    let mantissas: &[f64] = if hi / lo < 100.0 {
        &[1.0, 2.0, 5.0]
    } else {
        &[1.0]
    };
    let mut out = Vec::new();
    for e in (lo.log10().floor() as i32)..=(hi.log10().ceil() as i32) {
        for m in mantissas {
            let v = m * 10f64.powi(e);
            if v >= lo * 0.999 && v <= hi * 1.001 {
                out.push(v);
            }
        }
    }
    out
}

fn label(v: f64) -> String {
    if (1e-3..1e4).contains(&v) {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{v:.0e}")
    }
}

/// Writes the panels, `COLUMNS` to a row, as an RGB PNG at `path`.
pub fn write_png(path: &str, panels: &[Panel]) -> Result<(), Box<dyn std::error::Error>> {
    let rows = panels.len().div_ceil(COLUMNS);
    let mut canvas = Canvas {
        w: PANEL_W * COLUMNS,
        h: PANEL_H * rows,
        rgb: vec![255; 3 * PANEL_W * COLUMNS * PANEL_H * rows],
    };
    for (p, panel) in panels.iter().enumerate() {
        draw_panel(
            &mut canvas,
            (p % COLUMNS) * PANEL_W,
            (p / COLUMNS) * PANEL_H,
            panel,
        );
    }
    let file = std::io::BufWriter::new(std::fs::File::create(path)?);
    let mut encoder = png::Encoder::new(file, canvas.w as u32, canvas.h as u32);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.write_header()?.write_image_data(&canvas.rgb)?;
    Ok(())
}

fn draw_panel(canvas: &mut Canvas, ox: usize, oy: usize, panel: &Panel) {
    let points = panel.series.iter().flat_map(|(_, s)| s.iter());
    let (mut x_lo, mut x_hi, mut y_lo, mut y_hi) = (f64::MAX, 0f64, f64::MAX, 0f64);
    for &(x, y) in points.filter(|(x, y)| *x > 0.0 && *y > 0.0) {
        (x_lo, x_hi, y_lo, y_hi) = (x_lo.min(x), x_hi.max(x), y_lo.min(y), y_hi.max(y));
    }
    if x_hi <= 0.0 {
        return;
    }
    // Pad the y range a little, and to at least a factor 4 so the ticks have room.
    let (y_lo, y_hi) = {
        let (lo, hi) = (y_lo / 1.15, y_hi * 1.15);
        let short = (4.0 / (hi / lo)).max(1.0).sqrt();
        (lo / short, hi * short)
    };
    let (x_lo, x_hi) = (x_lo / 1.15, x_hi * 1.15);
    let [ml, mt, mr, mb] = MARGIN;
    let (left, top) = ((ox + ml) as f64, (oy + mt) as f64);
    let (w, h) = ((PANEL_W - ml - mr) as f64, (PANEL_H - mt - mb) as f64);
    let px = |x: f64| left + w * (x / x_lo).log10() / (x_hi / x_lo).log10();
    let py = |y: f64| top + h * (1.0 - (y / y_lo).log10() / (y_hi / y_lo).log10());
    let (grey, black) = ([215, 215, 215], [0, 0, 0]);
    for t in ticks(y_lo, y_hi) {
        canvas.line((left, py(t)), (left + w, py(t)), grey, 1);
        let l = label(t);
        canvas.text(ox + ml - 6 - 8 * l.len(), py(t) as usize - 4, &l, black);
    }
    for t in ticks(x_lo, x_hi) {
        canvas.line((px(t), top), (px(t), top + h), grey, 1);
        let l = label(t);
        canvas.text(
            (px(t) as usize).saturating_sub(4 * l.len()),
            (top + h) as usize + 6,
            &l,
            black,
        );
    }
    for (a, b) in [
        ((left, top), (left + w, top)),
        ((left, top + h), (left + w, top + h)),
        ((left, top), (left, top + h)),
        ((left + w, top), (left + w, top + h)),
    ] {
        canvas.line(a, b, black, 1);
    }
    canvas.text(ox + ml, oy + 12, &panel.title, black);
    canvas.text(
        ox + ml + (w as usize) / 2 - 60,
        oy + PANEL_H - 18,
        "training samples",
        black,
    );
    canvas.text(ox + 4, oy + mt - 12, "relvar", black);
    for (k, (name, series)) in panel.series.iter().enumerate() {
        let c = COLOURS[k % COLOURS.len()];
        for pair in series.windows(2) {
            canvas.line(
                (px(pair[0].0), py(pair[0].1)),
                (px(pair[1].0), py(pair[1].1)),
                c,
                2,
            );
        }
        for &(x, y) in series {
            canvas.line((px(x) - 3.0, py(y)), (px(x) + 3.0, py(y)), c, 5);
        }
        let (lx, ly) = (ox + PANEL_W - mr - 100, oy + mt + 10 + 14 * k);
        canvas.line(
            (lx as f64, ly as f64 + 4.0),
            (lx as f64 + 18.0, ly as f64 + 4.0),
            c,
            3,
        );
        canvas.text(lx + 24, ly, name, black);
    }
}
