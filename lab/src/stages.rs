//! The lab's stages as transformations (the CU SDK, no special paths): what each publishes,
//! from what.
//!
//! Stages with two inputs tell them apart by content, not by port name, and pair them by the
//! time `t` of the frame they come from (a frame keeps its camera's `t` down the pipeline), as
//! ROS' exact-time synchroniser does: a detector whose segmenter is gone publishes nothing.

use std::collections::BTreeMap;
use std::time::Duration;

use dyknow_cu::{CuError, NodeHandle, Sample, TimerId, Transformation, UnitSpec, now_ms};
use serde_json::{Value, json};

use crate::ceiling::{self, Stitcher, Undistorter};
use crate::image::{bad, decode, dimension, encode, number, object};
use crate::nao::{self, Level, PixelPos};
use crate::world::{Pose, World, camera_from_spec, inside_circle, robot_from_spec};

fn param_u64(spec: &UnitSpec, name: &str, default: u64, range: (u64, u64)) -> Result<u64, CuError> {
    let v = match spec.params.get(name) {
        None => default,
        Some(v) => v.as_u64().ok_or_else(|| CuError::Parameter {
            name: name.to_owned(),
            why: format!("{v} is not a non-negative integer"),
        })?,
    };
    if !(range.0..=range.1).contains(&v) {
        return Err(CuError::Parameter {
            name: name.to_owned(),
            why: format!("{v} is not in {}..={}", range.0, range.1),
        });
    }
    Ok(v)
}

/// A clock ticking at multiples of a period: every camera of the lab that runs at the same
/// rate stamps its frames with the same times.
pub(crate) struct Ticks {
    period_ms: i64,
    last: i64,
}

impl Ticks {
    pub(crate) fn from_spec(spec: &UnitSpec, default_fps: u64) -> Result<Self, CuError> {
        let fps = param_u64(spec, "fps", default_fps, (1, 100))?;
        Ok(Self {
            period_ms: (1000 / fps) as i64,
            last: i64::MIN,
        })
    }

    fn period(&self) -> Duration {
        Duration::from_millis(self.period_ms as u64)
    }

    /// The tick nearest to now, unless it was already taken.
    fn next(&mut self) -> Option<i64> {
        let now = now_ms();
        let t = (now + self.period_ms / 2) / self.period_ms * self.period_ms;
        (t > self.last).then(|| {
            self.last = t;
            t
        })
    }
}

/// A source: at every tick of its clock, one sample computed from the tick's time on every out
/// port.
pub struct Source<F> {
    ticks: Ticks,
    make: F,
}

impl<F: FnMut(i64) -> Value + Send + 'static> Transformation for Source<F> {
    fn start(&mut self, cu: &mut NodeHandle<'_>) -> Result<(), CuError> {
        cu.every(self.ticks.period());
        Ok(())
    }

    fn on_sample(&mut self, _: &mut NodeHandle<'_>, _: &str, _: Sample) -> Result<(), CuError> {
        Ok(())
    }

    fn on_timer(&mut self, cu: &mut NodeHandle<'_>, _: TimerId) -> Result<(), CuError> {
        if let Some(t) = self.ticks.next() {
            let value = (self.make)(t);
            cu.publish_all(&Sample::new(t, value))?;
        }
        Ok(())
    }
}

pub(crate) fn source(
    ticks: Ticks,
    make: impl FnMut(i64) -> Value + Send + 'static,
) -> Result<Box<dyn Transformation>, CuError> {
    Ok(Box::new(Source { ticks, make }))
}

/// `lab/world`: the true ball position `{"x", "y"}` at `fps` (10): what the cameras see, for
/// tests and demos (no pipeline needs it). Parameters: the world's.
pub fn world(spec: &UnitSpec) -> Result<Box<dyn Transformation>, CuError> {
    let world = World::from_spec(spec)?;
    source(Ticks::from_spec(spec, 10)?, move |t| {
        let (x, y) = world.ball_at(t);
        json!({"x": x, "y": y})
    })
}

