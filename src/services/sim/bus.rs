//! The simulated bus: module channel images exchanged synchronously with the cycles, backed by
//! the plant. Before a class's cycle the plant is advanced to the cycle's nominal time and the
//! input channels that class latches are copied into the image; after the cycle the class's output
//! channels are taken from the image and applied to the plant. Deterministic: a run depends only
//! on its configuration and scenario.

use crate::image::{Value, VarIndex, VarTable};
use crate::runtime::bus::Bus;
use crate::services::io::catalogue::Direction;
use crate::services::io::map::IoMap;

use pkm_api::machine::{Action, Plant};

use super::ResolvedWiring;
use super::scenario::Scenario;

/// Wired plant signals of one direction, in the plant's signal order: the signal indices (as the
/// plant's batch calls take them) and, by the same position, their (module, channel).
struct Wired {
    signals: Vec<usize>,
    channels: Vec<(usize, usize)>,
}

impl Wired {
    fn of(wiring: &ResolvedWiring, plant: &dyn Plant, direction: Direction) -> Wired {
        let (signals, channels) = wiring
            .signals
            .iter()
            .filter(|(s, _)| plant.signals()[*s].direction == direction)
            .copied()
            .unzip();
        Wired { signals, channels }
    }
}

/// What one task class's exchange copies, its variables resolved by `declare`: the exchange's
/// loops walk only their own class's bindings, and a wired input goes from the plant's signal
/// straight to its variable.
#[derive(Default)]
struct ClassExchange {
    /// The wired input signals the class latches, as the plant's batch read takes them.
    signals: Vec<usize>,
    /// Per input binding wired to a signal: the signal and the variable.
    wired: Vec<(usize, VarIndex)>,
    /// Per input binding of a channel no signal drives: the (module, channel) and the variable.
    unwired: Vec<(usize, usize, VarIndex)>,
    /// Per output binding: the (module, channel) and the variable.
    outputs: Vec<(usize, usize, VarIndex)>,
    /// The output signals the class's bindings drive, in the plant's signal order, and the
    /// (module, channel) of each: what its cycle's outputs change in the plant.
    output_signals: Vec<usize>,
    output_channels: Vec<(usize, usize)>,
}

/// The simulated bus.
pub struct SimBus {
    map: IoMap,
    /// Per module, per channel.
    channels: Vec<Vec<Value>>,
    plant: Box<dyn Plant>,
    /// The wired input signals (plant → channel).
    inputs: Wired,
    /// Per task class, what its exchange copies (set by `declare`): a class's cycle reads only
    /// the signals it latches from the plant (the fast class's hundred exchanges a second do not
    /// read the panel's switches, which the main class latches).
    classes: Vec<ClassExchange>,
    /// The wired output signals (channel → plant).
    outputs: Wired,
    /// Every signal's value as last exchanged, indexed by signal (allocated once).
    signal_values: Vec<Value>,
    /// The output signals a class's cycle changed (reused: no allocation in the cycle).
    changed: Vec<usize>,
    scenario: Scenario,
    next_event: usize,
    time_ns: u64,
    step_ns: u64,
}

impl SimBus {
    /// A simulated bus over `map`, wired by `wiring`, integrating every `step_ns`. Its joystick
    /// is plugged in only where `scenario` uses one ([`Scenario::uses_joystick`]).
    pub fn new(
        map: IoMap,
        mut plant: Box<dyn Plant>,
        wiring: ResolvedWiring,
        scenario: Scenario,
        step_ns: u64,
    ) -> Self {
        if !scenario.uses_joystick() {
            plant.apply(Action::JoystickConnected(false));
        }
        let channels = map
            .modules
            .iter()
            .map(|m| m.ty.channels.iter().map(|c| Value::zero(c.ty)).collect())
            .collect();
        let inputs = Wired::of(&wiring, plant.as_ref(), Direction::Input);
        let outputs = Wired::of(&wiring, plant.as_ref(), Direction::Output);
        let signal_values: Vec<Value> = plant.signals().iter().map(|s| Value::zero(s.ty)).collect();
        SimBus {
            map,
            channels,
            plant,
            inputs,
            classes: Vec::new(),
            outputs,
            changed: Vec::with_capacity(signal_values.len()),
            signal_values,
            scenario,
            next_event: 0,
            time_ns: 0,
            step_ns: step_ns.max(1),
        }
    }

    /// The plant (for tests and status displays: the machine's true state).
    pub fn plant(&self) -> &dyn Plant {
        self.plant.as_ref()
    }

    /// The plant, to act on it as a person at the machine would (tests).
    pub fn plant_mut(&mut self) -> &mut dyn Plant {
        self.plant.as_mut()
    }

    /// The scenario it plays.
    pub fn scenario(&self) -> &Scenario {
        &self.scenario
    }

    /// The simulated time the plant has reached (ns).
    pub fn time_ns(&self) -> u64 {
        self.time_ns
    }

    /// Advances the plant to `t_ns`, applying scenario events at their times.
    pub fn advance_to(&mut self, t_ns: u64) {
        loop {
            while let Some(&(at, action)) = self.scenario.events.get(self.next_event) {
                if at > self.time_ns {
                    break;
                }
                self.plant.apply(action);
                self.next_event += 1;
            }
            // Whole steps that fit before `t_ns`, and no further than the next event: the plant
            // takes them in one call (its loop inlines its step; one dynamic call per run).
            let mut n = t_ns.saturating_sub(self.time_ns) / self.step_ns;
            if let Some(&(at, _)) = self.scenario.events.get(self.next_event) {
                n = n.min((at - self.time_ns).div_ceil(self.step_ns));
            }
            if n == 0 {
                break;
            }
            self.plant.steps(self.step_ns as f64 * 1e-9, n);
            self.time_ns += n * self.step_ns;
        }
    }

