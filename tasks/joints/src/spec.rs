//! What the application needs to know of each machine that is not configuration: its kinematic
//! model, its kind of drive, how its switches reach the controller, its built-in files and its
//! defaults (docs/machines.md; the numbers the papers do not give are our choice, and a
//! configuration replaces them).

use pkm_api::machine::EmbeddedFile;
use pkm_api::program::ProgramInfo;
use pkm_kinematics::Machine as Model;

use crate::params::{DcDrive, DrivesParams, JogParams, JointParams, MainParams, Referencing, StepperDrive};

/// How the joints are driven.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DriveKind {
    /// Open-loop steppers on X20-like stepper modules: the emitted steps are the feedback.
    Stepper,
    /// DC motors with incremental encoders behind PWM bridges, PI position control.
    Dc,
}

/// How the limit and reference switches reach the controller.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SwitchLayout {
    /// Every joint's negative limit on one input, the positive ones on a second, the reference
    /// switches on a third (pn101's parallel port).
    Shared,
    /// Each joint its own three inputs.
    PerJoint,
}

/// A joint-driven machine as the application knows it.
pub struct Spec {
    /// The name configurations give (`"machine": NAME`).
    pub name: &'static str,
    /// One line on the machine.
    pub summary: &'static str,
    /// Its kinematic model.
    pub model: Model,
    /// Its drives.
    pub drive: DriveKind,
    /// Its switches.
    pub switches: SwitchLayout,
    /// Its I/O map (io-map/NAME.json), built in.
    pub io_map: EmbeddedFile,
    /// Its configuration (machines/NAME.json), built in.
    pub config: EmbeddedFile,
    /// Its programs: the drive program (fast class) and the main program.
    pub programs: &'static [ProgramInfo; 2],
}

impl std::fmt::Debug for Spec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Spec")
            .field("name", &self.name)
            .field("model", &self.model)
            .field("drive", &self.drive)
            .field("switches", &self.switches)
            .finish_non_exhaustive()
    }
}

impl Spec {
    /// Number of joints.
    pub fn joints(&self) -> usize {
        match self.model {
            Model::Hexapod => 6,
            Model::Trijoint => 2,
            Model::Pn101 | Model::OxX | Model::OxO => 3,
        }
    }

    /// The drive program's defaults.
    pub fn default_drives(&self) -> DrivesParams {
        let n = self.joints();
        match self.drive {
            DriveKind::Stepper => {
                let (speed, accel) = self.joint_limits();
                DrivesParams {
                    steppers: vec![
                        StepperDrive {
                            steps_per_mm: 400.0,
                            kp_per_s: 5.0,
                            // 10 % above the joint's speed, as LinuxCNC advises for its step
                            // generators (the motor pulls out at 1.25×): a set-point at the
                            // joint's speed leaves the regulator room to correct an error; without
                            // it pn101's joints lagged 0.02 mm on arcs.
                            max_speed_mm_s: 1.1 * speed,
                            // The main program plans at the joint's acceleration in 50 ms steps;
                            // the drive ramps each step out within 1.5× that (the motor pulls out
                            // at 2×), so it follows them closely.
                            max_accel_mm_s2: 1.5 * accel,
                            max_following_error_mm: 2.0,
                        };
                        n
                    ],
                    dc: Vec::new(),
                    pwm_period_us: None,
                }
            }
            DriveKind::Dc => DrivesParams {
                steppers: Vec::new(),
                dc: vec![
                    DcDrive {
                        counts_per_mm: 1000.0,
                        max_counts_per_cycle: 2000,
                        // 0.8 duty/mm with the feed-forwards keeps the hexapod's contour within
                        // 0.01 mm on its acceptance program (0.3 left 0.029 mm).
                        kp: 0.8,
                        ki: 1.0,
                        // The simulated strut runs 40 mm/s at full duty.
                        velocity_ff: 1.0 / 40.0,
                        // Its speed lags the duty by τ = 50 ms.
                        accel_ff: 0.05 / 40.0,
                        output_limit: 1.0,
                        max_following_error_mm: 5.0,
                    };
                    n
                ],
                pwm_period_us: Some(50),
            },
        }
    }

