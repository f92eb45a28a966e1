//! The planner against its promises: blends within tolerance, limits held, memory counted.

use super::*;
use crate::interp::{Machine, read};
use crate::watch::Unwatched;
use pkm_api::trajectory::TrajectoryEventKind;
use pkm_kinematics::MAX_DOF;

fn frame(model: pkm_kinematics::Machine) -> MachineFrame {
    MachineFrame::default_for(model).expect("the default home is a pose")
}

fn limits(n: usize, speed: f64, accel: f64) -> PlanLimits {
    PlanLimits {
        joint_speed: vec![speed; n],
        joint_accel: vec![accel; n],
        axis_speed: [50.0; 6],
        axis_accel: [500.0; 6],
    }
}

fn planned(model: pkm_kinematics::Machine, text: &str, l: &PlanLimits) -> Plan {
    let f = frame(model);
    let program = read(
        // A program ends (M2); what follows an end is never read.
        &format!("{text}\nM2"),
        &Machine {
            block_delete: false,
            axes: f.kinematics().pose_keys(),
            start: [0.0; 6],
            work_offsets: [[0.0; 6]; 6],
            homes: [[0.0; 6]; 2],
            tools: None,
        },
    )
    .unwrap_or_else(|e| panic!("{e}"));
    plan(&program, &f, l).unwrap_or_else(|e| panic!("{e}"))
}

/// Samples every `dt` from start to end.
fn samples(p: &Plan, dt: f64) -> Vec<Sample> {
    let mut cursor = 0;
    let steps = (p.duration_s / dt).ceil() as usize + 1;
    (0..=steps).map(|i| p.sample(i as f64 * dt, &mut cursor)).collect()
}