/// `nao/pose`: the robot's joint sensors, `{"x", "y", "theta", "head_yaw", "head_pitch"}`
/// (metres, radians) at `fps` (50). Parameters: `robot` and the world's.
pub fn pose(spec: &UnitSpec) -> Result<Box<dyn Transformation>, CuError> {
    let (world, robot) = (World::from_spec(spec)?, robot_from_spec(spec)?);
    source(Ticks::from_spec(spec, 50)?, move |t| {
        pose_json(&nao::sensed_pose(&world, &robot, t))
    })
}

fn pose_json(p: &Pose) -> Value {
    json!({"x": p.x, "y": p.y, "theta": p.theta, "head_yaw": p.head_yaw, "head_pitch": p.head_pitch})
}

fn pose_of(v: &Value) -> Result<Pose, CuError> {
    Ok(Pose {
        x: number(v, "x")?,
        y: number(v, "y")?,
        theta: number(v, "theta")?,
        head_yaw: number(v, "head_yaw")?,
        head_pitch: number(v, "head_pitch")?,
    })
}

/// `nao/bottom_cam`: 1280 × 960 YUV422 frames `{"width", "height", "format": "yuv422",
/// "data"}` at `fps` (10; the NAO's camera does up to 30). Parameters: `robot` and the
/// world's.
pub fn bottom_cam(spec: &UnitSpec) -> Result<Box<dyn Transformation>, CuError> {
    let (world, robot) = (World::from_spec(spec)?, robot_from_spec(spec)?);
    source(Ticks::from_spec(spec, 10)?, move |t| {
        object([
            ("width", json!(nao::WIDTH)),
            ("height", json!(nao::HEIGHT)),
            ("format", json!("yuv422")),
            ("data", encode(&nao::render(&world, &robot, t))),
        ])
    })
}

/// `nao/subsampler`: a frame into the pyramid `{"levels": [{"width", "height", "y", "u",
/// "v"}, …]}`.
pub struct Subsampler;

impl Transformation for Subsampler {
    fn on_sample(&mut self, cu: &mut NodeHandle<'_>, _: &str, s: Sample) -> Result<(), CuError> {
        if dimension(&s.value, "width")? != nao::WIDTH
            || dimension(&s.value, "height")? != nao::HEIGHT
            || s.value.get("format") != Some(&json!("yuv422"))
        {
            return Err(bad("not a 1280 × 960 yuv422 frame"));
        }
        let frame = decode(&s.value, "data", nao::WIDTH * nao::HEIGHT * 2)?;
        let levels: Vec<Value> = nao::subsample(&frame)
            .iter()
            .map(|l| {
                object([
                    ("width", json!(l.width)),
                    ("height", json!(l.height)),
                    ("y", encode(&l.y)),
                    ("u", encode(&l.u)),
                    ("v", encode(&l.v)),
                ])
            })
            .collect();
        cu.publish_all(&Sample::new(s.t, json!({ "levels": levels })))
    }
}

/// One level of a pyramid sample.
fn level(pyramid: &Value, index: usize) -> Result<Level, CuError> {
    let l = pyramid
        .get("levels")
        .and_then(|l| l.get(index))
        .ok_or_else(|| bad(&format!("no pyramid level {index}")))?;
    let (width, height) = (dimension(l, "width")?, dimension(l, "height")?);
    if (width, height) != nao::LEVELS[index] {
        return Err(bad(&format!("level {index} is {width} × {height}")));
    }
    Ok(Level {
        width,
        height,
        y: decode(l, "y", width * height)?,
        u: decode(l, "u", width * height)?,
        v: decode(l, "v", width * height)?,
    })
}

/// `nao/segmenter`: the pyramid's 80 × 60 level into the field's convex hull `{"hull":
/// [[x, y], …]}` (normalised image coordinates).
pub struct Segmenter;

