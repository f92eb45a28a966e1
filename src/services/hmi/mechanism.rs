//! The mechanism in its pose for the operator's screen: the machine's kinematics draws its
//! links at the measured joints of each frame (off the cyclic path, in the server's task).

use pkm_kinematics::Kinematics;

use crate::image::Value;
use crate::runtime::plc::Plc;

/// A machine the screen can draw: the composition gives the configured machine's.
pub trait Drawable {
    /// How the machine is drawn; `None` where it has no kinematics.
    fn drawing(&self) -> Option<Drawing>;
}

/// What draws a machine.
pub struct Drawing {
    /// Its kinematics (the mechanism frame).
    pub kinematics: Box<dyn Kinematics>,
    /// The variables that hold its measured joint positions.
    pub joints: Vec<&'static str>,
    /// The machine frame's origin in the mechanism frame (x y z, mm): the tool's positions and
    /// the programs' paths are in the machine frame, the links are moved into it.
    pub origin: [f64; 3],
}

/// The drawing of one machine.
pub struct Mechanism {
    kinematics: Box<dyn Kinematics>,
    /// The image indices of the measured joint positions.
    joints: Vec<usize>,
    links: Vec<[[f64; 3]; 2]>,
    /// The machine frame's origin in the mechanism frame ([`Drawing::origin`]).
    origin: [f64; 3],
    /// The links in the middle of every joint's range: the screen lays its views out by them
    /// before the machine is referenced (and drawn).
    sample: Vec<[[f64; 3]; 2]>,
}

impl Mechanism {
    /// The drawing of `machine` as `plc` declares its variables, if its kinematics draws one.
    pub fn of(machine: &impl Drawable, plc: &Plc) -> Option<Mechanism> {
        let Drawing {
            kinematics,
            joints: joint_vars,
            origin,
        } = machine.drawing()?;
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
        into_machine_frame(&mut links, origin);
        Some(Mechanism {
            kinematics,
            joints,
            origin,
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
        if !self.kinematics.links(&q[..n], &mut self.links) {
            return None;
        }
        into_machine_frame(&mut self.links, self.origin);
        Some(self.links.as_slice())
    }
}

/// Moves `links` from the mechanism frame into the machine frame, whose origin is `origin`.
fn into_machine_frame(links: &mut [[[f64; 3]; 2]], origin: [f64; 3]) {
    for point in links.iter_mut().flatten() {
        for (c, o) in point.iter_mut().zip(origin) {
            *c -= o;
        }
    }
}
