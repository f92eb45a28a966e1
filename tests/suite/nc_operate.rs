//! Operating a program: the feed override 0 … 150 % and the rapid override walk the
//! planned path faster or slower within the joints' limits; single block stands at the end of
//! every line. The executor of the machines' drive programs, on plans of the O-X glide made as
//! `run` makes them, in 10 ms cycles of simulated time.

use std::sync::Arc;

use pkm_api::trajectory::{MAX_AXES, Trajectory};
use pkm_drives::nc::{Command, Executor, Operator, RunState};
use pkm_plc::compose::Setup;
use pkm_plc::compose::{machines, nc_job};
use pkm_plc::runtime::config;

/// The fast class's cycle (s).
const DT: f64 = 0.01;

/// The O-X glide's limits: per joint speed (mm/s) and acceleration (mm/s²).
struct Limits {
    speed: Vec<f64>,
    accel: Vec<f64>,
}

/// `text` planned on the O-X glide as `run --program` plans it, with the machine's joint limits.
fn planned(text: &str) -> (Arc<dyn Trajectory>, Limits) {
    let machine = machines::find("ox-x").expect("ox-x is built in");
    let file = machine.configuration();
    let loaded = config::parse(file.text, file.name).unwrap_or_else(|e| panic!("{e}"));
    let setup = Setup::new(loaded).unwrap_or_else(|e| panic!("{e}"));
    let prepared =
        nc_job::prepare_text(&setup, "test.ngc".into(), text.into()).unwrap_or_else(|e| panic!("{}", e.message));
    let limits = Limits {
        speed: prepared.motion.joint_speed.clone(),
        accel: prepared.motion.joint_accel.clone(),
    };
    let job = prepared.into_job().unwrap_or_else(|e| panic!("{}", e.message));
    (job.trajectory, limits)
}

/// One cycle as the walk saw it.
#[derive(Clone, Copy, Debug)]
struct Seen {
    state: RunState,
    line: u32,
    pose: [f64; MAX_AXES],
    joints: [f64; MAX_AXES],
    rapid: bool,
    /// Distance along the path (mm).
    s: f64,
}

/// Walks `trajectory` from its start under `operator(cycle, executor)`, as the main program
/// commands it: run, and at a stand of single block a hold and a run (its resume) after
/// `resume_after` cycles. Stops at the end, or after `max` cycles.
fn walk(
    trajectory: &Arc<dyn Trajectory>,
    max: usize,
    resume_after: usize,
    mut operator: impl FnMut(usize, &Executor) -> Operator,
) -> Vec<Seen> {
    let mut e = Executor::new(Arc::clone(trajectory));
    let mut seen: Vec<Seen> = Vec::new();
    let mut standing = 0;
    for cycle in 0..max {
        let command = match e.state() {
            RunState::BlockDone => Command::Hold,
            RunState::Held if standing < resume_after => Command::Hold,
            _ => Command::Run,
        };
        standing = if matches!(e.state(), RunState::BlockDone | RunState::Held) {
            standing + 1
        } else {
            0
        };
        let op = operator(cycle, &e);
        e.step(command, op, DT, false);
        let s = e.sample();
        seen.push(Seen {
            state: e.state(),
            line: e.line(),
            pose: s.pose,
            joints: s.joints,
            rapid: s.rapid,
            s: s.s,
        });
        if e.state() == RunState::Done {
            break;
        }
    }
    seen
}

/// The tool's speed along the path over each cycle (mm/s, x y z).
fn speeds(seen: &[Seen]) -> Vec<f64> {
    seen.windows(2)
        .map(|w| {
            (0..3)
                .map(|c| (w[1].pose[c] - w[0].pose[c]).powi(2))
                .sum::<f64>()
                .sqrt()
                / DT
        })
        .collect()
}

/// Asserts that every joint kept its speed and acceleration limits over the walk (the
/// acceleration from three consecutive set-points, with 5 % for the cycle's discretisation).
fn within_limits(seen: &[Seen], limits: &Limits, what: &str) {
    for (j, (&vmax, &amax)) in limits.speed.iter().zip(&limits.accel).enumerate() {
        let v: Vec<f64> = seen
            .windows(2)
            .map(|w| (w[1].joints[j] - w[0].joints[j]) / DT)
            .collect();
        let fastest = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        assert!(
            fastest <= vmax * 1.001,
            "{what}: joint {} at {fastest} mm/s over {vmax}",
            j + 1
        );
        let harshest = v.windows(2).fold(0.0f64, |m, w| m.max(((w[1] - w[0]) / DT).abs()));
        assert!(
            harshest <= amax * 1.05,
            "{what}: joint {} at {harshest} mm/s² over {amax}",
            j + 1
        );
    }
}