impl Transformation for Segmenter {
    fn on_sample(&mut self, cu: &mut NodeHandle<'_>, _: &str, s: Sample) -> Result<(), CuError> {
        let hull = nao::segment(&level(&s.value, nao::SEGMENTER_LEVEL)?);
        let hull: Vec<Value> = hull.iter().map(|(x, y)| json!([x, y])).collect();
        cu.publish_all(&Sample::new(s.t, json!({ "hull": hull })))
    }
}

/// Keeps the latest few samples of each kind by `t` and hands out pairs with equal `t`.
struct Pairs {
    left: BTreeMap<i64, Value>,
    right: BTreeMap<i64, Value>,
}

impl Pairs {
    const KEEP: usize = 8;

    fn new() -> Self {
        Self {
            left: BTreeMap::new(),
            right: BTreeMap::new(),
        }
    }

    /// Adds a sample; returns the pair for its `t` when both are there (and forgets
    /// everything up to it).
    fn add(&mut self, is_left: bool, t: i64, value: Value) -> Option<(Value, Value)> {
        let (mine, other) = if is_left {
            (&mut self.left, &mut self.right)
        } else {
            (&mut self.right, &mut self.left)
        };
        if let Some(o) = other.remove(&t) {
            other.retain(|&k, _| k > t);
            mine.retain(|&k, _| k > t);
            return Some(if is_left { (value, o) } else { (o, value) });
        }
        mine.insert(t, value);
        while mine.len() > Self::KEEP {
            mine.pop_first();
        }
        None
    }
}

/// `nao/ball_detector`: a hull and the pyramid of the same frame into the ball's pixel
/// `{"u", "v", "radius"}` (full-resolution pixels); nothing when the frame shows no ball.
pub struct BallDetector {
    pairs: Pairs,
}

impl BallDetector {
    /// A detector.
    #[must_use]
    pub fn new() -> Self {
        Self {
            pairs: Pairs::new(),
        }
    }
}

impl Default for BallDetector {
    fn default() -> Self {
        Self::new()
    }
}

impl Transformation for BallDetector {
    fn on_sample(&mut self, cu: &mut NodeHandle<'_>, _: &str, s: Sample) -> Result<(), CuError> {
        let is_hull = s.value.get("hull").is_some();
        if !is_hull && s.value.get("levels").is_none() {
            return Err(bad("neither a hull nor a pyramid"));
        }
        let Some((hull, pyramid)) = self.pairs.add(is_hull, s.t, s.value) else {
            return Ok(());
        };
        let hull: Vec<(f64, f64)> = hull["hull"]
            .as_array()
            .ok_or_else(|| bad("hull is not an array"))?
            .iter()
            .map(|p| Some((p.get(0)?.as_f64()?, p.get(1)?.as_f64()?)))
            .collect::<Option<_>>()
            .ok_or_else(|| bad("hull points are not [x, y]"))?;
        if let Some(p) = nao::detect(&level(&pyramid, nao::DETECTOR_LEVEL)?, &hull) {
            cu.publish_all(&Sample::new(
                s.t,
                json!({"u": p.u, "v": p.v, "radius": p.radius}),
            ))?;
        }
        Ok(())
    }
}

/// `nao/ball_localization`: the ball's pixel and the robot's pose at the frame's time into
/// the ball's position on the field `{"x", "y"}` (metres).
pub struct BallLocalization {
    poses: BTreeMap<i64, Pose>,
}

impl BallLocalization {
    /// A localiser.
    #[must_use]
    pub fn new() -> Self {
        Self {
            poses: BTreeMap::new(),
        }
    }
}

impl Default for BallLocalization {
    fn default() -> Self {
        Self::new()
    }
}

