//! The HID joystick in the process image.
//!
//! A reader thread turns a Linux input device (evdev), a FIFO or a capture file of raw
//! `struct input_event` records into the channels of the I/O map's joystick module (axes, STOP,
//! buttons, connected), through the same decoding as everywhere ([`super::joystick::Decoder`]).
//! [`JoystickBus`] wraps the field bus and writes those channels' variables into the image before
//! every cycle, so the joystick is an input like any other: latched by its task class, recorded in
//! traces, replayed.
//!
//! An unplugged device, a read error or a FIFO whose writer went away publishes "disconnected"
//! with the axes at zero (the machine stops: MOTION → READY) and a warning; the thread then looks
//! for the device again and carries on when it is back (hot-plug). A capture file is played at
//! the pace of its timestamps and is "disconnected" at its end. In virtual time a capture file is
//! played on the simulated clock instead ([`JoystickBus::with_capture`], [`load_capture`]): its
//! first event at t = 0, each further one at its timestamp's distance from the first — the same
//! recorded operator session gives the same run every time, as fast as the CPU allows.
//!
//! Here: what the parts share (the joystick's state, its mailbox, the latency probe). Decoding
//! events into commands is [`super::joystick`]; reading a device, FIFO or capture in real time is
//! `device`; a capture on the simulated clock is `capture`; the bus that lays the channels over
//! the field bus's is `bus`.

mod bus;
mod capture;
mod device;

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

pub use bus::JoystickBus;
pub use capture::{CaptureError, MAX_CAPTURE_BYTES, load_capture};
pub use device::{End, read_records, spawn_reader};

use super::joystick::Command;

/// The name of the joystick's module type in the catalogue.
pub const MODULE_TYPE: &str = "Joystick";

/// Where the joystick comes from (`run --joystick`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum JoystickSpec {
    /// The first joystick or gamepad (the mapping's absolute X and Y axes and joystick buttons),
    /// looked for again every second while there is none.
    Auto,
    /// No joystick: the bus's own joystick channels (the simulated machine's) stay in use.
    None,
    /// An input device (`/dev/input/eventN`), a FIFO or a capture file of raw records.
    Path(PathBuf),
}

impl std::str::FromStr for JoystickSpec {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        Ok(match s {
            "auto" => JoystickSpec::Auto,
            "none" => JoystickSpec::None,
            "" => return Err("give a device, a FILE, auto or none".into()),
            path => JoystickSpec::Path(PathBuf::from(path)),
        })
    }
}

/// The joystick module's channels.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct JoystickState {
    /// M's x command, −1…1.
    pub x: f64,
    /// M's y command, −1…1.
    pub y: f64,
    /// The joystick's STOP button.
    pub stop: bool,
    /// Button01…04.
    pub buttons: [bool; 4],
    /// A device (or capture) is delivering events.
    pub connected: bool,
}

impl JoystickState {
    /// Disconnected: axes at zero, no button.
    pub const DISCONNECTED: JoystickState = JoystickState {
        x: 0.0,
        y: 0.0,
        stop: false,
        buttons: [false; 4],
        connected: false,
    };

    /// A connected joystick's command.
    pub fn connected(c: Command) -> JoystickState {
        JoystickState {
            x: c.x,
            y: c.y,
            stop: c.stop,
            buttons: c.buttons,
            connected: true,
        }
    }
}

/// What the source hands to the cycle.
#[derive(Clone, Copy, Debug, Default)]
struct Published {
    state: JoystickState,
    /// Counts publications, so the cycle can tell a new report from the last one.
    seq: u64,
    /// When it was published (CLOCK_MONOTONIC, ns).
    published_ns: u64,
    /// Whether a source has published at all (before that the bus's own channels stay).
    active: bool,
}

/// The source's end of the joystick mailbox.
pub struct JoystickFeed {
    input: triple_buffer::Input<Published>,
    seq: u64,
}

impl JoystickFeed {
    /// Publishes a new state; the next cycle of the joystick's task class takes it.
    pub fn publish(&mut self, state: JoystickState) {
        self.seq += 1;
        self.input.write(Published {
            state,
            seq: self.seq,
            published_ns: crate::runtime::timing::monotonic_ns(),
            active: true,
        });
    }
}

/// How long events took from their publication to the process image (real-time runs).
#[derive(Clone, Debug)]
pub struct LatencyProbe(Arc<Mutex<Vec<(u64, u64)>>>);

/// The latency figures of a run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LatencySummary {
    /// Reports taken into the process image.
    pub count: usize,
    /// Mean time from publication to the start of the cycle that latched it (ms).
    pub mean_ms: f64,
    /// Longest such time (ms).
    pub max_ms: f64,
}

/// Pairs recorded at most (one per report taken; about 80 minutes at one report per main cycle).
const PROBE_CAPACITY: usize = 100_000;

impl LatencyProbe {
    /// The figures, given the run's epoch (CLOCK_MONOTONIC ns of cycle time 0); `None` before
    /// any report was taken.
    pub fn summary(&self, epoch_ns: u64) -> Option<LatencySummary> {
        let pairs = self.0.lock().ok()?;
        if pairs.is_empty() {
            return None;
        }
        let latencies = pairs
            .iter()
            .map(|&(published, taken_t)| (epoch_ns + taken_t).saturating_sub(published));
        let (sum, max) = latencies.fold((0u64, 0u64), |(s, m), l| (s + l, m.max(l)));
        Some(LatencySummary {
            count: pairs.len(),
            mean_ms: sum as f64 / pairs.len() as f64 / 1e6,
            max_ms: max as f64 / 1e6,
        })
    }
}
