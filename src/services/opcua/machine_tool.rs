//! OPC 40501-1 Machine Tools: what the machine tool is doing, as the umati dashboard, an MES or
//! a machine-tool builder's tools read it. Built on Machinery ([`super::companion`]): the
//! machine's object is typed `MachineToolType`, and gets the type's building blocks:
//!
//! ```text
//! MACHINE                                  MachineToolType
//! ├─ Identification                        MachineToolIdentificationType (the nameplate)
//! ├─ Monitoring                            MonitoringType
//! │  ├─ MachineTool                        MachineOperationMonitoringType: OperationMode
//! │  ├─ Channel1                           ChannelMonitoringType: ChannelState, ChannelMode,
//! │  │                                     FeedOverride, RapidOverride
//! │  └─ Spindle                            SpindleMonitoringType: IsRotating, Override
//! ├─ Production                            ProductionType
//! │  ├─ ActiveProgram                      Name, NumberInList, State, JobIdentifier
//! │  └─ ProductionPlan/Job                 ProductionJobType: Identifier, RunsPlanned,
//! │                                        RunsCompleted, State, ProductionPrograms
//! ├─ Notification                          NotificationType
//! │  ├─ Messages                           the alarms' events are emitted here too
//! │  └─ Prognoses                          ToolChange while a manual tool change is ahead or due
//! └─ Equipment/Tools                       a ToolType per tool of the tool table
//! ```
//!
//! The published NodeSet (1.02) and the two it needs (Machinery Jobs, ISA-95 job control) are
//! loaded with the others; every value follows the frames ([`MachineTool::changes`]) and the
//! tool table as it changes.

use std::sync::Arc;

use opcua::server::address_space::{AccessLevel, AddressSpace, EventNotifier, ObjectBuilder, VariableBuilder};
use opcua::types::{
    DataTypeId, DataValue, DateTime, EUInformation, ExtensionObject, LocalizedText, NodeId, ObjectTypeId,
    QualifiedName, Range, ReferenceTypeId, UAString, VariableTypeId, Variant,
};
use pkm_api::library::NcLibrary;
use pkm_api::trajectory::TrajectoryEventKind;
use pkm_drives::nc::RunState;

use crate::image::Value;
use crate::runtime::frame::Frame;
use crate::runtime::tool_table::ToolTableKeeper;
use crate::services::hmi::job_news::JobNews;

/// OPC 40501-1 Machine Tools.
pub const MACHINE_TOOL: &str = "http://opcfoundation.org/UA/MachineTool/";

/// The node numbers of the Machine Tools namespace this view uses.
mod ids {
    pub const MACHINE_TOOL_TYPE: u32 = 13;
    pub const IDENTIFICATION_TYPE: u32 = 11;
    pub const MONITORING_TYPE: u32 = 14;
    pub const OPERATION_MONITORING_TYPE: u32 = 26;
    pub const CHANNEL_MONITORING_TYPE: u32 = 16;
    pub const SPINDLE_MONITORING_TYPE: u32 = 22;
    pub const PRODUCTION_TYPE: u32 = 21;
    pub const ACTIVE_PROGRAM_TYPE: u32 = 32;
    pub const PROGRAM_TYPE: u32 = 59;
    pub const PROGRAM_STATE_MACHINE_TYPE: u32 = 15;
    pub const JOB_LIST_TYPE: u32 = 30;
    pub const JOB_TYPE: u32 = 29;
    pub const JOB_STATE_MACHINE_TYPE: u32 = 28;
    pub const NOTIFICATION_TYPE: u32 = 7;
    pub const MESSAGES_TYPE: u32 = 38;
    pub const NOTIFICATION_EVENT_TYPE: u32 = 35;
    pub const PROGNOSIS_LIST_TYPE: u32 = 2;
    pub const TOOL_CHANGE_PROGNOSIS_TYPE: u32 = 45;
    pub const EQUIPMENT_TYPE: u32 = 12;
    pub const TOOL_LIST_TYPE: u32 = 44;
    pub const TOOL_TYPE: u32 = 50;
    /// The enumerations.
    pub const MACHINE_OPERATION_MODE: u32 = 65;
    pub const CHANNEL_STATE: u32 = 64;
    pub const CHANNEL_MODE: u32 = 67;
    pub const TOOL_MANAGEMENT: u32 = 69;
    pub const TOOL_LOCKED: u32 = 66;
}

/// The type the nameplate's `Identification` has where the Machine Tools model is loaded
/// (`MachineToolIdentificationType`, a subtype of Machinery's), in namespace `mt`.
pub fn identification_type(mt: u16) -> NodeId {
    NodeId::new(mt, ids::IDENTIFICATION_TYPE)
}

/// The machine tool's operation mode (`MachineOperationMode`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OperationMode {
    /// Manual: jogging, or waiting in READY.
    Manual = 0,
    /// Automatic: an NC program (AUTO).
    Automatic = 1,
    /// Setup: the runtime starting, the joints referencing.
    Setup = 2,
    /// Other: ERROR, or outside the automaton.
    Other = 5,
}

/// The NC channel's state (`ChannelState`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ChannelState {
    /// A program runs, or the axes move.
    Active = 0,
    /// A program stands: held, at an M0, a single block, a tool change, a wait for an input.
    Interrupted = 1,
    /// Nothing runs.
    Reset = 2,
}

/// The NC channel's mode (`ChannelMode`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ChannelMode {
    /// A program (AUTO).
    Automatic = 0,
    /// Jogging (MOTION, and READY, from where the operator jogs or starts).
    JogManual = 2,
    /// Referencing (INIT).
    Reference = 6,
    /// The runtime starting, ERROR, outside the automaton.
    Other = 7,
}

