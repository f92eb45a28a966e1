//! The OPC UA address space of a run, in the namespace [`NAMESPACE`]:
//!
//! ```text
//! Objects
//! └─ PkmPlc
//!    └─ MACHINE                        the running machine (hexapod, trijoint, …)
//!       ├─ State, Reason, Note         the main state, its error reason, the note to the operator
//!       ├─ MainState                    the main state as a number (MultiStateDiscreteType)
//!       ├─ BusFault, Configuration
//!       ├─ Status/                      the values the main program shows (x, y, q1, …: Double)
//!       ├─ Program/                     the NC program's variables (NC_LINE, NC_STATE, NC_RUN_S, …)
//!       ├─ Alarms/                      the conditions (Stop, LimitSwitch, EncoderFault, CycleTime,
//!       │                               BusFault, Error, JobRefused), their events emitted on MACHINE
//!       ├─ TaskClasses/
//!       │  └─ CLASS/                    per task class: Cycles, Overruns, Violations, CycleTimeMs,
//!       │     │                         LatenessMeanUs/MaxUs, ExecMeanUs/MaxUs
//!       │     └─ Variables/             every process-image variable the class writes or latches
//!       └─ Stop() Acknowledge() Start() Hold() Resume() Load(Program)
//! ```
//!
//! The machine's object is also in Machinery's `Machines` folder, with its nameplate and
//! Machinery states ([`super::companion`]).
//!
//! A process-image variable's node id is `ns=…;s=MACHINE.NAME`, its browse name its name, its
//! data type the OPC UA type of its IEC type (BOOL → Boolean, INT → Int16, UINT → UInt16, DINT →
//! Int32, REAL → Double), with the IEC type itself as the property `IecType` and, where the name
//! tells it, the unit as the property `EngineeringUnits`: an `AnalogItemType` with its `EURange`
//! where the range is known ([`super::ranges`]), else a `BaseAnalogType`. Every variable is
//! read-only.

use std::collections::HashMap;

use opcua::server::address_space::EventNotifier;
use opcua::server::address_space::{AccessLevel, AddressSpace, MethodBuilder, ObjectBuilder, VariableBuilder};
use opcua::types::{
    DataTypeId, DataValue, DateTime, EUInformation, ExtensionObject, LocalizedText, MethodId, NodeId, ObjectId,
    QualifiedName, Range, ReferenceTypeId, StatusCode, UAString, VariableTypeId, Variant,
};

use super::conditions::Kind;
use pkm_api::machine::MAIN_STATES;

use crate::image::{Value, VarType};
use crate::runtime::frame::Frame;

/// The namespace of the run's nodes.
pub const NAMESPACE: &str = "urn:pkm-plc";

/// What the address space is built from.
#[derive(Clone, Debug)]
pub struct SpaceInfo {
    /// The machine's name (`runtime` without one).
    pub machine: String,
    /// The configuration's file.
    pub config: String,
    /// The task classes: name and cycle time (ns), in configuration order.
    pub classes: Vec<(String, u64)>,
    /// Every process-image variable, in the image's order.
    pub variables: Vec<VarNode>,
    /// The run's NC programs (files), numbered from 1 for `Load`.
    pub programs: Vec<String>,
    /// The machine's nameplate (`None`: no machine, the runtime's self-test: nothing in
    /// Machinery's `Machines`).
    pub nameplate: Option<super::companion::Nameplate>,
}

/// A process-image variable as the address space shows it.
#[derive(Clone, Debug)]
pub struct VarNode {
    /// Its name.
    pub name: String,
    /// Its IEC type.
    pub ty: VarType,
    /// The task class it belongs to: the one whose program writes it or whose cycle latches it.
    pub class: usize,
    /// Who writes it, for its description.
    pub writer: String,
    /// The values it takes in normal operation, where known ([`super::ranges`]).
    pub range: Option<[f64; 2]>,
}

/// The commands, as methods of the machine's object.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Method {
    /// STOP (outside ERROR).
    Stop,
    /// Acknowledge the error (in ERROR).
    Acknowledge,
    /// Program start.
    Start,
    /// Program hold.
    Hold,
    /// Program resume.
    Resume,
    /// Load a program of the run by its number.
    Load,
}

impl Method {
    /// All of them.
    pub const ALL: [Method; 6] = [
        Method::Stop,
        Method::Acknowledge,
        Method::Start,
        Method::Hold,
        Method::Resume,
        Method::Load,
    ];

