//! The equal-area octahedral map between unit directions and the unit square.
//!
//! Every directional quadtree lives on the unit square `[0,1)²`; this module is the only place
//! that knows how the square wraps the sphere. The map (Clarberg's, "Fast equal-area mapping of
//! the (hemi)sphere using SIMD", 2008) folds the square onto the octahedron and the octahedron
//! onto the sphere. With `(u, v) = 2s − 1 ∈ [−1, 1]²` and `r = 1 − |1 − |u| − |v||`:
//!
//! ```text
//!   ω.z = ±(1 − r²)                 + inside the diamond |u| + |v| < 1, − outside it
//!   φ   = π/4 · ((|v| − |u|)/r + 1)  the azimuth within the quadrant of (sign u, sign v)
//!   ω.x = sign(u) · cos φ · r·sqrt(2 − r²),   ω.y = sign(v) · sin φ · r·sqrt(2 − r²)
//! ```
//!
//! in the world frame. The centre of the square is `+z`, its four corners are `−z`, and the
//! square's border folds onto itself at the midpoint of each side (`(u, ±1)` and `(−u, ±1)` are
//! the same direction).
//!
//! It preserves area up to the constant 4π, so a density `p□` on the square is the solid-angle
//! density `p□ / 4π` on the sphere: no Jacobian varies over the square, which keeps sample and
//! pdf exact inverses of each other.
//!
//! **Why not the cylindrical map** `(cos θ, φ)` (the SD-tree's): it squeezes each pole into a
//! whole side of the square. A sharp light near a pole becomes a thin strip across every `φ`,
//! and where the light's direction moves with position (parallax) it sweeps across many thin
//! leaves, each seen by few samples. The octahedral map has no such line: every cell of the
//! quadtree is a compact patch of the sphere, distorted by a bounded factor (the quality
//! harness compares the two maps: `docs/quality.md`).

use glam::{Vec2, Vec3};
use std::f32::consts::{FRAC_PI_4, PI};

/// The constant Jacobian of the map: solid angle of the sphere (4π) per unit of square area.
pub const SPHERE_AREA: f32 = 4.0 * PI;

/// 1 / 4π: the solid-angle density of a uniform density on the square.
pub const INV_SPHERE_AREA: f32 = 1.0 / SPHERE_AREA;

/// The largest `f32` below 1: coordinates are clamped to `[0, ONE_MINUS_EPSILON]` so a point on
/// the square always falls in exactly one cell.
pub(crate) const ONE_MINUS_EPSILON: f32 = 1.0 - f32::EPSILON / 2.0;

/// Bound on the rounding of the round trip `direction_to_square(normalize(square_to_direction(s)))`:
/// each coordinate comes back within this distance of `s`, except within it of the square's
/// border, where the map folds and a point may come back as its mirror image. The error is a few
/// ulps of the angle through sin/cos and the arctangent, and of the normalization; the test
/// below measures it, and samples farther than this from their cell's borders skip the check.
pub(crate) const ROUND_TRIP_BOUND: f32 = 1e-6;

/// The unit vector along `d`, or `None` if `d` is zero or not finite.
///
/// Directions whose squared length overflows or underflows `f32` are rescaled first, so every
/// finite non-zero vector has a direction.
///
/// ```
/// use sdguide::sphere::normalize;
/// use glam::Vec3;
/// assert_eq!(normalize(Vec3::new(0.0, 3.0, 4.0)), Some(Vec3::new(0.0, 0.6, 0.8)));
/// assert_eq!(normalize(Vec3::splat(f32::MAX)), Some(Vec3::splat(1.0 / 3f32.sqrt())));
/// assert_eq!(normalize(Vec3::ZERO), None);
/// ```
#[inline]
pub fn normalize(d: Vec3) -> Option<Vec3> {
    let len2 = d.length_squared();
    if len2 > f32::MIN_POSITIVE && len2.is_finite() {
        return Some(d / len2.sqrt());
    }
    normalize_rescaled(d)
}

#[cold]
fn normalize_rescaled(d: Vec3) -> Option<Vec3> {
    let scale = d.abs().max_element();
    if !(d.is_finite() && scale > 0.0) {
        return None;
    }
    let d = d / scale;
    Some(d / d.length())
}