/// The state of the active program and of its job (`ProductionProgramStateMachineType`,
/// `ProductionJobStateMachineType`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Production {
    /// Loaded, not started (or started again: each start is a new run).
    Initializing,
    /// Running.
    Running,
    /// Run to its end.
    Ended,
    /// Standing in the middle: held, at an M0, a single block, a tool change.
    Interrupted,
    /// Stopped before its end: ERROR, or left standing in the middle.
    Aborted,
}

impl Production {
    /// Its state's browse name, its node number in the program's and in the job's state
    /// machine type, and its state number.
    fn state(self) -> (&'static str, u32, u32, u32) {
        match self {
            Production::Initializing => ("Initializing", 5039, 5015, 0),
            Production::Running => ("Running", 5041, 5017, 1),
            Production::Ended => ("Ended", 5038, 5014, 2),
            Production::Interrupted => ("Interrupted", 5040, 5016, 3),
            Production::Aborted => ("Aborted", 5037, 5013, 4),
        }
    }
}

/// The machine tool's operation mode in the PLC's main state `state`.
pub fn operation_mode(state: &str) -> OperationMode {
    match state {
        "REBOOT" | "INIT" => OperationMode::Setup,
        "READY" | "MOTION" => OperationMode::Manual,
        "AUTO" => OperationMode::Automatic,
        _ => OperationMode::Other,
    }
}

/// The channel's state and mode in main state `state` with the NC executor in `nc`.
pub fn channel(state: &str, nc: Option<RunState>) -> (ChannelState, ChannelMode) {
    match state {
        "AUTO" => (
            match nc {
                Some(RunState::Running | RunState::Holding | RunState::Idle) | None => ChannelState::Active,
                Some(RunState::Done) => ChannelState::Reset,
                Some(_) => ChannelState::Interrupted,
            },
            ChannelMode::Automatic,
        ),
        "INIT" => (ChannelState::Reset, ChannelMode::Reference),
        "MOTION" => (ChannelState::Active, ChannelMode::JogManual),
        "READY" => (ChannelState::Reset, ChannelMode::JogManual),
        _ => (ChannelState::Reset, ChannelMode::Other),
    }
}

/// The active program's state after `previous`, in main state `state` with the NC executor in
/// `nc`; `loaded` says another program was loaded since.
///
/// | PLC | state |
/// |---|---|
/// | AUTO, the tool moving (or starting) | Running |
/// | AUTO, at the program's end | Ended |
/// | AUTO, standing in the middle | Interrupted |
/// | ERROR after Running or Interrupted | Aborted |
/// | out of AUTO from Running (its end) | Ended |
/// | out of AUTO from Interrupted | Aborted |
/// | another program loaded | Initializing |
/// | otherwise | as it was |
pub fn next_production(previous: Production, state: &str, nc: Option<RunState>, loaded: bool) -> Production {
    if state == "AUTO" {
        return match nc {
            Some(RunState::Running | RunState::Holding | RunState::Idle) | None => Production::Running,
            Some(RunState::Done) => Production::Ended,
            Some(_) => Production::Interrupted,
        };
    }
    match previous {
        Production::Running if state == "ERROR" => Production::Aborted,
        Production::Running => Production::Ended,
        Production::Interrupted => Production::Aborted,
        _ if loaded => Production::Initializing,
        other => other,
    }
}

/// What the view shows, to write only what changed.
#[derive(Clone, Debug, PartialEq)]
struct Shown {
    operation_mode: OperationMode,
    channel: (ChannelState, ChannelMode),
    feed_override: f64,
    rapid_override: f64,
    spindle: (bool, f64),
    program: String,
    production: Production,
    /// The job's runs: completed, and planned (the completed ones and the one loaded, running
    /// or stopped short; at least 1).
    runs: (u32, u32),
}

/// The runs of the loaded program's job, planned: those completed, and one more unless the
/// last has ended (the one loaded, running, or stopped short); at least one.
pub fn runs_planned(completed: u32, production: Production) -> u32 {
    match production {
        Production::Ended => completed.max(1),
        _ => completed + 1,
    }
}

/// Where the variables the view reads are in the process image.
#[derive(Clone, Copy, Debug, Default)]
struct Indices {
    nc_state: Option<usize>,
    nc_program: Option<usize>,
    feed_override: Option<usize>,
    rapid_override: Option<usize>,
    spindle_override: Option<usize>,
    spindle_on: Option<usize>,
    spindle_rpm: Option<usize>,
    tool_change_number: Option<usize>,
    nc_time_s: Option<usize>,
}

/// The nodes a frame writes.
struct Nodes {
    operation_mode: NodeId,
    channel_state: NodeId,
    channel_mode: NodeId,
    feed_override: NodeId,
    rapid_override: NodeId,
    spindle: Option<(NodeId, NodeId)>,
    /// The active program's name, the job's identifier, the job's program's name, the active
    /// program's job identifier: each the loaded program's name.
    program_names: Vec<NodeId>,
    program_state: [NodeId; 3],
    job_state: [NodeId; 3],
    runs_completed: NodeId,
    runs_planned: NodeId,
}

/// A tool change prognosis shown: its node and children (`PredictedTime` second), the tool,
/// the time it predicts.
struct Prognosis {
    nodes: Vec<NodeId>,
    tool: u32,
    predicted: DateTime,
}

