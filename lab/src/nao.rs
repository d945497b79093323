//! A NAO robot's ball pipeline (seed Ch. 6.3, Table 6.1, Figure 6.3): the bottom camera's
//! 1280 × 960 YUV422 frames (Ch. 6.2.2), the subsampler's scale pyramid of the three channels
//! (640 × 480 down to 40 × 30), the segmenter's convex hull of the green field on the
//! low-resolution Y, U and V channels, the ball detector's pixel position within the hull, and
//! the localisation of that pixel on the field with the robot's pose.
//!
//! Each stage is a pure function here, and a [`Transformation`] in [`crate::stages`].

use crate::image::Noise;
use crate::world::{
    BALL_RADIUS, NAO_BOTTOM_CAMERA_PITCH, NAO_CAMERA_HEIGHT, Pose, ROBOTS, Robot, World, mix,
    on_carpet, unit,
};

/// The bottom camera's frame width (seed Ch. 6.2.2).
pub const WIDTH: usize = 1280;
/// The bottom camera's frame height.
pub const HEIGHT: usize = 960;
/// The bottom camera's horizontal field of view (NAO V4: 60.97°).
pub const HFOV: f64 = 60.97 * std::f64::consts::PI / 180.0;
/// The focal length in full-resolution pixels (square pixels).
#[must_use]
pub fn focal() -> f64 {
    (WIDTH as f64 / 2.0) / (HFOV / 2.0).tan()
}
/// How often a frame misses the ball (motion blur): 1 in 20.
pub const MISS_RATE: f64 = 0.05;
/// The joint sensors' noise on the head angles, radians (±0.3°).
pub const JOINT_NOISE: f64 = 0.3 * std::f64::consts::PI / 180.0;
/// The pyramid's sizes (seed Ch. 6.3).
pub const LEVELS: [(usize, usize); 5] = [(640, 480), (320, 240), (160, 120), (80, 60), (40, 30)];
/// The level the segmenter reads (80 × 60).
pub const SEGMENTER_LEVEL: usize = 3;
/// The level the ball detector reads (320 × 240).
pub const DETECTOR_LEVEL: usize = 1;

/// A colour in YUV.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Yuv(pub u8, pub u8, pub u8);

/// The carpet.
pub const GREEN: Yuv = Yuv(100, 95, 85);
/// The floor beyond the carpet.
pub const FLOOR: Yuv = Yuv(140, 128, 128);
/// The walls (anything above the horizon).
pub const WALL: Yuv = Yuv(170, 128, 128);
/// The ball.
pub const ORANGE: Yuv = Yuv(150, 70, 190);

/// Whether a pixel looks like the carpet.
#[must_use]
pub fn is_green(u: u8, v: u8) -> bool {
    u < 110 && v < 110
}

/// Whether a pixel looks like the ball.
#[must_use]
pub fn is_orange(u: u8, v: u8) -> bool {
    v > 160 && u < 100
}

type V3 = [f64; 3];

fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
fn scale(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// The bottom camera in the world: where it is and its axes.
#[derive(Debug, Clone, Copy)]
pub struct Camera {
    position: V3,
    forward: V3,
    right: V3,
    down: V3,
    focal: f64,
}

impl Camera {
    /// The bottom camera of a robot in `pose`.
    #[must_use]
    pub fn of(pose: &Pose) -> Self {
        let yaw = pose.theta + pose.head_yaw;
        let pitch = pose.head_pitch + NAO_BOTTOM_CAMERA_PITCH;
        let forward = [
            pitch.cos() * yaw.cos(),
            pitch.cos() * yaw.sin(),
            -pitch.sin(),
        ];
        let right = [yaw.sin(), -yaw.cos(), 0.0];
        let up = cross(right, forward);
        Self {
            position: [pose.x, pose.y, NAO_CAMERA_HEIGHT],
            forward,
            right,
            down: scale(up, -1.0),
            focal: focal(),
        }
    }

    /// The ray through full-resolution pixel `(u, v)` (pixel centres at `.5`).
    #[must_use]
    pub fn ray(&self, u: f64, v: f64) -> V3 {
        let x = (u - WIDTH as f64 / 2.0) / self.focal;
        let y = (v - HEIGHT as f64 / 2.0) / self.focal;
        add(self.forward, add(scale(self.right, x), scale(self.down, y)))
    }

    /// Where the ray through `(u, v)` meets the horizontal plane at `height`, if it does.
    #[must_use]
    pub fn on_plane(&self, u: f64, v: f64, height: f64) -> Option<(f64, f64)> {
        let ray = self.ray(u, v);
        if ray[2] > -1e-6 {
            return None;
        }
        let s = (height - self.position[2]) / ray[2];
        Some((self.position[0] + s * ray[0], self.position[1] + s * ray[1]))
    }

    /// A point's pixel and its depth, if in front of the camera.
    #[must_use]
    pub fn project(&self, p: V3) -> Option<(f64, f64, f64)> {
        let d = add(p, scale(self.position, -1.0));
        let z = dot(d, self.forward);
        if z < 0.05 {
            return None;
        }
        Some((
            WIDTH as f64 / 2.0 + self.focal * dot(d, self.right) / z,
            HEIGHT as f64 / 2.0 + self.focal * dot(d, self.down) / z,
            z,
        ))
    }
}

/// The index of a robot in [`ROBOTS`].
fn robot_index(robot: &Robot) -> u64 {
    ROBOTS
        .iter()
        .position(|r| r.name == robot.name)
        .unwrap_or(0) as u64
}

/// The pose the robot's joint sensors report at `t_ms`: the true pose with the sensors'
/// noise (deterministic per robot and time).
#[must_use]
pub fn sensed_pose(world: &World, robot: &Robot, t_ms: i64) -> Pose {
    let mut pose = robot.pose_at(world, t_ms);
    let i = robot_index(robot);
    pose.head_yaw += JOINT_NOISE * (2.0 * unit(&[world.seed, i, t_ms as u64, 1]) - 1.0);
    pose.head_pitch += JOINT_NOISE * (2.0 * unit(&[world.seed, i, t_ms as u64, 2]) - 1.0);
    pose
}

/// The bottom camera's frame at `t_ms` (YUV422: `Y0 U Y1 V` per pair of pixels), rendered
/// from the robot's true pose: the carpet, the floor and walls beyond it, the ball (unless
/// the frame misses it) and sensor noise.
#[must_use]
pub fn render(world: &World, robot: &Robot, t_ms: i64) -> Vec<u8> {
    let camera = Camera::of(&robot.pose_at(world, t_ms));
    let mut frame = vec![0u8; WIDTH * HEIGHT * 2];
    const BLOCK: usize = 16;
    for by in (0..HEIGHT).step_by(BLOCK) {
        for bx in (0..WIDTH).step_by(BLOCK) {
            let (u, v) = ((bx + BLOCK / 2) as f64, (by + BLOCK / 2) as f64);
            let colour = match camera.on_plane(u, v, 0.0) {
                Some((x, y)) if on_carpet(x, y) => GREEN,
                Some(_) => FLOOR,
                None => WALL,
            };
            let pattern = [colour.0, colour.1, colour.0, colour.2];
            for row in by..(by + BLOCK).min(HEIGHT) {
                let start = (row * WIDTH + bx) * 2;
                for pair in frame[start..start + BLOCK * 2].chunks_exact_mut(4) {
                    pair.copy_from_slice(&pattern);
                }
            }
        }
    }
    let i = robot_index(robot);
    let missed = unit(&[world.seed, i, t_ms as u64, 3]) < MISS_RATE;
    let (bx, by) = world.ball_at(t_ms);
    if !missed && let Some((cu, cv, z)) = camera.project([bx, by, BALL_RADIUS]) {
        let r = camera.focal * BALL_RADIUS / z;
        let (x0, x1) = ((cu - r).floor().max(0.0), (cu + r).ceil().min(WIDTH as f64));
        let (y0, y1) = (
            (cv - r).floor().max(0.0),
            (cv + r).ceil().min(HEIGHT as f64),
        );
        for y in y0 as usize..y1.max(y0) as usize {
            for x in (x0 as usize & !1..x1.max(x0) as usize).step_by(2) {
                let (dx0, dx1, dy) = (
                    x as f64 + 0.5 - cu,
                    x as f64 + 1.5 - cu,
                    y as f64 + 0.5 - cv,
                );
                let (in0, in1) = (dx0.hypot(dy) <= r, dx1.hypot(dy) <= r);
                if !(in0 || in1) {
                    continue;
                }
                let at = (y * WIDTH + x) * 2;
                if in0 {
                    frame[at] = ORANGE.0;
                }
                if in1 {
                    frame[at + 2] = ORANGE.0;
                }
                frame[at + 1] = ORANGE.1;
                frame[at + 3] = ORANGE.2;
            }
        }
    }
    Noise::new(mix(&[world.seed, i, t_ms as u64])).apply(&mut frame, 8);
    frame
}

/// One level of the scale pyramid: the three channels at one resolution.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Level {
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// Luma.
    pub y: Vec<u8>,
    /// Chroma (blue difference).
    pub u: Vec<u8>,
    /// Chroma (red difference).
    pub v: Vec<u8>,
}

