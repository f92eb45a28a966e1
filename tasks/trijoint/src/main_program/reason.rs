//! Why the machine is in ERROR: the reasons, their texts and codes, and the switches they name.

use pkm_api::image::Var;

use crate::vars;

/// Why the machine is in ERROR.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reason {
    /// The STOP button.
    Stop,
    /// A limit switch in READY or MOTION (index: left upper, left down, right upper, right down).
    LimitSwitch(usize),
    /// An implausible encoder change (drive 0 left, 1 right).
    EncoderFault(usize),
    /// A motor bridge error (drive).
    BridgeError(usize),
    /// A following error (drive).
    FollowingError(usize),
    /// A cycle time violation reported by the runtime.
    CycleTimeViolation,
    /// The field bus failed beyond its error bound.
    BusFault,
    /// A switch not reached during INIT — in time, or at all because the carriage was blocked
    /// (switch index as for `LimitSwitch`).
    InitTimeout(usize),
    /// The wrong switch during INIT (switch index as for `LimitSwitch`).
    InitWrongSwitch(usize),
    /// A following error while a carriage seeks a switch in INIT (switch index as for
    /// `LimitSwitch`): the carriage is blocked (a switch that never comes lets it run to its hard
    /// stop), or its drive or the link lags.
    InitFollowingError(usize),
    /// The NC program's executor met a pose without joints.
    ProgramFault,
}

/// The limit switches in the original program's order: left upper, left lower, right upper,
/// right lower.
pub(super) const SWITCHES: [Var<bool>; 4] = [
    vars::SWITCHES[0][1],
    vars::SWITCHES[0][0],
    vars::SWITCHES[1][1],
    vars::SWITCHES[1][0],
];

impl Reason {
    /// The reason as users read it.
    pub fn text(self) -> &'static str {
        const LIMIT: [&str; 4] = [
            "limit switch SWITCH_LEFT_UPPER",
            "limit switch SWITCH_LEFT_DOWN",
            "limit switch SWITCH_RIGHT_UPPER",
            "limit switch SWITCH_RIGHT_DOWN",
        ];
        const WRONG: [&str; 4] = [
            "INIT: wrong switch SWITCH_LEFT_UPPER",
            "INIT: wrong switch SWITCH_LEFT_DOWN",
            "INIT: wrong switch SWITCH_RIGHT_UPPER",
            "INIT: wrong switch SWITCH_RIGHT_DOWN",
        ];
        const NOT_REACHED: [&str; 4] = [
            "INIT timeout: SWITCH_LEFT_UPPER not reached",
            "INIT timeout: SWITCH_LEFT_DOWN not reached",
            "INIT timeout: SWITCH_RIGHT_UPPER not reached",
            "INIT timeout: SWITCH_RIGHT_DOWN not reached",
        ];
        const SEEKING: [&str; 4] = [
            "INIT: following error while seeking SWITCH_LEFT_UPPER: the carriage is blocked, or its drive or the link lags",
            "INIT: following error while seeking SWITCH_LEFT_DOWN: the carriage is blocked, or its drive or the link lags",
            "INIT: following error while seeking SWITCH_RIGHT_UPPER: the carriage is blocked, or its drive or the link lags",
            "INIT: following error while seeking SWITCH_RIGHT_DOWN: the carriage is blocked, or its drive or the link lags",
        ];
        const SIDE: [[&str; 2]; 3] = [
            ["encoder fault left", "encoder fault right"],
            ["motor bridge error left", "motor bridge error right"],
            ["following error left", "following error right"],
        ];
        match self {
            Reason::Stop => "STOP",
            Reason::LimitSwitch(i) => LIMIT[i.min(3)],
            Reason::EncoderFault(d) => SIDE[0][d.min(1)],
            Reason::BridgeError(d) => SIDE[1][d.min(1)],
            Reason::FollowingError(d) => SIDE[2][d.min(1)],
            Reason::CycleTimeViolation => "cycle time violation",
            Reason::BusFault => pkm_api::bus::BUS_FAULT_REASON,
            Reason::InitTimeout(i) => NOT_REACHED[i.min(3)],
            Reason::InitWrongSwitch(i) => WRONG[i.min(3)],
            Reason::InitFollowingError(i) => SEEKING[i.min(3)],
            Reason::ProgramFault => {
                "the program's path has no joints here: the executor stands (its check should have refused the program)"
            }
        }
    }

    /// A number for the process image (`error_reason`): 0 is no error.
    pub fn code(self) -> i16 {
        match self {
            Reason::Stop => 1,
            Reason::LimitSwitch(i) => 10 + i as i16,
            Reason::EncoderFault(d) => 20 + d as i16,
            Reason::BridgeError(d) => 30 + d as i16,
            Reason::FollowingError(d) => 40 + d as i16,
            Reason::CycleTimeViolation => 50,
            Reason::BusFault => 55,
            Reason::InitTimeout(i) => 60 + i as i16,
            Reason::InitWrongSwitch(i) => 70 + i as i16,
            Reason::InitFollowingError(i) => 90 + i as i16,
            Reason::ProgramFault => 80,
        }
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
        for i in 0..4 {
            assert_eq!(ReasonClass::of(Reason::LimitSwitch(i).code()), ReasonClass::LimitSwitch);
            for other in [
                Reason::InitTimeout(i),
                Reason::InitWrongSwitch(i),
                Reason::InitFollowingError(i),
            ] {
                assert_eq!(ReasonClass::of(other.code()), ReasonClass::Other, "{other:?}");
            }
        }
        for d in 0..2 {
            assert_eq!(
                ReasonClass::of(Reason::EncoderFault(d).code()),
                ReasonClass::EncoderFault
            );
            assert_eq!(ReasonClass::of(Reason::BridgeError(d).code()), ReasonClass::Other);
            assert_eq!(ReasonClass::of(Reason::FollowingError(d).code()), ReasonClass::Other);
        }
        assert_eq!(ReasonClass::of(Reason::Stop.code()), ReasonClass::Stop);
        assert_eq!(
            ReasonClass::of(Reason::CycleTimeViolation.code()),
            ReasonClass::CycleTime
        );
        assert_eq!(ReasonClass::of(Reason::BusFault.code()), ReasonClass::BusFault);
        assert_eq!(ReasonClass::of(Reason::ProgramFault.code()), ReasonClass::Other);
    }
}