impl Transformation for BallLocalization {
    fn on_sample(&mut self, cu: &mut NodeHandle<'_>, _: &str, s: Sample) -> Result<(), CuError> {
        if s.value.get("head_yaw").is_some() {
            self.poses.insert(s.t, pose_of(&s.value)?);
            while self.poses.len() > 200 {
                self.poses.pop_first();
            }
            return Ok(());
        }
        let pixel = PixelPos {
            u: number(&s.value, "u")?,
            v: number(&s.value, "v")?,
            radius: number(&s.value, "radius")?,
        };
        // The pose sensed nearest to the frame's time, within 25 ms.
        let nearest = self
            .poses
            .range(s.t - 25..=s.t + 25)
            .min_by_key(|(t, _)| (**t - s.t).abs())
            .map(|(_, p)| *p);
        if let Some((x, y)) = nearest.and_then(|pose| nao::localize(&pixel, &pose)) {
            cu.publish_all(&Sample::new(s.t, json!({"x": x, "y": y})))?;
        }
        Ok(())
    }
}

/// `nao/circle_monitor`: a position into `InsideCircle`: `true` while within the centre
/// circle.
pub struct CircleMonitor;

impl Transformation for CircleMonitor {
    fn on_sample(&mut self, cu: &mut NodeHandle<'_>, _: &str, s: Sample) -> Result<(), CuError> {
        let (x, y) = (number(&s.value, "x")?, number(&s.value, "y")?);
        cu.publish_all(&Sample::new(s.t, Value::Bool(inside_circle(x, y))))
    }
}

/// `lab/ceiling_cam`: one ceiling camera's stream, `{"camera", "width", "height", "format":
/// "rgb8", "data"}`, distorted by its lens, at `fps` (10); `width` × `height` (256 × 144) is
/// the resolution the lab asks of the camera. Parameters: `camera` and the world's.
pub fn ceiling_cam(spec: &UnitSpec) -> Result<Box<dyn Transformation>, CuError> {
    let world = World::from_spec(spec)?;
    let (camera, cam) = camera_from_spec(spec)?;
    let size = (
        param_u64(spec, "width", ceiling::WIDTH as u64, (16, 1920))? as usize,
        param_u64(spec, "height", ceiling::HEIGHT as u64, (16, 1080))? as usize,
    );
    source(Ticks::from_spec(spec, 10)?, move |t| {
        let frame = ceiling::render(&world, camera, size.0, size.1, t);
        rgb_frame(cam.name, size, &frame)
    })
}

fn rgb_frame(camera: &str, (w, h): (usize, usize), data: &[u8]) -> Value {
    object([
        ("camera", json!(camera)),
        ("width", json!(w)),
        ("height", json!(h)),
        ("format", json!("rgb8")),
        ("data", encode(data)),
    ])
}

fn camera_of(value: &Value) -> Result<usize, CuError> {
    let name = value
        .get("camera")
        .and_then(Value::as_str)
        .ok_or_else(|| bad("no camera name"))?;
    crate::world::CEILING_CAMERAS
        .iter()
        .position(|c| c.name == name)
        .ok_or_else(|| bad(&format!("unknown camera {name:?}")))
}

/// `lab/undistort`: a camera's frame, undistorted (same size and fields).
pub struct Undistort {
    table: Option<Undistorter>,
}

impl Undistort {
    /// Builds the remap table for `width` × `height` (256 × 144) when it starts; a frame of
    /// another size rebuilds it.
    pub fn new(spec: &UnitSpec) -> Result<Self, CuError> {
        let w = param_u64(spec, "width", ceiling::WIDTH as u64, (16, 1920))? as usize;
        let h = param_u64(spec, "height", ceiling::HEIGHT as u64, (16, 1080))? as usize;
        Ok(Self {
            table: Some(Undistorter::new(w, h)),
        })
    }
}