/// The subsampler (tid 3): a full YUV422 frame into the five levels of [`LEVELS`], each
/// channel box-filtered from the level above.
#[must_use]
pub fn subsample(frame: &[u8]) -> Vec<Level> {
    let (w, h) = LEVELS[0];
    let mut first = Level {
        width: w,
        height: h,
        y: vec![0; w * h],
        u: vec![0; w * h],
        v: vec![0; w * h],
    };
    let stride = WIDTH * 2;
    for y in 0..h {
        let (a, b) = (
            &frame[2 * y * stride..][..stride],
            &frame[(2 * y + 1) * stride..][..stride],
        );
        for x in 0..w {
            let (p, q) = (&a[4 * x..4 * x + 4], &b[4 * x..4 * x + 4]);
            let i = y * w + x;
            first.y[i] =
                ((u16::from(p[0]) + u16::from(p[2]) + u16::from(q[0]) + u16::from(q[2]) + 2) / 4)
                    as u8;
            first.u[i] = (u16::from(p[1]) + u16::from(q[1])).div_ceil(2) as u8;
            first.v[i] = (u16::from(p[3]) + u16::from(q[3])).div_ceil(2) as u8;
        }
    }
    let mut levels = vec![first];
    for &(w, h) in &LEVELS[1..] {
        let above = levels.last().map_or(&levels[0], |l| l);
        let half = |plane: &[u8]| {
            let mut out = vec![0u8; w * h];
            for y in 0..h {
                for x in 0..w {
                    let at = |dx: usize, dy: usize| {
                        u16::from(plane[(2 * y + dy) * above.width + 2 * x + dx])
                    };
                    out[y * w + x] = ((at(0, 0) + at(1, 0) + at(0, 1) + at(1, 1) + 2) / 4) as u8;
                }
            }
            out
        };
        let level = Level {
            width: w,
            height: h,
            y: half(&above.y),
            u: half(&above.u),
            v: half(&above.v),
        };
        levels.push(level);
    }
    levels
}

/// The segmenter (tid 4): the convex hull of the carpet's pixels in a low-resolution level, in
/// image coordinates normalised to `[0, 1]`, counter-clockwise; empty when fewer than three
/// pixels are green.
#[must_use]
pub fn segment(level: &Level) -> Vec<(f64, f64)> {
    let mut points = Vec::new();
    for y in 0..level.height {
        // Only each row's outermost green pixels can be on the hull.
        let row = y * level.width;
        let green = |x: usize| is_green(level.u[row + x], level.v[row + x]);
        let first = (0..level.width).find(|&x| green(x));
        let last = (0..level.width).rev().find(|&x| green(x));
        for x in first.into_iter().chain(last) {
            points.push((
                (x as f64 + 0.5) / level.width as f64,
                (y as f64 + 0.5) / level.height as f64,
            ));
        }
    }
    convex_hull(points)
}

