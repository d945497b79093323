//! The lab's world (seed Ch. 6.2): a RoboCup SPL field with its centre circle, a ball that
//! moves on it, and where the robots and the ceiling cameras are.
//!
//! Coordinates are metres on the field's plane, with one field corner as the origin (seed
//! Ch. 6.2.1): the field lines span `[0, 9] × [0, 6]`, the green carpet reaches 0.7 m beyond
//! them, the centre is `(4.5, 3.0)` and the centre circle's radius 0.75 m. The world is a pure
//! function of time: every camera that renders the ball at time `t` sees it where
//! [`World::ball_at`] says, so cameras on different executors agree without talking to each
//! other, and a test can compare any estimate with the truth.

use std::f64::consts::PI;

use dyknow_cu::{CuError, UnitSpec};

/// The field lines' length (x), metres.
pub const FIELD_LENGTH: f64 = 9.0;
/// The field lines' width (y), metres.
pub const FIELD_WIDTH: f64 = 6.0;
/// How far the carpet reaches beyond the lines, metres.
pub const BORDER: f64 = 0.7;
/// The field's centre.
pub const CENTRE: (f64, f64) = (FIELD_LENGTH / 2.0, FIELD_WIDTH / 2.0);
/// The centre circle's radius, metres.
pub const CIRCLE_RADIUS: f64 = 0.75;
/// The ball's radius, metres.
pub const BALL_RADIUS: f64 = 0.05;
/// How fast the ball rolls out of the circle in [`Scenario::Leave`], metres per second.
pub const LEAVE_SPEED: f64 = 0.5;
/// How far from the centre the ball comes to rest in [`Scenario::Leave`], metres.
pub const LEAVE_DISTANCE: f64 = 2.0;

/// Whether a point of the plane is on the green carpet.
#[must_use]
pub fn on_carpet(x: f64, y: f64) -> bool {
    (-BORDER..=FIELD_LENGTH + BORDER).contains(&x) && (-BORDER..=FIELD_WIDTH + BORDER).contains(&y)
}

/// Whether a point is inside the centre circle (the predicate `InsideCircle`).
#[must_use]
pub fn inside_circle(x: f64, y: f64) -> bool {
    (x - CENTRE.0).hypot(y - CENTRE.1) <= CIRCLE_RADIUS
}

/// How the ball moves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Scenario {
    /// A smooth random walk that stays within 0.5 m of the centre: always inside the circle.
    Circle,
    /// A smooth random walk within 2 m of the centre: in and out of the circle.
    Walk,
    /// As [`Scenario::Circle`] until `at_ms` (ms since the Unix epoch), then the ball rolls
    /// straight away from the centre at [`LEAVE_SPEED`] and stops [`LEAVE_DISTANCE`] from it.
    Leave {
        /// When the ball starts rolling away.
        at_ms: i64,
    },
}

/// The world: where the ball is at any time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct World {
    /// How the ball moves.
    pub scenario: Scenario,
    /// The seed of its random walk.
    pub seed: u64,
}

impl Default for World {
    fn default() -> Self {
        Self {
            scenario: Scenario::Circle,
            seed: 1,
        }
    }
}

impl World {
    /// The world a CU's parameters describe: `scenario` (`circle`, the default, `walk` or
    /// `leave`), `seed` (1), `leave_at_ms` (required by `leave`). Every camera of one lab must
    /// be given the same.
    pub fn from_spec(spec: &UnitSpec) -> Result<Self, CuError> {
        let seed = match spec.params.get("seed") {
            None => 1,
            Some(v) => v
                .as_u64()
                .ok_or_else(|| param("seed", "not a non-negative integer"))?,
        };
        let scenario = match spec.params.get("scenario") {
            None => Scenario::Circle,
            Some(v) => match v.as_str() {
                Some("circle") => Scenario::Circle,
                Some("walk") => Scenario::Walk,
                Some("leave") => Scenario::Leave {
                    at_ms: spec
                        .params
                        .get("leave_at_ms")
                        .and_then(serde_json::Value::as_i64)
                        .ok_or_else(|| {
                            param("leave_at_ms", "the leave scenario needs a time in ms")
                        })?,
                },
                _ => return Err(param("scenario", "one of circle, walk, leave")),
            },
        };
        Ok(Self { scenario, seed })
    }