/// What the interpreter counts for a program bounds what the program and its plan hold:
/// short blended lines, arcs, long lines, exact stops, rotations.
#[test]
fn the_counted_cost_bounds_the_memory_of_the_program_and_its_plan() {
    let spiral: String = (0..5000)
        .map(|i| {
            let (a, r) = (i as f64 * 0.02, 5.0 + i as f64 * 0.001);
            format!("X{:.3} Y{:.3}\n", r * a.cos() - 5.0, r * a.sin())
        })
        .collect();
    let arcs: String = (0..200).map(|_| "G2 X0 Y0 I2 J0 P3\nG3 X0 Y0 I-1 J0\n").collect();
    let lines: String = (0..300).map(|i| format!("X{} Y{}\n", i % 2 * 30, i % 3 * 10)).collect();
    let tilts: String = (0..300).map(|i| format!("X{} A{}\n", i % 2, i % 3)).collect();
    for (model, text) in [
        // Q0: every line its own element, the most a program of lines holds.
        (
            pkm_kinematics::Machine::OxX,
            format!("G64 P0.01 Q0\nG1 F3000\n{spiral}"),
        ),
        (pkm_kinematics::Machine::OxX, format!("G64 P0.05\nG1 F600\n{arcs}")),
        (pkm_kinematics::Machine::OxX, format!("G61\nG1 F600\n{lines}")),
        (pkm_kinematics::Machine::Hexapod, format!("G64\nG1 F300\n{tilts}")),
    ] {
        let f = frame(model);
        let program = read(
            &format!("{text}M2"),
            &Machine {
                block_delete: false,
                axes: f.kinematics().pose_keys(),
                start: [0.0; 6],
                work_offsets: [[0.0; 6]; 6],
                homes: [[0.0; 6]; 2],
                tools: None,
            },
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let mut cost = crate::budget::Cost::default();
        for b in &program.blocks {
            cost.add(b);
        }
        let plan = plan(&program, &f, &limits(f.dof(), 50.0, 500.0)).unwrap_or_else(|e| panic!("{e}"));
        // At its most, while the profile is planned.
        let held = (program.blocks.capacity() * size_of::<crate::interp::Block>()) as u64
            + plan.heap_bytes()
            + plan.planning_bytes;
        // Counted: up to twice what it holds, and the points refining may add to any program
        // (which these do not need).
        let extra = crate::plan::allowance(0) as u64 * crate::plan::POINT_BYTES;
        assert!(
            held <= cost.bytes() && held * 2 + extra > cost.bytes(),
            "{model:?}: {held} bytes held, {} counted",
            cost.bytes()
        );
    }
}

/// G64 Q (LinuxCNC's naive CAM detector): a CAM program's run of short lines that stray less
/// than Q from one straight line is run as that line — fewer corners, a shorter time — and
/// lines that turn more than Q stay lines of their own; without Q, within P; Q0 merges none.
#[test]
fn g64_q_merges_nearly_collinear_lines_within_q() {
    let zigzag: String = (1..=100)
        .map(|i| format!("X{} Y{}\n", i as f64 * 0.5, if i % 2 == 0 { 0.0 } else { 0.004 }))
        .collect();
    let l = limits(3, 20.0, 100.0);
    let without = planned(
        pkm_kinematics::Machine::OxX,
        &format!("G64 P0.01 Q0\nG1 F600\n{zigzag}"),
        &l,
    );
    // G64 P alone merges within P, as LinuxCNC's naive CAM tolerance is P where Q is not given.
    let by_p = planned(
        pkm_kinematics::Machine::OxX,
        &format!("G64 P0.01\nG1 F600\n{zigzag}"),
        &l,
    );
    assert_eq!(by_p.elements().len(), 2, "{}", by_p.elements().len());
    let merged = planned(
        pkm_kinematics::Machine::OxX,
        &format!("G64 P0.01 Q0.01\nG1 F600\n{zigzag}"),
        &l,
    );
    // Without Q every corner is blended: a hundred pieces and more.
    assert!(without.elements().len() > 100, "{}", without.elements().len());
    // At most 64 lines a merge: two lines of 32 and 18 mm.
    let lines: Vec<f64> = merged.elements().iter().map(|e| e.segment.length()).collect();
    assert_eq!(lines.len(), 2, "{lines:?}");
    assert!(
        merged.duration_s < without.duration_s,
        "{} vs {}",
        merged.duration_s,
        without.duration_s
    );
    // A turn beyond Q is not merged away.
    let corner = planned(
        pkm_kinematics::Machine::OxX,
        "G64 P0.01 Q0.01\nG1 F600 X10\nX20 Y1\n",
        &l,
    );
    assert!(corner.elements().len() >= 2);
}

const SQUARE_AND_CIRCLE: &str = "G64 P0.05\nG1 X20 Y0 F1200\nY20\nX0\nY0\nG0 X10\nG2 X10 Y0 I-10 F900\nM2\n";

#[test]
fn every_joint_keeps_its_speed_and_acceleration_at_every_sample() {
    // Checked against the kinematics: joint positions by IK of the sampled poses, their
    // differences over 2 ms.
    const TILTS: &str = "G64 P0.05\nG1 X10 A3 F600\nY10 B-3\nX0 A0\nY0 B0\nG2 X0 Y0 I5 J0 C2\nM2\n";
    for (model, n, program, speed, accel) in [
        (pkm_kinematics::Machine::OxX, 3, SQUARE_AND_CIRCLE, 20.0, 100.0),
        (pkm_kinematics::Machine::Pn101, 3, SQUARE_AND_CIRCLE, 8.0, 40.0),
        (pkm_kinematics::Machine::Hexapod, 6, TILTS, 25.0, 200.0),
    ] {
        let l = limits(n, speed, accel);
        let p = planned(model, program, &l);
        let f = frame(model);
        let dt = 0.002;
        let q: Vec<[f64; MAX_DOF]> = samples(&p, dt)
            .iter()
            .map(|s| {
                let mut q = [0.0; MAX_DOF];
                f.inverse(&s.pose[..n], &mut q[..n]).expect("reachable");
                q
            })
            .collect();
        let (mut vmax, mut amax) = (0.0f64, 0.0f64);
        for w in q.windows(3) {
            for ((q0, q1), q2) in w[0][..n].iter().zip(&w[1][..n]).zip(&w[2][..n]) {
                vmax = vmax.max(((q1 - q0) / dt).abs());
                amax = amax.max(((q2 - 2.0 * q1 + q0) / (dt * dt)).abs());
            }
        }
        assert!(vmax <= speed * 1.01, "{model:?}: joint speed {vmax} > {speed}");
        assert!(amax <= accel * 1.05, "{model:?}: joint acceleration {amax} > {accel}");
    }
}

#[test]
fn blends_stay_within_the_tolerance_and_exact_stops_stop() {
    let l = limits(3, 100.0, 1000.0);
    // The square's corners rounded within 0.05 mm: every sample within 0.05 mm of the
    // programmed polyline.
    let p = planned(
        pkm_kinematics::Machine::OxX,
        "G64 P0.05\nG1 X20 F1200\nY20\nX0\nY0\nM2\n",
        &l,
    );
    let corners = [[0.0, 0.0], [20.0, 0.0], [20.0, 20.0], [0.0, 20.0], [0.0, 0.0]];
    let distance = |x: f64, y: f64| {
        corners
            .windows(2)
            .map(|w| {
                let (a, b) = (w[0], w[1]);
                let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
                let t = (((x - a[0]) * dx + (y - a[1]) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
                (x - a[0] - t * dx).hypot(y - a[1] - t * dy)
            })
            .fold(f64::INFINITY, f64::min)
    };
    let worst = samples(&p, 0.001)
        .iter()
        .map(|s| distance(s.pose[0], s.pose[1]))
        .fold(0.0, f64::max);
    assert!(worst <= 0.05 + 1e-9, "{worst} mm off the programmed path");
    assert!(worst > 0.01, "the corners are rounded, not stopped at: {worst}");
    // G64 without P: within PLAIN_G64_MM, not half of each 20 mm line (5.8 mm before).
    let plain = planned(pkm_kinematics::Machine::OxX, "G64\nG1 X20 F1200\nY20\nX0\nY0\nM2\n", &l);
    let worst = samples(&plain, 0.001)
        .iter()
        .map(|s| distance(s.pose[0], s.pose[1]))
        .fold(0.0, f64::max);
    assert!(worst <= PLAIN_G64_MM + 1e-9, "{worst} mm off the programmed path");
    // A 90° corner's arc passes the corner at the bound, the lines at 1 − cos 45° of its
    // radius: 0.707 of the bound.
    assert!(worst > 0.7 * PLAIN_G64_MM, "rounded up to the bound: {worst}");
    // G61: the tool stops at each corner; it takes longer.
    let exact = planned(pkm_kinematics::Machine::OxX, "G61\nG1 X20 F1200\nY20\nX0\nY0\nM2\n", &l);
    assert!(
        exact.duration_s > p.duration_s,
        "{} vs {}",
        exact.duration_s,
        p.duration_s
    );
    let closest = samples(&exact, 0.001)
        .iter()
        .map(|s| (s.pose[0] - 20.0).hypot(s.pose[1]))
        .fold(f64::INFINITY, f64::min);
    assert!(closest < 1e-3, "the tool reaches the corner: {closest} mm");
}

/// Short CAM lines written to three decimals, two of them turning by 2e-8 rad: planned,
/// every sample a finite pose (the blend between the two had a centre that was not a number).
#[test]
fn nearly_collinear_short_lines_plan_to_finite_poses() {
    let l = limits(3, 200.0, 2000.0);
    let p = planned(
        pkm_kinematics::Machine::Pn101,
        "G64 P0.01\nG0 X2.572 Y4.288\nG1 F600\nX2.545 Y4.304\nX2.518 Y4.320\nX2.491 Y4.335\nX2.464 Y4.351\nX2.436 Y4.366",
        &l,
    );
    assert!(p.duration_s > 0.0);
    for s in samples(&p, 0.002) {
        assert!(s.pose.iter().all(|v| v.is_finite()), "{s:?}");
    }
}

/// A line into an arc at an angle (90° here) is blended within G64 P by two arcs
/// instead of stopping: the tool keeps moving through the corner, passes it within P, and
/// the part takes less time than with G61.
#[test]
fn a_line_into_an_arc_is_blended_within_the_tolerance() {
    // The O-X glide's joints: stopping at a corner from 10 mm/s takes a tenth of a second.
    let l = limits(3, 20.0, 100.0);
    let text = |mode: &str| format!("{mode}\nG1 X10 F600\nG3 X20 Y0 I5 J0\nG1 X30\nM2\n");
    let blended = planned(pkm_kinematics::Machine::OxX, &text("G64 P0.01"), &l);
    let exact = planned(pkm_kinematics::Machine::OxX, &text("G61"), &l);
    assert!(
        blended.duration_s < exact.duration_s,
        "{} vs {}",
        blended.duration_s,
        exact.duration_s
    );
    let samples = samples(&blended, 0.0005);
    // Through both corners the tool never stands.
    let moving = samples
        .iter()
        .filter(|s| (s.pose[0] - 10.0).hypot(s.pose[1]) < 0.2 || (s.pose[0] - 20.0).hypot(s.pose[1]) < 0.2)
        .map(|s| s.speed)
        .fold(f64::INFINITY, f64::min);
    assert!(moving > 0.5, "the slowest speed at the corners: {moving} mm/s");
    // Within P of the programmed path: the lines (y = 0 outside 10 … 20) and the lower half
    // circle about (15, 0).
    let off = |s: &Sample| {
        let (x, y) = (s.pose[0], s.pose[1]);
        let to_circle = if y <= 0.0 {
            ((x - 15.0).hypot(y) - 5.0).abs()
        } else {
            f64::INFINITY
        };
        let to_lines = if x <= 10.0 || x >= 20.0 {
            y.abs()
        } else {
            (x - 10.0).hypot(y).min((x - 20.0).hypot(y))
        };
        to_circle.min(to_lines)
    };
    let worst = samples.iter().map(off).fold(0.0, f64::max);
    assert!(worst <= 0.01 + 1e-9, "{worst} mm off the programmed path");
}

#[test]
fn a_long_line_runs_at_its_feed_and_lasts_length_over_feed_plus_the_ramps() {
    let l = limits(3, 100.0, 1000.0);
    let p = planned(pkm_kinematics::Machine::OxX, "G1 X100 F1200\nM2\n", &l);
    let top = samples(&p, 0.01).iter().map(|s| s.speed).fold(0.0, f64::max);
    assert!((top - 20.0).abs() < 1e-6, "the feed 20 mm/s is reached: {top}");
    // 100 mm at 20 mm/s, plus the ramps' 20 mm/s ÷ a, where a is the tool's tangential
    // acceleration (half the slowest limit over the largest gear ratio).
    assert!(p.duration_s > 5.0 && p.duration_s < 5.6, "{}", p.duration_s);
    assert!(p.limited.is_empty(), "{:?}", p.limited);
}

#[test]
fn a_feed_beyond_a_joints_speed_is_limited_and_said_why() {
    // pn101's joints run 8 mm/s: a 100 mm/s feed along x cannot be had.
    let l = limits(3, 8.0, 40.0);
    let p = planned(pkm_kinematics::Machine::Pn101, "G1 X20 F6000\nM2\n", &l);
    assert_eq!(p.limited.len(), 1, "{:?}", p.limited);
    let lim = &p.limited[0];
    assert_eq!(lim.line, 1);
    assert_eq!(lim.programmed_mm_min, 6000.0);
    assert!(matches!(lim.why, Limit::JointSpeed(_)), "{lim:?}");
    assert!(lim.reachable_mm_min < 6000.0);
}

#[test]
fn short_segments_do_not_slow_the_tool() {
    // A circle of radius 30 mm as CAM writes it: chords of 0.05 … 0.5 mm, blended within
    // 0.01 mm. Its planned time stays within 5 % of length ÷ feed.
    let mut text = String::from("G64 P0.01\nG0 X30 Y0\n");
    let (mut angle, mut i) = (0.0f64, 0u32);
    while angle < std::f64::consts::TAU {
        let chord = 0.05 + 0.45 * f64::from(i % 10) / 9.0;
        angle = (angle + chord / 30.0).min(std::f64::consts::TAU);
        text.push_str(&format!(
            "G1 X{:.4} Y{:.4} F1200\n",
            30.0 * angle.cos(),
            30.0 * angle.sin()
        ));
        i += 1;
    }
    text.push_str("M2\n");
    let l = limits(3, 100.0, 1000.0);
    let p = planned(pkm_kinematics::Machine::OxX, &text, &l);
    let feed_time = (p.length_mm - 30.0) / 20.0;
    assert!(i > 600, "{i} segments");
    assert!(
        p.duration_s < 1.05 * feed_time + 2.0,
        "{} s for {} s at the feed",
        p.duration_s,
        feed_time
    );
    assert!(
        p.elements().iter().all(|e| e.segment.length() > 1e-9),
        "no empty pieces"
    );
}

#[test]
fn rotations_join_without_a_kink_and_a_straight_line_with_a_new_rate_stops() {
    let l = limits(6, 25.0, 200.0);
    // A corner blended: the tilt's rate changes smoothly through it.
    let p = planned(
        pkm_kinematics::Machine::Hexapod,
        "G64 P0.5\nG1 X10 A2 F600\nY10 A0\nM2\n",
        &l,
    );
    let blend = p.elements().iter().find(|e| e.segment.is_arc()).expect("a blend");
    let (r0, r1) = blend.segment.rotation_rates();
    assert!(
        (r0[0] - 0.2).abs() < 1e-9 && (r1[0] + 0.2).abs() < 1e-9,
        "{r0:?} {r1:?}"
    );
    // Straight on, but the tilt changes its rate: the tool stops between the two.
    let p = planned(
        pkm_kinematics::Machine::Hexapod,
        "G64\nG1 X10 A2 F600\nX20 A0\nM2\n",
        &l,
    );
    assert!(p.elements()[0].stop_after, "{:?}", p.elements()[0]);
    assert_eq!(p.elements().len(), 2);
}

#[test]
fn a_dwell_holds_the_tool() {
    let l = limits(3, 100.0, 1000.0);
    let without = planned(pkm_kinematics::Machine::OxX, "G1 X10 F600\nG1 X20\nM2\n", &l);
    let with = planned(pkm_kinematics::Machine::OxX, "G1 X10 F600\nG4 P2\nG1 X20\nM2\n", &l);
    assert!(
        with.duration_s > without.duration_s + 2.0,
        "{} vs {}",
        with.duration_s,
        without.duration_s
    );
    let mut cursor = 0;
    let s = with.sample(with.duration_s / 2.0, &mut cursor);
    assert!((s.pose[0] - 10.0).abs() < 1e-9 && s.speed == 0.0, "{s:?}");
}

#[test]
fn pauses_and_spindle_changes_stand_where_the_tool_stops_for_them() {
    let l = limits(3, 100.0, 1000.0);
    let p = planned(
        pkm_kinematics::Machine::OxX,
        "S1000 M3\nG64 P0.1\nG1 X10 F600\nG4 P1\nM0\nG1 X20\nM5\nM2\n",
        &l,
    );
    // The program coordinates aside (tested with the interpreter).
    let kinds: Vec<(u32, TrajectoryEventKind)> = p
        .events
        .iter()
        .filter(|e| !matches!(e.kind, TrajectoryEventKind::WorkOffset { .. }))
        .map(|e| (e.line, e.kind))
        .collect();
    assert_eq!(
        kinds,
        [
            (
                1,
                TrajectoryEventKind::Spindle {
                    direction: 1,
                    rpm: 1000.0
                }
            ),
            (4, TrajectoryEventKind::Dwell { seconds: 1.0 }),
            (5, TrajectoryEventKind::Pause),
            (7, TrajectoryEventKind::Spindle { direction: 0, rpm: 0.0 }),
        ]
    );
    let events: Vec<_> = p
        .events
        .iter()
        .filter(|e| !matches!(e.kind, TrajectoryEventKind::WorkOffset { .. }))
        .collect();
    assert_eq!(events[0].t, 0.0);
    // The dwell where the tool stops at the end of the first line, the pause a second after
    // it: the tool stands at X10 from the one to the other.
    assert!((events[2].t - events[1].t - 1.0).abs() < 1e-9, "{events:?}");
    let mut cursor = 0;
    let at = p.sample(events[2].t, &mut cursor);
    assert!((at.pose[0] - 10.0).abs() < 1e-9 && at.speed == 0.0, "{at:?}");
    let before = p.sample(events[1].t, &mut cursor);
    assert!(
        (before.pose[0] - 10.0).abs() < 1e-9 && before.speed == 0.0,
        "dwelling first: {before:?}"
    );
    assert!((events[3].t - p.duration_s).abs() < 1e-9, "M5 at the end");
}

/// The program: four short lines at F6000 whose corners' blends are short arcs. A point
/// 0.05 mm from each curve was put into lines split finer than that, behind the next point:
/// the distances went back, an interval had a negative length, and the plan's times were not
/// numbers. Every machine plans it to a finite time now, checked as the cyclic side samples it.
#[test]
fn short_lines_blended_at_a_high_feed_plan_to_finite_times_on_every_machine() {
    const PROGRAM: &str =
        "G1 X1.791 Y0.907 F6000\nG1 X-3.581 Y3.181 F6000\nG1 X-2.717 Y2.844 F6000\nG1 X-4.204 Y2.846 F6000";
    for (model, n) in [
        (pkm_kinematics::Machine::OxX, 3),
        (pkm_kinematics::Machine::Pn101, 3),
        (pkm_kinematics::Machine::Hexapod, 6),
        (pkm_kinematics::Machine::Trijoint, 2),
    ] {
        let l = limits(n, 20.0, 100.0);
        let p = planned(model, PROGRAM, &l);
        assert!(
            p.duration_s.is_finite() && p.duration_s > 0.0,
            "{model:?}: {}",
            p.duration_s
        );
        assert!(
            p.points.windows(2).all(|w| w[0].s <= w[1].s),
            "{model:?}: the distances only grow"
        );
        verify(p, &frame(model), &l, 0.01, &Unwatched).unwrap_or_else(|e| panic!("{model:?}: {e}"));
    }
}

/// The boundary check refuses a plan the machine cannot follow, or whose numbers are not
/// numbers, with the program line and column where it fails; a plan within the limits passes.
#[test]
fn a_plan_past_the_limits_or_not_a_number_is_refused_with_its_line_and_column() {
    let model = pkm_kinematics::Machine::OxX;
    let l = limits(3, 20.0, 100.0);
    let p = planned(model, "G1 X10 F1200\nG1 X10 Y5", &l);
    assert!(verify(p.clone(), &frame(model), &l, 0.01, &Unwatched).is_ok());
    // Held to half the acceleration it was planned with: refused where it first asks more,
    // the start of the first line (its X word at column 4).
    let e = verify(p.clone(), &frame(model), &limits(3, 20.0, 50.0), 0.01, &Unwatched).expect_err("refused");
    assert_eq!((e.line, e.column), (1, 4), "{e}");
    assert!(
        e.message.starts_with("the plan asks joint ") && e.message.contains("past its limit of 50 mm/s²"),
        "{e}"
    );
    assert!(
        e.message
            .ends_with("a fault of the planner; the program is refused and nothing moves"),
        "{e}"
    );
    // A speed that is not a number on the second line (its X word at column 4).
    let mut broken = p;
    let k = broken
        .points
        .iter()
        .position(|q| broken.elements[q.element as usize].line == 2)
        .expect("line 2");
    broken.points[k + 1].v = f64::NAN;
    let e = verify(broken, &frame(model), &l, 0.01, &Unwatched).expect_err("refused");
    assert_eq!((e.line, e.column), (2, 4), "{e}");
    assert!(e.message.starts_with("the plan is not a number at "), "{e}");
}
