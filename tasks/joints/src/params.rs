//! The programs' parameters (`params` of their entries in the configuration): the drive
//! program's per-joint drive parameters and the main program's limits, referencing and jog
//! settings. Each machine has its own defaults (docs/machines.md); a configuration's `params` are laid
//! over them key by key and parsed strictly, so that a file may give only what it changes and a
//! misspelt key is still refused with its path.

use pkm_api::image::Declare;
use pkm_api::program::ProgramArgs;
use pkm_drives::pi::PiGains;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

/// Lays `over` onto `base`: objects key by key (recursively), anything else replaced.
fn overlay(base: &mut serde_json::Value, over: &serde_json::Value) {
    match (base, over) {
        (serde_json::Value::Object(b), serde_json::Value::Object(o)) => {
            for (k, v) in o {
                match b.get_mut(k) {
                    Some(slot) => overlay(slot, v),
                    None => {
                        b.insert(k.clone(), v.clone());
                    }
                }
            }
        }
        (b, o) => *b = o.clone(),
    }
}

/// The program entry's `params` laid over `defaults` and parsed strictly; a problem is recorded
/// against the entry's path (with the path inside `params`) and the defaults are returned, so
/// that declaration goes on and every problem of the configuration is reported at once.
pub fn parse<P: DeserializeOwned + Serialize + Clone>(
    args: &ProgramArgs<'_>,
    decl: &mut Declare<'_>,
    defaults: P,
) -> P {
    match over_defaults(args.params, "params", defaults.clone()) {
        Ok(p) => p,
        Err(problem) => {
            decl.issue(&problem.at, problem.message);
            defaults
        }
    }
}

/// `params` (if any) laid over `defaults` and parsed strictly; a problem has its path from `at`.
pub fn over_defaults<P: DeserializeOwned + Serialize>(
    params: Option<&serde_json::Value>,
    at: &str,
    defaults: P,
) -> Result<P, pkm_api::problem::Problem> {
    let Some(params) = params else {
        return Ok(defaults);
    };
    let Ok(mut merged) = serde_json::to_value(&defaults) else {
        // The defaults are plain numbers and lists: serialising them cannot fail.
        return Ok(defaults);
    };
    overlay(&mut merged, params);
    pkm_api::strict_json::section::<P>(&merged, at)
}

/// A stepper joint's drive (the drive program).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct StepperDrive {
    /// Steps per mm of joint travel.
    pub steps_per_mm: f64,
    /// Gain of the correction towards the set-point (1/s): the emitted steps are the feedback.
    pub kp_per_s: f64,
    /// The speed the drive program never commands beyond (mm/s).
    pub max_speed_mm_s: f64,
    /// The rate of change of the commanded speed it never exceeds (mm/s²): the set-points'
    /// changes every 50 ms reach the module in 10 ms steps, inside the motor's pull-out limit.
    pub max_accel_mm_s2: f64,
    /// Set-point minus emitted position beyond this (mm) is a following error.
    pub max_following_error_mm: f64,
}

/// A DC joint's drive (encoder and motor bridge; the drive program).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DcDrive {
    /// Encoder counts per mm of joint travel.
    pub counts_per_mm: f64,
    /// A counter change beyond this in one cycle is an encoder fault (below 32768).
    pub max_counts_per_cycle: u16,
    /// Proportional gain: duty (−1 … 1) per mm of following error.
    pub kp: f64,
    /// Integral gain: duty per mm·s.
    pub ki: f64,
    /// Velocity feed-forward: duty per mm/s of set-point velocity.
    pub velocity_ff: f64,
    /// Acceleration feed-forward: duty per mm/s² of set-point acceleration (the drive's lag τ
    /// times `velocity_ff`).
    pub accel_ff: f64,
    /// Output limit (duty, 0 … 1).
    pub output_limit: f64,
    /// A following error beyond this (mm) is a fault.
    pub max_following_error_mm: f64,
}

