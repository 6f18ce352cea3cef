//! The pinhole camera: precomputed per-pixel rays in the robot frame, ray
//! casting against the floor, the ceiling, the walls and the boxes, textured
//! lookups, motion blur by averaging sub-exposures, and sensor noise.
//!
//! Robot frame: `x` forward, `y` left, `z` up. The camera sits
//! [`CameraConfig::forward_m`] ahead of the robot's centre at height
//! [`CameraConfig::height_m`], looking forward and pitched down by
//! [`CameraConfig::pitch_deg`]; image `+x` is right, `+y` down.
//!
//! ```
//! use vlsync_render::camera::{CameraConfig, CameraModel};
//! use vlsync_render::motion::Pose;
//! use vlsync_render::scene::Scene;
//! use vlsync_render::world::Room;
//! let cfg = CameraConfig { width: 64, height: 48, ..CameraConfig::default() };
//! let mut cam = CameraModel::new(&cfg).unwrap();
//! let scene = Scene::new(Room::new(8.0, 5.0, 2.5).unwrap(), 1);
//! let mut img = vec![0u8; 64 * 48];
//! let pose = Pose { x: 2.0, y: 2.5, yaw: 0.0 };
//! cam.render(&scene, &[pose], 0, &mut img).unwrap();
//! assert!(img.iter().any(|&p| p != img[0])); // textured
//! ```

use crate::motion::Pose;
use crate::scene::Scene;
use crate::world::{Room, Surface};
use crate::RenderError;
use vlsync_common::text::number;

/// Camera intrinsics, mounting and sensor parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraConfig {
    /// Image width, pixels (16..=4096).
    pub width: usize,
    /// Image height, pixels (16..=4096).
    pub height: usize,
    /// Horizontal field of view, degrees (10..=150); square pixels.
    pub hfov_deg: f64,
    /// Height of the optical centre above the floor, metres.
    pub height_m: f64,
    /// Mounting point ahead of the robot's centre, metres.
    pub forward_m: f64,
    /// Downward pitch of the optical axis, degrees (0..=80).
    pub pitch_deg: f64,
    /// Frame rate, Hz.
    pub fps: f64,
    /// Exposure time, seconds (0 = instantaneous). Default 8 ms: an indoor
    /// webcam's auto-exposure at a few hundred lux (5-20 ms); at 0.6 m/s it
    /// smears the floor near the bottom of the image by ~4 px.
    pub exposure_s: f64,
    /// Sub-exposures averaged per frame (1..=16): motion blur.
    pub exposure_samples: usize,
    /// Sensor noise, gray levels (1σ, approximately Gaussian, independent per
    /// pixel and frame). Default 2: read plus shot noise of a small consumer
    /// CMOS sensor at mid-gray, 8-bit output (1-3 levels typical).
    pub noise: f32,
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            width: 320,
            height: 240,
            hfov_deg: 60.0,
            height_m: 0.2,
            forward_m: 0.1,
            pitch_deg: 25.0,
            fps: 30.0,
            exposure_s: 0.008,
            exposure_samples: 3,
            noise: 2.0,
        }
    }
}