/// What the view needs beside the frames: the run's programs by number, the screen's jobs, the
/// tool table.
pub struct Sources {
    /// The run's NC programs (files), numbered from 1 as `NC_PROGRAM` holds them.
    pub programs: Vec<String>,
    /// What became of the screen's jobs (the name of a job the screen loaded).
    pub jobs: Option<tokio::sync::watch::Receiver<JobNews>>,
    /// The tool table, as it changes.
    pub tools: Option<Arc<ToolTableKeeper>>,
    /// The run's programs and screen jobs as planned (the next tool change on their time line).
    pub library: Option<NcLibrary>,
}

/// The Machine Tools view of a built address space and what it last showed.
pub struct MachineTool {
    mt: u16,
    ns: u16,
    machine: String,
    indices: Indices,
    nodes: Nodes,
    sources: Sources,
    /// The `Notification/Messages` object, where the alarms' events are emitted too.
    pub messages: NodeId,
    prognoses: NodeId,
    /// The tool change prognosis while one is ahead or due.
    prognosis: Option<Prognosis>,
    tools_list: NodeId,
    /// The tools' nodes (each tool's object and its children), and the tool table's change
    /// count they show.
    tool_nodes: Vec<NodeId>,
    tools_seen: Option<u64>,
    /// The loaded program, by its number and (for a screen job) the job's count.
    loaded: Option<(i16, u64)>,
    production: Production,
    runs_completed: u32,
    last: Option<Shown>,
}

/// A number of the image at `index`, if it is one.
fn number(frame: &Frame, index: Option<usize>) -> Option<f64> {
    match frame.image.get(index?)? {
        Value::Bool(b) => Some(f64::from(u8::from(*b))),
        Value::Int(v) => Some(f64::from(*v)),
        Value::Uint(v) => Some(f64::from(*v)),
        Value::Dint(v) => Some(f64::from(*v)),
        Value::Real(v) => Some(*v),
    }
}

/// Builds nodes below the machine, each id `MACHINE.path`.
struct Build<'a> {
    space: &'a mut AddressSpace,
    mt: u16,
    ns: u16,
    machine: &'a str,
}

impl Build<'_> {
    fn id(&self, path: &str) -> NodeId {
        NodeId::new(self.ns, format!("{}.{path}", self.machine))
    }

    /// An object `name` (browse name in `browse_ns`) of Machine Tools type `ty`, a component of
    /// `parent`.
    fn object(&mut self, path: &str, (browse_ns, name): (u16, &str), ty: NodeId, parent: &NodeId) -> NodeId {
        let node = self.id(path);
        ObjectBuilder::new(&node, QualifiedName::new(browse_ns, name), name)
            .has_type_definition(ty)
            .component_of(parent.clone())
            .insert(self.space);
        node
    }

    /// A variable of `parent`: a property (`PropertyType`) or a component of `ty`.
    fn variable(
        &mut self,
        path: &str,
        (browse_ns, name): (u16, &str),
        (data_type, value): (NodeId, Variant),
        ty: Option<VariableTypeId>,
        parent: &NodeId,
    ) -> NodeId {
        let node = self.id(path);
        let builder = VariableBuilder::new(&node, QualifiedName::new(browse_ns, name), name)
            .data_type(data_type)
            .value(value)
            .access_level(AccessLevel::CURRENT_READ)
            .user_access_level(AccessLevel::CURRENT_READ);
        match ty {
            None => builder
                .has_type_definition(VariableTypeId::PropertyType)
                .property_of(parent.clone())
                .insert(self.space),
            Some(ty) => builder
                .has_type_definition(ty)
                .component_of(parent.clone())
                .insert(self.space),
        };
        node
    }

    /// An override in percent (`AnalogUnitRangeType`: its range and unit as properties).
    fn override_percent(&mut self, path: &str, name: &str, value: f64, high: f64, parent: &NodeId) -> NodeId {
        let node = self.variable(
            path,
            (self.mt, name),
            (DataTypeId::Double.into(), Variant::Double(value)),
            Some(VariableTypeId::AnalogUnitRangeType),
            parent,
        );
        let unit = super::units::PERCENT;
        let eu = EUInformation {
            namespace_uri: UAString::from(super::units::UNECE_NAMESPACE),
            unit_id: unit.unit_id(),
            display_name: LocalizedText::new("", unit.symbol),
            description: LocalizedText::new("", unit.name),
        };
        self.variable(
            &format!("{path}.EngineeringUnits"),
            (0, "EngineeringUnits"),
            (
                DataTypeId::EUInformation.into(),
                Variant::from(ExtensionObject::from_message(eu)),
            ),
            None,
            &node,
        );
        self.variable(
            &format!("{path}.EURange"),
            (0, "EURange"),
            (
                DataTypeId::Range.into(),
                Variant::from(ExtensionObject::from_message(Range { low: 0.0, high })),
            ),
            None,
            &node,
        );
        node
    }

    /// An enumeration variable of Machine Tools' enumeration `enumeration`.
    fn enumeration(&mut self, path: &str, name: &str, enumeration: u32, value: i32, parent: &NodeId) -> NodeId {
        self.variable(
            path,
            (self.mt, name),
            (NodeId::new(self.mt, enumeration), Variant::Int32(value)),
            Some(VariableTypeId::BaseDataVariableType),
            parent,
        )
    }

    /// A state machine `State` of Machine Tools type `ty` with its `CurrentState` (`Id`,
    /// `Number`) in `state`, a component of `parent`: the three nodes a change writes.
    fn state_machine(
        &mut self,
        path: &str,
        ty: u32,
        (name, node, number): (&str, u32, u32),
        parent: &NodeId,
    ) -> [NodeId; 3] {
        let machine = self.object(path, (self.mt, "State"), NodeId::new(self.mt, ty), parent);
        let current = self.variable(
            &format!("{path}.CurrentState"),
            (0, "CurrentState"),
            (
                DataTypeId::LocalizedText.into(),
                Variant::from(LocalizedText::new("en", name)),
            ),
            Some(VariableTypeId::FiniteStateVariableType),
            &machine,
        );
        let id = self.variable(
            &format!("{path}.CurrentState.Id"),
            (0, "Id"),
            (DataTypeId::NodeId.into(), Variant::from(NodeId::new(self.mt, node))),
            None,
            &current,
        );
        let number = self.variable(
            &format!("{path}.CurrentState.Number"),
            (0, "Number"),
            (DataTypeId::UInt32.into(), Variant::UInt32(number)),
            None,
            &current,
        );
        [current, id, number]
    }
}

