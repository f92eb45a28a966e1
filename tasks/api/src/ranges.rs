//! The ranges of the numbers a configuration gives, written once and applied to every machine
//!: a value outside its range is refused by `check` with its path, its range and
//! why the range is what it is. A range is generous enough for any lab model these programs
//! drive and tight enough that no value in it defeats a safety function (a following-error bound
//! of 1e308 leaves a dead drive unnoticed; a STOP lockout of 0 lets a bouncing contact
//! acknowledge the error it caused).

use crate::image::Declare;
use crate::problem::Problem;

/// An inclusive range of a number, with its unit and the reason for its bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Range {
    /// The smallest value allowed.
    pub min: f64,
    /// The largest value allowed.
    pub max: f64,
    /// The unit, as messages give it (`mm/s`; empty for a ratio).
    pub unit: &'static str,
    /// Why these bounds (said after the range in a refusal; empty: nothing to add).
    pub why: &'static str,
}

impl Range {
    /// A range `min` … `max` in `unit`, for the reason `why`.
    pub const fn new(min: f64, max: f64, unit: &'static str, why: &'static str) -> Range {
        Range { min, max, unit, why }
    }

    /// The same range with another upper bound (a bound that depends on another value).
    pub const fn up_to(self, max: f64) -> Range {
        Range { max, ..self }
    }

    /// The same range up to `bound`, kept within the range: a value that must not exceed another
    /// (a search no faster than the joint's top speed) and still lie in its own range when the
    /// other does not.
    pub fn up_to_within(self, bound: f64) -> Range {
        self.up_to(bound.clamp(self.min, self.max))
    }

    /// The same range with another lower bound.
    pub const fn from(self, min: f64) -> Range {
        Range { min, ..self }
    }

    /// Whether `v` lies in the range (a NaN or an infinity never does).
    pub fn contains(&self, v: f64) -> bool {
        v.is_finite() && v >= self.min && v <= self.max
    }

    /// The refusal of `v`: `must be between 0.1 and 1000 mm/s (why), got 1e308`.
    pub fn refusal(&self, v: f64) -> String {
        let unit = if self.unit.is_empty() {
            String::new()
        } else {
            format!(" {}", self.unit)
        };
        let why = if self.why.is_empty() {
            String::new()
        } else {
            format!(" ({})", self.why)
        };
        format!(
            "must be between {} and {}{unit}{why}, got {}",
            shown(self.min),
            shown(self.max),
            shown(v)
        )
    }

    /// `Err` with the refusal of `v` when it lies outside.
    pub fn check(&self, v: f64) -> Result<(), String> {
        if self.contains(v) { Ok(()) } else { Err(self.refusal(v)) }
    }
}

/// Whether pose coordinate `key` (as a machine's kinematics names them, `x` … `c`) is a
/// rotation in degrees (`a`, `b`, `c`), not a position in mm: it takes the angular of two ranges.
pub fn is_rotation(key: &str) -> bool {
    matches!(key, "a" | "b" | "c")
}

/// Records a problem at `at` in `problems` when `value` lies outside `range`; true when it lies
/// in. For the checks that collect [`Problem`]s themselves (a plant section, say).
pub fn check_into(problems: &mut Vec<Problem>, at: impl Into<String>, value: f64, range: &Range) -> bool {
    let ok = range.contains(value);
    if !ok {
        problems.push(Problem::new(at, range.refusal(value)));
    }
    ok
}

/// A number as a message shows it: plain where that is short, else in exponent form (`1e308`,
/// not 309 digits).
pub fn shown(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-6..1e15).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

impl Declare<'_> {
    /// Records a problem at `sub_path` when `value` lies outside `range`; true when it lies in.
    pub fn within(&mut self, sub_path: &str, value: f64, range: &Range) -> bool {
        let ok = range.contains(value);
        if !ok {
            self.issue(sub_path, range.refusal(value));
        }
        ok
    }
}

