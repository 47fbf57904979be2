//! Queries and records over slices: the structure-of-arrays form a wavefront renderer uses,
//! which processes one bounce of many paths at once.
//!
//! Each lane is exactly the one-vertex call — the same lookup, the same descent, the same bits
//! out — so a renderer may mix the two forms. The lanes run in parallel on rayon's pool, at
//! least [`BATCH_CHUNK`] to a task; a call allocates nothing (the caller owns the outputs) and takes
//! `&self`, like the one-vertex calls, so several batches may run at once.

use crate::field::GuidingField;
use crate::sample::Sample;
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::fmt;

/// The fewest lanes one rayon task handles: enough to amortize the task, few enough to spread
/// a bounce of a small image over every thread.
pub const BATCH_CHUNK: usize = 1024;

/// Why a batch call refused its slices. Nothing is written then.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum BatchError {
    /// A slice does not have one entry per lane.
    LengthMismatch {
        /// The slice, by its parameter's name.
        slice: &'static str,
        /// The lanes: the length of `positions`.
        lanes: usize,
        /// Its length.
        found: usize,
    },
}

impl fmt::Display for BatchError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BatchError::LengthMismatch {
                slice,
                lanes,
                found,
            } => write!(f, "`{slice}` has {found} entries for {lanes} lanes"),
        }
    }
}

impl std::error::Error for BatchError {}

/// Checks that a slice has one entry per lane.
fn lanes(slice: &'static str, lanes: usize, found: usize) -> Result<(), BatchError> {
    if found == lanes {
        Ok(())
    } else {
        Err(BatchError::LengthMismatch {
            slice,
            lanes,
            found,
        })
    }
}

/// Calls `f(i, output)` for every lane `i` of `outputs`, in parallel, at least [`BATCH_CHUNK`]
/// lanes to a task.
fn for_each_lane<T: Send>(
    outputs: impl IndexedParallelIterator<Item = T>,
    f: impl Fn(usize, T) + Sync + Send,
) {
    outputs
        .with_min_len(BATCH_CHUNK)
        .enumerate()
        .for_each(|(i, out)| f(i, out));
}

impl GuidingField {
    /// [`distribution`](Self::distribution)`(positions[i]).sample(u[i])` for every lane `i`,
    /// or with `normals`, [`at_surface`](crate::DirectionalDistribution::at_surface)`(normals[i])`
    /// first (a zero or non-finite normal: the plain distribution, as there): the direction
    /// into `directions[i]`, its solid-angle pdf into `pdfs[i]`.
    ///
    /// ```
    /// use sdguide::{Aabb, GuidingConfig, GuidingField};
    /// use glam::{Vec2, Vec3};
    /// let field = GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), GuidingConfig::default())?;
    /// let positions = [Vec3::splat(0.5), Vec3::splat(0.25)];
    /// let u = [Vec2::new(0.1, 0.2), Vec2::new(0.7, 0.4)];
    /// let (mut directions, mut pdfs) = ([Vec3::ZERO; 2], [0.0; 2]);
    /// field.sample_batch(&positions, None, &u, &mut directions, &mut pdfs)?;
    /// assert_eq!((directions[1], pdfs[1]), field.distribution(positions[1]).sample(u[1]));
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    ///
    /// # Errors
    ///
    /// [`BatchError::LengthMismatch`] unless every slice has one entry per position.
    pub fn sample_batch(
        &self,
        positions: &[Vec3],
        normals: Option<&[Vec3]>,
        u: &[Vec2],
        directions: &mut [Vec3],
        pdfs: &mut [f32],
    ) -> Result<(), BatchError> {
        let n = positions.len();
        lanes("u", n, u.len())?;
        lanes("directions", n, directions.len())?;
        lanes("pdfs", n, pdfs.len())?;
        if let Some(normals) = normals {
            lanes("normals", n, normals.len())?;
        }
        let lanes = directions.par_iter_mut().zip(pdfs.par_iter_mut());
        for_each_lane(lanes, |i, (d, p)| {
            let dist = self.distribution(positions[i]);
            (*d, *p) = match normals {
                Some(normals) => dist.at_surface(normals[i]).sample(u[i]),
                None => dist.sample(u[i]),
            };
        });
        Ok(())
    }

    /// [`distribution`](Self::distribution)`(positions[i]).pdf(directions[i])` for every lane
    /// `i`, or with `normals`, the pdf of the product with the cosine (as
    /// [`sample_batch`](Self::sample_batch)), into `pdfs[i]`.
    ///
    /// # Errors
    ///
    /// [`BatchError::LengthMismatch`] unless every slice has one entry per position.
    pub fn pdf_batch(
        &self,
        positions: &[Vec3],
        normals: Option<&[Vec3]>,
        directions: &[Vec3],
        pdfs: &mut [f32],
    ) -> Result<(), BatchError> {
        let n = positions.len();
        lanes("directions", n, directions.len())?;
        lanes("pdfs", n, pdfs.len())?;
        if let Some(normals) = normals {
            lanes("normals", n, normals.len())?;
        }
        for_each_lane(pdfs.par_iter_mut(), |i, p| {
            let dist = self.distribution(positions[i]);
            *p = match normals {
                Some(normals) => dist.at_surface(normals[i]).pdf(directions[i]),
                None => dist.pdf(directions[i]),
            };
        });
        Ok(())
    }

    /// [`distribution`](Self::distribution)`(positions[i]).guide_probability()` for every lane
    /// `i`, into `probabilities[i]`.
    ///
    /// # Errors
    ///
    /// [`BatchError::LengthMismatch`] unless `probabilities` has one entry per position.
    pub fn guide_probability_batch(
        &self,
        positions: &[Vec3],
        probabilities: &mut [f32],
    ) -> Result<(), BatchError> {
        lanes("probabilities", positions.len(), probabilities.len())?;
        for_each_lane(probabilities.par_iter_mut(), |i, a| {
            *a = self.distribution(positions[i]).guide_probability();
        });
        Ok(())
    }

    /// [`record`](Self::record)s every sample, in parallel; returns how many were rejected
    /// (each counted in [`FieldStats::rejected`](crate::FieldStats::rejected), as by `record`).
    /// The sums are exact, so the field is the same whatever order the threads add them in.
    pub fn record_batch(&self, samples: &[Sample]) -> u64 {
        samples
            .par_chunks(BATCH_CHUNK)
            .map(|chunk| chunk.iter().filter(|s| self.try_record(s).is_err()).count() as u64)
            .sum()
    }
}
