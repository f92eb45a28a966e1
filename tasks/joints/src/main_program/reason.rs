//! Why a joint-driven machine is in ERROR: the reasons, their codes in the process image and
//! their texts, which name the machine's own inputs (a shared limit input says which joints
//! share it).

use crate::switches::Switches;

/// Why the machine is in ERROR.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reason {
    /// The STOP button.
    Stop,
    /// A limit input (index into the machine's limit inputs).
    Limit(usize),
    /// An implausible encoder change (joint).
    EncoderFault(usize),
    /// A motor bridge error (joint).
    BridgeError(usize),
    /// A following error (joint).
    FollowingError(usize),
    /// A cycle time violation reported by the runtime.
    CycleTimeViolation,
    /// The field bus failed beyond its error bound.
    BusFault,
    /// A joint's reference switch not found, or its reference position not reached, in time.
    InitTimeout(usize),
    /// A following error of a joint while it seeks its reference switch in INIT: the joint is
    /// blocked (a switch that never comes lets it run to its hard stop), or its drive or the
    /// link lags.
    InitFollowingError(usize),
    /// A joint's reference input stays on while the joint backs off its switch (pn101: another
    /// joint sits on its own switch, and the shared input cannot say which).
    ReferenceStaysOn(usize),
    /// A joint's search travelled as far as its switch can be from where it began without the
    /// reference input turning on (a switch that does not switch).
    ReferenceNotFound(usize),
    /// A joint's reference input says the other side of its switch than the frame of the last
    /// referencing puts the joint: its position is not known (a fault falsified it), and
    /// referencing does not move on by it.
    ReferenceContradicts(usize),
    /// The NC program's executor met a pose without joints.
    ProgramFault,
}

impl Reason {
    /// A number for the process image (`error_reason`): 0 is no error.
    pub fn code(self) -> i16 {
        let at = |base: i16, i: usize| base + i as i16;
        match self {
            Reason::Stop => 1,
            Reason::EncoderFault(j) => at(20, j),
            Reason::BridgeError(j) => at(30, j),
            Reason::FollowingError(j) => at(40, j),
            Reason::CycleTimeViolation => 50,
            Reason::BusFault => 55,
            Reason::InitTimeout(j) => at(60, j),
            Reason::ReferenceStaysOn(j) => at(70, j),
            Reason::ReferenceContradicts(j) => at(90, j),
            Reason::ReferenceNotFound(j) => at(130, j),
            Reason::InitFollowingError(j) => at(140, j),
            Reason::Limit(k) => at(100, k),
            Reason::ProgramFault => 80,
        }
    }
}

/// The text of [`Reason::ProgramFault`].
pub const PROGRAM_FAULT: &str =
    "the program's path has no joints here: the executor stands (its check should have refused the program)";

/// The texts of every reason a machine can give, made once when the program is created so that
/// entering ERROR allocates nothing.
pub struct ReasonTexts {
    texts: Vec<(Reason, String)>,
}