impl MachineTool {
    /// Builds the view of `machine` (its object `object`, in namespace `ns`, typed
    /// `MachineToolType` by the caller) into `space`, where the Machine Tools model is loaded
    /// (`None` if it is not); `variables` are the process image's names in order.
    pub fn build(
        space: &mut AddressSpace,
        (ns, machine, object): (u16, &str, &NodeId),
        variables: &[&str],
        sources: Sources,
    ) -> Option<MachineTool> {
        let mt = machine_tool_namespace(space)?;
        let at = |name: &str| variables.iter().position(|v| *v == name);
        let indices = Indices {
            nc_state: at("NC_STATE"),
            nc_program: at("NC_PROGRAM"),
            feed_override: at("NC_FEED_OVERRIDE"),
            rapid_override: at("NC_RAPID_OVERRIDE"),
            spindle_override: at("NC_SPINDLE_OVERRIDE"),
            spindle_on: at("SPINDLE_ON"),
            spindle_rpm: at("SPINDLE_RPM"),
            tool_change_number: at("TOOL_CHANGE_NUMBER"),
            nc_time_s: at("NC_TIME_S"),
        };
        let mut b = Build { space, mt, ns, machine };
        let t = |n: u32| NodeId::new(mt, n);

        let monitoring = b.object("Monitoring", (mt, "Monitoring"), t(ids::MONITORING_TYPE), object);
        let operation = b.object(
            "Monitoring.MachineTool",
            (mt, "MachineTool"),
            t(ids::OPERATION_MONITORING_TYPE),
            &monitoring,
        );
        let operation_mode = b.enumeration(
            "Monitoring.MachineTool.OperationMode",
            "OperationMode",
            ids::MACHINE_OPERATION_MODE,
            OperationMode::Other as i32,
            &operation,
        );
        let channel = b.object(
            "Monitoring.Channel1",
            (mt, "Channel1"),
            t(ids::CHANNEL_MONITORING_TYPE),
            &monitoring,
        );
        b.variable(
            "Monitoring.Channel1.Name",
            (mt, "Name"),
            (DataTypeId::String.into(), Variant::from("Channel1")),
            None,
            &channel,
        );
        let channel_state = b.enumeration(
            "Monitoring.Channel1.ChannelState",
            "ChannelState",
            ids::CHANNEL_STATE,
            ChannelState::Reset as i32,
            &channel,
        );
        let channel_mode = b.enumeration(
            "Monitoring.Channel1.ChannelMode",
            "ChannelMode",
            ids::CHANNEL_MODE,
            ChannelMode::Other as i32,
            &channel,
        );
        let feed_override = b.override_percent(
            "Monitoring.Channel1.FeedOverride",
            "FeedOverride",
            100.0,
            150.0,
            &channel,
        );
        let rapid_override = b.override_percent(
            "Monitoring.Channel1.RapidOverride",
            "RapidOverride",
            100.0,
            100.0,
            &channel,
        );
        let spindle = (indices.spindle_on.is_some() || indices.spindle_rpm.is_some()).then(|| {
            let spindle = b.object(
                "Monitoring.Spindle",
                (mt, "Spindle"),
                t(ids::SPINDLE_MONITORING_TYPE),
                &monitoring,
            );
            b.variable(
                "Monitoring.Spindle.Name",
                (mt, "Name"),
                (DataTypeId::String.into(), Variant::from("Spindle")),
                None,
                &spindle,
            );
            let rotating = b.variable(
                "Monitoring.Spindle.IsRotating",
                (mt, "IsRotating"),
                (DataTypeId::Boolean.into(), Variant::Boolean(false)),
                Some(VariableTypeId::BaseDataVariableType),
                &spindle,
            );
            let spindle_override =
                b.override_percent("Monitoring.Spindle.Override", "Override", 100.0, 150.0, &spindle);
            (rotating, spindle_override)
        });

        let production = b.object("Production", (mt, "Production"), t(ids::PRODUCTION_TYPE), object);
        let active = b.object(
            "Production.ActiveProgram",
            (mt, "ActiveProgram"),
            t(ids::ACTIVE_PROGRAM_TYPE),
            &production,
        );
        let initial = Production::Initializing.state();
        let active_name = b.variable(
            "Production.ActiveProgram.Name",
            (mt, "Name"),
            (DataTypeId::String.into(), Variant::from("")),
            None,
            &active,
        );
        b.variable(
            "Production.ActiveProgram.NumberInList",
            (0, "NumberInList"),
            (DataTypeId::UInt16.into(), Variant::UInt16(0)),
            None,
            &active,
        );
        let program_state = b.state_machine(
            "Production.ActiveProgram.State",
            ids::PROGRAM_STATE_MACHINE_TYPE,
            (initial.0, initial.1, initial.3),
            &active,
        );
        let job_identifier = b.variable(
            "Production.ActiveProgram.JobIdentifier",
            (mt, "JobIdentifier"),
            (DataTypeId::String.into(), Variant::from("")),
            Some(VariableTypeId::BaseDataVariableType),
            &active,
        );
        let plan = b.object(
            "Production.ProductionPlan",
            (mt, "ProductionPlan"),
            t(ids::JOB_LIST_TYPE),
            &production,
        );
        let job = b.object("Production.ProductionPlan.Job", (ns, "Job"), t(ids::JOB_TYPE), &plan);
        let job_name = b.variable(
            "Production.ProductionPlan.Job.Identifier",
            (mt, "Identifier"),
            (DataTypeId::String.into(), Variant::from("")),
            None,
            &job,
        );
        b.variable(
            "Production.ProductionPlan.Job.NumberInList",
            (0, "NumberInList"),
            (DataTypeId::UInt16.into(), Variant::UInt16(0)),
            None,
            &job,
        );
        let runs_planned = b.variable(
            "Production.ProductionPlan.Job.RunsPlanned",
            (mt, "RunsPlanned"),
            (DataTypeId::UInt32.into(), Variant::UInt32(1)),
            Some(VariableTypeId::BaseDataVariableType),
            &job,
        );
        // The runs are counted, so their number is known.
        b.variable(
            "Production.ProductionPlan.Job.RunsPlanned.IsValid",
            (mt, "IsValid"),
            (DataTypeId::Boolean.into(), Variant::Boolean(true)),
            None,
            &runs_planned,
        );
        let runs_completed = b.variable(
            "Production.ProductionPlan.Job.RunsCompleted",
            (mt, "RunsCompleted"),
            (DataTypeId::UInt32.into(), Variant::UInt32(0)),
            Some(VariableTypeId::BaseDataVariableType),
            &job,
        );
        let job_state = b.state_machine(
            "Production.ProductionPlan.Job.State",
            ids::JOB_STATE_MACHINE_TYPE,
            (initial.0, initial.2, initial.3),
            &job,
        );
        let programs = b.object(
            "Production.ProductionPlan.Job.ProductionPrograms",
            (mt, "ProductionPrograms"),
            ObjectTypeId::OrderedListType.into(),
            &job,
        );
        let listed = b.object(
            "Production.ProductionPlan.Job.ProductionPrograms.Program",
            (ns, "Program"),
            t(ids::PROGRAM_TYPE),
            &programs,
        );
        let listed_name = b.variable(
            "Production.ProductionPlan.Job.ProductionPrograms.Program.Name",
            (mt, "Name"),
            (DataTypeId::String.into(), Variant::from("")),
            None,
            &listed,
        );
        b.variable(
            "Production.ProductionPlan.Job.ProductionPrograms.Program.NumberInList",
            (0, "NumberInList"),
            (DataTypeId::UInt16.into(), Variant::UInt16(0)),
            None,
            &listed,
        );

        let notification = b.object("Notification", (mt, "Notification"), t(ids::NOTIFICATION_TYPE), object);
        let messages = b.id("Notification.Messages");
        ObjectBuilder::new(&messages, QualifiedName::new(mt, "Messages"), "Messages")
            .description("the machine's alarms: their events are emitted here (and on the machine's object)")
            .has_type_definition(t(ids::MESSAGES_TYPE))
            .event_notifier(EventNotifier::SUBSCRIBE_TO_EVENTS)
            .component_of(notification.clone())
            .insert(b.space);
        b.space.insert_reference(
            &messages,
            &t(ids::NOTIFICATION_EVENT_TYPE),
            ReferenceTypeId::GeneratesEvent,
        );
        let prognoses = b.object(
            "Notification.Prognoses",
            (mt, "Prognoses"),
            t(ids::PROGNOSIS_LIST_TYPE),
            &notification,
        );

        let equipment = b.object("Equipment", (mt, "Equipment"), t(ids::EQUIPMENT_TYPE), object);
        let tools_list = b.object("Equipment.Tools", (mt, "Tools"), t(ids::TOOL_LIST_TYPE), &equipment);

        Some(MachineTool {
            mt,
            ns,
            machine: machine.to_string(),
            indices,
            nodes: Nodes {
                operation_mode,
                channel_state,
                channel_mode,
                feed_override,
                rapid_override,
                spindle,
                program_names: vec![active_name, job_name, listed_name, job_identifier],
                program_state,
                job_state,
                runs_completed,
                runs_planned,
            },
            sources,
            messages,
            prognoses,
            prognosis: None,
            tools_list,
            tool_nodes: Vec::new(),
            tools_seen: None,
            loaded: None,
            production: Production::Initializing,
            runs_completed: 0,
            last: None,
        })
    }