    /// Its browse name.
    pub fn name(self) -> &'static str {
        match self {
            Method::Stop => "Stop",
            Method::Acknowledge => "Acknowledge",
            Method::Start => "Start",
            Method::Hold => "Hold",
            Method::Resume => "Resume",
            Method::Load => "Load",
        }
    }

    fn description(self) -> &'static str {
        match self {
            Method::Stop => {
                "STOP, as the panel's button: the machine stops and goes to ERROR (refused in ERROR: Acknowledge acknowledges)"
            }
            Method::Acknowledge => "Acknowledges the error: from ERROR to INIT (refused outside ERROR)",
            Method::Start => "Starts the loaded NC program (from READY)",
            Method::Hold => "Holds the running NC program (a controlled stop on the path)",
            Method::Resume => "Resumes the held NC program",
            Method::Load => {
                "Loads the run's NC program of this number (from 1) in place of the loaded one (refused while one runs)"
            }
        }
    }
}

/// The node ids of a built address space and the values last written to them.
pub struct Space {
    ns: u16,
    machine: String,
    vars: Vec<NodeId>,
    last: Vec<Option<Value>>,
    state: [NodeId; 5],
    last_state: Option<(String, String, String, bool)>,
    classes: Vec<[NodeId; 7]>,
    status_folder: NodeId,
    status: HashMap<&'static str, NodeId>,
    /// The machine object's node (the methods' object, the conditions' source and the node
    /// their events are emitted on).
    pub object: NodeId,
    /// The conditions' nodes ([`super::conditions`]).
    pub alarms: Vec<(Kind, NodeId)>,
    /// Where `error_reason` (the ERROR reason's code) is in the process image, if the run has
    /// it.
    pub reason_index: Option<usize>,
    /// The variables whose history is kept ([`super::history`]), with their kind of value.
    pub historized: Vec<(NodeId, super::history::ValueKind)>,
    /// The methods' nodes.
    pub methods: Vec<(Method, NodeId)>,
    /// The machine's Machinery nodes, where the companion is loaded and the run has a machine.
    machinery: Option<super::companion::Machinery>,
    /// The machine's Machine Tools view, likewise.
    machine_tool: Option<super::machine_tool::MachineTool>,
}

/// Whether the history of process-image variable `v` is kept: one with a unit (a position, a
/// speed, a feed, an override, a time) or the program's line and state.
fn historized_var(v: &VarNode) -> bool {
    v.ty != VarType::Bool && super::units::of(&v.name).is_some() || v.name == "NC_LINE" || v.name == "NC_STATE"
}

/// The OPC UA data type of an IEC type.
pub fn data_type(ty: VarType) -> DataTypeId {
    match ty {
        VarType::Bool => DataTypeId::Boolean,
        VarType::Int => DataTypeId::Int16,
        VarType::Uint => DataTypeId::UInt16,
        VarType::Dint => DataTypeId::Int32,
        VarType::Real => DataTypeId::Double,
    }
}

/// A process-image value as a variant of its OPC UA type.
pub fn variant(v: Value) -> Variant {
    match v {
        Value::Bool(b) => Variant::Boolean(b),
        Value::Int(i) => Variant::Int16(i),
        Value::Uint(u) => Variant::UInt16(u),
        Value::Dint(d) => Variant::Int32(d),
        Value::Real(r) => Variant::Double(r),
    }
}

/// OPC UA's DateTime (100 ns ticks since 1601-01-01) of a wall-clock time in µs since the Unix
/// epoch.
pub fn date_time(unix_us: u64) -> DateTime {
    const UNIX_EPOCH_TICKS: i64 = 11_644_473_600 * 10_000_000;
    DateTime::from(UNIX_EPOCH_TICKS.saturating_add((unix_us as i64).saturating_mul(10)))
}

/// The figures of a task class, in the order of [`Space`]'s class nodes.
const CLASS_FIGURES: [(&str, DataTypeId, &str); 7] = [
    ("Cycles", DataTypeId::UInt64, "cycles run"),
    ("Overruns", DataTypeId::UInt64, "cycles that overran their cycle time"),
    (
        "Violations",
        DataTypeId::UInt64,
        "cycles that started later than the tolerance",
    ),
    ("LatenessMeanUs", DataTypeId::Double, "mean start lateness (µs)"),
    ("LatenessMaxUs", DataTypeId::Double, "largest start lateness (µs)"),
    ("ExecMeanUs", DataTypeId::Double, "mean execution time (µs)"),
    ("ExecMaxUs", DataTypeId::Double, "largest execution time (µs)"),
];

