//! What a renderer pushes into the path recorder and what a finished path gives back.

use crate::sample::Sample;
use crate::splitting::Continuation;
use glam::Vec3;

/// The Rec. 709 luminance of an RGB radiance: the scalar the recorder records.
#[inline]
pub(crate) fn luminance(rgb: Vec3) -> f32 {
    rgb.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

/// A handle to one vertex of the path being recorded, returned by [`PathRecorder::start`](crate::PathRecorder::start) (the
/// camera ray) and [`PathRecorder::push`](crate::PathRecorder::push). Valid until the next `start`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct VertexId(pub(super) u32);

impl VertexId {
    /// The handle whose [`index`](Self::index) is `index` (for bindings that pass handles as
    /// integers). A handle the recorder did not hand out in the current path is ignored by
    /// every call, and counted in [`PathRecorderStats::bad_values`].
    pub fn from_index(index: u32) -> Self {
        VertexId(index)
    }

    /// Where the vertex sits in the order of pushes (the camera ray is 0): an index for a
    /// renderer that keeps data of its own beside the recorder's.
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

/// A scattering vertex as the renderer pushes it: where it is, the direction it drew, and the
/// weight that direction carries.
///
/// ```
/// use sdguide::PathVertex;
/// use sdguide::glam::Vec3;
/// let v = PathVertex::new(Vec3::ZERO, Vec3::Y, Vec3::splat(0.25), 0.5)
///     .with_normal(Vec3::Y)
///     .with_mixture(0.3, 0.7);
/// assert_eq!(v.pdfs.map(|p| p.guide), Some(0.7));
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PathVertex {
    /// The vertex (world space).
    pub position: Vec3,
    /// Its shading normal, the one passed to
    /// [`at_surface`](crate::DirectionalDistribution::at_surface) there, facing the side the
    /// path arrived from (`None`: recorded without one).
    pub normal: Option<Vec3>,
    /// The direction drawn, pointing away from `position` (any length).
    pub direction: Vec3,
    /// `f·|cos θ|` toward `direction`, per channel: the BSDF times the cosine, 0 where the
    /// BSDF is (below the surface).
    pub bsdf: Vec3,
    /// The density `direction` was drawn with: the mixture's `q = a·p_guide + (1 − a)·p_bsdf`
    /// where the renderer mixes, finite and positive.
    pub pdf: f32,
    /// The two techniques' pdfs of `direction` when the renderer sampled the one-sample
    /// mixture: what the cell's guide probability learns from (see [`Sample::with_mixture`]).
    pub pdfs: Option<TechniquePdfs>,
    /// Whether the vertex scattered inside a participating medium: its sample goes to the
    /// guide of medium vertices ([`Sample::volume`]); `bsdf` is then the phase function's
    /// value (times the scattering albedo), and the technique pdf the phase function's.
    pub volume: bool,
}

/// The BSDF's (or phase function's) and the guide's pdfs of a direction drawn from their
/// mixture.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TechniquePdfs {
    /// The BSDF sampling pdf (solid angle); at a medium vertex, the phase function's.
    pub bsdf: f32,
    /// The guide's pdf: the product's where the renderer samples
    /// [`at_surface`](crate::DirectionalDistribution::at_surface) or
    /// [`with_phase`](crate::DirectionalDistribution::with_phase), the plain one otherwise.
    pub guide: f32,
}

impl PathVertex {
    /// A vertex at `position` that drew `direction` with density `pdf`, where the BSDF times
    /// the cosine is `bsdf`.
    pub const fn new(position: Vec3, direction: Vec3, bsdf: Vec3, pdf: f32) -> Self {
        PathVertex {
            position,
            normal: None,
            direction,
            bsdf,
            pdf,
            pdfs: None,
            volume: false,
        }
    }

    /// The vertex as one inside a participating medium (see [`volume`](Self::volume)); a
    /// normal it has is not recorded.
    pub const fn in_volume(mut self) -> Self {
        self.volume = true;
        self
    }

    /// The vertex with its shading normal.
    pub const fn with_normal(mut self, normal: Vec3) -> Self {
        self.normal = Some(normal);
        self
    }

    /// The vertex with the BSDF's and the guide's pdfs of its direction.
    pub const fn with_mixture(mut self, bsdf_pdf: f32, guide_pdf: f32) -> Self {
        self.pdfs = Some(TechniquePdfs {
            bsdf: bsdf_pdf,
            guide: guide_pdf,
        });
        self
    }

    pub(super) fn is_valid(&self) -> bool {
        let weight = |w: Vec3| w.is_finite() && w.min_element() >= 0.0;
        let pdf = |p: f32| p.is_finite() && p >= 0.0;
        self.position.is_finite()
            && self.direction.is_finite()
            && self.direction != Vec3::ZERO
            && weight(self.bsdf)
            && self.pdf.is_finite()
            && self.pdf > 0.0
            && (self.bsdf / self.pdf).is_finite()
            && self.pdfs.is_none_or(|p| pdf(p.bsdf) && pdf(p.guide))
    }
}

/// What a finished path recorded at one vertex: its training sample and its continuation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathRecord {
    /// The vertex.
    pub id: VertexId,
    /// The radiance's luminance that arrived along its direction, the direction's pdf, its
    /// normal, mixture terms and second moment without roulette.
    pub sample: Sample,
    /// The light the vertex reflected through this direction, `f·cos·L_i/q` (its own split
    /// weight not included), and what tracing it cost: for roulette and splitting.
    pub continuation: Continuation,
}

/// The recorder's counts of bad input, since it was created. Bad input never panics: it is
/// dropped and counted here.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PathRecorderStats {
    /// Paths finished.
    pub paths: u64,
    /// Vertices pushed with a non-finite position or direction, a zero direction, a negative
    /// or non-finite `bsdf`, a pdf that is not finite and positive (or so small that
    /// `bsdf/pdf` overflows), or technique pdfs that are negative or not finite: kept in the path so
    /// that the handles stay valid, but they record nothing and pass nothing to the vertex
    /// before them.
    pub bad_vertices: u64,
    /// Radiance, costs, roulette probabilities or split factors that were negative or not
    /// finite (or a probability not in `(0, 1]`, a factor not positive): ignored.
    pub bad_values: u64,
    /// Vertices refused because the path already held [`PathRecorder::max_vertices`](crate::PathRecorder::max_vertices):
    /// the handle returned for them is the path's overflow sink, which drops what it is given.
    pub dropped_vertices: u64,
    /// Paths that overflowed: they record nothing (their values would lack what the dropped
    /// vertices gathered), and their estimate lacks it too.
    pub truncated_paths: u64,
    /// Vertices where [`PathRecorder::factor`](crate::PathRecorder::factor) gave a splitting factor.
    pub factors: u64,
    /// Vertices where it gave none (the cell had too few continuations, or the image terms
    /// were missing): the renderer played its own roulette there.
    pub no_factor: u64,
}