/// A STOP press is ignored this long after an accepted one (ms).
pub const STOP_LOCKOUT_MS: Range = Range::new(
    100.0,
    10_000.0,
    "ms",
    "a shorter lockout lets a bouncing STOP contact acknowledge the error it caused; a longer one leaves STOP dead for too long",
);
/// The largest following error before the drives stop (mm).
pub const FOLLOWING_ERROR_MM: Range = Range::new(
    0.01,
    50.0,
    "mm",
    "beyond it a blocked or dead drive goes unnoticed; 0 would stop at every step",
);
/// A joint's or a carriage's speed: maximal, jog, search (mm/s).
pub const SPEED_MM_S: Range = Range::new(0.01, 1000.0, "mm/s", "");
/// The slowest approaches (a reference's latch, the TRIJOINT's creep), in mm/s.
pub const SLOW_SPEED_MM_S: Range = Range::new(0.001, 100.0, "mm/s", "");
/// A rotation's jog speed (degrees/s).
pub const ANGULAR_SPEED_DEG_S: Range = Range::new(0.01, 360.0, "degrees/s", "");
/// An acceleration or deceleration (mm/s², degrees/s²).
pub const ACCEL_MM_S2: Range = Range::new(0.1, 100_000.0, "mm/s²", "");
/// The S word of a laser's full power (`nc.laser.s_max`): grbl's `$30` is 1000.
pub const LASER_S_MAX: Range = Range::new(1.0, 1_000_000.0, "", "the S value of the beam's full power");
/// The most moves and other actions one NC program may make (`nc.max_moves`).
pub const NC_MAX_MOVES: Range = Range::new(
    1000.0,
    4_000_000.0,
    "",
    "a plan's memory grows with its moves; split longer programs",
);
/// The most memory one NC program and its plan may take (`nc.max_plan_mib`, MiB).
pub const NC_MAX_PLAN_MIB: Range = Range::new(16.0, 16_384.0, "MiB", "");
/// The longest one NC program's reading, check and plan may take (`nc.max_planning_s`).
pub const NC_MAX_PLANNING_S: Range = Range::new(
    1.0,
    600.0,
    "s",
    "a job the operator waits for, which nothing else may hold up for longer",
);
/// The longest one NC program may run as planned (`nc.max_duration_h`, hours).
pub const NC_MAX_DURATION_H: Range = Range::new(0.01, 1000.0, "h", "");
/// The share of the joints' and axes' accelerations an NC program's plan uses.
pub const ACCEL_SHARE: Range = Range::new(0.05, 1.0, "", "a fraction of each acceleration");
/// A distance a search backs off or approaches from (mm).
pub const SEARCH_DISTANCE_MM: Range = Range::new(0.001, 100.0, "mm", "");
/// How long a search or a move in INIT may take before it is an INIT timeout (s).
pub const TIMEOUT_S: Range = Range::new(1.0, 3600.0, "s", "");
/// How far inside the travel the software limits lie (mm); the upper bound depends on the
/// travel ([`Range::up_to`]).
pub const SOFT_LIMIT_MARGIN_MM: Range = Range::new(
    0.1,
    f64::MAX,
    "mm",
    "0 puts the software limits on the hard ends of the travel; at most a quarter of the shortest travel",
);
/// A position, a length or a limit in the machine's frame (mm).
pub const POSITION_MM: Range = Range::new(-10_000.0, 10_000.0, "mm", "");
/// An angle of the tool's pose (degrees).
pub const ANGLE_DEG: Range = Range::new(-180.0, 180.0, "degrees", "");
/// The ratio of singular values below which the tool is never commanded.
pub const SINGULARITY_THRESHOLD: Range = Range::new(
    0.01,
    0.99,
    "",
    "a ratio of singular values; 0 would let the tool reach a singularity",
);
/// A joystick's dead zone (a fraction of full deflection).
pub const DEAD_ZONE: Range = Range::new(0.0, 0.9, "", "a fraction of full deflection");
/// Encoder counts or motor steps per mm.
pub const COUNTS_PER_MM: Range = Range::new(1.0, 1_000_000.0, "per mm", "");
/// A proportional gain of a position regulator: duty per mm of error (DC), or 1/s (steppers).
pub const PROPORTIONAL_GAIN: Range = Range::new(0.0001, 100.0, "", "0 leaves the drive uncontrolled");
/// An integral gain: duty per mm·s.
pub const INTEGRAL_GAIN: Range = Range::new(0.0, 100.0, "duty per mm·s", "");
/// A velocity feed-forward: duty per mm/s.
pub const VELOCITY_FF: Range = Range::new(0.0, 1.0, "duty per mm/s", "");
/// An acceleration feed-forward: duty per mm/s².
pub const ACCEL_FF: Range = Range::new(0.0, 0.1, "duty per mm/s²", "");
/// A regulator's output limit (duty).
pub const OUTPUT_LIMIT: Range = Range::new(0.01, 1.0, "duty", "");
/// The PWM period of the motor bridges (µs).
pub const PWM_PERIOD_US: Range = Range::new(10.0, 10_000.0, "µs", "0 switches the motor bridges off");
/// A simulated motor's speed at full duty or pull-out speed (mm/s).
pub const MOTOR_SPEED_MM_S: Range = Range::new(0.1, 10_000.0, "mm/s", "");
/// A simulated motor's time constant (s).
pub const MOTOR_LAG_S: Range = Range::new(0.0001, 10.0, "s", "");

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refusal_says_the_range_its_unit_and_why() {
        assert_eq!(
            FOLLOWING_ERROR_MM.check(1e308),
            Err("must be between 0.01 and 50 mm (beyond it a blocked or dead drive goes unnoticed; 0 would stop at every step), got 1e308".into())
        );
        assert_eq!(DEAD_ZONE.check(0.0), Ok(()));
        assert!(SPEED_MM_S.check(f64::NAN).is_err());
        assert!(SPEED_MM_S.check(f64::INFINITY).is_err());
        assert_eq!(
            SPEED_MM_S.up_to(5.0).check(6.0),
            Err("must be between 0.01 and 5 mm/s, got 6".into())
        );
        // A bound from another value stays within the range's own.
        assert_eq!(SPEED_MM_S.up_to_within(5.0).max, 5.0);
        assert_eq!(SPEED_MM_S.up_to_within(1e9).max, SPEED_MM_S.max);
        assert_eq!(SPEED_MM_S.up_to_within(0.0).max, SPEED_MM_S.min);
    }
}