    /// Maximal joint speed (mm/s) and acceleration (mm/s²), docs/machines.md.
    pub(crate) fn joint_limits(&self) -> (f64, f64) {
        match self.model {
            Model::Pn101 => (8.0, 40.0),
            Model::Hexapod => (25.0, 200.0),
            _ => (20.0, 100.0),
        }
    }

    /// The main program's defaults.
    pub fn default_main(&self) -> MainParams {
        let (speed, accel) = self.joint_limits();
        let joint = |switch_mm: f64, search: f64| JointParams {
            max_speed_mm_s: speed,
            max_accel_mm_s2: accel,
            reference: Referencing {
                switch_mm,
                direction: 1.0,
                search_speed_mm_s: search,
                latch_speed_mm_s: 0.5,
                back_off_mm: 2.0,
            },
        };
        let reversed = |mut j: JointParams| {
            j.reference.direction = -1.0;
            j
        };
        let pairs = |p: &[[&str; 2]]| p.iter().map(|[a, b]| [a.to_string(), b.to_string()]).collect();
        match self.model {
            Model::Pn101 => MainParams {
                stop_lockout_ms: 500,
                // q3 assembles only up to about +17 mm with q1 = q2 = 0: its switch is at the
                // negative end.
                joints: vec![joint(55.0, 4.0), joint(55.0, 4.0), reversed(joint(-55.0, 4.0))],
                reference_order: vec![vec![1], vec![2], vec![3]],
                search_timeout_s: 60.0,
                soft_limit_margin_mm: 2.0,
                world_limits: vec![[-40.0, 40.0]; 3],
                singularity_threshold: 0.05,
                jog: JogParams {
                    linear_speed_mm_s: 5.0,
                    angular_speed_deg_s: 0.0,
                    accel_mm_s2: 20.0,
                    joint_speed_mm_s: 4.0,
                    axis_pairs: pairs(&[["x", "y"], ["x", "z"]]),
                    dead_zone: 0.05,
                },
            },
            Model::Hexapod => MainParams {
                stop_lockout_ms: 500,
                joints: vec![joint(765.0, 10.0); 6],
                reference_order: vec![vec![1, 2, 3, 4, 5, 6]],
                search_timeout_s: 60.0,
                soft_limit_margin_mm: 2.0,
                world_limits: vec![
                    [-100.0, 100.0],
                    [-100.0, 100.0],
                    [-150.0, 150.0],
                    [-15.0, 15.0],
                    [-15.0, 15.0],
                    [-15.0, 15.0],
                ],
                singularity_threshold: 0.05,
                jog: JogParams {
                    linear_speed_mm_s: 10.0,
                    angular_speed_deg_s: 5.0,
                    accel_mm_s2: 50.0,
                    joint_speed_mm_s: 5.0,
                    axis_pairs: pairs(&[["x", "y"], ["z", "c"], ["a", "b"]]),
                    dead_zone: 0.05,
                },
            },
            _ => MainParams {
                stop_lockout_ms: 500,
                joints: vec![joint(0.0, 10.0); 3],
                reference_order: vec![vec![1, 2], vec![3]],
                search_timeout_s: 60.0,
                soft_limit_margin_mm: 2.0,
                world_limits: vec![[-120.0, 120.0], [-95.0, 95.0], [-120.0, 120.0]],
                singularity_threshold: 0.05,
                jog: JogParams {
                    linear_speed_mm_s: 10.0,
                    angular_speed_deg_s: 0.0,
                    accel_mm_s2: 50.0,
                    joint_speed_mm_s: 5.0,
                    axis_pairs: pairs(&[["x", "z"], ["x", "y"]]),
                    dead_zone: 0.05,
                },
            },
        }
    }
}