/// Andrew's monotone chain: the convex hull, counter-clockwise (in a y-down image,
/// clockwise on screen), without collinear points.
#[must_use]
pub fn convex_hull(mut points: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
    points.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    points.dedup();
    if points.len() < 3 {
        return Vec::new();
    }
    let turn = |o: (f64, f64), a: (f64, f64), b: (f64, f64)| {
        (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0)
    };
    let mut hull: Vec<(f64, f64)> = Vec::with_capacity(2 * points.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &(f64, f64)>> = if pass == 0 {
            Box::new(points.iter())
        } else {
            Box::new(points.iter().rev())
        };
        for &p in iter {
            while hull.len() >= start + 2
                && turn(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0
            {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    if hull.len() < 3 { Vec::new() } else { hull }
}

/// Whether a point is inside a counter-clockwise convex polygon (or on its boundary).
#[must_use]
pub fn inside(hull: &[(f64, f64)], p: (f64, f64)) -> bool {
    hull.len() >= 3
        && (0..hull.len()).all(|i| {
            let (a, b) = (hull[i], hull[(i + 1) % hull.len()]);
            (b.0 - a.0) * (p.1 - a.1) - (b.1 - a.1) * (p.0 - a.0) >= 0.0
        })
}

/// A ball seen in a frame: its centre and radius in full-resolution pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelPos {
    /// Column.
    pub u: f64,
    /// Row.
    pub v: f64,
    /// Radius.
    pub radius: f64,
}

/// The ball detector (tid 5): the centroid of the ball-coloured pixels inside the field's
/// hull in the 320 × 240 level; `None` when fewer than three such pixels (no ball seen).
#[must_use]
pub fn detect(level: &Level, hull: &[(f64, f64)]) -> Option<PixelPos> {
    if hull.len() < 3 {
        return None;
    }
    let (top, bottom) = hull
        .iter()
        .fold((1.0f64, 0.0f64), |(lo, hi), p| (lo.min(p.1), hi.max(p.1)));
    let rows = ((top * level.height as f64).floor() as usize)
        ..((bottom * level.height as f64).ceil() as usize).min(level.height);
    let (mut n, mut sx, mut sy) = (0usize, 0.0, 0.0);
    for y in rows {
        let row = y * level.width;
        for x in 0..level.width {
            if is_orange(level.u[row + x], level.v[row + x])
                && inside(
                    hull,
                    (
                        (x as f64 + 0.5) / level.width as f64,
                        (y as f64 + 0.5) / level.height as f64,
                    ),
                )
            {
                n += 1;
                sx += x as f64 + 0.5;
                sy += y as f64 + 0.5;
            }
        }
    }
    if n < 3 {
        return None;
    }
    let k = WIDTH as f64 / level.width as f64;
    Some(PixelPos {
        u: sx / n as f64 * k,
        v: sy / n as f64 * k,
        radius: (n as f64 / std::f64::consts::PI).sqrt() * k,
    })
}

/// The ball localisation (tid 6): the ball's position on the field from its pixel and the
/// robot's (sensed) pose: the pixel's ray met with the plane of the ball's centre.
#[must_use]
pub fn localize(pixel: &PixelPos, pose: &Pose) -> Option<(f64, f64)> {
    Camera::of(pose).on_plane(pixel.u, pixel.v, BALL_RADIUS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hulls_are_convex_and_contain_their_points() {
        let mut rng = Noise::new(5);
        for _ in 0..200 {
            let points: Vec<(f64, f64)> = (0..30)
                .map(|_| {
                    (
                        (rng.next_u64() % 1000) as f64 / 1000.0,
                        (rng.next_u64() % 1000) as f64 / 1000.0,
                    )
                })
                .collect();
            let hull = convex_hull(points.clone());
            assert!(hull.len() >= 3);
            for p in &points {
                assert!(inside(&hull, *p), "{p:?} outside {hull:?}");
            }
        }
    }

    #[test]
    fn a_projected_point_is_found_again_on_its_plane() {
        let world = World::default();
        for robot in &ROBOTS {
            for t in (0..60_000).step_by(777) {
                let pose = robot.pose_at(&world, t);
                let camera = Camera::of(&pose);
                let (bx, by) = world.ball_at(t);
                let (u, v, _) = camera.project([bx, by, BALL_RADIUS]).unwrap();
                let (x, y) = camera.on_plane(u, v, BALL_RADIUS).unwrap();
                assert!((x - bx).hypot(y - by) < 1e-6);
            }
        }
    }
}