/// A 40 mm square at F600 (10 mm/s; the O-X glide's joints go 20 mm/s at most) with exact
/// stops, reached and left by rapids.
const SQUARE: &str = "G21 G90 G61\nG0 X-20 Y-20\nG1 X20 F600\nY20\nX-20\nY-20\nG0 X0 Y0\nM2\n";

/// The fastest speed (mm/s) of the feed moves and of the rapids.
fn fastest(seen: &[Seen]) -> (f64, f64) {
    let v = speeds(seen);
    let top = |rapid: bool| {
        v.iter()
            .zip(seen.windows(2))
            .filter(|(_, w)| w[0].rapid == rapid && w[1].rapid == rapid)
            .fold(0.0f64, |m, (v, _)| m.max(*v))
    };
    (top(false), top(true))
}

fn with(feed: i16, rapid: i16) -> Operator {
    Operator::from_percent(feed, rapid, false)
}

#[test]
fn the_feed_override_moves_the_tool_at_its_share_of_the_feed_within_the_joints_limits() {
    let (trajectory, limits) = planned(SQUARE);
    let mut cycles = Vec::new();
    let mut feeds = Vec::new();
    for percent in [50, 100, 150] {
        let seen = walk(&trajectory, 10_000, 0, |_, _| with(percent, 100));
        assert_eq!(seen.last().map(|s| s.state), Some(RunState::Done), "{percent} %");
        within_limits(&seen, &limits, &format!("feed override {percent} %"));
        let (feed, _) = fastest(&seen);
        feeds.push(feed);
        cycles.push(seen.len());
    }
    // 5, 10 and 15 mm/s on the square's sides.
    for (feed, want) in feeds.iter().zip([5.0, 10.0, 15.0]) {
        assert!((feed - want).abs() < want * 0.01, "{feed} mm/s, not {want}: {feeds:?}");
    }
    // At 100 % the run takes its planned time; slower at 50 %, faster at 150 %.
    let planned_cycles = (trajectory.duration_s() / DT).ceil() as usize;
    assert!(
        cycles[1].abs_diff(planned_cycles) <= 2,
        "{cycles:?} against {planned_cycles}"
    );
    assert!(
        cycles[0] > cycles[1] * 3 / 2 && cycles[2] < cycles[1] * 9 / 10,
        "{cycles:?}"
    );
}

#[test]
fn the_rapid_override_slows_the_rapids_and_leaves_the_feed_moves() {
    let (trajectory, limits) = planned(SQUARE);
    let full = walk(&trajectory, 10_000, 0, |_, _| with(100, 100));
    let half = walk(&trajectory, 10_000, 0, |_, _| with(100, 50));
    within_limits(&half, &limits, "rapid override 50 %");
    let ((feed_full, rapid_full), (feed_half, rapid_half)) = (fastest(&full), fastest(&half));
    assert!((feed_full - feed_half).abs() < 1e-6, "{feed_full} {feed_half}");
    assert!(
        (rapid_half - rapid_full / 2.0).abs() < rapid_full * 0.01,
        "{rapid_half} mm/s at 50 % of {rapid_full}"
    );
    assert!(half.len() > full.len(), "the rapids took longer");
}

#[test]
fn an_override_of_zero_stands_on_the_path_and_raising_it_goes_on() {
    let (trajectory, limits) = planned(SQUARE);
    // 0 % from cycle 300 (on the first side) to cycle 500, then 150 %.
    let seen = walk(&trajectory, 10_000, 0, |cycle, _| match cycle {
        0..300 => with(100, 100),
        300..500 => with(0, 100),
        _ => with(150, 100),
    });
    within_limits(&seen, &limits, "0 % and back");
    let standing = &seen[450..500];
    assert!(
        standing.iter().all(|s| s.state == RunState::Running && s.line == 3),
        "{:?}",
        standing[0]
    );
    assert!(standing.windows(2).all(|w| w[0].pose == w[1].pose), "standing still");
    // On the side y = −20, between its corners.
    let at = standing[0].pose;
    assert!((at[1] + 20.0).abs() < 1e-9 && at[0] > -20.0 && at[0] < 20.0, "{at:?}");
    assert_eq!(seen.last().map(|s| s.state), Some(RunState::Done));
}

