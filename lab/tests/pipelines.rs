//! The two pipelines computed offline, stage by stage, against the world's truth: every
//! estimate within the tolerance, and the ball found in nearly every frame.
#![allow(clippy::unwrap_used, reason = "test")]

use dyknow_lab::POSITION_TOLERANCE;
use dyknow_lab::ceiling::{self, Stitcher, Undistorter};
use dyknow_lab::nao;
use dyknow_lab::world::{CENTRE, ROBOTS, Scenario, World, inside_circle};

fn worlds() -> [World; 2] {
    [
        World::default(),
        World {
            scenario: Scenario::Walk,
            seed: 11,
        },
    ]
}

#[test]
fn each_robot_localises_the_ball_within_the_tolerance() {
    for world in worlds() {
        for robot in &ROBOTS {
            let (mut seen, mut frames, mut worst) = (0, 0, 0.0f64);
            for t in (1_000_000..1_000_000 + 40 * 1500).step_by(1500) {
                frames += 1;
                let frame = nao::render(&world, robot, t);
                let levels = nao::subsample(&frame);
                let hull = nao::segment(&levels[nao::SEGMENTER_LEVEL]);
                assert!(hull.len() >= 3, "the field is seen");
                let Some(pixel) = nao::detect(&levels[nao::DETECTOR_LEVEL], &hull) else {
                    continue;
                };
                let pose = nao::sensed_pose(&world, robot, t);
                let (x, y) = nao::localize(&pixel, &pose).unwrap();
                let (bx, by) = world.ball_at(t);
                let error = (x - bx).hypot(y - by);
                worst = worst.max(error);
                assert!(
                    error < POSITION_TOLERANCE,
                    "{} at {t}: ({x:.3}, {y:.3}) for ({bx:.3}, {by:.3})",
                    robot.name
                );
                seen += 1;
            }
            eprintln!(
                "{} {:?}: {seen}/{frames} frames, worst error {worst:.3} m",
                robot.name, world.scenario
            );
            assert!(seen * 10 >= frames * 8, "{seen} of {frames}");
        }
    }
}

#[test]
fn the_ceiling_cameras_localise_the_ball_within_the_tolerance() {
    let undistort = Undistorter::new(ceiling::WIDTH, ceiling::HEIGHT);
    let stitch = Stitcher::new(ceiling::WIDTH, ceiling::HEIGHT);
    for world in worlds() {
        let mut worst = 0.0f64;
        for t in (2_000_000..2_000_000 + 40 * 1500).step_by(1500) {
            let frames: Vec<Vec<u8>> = (0..4)
                .map(|c| {
                    undistort.apply(&ceiling::render(
                        &world,
                        c,
                        ceiling::WIDTH,
                        ceiling::HEIGHT,
                        t,
                    ))
                })
                .collect();
            let top = stitch.apply([&frames[0], &frames[1], &frames[2], &frames[3]]);
            let (x, y) = ceiling::detect(&top).unwrap();
            let (bx, by) = world.ball_at(t);
            let error = (x - bx).hypot(y - by);
            worst = worst.max(error);
            assert!(
                error < POSITION_TOLERANCE,
                "at {t}: ({x:.3}, {y:.3}) for ({bx:.3}, {by:.3})"
            );
        }
        eprintln!("ceiling {:?}: worst error {worst:.3} m", world.scenario);
    }
}

#[test]
fn a_frame_without_the_ball_yields_no_position() {
    // The ball far behind Piff: not in its camera's view.
    let world = World {
        scenario: Scenario::Walk,
        seed: 11,
    };
    let t = 1_000_000;
    let frame = nao::render(&world, &ROBOTS[0], t);
    let levels = nao::subsample(&frame);
    let hull = nao::segment(&levels[nao::SEGMENTER_LEVEL]);
    // An empty hull finds nothing, whatever the pyramid shows.
    assert!(nao::detect(&levels[nao::DETECTOR_LEVEL], &[]).is_none());
    assert!(!hull.is_empty());
    // An image of the carpet only has no ball.
    let carpet =
        vec![ceiling::GREEN; ceiling::stitched_size().0 * ceiling::stitched_size().1].concat();
    assert!(ceiling::detect(&carpet).is_none());
    assert!(inside_circle(CENTRE.0, CENTRE.1));
}