impl DcDrive {
    /// The regulator's gains (duty per mm, per mm·s, per mm/s, per mm/s²; duty limit).
    pub fn gains(&self) -> PiGains {
        PiGains {
            kp: self.kp,
            ki: self.ki,
            velocity_ff: self.velocity_ff,
            accel_ff: self.accel_ff,
            output_limit: self.output_limit,
        }
    }
}

/// The drive program's parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DrivesParams {
    /// Stepper joints (pn101, O-X glide), one per joint; empty on a DC machine.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub steppers: Vec<StepperDrive>,
    /// DC joints (hexapod), one per joint; empty on a stepper machine.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub dc: Vec<DcDrive>,
    /// PWM period written to the motor bridge modules (µs; DC machines).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pwm_period_us: Option<u16>,
}

/// How one joint is referenced.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Referencing {
    /// The joint's value where its reference switch trips (mm): the switch defines it.
    pub switch_mm: f64,
    /// Which way the joint seeks its switch: +1 or −1 (the switch is on beyond its position in
    /// this direction).
    pub direction: f64,
    /// Speed of the first, coarse search (mm/s).
    pub search_speed_mm_s: f64,
    /// Speed of the second, slow approach whose edge is the reference (mm/s).
    pub latch_speed_mm_s: f64,
    /// How far the joint backs off the switch before the slow approach (mm).
    pub back_off_mm: f64,
}

/// One joint's limits and referencing (the main program).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct JointParams {
    /// The joint's maximal speed (mm/s).
    pub max_speed_mm_s: f64,
    /// The joint's maximal acceleration (mm/s²).
    pub max_accel_mm_s2: f64,
    /// Its referencing.
    pub reference: Referencing,
}

/// The operator's jog.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct JogParams {
    /// Tool speed at full deflection along x, y, z (mm/s).
    pub linear_speed_mm_s: f64,
    /// Tool speed at full deflection about a, b, c (degrees/s).
    pub angular_speed_deg_s: f64,
    /// How fast the tool's jog speed changes (mm/s², and degrees/s² for angles).
    pub accel_mm_s2: f64,
    /// Joint speed at full deflection in joint mode, before referencing (mm/s).
    pub joint_speed_mm_s: f64,
    /// The world axes the stick's x and y drive, one pair per press of the axis button, in order.
    pub axis_pairs: Vec<[String; 2]>,
    /// Stick deflections below this count as released.
    pub dead_zone: f64,
}

/// The main program's parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MainParams {
    /// After an accepted STOP press the button is ignored this long (ms).
    pub stop_lockout_ms: u64,
    /// Per joint: limits and referencing.
    pub joints: Vec<JointParams>,
    /// The referencing sequence: groups of joints (numbered from 1) referenced together, one
    /// group after another. Joints that share a reference input must be in groups of their own.
    pub reference_order: Vec<Vec<usize>>,
    /// A reference switch not found within this time is an INIT timeout (s).
    pub search_timeout_s: f64,
    /// The software limits lie this far inside each joint's travel of the kinematics (mm).
    pub soft_limit_margin_mm: f64,
    /// World soft limits: `[min, max]` per pose coordinate of the machine frame (mm, degrees),
    /// in the order of the kinematics' pose keys.
    pub world_limits: Vec<[f64; 2]>,
    /// The tool is never commanded where the singularity measure is below this.
    pub singularity_threshold: f64,
    /// The operator's jog.
    pub jog: JogParams,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_configuration_overrides_only_what_it_gives() {
        let mut base = serde_json::json!({"a": 1, "b": {"c": 2, "d": 3}, "e": [1, 2]});
        overlay(&mut base, &serde_json::json!({"b": {"d": 4}, "e": [5]}));
        assert_eq!(base, serde_json::json!({"a": 1, "b": {"c": 2, "d": 4}, "e": [5]}));
    }
}
