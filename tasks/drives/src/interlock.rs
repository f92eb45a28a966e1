//! The fast interlock: the rule that sets every drive output of a machine to zero in the same
//! fast cycle as its cause (the original B&R program reacted only in its 50 ms task), and the
//! following-error supervision that feeds it.

/// What the interlock looks at, once per fast cycle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct InterlockInputs {
    /// A STOP button (the panel's or the joystick's) is pressed.
    pub stop: bool,
    /// A limit switch is active.
    pub limit_switch: bool,
    /// Limit switches are expected now and do not stop the drives: referencing drives onto them,
    /// and an operator may jog off one with the limits overridden.
    pub switches_expected: bool,
    /// A fault: the bus, a motor bridge, an encoder.
    pub fault: bool,
    /// The main program enables the drives (a state that drives, and its enable).
    pub enabled: bool,
}

impl InterlockInputs {
    /// Whether the drive outputs must be zero this cycle (before following errors are counted).
    pub fn engaged(&self) -> bool {
        self.stop || (self.limit_switch && !self.switches_expected) || self.fault || !self.enabled
    }
}

/// One drive's following-error flag this cycle: latched while the drives stay enabled (the main
/// program turns it into ERROR, which disables them), newly set when the error exceeds `bound_mm`
/// while the drive is regulated (not interlocked).
pub fn following_error(enabled: bool, latched: bool, interlocked: bool, error_mm: f64, bound_mm: f64) -> bool {
    enabled && (latched || (!interlocked && error_mm.abs() > bound_mm))
}

#[cfg(test)]
mod tests {
    use super::*;

    const DRIVING: InterlockInputs = InterlockInputs {
        stop: false,
        limit_switch: false,
        switches_expected: false,
        fault: false,
        enabled: true,
    };

    #[test]
    fn each_cause_engages_it() {
        assert!(!DRIVING.engaged());
        assert!(InterlockInputs { stop: true, ..DRIVING }.engaged());
        assert!(InterlockInputs { fault: true, ..DRIVING }.engaged());
        assert!(
            InterlockInputs {
                enabled: false,
                ..DRIVING
            }
            .engaged()
        );
        assert!(
            InterlockInputs {
                limit_switch: true,
                ..DRIVING
            }
            .engaged()
        );
    }

    #[test]
    fn an_expected_switch_does_not_but_stop_still_does() {
        let referencing = InterlockInputs {
            limit_switch: true,
            switches_expected: true,
            ..DRIVING
        };
        assert!(!referencing.engaged());
        assert!(
            InterlockInputs {
                stop: true,
                ..referencing
            }
            .engaged()
        );
    }

    #[test]
    fn a_following_error_latches_until_disabled() {
        assert!(!following_error(true, false, false, 4.9, 5.0));
        assert!(following_error(true, false, false, -5.1, 5.0));
        // Not newly found while interlocked (the drive is not regulated), but kept once found.
        assert!(!following_error(true, false, true, 9.0, 5.0));
        assert!(following_error(true, true, true, 0.0, 5.0));
        assert!(!following_error(false, true, false, 9.0, 5.0));
    }
}
