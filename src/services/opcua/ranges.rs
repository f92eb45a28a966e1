//! The EURange of a process-image variable: the values it takes in normal operation, where the
//! machine's configuration or the PLC bounds them. A variable with a unit and such a range is an
//! `AnalogItemType` (whose EURange is mandatory); one with a unit and no known range (a drive's
//! counter position since power-on, a time, a feed the program chooses) a `BaseAnalogType`,
//! whose EURange is optional — rather than a range made up.

use pkm_api::machine::{Motion, NO_WORLD_LIMIT};

/// The range `[low, high]` of the variable `name`, if known: the world limits of a pose
/// coordinate (where the machine has them) (`TOOL_X`, `NC_X`, `NC_TOOL_X`, …), 0 … 150 % for the feed and spindle overrides
/// and 0 … 100 % for the rapid override (the PLC clamps them there), ± the joint's speed for a
/// set-point velocity (`JOINTn_SETPOINT_VELOCITY`; stepper drives may take 10 % more).
pub fn of(name: &str, motion: Option<&Motion>) -> Option<[f64; 2]> {
    match name {
        "NC_FEED_OVERRIDE" | "NC_SPINDLE_OVERRIDE" => return Some([0.0, 150.0]),
        "NC_RAPID_OVERRIDE" => return Some([0.0, 100.0]),
        _ => {}
    }
    let motion = motion?;
    let axis = ["TOOL_", "NC_TOOL_", "NC_"]
        .iter()
        .find_map(|p| name.strip_prefix(p).filter(|rest| rest.len() == 1));
    if let Some(axis) = axis {
        let lower = axis.to_ascii_lowercase();
        let k = motion.axes.iter().position(|a| *a == lower)?;
        // A machine without world limits (the TRIJOINT: its joints bound it) gives the
        // kinematics' bound on any length, which is no range of normal operation.
        return motion
            .world_limits
            .get(k)
            .copied()
            .filter(|[low, high]| low.abs() < NO_WORLD_LIMIT && high.abs() < NO_WORLD_LIMIT);
    }
    let joint = name
        .strip_prefix("JOINT")?
        .strip_suffix("_SETPOINT_VELOCITY")?
        .parse::<usize>()
        .ok()?;
    let speed = motion.joint_speed.get(joint.checked_sub(1)?)? * 1.1;
    Some([-speed, speed])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_configuration_bounds_poses_overrides_and_set_point_speeds() {
        let motion = Motion {
            model: "ox-x",
            axes: &["x", "y", "z"],
            home: pkm_api::machine::Home::Joints(vec![0.0; 3]),
            soft_limits: vec![[0.0, 100.0]; 3],
            world_limits: vec![[-40.0, 40.0], [-35.0, 35.0], [-10.0, 5.0]],
            singularity_threshold: 0.1,
            joint_speed: vec![20.0; 3],
            joint_accel: vec![100.0; 3],
            joint_vars: vec![],
            setpoint_vars: vec![],
        };
        let m = Some(&motion);
        assert_eq!(of("TOOL_X", m), Some([-40.0, 40.0]));
        assert_eq!(of("NC_Y", m), Some([-35.0, 35.0]));
        assert_eq!(of("NC_TOOL_Z", m), Some([-10.0, 5.0]));
        // A coordinate the machine does not have.
        assert_eq!(of("TOOL_A", m), None);
        // No world limits.
        let unbounded = Motion {
            world_limits: vec![[-NO_WORLD_LIMIT, NO_WORLD_LIMIT]; 3],
            ..motion.clone()
        };
        assert_eq!(of("TOOL_X", Some(&unbounded)), None);
        assert_eq!(of("NC_FEED_OVERRIDE", None), Some([0.0, 150.0]));
        assert_eq!(of("NC_RAPID_OVERRIDE", m), Some([0.0, 100.0]));
        let [low, high] = of("JOINT2_SETPOINT_VELOCITY", m).expect("a range");
        assert!((low + 22.0).abs() < 1e-9 && (high - 22.0).abs() < 1e-9, "{low} {high}");
        assert_eq!(of("JOINT4_SETPOINT_VELOCITY", m), None);
        assert_eq!(of("JOINT0_SETPOINT_VELOCITY", m), None);
        // Counter positions since power-on, times, feeds: no range known.
        for name in ["JOINT1_POSITION", "NC_RUN_S", "NC_FEED", "SPINDLE_RPM"] {
            assert_eq!(of(name, m), None, "{name}");
        }
    }
}