impl CameraConfig {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), RenderError> {
        let bad = |field, reason: String| Err(RenderError::config(field, reason));
        if !(16..=4096).contains(&self.width) {
            return bad(
                "camera.width",
                format!("{} is outside 16..=4096", self.width),
            );
        }
        if !(16..=4096).contains(&self.height) {
            return bad(
                "camera.height",
                format!("{} is outside 16..=4096", self.height),
            );
        }
        let ranges = [
            ("camera.hfov_deg", self.hfov_deg, 10.0, 150.0),
            ("camera.height_m", self.height_m, 0.02, 2.0),
            ("camera.forward_m", self.forward_m, -1.0, 1.0),
            ("camera.pitch_deg", self.pitch_deg, 0.0, 80.0),
            ("camera.fps", self.fps, 1.0, 1000.0),
            ("camera.exposure_s", self.exposure_s, 0.0, 0.1),
            ("camera.noise", f64::from(self.noise), 0.0, 50.0),
        ];
        for (field, v, lo, hi) in ranges {
            if !(v.is_finite() && v >= lo && v <= hi) {
                return bad(
                    field,
                    format!("{} is outside {}..={}", number(v), number(lo), number(hi)),
                );
            }
        }
        if self.exposure_s >= 1.0 / self.fps {
            return bad(
                "camera.exposure_s",
                format!(
                    "{} s is not shorter than the frame period {} s",
                    self.exposure_s,
                    1.0 / self.fps
                ),
            );
        }
        if !(1..=16).contains(&self.exposure_samples) {
            return bad(
                "camera.exposure_samples",
                format!("{} is outside 1..=16", self.exposure_samples),
            );
        }
        Ok(())
    }

    /// Focal length in pixels.
    pub fn focal_px(&self) -> f64 {
        0.5 * self.width as f64 / (0.5 * self.hfov_deg.to_radians()).tan()
    }
}

/// One pixel's ray, fixed in the robot frame.
#[derive(Debug, Clone, Copy)]
struct PixelRay {
    /// Unit horizontal direction (robot frame).
    ux: f32,
    uy: f32,
    /// Horizontal distance to the floor hit (`inf` when looking up).
    floor: f32,
    /// Horizontal distance to the ceiling hit (`inf` when looking down).
    ceil: f32,
    /// Height change per horizontal metre.
    slope: f32,
}

/// A camera with its precomputed rays.
#[derive(Debug, Clone)]
pub struct CameraModel {
    cfg: CameraConfig,
    rays: Vec<PixelRay>,
    /// accumulation buffer for the sub-exposures
    acc: Vec<f32>,
}

impl CameraModel {
    /// Validates the configuration and precomputes one ray per pixel (centre).
    pub fn new(cfg: &CameraConfig) -> Result<Self, RenderError> {
        cfg.validate()?;
        let f = cfg.focal_px();
        let (cx, cy) = (0.5 * cfg.width as f64, 0.5 * cfg.height as f64);
        let p = cfg.pitch_deg.to_radians();
        let (sp, cp) = p.sin_cos();
        let mut rays = Vec::with_capacity(cfg.width * cfg.height);
        for v in 0..cfg.height {
            let yc = (v as f64 + 0.5 - cy) / f;
            for u in 0..cfg.width {
                let xc = (u as f64 + 0.5 - cx) / f;
                // forward (cp, 0, -sp), right (0, -1, 0), down (-sp, 0, -cp)
                let dx = cp - yc * sp;
                let dy = -xc;
                let dz = -sp - yc * cp;
                let hn = dx.hypot(dy);
                let slope = dz / hn;
                let floor = if dz < 0.0 {
                    cfg.height_m / -slope
                } else {
                    f64::INFINITY
                };
                rays.push(PixelRay {
                    ux: (dx / hn) as f32,
                    uy: (dy / hn) as f32,
                    floor: floor as f32,
                    ceil: f32::INFINITY,
                    slope: slope as f32,
                });
            }
        }
        Ok(Self {
            cfg: *cfg,
            rays,
            acc: vec![0.0; cfg.width * cfg.height],
        })
    }

    /// The configuration.
    pub fn config(&self) -> &CameraConfig {
        &self.cfg
    }

