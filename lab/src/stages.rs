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

    /// The ticks due now, oldest first: every tick after the last one taken up to the tick
    /// nearest to now, none more than [`LATE_MS`] before it. A timer can fire late: when the
    /// host's CUs shared one timer thread, a camera's callback (rendering, then the in-process
    /// stages its frame feeds) held it for tens of milliseconds, and taking only the tick
    /// nearest to now lost up to one pose in four. The host's timers now have workers
    /// (`dyknow_cu::Timers`), and a timer can still be late on a busy machine. A late tick is
    /// published late instead of never; after a longer stall the older ticks are skipped
    /// rather than replayed, so a stream's gap is a real outage.
    fn due(&mut self) -> impl Iterator<Item = i64> + use<> {
        self.due_at(now_ms())
    }

    fn due_at(&mut self, now: i64) -> impl Iterator<Item = i64> + use<> {
        let period = self.period_ms;
        let t = (now + period / 2) / period * period;
        let oldest = t - LATE_MS / period * period;
        let first = if self.last == i64::MIN {
            t
        } else {
            (self.last + period).max(oldest)
        };
        if t > self.last {
            self.last = t;
        }
        (first..=t).step_by(period as usize)
    }
}

/// How late a tick may be published (see [`Ticks::due`]).
const LATE_MS: i64 = 250;

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
        for t in self.ticks.due() {
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
/// the ball's position on the field `{"x", "y"}` (metres), with the pose sensed nearest to
/// the frame's time within [`POSE_WINDOW_MS`].
///
/// A pixel waits for its poses: the two inputs arrive on different threads (the pose from
/// a timer of the host, the pixel after the segmenter's round trip), so a pixel may come
/// before the poses around its frame's time. It is localised once a pose at exactly its time
/// is there or one later than its window (nothing nearer can come), and dropped only when
/// no pose of its window ever came. Before, it was dropped on arrival: up to 8 of 60 frames
/// in a run of the Chapter 6 pipeline (`docs/lab.md`).
pub struct BallLocalization {
    poses: BTreeMap<i64, Pose>,
    /// Pixels waiting for the poses of their window, by frame time.
    waiting: BTreeMap<i64, PixelPos>,
}

/// How far from a frame's time its pose may have been sensed.
const POSE_WINDOW_MS: i64 = 25;

impl BallLocalization {
    /// Poses kept (4 s at 50 Hz), and pixels waiting at most.
    const POSES: usize = 200;
    const WAITING: usize = 32;

    /// A localiser.
    #[must_use]
    pub fn new() -> Self {
        Self {
            poses: BTreeMap::new(),
            waiting: BTreeMap::new(),
        }
    }

    /// Localises the waiting pixels whose pose is known now, oldest first.
    fn localise_waiting(&mut self, cu: &mut NodeHandle<'_>) -> Result<(), CuError> {
        let latest = self.poses.last_key_value().map(|(t, _)| *t);
        while let Some((&t, _)) = self.waiting.first_key_value() {
            let closed = latest.is_some_and(|l| l > t + POSE_WINDOW_MS);
            if !closed && !self.poses.contains_key(&t) {
                break;
            }
            let pixel = self.waiting.pop_first().map(|(_, p)| p);
            let nearest = self
                .poses
                .range(t - POSE_WINDOW_MS..=t + POSE_WINDOW_MS)
                .min_by_key(|(pt, _)| (**pt - t).abs())
                .map(|(_, p)| *p);
            if let Some((x, y)) = pixel
                .zip(nearest)
                .and_then(|(pixel, pose)| nao::localize(&pixel, &pose))
            {
                cu.publish_all(&Sample::new(t, json!({"x": x, "y": y})))?;
            }
        }
        Ok(())
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
            while self.poses.len() > Self::POSES {
                self.poses.pop_first();
            }
        } else {
            let pixel = PixelPos {
                u: number(&s.value, "u")?,
                v: number(&s.value, "v")?,
                radius: number(&s.value, "radius")?,
            };
            self.waiting.insert(s.t, pixel);
            // Without poses (the pose CU is gone) the oldest would wait for ever.
            while self.waiting.len() > Self::WAITING {
                self.waiting.pop_first();
            }
        }
        self.localise_waiting(cu)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::ROBOTS;

    fn every(period_ms: i64) -> Ticks {
        Ticks {
            period_ms,
            last: i64::MIN,
        }
    }

    fn due(ticks: &mut Ticks, now: i64) -> Vec<i64> {
        ticks.due_at(now).collect()
    }

    #[test]
    fn a_source_starts_at_the_tick_nearest_to_now_and_takes_each_tick_once() {
        let mut ticks = every(20);
        assert_eq!(due(&mut ticks, 1_009), [1_000]);
        // Early, or again within the same tick: nothing.
        assert_eq!(due(&mut ticks, 1_009), Vec::<i64>::new());
        assert_eq!(due(&mut ticks, 1_001), Vec::<i64>::new());
        // On time.
        assert_eq!(due(&mut ticks, 1_020), [1_020]);
        assert_eq!(due(&mut ticks, 1_041), [1_040]);
    }

    #[test]
    fn a_timer_that_fires_late_loses_no_tick() {
        // The 50 Hz pose when a camera's callback held the (then only) timer thread: the timer due at
        // 1,040 fires at 1,052, whose nearest tick is 1,060. Before, 1,040 was never
        // published.
        let mut ticks = every(20);
        assert_eq!(due(&mut ticks, 1_020), [1_020]);
        assert_eq!(due(&mut ticks, 1_052), [1_040, 1_060]);
        assert_eq!(due(&mut ticks, 1_080), [1_080]);
        // Ticks up to LATE_MS late are taken, oldest first: 240 ms of them here.
        assert_eq!(
            due(&mut ticks, 1_320),
            (1_100..=1_320).step_by(20).collect::<Vec<_>>()
        );
    }

    #[test]
    fn after_a_long_stall_the_older_ticks_are_skipped_not_replayed() {
        let mut ticks = every(100);
        assert_eq!(due(&mut ticks, 1_000), [1_000]);
        // Ten seconds without a firing: only the ticks of the last LATE_MS.
        assert_eq!(due(&mut ticks, 11_010), [10_800, 10_900, 11_000]);
        assert_eq!(due(&mut ticks, 11_100), [11_100]);
    }

    /// Feeds `samples` to a localiser; returns the (t, position) it published.
    fn localise(samples: &[Sample]) -> Vec<(i64, (f64, f64))> {
        let (params, inputs, outputs) = (BTreeMap::new(), Vec::new(), vec!["out".to_owned()]);
        let (mut published, mut timers) = (dyknow_cu::Collect::default(), Vec::new());
        let mut localiser = BallLocalization::new();
        for s in samples {
            let mut cu = NodeHandle::new(
                "localiser",
                &params,
                &inputs,
                &outputs,
                &mut published,
                &mut timers,
            );
            localiser.on_sample(&mut cu, "in", s.clone()).unwrap();
        }
        published
            .0
            .iter()
            .map(|(_, s)| {
                (
                    s.t,
                    (
                        s.value["x"].as_f64().unwrap(),
                        s.value["y"].as_f64().unwrap(),
                    ),
                )
            })
            .collect()
    }

    fn pose_at(t: i64) -> Sample {
        Sample::new(
            t,
            pose_json(&nao::sensed_pose(&World::default(), &ROBOTS[0], t)),
        )
    }

    const PIXEL: PixelPos = PixelPos {
        u: 640.0,
        v: 900.0,
        radius: 12.0,
    };

    fn pixel_at(t: i64) -> Sample {
        Sample::new(
            t,
            json!({"u": PIXEL.u, "v": PIXEL.v, "radius": PIXEL.radius}),
        )
    }

    /// Where [`PIXEL`] is with the pose sensed at `t`.
    fn seen_with_pose_of(t: i64) -> (f64, f64) {
        nao::localize(&PIXEL, &nao::sensed_pose(&World::default(), &ROBOTS[0], t)).unwrap()
    }

    #[test]
    fn a_pixel_after_its_pose_is_localised_at_once() {
        let out = localise(&[pose_at(980), pose_at(1_000), pixel_at(1_000)]);
        assert_eq!(out, [(1_000, seen_with_pose_of(1_000))]);
    }

    #[test]
    fn a_pixel_before_its_pose_waits_for_it() {
        // The pixel overtook the poses of its window (they were held on the timer thread).
        let out = localise(&[pose_at(960), pixel_at(1_000)]);
        assert!(out.is_empty(), "{out:?}");
        let out = localise(&[pose_at(960), pixel_at(1_000), pose_at(980), pose_at(1_000)]);
        assert_eq!(out, [(1_000, seen_with_pose_of(1_000))]);
        // No pose at its time: the nearest in its window, once a later one closes it.
        let out = localise(&[pose_at(960), pixel_at(1_010), pose_at(1_000)]);
        assert!(out.is_empty(), "{out:?}");
        let out = localise(&[
            pose_at(960),
            pixel_at(1_010),
            pose_at(1_000),
            pose_at(1_020),
            pose_at(1_040),
        ]);
        assert_eq!(out, [(1_010, seen_with_pose_of(1_000))]);
    }

    #[test]
    fn a_pixel_without_a_pose_in_its_window_is_dropped_and_holds_up_nothing() {
        let out = localise(&[
            pose_at(900),
            pixel_at(1_000),
            pixel_at(1_100),
            pose_at(1_100),
        ]);
        assert_eq!(out, [(1_100, seen_with_pose_of(1_100))]);
        // Without any pose, at most WAITING pixels wait.
        let pixels: Vec<Sample> = (0..100).map(|k| pixel_at(k * 100)).collect();
        let mut all = pixels.clone();
        all.push(pose_at(9_900));
        let out = localise(&all);
        assert_eq!(out, [(9_900, seen_with_pose_of(9_900))]);
    }
}
