//! A simulated humanoid lab (the DyKnow thesis, Ch. 6): a ball on a RoboCup field, two NAO
//! robots (Piff and Puff) each with the seven stages of Table 6.1, and the lab's four ceiling
//! cameras with their pipeline (Table 6.2), as builtin transformations written with the CU SDK.
//!
//! The data are synthetic, the computation is not: cameras render frames of the ball as seen
//! from where they are ([`world`]), and every later stage computes its output from its input
//! only — pyramids from frames, hulls and pixels from pyramids, positions from pixels and
//! poses ([`nao`]), undistorted, stitched images and positions from camera streams
//! ([`ceiling`]). What each stage costs is what it really does, at the resolutions the thesis
//! gives ([`ceiling`] says why the two pipelines differ).
//!
//! | builtin | in → out | parameters |
//! | --- | --- | --- |
//! | `lab/world` | – → the true ball position `{"x", "y"}` | world, `fps` (10) |
//! | `nao/pose` | – → the robot's pose | `robot`, world, `fps` (50) |
//! | `nao/bottom_cam` | – → 1280 × 960 YUV422 frames | `robot`, world, `fps` (10) |
//! | `nao/subsampler` | frame → pyramid (640 × 480 … 40 × 30) | – |
//! | `nao/segmenter` | pyramid → the field's convex hull | – |
//! | `nao/ball_detector` | hull, pyramid → the ball's pixel | – |
//! | `nao/ball_localization` | pixel, pose → the ball's position | – |
//! | `nao/circle_monitor` | position → `InsideCircle` (boolean) | – |
//! | `lab/ceiling_cam` | – → one camera's stream (256 × 144 RGB, distorted) | `camera`, world, `fps` (10), `width`, `height` |
//! | `lab/undistort` | camera stream → undistorted | `width`, `height` |
//! | `lab/stitch` | four undistorted streams → the top-down image of the carpet | – |
//! | `lab/ball_detector` | top-down image → the ball's position | – |
//! | `sim/uav_altitude`, `sim/battery`, `sim/regions` | – → an altitude, a battery level or charging flag, RCC-8 constraints (formula groups' examples, `sim.rs`) | see `sim.rs` |
//!
//! The world's parameters (`scenario`: `circle`, `walk` or `leave`; `seed`; `leave_at_ms`)
//! must be the same for every camera of a lab. Positions are metres from a field corner.

pub mod ceiling;
pub mod image;
pub mod nao;
pub mod sim;
pub mod stages;
pub mod world;

use dyknow_cu::{CuError, Transformation, UnitSpec};

pub use world::{Scenario, World};

/// Builds a lab stage for a CU.
pub type Factory = fn(&UnitSpec) -> Result<Box<dyn Transformation>, CuError>;

/// How far a pipeline's position may be from the truth at the frame's time, metres: the
/// cameras' pixel noise, the pyramid's resolution and the joint sensors' noise together stay
/// well within it (`tests/pipelines.rs` measures the errors).
pub const POSITION_TOLERANCE: f64 = 0.25;

fn boxed<T: Transformation>(t: T) -> Result<Box<dyn Transformation>, CuError> {
    Ok(Box::new(t))
}

/// The lab's builtins, by name.
pub const BUILTINS: [(&str, Factory); 15] = [
    ("lab/world", stages::world),
    ("nao/pose", stages::pose),
    ("nao/bottom_cam", stages::bottom_cam),
    ("nao/subsampler", |_| boxed(stages::Subsampler)),
    ("nao/segmenter", |_| boxed(stages::Segmenter)),
    ("nao/ball_detector", |_| boxed(stages::BallDetector::new())),
    ("nao/ball_localization", |_| {
        boxed(stages::BallLocalization::new())
    }),
    ("nao/circle_monitor", |_| boxed(stages::CircleMonitor)),
    ("lab/ceiling_cam", stages::ceiling_cam),
    ("lab/undistort", |s| boxed(stages::Undistort::new(s)?)),
    ("lab/stitch", |_| boxed(stages::Stitch::new())),
    ("lab/ball_detector", |_| boxed(stages::FieldBallDetector)),
    ("sim/uav_altitude", sim::uav_altitude),
    ("sim/battery", sim::battery),
    ("sim/regions", sim::regions),
];