#[test]
fn lowering_the_override_from_150_brakes_within_the_joints_limits() {
    // A long straight line: cruising at 150 %, then 100 %, then 20 %.
    let (trajectory, limits) = planned("G21 G90\nG1 X30 F600\nX-30\nM2\n");
    let seen = walk(&trajectory, 20_000, 0, |cycle, _| match cycle {
        0..100 => with(150, 100),
        100..250 => with(100, 100),
        _ => with(20, 100),
    });
    within_limits(&seen, &limits, "150, 100, 20 %");
    let v = speeds(&seen);
    assert!((v[90] - 15.0).abs() < 0.15, "{} mm/s at 150 %", v[90]);
    assert!((v[240] - 10.0).abs() < 0.1, "{} mm/s at 100 %", v[240]);
    assert!((v[400] - 2.0).abs() < 0.05, "{} mm/s at 20 %", v[400]);
    assert_eq!(seen.last().map(|s| s.state), Some(RunState::Done));
}

#[test]
fn single_block_stands_at_the_end_of_every_line_and_a_resume_runs_the_next() {
    let text = "G21 G90 G64 P0.01\nG0 X-20 Y-20\nG1 X20 F1200\nY20\nG2 X-20 Y20 R20\nG1 Y-20\nM2\n";
    let (trajectory, limits) = planned(text);
    let seen = walk(&trajectory, 20_000, 20, |_, _| Operator::from_percent(100, 100, true));
    assert_eq!(seen.last().map(|s| s.state), Some(RunState::Done));
    within_limits(&seen, &limits, "single block");
    // Where it stood: the line that runs next, and the pose.
    let stands: Vec<(u32, [f64; MAX_AXES])> = seen
        .windows(2)
        .filter(|w| w[1].state == RunState::BlockDone && w[0].state != RunState::BlockDone)
        .map(|w| (w[1].line, w[1].pose))
        .collect();
    let lines: Vec<u32> = stands.iter().map(|(l, _)| *l).collect();
    assert_eq!(lines, [3, 4, 5, 6], "stood before each line");
    // Each stand is at its corner (the blended ones, before it within the tolerance).
    for ((_, pose), corner) in stands
        .iter()
        .zip([[-20.0, -20.0], [20.0, -20.0], [20.0, 20.0], [-20.0, 20.0]])
    {
        let off = (pose[0] - corner[0]).hypot(pose[1] - corner[1]);
        assert!(off < 0.1, "{pose:?} is {off} mm from the corner {corner:?}");
    }
    // Standing still while it stands.
    for w in seen
        .windows(2)
        .filter(|w| w[0].state == RunState::BlockDone && w[1].state == RunState::BlockDone)
    {
        assert_eq!(w[0].pose, w[1].pose);
    }
}

#[test]
fn single_block_switched_on_at_speed_stands_at_the_first_line_end_it_can_brake_for() {
    // Lines of 0.2 mm at 20 mm/s blend into each other (Q0: not merged); braking from 20 mm/s
    // takes more than one of them. With G64 P alone they merge within P (as LinuxCNC's naive
    // CAM detector merges them) into lines of 64, and the tool brakes to the end of the first:
    // in whole cycles within the joints' acceleration (the last cycle of a braking to an end
    // a whole number of decrements does not fit took 112 % of it once).
    for blending in ["G64 P0.01 Q0", "G64 P0.01"] {
        let mut text = format!("G21 G90 {blending}\nG1 F1200\n");
        for k in 1..=100 {
            text.push_str(&format!(
                "X{:.1} Y{:.3}\n",
                0.2 * f64::from(k),
                0.001 * f64::from(k % 2)
            ));
        }
        text.push_str("M2\n");
        let (trajectory, limits) = planned(&text);
        let mut switched_at = None;
        let seen = walk(&trajectory, 20_000, 1_000_000, |cycle, e| {
            if cycle >= 50 && switched_at.is_none() {
                switched_at = Some(e.sample().s);
            }
            Operator::from_percent(100, 100, cycle >= 50)
        });
        within_limits(&seen, &limits, &format!("single block at speed, {blending}"));
        let stand = seen.iter().find(|s| s.state == RunState::BlockDone).expect("it stood");
        let from = switched_at.expect("switched");
        // It stood at a line's end (where the next line's blend begins), not before it could
        // brake there from 20 mm/s at the path's acceleration (at least 0.5 mm).
        let end = trajectory.block_end(stand.s - 1e-6).map(|(s, _)| s);
        assert!(
            end.is_some_and(|end| (end - stand.s).abs() < 1e-6),
            "{blending}: {} is no line's end",
            stand.s
        );
        assert!(
            stand.s - from > 0.5,
            "{blending}: stood {} mm after the switch",
            stand.s - from
        );
        assert!(stand.line >= 3 && stand.line <= 102, "{blending}: {}", stand.line);
    }
}
