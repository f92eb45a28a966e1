//! The mechanism in its pose for the operator's screen: the machine's kinematics draws its
//! links at the measured joints of each frame (off the cyclic path, in the server's task).

use pkm_kinematics::Kinematics;

use crate::image::Value;
use crate::runtime::plc::Plc;

/// A machine the screen can draw: the composition gives the configured machine's.
pub trait Drawable {
    /// The machine's kinematics, with the names of the variables that hold its measured joint
    /// positions; `None` where it has none.
    fn drawing(&self) -> Option<(Box<dyn Kinematics>, Vec<&'static str>)>;
}

/// The drawing of one machine.
pub struct Mechanism {
    kinematics: Box<dyn Kinematics>,
    /// The image indices of the measured joint positions.
    joints: Vec<usize>,
    links: Vec<[[f64; 3]; 2]>,
    /// The links in the middle of every joint's range: the screen lays its views out by them
    /// before the machine is referenced (and drawn).
    sample: Vec<[[f64; 3]; 2]>,
}

impl Mechanism {
    /// The drawing of `machine` as `plc` declares its variables, if its kinematics draws one.
    pub fn of(machine: &impl Drawable, plc: &Plc) -> Option<Mechanism> {
        let (kinematics, joint_vars) = machine.drawing()?;
        let joints = joint_vars
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
            sample: links.clone(),
            links,
        })
    }

    /// The links in the middle of every joint's range (not a pose the machine is in).
    pub fn sample(&self) -> &[[[f64; 3]; 2]] {
        &self.sample
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
