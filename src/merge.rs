//! Merging fields trained in parallel: the render-farm half of the cache.
//!
//! Workers that loaded the same cache record into identical trees, and a tree's statistics are
//! sums, so adding the workers' sums cell by cell gives exactly what one process would have
//! recorded from all their samples. Merge checks that the two fields really share everything but
//! those sums; `refine` afterwards proceeds as if one machine had done all the work.

use crate::field::GuidingField;
use std::fmt;

/// Why two fields cannot be merged.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum MergeError {
    /// The configurations differ.
    ConfigDiffers,
    /// The bounds differ.
    BoundsDiffers,
    /// The fields are at different iterations.
    IterationDiffers {
        /// This field's iteration.
        ours: u32,
        /// The other field's iteration.
        theirs: u32,
    },
    /// The trees differ: the fields did not start this iteration from the same state.
    TopologyDiffers {
        /// Where they first differ.
        detail: String,
    },
}

impl fmt::Display for MergeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MergeError::ConfigDiffers => write!(f, "cannot merge: configurations differ"),
            MergeError::BoundsDiffers => write!(f, "cannot merge: bounds differ"),
            MergeError::IterationDiffers { ours, theirs } => {
                write!(f, "cannot merge: iteration {ours} vs {theirs}")
            }
            MergeError::TopologyDiffers { detail } => write!(f, "cannot merge: {detail}"),
        }
    }
}

impl std::error::Error for MergeError {}

impl GuidingField {
    /// Adds the statistics `other` recorded in the current iteration — every cell's sums and
    /// counts, the guide-selection sums, the continuation sums, and the rejection counts — to this field's. Both
    /// fields must have started the iteration from the same state (typically: the same cache,
    /// loaded on two workers). The sums are exact integers, so merging is exact, commutative
    /// and associative: workers that split an iteration's samples and are merged in any order
    /// give the bytes one field recording every sample gives.
    ///
    /// ```
    /// use sdguide::{Aabb, GuidingConfig, GuidingField, Sample};
    /// use glam::Vec3;
    /// let base = GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), GuidingConfig::default())?;
    /// let (mut a, b) = (base.clone(), base.clone());
    /// a.record(&Sample { position: Vec3::splat(0.5), direction: Vec3::Z, value: 1.0, pdf: 1.0, ..Sample::default() });
    /// b.record(&Sample { position: Vec3::splat(0.5), direction: Vec3::X, value: 2.0, pdf: 1.0, ..Sample::default() });
    /// a.merge(&b)?;
    /// assert_eq!(a.stats().samples_recorded, 2);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    ///
    /// # Errors
    ///
    /// A [`MergeError`] when `other` did not start the iteration from the same cache
    /// (different configuration, bounds, iteration or trees); nothing `self` reports or saves
    /// changes then.
    pub fn merge(&mut self, other: &GuidingField) -> Result<(), MergeError> {
        if self.config != other.config {
            return Err(MergeError::ConfigDiffers);
        }
        if self.bounds != other.bounds {
            return Err(MergeError::BoundsDiffers);
        }
        if self.iteration != other.iteration {
            return Err(MergeError::IterationDiffers {
                ours: self.iteration,
                theirs: other.iteration,
            });
        }
        let differs = |detail: String| Err(MergeError::TopologyDiffers { detail });
        if self.spatial.nodes() != other.spatial.nodes() {
            return differs("the spatial trees differ".into());
        }
        for (i, (a, b)) in self.regions.iter().zip(&other.regions).enumerate() {
            a.same_start(b)
                .or_else(|what| differs(format!("the {what} of tree {i} differ")))?;
        }
        // Checked everything first: a refused merge leaves this field untouched.
        for (a, b) in self.regions.iter_mut().zip(&other.regions) {
            a.add(b);
        }
        self.rejected.add(&other.rejected.get());
        self.clamped.add(&other.clamped);
        Ok(())
    }
}
