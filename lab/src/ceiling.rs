//! The humanoid lab's ceiling-camera pipeline (seed Ch. 6.4, Table 6.2): four wide-angle
//! network cameras looking down on the field (AXIS M3005-V, 118°, Ch. 6.2.1), each frame
//! undistorted, the four stitched into one top-down image of the carpet, and the ball found in
//! it.
//!
//! The cameras are network cameras: they scale and encode on board and stream the resolution
//! the lab asks for (`width` × `height`, default 256 × 144 of their 1920 × 1080 sensor), so the
//! lab's computer never handles full-resolution pixels. A NAO has no such camera: its driver
//! hands the robot's own CPU 1280 × 960 frames, which its subsampler must reduce before
//! anything else can run (Ch. 6.3). That is why the ceiling pipeline's measured upkeep is the
//! lower one, though it has more stages.
//!
//! Lens distortion follows the one-parameter division model: a distorted normalised point
//! `p_d` is the undistorted `p_u = p_d / (1 + k |p_d|²)`.

use crate::image::Noise;
use crate::world::{
    BALL_RADIUS, BORDER, CEILING_CAMERAS, CEILING_HEIGHT, CeilingCamera, FIELD_LENGTH, FIELD_WIDTH,
    World, mix, on_carpet, quarter_of,
};

/// The stream's default width.
pub const WIDTH: usize = 256;
/// The stream's default height.
pub const HEIGHT: usize = 144;
/// The lens' distortion (division model; negative: barrel).
pub const K: f64 = -0.2;
/// Half the distorted image's width in normalised coordinates (the 118° lens).
pub const HALF_WIDTH_DISTORTED: f64 = 1.25;
/// Half the undistorted image's width in normalised coordinates.
pub const HALF_WIDTH_UNDISTORTED: f64 = 1.1;
/// The stitched image's resolution, metres per pixel.
pub const RESOLUTION: f64 = 0.04;

/// A colour in RGB.
pub type Rgb = [u8; 3];
/// The carpet.
pub const GREEN: Rgb = [40, 140, 50];
/// The floor beyond it.
pub const FLOOR: Rgb = [120, 120, 120];
/// The ball.
pub const ORANGE: Rgb = [250, 120, 20];

/// Whether a pixel looks like the ball.
#[must_use]
pub fn is_orange(p: &[u8]) -> bool {
    p[0] > 180 && p[1] < 170 && p[2] < 90
}

/// A camera's focal lengths: distorted (raw stream) and undistorted, in pixels.
#[must_use]
pub fn focals(width: usize) -> (f64, f64) {
    let half = width as f64 / 2.0;
    (half / HALF_WIDTH_DISTORTED, half / HALF_WIDTH_UNDISTORTED)
}

/// The undistorted radius of a distorted one.
#[must_use]
pub fn undistort_radius(rd: f64) -> f64 {
    rd / (1.0 + K * rd * rd)
}

/// The distorted radius of an undistorted one (the division model's inverse).
#[must_use]
pub fn distort_radius(ru: f64) -> f64 {
    if ru < 1e-12 {
        return ru;
    }
    (1.0 - (1.0 - 4.0 * K * ru * ru).sqrt()) / (2.0 * K * ru)
}

/// Where a point of the plane at `height` appears, looking straight down from `camera`, in
/// undistorted normalised coordinates (image x along the field's x, image y against its y).
fn normalised(camera: &CeilingCamera, x: f64, y: f64, height: f64) -> (f64, f64) {
    let h = CEILING_HEIGHT - height;
    ((x - camera.x) / h, -(y - camera.y) / h)
}

/// A ceiling camera's raw frame at `t_ms` (RGB, `width` × `height`, distorted by the lens):
/// the carpet, the floor beyond it, the ball, sensor noise.
#[must_use]
pub fn render(world: &World, camera: usize, width: usize, height: usize, t_ms: i64) -> Vec<u8> {
    let cam = &CEILING_CAMERAS[camera];
    let (fd, _) = focals(width);
    let (bx, by) = world.ball_at(t_ms);
    // The ball seen from above: the disc of rays that hit it, projected to the carpet.
    let (ball_u, ball_v) = normalised(cam, bx, by, BALL_RADIUS);
    let ball_r = BALL_RADIUS / (CEILING_HEIGHT - BALL_RADIUS);
    let mut frame = vec![0u8; width * height * 3];
    for row in 0..height {
        let yd = (row as f64 + 0.5 - height as f64 / 2.0) / fd;
        for col in 0..width {
            let xd = (col as f64 + 0.5 - width as f64 / 2.0) / fd;
            let s = 1.0 / (1.0 + K * (xd * xd + yd * yd));
            let (xu, yu) = (xd * s, yd * s);
            let colour = if (xu - ball_u).hypot(yu - ball_v) <= ball_r {
                ORANGE
            } else if on_carpet(cam.x + xu * CEILING_HEIGHT, cam.y - yu * CEILING_HEIGHT) {
                GREEN
            } else {
                FLOOR
            };
            frame[(row * width + col) * 3..][..3].copy_from_slice(&colour);
        }
    }
    Noise::new(mix(&[world.seed, 100 + camera as u64, t_ms as u64])).apply(&mut frame, 8);
    frame
}

/// Undistortion (tids 16, 18, 20, 22): a remap table computed once, when the CU starts (its
/// labour), then one gather per pixel per frame (its upkeep).
#[derive(Debug, Clone)]
pub struct Undistorter {
    width: usize,
    height: usize,
    source: Vec<u32>,
}

