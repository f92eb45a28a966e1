//! The `plant` section of a joint-driven machine's configuration: the integration step, each
//! joint's mechanics (power-on position, hard stops, switches, motor) and the harness (which
//! module channel each signal is wired to).

use std::collections::BTreeMap;

use pkm_api::problem::Problem;
use serde::{Deserialize, Serialize};

/// A stepper on an X20-like stepper module channel.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct StepperMotor {
    /// Steps per mm of joint travel.
    pub steps_per_mm: f64,
    /// Above this speed the motor falls out of step (mm/s).
    pub pull_out_speed_mm_s: f64,
    /// A change of the commanded speed faster than this makes it fall out of step (mm/s²).
    pub pull_out_accel_mm_s2: f64,
    /// It follows any change between speeds at most this fast, and catches the step train
    /// again below it (mm/s).
    pub pull_in_speed_mm_s: f64,
}

/// A DC motor behind a PWM bridge, with an incremental encoder.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DcMotor {
    /// Speed at full duty, after the lag (mm/s).
    pub v_max_mm_s: f64,
    /// Time constant of the motor's first-order lag (s).
    pub tau_s: f64,
    /// Encoder counts per mm.
    pub counts_per_mm: f64,
}

/// A joint's motor: exactly one of `stepper` and `dc`.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Motor {
    /// A stepper.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stepper: Option<StepperMotor>,
    /// A DC motor.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dc: Option<DcMotor>,
}

/// One joint of the simulated machine (positions in the joint coordinates of the kinematics).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct JointPlant {
    /// Position at power-on (mm).
    pub start_mm: f64,
    /// The hard stops `[min, max]` (mm): the joint cannot pass them.
    pub hard_stops_mm: [f64; 2],
    /// The limit switches trip at or beyond `[negative, positive]` (mm).
    pub limit_switches_mm: [f64; 2],
    /// The reference switch trips here (mm) …
    pub reference_switch_mm: f64,
    /// … and stays on beyond it in this direction (+1 or −1).
    pub reference_direction: f64,
    /// The motor.
    pub motor: Motor,
}

/// The `plant` section.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PlantConfig {
    /// Integration step (µs).
    pub step_us: u32,
    /// Whether the mechanism jams where the forward kinematics has no assembly.
    pub mechanism: bool,
    /// The joints, one per joint of the kinematics.
    pub joints: Vec<JointPlant>,
    /// Which module channel (`MODULE.Channel`) each signal is wired to, by signal key.
    pub wiring: BTreeMap<String, String>,
}

impl PlantConfig {
    /// Checks the parameters for a machine of `joints` joints whose signals have `keys`;
    /// problems have their path below `plant`.
    pub fn check(&self, joints: usize, keys: &[&str], steppers: bool) -> Vec<Problem> {
        let mut problems = Vec::new();
        if self.step_us == 0 || self.step_us > 10_000 {
            problems.push(Problem::new(
                "step_us",
                format!("must be 1 … 10000 µs, got {}", self.step_us),
            ));
        }
        if self.joints.len() != joints {
            problems.push(Problem::new(
                "joints",
                format!(
                    "the machine has {joints} joints, the section gives {}",
                    self.joints.len()
                ),
            ));
        }
        for (i, j) in self.joints.iter().enumerate() {
            j.check(&format!("joints[{i}]"), &mut problems);
            let (has, wants) = if steppers {
                (j.motor.stepper.is_some(), "stepper")
            } else {
                (j.motor.dc.is_some(), "dc")
            };
            if !has {
                problems.push(Problem::new(
                    format!("joints[{i}].motor"),
                    format!("this machine's drives are \"{wants}\" motors (its I/O map and drive program say so)"),
                ));
            }
        }
        for key in self.wiring.keys() {
            if !keys.contains(&key.as_str()) {
                problems.push(Problem::new(
                    format!("wiring.{key}"),
                    format!(
                        "the machine has no signal \"{key}\"; its signals are {}",
                        keys.join(", ")
                    ),
                ));
            }
        }
        problems
    }
}

