//! The configuration's `joystick` section: which of the device's axes and buttons mean what,
//! with the Linux input codes it names them by. The joystick service (`services::io::joystick`)
//! decodes events with it.

use serde::Deserialize;

use crate::image::Problem;

/// Event types and codes used here (linux/input-event-codes.h).
pub mod codes {
    /// Synchronisation events.
    pub const EV_SYN: u16 = 0;
    /// Keys and buttons.
    pub const EV_KEY: u16 = 1;
    /// Absolute axes.
    pub const EV_ABS: u16 = 3;
    /// End of a consistent set of events.
    pub const SYN_REPORT: u16 = 0;
    /// The kernel dropped events: the state is unknown until the next report.
    pub const SYN_DROPPED: u16 = 3;
    /// Absolute X axis.
    pub const ABS_X: u16 = 0;
    /// Absolute Y axis.
    pub const ABS_Y: u16 = 1;
    /// The trigger button of a joystick.
    pub const BTN_TRIGGER: u16 = 0x120;
    /// The thumb button of a joystick.
    pub const BTN_THUMB: u16 = 0x121;
    /// The second thumb button of a joystick.
    pub const BTN_THUMB2: u16 = 0x122;
    /// The top button of a joystick.
    pub const BTN_TOP: u16 = 0x123;
}

use codes::*;

/// How the joystick maps to the operator's commands: config.json's `joystick` section.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct JoystickMapping {
    /// The axis that drives M's x (`ABS_X` = 0).
    pub x_axis: u16,
    /// The axis that drives M's y (`ABS_Y` = 1).
    pub y_axis: u16,
    /// Invert x.
    pub invert_x: bool,
    /// Invert y (default: pushing the stick away, which most devices report as negative, moves M
    /// up).
    pub invert_y: bool,
    /// Deflections below this fraction of full scale count as centred; above it the output
    /// rises continuously from 0.
    pub dead_zone: f64,
    /// The axes' raw range `[min, max]` when the source does not report it (a capture file);
    /// a device's reported range is used instead.
    pub axis_range: [i32; 2],
    /// A button that acts as STOP, in addition to the panel's STOP button.
    pub stop_button: Option<u16>,
    /// A dead-man button that must be held for the axes to count.
    pub deadman_button: Option<u16>,
    /// The buttons reported as the joystick module's Button01…04 (event codes).
    pub buttons: [u16; 4],
}

impl Default for JoystickMapping {
    fn default() -> Self {
        JoystickMapping {
            x_axis: ABS_X,
            y_axis: ABS_Y,
            invert_x: false,
            invert_y: true,
            dead_zone: 0.08,
            axis_range: [-32768, 32767],
            stop_button: None,
            deadman_button: None,
            buttons: [BTN_TRIGGER, BTN_THUMB, BTN_THUMB2, BTN_TOP],
        }
    }
}

impl JoystickMapping {
    /// Checks the mapping; the problems' paths are below the `joystick` section.
    pub fn check(&self) -> Vec<Problem> {
        let mut p = Vec::new();
        if !(0.0..0.9).contains(&self.dead_zone) {
            p.push(Problem::new(
                "dead_zone",
                format!("must be at least 0 and below 0.9, got {}", self.dead_zone),
            ));
        }
        if self.axis_range[0] >= self.axis_range[1] {
            p.push(Problem::new(
                "axis_range",
                format!("must be [min, max] with min < max, got {:?}", self.axis_range),
            ));
        }
        if self.x_axis == self.y_axis {
            p.push(Problem::new(
                "y_axis",
                format!("must differ from x_axis ({})", self.x_axis),
            ));
        }
        p
    }
}
