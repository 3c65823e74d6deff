//! What the arm must keep clear of besides itself: a table plane and a few axis-aligned boxes,
//! all in the base frame, in fixed-capacity storage (copying or checking a scene never
//! allocates).

use nalgebra::Point3;

use super::geometry::Aabb;

/// Most boxes a [`Scene`] holds.
pub const MAX_BOXES: usize = 8;

/// Why a scene was refused.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum SceneError {
    /// A coordinate is NaN or infinite.
    #[error("the {what} has a non-finite coordinate")]
    NonFinite {
        /// `table height` or `box`.
        what: &'static str,
    },
    /// The scene already holds [`MAX_BOXES`] boxes.
    #[error("a scene holds at most {MAX_BOXES} boxes; merge some into one enclosing box")]
    Full,
}

/// The table and the boxes around the arm, in the base frame (m).
///
/// `Scene::default()` is the arm's usual set-up: the base stands on a table whose top is at
/// `z = 0` (the base link's frame is at the bottom of its mounting face), no boxes. The
/// table is a half-space: everything below `table_z_m` is solid, infinite in x and y.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scene {
    table_z_m: Option<f64>,
    boxes: [Aabb; MAX_BOXES],
    n_boxes: usize,
}

impl Default for Scene {
    fn default() -> Self {
        Self {
            table_z_m: Some(0.0),
            ..Self::empty()
        }
    }
}

impl Scene {
    /// No table, no boxes.
    pub fn empty() -> Self {
        let zero = Point3::origin();
        Self {
            table_z_m: None,
            boxes: [Aabb {
                min: zero,
                max: zero,
            }; MAX_BOXES],
            n_boxes: 0,
        }
    }

    /// A table at height `z_m` in the base frame, no boxes.
    pub fn with_table(z_m: f64) -> Result<Self, SceneError> {
        let mut s = Self::empty();
        s.set_table(Some(z_m))?;
        Ok(s)
    }

    /// Sets (or with `None` removes) the table.
    pub fn set_table(&mut self, z_m: Option<f64>) -> Result<(), SceneError> {
        if let Some(z) = z_m
            && !z.is_finite()
        {
            return Err(SceneError::NonFinite {
                what: "table height",
            });
        }
        self.table_z_m = z_m;
        Ok(())
    }

    /// Adds a box given by two opposite corners (base frame, m); returns its index, which
    /// [`super::Target::Box`] refers to.
    pub fn add_box(
        &mut self,
        corner: Point3<f64>,
        opposite: Point3<f64>,
    ) -> Result<usize, SceneError> {
        if !(corner.iter().chain(opposite.iter()).all(|v| v.is_finite())) {
            return Err(SceneError::NonFinite { what: "box" });
        }
        if self.n_boxes == MAX_BOXES {
            return Err(SceneError::Full);
        }
        self.boxes[self.n_boxes] = Aabb::from_corners(corner, opposite);
        self.n_boxes += 1;
        Ok(self.n_boxes - 1)
    }

    /// Height of the table top (m), if there is a table.
    pub fn table_z_m(&self) -> Option<f64> {
        self.table_z_m
    }

    /// The boxes, in the order they were added.
    pub fn boxes(&self) -> &[Aabb] {
        &self.boxes[..self.n_boxes]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scenes_are_checked() {
        let s = Scene::default();
        assert_eq!(s.table_z_m(), Some(0.0));
        assert!(s.boxes().is_empty());
        assert_eq!(
            Scene::with_table(f64::NAN).unwrap_err().to_string(),
            "the table height has a non-finite coordinate"
        );
        let mut s = Scene::empty();
        assert_eq!(s.table_z_m(), None);
        for i in 0..MAX_BOXES {
            let k = s
                .add_box(Point3::new(1.0, 1.0, 1.0), Point3::new(0.5, 0.0, i as f64))
                .unwrap();
            assert_eq!(k, i);
        }
        assert_eq!(s.boxes()[0].min, Point3::new(0.5, 0.0, 0.0));
        assert_eq!(
            s.add_box(Point3::origin(), Point3::origin()),
            Err(SceneError::Full)
        );
        let mut s = Scene::empty();
        assert!(
            s.add_box(Point3::new(f64::INFINITY, 0.0, 0.0), Point3::origin())
                .is_err()
        );
    }
}