impl JointPlant {
    fn check(&self, at: &str, problems: &mut Vec<Problem>) {
        use pkm_api::ranges::{self, check_into};
        let [min, max] = self.hard_stops_mm;
        let [neg, pos] = self.limit_switches_mm;
        let order = [min, neg, pos, max];
        let mut inside = true;
        for (k, v) in [
            ("hard_stops_mm[0]", min),
            ("limit_switches_mm[0]", neg),
            ("limit_switches_mm[1]", pos),
            ("hard_stops_mm[1]", max),
        ] {
            inside &= check_into(problems, format!("{at}.{k}"), v, &ranges::POSITION_MM);
        }
        if inside && !order.windows(2).all(|w| w[0] < w[1]) {
            problems.push(Problem::new(
                at.to_string(),
                format!(
                    "positions must satisfy hard_stops_mm[0] < limit_switches_mm[0] < limit_switches_mm[1] < hard_stops_mm[1], got {min} < {neg} < {pos} < {max}"
                ),
            ));
        }
        if !(min..=max).contains(&self.start_mm) {
            problems.push(Problem::new(
                format!("{at}.start_mm"),
                format!("must lie between the hard stops, got {}", self.start_mm),
            ));
        }
        if !(neg..=pos).contains(&self.reference_switch_mm) {
            problems.push(Problem::new(
                format!("{at}.reference_switch_mm"),
                format!("must lie between the limit switches, got {}", self.reference_switch_mm),
            ));
        }
        if self.reference_direction.abs() != 1.0 {
            problems.push(Problem::new(
                format!("{at}.reference_direction"),
                format!("must be 1 or -1, got {}", self.reference_direction),
            ));
        }
        let motor = |problems: &mut Vec<Problem>, k: &str, v: f64, range: &ranges::Range| {
            check_into(problems, format!("{at}.motor.{k}"), v, range);
        };
        if self.motor.stepper.is_some() == self.motor.dc.is_some() {
            problems.push(Problem::new(
                format!("{at}.motor"),
                "give exactly one of \"stepper\" and \"dc\"",
            ));
        }
        if let Some(m) = &self.motor.stepper {
            motor(problems, "stepper.steps_per_mm", m.steps_per_mm, &ranges::COUNTS_PER_MM);
            motor(
                problems,
                "stepper.pull_out_speed_mm_s",
                m.pull_out_speed_mm_s,
                &ranges::MOTOR_SPEED_MM_S,
            );
            motor(
                problems,
                "stepper.pull_out_accel_mm_s2",
                m.pull_out_accel_mm_s2,
                &ranges::ACCEL_MM_S2,
            );
            motor(
                problems,
                "stepper.pull_in_speed_mm_s",
                m.pull_in_speed_mm_s,
                &ranges::MOTOR_SPEED_MM_S,
            );
            if m.pull_in_speed_mm_s > m.pull_out_speed_mm_s {
                problems.push(Problem::new(
                    format!("{at}.motor.stepper.pull_in_speed_mm_s"),
                    format!(
                        "must not exceed pull_out_speed_mm_s ({}), got {}",
                        m.pull_out_speed_mm_s, m.pull_in_speed_mm_s
                    ),
                ));
            }
        }
        if let Some(m) = &self.motor.dc {
            motor(problems, "dc.v_max_mm_s", m.v_max_mm_s, &ranges::MOTOR_SPEED_MM_S);
            motor(problems, "dc.tau_s", m.tau_s, &ranges::MOTOR_LAG_S);
            motor(problems, "dc.counts_per_mm", m.counts_per_mm, &ranges::COUNTS_PER_MM);
        }
    }
}

/// The simulated plant a machine of the family starts from, before its configuration's `plant`
/// section.
impl crate::spec::Spec {
    /// The simulated plant's defaults.
    pub fn default_plant(&self) -> PlantConfig {
        let stepper = |speed: f64, accel: f64| Motor {
            stepper: Some(StepperMotor {
                steps_per_mm: 400.0,
                pull_out_speed_mm_s: 1.25 * speed,
                pull_out_accel_mm_s2: 2.0 * accel,
                pull_in_speed_mm_s: 0.25 * speed,
            }),
            dc: None,
        };
        let joint = |start_mm: f64, travel: [f64; 2], reference: f64, motor: Motor| JointPlant {
            start_mm,
            hard_stops_mm: [travel[0] - 3.0, travel[1] + 3.0],
            limit_switches_mm: travel,
            reference_switch_mm: reference,
            reference_direction: 1.0,
            motor,
        };
        let (speed, accel) = self.joint_limits();
        let joints = match self.model {
            pkm_kinematics::Machine::Pn101 => vec![
                joint(-10.0, [-60.0, 60.0], 55.0, stepper(speed, accel)),
                joint(5.0, [-60.0, 60.0], 55.0, stepper(speed, accel)),
                JointPlant {
                    reference_direction: -1.0,
                    ..joint(12.0, [-60.0, 60.0], -55.0, stepper(speed, accel))
                },
            ],
            pkm_kinematics::Machine::Hexapod => vec![
                joint(
                    745.0,
                    [400.0, 1000.0],
                    765.0,
                    Motor {
                        stepper: None,
                        dc: Some(DcMotor {
                            v_max_mm_s: 40.0,
                            tau_s: 0.05,
                            counts_per_mm: 1000.0,
                        }),
                    }
                );
                6
            ],
            _ => vec![
                joint(-10.0, [-150.0, 150.0], 0.0, stepper(speed, accel)),
                joint(-8.0, [-150.0, 150.0], 0.0, stepper(speed, accel)),
                joint(-5.0, [-100.0, 100.0], 0.0, stepper(speed, accel)),
            ],
        };
        PlantConfig {
            step_us: 1000,
            mechanism: true,
            joints,
            wiring: super::harness::default_wiring(self),
        }
    }
}