    /// Where the ball's centre is (on the plane; it rests on the carpet) at `t_ms`.
    #[must_use]
    pub fn ball_at(&self, t_ms: i64) -> (f64, f64) {
        match self.scenario {
            Scenario::Circle => self.walk(t_ms, 0.5),
            Scenario::Walk => self.walk(t_ms, 2.0),
            Scenario::Leave { at_ms } => {
                if t_ms <= at_ms {
                    return self.walk(t_ms, 0.5);
                }
                let (x0, y0) = self.walk(at_ms, 0.5);
                let (dx, dy) = (x0 - CENTRE.0, y0 - CENTRE.1);
                let r0 = dx.hypot(dy);
                let (ux, uy) = if r0 < 1e-9 {
                    (1.0, 0.0)
                } else {
                    (dx / r0, dy / r0)
                };
                let r = (r0 + LEAVE_SPEED * (t_ms - at_ms) as f64 / 1000.0).min(LEAVE_DISTANCE);
                (CENTRE.0 + r * ux, CENTRE.1 + r * uy)
            }
        }
    }

    /// When the ball first leaves the centre circle, for [`Scenario::Leave`].
    #[must_use]
    pub fn exits_at(&self) -> Option<i64> {
        let Scenario::Leave { at_ms } = self.scenario else {
            return None;
        };
        let (x0, y0) = self.walk(at_ms, 0.5);
        let r0 = (x0 - CENTRE.0).hypot(y0 - CENTRE.1);
        Some(at_ms + ((CIRCLE_RADIUS - r0) / LEAVE_SPEED * 1000.0).ceil() as i64)
    }

    /// A smooth random walk within `radius` of the centre: two octaves of value noise per
    /// axis, folded into the disc.
    fn walk(&self, t_ms: i64, radius: f64) -> (f64, f64) {
        let s = t_ms as f64 / 4000.0;
        let nx = 0.7 * value_noise(self.seed, 0, s) + 0.3 * value_noise(self.seed, 1, s * 2.3);
        let ny = 0.7 * value_noise(self.seed, 2, s) + 0.3 * value_noise(self.seed, 3, s * 2.3);
        let n = nx.hypot(ny);
        let scale = if n > 1.0 { radius / n } else { radius };
        (CENTRE.0 + nx * scale, CENTRE.1 + ny * scale)
    }
}

fn param(name: &str, why: &str) -> CuError {
    CuError::Parameter {
        name: name.to_owned(),
        why: why.to_owned(),
    }
}

/// splitmix64: a hash of a few integers to 64 well-mixed bits.
#[must_use]
pub fn mix(parts: &[u64]) -> u64 {
    let mut z = 0x9E37_79B9_7F4A_7C15_u64;
    for &p in parts {
        z = z.wrapping_add(p).wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
    }
    z
}

/// A hash as a number in `[0, 1)`.
#[must_use]
pub fn unit(parts: &[u64]) -> f64 {
    (mix(parts) >> 11) as f64 / (1u64 << 53) as f64
}

/// Smooth 1-D value noise in `[-1, 1]`: hashed values at integer knots, smoothstep between.
fn value_noise(seed: u64, axis: u64, x: f64) -> f64 {
    let i = x.floor();
    let f = x - i;
    let knot = |k: f64| 2.0 * unit(&[seed, axis, k as i64 as u64]) - 1.0;
    let w = f * f * (3.0 - 2.0 * f);
    knot(i) * (1.0 - w) + knot(i + 1.0) * w
}