/// Marks a pixel with no source.
const NONE: u32 = u32::MAX;

impl Undistorter {
    /// The table for `width` × `height` frames: the undistorted (pinhole) image has the same
    /// size and the focal length of [`focals`].
    #[must_use]
    pub fn new(width: usize, height: usize) -> Self {
        let (fd, fu) = focals(width);
        let mut source = Vec::with_capacity(width * height);
        for row in 0..height {
            let yu = (row as f64 + 0.5 - height as f64 / 2.0) / fu;
            for col in 0..width {
                let xu = (col as f64 + 0.5 - width as f64 / 2.0) / fu;
                let ru = xu.hypot(yu);
                let s = if ru < 1e-12 {
                    1.0
                } else {
                    distort_radius(ru) / ru
                };
                let (c, r) = (
                    (xu * s * fd + width as f64 / 2.0).floor(),
                    (yu * s * fd + height as f64 / 2.0).floor(),
                );
                source.push(
                    if (0.0..width as f64).contains(&c) && (0.0..height as f64).contains(&r) {
                        (r as usize * width + c as usize) as u32
                    } else {
                        NONE
                    },
                );
            }
        }
        Self {
            width,
            height,
            source,
        }
    }

    /// The frame size the table is for.
    #[must_use]
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// An undistorted frame.
    #[must_use]
    pub fn apply(&self, raw: &[u8]) -> Vec<u8> {
        let mut out = vec![0u8; self.source.len() * 3];
        for (o, &s) in out.chunks_exact_mut(3).zip(&self.source) {
            if s != NONE {
                o.copy_from_slice(&raw[s as usize * 3..][..3]);
            }
        }
        out
    }
}

/// The stitched image's size: the carpet at [`RESOLUTION`].
#[must_use]
pub fn stitched_size() -> (usize, usize) {
    (
        ((FIELD_LENGTH + 2.0 * BORDER) / RESOLUTION).round() as usize,
        ((FIELD_WIDTH + 2.0 * BORDER) / RESOLUTION).round() as usize,
    )
}

/// The stitcher (tid 23): a table from each pixel of the top-down image of the carpet to the
/// pixel of the undistorted frame of the camera over its quarter, computed once for a frame
/// size. The image is of the plane of the ball's centre (0.05 m above the carpet), not of the
/// carpet: so a ball on the seam between two quarters is where both cameras see it, instead of
/// shifted away from the seam by each camera's parallax (and lost in it).
#[derive(Debug, Clone)]
pub struct Stitcher {
    frame: (usize, usize),
    source: Vec<(u8, u32)>,
}

impl Stitcher {
    /// The table for undistorted frames of `width` × `height`.
    #[must_use]
    pub fn new(width: usize, height: usize) -> Self {
        let (_, fu) = focals(width);
        let (w, h) = stitched_size();
        let mut source = Vec::with_capacity(w * h);
        for j in 0..h {
            let y = -BORDER + (j as f64 + 0.5) * RESOLUTION;
            for i in 0..w {
                let x = -BORDER + (i as f64 + 0.5) * RESOLUTION;
                let camera = quarter_of(x, y);
                let (xu, yu) = normalised(&CEILING_CAMERAS[camera], x, y, BALL_RADIUS);
                let (c, r) = (
                    (xu * fu + width as f64 / 2.0).floor(),
                    (yu * fu + height as f64 / 2.0).floor(),
                );
                source.push(
                    if (0.0..width as f64).contains(&c) && (0.0..height as f64).contains(&r) {
                        (camera as u8, (r as usize * width + c as usize) as u32)
                    } else {
                        (0, NONE)
                    },
                );
            }
        }
        Self {
            frame: (width, height),
            source,
        }
    }

    /// The frame size the table is for.
    #[must_use]
    pub fn frame_size(&self) -> (usize, usize) {
        self.frame
    }

    /// The top-down image from the four undistorted frames, in camera order.
    #[must_use]
    pub fn apply(&self, frames: [&[u8]; 4]) -> Vec<u8> {
        let mut out = vec![0u8; self.source.len() * 3];
        for (o, &(camera, s)) in out.chunks_exact_mut(3).zip(&self.source) {
            if s != NONE {
                o.copy_from_slice(&frames[camera as usize][s as usize * 3..][..3]);
            }
        }
        out
    }
}

/// The field's ball detector (tid 24): the centroid of the ball-coloured pixels of the
/// top-down image (of the plane of the ball's centre); `None` when there is none (sensor
/// noise never turns the carpet or the floor ball-coloured).
#[must_use]
pub fn detect(top_down: &[u8]) -> Option<(f64, f64)> {
    let (w, _) = stitched_size();
    let (mut n, mut sx, mut sy) = (0usize, 0.0, 0.0);
    for (k, p) in top_down.chunks_exact(3).enumerate() {
        if is_orange(p) {
            n += 1;
            sx += (k % w) as f64 + 0.5;
            sy += (k / w) as f64 + 0.5;
        }
    }
    if n == 0 {
        return None;
    }
    Some((
        -BORDER + sx / n as f64 * RESOLUTION,
        -BORDER + sy / n as f64 * RESOLUTION,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distortion_inverts() {
        for i in 0..200 {
            let ru = f64::from(i) * 0.01;
            assert!(
                (undistort_radius(distort_radius(ru)) - ru).abs() < 1e-9,
                "{ru}"
            );
        }
    }
}