    /// Renders the average of the views from `poses` (the sub-exposures) into
    /// `out` (`width * height` gray pixels, row-major), adding sensor noise
    /// drawn deterministically from `noise_seed`.
    pub fn render(
        &mut self,
        scene: &Scene,
        poses: &[Pose],
        noise_seed: u64,
        out: &mut [u8],
    ) -> Result<(), RenderError> {
        let n = self.cfg.width * self.cfg.height;
        if out.len() != n {
            return Err(RenderError::config(
                "render.out",
                format!(
                    "buffer of {} pixels for a {}x{} image",
                    out.len(),
                    self.cfg.width,
                    self.cfg.height
                ),
            ));
        }
        if poses.is_empty() {
            return Err(RenderError::config(
                "render.poses",
                "no pose to render".into(),
            ));
        }
        let acc = &mut self.acc;
        acc.iter_mut().for_each(|a| *a = 0.0);
        let room = &scene.room;
        let ceil_h = (room.height - self.cfg.height_m) as f32;
        if ceil_h.is_nan() || ceil_h <= 0.0 {
            // a scene built by hand (RenderConfig checks its own): every ray looking
            // up would meet the ceiling behind the camera
            return Err(RenderError::config(
                "camera.height_m",
                format!(
                    "{} m is not below the room's height ({} m): the camera must be inside the room",
                    self.cfg.height_m, room.height
                ),
            ));
        }
        for pose in poses {
            let (s, c) = pose.yaw.sin_cos();
            let cxw = pose.x + c * self.cfg.forward_m;
            let cyw = pose.y + s * self.cfg.forward_m;
            if !room.is_free(cxw, cyw) {
                return Err(RenderError::config(
                    "render.pose",
                    format!("camera at ({cxw:.3}, {cyw:.3}) is outside the free space"),
                ));
            }
            let (s, c) = (s as f32, c as f32);
            // a ray reaching the floor nearer than every wall and box hits the
            // floor: no cast needed (the same pixel value, cheaper)
            let clear = room.clearance(cxw, cyw) as f32;
            for (a, r) in acc.iter_mut().zip(&self.rays) {
                let wx = c * r.ux - s * r.uy;
                let wy = s * r.ux + c * r.uy;
                if r.floor < clear {
                    let d = f64::from(r.floor);
                    *a += scene
                        .floor
                        .sample(cxw + f64::from(wx) * d, cyw + f64::from(wy) * d);
                    continue;
                }
                // the world point at horizontal distance t along the ray
                let at = |t: f32| {
                    let t = f64::from(t);
                    (cxw + f64::from(wx) * t, cyw + f64::from(wy) * t)
                };
                *a += match trace(room, self.cfg.height_m, r, ceil_h, (cxw, cyw), (wx, wy)) {
                    Seen::Floor(t) => {
                        let (x, y) = at(t);
                        scene.floor.sample(x, y)
                    }
                    Seen::Ceiling(t) => {
                        let (x, y) = at(t);
                        0.5 * scene.ceiling.sample(x, y) + 90.0
                    }
                    Seen::Wall { along, z, .. } => scene.wall.sample(along, z),
                    Seen::BoxFace { along, z } => 0.7 * scene.wall.sample(along + 50.0, z) + 20.0,
                    // the boxes' material, laid on the top in world coordinates
                    Seen::BoxTop(t) => {
                        let (x, y) = at(t);
                        0.7 * scene.wall.sample(x + 50.0, y) + 20.0
                    }
                };
            }
        }
        let scale = 1.0 / poses.len() as f32;
        let mut rng = SplitMix(noise_seed);
        let sigma = self.cfg.noise;
        for (o, a) in out.iter_mut().zip(acc.iter()) {
            let noise = if sigma > 0.0 {
                sigma * rng.gauss()
            } else {
                0.0
            };
            *o = (a * scale + noise).round().clamp(0.0, 255.0) as u8;
        }
        Ok(())
    }
}

/// What a pixel's ray meets first; distances are horizontal, metres.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Seen {
    /// The floor, at that distance.
    Floor(f32),
    /// The ceiling, at that distance.
    Ceiling(f32),
    /// A wall at `distance`, `along` it and at height `z`.
    Wall { along: f64, z: f64, distance: f32 },
    /// A box's side, `along` it and at height `z`.
    BoxFace { along: f64, z: f64 },
    /// A box's top, at that distance.
    BoxTop(f32),
}