/// Maps any finite non-zero direction (not necessarily unit) to its point on the unit square, or
/// `None` for a zero or non-finite one.
///
/// ```
/// use sdguide::sphere::{direction_to_square, square_of};
/// use glam::Vec3;
/// let d = Vec3::new(1.0, 2.0, 2.0);
/// let s = square_of(d).unwrap();
/// assert!((s - direction_to_square(d / 3.0)).abs().max_element() < 1e-6);
/// assert_eq!(square_of(Vec3::ZERO), None);
/// ```
#[inline]
pub fn square_of(d: Vec3) -> Option<Vec2> {
    let len2 = d.length_squared();
    // A direction already unit to rounding (what renderers pass, and what `sample` returns)
    // skips the square root and the division: the map is as accurate for it (the round trip
    // below is tested through here), and the pdf's chain of dependent steps is shorter.
    if (len2 - 1.0).abs() <= 4.0 * f32::EPSILON {
        return Some(direction_to_square(d));
    }
    if len2 > f32::MIN_POSITIVE && len2.is_finite() {
        return Some(direction_to_square(d / len2.sqrt()));
    }
    normalize_rescaled(d).map(direction_to_square)
}

/// Maps a unit direction to its point on the unit square (clamped into `[0, 1)²` against
/// rounding).
///
/// ```
/// use sdguide::sphere::{direction_to_square, square_to_direction};
/// use glam::Vec3;
/// let d = Vec3::new(0.3, -0.4, 0.5).normalize();
/// let back = square_to_direction(direction_to_square(d));
/// assert!((back - d).length() < 1e-6);
/// ```
#[inline]
pub fn direction_to_square(d: Vec3) -> Vec2 {
    let (ax, ay, az) = (d.x.abs(), d.y.abs(), d.z.abs());
    // r² = 1 − |z|, from x² + y² near the poles, where 1 − |z| cancels. (Both, and a select:
    // for directions from all over the sphere, a jump here is a coin flip.)
    let r2 = select(az > 0.5, 1.0 - az, (ax * ax + ay * ay) / (1.0 + az));
    let r = r2.max(0.0).sqrt();
    let t = ax.min(ay) / ax.max(ay).max(f32::MIN_POSITIVE);
    let mut phi = atan01(t) * (2.0 / PI);
    if ax < ay {
        phi = 1.0 - phi;
    }
    let v = phi * r;
    let u = r - v;
    let (u, v) = if d.z < 0.0 {
        (1.0 - v, 1.0 - u)
    } else {
        (u, v)
    };
    let (u, v) = (u.copysign(d.x), v.copysign(d.y));
    Vec2::new(
        ((u + 1.0) * 0.5).clamp(0.0, ONE_MINUS_EPSILON),
        ((v + 1.0) * 0.5).clamp(0.0, ONE_MINUS_EPSILON),
    )
}

/// `if pick { b } else { a }`, without a jump: for directions from all over the sphere, `pick`
/// is a coin flip, and a jump would be mispredicted half the time.
#[inline(always)]
fn select(pick: bool, a: f32, b: f32) -> f32 {
    std::hint::select_unpredictable(pick, b, a)
}

/// `atan(t)` for `t ∈ [0, 1]`, to within 2·10⁻⁷ rad (tested against `f64`): the
/// minimax-fitted odd polynomial `t·P(t²)` of degree 15 (fit error 3.8·10⁻⁸).
#[inline]
fn atan01(t: f32) -> f32 {
    const C: [f32; 8] = [
        0.999_999_34,
        -0.333_298_6,
        0.199_465_69,
        -0.139_086_5,
        0.096_422_5,
        -0.055_913_09,
        0.021_863_51,
        -0.004_054_726,
    ];
    let t2 = t * t;
    let t4 = t2 * t2;
    let t8 = t4 * t4;
    let p01 = C[0] + C[1] * t2;
    let p23 = C[2] + C[3] * t2;
    let p45 = C[4] + C[5] * t2;
    let p67 = C[6] + C[7] * t2;
    ((p01 + p23 * t4) + (p45 + p67 * t4) * t8) * t
}

