//! Kinematics of the four machine models of docs/kinematics.md behind one trait.
//!
//! Units at every interface: millimetres and degrees; radians only inside. Poses and joints are
//! slices of length [`Kinematics::dof`] in the mechanism frame (docs/kinematics.md). Nothing here allocates
//! per call, and every failure is an error value that says which condition failed — never NaN,
//! never a panic.

pub mod frame;
pub mod hexapod;
pub mod linalg;
pub mod ox;
pub mod pn101;
pub mod trijoint;
pub mod workspace;

use pkm_api::problem::Problem;
use serde::Deserialize;

pub use linalg::{MAX as MAX_DOF, Mat};

/// The machine models.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Machine {
    /// TRIJOINT 900H lab model (planar, 2 joints): the machine of the B&R application.
    Trijoint,
    /// pn101 (spatial 3-DOF parallel mechanism).
    Pn101,
    /// O-X glide in the crossed X configuration (2-DOF parallel + 1 serial axis).
    OxX,
    /// O-X glide in the extended O configuration.
    OxO,
    /// Stewart–Gough hexapod (6 struts).
    Hexapod,
}

impl Machine {
    /// Every machine.
    pub const ALL: [Machine; 5] = [
        Machine::Trijoint,
        Machine::Pn101,
        Machine::OxX,
        Machine::OxO,
        Machine::Hexapod,
    ];

    /// The machine of that name (as [`Machine::name`] gives it), if there is one.
    pub fn from_name(name: &str) -> Option<Machine> {
        Machine::ALL.into_iter().find(|m| m.name() == name)
    }

    /// The name used on the command line and in JSON.
    pub fn name(self) -> &'static str {
        match self {
            Machine::Trijoint => "trijoint",
            Machine::Pn101 => "pn101",
            Machine::OxX => "ox-x",
            Machine::OxO => "ox-o",
            Machine::Hexapod => "hexapod",
        }
    }
}

/// Why a kinematic transformation has no answer.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum KinError {
    /// An input is NaN or infinite.
    #[error("{0} is not a finite number")]
    NotFinite(&'static str),
    /// The pose cannot be reached by the mechanism.
    #[error("pose unreachable: {0}")]
    Unreachable(&'static str),
    /// A joint value lies outside the joint's travel.
    #[error("joint {joint} = {value:.6} mm is outside its travel {min} … {max} mm")]
    JointOutOfRange {
        /// 1-based joint number.
        joint: usize,
        /// The value.
        value: f64,
        /// Lower end of the travel.
        min: f64,
        /// Upper end of the travel.
        max: f64,
    },
    /// The joints cannot be assembled (in the assembly mode docs/kinematics.md names).
    #[error("no assembly: {0}")]
    NoAssembly(&'static str),
    /// The configuration is singular.
    #[error("singular configuration: {0}")]
    Singular(&'static str),
    /// Newton's method did not converge.
    #[error(
        "forward kinematics did not converge after {iterations} iterations (largest strut-length error {residual:.3e} mm)"
    )]
    NotConverged {
        /// Iterations done.
        iterations: usize,
        /// Largest strut-length error at the end (mm).
        residual: f64,
    },
    /// Newton's method ran away.
    #[error("forward kinematics diverged: summed strut-length error {error:.1} mm exceeds {bound} mm")]
    Diverged {
        /// Summed strut-length error (mm).
        error: f64,
        /// The configured bound (mm).
        bound: f64,
    },
}

/// The kinematics of one machine.
pub trait Kinematics: Send + Sync {
    /// Which machine this is.
    fn machine(&self) -> Machine;
    /// Number of joints, equal to the number of pose coordinates.
    fn dof(&self) -> usize;
    /// The names of the pose coordinates (mm; degrees for angles).
    fn pose_keys(&self) -> &'static [&'static str];
    /// The travel of each joint, `[min, max]` in mm.
    fn joint_limits(&self) -> &[[f64; 2]];
    /// Pose → joints. Fails if the pose is unreachable or a joint leaves its travel.
    fn inverse(&self, pose: &[f64], joints: &mut [f64]) -> Result<(), KinError>;
    /// Joints → pose. `hint` is a previous pose for iterative methods (the hexapod's Newton
    /// iteration starts there instead of at the home pose).
    fn forward(&self, joints: &[f64], hint: Option<&[f64]>, pose: &mut [f64]) -> Result<(), KinError>;
    /// ∂joints/∂pose at a pose (row i: joint i; columns: pose coordinates, angles in degrees).
    fn inverse_jacobian(&self, pose: &[f64], jinv: &mut Mat) -> Result<(), KinError>;
    /// Scale of each pose coordinate for the singularity measure, so that it is dimensionless
    /// (the hexapod's angles are weighted by a characteristic length). Default: 1.
    fn measure_scale(&self, _coordinate: usize) -> f64 {
        1.0
    }

    /// The mechanism's links at `joints` for a drawing (the operator's screen): line segments
    /// between 3-D points of the mechanism frame (mm), pushed onto `out`. False where this model
    /// draws nothing yet or the joints have no pose.
    fn links(&self, _joints: &[f64], _out: &mut Vec<[[f64; 3]; 2]>) -> bool {
        false
    }

    /// ∂pose/∂joints at a pose (row i: pose coordinate i, columns: joints).
    fn jacobian(&self, pose: &[f64], j: &mut Mat) -> Result<(), KinError> {
        let mut jinv = [0.0; MAX_DOF * MAX_DOF];
        self.inverse_jacobian(pose, &mut jinv)?;
        if linalg::invert(self.dof(), &jinv, j, 1e-12) {
            Ok(())
        } else {
            Err(KinError::Singular("the Jacobian is not invertible"))
        }
    }

    /// Singularity measure at a pose: smallest over largest singular value of the (scaled)
    /// inverse Jacobian, 0 at a singularity, 1 for an isotropic mechanism.
    fn singularity_measure(&self, pose: &[f64]) -> Result<f64, KinError> {
        let n = self.dof();
        let mut jinv = [0.0; MAX_DOF * MAX_DOF];
        self.inverse_jacobian(pose, &mut jinv)?;
        for r in 0..n {
            for c in 0..n {
                jinv[r * MAX_DOF + c] /= self.measure_scale(c);
            }
        }
        let s = linalg::singular_values(n, &jinv);
        Ok(if s[0] > 0.0 { s[n - 1] / s[0] } else { 0.0 })
    }
}

