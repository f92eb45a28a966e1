//! The mechanism in its pose for the operator's screen: the machine's kinematics draws its
//! links at the measured joints of each frame (off the cyclic path, in the server's task).

use pkm_kinematics::{Kinematics, KinematicsConfig, Machine as Model};

use crate::compose::Setup;
use crate::image::Value;
use crate::runtime::plc::Plc;

/// The drawing of one machine.
pub struct Mechanism {
    kinematics: Box<dyn Kinematics>,
    /// The image indices of the measured joint positions.
    joints: Vec<usize>,
    links: Vec<[[f64; 3]; 2]>,
}

impl Mechanism {
    /// The drawing of `setup`'s machine as `plc` declares its variables, if its kinematics
    /// draws one.
    pub fn of(setup: &Setup, plc: &Plc) -> Option<Mechanism> {
        let machine = setup.machine?;
        let motion = machine.motion(&setup.loaded.json).ok()?;
        let config = KinematicsConfig::from_section(setup.loaded.config.kinematics.as_ref()).ok()?;
        let kinematics = config.build(Model::from_name(motion.model)?);
        let joints = motion
            .joint_vars
            .iter()
            .map(|name| plc.vars().index_of(name).map(usize::from))
            .collect::<Option<Vec<usize>>>()?;
        let mut links = Vec::new();
        // Only a model that draws is worth a drawing.
        let probe: Vec<f64> = kinematics
            .joint_limits()
            .iter()
            .map(|[lo, hi]| (lo + hi) / 2.0)
            .collect();
        if !kinematics.links(&probe, &mut links) {
            return None;
        }
        Some(Mechanism {
            kinematics,
            joints,
            links,
        })
    }

    /// The links at the joints of `image`, if they have a pose.
    pub fn links(&mut self, image: &[Value]) -> Option<&[[[f64; 3]; 2]]> {
        let mut q = [0.0; pkm_kinematics::MAX_DOF];
        for (q, &i) in q.iter_mut().zip(&self.joints) {
            *q = match image.get(i) {
                Some(Value::Real(x)) => *x,
                _ => return None,
            };
        }
        self.links.clear();
        let n = self.joints.len();
        self.kinematics
            .links(&q[..n], &mut self.links)
            .then_some(self.links.as_slice())
    }
}
