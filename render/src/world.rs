//! The 2-D room: rectangular walls and optional axis-aligned box obstacles, and
//! horizontal ray casting against them.
//!
//! World frame: `x` along the room's length (the robot drives along it), `y`
//! across, `z` up; the room spans `[0, length] x [0, width]`. Angles are CCW
//! positive seen from above, `0` = `+x`.
//!
//! ```
//! use vlsync_render::world::{Room, Surface};
//! let room = Room::new(8.0, 5.0, 2.5).unwrap();
//! let hit = room.cast(2.0, 2.5, 1.0, 0.0); // from (2, 2.5) toward +x
//! assert!((hit.distance - 6.0).abs() < 1e-12);
//! assert_eq!(hit.surface, Surface::Wall);
//! assert!((hit.along - 2.5).abs() < 1e-12); // 2.5 m along the front wall
//! ```

use crate::RenderError;
use vlsync_common::text::number;

/// An axis-aligned box standing on the floor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxObstacle {
    /// Smallest x, metres.
    pub x0: f64,
    /// Smallest y, metres.
    pub y0: f64,
    /// Largest x, metres.
    pub x1: f64,
    /// Largest y, metres.
    pub y1: f64,
    /// Height, metres.
    pub height: f64,
}

impl BoxObstacle {
    /// True when `(x, y)` lies inside the box's footprint (edges included).
    pub fn contains(&self, x: f64, y: f64) -> bool {
        x >= self.x0 && x <= self.x1 && y >= self.y0 && y <= self.y1
    }

    /// Where a horizontal ray from `(x, y)`, outside the footprint, along the unit
    /// direction `(dx, dy)` crosses the footprint: the distances at which it enters
    /// and leaves it (`None` when it misses). A ray that passes over the box comes
    /// down onto its top only between the two.
    pub fn span(&self, x: f64, y: f64, dx: f64, dy: f64) -> Option<(f64, f64)> {
        slab(self, x, y, dx, dy, 0.0).map(|(near, far, _)| (near, far))
    }
}

/// What a horizontal ray hit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Surface {
    /// One of the room's four walls.
    Wall,
    /// A box obstacle (index into [`Room::boxes`]).
    Box(usize),
}

/// The first surface met by a horizontal ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Horizontal distance to the surface, metres (`+inf` if none).
    pub distance: f64,
    /// Coordinate along the surface (for texturing), metres.
    pub along: f64,
    /// Which surface.
    pub surface: Surface,
}

/// A rectangular room with box obstacles.
#[derive(Debug, Clone, PartialEq)]
pub struct Room {
    /// Extent along x, metres.
    pub length: f64,
    /// Extent along y, metres.
    pub width: f64,
    /// Wall height (the ceiling), metres.
    pub height: f64,
    /// Obstacles.
    pub boxes: Vec<BoxObstacle>,
}

impl Room {
    /// An empty room; every dimension must be finite and in `0.5..=100` m.
    pub fn new(length: f64, width: f64, height: f64) -> Result<Self, RenderError> {
        for (field, v) in [
            ("room.length", length),
            ("room.width", width),
            ("room.height", height),
        ] {
            if !(v.is_finite() && (0.5..=100.0).contains(&v)) {
                return Err(RenderError::config(
                    field,
                    format!("{} m is outside 0.5..=100", number(v)),
                ));
            }
        }
        Ok(Self {
            length,
            width,
            height,
            boxes: Vec::new(),
        })
    }

    /// True when `(x, y)` is inside the room and outside every box.
    pub fn is_free(&self, x: f64, y: f64) -> bool {
        x > 0.0
            && x < self.length
            && y > 0.0
            && y < self.width
            && !self.boxes.iter().any(|b| b.contains(x, y))
    }

    /// Horizontal distance from `(x, y)` (inside the room) to the nearest wall
    /// or box: no ray cast from there hits anything closer.
    pub fn clearance(&self, x: f64, y: f64) -> f64 {
        let walls = x.min(self.length - x).min(y).min(self.width - y);
        self.boxes.iter().fold(walls, |m, b| {
            let dx = (b.x0 - x).max(x - b.x1).max(0.0);
            let dy = (b.y0 - y).max(y - b.y1).max(0.0);
            m.min(dx.hypot(dy))
        })
    }

    /// Casts a horizontal ray from `(x, y)` (inside the room) along the unit
    /// direction `(dx, dy)`. Returns the nearest wall or box face.
    pub fn cast(&self, x: f64, y: f64, dx: f64, dy: f64) -> Hit {
        self.cast_beyond(x, y, dx, dy, 0.0)
    }

    /// [`Room::cast`] past the first `beyond` metres: boxes the ray enters at
    /// `beyond` or nearer are left out. What a ray that passes over a box meets
    /// next is cast again from the same origin with `beyond` at that box's entry:
    /// cast from the box's face instead, the ray met the same box again about half
    /// the time, at a rounding error's distance.
    pub fn cast_beyond(&self, x: f64, y: f64, dx: f64, dy: f64, beyond: f64) -> Hit {
        // the room: exit through the nearer of the x and y walls
        let tx = if dx > 0.0 {
            (self.length - x) / dx
        } else if dx < 0.0 {
            -x / dx
        } else {
            f64::INFINITY
        };
        let ty = if dy > 0.0 {
            (self.width - y) / dy
        } else if dy < 0.0 {
            -y / dy
        } else {
            f64::INFINITY
        };
        let mut best = if tx <= ty {
            // x = 0 or x = length walls: texture along y (offset so walls differ)
            let along = y + dy * tx + if dx > 0.0 { 0.0 } else { 2.0 * self.width };
            Hit {
                distance: tx,
                along,
                surface: Surface::Wall,
            }
        } else {
            let along = x + dx * ty + 3.0 * self.width + if dy > 0.0 { 0.0 } else { self.length };
            Hit {
                distance: ty,
                along,
                surface: Surface::Wall,
            }
        };
        for (i, b) in self.boxes.iter().enumerate() {
            if let Some((t, _, along)) = slab(b, x, y, dx, dy, beyond) {
                if t < best.distance {
                    best = Hit {
                        distance: t,
                        along,
                        surface: Surface::Box(i),
                    };
                }
            }
        }
        best
    }
}

