//! Engineering units of process-image variables, where the name tells them: the machines name
//! their variables by one convention (`JOINTn_POSITION` in mm, `TOOL_A` in degrees, `…_S` in
//! seconds; see the kinematics spec), so the unit follows from the name. A variable whose name
//! does not tell (a count, a PWM duty, a flag) has none.

/// A unit as OPC UA's EUInformation gives it: the UNECE Recommendation 20 common code, its
/// symbol and its name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Unit {
    /// The UNECE common code (`MMT`).
    pub code: &'static str,
    /// The symbol shown (`mm`).
    pub symbol: &'static str,
    /// The unit's name (`millimetre`).
    pub name: &'static str,
}

/// Millimetres.
pub const MM: Unit = Unit {
    code: "MMT",
    symbol: "mm",
    name: "millimetre",
};
/// Millimetres per second.
pub const MM_S: Unit = Unit {
    code: "C16",
    symbol: "mm/s",
    name: "millimetre per second",
};
/// Degrees (of angle).
pub const DEG: Unit = Unit {
    code: "DD",
    symbol: "°",
    name: "degree",
};
/// Seconds.
pub const S: Unit = Unit {
    code: "SEC",
    symbol: "s",
    name: "second",
};
/// Percent.
pub const PERCENT: Unit = Unit {
    code: "P1",
    symbol: "%",
    name: "percent",
};
/// Millimetres per minute (a feed).
pub const MM_MIN: Unit = Unit {
    code: "H81",
    symbol: "mm/min",
    name: "millimetre per minute",
};
/// Revolutions per minute.
pub const RPM: Unit = Unit {
    code: "RPM",
    symbol: "r/min",
    name: "revolutions per minute",
};

/// The namespace OPC UA names the UNECE codes by.
pub const UNECE_NAMESPACE: &str = "http://www.opcfoundation.org/UA/units/un/cefact";

impl Unit {
    /// The code as OPC UA's `UnitId`: its characters' bytes, big-endian (OPC UA Part 8, 5.6.3).
    pub fn unit_id(&self) -> i32 {
        self.code.bytes().fold(0i32, |id, b| (id << 8) | i32::from(b))
    }
}

/// The unit of the variable `name`, where its name tells it.
pub fn of(name: &str) -> Option<Unit> {
    let upper = name.to_ascii_uppercase();
    let n = upper.as_str();
    // Rates first: `…_MM_S` ends in `_S` too.
    if n.ends_with("_MM_S") || n.ends_with("_SETPOINT_VELOCITY") {
        return Some(MM_S);
    }
    if n.ends_with("_OVERRIDE") && n.starts_with("NC_") {
        return Some(PERCENT);
    }
    if n == "SPINDLE_RPM" {
        return Some(RPM);
    }
    if n == "NC_FEED" || n == "NC_FEED_MEASURED" {
        return Some(MM_MIN);
    }
    if n == "NC_DISTANCE_TO_GO" {
        return Some(MM);
    }
    // Pose coordinates: x y z in mm, a b c in degrees.
    let pose = ["TOOL_", "NC_TOOL_", "NC_"]
        .iter()
        .find_map(|p| n.strip_prefix(p).filter(|rest| rest.len() == 1));
    if let Some(axis) = pose {
        return match axis {
            "X" | "Y" | "Z" => Some(MM),
            "A" | "B" | "C" => Some(DEG),
            _ => None,
        };
    }
    if n.ends_with("_MM") {
        return Some(MM);
    }
    if n.starts_with("JOINT") || n.starts_with("NC_JOINT") {
        let lengths = [
            "_POSITION",
            "_SETPOINT",
            "_OFFSET",
            "_REFERENCE",
            "_CAPTURE",
            "_FOLLOWING_ERROR",
            "_FOLLOWING_MAX",
        ];
        if lengths.iter().any(|s| n.ends_with(s)) {
            return Some(MM);
        }
    }
    if n.starts_with("NC_CONTOUR_") {
        return Some(MM);
    }
    if n.ends_with("_S") && !n.ends_with("_CAPTURES") {
        return Some(S);
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_name_tells_the_unit() {
        let cases = [
            ("JOINT3_POSITION", Some(MM)),
            ("JOINT1_SETPOINT", Some(MM)),
            ("JOINT1_SETPOINT_VELOCITY", Some(MM_S)),
            ("JOINT2_FOLLOWING_ERROR", Some(MM)),
            ("NC_JOINT6_FOLLOWING_MAX", Some(MM)),
            ("TOOL_X", Some(MM)),
            ("TOOL_C", Some(DEG)),
            ("NC_A", Some(DEG)),
            ("NC_Z", Some(MM)),
            ("NC_TOOL_B", Some(DEG)),
            ("NC_CONTOUR_RMS", Some(MM)),
            ("NC_TIME_S", Some(S)),
            ("NC_RUN_S", Some(S)),
            ("setpoint_time_s", Some(S)),
            ("capture_left_lower_mm", Some(MM)),
            ("velocity_left_mm_s", Some(MM_S)),
            ("NC_FEED_OVERRIDE", Some(PERCENT)),
            ("SPINDLE_RPM", Some(RPM)),
            ("NC_FEED", Some(MM_MIN)),
            ("NC_FEED_MEASURED", Some(MM_MIN)),
            ("NC_DISTANCE_TO_GO", Some(MM)),
            ("NC_SPINDLE_OVERRIDE", Some(PERCENT)),
            ("TOOL_NUMBER", None),
            ("NC_MESSAGES", None),
            ("JOINT1_CAPTURES", None),
            ("JOINT1_COUNTER", None),
            ("JOINT1_PWM", None),
            ("NC_LINE", None),
            ("NC_STATE", None),
            ("HMI_JOG_X", None),
            ("main_state", None),
        ];
        for (name, unit) in cases {
            assert_eq!(of(name), unit, "{name}");
        }
    }

    #[test]
    fn unit_ids_are_the_codes_bytes() {
        assert_eq!(MM.unit_id(), 0x4D4D54);
        assert_eq!(DEG.unit_id(), 17476);
        assert_eq!(MM_S.unit_id(), 4403510);
    }
}