/// A NAO robot standing on the field (seed Ch. 6.2.2), turning its head to track the ball.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Robot {
    /// Its name, the `robot` parameter of its transformations.
    pub name: &'static str,
    /// Where it stands.
    pub x: f64,
    /// Where it stands.
    pub y: f64,
    /// Which way its body faces (radians, from the x axis): towards the centre.
    pub theta: f64,
}

/// The lab's robots.
pub const ROBOTS: [Robot; 2] = [
    Robot {
        name: "piff",
        x: 3.0,
        y: 1.5,
        theta: PI / 4.0,
    },
    Robot {
        name: "puff",
        x: 6.0,
        y: 4.5,
        theta: -3.0 * PI / 4.0,
    },
];

/// The robot a CU's `robot` parameter names.
pub fn robot_from_spec(spec: &UnitSpec) -> Result<Robot, CuError> {
    let name = spec
        .params
        .get("robot")
        .and_then(serde_json::Value::as_str)
        .ok_or_else(|| param("robot", "the robot's name (piff or puff) is required"))?;
    ROBOTS
        .iter()
        .find(|r| r.name == name)
        .copied()
        .ok_or_else(|| {
            param(
                "robot",
                &format!("no robot {name:?} in the lab (piff, puff)"),
            )
        })
}

/// The height of the NAO's bottom camera above the carpet while standing, metres.
pub const NAO_CAMERA_HEIGHT: f64 = 0.46;
/// The bottom camera's pitch below the head's axis (NAO V4: 39.7°).
pub const NAO_BOTTOM_CAMERA_PITCH: f64 = 39.7 * PI / 180.0;
/// How long the head's tracking lags behind the ball, ms.
pub const TRACKING_LAG_MS: i64 = 300;
/// The head yaw joint's range (NAO: ±119.5°).
pub const HEAD_YAW_LIMIT: f64 = 119.5 * PI / 180.0;
/// The head pitch joint's range (NAO: −38.5° up to 29.5° down).
pub const HEAD_PITCH_RANGE: (f64, f64) = (-38.5 * PI / 180.0, 29.5 * PI / 180.0);

/// A robot's pose as its joint sensors report it: where it stands and its head's angles.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Position.
    pub x: f64,
    /// Position.
    pub y: f64,
    /// Body heading, radians.
    pub theta: f64,
    /// Head yaw relative to the body, radians (left positive).
    pub head_yaw: f64,
    /// Head pitch, radians (down positive).
    pub head_pitch: f64,
}

impl Robot {
    /// The robot's true pose at `t_ms`: its head points the bottom camera at where the ball
    /// was [`TRACKING_LAG_MS`] earlier, within the joints' ranges.
    #[must_use]
    pub fn pose_at(&self, world: &World, t_ms: i64) -> Pose {
        let (bx, by) = world.ball_at(t_ms - TRACKING_LAG_MS);
        let yaw = (by - self.y).atan2(bx - self.x);
        let head_yaw = wrap(yaw - self.theta).clamp(-HEAD_YAW_LIMIT, HEAD_YAW_LIMIT);
        let distance = (bx - self.x).hypot(by - self.y);
        let down = (NAO_CAMERA_HEIGHT - BALL_RADIUS).atan2(distance);
        let head_pitch =
            (down - NAO_BOTTOM_CAMERA_PITCH).clamp(HEAD_PITCH_RANGE.0, HEAD_PITCH_RANGE.1);
        Pose {
            x: self.x,
            y: self.y,
            theta: self.theta,
            head_yaw,
            head_pitch,
        }
    }
}

/// An angle in `(-π, π]`.
#[must_use]
pub fn wrap(a: f64) -> f64 {
    let mut a = a % (2.0 * PI);
    if a > PI {
        a -= 2.0 * PI;
    } else if a <= -PI {
        a += 2.0 * PI;
    }
    a
}

