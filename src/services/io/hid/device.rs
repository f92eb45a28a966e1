//! The reader thread: a Linux input device (evdev), a FIFO or a capture file played in real
//! time, decoded and published to the joystick's mailbox; hot-plug and "disconnected" handling.

use std::fs::File;
use std::io::{self, Read};
use std::os::unix::fs::FileTypeExt;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use super::{JoystickFeed, JoystickSpec, JoystickState};
use crate::services::io::joystick::{Decoder, EVENT_SIZE, InputEvent, JoystickMapping, parse_events};

/// Why a source stopped delivering.
#[derive(Debug, PartialEq, Eq)]
pub enum End {
    /// A capture file was played to its end.
    CaptureEnded,
    /// The device went away, a read failed, or a FIFO's writer closed it (why).
    Lost(String),
}

/// An opened source.
enum Source {
    Device {
        device: Box<evdev::raw_stream::RawDevice>,
        ranges: [[i32; 2]; 2],
    },
    Fifo(File),
    Capture(File),
}

/// Starts the reader thread for `spec` (nothing for `None`); it runs until `stop` is set and
/// its source next delivers, or for ever (it holds nothing that needs closing).
pub fn spawn_reader(
    spec: JoystickSpec,
    mapping: JoystickMapping,
    feed: JoystickFeed,
    stop: Arc<AtomicBool>,
) -> io::Result<()> {
    if spec == JoystickSpec::None {
        return Ok(());
    }
    std::thread::Builder::new()
        .name("joystick".into())
        .spawn(move || run_reader(&spec, &mapping, feed, &stop))?;
    Ok(())
}

fn run_reader(spec: &JoystickSpec, mapping: &JoystickMapping, mut feed: JoystickFeed, stop: &AtomicBool) {
    let mut said_missing = false;
    while !stop.load(Ordering::Relaxed) {
        let opened = match spec {
            JoystickSpec::Auto => find_device(mapping),
            JoystickSpec::Path(p) => open(p, mapping).map(|s| (p.clone(), s)),
            JoystickSpec::None => return,
        };
        let (path, source) = match opened {
            Ok(found) => found,
            Err(e) => {
                if !said_missing {
                    said_missing = true;
                    match spec {
                        JoystickSpec::Auto => {
                            tracing::info!("joystick: {e}: panel buttons only (looking again every second)")
                        }
                        _ => tracing::warn!("joystick: {e} (trying again every second)"),
                    }
                }
                std::thread::sleep(Duration::from_secs(1));
                continue;
            }
        };
        said_missing = false;
        let what = match &source {
            Source::Device { device, .. } => format!("device {} \"{}\"", path.display(), device.name().unwrap_or("?")),
            Source::Fifo(_) => format!("FIFO {}", path.display()),
            Source::Capture(_) => format!("capture {}", path.display()),
        };
        tracing::info!("joystick: reading {what}");
        let end = match source {
            Source::Device { mut device, ranges } => read_device(&mut device, mapping, ranges, &mut feed, stop),
            Source::Fifo(file) => read_records(file, mapping, false, &mut feed, stop),
            Source::Capture(file) => read_records(file, mapping, true, &mut feed, stop),
        };
        feed.publish(JoystickState::DISCONNECTED);
        match end {
            End::CaptureEnded => {
                tracing::info!("joystick: {what} ended; the joystick counts as disconnected");
                return;
            }
            End::Lost(why) => {
                if stop.load(Ordering::Relaxed) {
                    return;
                }
                tracing::warn!("joystick: {what}: {why}: disconnected, axes at zero; waiting for it to come back");
                std::thread::sleep(Duration::from_millis(500));
            }
        }
    }
}

/// Why no joystick could be opened (logged; the reader tries again every second).
#[derive(Debug, thiserror::Error)]
enum OpenError {
    /// `auto` found none.
    #[error("no joystick or gamepad (absolute X and Y axes, joystick buttons) in /dev/input{hint}")]
    NoJoystick {
        /// Why, perhaps (event devices this user may not open).
        hint: String,
    },
    /// The named path could not be opened.
    #[error("{path}: {source}")]
    Io {
        /// The path.
        path: String,
        /// The error.
        source: io::Error,
    },
    /// The named device lacks the mapped axes.
    #[error("{path}: the device has no absolute axes {x} and {y} (see joystick.x_axis, joystick.y_axis)")]
    NoAxes {
        /// The device.
        path: String,
        /// The mapped x axis.
        x: u16,
        /// The mapped y axis.
        y: u16,
    },
    /// The named path is none of the three.
    #[error("{path}: not an input device, FIFO or capture file")]
    NotInput {
        /// The path.
        path: String,
    },
}

/// The first device (by path) with the mapping's absolute X and Y axes.
fn find_device(mapping: &JoystickMapping) -> Result<(PathBuf, Source), OpenError> {
    let opened: Vec<(PathBuf, evdev::raw_stream::RawDevice)> = evdev::raw_stream::enumerate().collect();
    let opened_count = opened.len();
    let mut found: Vec<_> = opened
        .into_iter()
        .filter(|(_, d)| has_axes(d, mapping) && looks_like_joystick(d))
        .collect();
    found.sort_by(|a, b| a.0.cmp(&b.0));
    let Some((path, device)) = found.into_iter().next() else {
        // Devices this user may not open are skipped by the scan: say so, it is the usual cause.
        let present = std::fs::read_dir("/dev/input")
            .map(|d| {
                d.flatten()
                    .filter(|e| e.file_name().to_string_lossy().starts_with("event"))
                    .count()
            })
            .unwrap_or(0);
        let unreadable = present.saturating_sub(opened_count);
        let hint = if unreadable > 0 {
            format!(
                " ({unreadable} of {present} event devices could not be opened: is the user in the \"input\" group?)"
            )
        } else {
            String::new()
        };
        return Err(OpenError::NoJoystick { hint });
    };
    let ranges = axis_ranges(&device, mapping);
    Ok((
        path,
        Source::Device {
            device: Box::new(device),
            ranges,
        },
    ))
}

