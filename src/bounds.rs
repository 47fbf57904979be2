//! Axis-aligned boxes: the scene bounds a field is built over, and the cells of the spatial tree.

use glam::Vec3;
use serde::{Deserialize, Serialize};

/// An axis-aligned bounding box `[min, max]`.
///
/// ```
/// use sdguide::Aabb;
/// use glam::Vec3;
/// let b = Aabb::new(Vec3::ZERO, Vec3::new(2.0, 1.0, 1.0));
/// assert_eq!(b.extent(), Vec3::new(2.0, 1.0, 1.0));
/// assert!(b.contains(Vec3::splat(0.5)));
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Aabb {
    /// The corner with the smallest coordinates.
    pub min: Vec3,
    /// The corner with the largest coordinates.
    pub max: Vec3,
}

impl Aabb {
    /// The box with corners `min` and `max`. Nothing is checked here; [`GuidingField::new`]
    /// rejects boxes that are not finite or have no extent.
    ///
    /// [`GuidingField::new`]: crate::GuidingField::new
    pub const fn new(min: Vec3, max: Vec3) -> Self {
        Self { min, max }
    }

    /// `max − min`.
    pub fn extent(&self) -> Vec3 {
        self.max - self.min
    }

    /// The centre of the box.
    pub fn center(&self) -> Vec3 {
        0.5 * (self.min + self.max)
    }

    /// Whether `p` lies in the closed box.
    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }

    /// The smallest cube with the same centre that contains this box: the spatial tree's root,
    /// so that splitting at midpoints with cycling axes keeps cells close to cubes. Its corners
    /// are rounded outward where `centre ± half side` rounds inward, so every point of the box is
    /// in the cube.
    pub fn bounding_cube(&self) -> Aabb {
        let half = 0.5 * self.extent().max_element();
        let c = self.center();
        Aabb::new(
            (c - Vec3::splat(half)).min(self.min),
            (c + Vec3::splat(half)).max(self.max),
        )
    }

    /// The nearest point of the box to `p`.
    pub fn clamp(&self, p: Vec3) -> Vec3 {
        p.clamp(self.min, self.max)
    }
}
