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

use std::fs::File;
use std::io::{self, Read};
use std::os::unix::fs::FileTypeExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::catalogue::Direction;
use super::joystick::{Command, Decoder, InputEvent, JoystickMapping, parse_events};
use super::map::IoMap;
use crate::bus::Bus;
use crate::image::{Value, VarIndex, VarTable};

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
            published_ns: crate::timing::monotonic_ns(),
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

/// Which state field a joystick channel carries.
#[derive(Clone, Copy, Debug)]
enum Field {
    X,
    Y,
    Stop,
    Button(usize),
    Connected,
}

impl Field {
    fn of(channel: &str) -> Option<Field> {
        Some(match channel {
            "AxisX" => Field::X,
            "AxisY" => Field::Y,
            "Stop" => Field::Stop,
            "Button01" => Field::Button(0),
            "Button02" => Field::Button(1),
            "Button03" => Field::Button(2),
            "Button04" => Field::Button(3),
            "Connected" => Field::Connected,
            _ => return None,
        })
    }

    fn value(self, s: &JoystickState) -> Value {
        match self {
            Field::X => Value::Real(s.x),
            Field::Y => Value::Real(s.y),
            Field::Stop => Value::Bool(s.stop),
            Field::Button(i) => Value::Bool(s.buttons[i]),
            Field::Connected => Value::Bool(s.connected),
        }
    }
}

/// A joystick channel bound to a variable.
#[derive(Clone, Debug)]
struct Bound {
    field: Field,
    binding: super::map::Binding,
    var: VarIndex,
}

/// Where the joystick's states come from.
enum Feed {
    /// A reader thread, live (real time).
    Live(triple_buffer::Output<Published>),
    /// A capture played on the simulated clock: (time in ns, state) in time order, the next
    /// one to take, and the state taken last.
    Capture {
        states: Vec<(u64, JoystickState)>,
        next: usize,
        current: Published,
    },
}

/// A field bus with the HID joystick's channels laid over its own.
pub struct JoystickBus {
    inner: Box<dyn Bus>,
    bound: Vec<Bound>,
    /// The task class that latches the axes: where the latency is taken.
    axes_class: Option<usize>,
    feed: Feed,
    last_seq: u64,
    probe: LatencyProbe,
}

impl JoystickBus {
    /// Wraps `inner`; the joystick module's bindings in `map` get their values from the returned
    /// feed once it has published (until then, `inner`'s own values stay).
    pub fn new(inner: Box<dyn Bus>, map: &IoMap) -> (JoystickBus, JoystickFeed, LatencyProbe) {
        let bound: Vec<Bound> = map
            .bindings
            .iter()
            .filter(|b| map.modules[b.module].ty.name == MODULE_TYPE && b.direction == Direction::Input)
            .filter_map(|b| {
                let field = Field::of(map.modules[b.module].ty.channels[b.channel].name)?;
                Some(Bound {
                    field,
                    binding: b.clone(),
                    var: 0,
                })
            })
            .collect();
        let axes_class = bound
            .iter()
            .find(|b| matches!(b.field, Field::X | Field::Y))
            .map(|b| b.binding.class);
        let (input, output) = triple_buffer::triple_buffer(&Published::default());
        let probe = LatencyProbe(Arc::new(Mutex::new(Vec::with_capacity(PROBE_CAPACITY))));
        let bus = JoystickBus {
            inner,
            bound,
            axes_class,
            feed: Feed::Live(output),
            last_seq: 0,
            probe: probe.clone(),
        };
        (bus, JoystickFeed { input, seq: 0 }, probe)
    }

    /// Wraps `inner` with the joystick module's bindings in `map` playing `states` (from
    /// [`load_capture`]) on the simulated clock: deterministic, for virtual time.
    pub fn with_capture(inner: Box<dyn Bus>, map: &IoMap, states: Vec<(u64, JoystickState)>) -> JoystickBus {
        let (mut bus, _feed, _probe) = JoystickBus::new(inner, map);
        bus.feed = Feed::Capture {
            states,
            next: 0,
            current: Published::default(),
        };
        bus
    }

    /// Whether the I/O map binds any joystick channel.
    pub fn binds_anything(&self) -> bool {
        !self.bound.is_empty()
    }
}

impl Bus for JoystickBus {
    fn name(&self) -> &str {
        self.inner.name()
    }

    fn declare(&mut self, table: &mut VarTable) {
        self.inner.declare(table);
        for b in &mut self.bound {
            // A bus that declares the whole map (simulated, Modbus) already made itself the
            // writer; without one the joystick's variables are declared here.
            b.var = match table.index_of(&b.binding.variable) {
                Some(i) => i,
                None => b.binding.declare(table),
            };
        }
    }