/// `(sin φ, cos φ)` for the azimuth `φ = π/4·(1 + t)`, `t ∈ [−1, 1]`, to within 2·10⁻⁷ (tested
/// against `f64`): `sin θ` and `cos θ` of the angle `θ = π/4·(1 − |t|) ≤ π/4` to the nearer axis,
/// by their Taylor polynomials of degree 9 and 8 (remainders below 2·10⁻⁹ and 3·10⁻⁸ there),
/// swapped past the diagonal. Inline, where a call to the C library's `sincosf` is a call the
/// sample's chain of steps waits on; and exact on the axes (`t = ±1` gives 0 and 1), where
/// `sincosf(π/2)` gives `cos` a residue of −4·10⁻⁸ that puts a cell corner on the axis a hair
/// below a horizon through it.
#[inline]
fn azimuth_sin_cos(t: f32) -> (f32, f32) {
    let theta = FRAC_PI_4 * (1.0 - t.abs());
    let x2 = theta * theta;
    let sin = theta
        * (1.0 + x2 * (-1.0 / 6.0 + x2 * (1.0 / 120.0 + x2 * (-1.0 / 5040.0 + x2 / 362_880.0))));
    let cos = 1.0 + x2 * (-0.5 + x2 * (1.0 / 24.0 + x2 * (-1.0 / 720.0 + x2 / 40_320.0)));
    // Past the diagonal θ runs from the y axis: sin φ = cos θ. (A select: t's sign is a coin
    // flip over the sphere.)
    let past = t >= 0.0;
    (select(past, sin, cos), select(past, cos, sin))
}

/// Maps a point of the unit square to its unit direction.
///
/// ```
/// use sdguide::sphere::square_to_direction;
/// use glam::{Vec2, Vec3};
/// // +z is the centre of the square, −z each of its corners.
/// assert!((square_to_direction(Vec2::new(0.5, 0.5)) - Vec3::Z).length() < 1e-6);
/// assert!((square_to_direction(Vec2::new(1.0, 0.0)) + Vec3::Z).length() < 1e-6);
/// ```
#[inline]
pub fn square_to_direction(s: Vec2) -> Vec3 {
    let (u, v) = (2.0 * s.x - 1.0, 2.0 * s.y - 1.0);
    let (up, vp) = (u.abs(), v.abs());
    let sd = 1.0 - (up + vp);
    let r = 1.0 - sd.abs();
    let t = if r == 0.0 { 0.0 } else { (vp - up) / r };
    let z = (1.0 - r * r).copysign(sd);
    let (sin_phi, cos_phi) = azimuth_sin_cos(t);
    let k = r * (2.0 - r * r).max(0.0).sqrt();
    Vec3::new(cos_phi.copysign(u) * k, sin_phi.copysign(v) * k, z)
}

/// The pieces of the unit square that the box `[x0, x1) × [y0, y1)` covers on the sphere, when
/// the box may cross the square's border (by less than 1 on each axis): the part inside, and
/// each part outside folded back in as the map folds it. A point just past a side is the mirror
/// image, through that side's midpoint, of a point just inside (`(1 + e, y)` is `(1 − e, 1 − y)`);
/// a point past a corner is the point one square away diagonally (`(1 + a, 1 + b)` is `(a, b)`:
/// all four corners are `−z`). Each piece has the area of the part it comes from, so together
/// they have the box's area. `None` for parts the box does not have.
///
/// The directional box filter spreads a sample over these pieces, so a sample near the border
/// reaches the leaves that are its neighbours on the sphere.
pub(crate) fn fold_box(x: [f64; 2], y: [f64; 2]) -> [Option<[[f64; 2]; 2]>; 4] {
    let (xi, xo) = fold_axis(x);
    let (yi, yo) = fold_axis(y);
    let mirror = |[a, b]: [f64; 2]| [1.0 - b, 1.0 - a];
    [
        Some([xi, yi]),
        xo.map(|(reflected, _)| [reflected, mirror(yi)]),
        yo.map(|(reflected, _)| [mirror(xi), reflected]),
        xo.zip(yo).map(|((_, tx), (_, ty))| [tx, ty]),
    ]
}