/// Entry and exit distances of a ray into an axis-aligned box (from outside,
/// entering beyond `beyond`), and the coordinate along the face it enters.
fn slab(b: &BoxObstacle, x: f64, y: f64, dx: f64, dy: f64, beyond: f64) -> Option<(f64, f64, f64)> {
    let inv_x = 1.0 / dx;
    let inv_y = 1.0 / dy;
    let (ax, bx) = ((b.x0 - x) * inv_x, (b.x1 - x) * inv_x);
    let (ay, by) = ((b.y0 - y) * inv_y, (b.y1 - y) * inv_y);
    let (nx, fx) = if ax <= bx { (ax, bx) } else { (bx, ax) };
    let (ny, fy) = if ay <= by { (ay, by) } else { (by, ay) };
    // NaN (0 * inf when the ray runs along a face) compares false: no hit
    let near = if nx > ny { nx } else { ny };
    let far = if fx < fy { fx } else { fy };
    let hit = near <= far && near > beyond;
    if !hit {
        return None;
    }
    let along = if nx > ny {
        y + dy * near
    } else {
        x + dx * near
    };
    Some((near, far, along))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn room() -> Room {
        let mut r = Room::new(8.0, 5.0, 2.5).unwrap();
        r.boxes.push(BoxObstacle {
            x0: 3.0,
            y0: 0.0,
            x1: 4.0,
            y1: 1.0,
            height: 0.5,
        });
        r
    }

    #[test]
    fn walls_and_boxes() {
        let r = room();
        let h = r.cast(1.0, 0.5, 1.0, 0.0);
        assert_eq!(h.surface, Surface::Box(0));
        assert!((h.distance - 2.0).abs() < 1e-12);
        let h = r.cast(1.0, 2.0, -1.0, 0.0);
        assert!((h.distance - 1.0).abs() < 1e-12);
        let h = r.cast(1.0, 2.0, 0.0, 1.0);
        assert!((h.distance - 3.0).abs() < 1e-12);
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let h = r.cast(1.0, 1.0, s, s);
        assert!((h.distance - 4.0 * 2f64.sqrt()).abs() < 1e-9, "{h:?}");
        assert!(Room::new(f64::NAN, 1.0, 1.0).is_err());
        assert!(Room::new(8.0, 0.1, 1.0)
            .unwrap_err()
            .to_string()
            .contains("room.width"));
        assert!(!r.is_free(3.5, 0.5) && r.is_free(3.5, 2.0) && !r.is_free(-1.0, 2.0));
    }

    /// Past a box's entry the box is left out and the wall behind it is met at
    /// its own distance from the same origin; a box's span is where the ray
    /// crosses its footprint.
    #[test]
    fn a_cast_beyond_a_box_meets_what_is_behind_it() {
        let r = room();
        let a = 0.3f64;
        let (dx, dy) = (a.cos(), a.sin());
        // from (2, 0.2): into the box's x = 3 face, out through its x = 4 face
        let h = r.cast(2.0, 0.2, dx, dy);
        assert_eq!(h.surface, Surface::Box(0));
        let (near, far) = r.boxes[0].span(2.0, 0.2, dx, dy).unwrap();
        assert_eq!(near, h.distance);
        assert!((near - 1.0 / dx).abs() < 1e-12 && (far - 2.0 / dx).abs() < 1e-12);
        let behind = r.cast_beyond(2.0, 0.2, dx, dy, h.distance);
        let empty = Room::new(8.0, 5.0, 2.5).unwrap().cast(2.0, 0.2, dx, dy);
        assert_eq!(behind, empty);
        assert_eq!(behind.surface, Surface::Wall);
        assert!(r.boxes[0].span(2.0, 2.0, 1.0, 0.0).is_none());
    }

    proptest! {
        /// The hit point lies on the room boundary or a box face, and no
        /// sampled point before it is outside the free space.
        #[test]
        fn hit_is_first_obstacle(x in 0.1f64..7.9, y in 1.1f64..4.9, a in -3.2f64..3.2) {
            let r = room();
            prop_assume!(r.is_free(x, y));
            let (dx, dy) = (a.cos(), a.sin());
            let h = r.cast(x, y, dx, dy);
            prop_assert!(h.distance.is_finite() && h.distance > 0.0);
            let (hx, hy) = (x + dx * h.distance, y + dy * h.distance);
            let on_wall = hx.abs() < 1e-9 || (hx - 8.0).abs() < 1e-9 || hy.abs() < 1e-9 || (hy - 5.0).abs() < 1e-9;
            let on_box = hx > 3.0 - 1e-9 && hx < 4.0 + 1e-9 && hy > -1e-9 && hy < 1.0 + 1e-9;
            prop_assert!(on_wall || on_box, "{hx} {hy}");
            prop_assert!(r.clearance(x, y) <= h.distance + 1e-9);
            for k in 1..50 {
                let s = h.distance * (k as f64) / 50.0 - 1e-9;
                prop_assert!(r.is_free(x + dx * s, y + dy * s) || s <= 0.0);
            }
        }
    }
}