/// The first surface a pixel's ray `r`, from the camera at `(x, y)` and
/// `height_m` (the ceiling `ceil_h` above it) along the world direction `w`,
/// meets. A ray over a box goes on: to the wall or the box behind it, down onto
/// the box's top, or to the floor or the ceiling beyond, each cast from the camera
/// past the box ([`Room::cast_beyond`]). Each pass starts beyond a box entry
/// further than the last, so it ends within one pass per box.
fn trace(
    room: &Room,
    height_m: f64,
    r: &PixelRay,
    ceil_h: f32,
    (x, y): (f64, f64),
    (wx, wy): (f32, f32),
) -> Seen {
    let (dx, dy) = (f64::from(wx), f64::from(wy));
    let ceil = if r.slope > 0.0 {
        ceil_h / r.slope
    } else {
        r.ceil
    };
    let mut beyond = 0.0;
    // the nearest box top the ray comes down onto, among the boxes it went over
    let mut top = f32::INFINITY;
    loop {
        let hit = room.cast_beyond(x, y, dx, dy, beyond);
        let wall = hit.distance as f32;
        let near = wall.min(top);
        if r.floor < near {
            return Seen::Floor(r.floor);
        }
        if ceil < near {
            return Seen::Ceiling(ceil);
        }
        if top < wall {
            return Seen::BoxTop(top);
        }
        let z = height_m + f64::from(r.slope * wall);
        match hit.surface {
            Surface::Wall => {
                return Seen::Wall {
                    along: hit.along,
                    z,
                    distance: wall,
                }
            }
            Surface::Box(i) => {
                let b = room.boxes[i];
                if z <= b.height {
                    return Seen::BoxFace {
                        along: hit.along,
                        z,
                    };
                }
                // over its face: a ray going down may meet its top before leaving it
                if r.slope < 0.0 {
                    if let Some((_, exit)) = b.span(x, y, dx, dy) {
                        let t = ((b.height - height_m) / f64::from(r.slope)) as f32;
                        if t <= exit as f32 {
                            top = top.min(t);
                        }
                    }
                }
                beyond = hit.distance;
            }
        }
    }
}

/// The step of [`SplitMix`]'s state per draw (the golden ratio's 64-bit fraction).
pub(crate) const SPLITMIX_GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;

/// SplitMix64's finaliser: a bijection of `u64` that scatters nearby inputs.
pub(crate) fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The pixel noise's seed of frame `index` of a run of seed `seed`. Each frame's noise
/// is a [`SplitMix`] stream from it, whose state steps by [`SPLITMIX_GAMMA`] per pixel:
/// two frames' streams must not be one shifted copy of the other (until 2026-12-06 the
/// seed was `seed ^ index·γ`, which for a seed below 2^b made frame k+2^b's noise frame
/// k's shifted by 2^b pixels: noise that moves coherently, which optical flow can see).
pub(crate) fn frame_noise_seed(seed: u64, index: u64) -> u64 {
    mix64(mix64(seed) ^ index)
}

