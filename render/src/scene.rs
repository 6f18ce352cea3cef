//! The scene: the room and its textures (floor, walls and boxes, ceiling).
//!
//! ```
//! use vlsync_render::scene::Scene;
//! use vlsync_render::world::Room;
//! let s = Scene::new(Room::new(8.0, 5.0, 2.5).unwrap(), 4);
//! assert!(s.floor.sample(1.0, 2.0) != s.floor.sample(1.05, 2.0));
//! ```

use crate::texture::Texture;
use crate::world::Room;

/// Floor texel size, metres: about a pixel's footprint at the default camera's ROI.
pub const FLOOR_TEXEL_M: f64 = 0.002;

/// A room with its textures.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Geometry.
    pub room: Room,
    /// Floor texture (world `x`, `y`).
    pub floor: Texture,
    /// Wall and box texture (coordinate along the surface, height).
    pub wall: Texture,
    /// Ceiling texture (world `x`, `y`).
    pub ceiling: Texture,
}

impl Scene {
    /// Textures the room deterministically from `seed`: a 2 mm floor texture
    /// (4 m tile, 10 cm checker blended into multi-scale noise), 5 mm walls,
    /// 1 cm ceiling.
    pub fn new(room: Room, seed: u64) -> Self {
        Self {
            room,
            floor: Texture::generate(2048, FLOOR_TEXEL_M, seed, 0.1),
            wall: Texture::generate(1024, 0.005, seed.wrapping_add(1), 0.25),
            ceiling: Texture::generate(256, 0.01, seed.wrapping_add(2), 0.0),
        }
    }
}