impl Space {
    /// Builds the nodes of `info` into `space` (namespace index `ns`), with the values of
    /// `first`: the machine's object with its state, the task classes' figures, every variable of
    /// the process image, and the methods.
    pub fn build(
        space: &mut AddressSpace,
        ns: u16,
        info: &SpaceInfo,
        first: &Frame,
        sources: super::machine_tool::Sources,
    ) -> Space {
        let root = NodeId::new(ns, "PkmPlc");
        ObjectBuilder::new(&root, QualifiedName::new(ns, "PkmPlc"), "PkmPlc")
            .description("pkm-plc, a soft-PLC for parallel-kinematic machine models")
            .is_folder()
            .organized_by(ObjectId::ObjectsFolder)
            .insert(space);
        let object = NodeId::new(ns, info.machine.clone());
        ObjectBuilder::new(
            &object,
            QualifiedName::new(ns, info.machine.as_str()),
            info.machine.as_str(),
        )
        .description(format!("The {} machine of this run", info.machine))
        .has_type_definition(super::machine_tool::object_type(space, info.nameplate.is_some()))
        .organized_by(root.clone())
        // Its conditions' events are emitted on it (and so on the Server object).
        .event_notifier(EventNotifier::SUBSCRIBE_TO_EVENTS)
        .insert(space);
        let b = Builder {
            ns,
            machine: &info.machine,
            object: object.clone(),
        };
        let state = b.state(space, info);
        let status_folder = b.id("Status");
        b.folder(space, &status_folder, "Status", &object);
        let program = b.id("Program");
        b.folder(space, &program, "Program", &object);
        let classes_folder = b.id("TaskClasses");
        b.folder(space, &classes_folder, "TaskClasses", &object);
        let (classes, class_vars) = b.classes(space, info, &classes_folder);
        let vars = b.variables(space, info, first, &class_vars, &classes_folder, &program);
        let methods = b.methods(space);
        let alarms = b.alarms(space);
        let mut historized = vec![
            (state[4].clone(), super::history::ValueKind::UInt32),
            (state[3].clone(), super::history::ValueKind::Bool),
        ];
        historized.extend(
            info.variables
                .iter()
                .zip(&vars)
                .filter(|(v, _)| historized_var(v))
                .filter_map(|(v, node)| super::history::ValueKind::of(data_type(v.ty)).map(|k| (node.clone(), k))),
        );
        for (node, _) in &historized {
            if let Some(opcua::server::address_space::NodeType::Variable(var)) = space.find_mut(node) {
                var.set_access_level(AccessLevel::CURRENT_READ | AccessLevel::HISTORY_READ);
                var.set_user_access_level(AccessLevel::CURRENT_READ | AccessLevel::HISTORY_READ);
                var.set_historizing(true);
            }
        }
        let machinery = info.nameplate.as_ref().and_then(|nameplate| {
            super::companion::Machinery::build(
                space,
                (ns, &info.machine, &object),
                nameplate,
                info.variables.iter().position(|v| v.name == "NC_STATE"),
            )
        });
        let names: Vec<&str> = info.variables.iter().map(|v| v.name.as_str()).collect();
        let machine_tool = info.nameplate.as_ref().and_then(|_| {
            super::machine_tool::MachineTool::build(space, (ns, &info.machine, &object), &names, sources)
        });
        Space {
            machinery,
            machine_tool,
            historized,
            alarms,
            reason_index: info.variables.iter().position(|v| v.name == "error_reason"),
            ns,
            machine: info.machine.clone(),
            last: vec![None; vars.len()],
            vars,
            state,
            last_state: None,
            classes,
            status_folder,
            status: HashMap::new(),
            object,
            methods,
        }
    }

    /// The changes `frame` brings: every variable whose value changed, the state's texts when
    /// they changed, the classes' figures. Status values seen for the first time get their node
    /// (in `space`).
    pub fn changes(&mut self, space: &mut AddressSpace, frame: &Frame) -> Vec<(NodeId, DataValue)> {
        self.changes_of(space, frame)
    }

    /// Every node a frame's [`Space::changes`] write: the process image, the state, the task
    /// classes' figures, the main program's shown values and the Machinery states.
    pub fn value_nodes(&self) -> Vec<NodeId> {
        let mut nodes: Vec<NodeId> = self.vars.iter().chain(&self.state).cloned().collect();
        nodes.extend(self.classes.iter().flatten().cloned());
        nodes.extend(self.status.values().cloned());
        if let Some(machinery) = &self.machinery {
            nodes.extend(machinery.nodes().cloned());
        }
        if let Some(view) = &self.machine_tool {
            nodes.extend(view.nodes().cloned());
        }
        nodes
    }

    /// Where the alarms' events are emitted: the machine's object and, in the Machine Tools
    /// view, `Notification/Messages`.
    pub fn emitters(&self) -> super::emitters::Emitters {
        super::emitters::Emitters {
            object: self.object.clone(),
            messages: self.machine_tool.as_ref().map(|v| v.messages.clone()),
        }
    }

    /// Forgets what was published: the next frame writes every value again (after values
    /// were marked bad, or a publication stopped halfway).
    pub fn forget(&mut self) {
        self.last.fill(None);
        self.last_state = None;
        if let Some(machinery) = &mut self.machinery {
            machinery.forget();
        }
        if let Some(view) = &mut self.machine_tool {
            view.forget();
        }
    }