    /// The nodes [`MachineTool::changes`] writes (the tools' and the prognosis' are written
    /// when made).
    pub fn nodes(&self) -> impl Iterator<Item = &NodeId> {
        let n = &self.nodes;
        [
            &n.operation_mode,
            &n.channel_state,
            &n.channel_mode,
            &n.feed_override,
            &n.rapid_override,
            &n.runs_completed,
            &n.runs_planned,
        ]
        .into_iter()
        .chain(n.spindle.iter().flat_map(|(a, b)| [a, b]))
        .chain(&n.program_names)
        .chain(&n.program_state)
        .chain(&n.job_state)
    }

    /// Forgets what was published: the next frame writes every value again.
    pub fn forget(&mut self) {
        self.last = None;
    }

    /// The name of the program loaded as number `k` (`NC_PROGRAM`): one of the run's, or the
    /// job the screen loaded last; empty when nothing is loaded.
    fn program_name(&self, k: i16) -> String {
        if let Some(file) = usize::try_from(k)
            .ok()
            .and_then(|k| k.checked_sub(1))
            .and_then(|k| self.sources.programs.get(k))
        {
            return file.clone();
        }
        if k <= 0 {
            return String::new();
        }
        match self.sources.jobs.as_ref().and_then(|j| j.borrow().loaded.clone()) {
            Some(file) => file,
            None => format!("job {k}"),
        }
    }