/// Fails with [`KinError::NotFinite`] if any value is NaN or infinite.
pub(crate) fn check_finite(values: &[f64], what: &'static str) -> Result<(), KinError> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(KinError::NotFinite(what))
    }
}

/// How far (mm) a joint may lie outside its travel and still count as inside: the accuracy the
/// spec requires, so that IK at a travel end (which rounding may put at −1e-14) is not refused.
/// Values are never clamped.
pub const LIMIT_TOLERANCE_MM: f64 = 1e-9;

/// Fails with [`KinError::JointOutOfRange`] for the first joint outside its travel.
pub(crate) fn check_limits(limits: &[[f64; 2]], joints: &[f64]) -> Result<(), KinError> {
    for (i, (&q, &[min, max])) in joints.iter().zip(limits).enumerate() {
        if !(min - LIMIT_TOLERANCE_MM..=max + LIMIT_TOLERANCE_MM).contains(&q) {
            return Err(KinError::JointOutOfRange {
                joint: i + 1,
                value: q,
                min,
                max,
            });
        }
    }
    Ok(())
}

/// Parameters of all machines; every section is optional and defaults to the values of docs/kinematics.md.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct KinematicsConfig {
    /// TRIJOINT lab model.
    pub trijoint: trijoint::TrijointParams,
    /// pn101.
    pub pn101: pn101::Pn101Params,
    /// O-X glide, X configuration.
    pub ox_x: ox::OxParams,
    /// O-X glide, O configuration.
    pub ox_o: ox::OxParams,
    /// Hexapod.
    pub hexapod: hexapod::HexapodParams,
}

impl Default for KinematicsConfig {
    /// The defaults of docs/kinematics.md (the O configuration gets its own slider references, see [`ox`]).
    fn default() -> Self {
        KinematicsConfig {
            trijoint: Default::default(),
            pn101: Default::default(),
            ox_x: ox::OxParams::default(),
            ox_o: ox::OxParams::default_o(),
            hexapod: Default::default(),
        }
    }
}

impl KinematicsConfig {
    /// Parses and checks the `kinematics` section of a configuration (`None`: the
    /// defaults); problems carry their full JSON path (`kinematics.trijoint.d`).
    pub fn from_section(section: Option<&serde_json::Value>) -> Result<KinematicsConfig, Vec<Problem>> {
        let config: KinematicsConfig = match section {
            None => KinematicsConfig::default(),
            Some(v) => pkm_api::strict_json::section(v, "kinematics").map_err(|p| vec![p])?,
        };
        let problems = pkm_api::problem::under("kinematics", config.check());
        if problems.is_empty() { Ok(config) } else { Err(problems) }
    }

    /// Checks every parameter; problems have their JSON path below the section.
    pub fn check(&self) -> Vec<Problem> {
        let mut problems = Vec::new();
        self.trijoint.check("trijoint", &mut problems);
        self.pn101.check("pn101", &mut problems);
        self.ox_x.check("ox_x", &mut problems);
        self.ox_o.check("ox_o", &mut problems);
        self.hexapod.check("hexapod", &mut problems);
        problems
    }

    /// The kinematics of `machine` with these parameters (allocates once).
    pub fn build(&self, machine: Machine) -> Box<dyn Kinematics> {
        match machine {
            Machine::Trijoint => Box::new(trijoint::Trijoint::new(&self.trijoint)),
            Machine::Pn101 => Box::new(pn101::Pn101::new(&self.pn101)),
            Machine::OxX => Box::new(ox::OxGlide::new(&self.ox_x, ox::Configuration::X)),
            Machine::OxO => Box::new(ox::OxGlide::new(&self.ox_o, ox::Configuration::O)),
            Machine::Hexapod => Box::new(hexapod::Hexapod::new(&self.hexapod)),
        }
    }
}

/// The largest length or travel end a machine of the papers' scale has (mm): 10 m.
pub const MAX_LENGTH_MM: f64 = pkm_api::machine::NO_WORLD_LIMIT;

/// Helpers for parameter checks.
pub(crate) fn positive(problems: &mut Vec<Problem>, path: &str, value: f64) {
    if !(value.is_finite() && value > 0.0 && value <= MAX_LENGTH_MM) {
        problems.push(Problem::new(
            path.to_string(),
            // Debug formatting: 1e308 reads "1e308", not 309 digits.
            format!("must be a positive length in mm, at most {MAX_LENGTH_MM}, got {value:?}"),
        ));
    }
}

pub(crate) fn travel(problems: &mut Vec<Problem>, path: &str, t: [f64; 2]) {
    if !(t[0].is_finite() && t[1].is_finite() && t[0] < t[1] && t[0].abs().max(t[1].abs()) <= MAX_LENGTH_MM) {
        problems.push(Problem::new(
            path.to_string(),
            format!(
                "travel must be [min, max] with min < max, within ±{MAX_LENGTH_MM} mm, got [{:?}, {:?}]",
                t[0], t[1]
            ),
        ));
    }
}