/// A tiny deterministic generator for pixel noise.
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(SPLITMIX_GAMMA);
        mix64(self.0)
    }

    /// Approximately standard normal: the sum of four uniforms, scaled.
    fn gauss(&mut self) -> f32 {
        let r = self.next();
        let u = |k: u32| ((r >> (16 * k)) & 0xFFFF) as f32 / 65535.0;
        // sum of 4 U(0,1): mean 2, variance 1/3
        (u(0) + u(1) + u(2) + u(3) - 2.0) * 1.732_050_8
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::BoxObstacle;

    /// The inverse of an odd `a` modulo 2^64 (Newton's iteration).
    fn inverse(a: u64) -> u64 {
        let mut x = a;
        for _ in 0..6 {
            x = x.wrapping_mul(2u64.wrapping_sub(a.wrapping_mul(x)));
        }
        x
    }

    /// No frame's noise stream is another's shifted by fewer pixels than the largest
    /// image has (4096 x 4096): the state difference of two frames' streams, in steps of
    /// γ, is never that small, for the seeds the docs and tests use and their first frames.
    #[test]
    fn frames_draw_independent_noise() {
        let g_inv = inverse(SPLITMIX_GAMMA);
        assert_eq!(SPLITMIX_GAMMA.wrapping_mul(g_inv), 1);
        let max_pixels = 4096u64 * 4096;
        let steps = |a: u64, b: u64| b.wrapping_sub(a).wrapping_mul(g_inv);
        for seed in (0..16).chain([100, 12345, 5000, 5039]) {
            let s: Vec<u64> = (0..300).map(|k| frame_noise_seed(seed, k)).collect();
            for (i, &a) in s.iter().enumerate() {
                for &b in &s[i + 1..] {
                    let d = steps(a, b);
                    assert!(
                        d > max_pixels && d.wrapping_neg() > max_pixels,
                        "seed {seed}: two frames' noise {d} draws apart"
                    );
                }
            }
        }
        // what the old derivation gave: seed 1, frames 0 and 2, two draws apart
        let old = |seed: u64, k: u64| seed ^ k.wrapping_mul(SPLITMIX_GAMMA);
        assert_eq!(steps(old(1, 0), old(1, 2)), 2);
    }

    fn scene() -> Scene {
        Scene::new(Room::new(8.0, 5.0, 2.5).unwrap(), 3)
    }

    #[test]
    fn a_range_error_quotes_a_huge_value_in_exponent_form() {
        let e = CameraConfig {
            fps: 1e300,
            ..CameraConfig::default()
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("camera.fps") && e.contains("1e300 is outside 1..=1000"),
            "{e}"
        );
    }

    #[test]
    fn rays_hit_the_floor_where_geometry_says() {
        let cfg = CameraConfig::default();
        let cam = CameraModel::new(&cfg).unwrap();
        // the centre ray is pitched 25° down: floor at h / tan(25°)
        let (w, h) = (cfg.width, cfg.height);
        let r = cam.rays[(h / 2) * w + w / 2];
        let expect = 0.2 / 25f64.to_radians().tan();
        assert!((f64::from(r.floor) - expect).abs() < 3e-3, "{}", r.floor);
        // top rows look above the horizon (65.5° half vfov is not reached at 25° pitch
        // and 60° hfov, but the default vfov of ~47° keeps the top row below it)
        assert!(cam.rays[0].floor.is_finite());
        let up = CameraModel::new(&CameraConfig {
            pitch_deg: 0.0,
            ..cfg
        })
        .unwrap();
        assert!(up.rays[0].floor.is_infinite() && up.rays[0].slope > 0.0);
    }

    /// A scene built by hand with the camera at or above its ceiling is an error
    /// naming the height, not an image of the ceiling seen from behind.
    #[test]
    fn a_camera_above_a_hand_built_room_s_ceiling_is_refused() {
        let cfg = CameraConfig {
            height_m: 0.6,
            ..CameraConfig::default()
        };
        let mut cam = CameraModel::new(&cfg).unwrap();
        let low = Scene::new(Room::new(8.0, 5.0, 0.5).unwrap(), 3);
        let mut out = vec![0u8; cfg.width * cfg.height];
        let pose = Pose {
            x: 2.0,
            y: 2.5,
            yaw: 0.0,
        };
        let e = cam
            .render(&low, &[pose], 0, &mut out)
            .unwrap_err()
            .to_string();
        assert!(e.contains("camera.height_m") && e.contains("0.6"), "{e}");
        cam.render(&scene(), &[pose], 0, &mut out).unwrap();
    }

    #[test]
    fn moving_forward_moves_the_floor_down_the_image() {
        // a forward step shifts the floor texture toward the bottom of the image
        let cfg = CameraConfig {
            noise: 0.0,
            ..CameraConfig::default()
        };
        let mut cam = CameraModel::new(&cfg).unwrap();
        let sc = scene();
        let (w, h) = (cfg.width, cfg.height);
        let mut a = vec![0u8; w * h];
        let mut b = vec![0u8; w * h];
        cam.render(
            &sc,
            &[Pose {
                x: 2.0,
                y: 2.5,
                yaw: 0.0,
            }],
            0,
            &mut a,
        )
        .unwrap();
        cam.render(
            &sc,
            &[Pose {
                x: 2.01,
                y: 2.5,
                yaw: 0.0,
            }],
            0,
            &mut b,
        )
        .unwrap();
        // best vertical shift of the bottom-centre block
        let block = |img: &[u8], dy: usize| -> Vec<f64> {
            (0..40)
                .flat_map(|y| (140..180).map(move |x| (x, y)))
                .map(|(x, y)| f64::from(img[(170 + y + dy) * w + x]))
                .collect()
        };
        let base = block(&a, 0);
        let best = (0..20)
            .min_by_key(|&dy| {
                let o = block(&b, dy);
                base.iter()
                    .zip(&o)
                    .map(|(p, q)| ((p - q) * (p - q)) as u64)
                    .sum::<u64>()
            })
            .unwrap();
        assert!((2..15).contains(&best), "{best}");
        assert!(cam.render(&sc, &[], 0, &mut a).is_err());
        assert!(cam
            .render(
                &sc,
                &[Pose {
                    x: -1.0,
                    y: 2.5,
                    yaw: 0.0
                }],
                0,
                &mut a
            )
            .is_err());
        assert!(cam
            .render(
                &sc,
                &[Pose {
                    x: 2.0,
                    y: 2.5,
                    yaw: 0.0
                }],
                0,
                &mut a[1..]
            )
            .is_err());
    }

    /// A ray over a box sees what it would see without the box: the wall behind
    /// at its own distance and height, or the floor or the ceiling beyond the box.
    /// (It used to be cast again from the box's face, where it met the same box
    /// again about half the time and was textured as the wall at the face; and past
    /// a box neither the floor nor the ceiling was looked for: a ray going up met
    /// the wall above the ceiling, one going down the wall under the floor.) A
    /// 90° lens 0.4 m up, pitched 10° down: rays both over and down past a box.
    #[test]
    fn a_ray_over_a_box_sees_what_is_behind_it() {
        let cfg = CameraConfig {
            width: 96,
            height: 72,
            hfov_deg: 90.0,
            pitch_deg: 10.0,
            height_m: 0.4,
            noise: 0.0,
            ..CameraConfig::default()
        };
        let mut cam = CameraModel::new(&cfg).unwrap();
        let mut boxed = Room::new(8.0, 5.0, 2.5).unwrap();
        boxed.boxes.push(BoxObstacle {
            x0: 3.0,
            y0: 1.5,
            x1: 3.5,
            y1: 3.5,
            height: 0.3,
        });
        let with = Scene::new(boxed, 3);
        let without = Scene {
            room: Room::new(8.0, 5.0, 2.5).unwrap(),
            ..with.clone()
        };
        // the camera at (1.1, 2.5), facing +x
        let pose = [Pose {
            x: 1.0,
            y: 2.5,
            yaw: 0.0,
        }];
        let (mut a, mut b) = (vec![0u8; 96 * 72], vec![0u8; 96 * 72]);
        cam.render(&with, &pose, 0, &mut a).unwrap();
        cam.render(&without, &pose, 0, &mut b).unwrap();
        // the rays that pass over the box: through its far face (x = 3.5, inside
        // its width, 2.4 m ahead), above its top there
        let mut over = 0;
        for (k, r) in cam.rays.iter().enumerate() {
            let (ux, uy, slope) = (f64::from(r.ux), f64::from(r.uy), f64::from(r.slope));
            if (uy / ux).abs() < 0.4 && 0.4 + slope * 2.4 / ux > 0.31 {
                assert_eq!(a[k], b[k], "pixel ({}, {})", k % 96, k / 96);
                over += 1;
            }
        }
        assert!(over > 1000, "{over} pixels over the box");
        // and the box is in the picture
        assert!(a.iter().zip(&b).filter(|(p, q)| p != q).count() > 100);
    }

    /// The surface a ray meets past a box, where and how far: the wall behind it
    /// (at the distance and height of the room without the box), the box's top
    /// when the ray comes down onto it, the floor or the ceiling beyond it.
    #[test]
    fn a_ray_past_a_box_meets_the_next_surface_at_its_distance() {
        let mut room = Room::new(8.0, 5.0, 2.5).unwrap();
        let empty = room.clone();
        room.boxes.push(BoxObstacle {
            x0: 3.0,
            y0: 1.5,
            x1: 3.5,
            y1: 3.5,
            height: 0.25,
        });
        let ray = |a: f64, slope: f64, h: f64| PixelRay {
            ux: a.cos() as f32,
            uy: a.sin() as f32,
            floor: if slope < 0.0 {
                (h / -slope) as f32
            } else {
                f32::INFINITY
            },
            ceil: f32::INFINITY,
            slope: slope as f32,
        };
        let dir = |r: &PixelRay| (r.ux, r.uy);
        // rising 5 cm a metre from 0.2 m: over the box (0.3 m up at its face) to the
        // wall behind, at the empty room's distance and along it, at that height
        for a in [-0.3, -0.11, 0.0, 0.07, 0.2, 0.33] {
            let r = ray(a, 0.05, 0.2);
            let (wx, wy) = dir(&r);
            let seen = trace(&room, 0.2, &r, 2.3, (1.0, 2.5), (wx, wy));
            let want = empty.cast(1.0, 2.5, f64::from(wx), f64::from(wy));
            let Seen::Wall { along, z, distance } = seen else {
                panic!("{a}: {seen:?}");
            };
            assert_eq!(distance, want.distance as f32, "{a}");
            assert_eq!(along, want.along, "{a}");
            assert!((z - (0.2 + 0.05 * want.distance)).abs() < 1e-6, "{a}: {z}");
            assert!(z > 0.5, "{a}: {z}");
        }
        // from 0.4 m, 10 cm down a metre, from x = 2.2 (the box 0.8-1.3 m ahead):
        // a 0.25 m box is passed (0.27 m at its far face), the floor is 4 m ahead
        let r = ray(0.0, -0.1, 0.4);
        assert_eq!(
            trace(&room, 0.4, &r, 2.1, (2.2, 2.5), dir(&r)),
            Seen::Floor(4.0)
        );
        // a 0.3 m one is met on its top, 1 m ahead (0.32 m up at its face)
        let mut tall = room.clone();
        tall.boxes[0].height = 0.3;
        let Seen::BoxTop(t) = trace(&tall, 0.4, &r, 2.1, (2.2, 2.5), dir(&r)) else {
            panic!("no box top");
        };
        assert!((t - 1.0).abs() < 1e-6, "{t}");
        // rising 1 m a metre: over the box, into the ceiling 2.1 m ahead
        let r = ray(0.0, 1.0, 0.4);
        assert_eq!(
            trace(&room, 0.4, &r, 2.1, (2.2, 2.5), dir(&r)),
            Seen::Ceiling(2.1)
        );
        // and a ray that meets the box below its top sees the box
        let r = ray(0.0, 0.01, 0.2);
        assert!(matches!(
            trace(&room, 0.2, &r, 2.3, (1.0, 2.5), dir(&r)),
            Seen::BoxFace { .. }
        ));
    }

    #[test]
    fn noise_is_deterministic_and_near_gaussian() {
        let mut r = SplitMix(5);
        let v: Vec<f32> = (0..20000).map(|_| r.gauss()).collect();
        let m = v.iter().sum::<f32>() / v.len() as f32;
        let s = (v.iter().map(|x| (x - m).powi(2)).sum::<f32>() / v.len() as f32).sqrt();
        assert!(m.abs() < 0.03 && (s - 1.0).abs() < 0.03, "{m} {s}");
        let mut r2 = SplitMix(5);
        assert_eq!(r2.gauss(), v[0]);
        let bad = CameraConfig {
            exposure_s: 0.05,
            ..CameraConfig::default()
        };
        assert!(CameraModel::new(&bad)
            .unwrap_err()
            .to_string()
            .contains("exposure_s"));
    }
}