    /// The changes `frame` brings, as `value` stamps them; the tool table's and a due tool
    /// change's nodes are made (and unmade) in `space` as they change.
    pub fn changes(
        &mut self,
        space: &mut AddressSpace,
        frame: &Frame,
        value: impl Fn(Variant) -> DataValue,
    ) -> Vec<(NodeId, DataValue)> {
        self.refresh_tools(space);
        let state = frame.status.state.as_str();
        let nc = number(frame, self.indices.nc_state).and_then(|c| RunState::from_code(c as i16));
        let k = number(frame, self.indices.nc_program).map_or(0, |k| k as i16);
        let next = self.next_tool_change(frame, state, nc, k);
        let mut out = Vec::new();
        self.tool_change_prognosis(space, next, &value, &mut out);
        // A job made is a new load; a refused one leaves the load as it was.
        let job_count = self.sources.jobs.as_ref().map_or(0, |j| j.borrow().made);
        let loaded_key = (
            k,
            if usize::try_from(k).is_ok_and(|k| k <= self.sources.programs.len()) {
                0
            } else {
                job_count
            },
        );
        let loaded = self.loaded.is_some_and(|was| was != loaded_key);
        if loaded || self.loaded.is_none() {
            self.runs_completed = 0;
        }
        self.loaded = Some(loaded_key);
        let production = next_production(self.production, state, nc, loaded);
        if production == Production::Ended && self.production != Production::Ended {
            self.runs_completed += 1;
        }
        // A start after an end or an abort is a new run of the job.
        self.production = production;
        let spindle_rpm = number(frame, self.indices.spindle_rpm).unwrap_or(0.0);
        let now = Shown {
            operation_mode: operation_mode(state),
            channel: channel(state, nc),
            feed_override: number(frame, self.indices.feed_override).unwrap_or(100.0),
            rapid_override: number(frame, self.indices.rapid_override).unwrap_or(100.0),
            spindle: (
                number(frame, self.indices.spindle_on).is_some_and(|on| on != 0.0) || spindle_rpm != 0.0,
                number(frame, self.indices.spindle_override).unwrap_or(100.0),
            ),
            program: self.program_name(k),
            production,
            runs: (self.runs_completed, runs_planned(self.runs_completed, production)),
        };
        let last = self.last.replace(now.clone());
        let changed = |f: &dyn Fn(&Shown) -> bool| last.as_ref().is_none_or(f);
        let n = &self.nodes;
        if changed(&|l| l.operation_mode != now.operation_mode) {
            out.push((
                n.operation_mode.clone(),
                value(Variant::Int32(now.operation_mode as i32)),
            ));
        }
        if changed(&|l| l.channel != now.channel) {
            out.push((n.channel_state.clone(), value(Variant::Int32(now.channel.0 as i32))));
            out.push((n.channel_mode.clone(), value(Variant::Int32(now.channel.1 as i32))));
        }
        if changed(&|l| l.feed_override != now.feed_override) {
            out.push((n.feed_override.clone(), value(Variant::Double(now.feed_override))));
        }
        if changed(&|l| l.rapid_override != now.rapid_override) {
            out.push((n.rapid_override.clone(), value(Variant::Double(now.rapid_override))));
        }
        if let Some((rotating, spindle_override)) = &n.spindle
            && changed(&|l| l.spindle != now.spindle)
        {
            out.push((rotating.clone(), value(Variant::Boolean(now.spindle.0))));
            out.push((spindle_override.clone(), value(Variant::Double(now.spindle.1))));
        }
        if changed(&|l| l.program != now.program) {
            for node in &n.program_names {
                out.push((node.clone(), value(Variant::from(now.program.as_str()))));
            }
        }
        if changed(&|l| l.production != now.production) {
            let (name, program_node, job_node, number) = now.production.state();
            for (nodes, state_node) in [(&n.program_state, program_node), (&n.job_state, job_node)] {
                out.push((nodes[0].clone(), value(Variant::from(LocalizedText::new("en", name)))));
                out.push((nodes[1].clone(), value(Variant::from(NodeId::new(self.mt, state_node)))));
                out.push((nodes[2].clone(), value(Variant::UInt32(number))));
            }
        }
        if changed(&|l| l.runs != now.runs) {
            out.push((n.runs_completed.clone(), value(Variant::UInt32(now.runs.0))));
            out.push((n.runs_planned.clone(), value(Variant::UInt32(now.runs.1))));
        }
        out
    }