fn rgb_of(value: &Value) -> Result<((usize, usize), Vec<u8>), CuError> {
    let size = (dimension(value, "width")?, dimension(value, "height")?);
    if value.get("format") != Some(&json!("rgb8")) {
        return Err(bad("not an rgb8 frame"));
    }
    Ok((size, decode(value, "data", size.0 * size.1 * 3)?))
}

impl Transformation for Undistort {
    fn on_sample(&mut self, cu: &mut NodeHandle<'_>, _: &str, s: Sample) -> Result<(), CuError> {
        let camera = camera_of(&s.value)?;
        let (size, raw) = rgb_of(&s.value)?;
        let table = match self.table.take() {
            Some(t) if t.size() == size => t,
            _ => Undistorter::new(size.0, size.1),
        };
        let out = table.apply(&raw);
        self.table = Some(table);
        let name = crate::world::CEILING_CAMERAS[camera].name;
        cu.publish_all(&Sample::new(s.t, rgb_frame(name, size, &out)))
    }
}

/// `lab/stitch`: the four undistorted frames of one time into the top-down image of the
/// carpet `{"width", "height", "origin": [x, y], "resolution", "format": "rgb8", "data"}`.
pub struct Stitch {
    table: Option<Stitcher>,
    frames: BTreeMap<i64, [Option<Vec<u8>>; 4]>,
}

impl Stitch {
    /// A stitcher; its table is built for the first frames' size.
    #[must_use]
    pub fn new() -> Self {
        Self {
            table: Some(Stitcher::new(ceiling::WIDTH, ceiling::HEIGHT)),
            frames: BTreeMap::new(),
        }
    }
}

impl Default for Stitch {
    fn default() -> Self {
        Self::new()
    }
}

impl Transformation for Stitch {
    fn on_sample(&mut self, cu: &mut NodeHandle<'_>, _: &str, s: Sample) -> Result<(), CuError> {
        let camera = camera_of(&s.value)?;
        let (size, frame) = rgb_of(&s.value)?;
        let table = match self.table.take() {
            Some(t) if t.frame_size() == size => t,
            _ => Stitcher::new(size.0, size.1),
        };
        let slot = self.frames.entry(s.t).or_default();
        slot[camera] = Some(frame);
        if slot.iter().all(Option::is_some) {
            let slot = self.frames.remove(&s.t).unwrap_or_default();
            self.frames.retain(|&t, _| t > s.t);
            let frames: Vec<&[u8]> = slot.iter().flatten().map(Vec::as_slice).collect();
            let top_down = table.apply([frames[0], frames[1], frames[2], frames[3]]);
            let (w, h) = ceiling::stitched_size();
            cu.publish_all(&Sample::new(
                s.t,
                object([
                    ("width", json!(w)),
                    ("height", json!(h)),
                    (
                        "origin",
                        json!([-crate::world::BORDER, -crate::world::BORDER]),
                    ),
                    ("resolution", json!(ceiling::RESOLUTION)),
                    ("format", json!("rgb8")),
                    ("data", encode(&top_down)),
                ]),
            ))?;
        }
        while self.frames.len() > 8 {
            self.frames.pop_first();
        }
        self.table = Some(table);
        Ok(())
    }
}

/// `lab/ball_detector`: the top-down image into the ball's position `{"x", "y"}`.
pub struct FieldBallDetector;

impl Transformation for FieldBallDetector {
    fn on_sample(&mut self, cu: &mut NodeHandle<'_>, _: &str, s: Sample) -> Result<(), CuError> {
        let (w, h) = ceiling::stitched_size();
        if (
            dimension(&s.value, "width")?,
            dimension(&s.value, "height")?,
        ) != (w, h)
        {
            return Err(bad("not the stitched image of the carpet"));
        }
        let image = decode(&s.value, "data", w * h * 3)?;
        if let Some((x, y)) = ceiling::detect(&image) {
            cu.publish_all(&Sample::new(s.t, json!({"x": x, "y": y})))?;
        }
        Ok(())
    }
}
