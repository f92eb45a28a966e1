//! The machine frame of docs/kinematics.md: the mechanism frame shifted so that the tool's home
//! position is the origin. Operators, jogs and NC programs work in it; the formulas stay in the
//! mechanism frame. Only the translational coordinates are shifted (x, y, z); angles (a, b, c)
//! are the mechanism's.

use crate::{KinError, Kinematics, MAX_DOF};

/// Where a machine's home is given.
#[derive(Clone, Copy, Debug)]
pub enum Home<'a> {
    /// By its joints (pn101 and the O-X glide: all joints at their reference, FK(0, …)).
    Joints(&'a [f64]),
    /// By its pose in the mechanism frame (the hexapod's home pose).
    Pose(&'a [f64]),
}

/// A machine's kinematics seen in its machine frame.
pub struct MachineFrame {
    kin: Box<dyn Kinematics>,
    home_joints: [f64; MAX_DOF],
    /// The home pose in the mechanism frame.
    home_pose: [f64; MAX_DOF],
    /// Whether each pose coordinate is translational (shifted) or an angle (not).
    shifted: [bool; MAX_DOF],
}

impl MachineFrame {
    /// The frame whose origin is `home`. Fails if the home is not a pose of the machine.
    pub fn new(kin: Box<dyn Kinematics>, home: Home<'_>) -> Result<MachineFrame, KinError> {
        let n = kin.dof();
        let mut home_joints = [0.0; MAX_DOF];
        let mut home_pose = [0.0; MAX_DOF];
        match home {
            Home::Joints(q) => {
                home_joints[..n].copy_from_slice(&q[..n]);
                kin.forward(&home_joints[..n], None, &mut home_pose[..n])?;
            }
            Home::Pose(x) => {
                home_pose[..n].copy_from_slice(&x[..n]);
                kin.inverse(&home_pose[..n], &mut home_joints[..n])?;
            }
        }
        let mut shifted = [false; MAX_DOF];
        for (s, key) in shifted.iter_mut().zip(kin.pose_keys()) {
            *s = matches!(*key, "x" | "y" | "z");
        }
        Ok(MachineFrame {
            kin,
            home_joints,
            home_pose,
            shifted,
        })
    }

    /// The frame of `model` with the default parameters of docs/kinematics.md and its default home: pn101
    /// and the O-X glide at their joints' zeros (the original controllers' home point), the
    /// hexapod at its home pose, the TRIJOINT at the middle of its carriages' travel.
    pub fn default_for(model: crate::Machine) -> Result<MachineFrame, KinError> {
        let config = crate::KinematicsConfig::default();
        let kin = config.build(model);
        match model {
            crate::Machine::Hexapod => MachineFrame::new(kin, Home::Pose(&config.hexapod.home)),
            crate::Machine::Trijoint => {
                let t = &config.trijoint;
                let middle = [
                    (t.h1_travel[0] + t.h1_travel[1]) / 2.0,
                    (t.h2_travel[0] + t.h2_travel[1]) / 2.0,
                ];
                MachineFrame::new(kin, Home::Joints(&middle))
            }
            _ => MachineFrame::new(kin, Home::Joints(&[0.0; MAX_DOF])),
        }
    }

    /// The kinematics in the mechanism frame.
    pub fn kinematics(&self) -> &dyn Kinematics {
        self.kin.as_ref()
    }

    /// Number of joints and of pose coordinates.
    pub fn dof(&self) -> usize {
        self.kin.dof()
    }

    /// The joints at home.
    pub fn home_joints(&self) -> &[f64] {
        &self.home_joints[..self.dof()]
    }

    /// The home pose in the mechanism frame.
    pub fn home_pose(&self) -> &[f64] {
        &self.home_pose[..self.dof()]
    }

    /// Joints → tool pose in the machine frame. `hint` is a previous machine-frame pose (the
    /// hexapod's Newton iteration starts there).
    pub fn forward(&self, joints: &[f64], hint: Option<&[f64]>, pose: &mut [f64]) -> Result<(), KinError> {
        let n = self.dof();
        let mut mechanism_hint = [0.0; MAX_DOF];
        let hint = hint.map(|h| {
            self.to_mechanism(h, &mut mechanism_hint[..n]);
            &mechanism_hint[..n]
        });
        self.kin.forward(joints, hint, pose)?;
        for ((c, home), shifted) in pose.iter_mut().zip(&self.home_pose[..n]).zip(&self.shifted) {
            if *shifted {
                *c -= home;
            }
        }
        Ok(())
    }

    /// Tool pose in the machine frame → joints.
    pub fn inverse(&self, pose: &[f64], joints: &mut [f64]) -> Result<(), KinError> {
        let n = self.dof();
        let mut mechanism = [0.0; MAX_DOF];
        self.to_mechanism(pose, &mut mechanism[..n]);
        self.kin.inverse(&mechanism[..n], joints)
    }

    /// The singularity measure at a machine-frame pose.
    pub fn singularity_measure(&self, pose: &[f64]) -> Result<f64, KinError> {
        let n = self.dof();
        let mut mechanism = [0.0; MAX_DOF];
        self.to_mechanism(pose, &mut mechanism[..n]);
        self.kin.singularity_measure(&mechanism[..n])
    }

    /// A machine-frame pose in the mechanism frame.
    pub fn to_mechanism(&self, pose: &[f64], out: &mut [f64]) {
        for i in 0..self.dof() {
            out[i] = if self.shifted[i] {
                pose[i] + self.home_pose[i]
            } else {
                pose[i]
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_models_default_frame_has_its_home_at_the_origin() {
        for model in crate::Machine::ALL {
            let f = MachineFrame::default_for(model).unwrap_or_else(|e| panic!("{model:?}: {e}"));
            let n = f.dof();
            let mut pose = [1.0; MAX_DOF];
            f.forward(f.home_joints(), None, &mut pose[..n])
                .expect("home assembles");
            for (c, key) in f.kinematics().pose_keys().iter().enumerate() {
                let home = if matches!(*key, "x" | "y" | "z") {
                    0.0
                } else {
                    f.home_pose()[c]
                };
                assert!((pose[c] - home).abs() < 1e-9, "{model:?} {key}: {}", pose[c]);
            }
        }
    }
}