/// One axis of [`fold_box`]: the part of `[a, b)` inside `[0, 1)`, and the part outside, both as
/// a side's fold reflects it (`x → −x` or `2 − x`) and as a corner's shift moves it (`x → x ± 1`).
#[allow(clippy::type_complexity, reason = "two intervals, named in the doc")]
fn fold_axis([a, b]: [f64; 2]) -> ([f64; 2], Option<([f64; 2], [f64; 2])>) {
    let inside = [a.max(0.0), b.min(1.0)];
    let outside = if a < 0.0 {
        Some(([0.0, -a], [a + 1.0, 1.0]))
    } else if b > 1.0 {
        Some(([2.0 - b, 1.0], [0.0, b - 1.0]))
    } else {
        None
    };
    (inside, outside)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axes_land_where_the_map_says() {
        let at = |x: f32, y: f32| square_to_direction(Vec2::new(x, y));
        assert!((at(0.5, 0.5) - Vec3::Z).length() < 1e-6);
        for corner in [(0.0, 0.0), (0.0, 1.0), (1.0, 0.0), (1.0, 1.0)] {
            assert!((at(corner.0, corner.1) + Vec3::Z).length() < 1e-6);
        }
        assert!((at(1.0, 0.5) - Vec3::X).length() < 1e-6);
        assert!((at(0.5, 1.0) - Vec3::Y).length() < 1e-6);
        assert!((at(0.0, 0.5) + Vec3::X).length() < 1e-6);
        assert!((at(0.5, 0.0) + Vec3::Y).length() < 1e-6);
        // The equator is the diamond |u| + |v| = 1.
        assert!(at(0.75, 0.75).z.abs() < 1e-6);
        // The border folds at its midpoints: (u, 1) and (−u, 1) are the same direction.
        assert!((at(0.2, 1.0) - at(0.8, 1.0)).length() < 1e-6);
        assert!((at(1.0, 0.3) - at(1.0, 0.7)).length() < 1e-6);
    }

    #[test]
    fn a_box_across_the_border_folds_onto_its_neighbourhood_on_the_sphere() {
        // Boxes of half-size 0.1 around points near a side, near a corner, and inside. The
        // pieces lie in the square and keep the box's area; and every direction within 0.1 rad
        // of the centre's direction lands in a piece. Away from the fold the inverse map moves
        // a point of the square by at most about 0.42 (in each coordinate) per radian (measured
        // on 400k random pairs of nearby directions), so the cap lies within 0.042 of the
        // centre: well inside the box, once the box is folded. Clipping instead of folding
        // leaves out the part of the cap across the border.
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 40) as f32 / (1u64 << 24) as f32
        };
        for centre in [
            [0.3, 0.97],
            [0.98, 0.6],
            [0.02, 0.45],
            [0.55, 0.01],
            [0.97, 0.98],
            [0.03, 0.02],
            [0.5, 0.5],
        ] {
            let (x, y) = (
                [centre[0] - 0.1, centre[0] + 0.1],
                [centre[1] - 0.1, centre[1] + 0.1],
            );
            let pieces: Vec<_> = fold_box(x, y).into_iter().flatten().collect();
            let area: f64 = pieces
                .iter()
                .map(|[a, b]| (a[1] - a[0]) * (b[1] - b[0]))
                .sum();
            assert!((area - 0.04).abs() < 1e-12, "{centre:?}: area {area}");
            for [a, b] in &pieces {
                assert!(
                    a[0] >= 0.0 && a[1] <= 1.0 && b[0] >= 0.0 && b[1] <= 1.0,
                    "{pieces:?}"
                );
            }
            let d = square_to_direction(Vec2::new(centre[0] as f32, centre[1] as f32));
            // An orthonormal frame around d, and directions at angles up to 0.1 rad from it.
            let t = if d.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
            let (e1, e2) = (d.cross(t).normalize(), d.cross(d.cross(t).normalize()));
            for _ in 0..2000 {
                let (theta, phi) = (0.1 * next(), 2.0 * PI * next());
                let w = d * theta.cos() + (e1 * phi.cos() + e2 * phi.sin()) * theta.sin();
                let p = direction_to_square(w.normalize());
                let (px, py) = (f64::from(p.x), f64::from(p.y));
                assert!(
                    pieces
                        .iter()
                        .any(|[a, b]| (a[0]..=a[1]).contains(&px) && (b[0]..=b[1]).contains(&py)),
                    "{centre:?}: {w} at {p} lies in no piece of {pieces:?}"
                );
            }
        }
    }

    #[test]
    fn poles_and_border_map_inside_the_square() {
        for d in [
            Vec3::Z,
            -Vec3::Z,
            Vec3::X,
            -Vec3::X,
            Vec3::Y,
            -Vec3::Y,
            Vec3::new(1.0, -1e-9, 0.0).normalize(),
            Vec3::new(-1.0, -0.0, 0.0),
            Vec3::new(1e-9, 1e-9, -1.0).normalize(),
        ] {
            let s = direction_to_square(d);
            assert!(
                (0.0..1.0).contains(&s.x) && (0.0..1.0).contains(&s.y),
                "{d} -> {s}"
            );
            assert!((square_to_direction(s) - d).length() < 1e-6, "{d} -> {s}");
        }
    }

    #[test]
    fn round_trip_over_a_grid() {
        let n = 64;
        for i in 0..n {
            for j in 0..n {
                let s = Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
                let back = direction_to_square(square_to_direction(s));
                assert!((back - s).abs().max_element() < 1e-5, "{s} -> {back}");
            }
        }
    }

    /// Largest round-trip error over `points`, skipping those within the bound of the square's
    /// border, where the map folds and a point may come back as its mirror image.
    fn max_round_trip_error(points: impl Iterator<Item = Vec2>) -> f32 {
        let mut worst = 0.0f32;
        for s in points {
            if s.min_element() <= ROUND_TRIP_BOUND || s.max_element() >= 1.0 - ROUND_TRIP_BOUND {
                continue;
            }
            let back = square_of(square_to_direction(s)).unwrap();
            worst = worst.max((back - s).abs().max_element());
        }
        worst
    }

    #[test]
    fn round_trip_error_is_within_the_bound() {
        let mut next = crate::test_uniforms(1);
        let random = (0..2_000_000).map(|_| Vec2::new(next(), next()));
        // Near the border, the centre (+z), the axes and the equator's diamond, where the
        // map's pieces meet and where ulps are largest.
        let special = (0..1_200_000).map(|i| {
            let t = i as f32 / 1.2e6;
            let e = t * t * 1e-3;
            match i % 6 {
                0 => Vec2::new(e, t),
                1 => Vec2::new(ONE_MINUS_EPSILON - e, t),
                2 => Vec2::new(t, e),
                3 => Vec2::new(0.5 + e - 5e-4, t),
                4 => Vec2::new(0.5 + e - 5e-4, 0.5 + t * 1e-3 - 5e-4),
                _ => Vec2::new(t, (1.5 - t + e - 5e-4).rem_euclid(1.0)),
            }
        });
        let worst = max_round_trip_error(random.chain(special));
        // Keep a factor of two between what is measured and what sampling relies on.
        assert!(worst < 0.5 * ROUND_TRIP_BOUND, "round trip error {worst:e}");
    }

    #[test]
    fn the_azimuths_sin_cos_matches_f64_and_is_exact_on_the_axes() {
        let n = 1_000_000;
        let mut worst = 0.0f64;
        for i in 0..=n {
            let t = 2.0 * i as f32 / n as f32 - 1.0;
            let (sin, cos) = azimuth_sin_cos(t);
            let phi = std::f64::consts::FRAC_PI_4 * (1.0 + f64::from(t));
            worst = worst
                .max((f64::from(sin) - phi.sin()).abs())
                .max((f64::from(cos) - phi.cos()).abs());
        }
        // Remainders below 3e-8 and a few ulps of 1 in the evaluation.
        assert!(worst < 2e-7, "{worst:e}");
        assert_eq!(azimuth_sin_cos(-1.0), (0.0, 1.0));
        assert_eq!(azimuth_sin_cos(1.0), (1.0, 0.0));
    }

    #[test]
    fn fast_atan_matches_f64() {
        let n = 1_000_000;
        let mut worst = 0.0f64;
        for i in 0..=n {
            let t = i as f32 / n as f32;
            worst = worst.max((f64::from(atan01(t)) - f64::from(t).atan()).abs());
        }
        // Fit error 3.8e-8 and a few ulps of π/4 in the evaluation.
        assert!(worst < 2e-7, "{worst:e}");
        assert_eq!(atan01(0.0), 0.0);
    }

    #[test]
    fn equal_area() {
        // A fine grid of the square, binned by z band and by quadrant of (x, y): each bin's share of the
        // grid must be its share of the sphere's area (a band [a, b) of z holds (b − a)/2 by
        // Archimedes' hat-box theorem, and the quadrants split it evenly).
        // An odd n and an offset keep grid points off the equator's diamond and the axes.
        let n = 999;
        let bands = 8;
        let mut count = vec![0u32; bands * 4];
        for i in 0..n {
            for j in 0..n {
                let s = Vec2::new((i as f32 + 0.37) / n as f32, (j as f32 + 0.61) / n as f32);
                let d = square_to_direction(s);
                assert!((d.length() - 1.0).abs() < 1e-6, "{s} -> {d}");
                let band = (((d.z + 1.0) * 0.5 * bands as f32) as usize).min(bands - 1);
                let quadrant = usize::from(d.x < 0.0) | usize::from(d.y < 0.0) << 1;
                count[band * 4 + quadrant] += 1;
            }
        }
        let expected = (n * n) as f64 / (bands * 4) as f64;
        for (k, &c) in count.iter().enumerate() {
            // A bin's border crosses O(n) of the n² cells of the grid: an error of order 1/n.
            let c = f64::from(c);
            assert!(
                (c - expected).abs() < 0.01 * expected,
                "bin {k}: {c} vs {expected}"
            );
        }
    }
}
