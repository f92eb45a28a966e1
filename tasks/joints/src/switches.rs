//! Which inputs carry a machine's limit and reference switches: each joint its own, or (pn101)
//! one input shared by all joints for each kind, which says only that *some* joint tripped it.

use pkm_api::image::Var;

use crate::spec::{Spec, SwitchLayout};
use crate::vars;

/// One limit input.
#[derive(Clone, Copy, Debug)]
pub struct LimitInput {
    /// Its variable.
    pub var: Var<bool>,
    /// The joint it belongs to; `None` when all joints share it.
    pub joint: Option<usize>,
    /// The end of the travel: 0 negative, 1 positive.
    pub end: usize,
}

/// A machine's switch inputs.
#[derive(Clone, Debug)]
pub struct Switches {
    layout: SwitchLayout,
    limits: Vec<LimitInput>,
}

impl Switches {
    /// The switch inputs of `spec`.
    pub fn of(spec: &Spec) -> Switches {
        let limits = match spec.switches {
            SwitchLayout::Shared => (0..2)
                .map(|end| LimitInput {
                    var: vars::SHARED_LIMIT[end],
                    joint: None,
                    end,
                })
                .collect(),
            SwitchLayout::PerJoint => (0..spec.joints())
                .flat_map(|j| {
                    [
                        LimitInput {
                            var: vars::LIMIT_NEG[j],
                            joint: Some(j),
                            end: 0,
                        },
                        LimitInput {
                            var: vars::LIMIT_POS[j],
                            joint: Some(j),
                            end: 1,
                        },
                    ]
                })
                .collect(),
        };
        Switches {
            layout: spec.switches,
            limits,
        }
    }

    /// The limit inputs.
    pub fn limits(&self) -> &[LimitInput] {
        &self.limits
    }

    /// Joint `j`'s reference input.
    pub fn reference(&self, j: usize) -> Var<bool> {
        match self.layout {
            SwitchLayout::Shared => vars::SHARED_REFERENCE,
            SwitchLayout::PerJoint => vars::REFERENCE[j],
        }
    }

    /// Whether the joints share their reference input (then they reference one at a time).
    pub fn shared(&self) -> bool {
        self.layout == SwitchLayout::Shared
    }
}