    fn read_inputs(&mut self, class: usize, t_ns: u64, image: &mut [Value]) {
        self.inner.read_inputs(class, t_ns, image);
        let p = match &mut self.feed {
            Feed::Live(output) => *output.read(),
            Feed::Capture { states, next, current } => {
                while let Some(&(at, state)) = states.get(*next).filter(|(at, _)| *at <= t_ns) {
                    *next += 1;
                    current.seq += 1;
                    *current = Published {
                        state,
                        seq: current.seq,
                        published_ns: at,
                        active: true,
                    };
                }
                *current
            }
        };
        if !p.active {
            return;
        }
        for b in &self.bound {
            image[usize::from(b.var)] = b.field.value(&p.state);
        }
        if Some(class) == self.axes_class && p.seq != self.last_seq && matches!(self.feed, Feed::Live(_)) {
            self.last_seq = p.seq;
            // Never waits: the probe is only read after the run; a full probe stops recording.
            if let Ok(mut pairs) = self.probe.0.try_lock()
                && pairs.len() < pairs.capacity()
            {
                pairs.push((p.published_ns, t_ns));
            }
        }
    }

    fn write_outputs(&mut self, class: usize, t_ns: u64, image: &[Value]) {
        self.inner.write_outputs(class, t_ns, image);
    }

    fn write_safe(&mut self, image: &[Value]) {
        self.inner.write_safe(image);
    }

    /// The wrapped bus (the wrapper is transparent to callers that look for the bus's type).
    fn as_any(&self) -> &dyn std::any::Any {
        self.inner.as_any()
    }

    fn fault(&self) -> bool {
        self.inner.fault()
    }
}

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

/// The first device (by path) with the mapping's absolute X and Y axes.
fn find_device(mapping: &JoystickMapping) -> Result<(PathBuf, Source), String> {
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
        return Err(format!(
            "no joystick or gamepad (absolute X and Y axes, joystick buttons) in /dev/input{hint}"
        ));
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
fn open(path: &Path, mapping: &JoystickMapping) -> Result<Source, String> {
    let shown = path.display();
    let meta = std::fs::metadata(path).map_err(|e| format!("{shown}: {e}"))?;
    let ty = meta.file_type();
    if ty.is_char_device() {
        let device = evdev::raw_stream::RawDevice::open(path).map_err(|e| format!("{shown}: {e}"))?;
        if !has_axes(&device, mapping) {
            return Err(format!(
                "{shown}: the device has no absolute axes {} and {} (see joystick.x_axis, joystick.y_axis)",
                mapping.x_axis, mapping.y_axis
            ));
        }
        let ranges = axis_ranges(&device, mapping);
        Ok(Source::Device {
            device: Box::new(device),
            ranges,
        })
    } else if ty.is_fifo() {
        // Blocks until a writer opens the FIFO.
        File::open(path).map(Source::Fifo).map_err(|e| format!("{shown}: {e}"))
    } else if ty.is_file() {
        File::open(path)
            .map(Source::Capture)
            .map_err(|e| format!("{shown}: {e}"))
    } else {
        Err(format!("{shown}: not an input device, FIFO or capture file"))
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
    let mut buf = vec![0u8; 64 * super::joystick::EVENT_SIZE];
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

/// The most a capture file may hold for virtual time (256 MiB: 11 million events, days of
/// operator input).
pub const MAX_CAPTURE_BYTES: u64 = 256 << 20;

/// Reads a capture file (raw `struct input_event` records) into the joystick's states on the
/// simulated clock: connected and at rest at t = 0; each report at its timestamp's distance from
/// the first event's (a timestamp earlier than the one before counts as that one); disconnected
/// right after the last. Only a regular file is a capture: a device or FIFO needs real time.
pub fn load_capture(path: &Path, mapping: &JoystickMapping) -> Result<Vec<(u64, JoystickState)>, String> {
    let shown = path.display();
    let file = crate::files::open_regular(path).map_err(|e| {
        format!("{shown}: {e} (in virtual time --joystick plays a capture file; a device or FIFO needs real time)")
    })?;
    let bytes = crate::files::read_to_limit(file, MAX_CAPTURE_BYTES).map_err(|e| format!("{shown}: {e}"))?;
    if bytes.len() % super::joystick::EVENT_SIZE != 0 {
        return Err(format!(
            "{shown}: {} bytes is not a whole number of {}-byte input_event records",
            bytes.len(),
            super::joystick::EVENT_SIZE
        ));
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
