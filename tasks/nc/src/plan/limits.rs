//! What the planner is given of the machine, and what it says of a program: a block's speed the
//! machine limits, and why a program cannot be planned.

use crate::interp::block::AXES;

/// The machine's limits.
#[derive(Clone, Debug, PartialEq)]
pub struct PlanLimits {
    /// Per joint: speed (mm/s).
    pub joint_speed: Vec<f64>,
    /// Per joint: acceleration (mm/s²).
    pub joint_accel: Vec<f64>,
    /// Per world axis x y z a b c: speed (mm/s, degrees/s), also the speed of rapids.
    pub axis_speed: [f64; 6],
    /// Per world axis: acceleration (mm/s², degrees/s²).
    pub axis_accel: [f64; 6],
}

/// What limits a point's speed below the feed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Limit {
    /// The programmed feed.
    Feed,
    /// A world axis' speed (index in x y z a b c).
    AxisSpeed(usize),
    /// A joint's speed.
    JointSpeed(usize),
    /// A world axis' acceleration on the path's curvature.
    AxisCurvature(usize),
    /// A joint's acceleration on the path's curvature (a corner blend, an arc, the mechanism).
    JointCurvature(usize),
}

impl Limit {
    /// The limit as users read it.
    pub fn text(self) -> String {
        match self {
            Limit::Feed => "the programmed feed".into(),
            Limit::AxisSpeed(c) => format!("the speed of axis {}", AXES[c]),
            Limit::JointSpeed(j) => format!("the speed of joint {}", j + 1),
            Limit::AxisCurvature(c) => format!("the acceleration of axis {} on the curve", AXES[c]),
            Limit::JointCurvature(j) => format!("the acceleration of joint {} on the curve", j + 1),
        }
    }
}

/// A block whose speed the machine limits below its feed.
#[derive(Clone, Debug, PartialEq)]
pub struct Limited {
    /// The program line.
    pub line: usize,
    /// Its feed (mm/min).
    pub programmed_mm_min: f64,
    /// The highest speed any point of it may take (mm/min).
    pub reachable_mm_min: f64,
    /// Why.
    pub why: Limit,
}

/// Why a program cannot be planned.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("line {line}, column {column}: {message}")]
pub struct PlanError {
    /// The program line.
    pub line: usize,
    /// The column of the word that made the move (1-based).
    pub column: usize,
    /// What fails.
    pub message: String,
}
