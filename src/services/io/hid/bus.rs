//! The bus wrapper that lays the HID joystick's channels over the field bus's own, from a live
//! reader (real time) or a capture on the simulated clock (virtual time).

use std::sync::{Arc, Mutex};

use super::{JoystickFeed, JoystickState, LatencyProbe, MODULE_TYPE, PROBE_CAPACITY, Published};
use crate::image::{Value, VarIndex, VarTable};
use crate::runtime::bus::Bus;
use crate::services::io::catalogue::Direction;
use crate::services::io::map::{Binding, IoMap};

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
    binding: Binding,
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

    fn start(&mut self) -> Result<(), String> {
        self.inner.start()
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

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self.inner.as_any_mut()
    }

    fn write_fault_cause(&self, out: &mut String) -> bool {
        self.inner.write_fault_cause(out)
    }

    fn observe_error(&mut self, in_error: bool) {
        self.inner.observe_error(in_error);
    }

    fn fault(&self) -> bool {
        self.inner.fault()
    }
}