    fn changes_of(&mut self, space: &mut AddressSpace, frame: &Frame) -> Vec<(NodeId, DataValue)> {
        // A frame not yet published (the first, before the cycle ran) carries no time: its values
        // are the ones known now (1970-01-01 before, for every value unchanged since the start).
        let at = match frame.published_unix_us {
            0 => DateTime::now(),
            us => date_time(us),
        };
        let value = |v: Variant| DataValue {
            value: Some(v),
            status: None,
            source_timestamp: Some(at),
            source_picoseconds: None,
            server_timestamp: Some(at),
            server_picoseconds: None,
        };
        let mut out = Vec::new();
        for (k, v) in frame.image.iter().enumerate() {
            if let Some(node) = self.vars.get(k)
                && self.last[k] != Some(*v)
            {
                self.last[k] = Some(*v);
                out.push((node.clone(), value(variant(*v))));
            }
        }
        let s = &frame.status;
        let state = (s.state.clone(), s.reason.clone(), s.note.clone(), frame.bus_fault);
        if self.last_state.as_ref() != Some(&state) {
            // The state's number: its code in the automaton (EnumStrings' index); a state
            // outside the automaton (the runtime's self-test) has none.
            let code = MAIN_STATES.iter().position(|m| *m == state.0);
            out.push((
                self.state[4].clone(),
                match code {
                    Some(code) => value(Variant::UInt32(code as u32)),
                    None => DataValue {
                        status: Some(StatusCode::BadWaitingForInitialData),
                        ..value(Variant::UInt32(0))
                    },
                },
            ));
            out.push((self.state[0].clone(), value(Variant::from(state.0.as_str()))));
            out.push((self.state[1].clone(), value(Variant::from(state.1.as_str()))));
            out.push((self.state[2].clone(), value(Variant::from(state.2.as_str()))));
            out.push((self.state[3].clone(), value(Variant::Boolean(state.3))));
            self.last_state = Some(state);
        }
        if let Some(machinery) = &mut self.machinery {
            out.extend(machinery.changes(frame, value));
        }
        if let Some(view) = &mut self.machine_tool {
            out.extend(view.changes(space, frame, value));
        }
        for (c, nodes) in s.classes.iter().zip(&self.classes) {
            let figures = [
                Variant::UInt64(c.cycles),
                Variant::UInt64(c.overruns),
                Variant::UInt64(c.violations),
                Variant::Double(c.lateness_mean_ns / 1e3),
                Variant::Double(c.lateness_max_ns as f64 / 1e3),
                Variant::Double(c.exec_mean_ns / 1e3),
                Variant::Double(c.exec_max_ns as f64 / 1e3),
            ];
            for (node, v) in nodes.iter().zip(figures) {
                out.push((node.clone(), value(v)));
            }
        }
        for (name, v) in &s.values {
            // The program line is a count, not a measure.
            let (ty, v) = match *name {
                "line" if v.is_finite() && *v >= 0.0 => (DataTypeId::UInt32, Variant::UInt32(*v as u32)),
                "line" => (DataTypeId::UInt32, Variant::UInt32(0)),
                _ => (DataTypeId::Double, Variant::Double(*v)),
            };
            let node = match self.status.get(name) {
                Some(node) => node.clone(),
                None => {
                    let node = NodeId::new(self.ns, format!("{}.Status.{name}", self.machine));
                    VariableBuilder::new(&node, QualifiedName::new(self.ns, *name), *name)
                        .description("a value the main program shows with its state")
                        .data_type(ty)
                        .value(v.clone())
                        .access_level(AccessLevel::CURRENT_READ)
                        .user_access_level(AccessLevel::CURRENT_READ)
                        .organized_by(self.status_folder.clone())
                        .insert(space);
                    self.status.insert(name, node.clone());
                    node
                }
            };
            out.push((node, value(v)));
        }
        out
    }
}

/// What builds the address space's nodes: the namespace, the machine's name (every node id
/// starts with it) and its object.
struct Builder<'a> {
    ns: u16,
    machine: &'a str,
    object: NodeId,
}