    /// The next manual tool change of the loaded program `k`, if a run is under way: the tool
    /// and how many seconds ahead it is (0: due, the program stands at its M6) — from the
    /// plan's time line, where the executor stands on it, at the feed override in force.
    fn next_tool_change(&self, frame: &Frame, state: &str, nc: Option<RunState>, k: i16) -> Option<(u32, f64)> {
        if nc == Some(RunState::ToolChange) {
            let tool = number(frame, self.indices.tool_change_number).map_or(0, |t| t as u32);
            return Some((tool, 0.0));
        }
        let under_way = state == "AUTO" && nc.is_some_and(|s| !matches!(s, RunState::Idle | RunState::Done));
        if !under_way {
            return None;
        }
        let now_s = number(frame, self.indices.nc_time_s)?;
        let trajectory = self.sources.library.as_ref()?.trajectory(k)?;
        let (t, tool) = trajectory.events().iter().find_map(|e| match e.kind {
            TrajectoryEventKind::ToolChange { tool } if e.t > now_s + 1e-6 => Some((e.t, tool)),
            _ => None,
        })?;
        // The time line runs at the feed override's rate (a hold stops it: the prognosis then
        // moves on with the wall clock until the run goes on).
        let rate = number(frame, self.indices.feed_override).unwrap_or(100.0).max(1.0) / 100.0;
        Some((tool, (t - now_s) / rate))
    }

    /// Makes, moves or unmakes the tool change prognosis for `next` (the tool and how many
    /// seconds ahead, as [`Self::next_tool_change`]); the time it predicts is written when it
    /// moves by a second or more.
    fn tool_change_prognosis(
        &mut self,
        space: &mut AddressSpace,
        next: Option<(u32, f64)>,
        value: &impl Fn(Variant) -> DataValue,
        out: &mut Vec<(NodeId, DataValue)>,
    ) {
        let frame_time = value(Variant::Boolean(true))
            .source_timestamp
            .unwrap_or_else(DateTime::now);
        let predicted =
            |ahead_s: f64| DateTime::from(frame_time.checked_ticks().saturating_add((ahead_s * 1e7) as i64));
        let changed_tool = match (&self.prognosis, next) {
            (Some(shown), Some((tool, _))) => shown.tool != tool,
            (Some(_), None) => true,
            _ => false,
        };
        if changed_tool && let Some(shown) = self.prognosis.take() {
            for node in shown.nodes.iter().rev() {
                space.delete(node, true);
            }
        }
        let Some((tool, ahead_s)) = next else {
            return;
        };
        let at = predicted(ahead_s);
        if let Some(shown) = &mut self.prognosis {
            // Due: the time it became due stays; ahead: moved when it moves by a second.
            let moved = (at.checked_ticks() - shown.predicted.checked_ticks()).abs() >= 10_000_000;
            if ahead_s > 0.0 && moved {
                shown.predicted = at;
                out.push((shown.nodes[1].clone(), value(Variant::from(at))));
            }
            return;
        }
        let name = self
            .sources
            .tools
            .as_ref()
            .and_then(|k| k.table().tools.into_iter().find(|t| t.number == tool))
            .map(|t| t.comment)
            .filter(|c| !c.is_empty())
            .unwrap_or_else(|| format!("T{tool}"));
        let mut b = Build {
            space,
            mt: self.mt,
            ns: self.ns,
            machine: &self.machine,
        };
        let node = b.object(
            "Notification.Prognoses.ToolChange",
            (self.ns, "ToolChange"),
            NodeId::new(self.mt, ids::TOOL_CHANGE_PROGNOSIS_TYPE),
            &self.prognoses,
        );
        let mut nodes = vec![node.clone()];
        nodes.push(b.variable(
            "Notification.Prognoses.ToolChange.PredictedTime",
            (self.mt, "PredictedTime"),
            (DataTypeId::UtcTime.into(), Variant::from(at)),
            None,
            &node,
        ));
        nodes.push(b.variable(
            "Notification.Prognoses.ToolChange.Location",
            (self.mt, "Location"),
            (
                DataTypeId::LocalizedText.into(),
                Variant::from(LocalizedText::new("en", "spindle (manual change)")),
            ),
            Some(VariableTypeId::BaseDataVariableType),
            &node,
        ));
        nodes.push(b.variable(
            "Notification.Prognoses.ToolChange.ToolIdentifier",
            (self.mt, "ToolIdentifier"),
            (DataTypeId::String.into(), Variant::from(format!("T{tool}"))),
            Some(VariableTypeId::BaseDataVariableType),
            &node,
        ));
        nodes.push(b.variable(
            "Notification.Prognoses.ToolChange.ToolName",
            (self.mt, "ToolName"),
            (DataTypeId::String.into(), Variant::from(name)),
            Some(VariableTypeId::BaseDataVariableType),
            &node,
        ));
        self.prognosis = Some(Prognosis {
            nodes,
            tool,
            predicted: at,
        });
    }

