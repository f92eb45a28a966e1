//! Joystick input: Linux input events (the records `cat /dev/input/eventN` produces) decoded into
//! the operator's commands — axes scaled to −1…1 with inversion and a dead zone, a STOP button
//! (in addition to the panel's, never instead of it) and an optional dead-man button.
//!
//! Decoding is a plain function of the event stream, so recorded captures test it without a
//! device. Values change only at `SYN_REPORT`: the events between two reports form one
//! consistent set, as the kernel means them.

/// Size of one `struct input_event` on 64-bit Linux: a `timeval` (two i64), type (u16),
/// code (u16), value (i32), native byte order.
pub const EVENT_SIZE: usize = 24;

pub use crate::runtime::config::joystick::{JoystickMapping, codes};

use codes::*;

/// One input event.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InputEvent {
    /// Kernel timestamp (µs).
    pub time_us: i64,
    /// Event type (`EV_*`).
    pub kind: u16,
    /// Event code (`ABS_*`, `BTN_*`, `SYN_*`).
    pub code: u16,
    /// Value.
    pub value: i32,
}

impl InputEvent {
    /// Decodes one record of [`EVENT_SIZE`] bytes.
    pub fn from_bytes(b: &[u8; EVENT_SIZE]) -> InputEvent {
        let i64_at = |o: usize| {
            i64::from_ne_bytes([
                b[o],
                b[o + 1],
                b[o + 2],
                b[o + 3],
                b[o + 4],
                b[o + 5],
                b[o + 6],
                b[o + 7],
            ])
        };
        InputEvent {
            time_us: i64_at(0).saturating_mul(1_000_000).saturating_add(i64_at(8)),
            kind: u16::from_ne_bytes([b[16], b[17]]),
            code: u16::from_ne_bytes([b[18], b[19]]),
            value: i32::from_ne_bytes([b[20], b[21], b[22], b[23]]),
        }
    }

    /// Encodes the event as a record (for captures made by tests and tools).
    pub fn to_bytes(&self) -> [u8; EVENT_SIZE] {
        let mut b = [0u8; EVENT_SIZE];
        b[0..8].copy_from_slice(&(self.time_us.div_euclid(1_000_000)).to_ne_bytes());
        b[8..16].copy_from_slice(&(self.time_us.rem_euclid(1_000_000)).to_ne_bytes());
        b[16..18].copy_from_slice(&self.kind.to_ne_bytes());
        b[18..20].copy_from_slice(&self.code.to_ne_bytes());
        b[20..24].copy_from_slice(&self.value.to_ne_bytes());
        b
    }
}

/// Splits a byte stream into events; returns them and how many bytes they used (a trailing
/// partial record waits for more bytes).
pub fn parse_events(bytes: &[u8]) -> (Vec<InputEvent>, usize) {
    let events: Vec<InputEvent> = bytes
        .chunks_exact(EVENT_SIZE)
        .map(|c| {
            let mut record = [0u8; EVENT_SIZE];
            record.copy_from_slice(c);
            InputEvent::from_bytes(&record)
        })
        .collect();
    let used = events.len() * EVENT_SIZE;
    (events, used)
}

/// The operator's commands from the joystick.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Command {
    /// M's x command, −1…1.
    pub x: f64,
    /// M's y command, −1…1.
    pub y: f64,
    /// The joystick's STOP button is pressed.
    pub stop: bool,
    /// The mapping's `buttons` are pressed.
    pub buttons: [bool; 4],
}

/// Decodes an event stream into [`Command`]s.
#[derive(Clone, Debug)]
pub struct Decoder {
    mapping: JoystickMapping,
    ranges: [[i32; 2]; 2],
    pending_axes: [Option<i32>; 2],
    axes: [i32; 2],
    pending_buttons: Vec<(u16, bool)>,
    stop: bool,
    deadman: bool,
    buttons: [bool; 4],
    dropped: bool,
    command: Command,
}

impl Decoder {
    /// A decoder; `ranges` are the device's reported ranges of the x and y axes, if it reports
    /// them (the mapping's `axis_range` otherwise). The axes start centred.
    pub fn new(mapping: JoystickMapping, ranges: Option<[[i32; 2]; 2]>) -> Decoder {
        let ranges = ranges.unwrap_or([mapping.axis_range; 2]);
        let centre = ranges.map(|[lo, hi]| ((i64::from(lo) + i64::from(hi)) / 2) as i32);
        Decoder {
            mapping,
            ranges,
            pending_axes: [None; 2],
            axes: centre,
            pending_buttons: Vec::new(),
            stop: false,
            deadman: false,
            buttons: [false; 4],
            dropped: false,
            command: Command::default(),
        }
    }

    /// The current command.
    pub fn command(&self) -> Command {
        self.command
    }

    /// Feeds one event; returns the new command when a report completes a set.
    pub fn apply(&mut self, e: &InputEvent) -> Option<Command> {
        match (e.kind, e.code) {
            (EV_ABS, code) if code == self.mapping.x_axis => self.pending_axes[0] = Some(e.value),
            (EV_ABS, code) if code == self.mapping.y_axis => self.pending_axes[1] = Some(e.value),
            // 1 press, 0 release; 2 is auto-repeat of a held key and changes nothing.
            (EV_KEY, code) if e.value == 0 || e.value == 1 => self.pending_buttons.push((code, e.value == 1)),
            (EV_SYN, SYN_DROPPED) => {
                // Events were lost: the state is unknown. Stop until the next full report.
                self.dropped = true;
                self.pending_axes = [None; 2];
                self.pending_buttons.clear();
            }
            (EV_SYN, SYN_REPORT) => return Some(self.report()),
            _ => {}
        }
        None
    }

    fn report(&mut self) -> Command {
        if std::mem::take(&mut self.dropped) {
            self.command = Command {
                x: 0.0,
                y: 0.0,
                stop: self.stop,
                buttons: self.buttons,
            };
            return self.command;
        }
        for (i, v) in self.pending_axes.iter_mut().enumerate() {
            if let Some(v) = v.take() {
                self.axes[i] = v;
            }
        }
        for (code, pressed) in self.pending_buttons.drain(..) {
            if Some(code) == self.mapping.stop_button {
                self.stop = pressed;
            }
            if Some(code) == self.mapping.deadman_button {
                self.deadman = pressed;
            }
            for (i, _) in self.mapping.buttons.iter().enumerate().filter(|(_, b)| **b == code) {
                self.buttons[i] = pressed;
            }
        }
        let enabled = self.mapping.deadman_button.is_none() || self.deadman;
        let axis = |i: usize, invert: bool| {
            let [lo, hi] = self.ranges[i];
            let (lo, hi) = (f64::from(lo), f64::from(hi));
            let centre = (lo + hi) / 2.0;
            let n = ((f64::from(self.axes[i]) - centre) / ((hi - lo) / 2.0)).clamp(-1.0, 1.0);
            let dz = self.mapping.dead_zone;
            let shaped = if n.abs() <= dz {
                0.0
            } else {
                n.signum() * (n.abs() - dz) / (1.0 - dz)
            };
            if invert { -shaped } else { shaped }
        };
        let (x, y) = if enabled {
            (axis(0, self.mapping.invert_x), axis(1, self.mapping.invert_y))
        } else {
            (0.0, 0.0)
        };
        self.command = Command {
            x,
            y,
            stop: self.stop,
            buttons: self.buttons,
        };
        self.command
    }
}