fn has_axes(d: &evdev::raw_stream::RawDevice, mapping: &JoystickMapping) -> bool {
    d.supported_absolute_axes().is_some_and(|axes| {
        axes.contains(evdev::AbsoluteAxisCode(mapping.x_axis)) && axes.contains(evdev::AbsoluteAxisCode(mapping.y_axis))
    })
}

/// Whether a device with absolute axes is a joystick or gamepad, not a touchpad, tablet or
/// touchscreen (they report absolute X/Y too): it has a joystick or gamepad button (`BTN_JOYSTICK`
/// … `BTN_THUMBR`, 0x120…0x13f) and no `BTN_TOUCH` — the test the kernel's joydev driver makes.
/// Only `auto` applies it; a device named on the command line is taken as it is.
fn looks_like_joystick(d: &evdev::raw_stream::RawDevice) -> bool {
    const BTN_TOUCH: u16 = 0x14a;
    d.supported_keys().is_some_and(|keys| {
        keys.iter().any(|k| (0x120..=0x13f).contains(&k.0)) && !keys.contains(evdev::KeyCode(BTN_TOUCH))
    })
}

/// The device's reported ranges of the mapped axes (the mapping's `axis_range` where it reports
/// none).
fn axis_ranges(d: &evdev::raw_stream::RawDevice, mapping: &JoystickMapping) -> [[i32; 2]; 2] {
    let mut ranges = [mapping.axis_range; 2];
    if let Ok(infos) = d.get_absinfo() {
        for (code, info) in infos {
            for (i, axis) in [mapping.x_axis, mapping.y_axis].into_iter().enumerate() {
                if code.0 == axis && info.minimum() < info.maximum() {
                    ranges[i] = [info.minimum(), info.maximum()];
                }
            }
        }
    }
    ranges
}

/// Opens a device, FIFO or capture file.
fn open(path: &Path, mapping: &JoystickMapping) -> Result<Source, OpenError> {
    let shown = || path.display().to_string();
    let io = |source: io::Error| OpenError::Io { path: shown(), source };
    let meta = std::fs::metadata(path).map_err(io)?;
    let ty = meta.file_type();
    if ty.is_char_device() {
        let device = evdev::raw_stream::RawDevice::open(path).map_err(io)?;
        if !has_axes(&device, mapping) {
            return Err(OpenError::NoAxes {
                path: shown(),
                x: mapping.x_axis,
                y: mapping.y_axis,
            });
        }
        let ranges = axis_ranges(&device, mapping);
        Ok(Source::Device {
            device: Box::new(device),
            ranges,
        })
    } else if ty.is_fifo() {
        // Blocks until a writer opens the FIFO.
        File::open(path).map(Source::Fifo).map_err(io)
    } else if ty.is_file() {
        File::open(path).map(Source::Capture).map_err(io)
    } else {
        Err(OpenError::NotInput { path: shown() })
    }
}

fn read_device(
    device: &mut evdev::raw_stream::RawDevice,
    mapping: &JoystickMapping,
    ranges: [[i32; 2]; 2],
    feed: &mut JoystickFeed,
    stop: &AtomicBool,
) -> End {
    let mut decoder = Decoder::new(mapping.clone(), Some(ranges));
    feed.publish(JoystickState::connected(decoder.command()));
    while !stop.load(Ordering::Relaxed) {
        let events = match device.fetch_events() {
            Ok(events) => events,
            Err(e) => return End::Lost(e.to_string()),
        };
        for e in events {
            let event = InputEvent {
                time_us: 0,
                kind: e.event_type().0,
                code: e.code(),
                value: e.value(),
            };
            if let Some(c) = decoder.apply(&event) {
                feed.publish(JoystickState::connected(c));
            }
        }
    }
    End::Lost("stopped".into())
}

/// Reads raw records from `reader` and publishes every report; with `paced`, each event waits
/// until its timestamp, counted from the first event's, has come.
pub fn read_records(
    mut reader: impl Read,
    mapping: &JoystickMapping,
    paced: bool,
    feed: &mut JoystickFeed,
    stop: &AtomicBool,
) -> End {
    let mut decoder = Decoder::new(mapping.clone(), None);
    feed.publish(JoystickState::connected(decoder.command()));
    let mut buf = vec![0u8; 64 * EVENT_SIZE];
    let mut filled = 0;
    let mut start: Option<(Instant, i64)> = None;
    while !stop.load(Ordering::Relaxed) {
        let n = match reader.read(&mut buf[filled..]) {
            Ok(0) if paced => return End::CaptureEnded,
            Ok(0) => return End::Lost("the writer closed it".into()),
            Ok(n) => n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return End::Lost(e.to_string()),
        };
        filled += n;
        let (events, used) = parse_events(&buf[..filled]);
        for e in &events {
            if paced {
                let (t0, first_us) = *start.get_or_insert((Instant::now(), e.time_us));
                let due = Duration::from_micros(e.time_us.saturating_sub(first_us).max(0) as u64);
                std::thread::sleep((t0 + due).saturating_duration_since(Instant::now()));
            }
            if let Some(c) = decoder.apply(e) {
                feed.publish(JoystickState::connected(c));
            }
        }
        buf.copy_within(used..filled, 0);
        filled -= used;
    }
    End::Lost("stopped".into())
}
