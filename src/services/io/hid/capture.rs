//! A capture file read whole into the joystick's states on the simulated clock (virtual time).

use std::path::Path;

use super::JoystickState;
use crate::services::io::joystick::{Decoder, EVENT_SIZE, JoystickMapping, parse_events};

/// The most a capture file may hold for virtual time (256 MiB: 11 million events, days of
/// operator input).
pub const MAX_CAPTURE_BYTES: u64 = 256 << 20;

/// Why a capture file cannot be played.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// It cannot be opened (or is not a regular file).
    #[error("{path}: {error} (in virtual time --joystick plays a capture file; a device or FIFO needs real time)")]
    Open {
        /// The file.
        path: String,
        /// Why.
        error: std::io::Error,
    },
    /// It cannot be read, or is larger than [`MAX_CAPTURE_BYTES`].
    #[error("{path}: {error}")]
    Read {
        /// The file.
        path: String,
        /// Why.
        error: std::io::Error,
    },
    /// Its length is not a whole number of records.
    #[error("{path}: {len} bytes is not a whole number of {EVENT_SIZE}-byte input_event records")]
    Truncated {
        /// The file.
        path: String,
        /// Its length in bytes.
        len: usize,
    },
}

/// Reads a capture file (raw `struct input_event` records) into the joystick's states on the
/// simulated clock: connected and at rest at t = 0; each report at its timestamp's distance from
/// the first event's (a timestamp earlier than the one before counts as that one); disconnected
/// right after the last. Only a regular file is a capture: a device or FIFO needs real time.
pub fn load_capture(path: &Path, mapping: &JoystickMapping) -> Result<Vec<(u64, JoystickState)>, CaptureError> {
    let shown = || path.display().to_string();
    let file =
        crate::runtime::files::open_regular(path).map_err(|error| CaptureError::Open { path: shown(), error })?;
    let bytes = crate::runtime::files::read_to_limit(file, MAX_CAPTURE_BYTES)
        .map_err(|error| CaptureError::Read { path: shown(), error })?;
    if bytes.len() % EVENT_SIZE != 0 {
        return Err(CaptureError::Truncated {
            path: shown(),
            len: bytes.len(),
        });
    }
    let (events, _) = parse_events(&bytes);
    let mut decoder = Decoder::new(mapping.clone(), None);
    let mut states = vec![(0, JoystickState::connected(decoder.command()))];
    let first_us = events.first().map_or(0, |e| e.time_us);
    let mut t_ns = 0u64;
    for e in &events {
        let since = u64::try_from(e.time_us.saturating_sub(first_us)).unwrap_or(0);
        t_ns = t_ns.max(since.saturating_mul(1000));
        if let Some(c) = decoder.apply(e) {
            states.push((t_ns, JoystickState::connected(c)));
        }
    }
    // Disconnected at its end, as a capture played in real time is; a cycle later than the
    // last report, so that report is seen.
    states.push((t_ns.saturating_add(1), JoystickState::DISCONNECTED));
    Ok(states)
}