    /// Makes the tools' nodes again when the tool table has changed since they were made.
    fn refresh_tools(&mut self, space: &mut AddressSpace) {
        let Some(keeper) = &self.sources.tools else {
            return;
        };
        let seen = *keeper.changes().borrow();
        if self.tools_seen == Some(seen) {
            return;
        }
        self.tools_seen = Some(seen);
        for node in self.tool_nodes.drain(..).rev() {
            space.delete(&node, true);
        }
        let table = keeper.table();
        let mut b = Build {
            space,
            mt: self.mt,
            ns: self.ns,
            machine: &self.machine,
        };
        let mt = self.mt;
        for tool in &table.tools {
            let path = format!("Equipment.Tools.T{}", tool.number);
            let name = format!("T{}", tool.number);
            let node = b.object(
                &path,
                (self.ns, &name),
                NodeId::new(mt, ids::TOOL_TYPE),
                &self.tools_list,
            );
            self.tool_nodes.push(node.clone());
            let shown = if tool.comment.is_empty() {
                name.clone()
            } else {
                tool.comment.clone()
            };
            let children = [
                (
                    "Identifier",
                    (DataTypeId::String.into(), Variant::from(name.as_str())),
                    None,
                ),
                ("Name", (DataTypeId::String.into(), Variant::from(shown)), None),
                (
                    "ControlIdentifier1",
                    (DataTypeId::UInt32.into(), Variant::UInt32(tool.number)),
                    Some(VariableTypeId::BaseDataVariableType),
                ),
                (
                    "ControlIdentifierInterpretation",
                    (NodeId::new(mt, ids::TOOL_MANAGEMENT), Variant::Int32(0)),
                    Some(VariableTypeId::BaseDataVariableType),
                ),
                (
                    "Locked",
                    (DataTypeId::Boolean.into(), Variant::Boolean(false)),
                    Some(VariableTypeId::BaseDataVariableType),
                ),
            ];
            for (child, value, ty) in children {
                let id = b.variable(&format!("{path}.{child}"), (mt, child), value, ty, &node);
                self.tool_nodes.push(id.clone());
                if child == "Locked" {
                    // Mandatory, and meaningless while the tool is not locked: Other.
                    let reason = b.variable(
                        &format!("{path}.Locked.ReasonForLocking"),
                        (mt, "ReasonForLocking"),
                        (NodeId::new(mt, ids::TOOL_LOCKED), Variant::Int32(5)),
                        None,
                        &id,
                    );
                    self.tool_nodes.push(reason);
                }
            }
        }
    }
}

/// The Machine Tools namespace's index in `space`, where its model is loaded.
pub fn machine_tool_namespace(space: &AddressSpace) -> Option<u16> {
    space
        .namespaces()
        .iter()
        .find(|(_, u)| *u == MACHINE_TOOL)
        .map(|(i, _)| *i)
}

/// The type of the machine's object: `MachineToolType` where the Machine Tools model is loaded
/// and the run has a machine, else `BaseObjectType` (every object has a type definition).
pub fn object_type(space: &AddressSpace, has_machine: bool) -> NodeId {
    match machine_tool_namespace(space) {
        Some(mt) if has_machine => NodeId::new(mt, ids::MACHINE_TOOL_TYPE),
        _ => ObjectTypeId::BaseObjectType.into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plcs_states_map_onto_the_machine_tools_modes() {
        assert_eq!(operation_mode("INIT"), OperationMode::Setup);
        assert_eq!(operation_mode("READY"), OperationMode::Manual);
        assert_eq!(operation_mode("MOTION"), OperationMode::Manual);
        assert_eq!(operation_mode("AUTO"), OperationMode::Automatic);
        assert_eq!(operation_mode("ERROR"), OperationMode::Other);
        assert_eq!(
            channel("AUTO", Some(RunState::Running)),
            (ChannelState::Active, ChannelMode::Automatic)
        );
        assert_eq!(
            channel("AUTO", Some(RunState::ToolChange)),
            (ChannelState::Interrupted, ChannelMode::Automatic)
        );
        assert_eq!(channel("INIT", None), (ChannelState::Reset, ChannelMode::Reference));
        assert_eq!(channel("MOTION", None), (ChannelState::Active, ChannelMode::JogManual));
        assert_eq!(channel("ERROR", None), (ChannelState::Reset, ChannelMode::Other));
    }

    #[test]
    fn a_job_plans_the_runs_completed_and_the_one_under_way() {
        assert_eq!(runs_planned(0, Production::Initializing), 1);
        assert_eq!(runs_planned(0, Production::Running), 1);
        assert_eq!(runs_planned(1, Production::Ended), 1);
        assert_eq!(runs_planned(1, Production::Running), 2);
        assert_eq!(runs_planned(1, Production::Aborted), 2);
        assert_eq!(runs_planned(2, Production::Ended), 2);
    }

    #[test]
    fn a_program_runs_is_interrupted_ends_or_is_aborted() {
        use Production::*;
        let run = |steps: &[(&str, Option<RunState>, bool)]| {
            steps.iter().fold(vec![Initializing], |mut seen, &(state, nc, loaded)| {
                let last = *seen.last().expect("one");
                seen.push(next_production(last, state, nc, loaded));
                seen
            })
        };
        // Loaded, started, held, resumed, ended; READY after it keeps Ended.
        assert_eq!(
            run(&[
                ("READY", Some(RunState::Idle), false),
                ("AUTO", Some(RunState::Running), false),
                ("AUTO", Some(RunState::Held), false),
                ("AUTO", Some(RunState::Running), false),
                ("AUTO", Some(RunState::Done), false),
                ("READY", Some(RunState::Idle), false),
            ]),
            [Initializing, Initializing, Running, Interrupted, Running, Ended, Ended]
        );
        // STOP while running: Aborted, kept through the acknowledgement; a new load starts over.
        assert_eq!(
            run(&[
                ("AUTO", Some(RunState::Running), false),
                ("ERROR", Some(RunState::Idle), false),
                ("REBOOT", None, false),
                ("READY", Some(RunState::Idle), true),
            ]),
            [Initializing, Running, Aborted, Aborted, Initializing]
        );
        // Left standing at an M0 (out of AUTO from Interrupted): Aborted.
        assert_eq!(
            run(&[("AUTO", Some(RunState::Paused), false), ("READY", None, false)]),
            [Initializing, Interrupted, Aborted]
        );
    }
}