impl ReasonTexts {
    /// The texts for a machine of `n` joints with `switches`.
    pub fn new(n: usize, switches: &Switches) -> ReasonTexts {
        let mut texts = vec![
            (Reason::Stop, "STOP".to_string()),
            (Reason::CycleTimeViolation, "cycle time violation".to_string()),
            (Reason::BusFault, pkm_api::bus::BUS_FAULT_REASON.to_string()),
            (Reason::ProgramFault, PROGRAM_FAULT.to_string()),
        ];
        for (k, l) in switches.limits().iter().enumerate() {
            let text = match l.joint {
                Some(_) => format!("limit switch {}", l.var.name()),
                None => format!(
                    "limit input {} (shared by joints {}: it does not say which; acknowledge, then jog off in joint mode with BUTTON_OVERRIDE held)",
                    l.var.name(),
                    (1..=n).map(|j| j.to_string()).collect::<Vec<_>>().join(", ")
                ),
            };
            texts.push((Reason::Limit(k), text));
        }
        for j in 0..n {
            let reference = switches.reference(j).name();
            texts.push((Reason::EncoderFault(j), format!("encoder fault joint {}", j + 1)));
            texts.push((Reason::BridgeError(j), format!("motor bridge error joint {}", j + 1)));
            texts.push((Reason::FollowingError(j), format!("following error joint {}", j + 1)));
            texts.push((
                Reason::InitTimeout(j),
                format!(
                    "INIT timeout: joint {} did not reach its reference ({reference})",
                    j + 1
                ),
            ));
            texts.push((
                Reason::InitFollowingError(j),
                format!(
                    "INIT: following error joint {} while seeking its reference ({reference}): the joint is blocked, or its drive or the link lags",
                    j + 1
                ),
            ));
            texts.push((
                Reason::ReferenceStaysOn(j),
                format!(
                    "INIT: reference input {reference} stays on while joint {} backs off its switch{}",
                    j + 1,
                    if switches.shared() {
                        ": another joint is on its switch (the shared input cannot say which); the joint went back to where it started. \
                         Acknowledge, then hold BUTTON_OVERRIDE and jog the joint on its switch off it in joint mode"
                    } else {
                        " (a switch stuck on?); the joint went back to where it started"
                    }
                ),
            ));
            texts.push((
                Reason::ReferenceNotFound(j),
                format!(
                    "INIT: joint {} searched as far as its reference switch can be without {reference} turning on (a switch that does not switch?)",
                    j + 1
                ),
            ));
            texts.push((
                Reason::ReferenceContradicts(j),
                format!(
                    "reference input {reference} contradicts joint {}'s position in the last referencing's frame: the positions are not known; {}",
                    j + 1,
                    if switches.shared() {
                        // One joint at a time from a pose far from home, the mechanism can jam.
                        "bring the machine near its home pose (drives off: by hand) and acknowledge to reference it joint by joint"
                    } else {
                        "acknowledge to reference from where the joints stand"
                    }
                ),
            ));
        }
        ReasonTexts { texts }
    }

    /// The text of `reason`.
    pub fn text(&self, reason: Reason) -> &str {
        self.texts
            .iter()
            .find(|(r, _)| *r == reason)
            .map_or("unknown reason", |(_, t)| t.as_str())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pkm_api::machine::ReasonClass;

    /// The codes follow the classes every machine's codes follow (OPC UA's conditions tell the
    /// causes apart by them).
    #[test]
    fn every_reason_code_is_in_its_class() {
        for j in 0..6 {
            assert_eq!(ReasonClass::of(Reason::Limit(j).code()), ReasonClass::LimitSwitch);
            assert_eq!(
                ReasonClass::of(Reason::EncoderFault(j).code()),
                ReasonClass::EncoderFault
            );
            for other in [
                Reason::BridgeError(j),
                Reason::FollowingError(j),
                Reason::InitTimeout(j),
                Reason::InitFollowingError(j),
                Reason::ReferenceStaysOn(j),
                Reason::ReferenceNotFound(j),
                Reason::ReferenceContradicts(j),
            ] {
                assert_eq!(ReasonClass::of(other.code()), ReasonClass::Other, "{other:?}");
            }
        }
        // Twelve limit inputs at most (two per joint).
        assert_eq!(ReasonClass::of(Reason::Limit(11).code()), ReasonClass::LimitSwitch);
        assert_eq!(ReasonClass::of(Reason::Stop.code()), ReasonClass::Stop);
        assert_eq!(
            ReasonClass::of(Reason::CycleTimeViolation.code()),
            ReasonClass::CycleTime
        );
        assert_eq!(ReasonClass::of(Reason::BusFault.code()), ReasonClass::BusFault);
        assert_eq!(ReasonClass::of(Reason::ProgramFault.code()), ReasonClass::Other);
    }
}