/// A ceiling camera (seed Ch. 6.2.1: AXIS M3005-V), looking straight down over one quarter of
/// the field.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CeilingCamera {
    /// Its name, the `camera` parameter (`cam_1` … `cam_4`).
    pub name: &'static str,
    /// Where it hangs.
    pub x: f64,
    /// Where it hangs.
    pub y: f64,
}

/// The ceiling cameras' height above the carpet, metres.
pub const CEILING_HEIGHT: f64 = 3.2;

/// The four ceiling cameras, one over the centre of each quarter of the field.
pub const CEILING_CAMERAS: [CeilingCamera; 4] = [
    CeilingCamera {
        name: "cam_1",
        x: 2.25,
        y: 1.5,
    },
    CeilingCamera {
        name: "cam_2",
        x: 6.75,
        y: 1.5,
    },
    CeilingCamera {
        name: "cam_3",
        x: 2.25,
        y: 4.5,
    },
    CeilingCamera {
        name: "cam_4",
        x: 6.75,
        y: 4.5,
    },
];

/// The camera a CU's `camera` parameter names.
pub fn camera_from_spec(spec: &UnitSpec) -> Result<(usize, CeilingCamera), CuError> {
    let name = spec
        .params
        .get("camera")
        .and_then(serde_json::Value::as_str)
        .ok_or_else(|| param("camera", "the camera's name (cam_1 … cam_4) is required"))?;
    CEILING_CAMERAS
        .iter()
        .copied()
        .enumerate()
        .find(|(_, c)| c.name == name)
        .ok_or_else(|| param("camera", &format!("no camera {name:?} (cam_1 … cam_4)")))
}

/// The index of the ceiling camera whose quarter holds a point.
#[must_use]
pub fn quarter_of(x: f64, y: f64) -> usize {
    usize::from(x >= CENTRE.0) + 2 * usize::from(y >= CENTRE.1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_circle_scenario_stays_inside_and_the_walk_leaves() {
        let circle = World::default();
        let walk = World {
            scenario: Scenario::Walk,
            seed: 7,
        };
        let mut outside = 0;
        for t in (0..600_000).step_by(250) {
            let (x, y) = circle.ball_at(t);
            assert!((x - CENTRE.0).hypot(y - CENTRE.1) <= 0.5 + 1e-9);
            let (x, y) = walk.ball_at(t);
            assert!((x - CENTRE.0).hypot(y - CENTRE.1) <= 2.0 + 1e-9);
            outside += usize::from(!inside_circle(x, y));
        }
        assert!(outside > 100, "the walk leaves the circle ({outside})");
    }

    #[test]
    fn the_ball_moves_smoothly() {
        let w = World {
            scenario: Scenario::Walk,
            seed: 3,
        };
        for t in (0..120_000).step_by(100) {
            let (a, b) = (w.ball_at(t), w.ball_at(t + 100));
            // At most ~2 m/s.
            assert!((a.0 - b.0).hypot(a.1 - b.1) < 0.2, "{t}: {a:?} → {b:?}");
        }
    }

    #[test]
    fn the_leave_scenario_exits_when_it_says() {
        let w = World {
            scenario: Scenario::Leave { at_ms: 50_000 },
            seed: 2,
        };
        let exit = w.exits_at().unwrap();
        assert!(exit > 50_000 && exit <= 50_000 + 1500);
        let (x, y) = w.ball_at(exit - 5);
        assert!(inside_circle(x, y));
        let (x, y) = w.ball_at(exit + 5);
        assert!(!inside_circle(x, y));
        let (x, y) = w.ball_at(exit + 60_000);
        assert!(((x - CENTRE.0).hypot(y - CENTRE.1) - LEAVE_DISTANCE).abs() < 1e-9);
    }

    #[test]
    fn quarters_name_the_nearest_camera() {
        for (i, c) in CEILING_CAMERAS.iter().enumerate() {
            assert_eq!(quarter_of(c.x, c.y), i);
        }
    }
}