    /// Channel-level access for a station that serves the modules itself (the Modbus I/O
    /// simulator): advances the plant to `t_ns` and refreshes the input channels.
    pub fn refresh(&mut self, t_ns: u64) {
        self.advance_to(t_ns);
        self.plant_to_channels();
    }

    /// The I/O map the station serves.
    pub fn io_map(&self) -> &IoMap {
        &self.map
    }

    /// A channel's value: an output's as last written, an input's as of the last
    /// [`SimBus::refresh`] (a task class's exchange takes its inputs from the plant directly).
    pub fn channel(&self, module: usize, channel: usize) -> Value {
        self.channels[module][channel]
    }

    /// Sets an output channel and applies the outputs to the plant.
    pub fn set_output(&mut self, module: usize, channel: usize, value: Value) {
        self.channels[module][channel] = value;
        self.channels_to_plant();
    }

    /// Copies the plant's signals into the input channels.
    fn plant_to_channels(&mut self) {
        self.plant.read_into(&self.inputs.signals, &mut self.signal_values);
        for (&signal, &(m, c)) in self.inputs.signals.iter().zip(&self.inputs.channels) {
            self.channels[m][c] = self.signal_values[signal];
        }
    }

    /// Copies the output variables of task class `class` (every class: `None`) from `image` into
    /// their channels and applies the output channels to the plant.
    fn outputs_to_plant(&mut self, class: Option<usize>, image: &[Value]) {
        let classes = match class {
            Some(c) => c..c + 1,
            None => 0..self.classes.len(),
        };
        for c in classes {
            let Some(exchange) = self.classes.get(c) else {
                continue;
            };
            for &(m, ch, var) in &exchange.outputs {
                self.channels[m][ch] = image[usize::from(var)];
            }
        }
        match class.and_then(|c| self.classes.get(c)) {
            // A class's cycle changes only its own outputs, and of those only what changed goes
            // to the plant: it holds the rest already (every output reaches it through
            // `signal_values`, which start at the plant's zero outputs). Writing every output
            // after every cycle took a tenth of the hexapod's simulated hour.
            Some(exchange) => {
                self.changed.clear();
                for (&signal, &(m, c)) in exchange.output_signals.iter().zip(&exchange.output_channels) {
                    let value = self.channels[m][c];
                    if self.signal_values[signal] != value {
                        self.signal_values[signal] = value;
                        self.changed.push(signal);
                    }
                }
                if !self.changed.is_empty() {
                    self.plant.write_from(&self.changed, &self.signal_values);
                }
            }
            None => self.channels_to_plant(),
        }
    }

    /// Applies the output channels to the plant.
    fn channels_to_plant(&mut self) {
        for (&signal, &(m, c)) in self.outputs.signals.iter().zip(&self.outputs.channels) {
            self.signal_values[signal] = self.channels[m][c];
        }
        self.plant.write_from(&self.outputs.signals, &self.signal_values);
    }
}

impl Bus for SimBus {
    fn name(&self) -> &str {
        "sim"
    }

    fn declare(&mut self, table: &mut VarTable) {
        let vars: Vec<VarIndex> = self.map.bindings.iter().map(|b| b.declare(table)).collect();
        let classes = self.map.bindings.iter().map(|b| b.class + 1).max().unwrap_or(0);
        self.classes = (0..classes).map(|_| ClassExchange::default()).collect();
        for (b, var) in self.map.bindings.iter().zip(vars) {
            let exchange = &mut self.classes[b.class];
            let at = (b.module, b.channel);
            match b.direction {
                Direction::Output => exchange.outputs.push((b.module, b.channel, var)),
                Direction::Input => match self.inputs.channels.iter().position(|c| *c == at) {
                    Some(k) => {
                        let signal = self.inputs.signals[k];
                        exchange.signals.push(signal);
                        exchange.wired.push((signal, var));
                    }
                    None => exchange.unwired.push((b.module, b.channel, var)),
                },
            }
        }
        for exchange in &mut self.classes {
            // The plant's batch read in its signal order.
            exchange.signals.sort_unstable();
            // The plant's output signals this class's bindings drive, in signal order.
            let mut driven: Vec<(usize, (usize, usize))> = exchange
                .outputs
                .iter()
                .filter_map(|&(m, ch, _)| {
                    let k = self.outputs.channels.iter().position(|c| *c == (m, ch))?;
                    Some((self.outputs.signals[k], (m, ch)))
                })
                .collect();
            driven.sort_unstable();
            driven.dedup();
            (exchange.output_signals, exchange.output_channels) = driven.into_iter().unzip();
        }
    }

    fn read_inputs(&mut self, class: usize, t_ns: u64, image: &mut [Value]) {
        self.advance_to(t_ns);
        // Wired inputs go from the plant to the image without their channels (which only a
        // station serving the modules reads, after `refresh`).
        if let Some(exchange) = self.classes.get(class) {
            self.plant.read_into(&exchange.signals, &mut self.signal_values);
            for &(signal, var) in &exchange.wired {
                image[usize::from(var)] = self.signal_values[signal];
            }
            for &(m, c, var) in &exchange.unwired {
                image[usize::from(var)] = self.channels[m][c];
            }
        }
    }

    fn write_outputs(&mut self, class: usize, _t_ns: u64, image: &[Value]) {
        self.outputs_to_plant(Some(class), image);
    }

    fn write_safe(&mut self, image: &[Value]) {
        self.outputs_to_plant(None, image);
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }
}