impl Builder<'_> {
    /// The node id of `path` below the machine.
    fn id(&self, path: &str) -> NodeId {
        NodeId::new(self.ns, format!("{}.{path}", self.machine))
    }

    /// A folder `name` at `node`, organized by `parent`.
    fn folder(&self, space: &mut AddressSpace, node: &NodeId, name: &str, parent: &NodeId) {
        ObjectBuilder::new(node, QualifiedName::new(self.ns, name), name)
            .is_folder()
            .organized_by(parent.clone())
            .insert(space);
    }

    /// A read-only variable `name` of the machine's object.
    fn text_var(
        &self,
        space: &mut AddressSpace,
        node: &NodeId,
        name: &str,
        value: Variant,
        ty: DataTypeId,
        about: &str,
    ) {
        VariableBuilder::new(node, QualifiedName::new(self.ns, name), name)
            .description(about)
            .data_type(ty)
            .value(value)
            .access_level(AccessLevel::CURRENT_READ)
            .user_access_level(AccessLevel::CURRENT_READ)
            .has_type_definition(VariableTypeId::BaseDataVariableType)
            .component_of(self.object.clone())
            .insert(space);
    }

    /// The main state (as text and as a number), its reason and note, the bus fault and the
    /// configuration: the nodes of all but the configuration.
    fn state(&self, space: &mut AddressSpace, info: &SpaceInfo) -> [NodeId; 5] {
        let state = [
            self.id("State"),
            self.id("Reason"),
            self.id("Note"),
            self.id("BusFault"),
            self.id("MainState"),
        ];
        // The number beside the text, for a SCADA that maps states to numbers: a
        // MultiStateDiscrete whose EnumStrings name each code.
        VariableBuilder::new(&state[4], QualifiedName::new(self.ns, "MainState"), "MainState")
            .description("the main state as a number: its code, named by EnumStrings (0 REBOOT, 1 INIT, 2 READY, 3 MOTION, 4 ERROR, 5 AUTO)")
            .data_type(DataTypeId::UInt32)
            .value(Variant::UInt32(0))
            .access_level(AccessLevel::CURRENT_READ)
            .user_access_level(AccessLevel::CURRENT_READ)
            .has_type_definition(VariableTypeId::MultiStateDiscreteType)
            .component_of(self.object.clone())
            .insert(space);
        let names: Vec<LocalizedText> = MAIN_STATES.iter().map(|m| LocalizedText::new("", m)).collect();
        VariableBuilder::new(
            &self.id("MainState.EnumStrings"),
            QualifiedName::new(0, "EnumStrings"),
            "EnumStrings",
        )
        .data_type(DataTypeId::LocalizedText)
        .value_rank(1)
        .value(Variant::from(names))
        .has_type_definition(VariableTypeId::PropertyType)
        .property_of(state[4].clone())
        .insert(space);
        self.text_var(
            space,
            &state[0],
            "State",
            Variant::from(""),
            DataTypeId::String,
            "the main state (REBOOT, INIT, READY, MOTION, AUTO, ERROR)",
        );
        self.text_var(
            space,
            &state[1],
            "Reason",
            Variant::from(""),
            DataTypeId::String,
            "the error reason in ERROR, else empty",
        );
        self.text_var(
            space,
            &state[2],
            "Note",
            Variant::from(""),
            DataTypeId::String,
            "the main program's note to the operator",
        );
        self.text_var(
            space,
            &state[3],
            "BusFault",
            Variant::Boolean(false),
            DataTypeId::Boolean,
            "the field bus reports a fault",
        );
        self.text_var(
            space,
            &self.id("Configuration"),
            "Configuration",
            Variant::from(info.config.as_str()),
            DataTypeId::String,
            "the configuration this run was built from",
        );

        state
    }

    /// Each task class's folder with its cycle time and figures, and the folder of its variables.
    fn classes(
        &self,
        space: &mut AddressSpace,
        info: &SpaceInfo,
        classes_folder: &NodeId,
    ) -> (Vec<[NodeId; CLASS_FIGURES.len()]>, Vec<NodeId>) {
        let ns = self.ns;
        let mut classes = Vec::with_capacity(info.classes.len());
        let mut class_vars = Vec::with_capacity(info.classes.len());
        for (name, period_ns) in &info.classes {
            let class = self.id(&format!("TaskClasses.{name}"));
            self.folder(space, &class, name, classes_folder);
            let figure = |what: &str| self.id(&format!("TaskClasses.{name}.{what}"));
            VariableBuilder::new(
                &figure("CycleTimeMs"),
                QualifiedName::new(ns, "CycleTimeMs"),
                "CycleTimeMs",
            )
            .description("the class's cycle time (ms)")
            .data_type(DataTypeId::Double)
            .value(*period_ns as f64 / 1e6)
            .organized_by(class.clone())
            .insert(space);
            let nodes = CLASS_FIGURES.map(|(what, ty, about)| {
                let node = figure(what);
                let zero = if ty == DataTypeId::UInt64 {
                    Variant::UInt64(0)
                } else {
                    Variant::Double(0.0)
                };
                VariableBuilder::new(&node, QualifiedName::new(ns, what), what)
                    .description(about)
                    .data_type(ty)
                    .value(zero)
                    .organized_by(class.clone())
                    .insert(space);
                node
            });
            classes.push(nodes);
            let vars = figure("Variables");
            self.folder(space, &vars, "Variables", &class);
            class_vars.push(vars);
        }

        (classes, class_vars)
    }

    /// Every variable of the process image in its class's folder (the program's also in
    /// `program`), with its IEC type and, where its name says, its engineering unit.
    fn variables(
        &self,
        space: &mut AddressSpace,
        info: &SpaceInfo,
        first: &Frame,
        class_vars: &[NodeId],
        classes_folder: &NodeId,
        program: &NodeId,
    ) -> Vec<NodeId> {
        let ns = self.ns;
        let mut vars = Vec::with_capacity(info.variables.len());
        for (k, v) in info.variables.iter().enumerate() {
            let node = self.id(&v.name);
            let parent = class_vars.get(v.class).unwrap_or(classes_folder).clone();
            // A BOOL is a state, never a measure (JOINT1_REFERENCE is a switch, not a length).
            let unit = super::units::of(&v.name).filter(|_| v.ty != VarType::Bool);
            let about = match unit {
                Some(u) => format!("{} ({}), written by {}", v.ty, u.symbol, v.writer),
                None => format!("{}, written by {}", v.ty, v.writer),
            };
            let value = first.image.get(k).copied().unwrap_or(Value::zero(v.ty));
            VariableBuilder::new(&node, QualifiedName::new(ns, v.name.as_str()), v.name.as_str())
                .description(about)
                .data_type(data_type(v.ty))
                .value(variant(value))
                .access_level(AccessLevel::CURRENT_READ)
                .user_access_level(AccessLevel::CURRENT_READ)
                .minimum_sampling_interval(0.0)
                .has_type_definition(match (unit, v.range) {
                    (Some(_), Some(_)) => VariableTypeId::AnalogItemType,
                    (Some(_), None) => VariableTypeId::BaseAnalogType,
                    (None, _) => VariableTypeId::BaseDataVariableType,
                })
                .organized_by(parent)
                .insert(space);
            // IecType is this namespace's; EngineeringUnits the standard property (namespace 0).
            let property = |space: &mut AddressSpace, name: QualifiedName, ty: DataTypeId, value: Variant| {
                let p = self.id(&format!("{}.{}", v.name, name.name));
                let display = name.name.to_string();
                VariableBuilder::new(&p, name, display)
                    .data_type(ty)
                    .value(value)
                    .has_type_definition(VariableTypeId::PropertyType)
                    .property_of(node.clone())
                    .insert(space);
            };
            property(
                space,
                QualifiedName::new(ns, "IecType"),
                DataTypeId::String,
                Variant::from(v.ty.to_string()),
            );
            if let Some(u) = unit {
                let eu = EUInformation {
                    namespace_uri: UAString::from(super::units::UNECE_NAMESPACE),
                    unit_id: u.unit_id(),
                    display_name: LocalizedText::new("", u.symbol),
                    description: LocalizedText::new("", u.name),
                };
                property(
                    space,
                    QualifiedName::new(0, "EngineeringUnits"),
                    DataTypeId::EUInformation,
                    Variant::from(ExtensionObject::from_message(eu)),
                );
                if let Some([low, high]) = v.range {
                    property(
                        space,
                        QualifiedName::new(0, "EURange"),
                        DataTypeId::Range,
                        Variant::from(ExtensionObject::from_message(Range { low, high })),
                    );
                }
            }
            if v.name.starts_with("NC_") || v.name.starts_with("SPINDLE_") {
                space.insert_reference(program, &node, ReferenceTypeId::Organizes);
            }
            vars.push(node);
        }

        vars
    }

    /// The folder `Alarms` with a condition of each kind: an object of the kind's alarm type
    /// whose `Acknowledge` is the type's (the method clients call with the condition as its
    /// object).
    fn alarms(&self, space: &mut AddressSpace) -> Vec<(Kind, NodeId)> {
        let folder = self.id("Alarms");
        ObjectBuilder::new(&folder, QualifiedName::new(self.ns, "Alarms"), "Alarms")
            .is_folder()
            .description("the machine's alarms and conditions: subscribe to the events of this machine's object or the Server object")
            .component_of(self.object.clone())
            .insert(space);
        Kind::ALL
            .iter()
            .map(|&kind| {
                let node = self.id(&format!("Alarms.{}", kind.name()));
                ObjectBuilder::new(&node, QualifiedName::new(self.ns, kind.name()), kind.name())
                    .description(kind.description())
                    .has_type_definition(kind.event_type())
                    .organized_by(folder.clone())
                    .insert(space);
                space.insert_reference(
                    &node,
                    &NodeId::from(MethodId::AcknowledgeableConditionType_Acknowledge),
                    ReferenceTypeId::HasComponent,
                );
                space.insert_reference(&self.object, &node, ReferenceTypeId::HasCondition);
                (kind, node)
            })
            .collect()
    }

    /// The methods, with their arguments.
    fn methods(&self, space: &mut AddressSpace) -> Vec<(Method, NodeId)> {
        let (ns, object) = (self.ns, &self.object);
        let mut methods = Vec::with_capacity(Method::ALL.len());
        for m in Method::ALL {
            let node = self.id(m.name());
            let mut builder = MethodBuilder::new(&node, QualifiedName::new(ns, m.name()), m.name())
                .description(m.description())
                .executable(true)
                .user_executable(true)
                .component_of(object.clone());
            if m == Method::Load {
                builder = builder.input_args(
                    space,
                    &self.id("Load.InputArguments"),
                    &[("Program", DataTypeId::Int16).into()],
                );
            }
            builder = builder.output_args(
                space,
                &self.id(&format!("{}.OutputArguments", m.name())),
                &[("Result", DataTypeId::String).into()],
            );
            builder.insert(space);
            methods.push((m, node));
        }

        methods
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::snapshot::Snapshot;

    /// No programs, screen jobs or tool table.
    fn no_sources() -> crate::services::opcua::machine_tool::Sources {
        crate::services::opcua::machine_tool::Sources {
            programs: Vec::new(),
            jobs: None,
            tools: None,
            library: None,
        }
    }

    fn info() -> SpaceInfo {
        let var = |name: &str, ty: VarType, range: Option<[f64; 2]>| VarNode {
            name: name.to_string(),
            ty,
            class: 0,
            writer: "program main".into(),
            range,
        };
        SpaceInfo {
            machine: "ox-x".into(),
            config: "ox-x.json".into(),
            classes: vec![("main".into(), 50_000_000)],
            variables: vec![
                var("JOINT1_REFERENCE", VarType::Bool, None),
                var("TOOL_X", VarType::Real, Some([-40.0, 40.0])),
                var("JOINT1_POSITION", VarType::Real, None),
                var("NC_STATE", VarType::Int, None),
            ],
            programs: vec![],
            nameplate: None,
        }
    }

    fn frame(state: &str, values: Vec<(&'static str, f64)>, published_unix_us: u64) -> Frame {
        Frame {
            seq: 1,
            status: Snapshot {
                state: state.into(),
                values,
                ..Snapshot::default()
            },
            image: vec![Value::Bool(true), Value::Real(1.5), Value::Real(2.0), Value::Int(1)],
            bus_fault: false,
            bus_cause: String::new(),
            published_unix_us,
        }
    }

    /// The node `path` below the machine, in `space`.
    fn node(space: &Space, path: &str) -> NodeId {
        NodeId::new(space.ns, format!("{}.{path}", space.machine))
    }

    #[test]
    fn the_state_has_its_number_the_line_is_an_integer_and_a_value_never_dates_from_1970() {
        let mut address_space = AddressSpace::new();
        address_space.add_namespace(NAMESPACE, 1);
        let ns = 1;
        let before = DateTime::now();
        let first = frame("", vec![], 0);
        let mut space = Space::build(&mut address_space, ns, &info(), &first, no_sources());
        // Before the first cycle published anything, values carry the time they were known.
        let changes = space.changes(&mut address_space, &first);
        assert!(!changes.is_empty());
        for (id, v) in &changes {
            let at = v
                .source_timestamp
                .unwrap_or_else(|| panic!("{id}: no source timestamp"));
            assert!(at >= before, "{id}: {at}");
        }
        // No state yet: MainState waits for one.
        let main = changes
            .iter()
            .find(|(id, _)| *id == node(&space, "MainState"))
            .expect("MainState");
        assert_eq!(main.1.status, Some(StatusCode::BadWaitingForInitialData));

        let running = frame("AUTO", vec![("line", 12.0), ("x", 1.25)], 1_795_000_000_000_000);
        let changes = space.changes(&mut address_space, &running);
        let value = |path: &str| {
            changes
                .iter()
                .find(|(id, _)| *id == node(&space, path))
                .and_then(|(_, v)| v.value.clone())
                .unwrap_or_else(|| panic!("{path}: no change"))
        };
        assert_eq!(value("MainState"), Variant::UInt32(5));
        assert_eq!(MAIN_STATES[5], "AUTO");
        assert_eq!(value("State"), Variant::from("AUTO"));
        assert_eq!(value("Status.line"), Variant::UInt32(12));
        assert_eq!(value("Status.x"), Variant::Double(1.25));
        // The published time, not the time of the read.
        let (_, v) = changes
            .iter()
            .find(|(id, _)| *id == node(&space, "State"))
            .expect("State");
        assert_eq!(v.source_timestamp, Some(date_time(1_795_000_000_000_000)));
    }

    #[test]
    fn a_switch_has_no_unit_and_an_analog_item_has_its_range() {
        let mut address_space = AddressSpace::new();
        address_space.add_namespace(NAMESPACE, 1);
        let ns = 1;
        let space = Space::build(&mut address_space, ns, &info(), &frame("", vec![], 0), no_sources());
        let has = |path: &str| address_space.find(&node(&space, path)).is_some();
        // JOINT1_REFERENCE reads as a length by its name, but it is a BOOL: a switch.
        assert!(!has("JOINT1_REFERENCE.EngineeringUnits"));
        assert!(has("TOOL_X.EngineeringUnits") && has("TOOL_X.EURange"));
        // A counter's position since power-on: a unit, no range.
        assert!(has("JOINT1_POSITION.EngineeringUnits") && !has("JOINT1_POSITION.EURange"));
        let typed = |path: &str, ty: VariableTypeId| {
            let ty: NodeId = ty.into();
            let id = node(&space, path);
            address_space.has_reference(&id, &ty, &NodeId::from(ReferenceTypeId::HasTypeDefinition))
        };
        assert!(typed("TOOL_X", VariableTypeId::AnalogItemType));
        assert!(typed("JOINT1_POSITION", VariableTypeId::BaseAnalogType));
        assert!(!typed("JOINT1_POSITION", VariableTypeId::AnalogItemType));
        assert!(typed("JOINT1_REFERENCE", VariableTypeId::BaseDataVariableType));
        assert!(typed("MainState", VariableTypeId::MultiStateDiscreteType));
    }

    #[test]
    fn the_machine_is_in_machinerys_machines_folder_with_its_nameplate_and_states() {
        use super::super::companion::{self, DI, MACHINERY, Nameplate};
        let mut address_space = AddressSpace::new();
        let mut namespaces = opcua::types::NamespaceMap::new();
        let ns = namespaces.add_namespace(NAMESPACE);
        address_space.add_namespace(NAMESPACE, ns);
        for import in companion::imports().expect("the node sets") {
            address_space.import_node_set(&import, &mut namespaces);
        }
        let index = |uri: &str| *namespaces.known_namespaces().get(uri).expect("loaded");
        let (di, m) = (index(DI), index(MACHINERY));
        let mut info = info();
        info.nameplate = Some(Nameplate::new(
            &Default::default(),
            "ox-x",
            "O-X glide, crossed X configuration: …",
            "lab-pc",
        ));
        let mut space = Space::build(&mut address_space, ns, &info, &frame("", vec![], 0), no_sources());
        let organizes = NodeId::from(ReferenceTypeId::Organizes);
        assert!(address_space.has_reference(&NodeId::new(m, 1001u32), &space.object, &organizes));
        // Browse names in the companions' namespaces, as an MES browses them.
        let browse = |path: &str| {
            address_space
                .find(&node(&space, path))
                .map(|n| n.as_node().browse_name().clone())
                .unwrap_or_else(|| panic!("{path}: no node"))
        };
        assert_eq!(browse("Identification"), QualifiedName::new(di, "Identification"));
        assert_eq!(
            browse("Identification.SerialNumber"),
            QualifiedName::new(di, "SerialNumber")
        );
        assert_eq!(
            browse("MachineryBuildingBlocks.MachineryItemState"),
            QualifiedName::new(m, "MachineryItemState")
        );
        let current = |changes: &[(NodeId, DataValue)], machine: &str| {
            let id = NodeId::new(ns, format!("ox-x.MachineryBuildingBlocks.{machine}.CurrentState"));
            changes
                .iter()
                .find(|(n, _)| *n == id)
                .and_then(|(_, v)| v.value.clone())
        };
        let text = |s: &str| Some(Variant::from(LocalizedText::new("en", s)));
        let changes = space.changes(&mut address_space, &frame("AUTO", vec![], 1));
        assert_eq!(current(&changes, "MachineryItemState"), text("Executing"));
        assert_eq!(current(&changes, "MachineryOperationMode"), text("Processing"));
        // The same states: nothing to write.
        let changes = space.changes(&mut address_space, &frame("AUTO", vec![("x", 1.0)], 2));
        assert_eq!(current(&changes, "MachineryItemState"), None);
        let changes = space.changes(&mut address_space, &frame("ERROR", vec![], 3));
        assert_eq!(current(&changes, "MachineryItemState"), text("OutOfService"));
        assert_eq!(current(&changes, "MachineryOperationMode"), text("None"));
        let id = NodeId::new(ns, "ox-x.MachineryBuildingBlocks.MachineryItemState.CurrentState.Id");
        let id = changes
            .iter()
            .find(|(n, _)| *n == id)
            .and_then(|(_, v)| v.value.clone());
        assert_eq!(id, Some(Variant::from(NodeId::new(m, 5004u32))));
    }
}
