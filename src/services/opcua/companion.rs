//! OPC 40001-1 Machinery: what an MES expects of any machine, on the run's machine.
//!
//! The companion's information model (and those it is built on, DI and IA) is loaded from its
//! published NodeSet2 files ([`imports`]); this module adds the machine's instance to it:
//!
//! ```text
//! Objects
//! └─ Machines                                  (Machinery's entry point)
//!    └─ MACHINE                                (the machine's object of `space`, organized here too)
//!       ├─ Identification                      MachineIdentificationType, HasAddIn:
//!       │    Manufacturer, Model, SerialNumber, ProductInstanceUri, SoftwareRevision,
//!       │    YearOfConstruction (when configured)
//!       └─ MachineryBuildingBlocks             HasAddIn to Identification and to:
//!          ├─ MachineryItemState               MachineryItemState_StateMachineType
//!          │    └─ CurrentState (Id, Number)
//!          └─ MachineryOperationMode           MachineryOperationModeStateMachineType
//!               └─ CurrentState (Id, Number)
//! ```
//!
//! The two state machines follow the PLC's state ([`machinery_states`]).

use opcua::nodes::NodeSet2Import;
use opcua::server::address_space::{AccessLevel, AddressSpace, ObjectBuilder, VariableBuilder};
use opcua::types::{
    DataTypeId, DataValue, LocalizedText, NodeId, ObjectTypeId, QualifiedName, ReferenceTypeId, VariableTypeId, Variant,
};

use crate::image::Value;
use crate::runtime::config::identification::Identification;
use crate::runtime::frame::Frame;
use pkm_drives::nc::RunState;

/// OPC 10000-100 Devices (DI): the nameplate's fields.
pub const DI: &str = "http://opcfoundation.org/UA/DI/";
/// OPC 10000-200 Industrial Automation, a model Machinery requires.
pub const IA: &str = "http://opcfoundation.org/UA/IA/";
/// OPC 40001-1 Machinery.
pub const MACHINERY: &str = "http://opcfoundation.org/UA/Machinery/";

/// The companions' NodeSet2 files, each after the ones it needs: Machine Tools needs Machinery,
/// IA, Machinery Jobs and ISA-95 job control.
const NODESETS: [(&str, &str); 6] = [
    (
        "Opc.Ua.Di.NodeSet2.xml",
        include_str!("nodesets/Opc.Ua.Di.NodeSet2.xml"),
    ),
    (
        "Opc.Ua.IA.NodeSet2.xml",
        include_str!("nodesets/Opc.Ua.IA.NodeSet2.xml"),
    ),
    (
        "Opc.Ua.Machinery.NodeSet2.xml",
        include_str!("nodesets/Opc.Ua.Machinery.NodeSet2.xml"),
    ),
    (
        "opc.ua.isa95-jobcontrol.nodeset2.xml",
        include_str!("nodesets/opc.ua.isa95-jobcontrol.nodeset2.xml"),
    ),
    (
        "Opc.Ua.Machinery.Jobs.Nodeset2.xml",
        include_str!("nodesets/Opc.Ua.Machinery.Jobs.Nodeset2.xml"),
    ),
    (
        "Opc.Ua.MachineTool.NodeSet2.xml",
        include_str!("nodesets/Opc.Ua.MachineTool.NodeSet2.xml"),
    ),
];

/// The companions' node sets, parsed and ready to be imported into the address space, in order.
pub fn imports() -> Result<Vec<NodeSet2Import>, String> {
    NODESETS
        .iter()
        .map(|(name, xml)| {
            NodeSet2Import::new_str("en", &compact_byte_strings(xml), Vec::new())
                .map_err(|e| format!("the built-in {name} cannot be read (a broken build): {e}"))
        })
        .collect()
}

/// Where the content of each `ByteString` element of `xml` (with or without a namespace prefix;
/// not an empty `<ByteString/>`, not a closing tag, not the word in an attribute) starts and ends.
fn byte_string_contents(xml: &str) -> Vec<std::ops::Range<usize>> {
    let content = |at: usize| -> Option<std::ops::Range<usize>> {
        // `at` must start the element's name: after `<` and a prefix, nothing else between.
        let tag_start = xml[..at].rfind('<')?;
        let between = &xml[tag_start + 1..at];
        if between.starts_with('/') || between.contains(|c: char| c.is_whitespace() || c == '>') {
            return None;
        }
        let open_end = at + xml[at..].find('>')? + 1;
        if xml[..open_end].ends_with("/>") {
            return None;
        }
        Some(open_end..open_end + xml[open_end..].find("</")?)
    };
    let mut spans = Vec::new();
    let mut from = 0;
    while let Some(found) = xml[from..].find("ByteString") {
        let at = from + found;
        from = at + "ByteString".len();
        if let Some(span) = content(at) {
            from = span.end;
            spans.push(span);
        }
    }
    spans
}

/// `xml` with the white space inside every `ByteString` element removed: the files break
/// their base64 into lines, which the library's decoder refuses (the value would be lost, with a
/// warning of kilobytes in the log).
pub fn compact_byte_strings(xml: &str) -> String {
    let mut out = String::with_capacity(xml.len());
    let mut done = 0;
    for span in byte_string_contents(xml) {
        out.push_str(&xml[done..span.start]);
        out.extend(xml[span.clone()].chars().filter(|c| !c.is_whitespace()));
        done = span.end;
    }
    out.push_str(&xml[done..]);
    out
}

/// Machinery's node ids (its namespace's numbers).
mod ids {
    /// The `Machines` folder.
    pub const MACHINES: u32 = 1001;
    /// `MachineIdentificationType`.
    pub const MACHINE_IDENTIFICATION_TYPE: u32 = 1012;
    /// `MachineryItemState_StateMachineType`.
    pub const ITEM_STATE_TYPE: u32 = 1002;
    /// `MachineryOperationModeStateMachineType`.
    pub const OPERATION_MODE_TYPE: u32 = 1008;
}

/// The machine's nameplate as the server shows it: the configuration's, with what the server
/// knows where a field is left out.
#[derive(Clone, Debug, PartialEq)]
pub struct Nameplate {
    /// Who built it; "unknown" unless configured.
    pub manufacturer: String,
    /// Its model; the machine's description unless configured.
    pub model: String,
    /// Its serial number; "unknown" unless configured.
    pub serial_number: String,
    /// The URI of this machine; `urn:HOST:pkm-plc:MACHINE` unless configured.
    pub product_instance_uri: String,
    /// The year it was built, if configured.
    pub year_of_construction: Option<u16>,
    /// The fields the configuration left out that have no value of their own (for the log).
    pub missing: Vec<&'static str>,
}

/// What a nameplate field shows when the configuration does not give it.
pub const UNKNOWN: &str = "unknown";

impl Nameplate {
    /// The nameplate of `machine` (`summary`: its one-line description, whose part before a
    /// `:` is its model) on computer `host`, from the configuration's `identification`.
    pub fn new(configured: &Identification, machine: &str, summary: &str, host: &str) -> Nameplate {
        let mut missing = Vec::new();
        let mut or_unknown = |field: &Option<String>, name: &'static str| {
            field.clone().unwrap_or_else(|| {
                missing.push(name);
                UNKNOWN.to_string()
            })
        };
        let manufacturer = or_unknown(&configured.manufacturer, "manufacturer");
        let serial_number = or_unknown(&configured.serial_number, "serial_number");
        Nameplate {
            manufacturer,
            serial_number,
            model: configured
                .model
                .clone()
                .unwrap_or_else(|| summary.split(':').next().unwrap_or(machine).trim().to_string()),
            product_instance_uri: configured
                .product_instance_uri
                .clone()
                .unwrap_or_else(|| format!("urn:{host}:pkm-plc:{machine}")),
            year_of_construction: configured.year_of_construction,
            missing,
        }
    }
}

/// The state of a machinery item (`MachineryItemState`), as Machinery defines them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ItemState {
    /// Not available and doing nothing (switched off): the runtime's self-test, no machine.
    NotAvailable,
    /// Not functional and doing nothing (an error): ERROR, a bus fault.
    OutOfService,
    /// Available, functional and doing something: referencing, jogging, running a program.
    Executing,
    /// Available, functional and waiting for an action from outside.
    NotExecuting,
}

/// The operation mode of a machinery item (`MachineryOperationMode`), as Machinery defines them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OperationMode {
    /// No mode: in ERROR, or no machine.
    None,
    /// Maintenance or servicing: the PLC has no such mode, so it is never shown.
    Maintenance,
    /// Setting up: referencing, jogging, and waiting in READY.
    Setup,
    /// The value-adding work: an NC program (AUTO).
    Processing,
}

impl ItemState {
    /// Its state's browse name, node number in Machinery's namespace and state number.
    fn state(self) -> (&'static str, u32, u32) {
        match self {
            ItemState::NotAvailable => ("NotAvailable", 5005, 0),
            ItemState::OutOfService => ("OutOfService", 5004, 1),
            ItemState::NotExecuting => ("NotExecuting", 5007, 2),
            ItemState::Executing => ("Executing", 5006, 3),
        }
    }
}

impl OperationMode {
    /// Its state's browse name, node number in Machinery's namespace and state number.
    fn state(self) -> (&'static str, u32, u32) {
        match self {
            OperationMode::None => ("None", 5024, 0),
            OperationMode::Maintenance => ("Maintenance", 5025, 1),
            OperationMode::Setup => ("Setup", 5027, 2),
            OperationMode::Processing => ("Processing", 5026, 3),
        }
    }
}

/// The NC executor's states in which the tool moves (running, holding — braking on the path); in
/// the others (held, at M0, a single-block stop, a tool change, done) the program waits for the
/// operator.
const NC_MOVING: [RunState; 2] = [RunState::Running, RunState::Holding];

/// Machinery's states of the PLC in main state `state` (`None`: outside the automaton), with
/// the bus faulted or not and the NC executor in `nc_state` (`NC_STATE`, where the run has it).
///
/// | PLC | MachineryItemState | MachineryOperationMode |
/// |---|---|---|
/// | REBOOT, READY | NotExecuting | Setup |
/// | INIT (referencing), MOTION (jogging) | Executing | Setup |
/// | AUTO, the tool moving | Executing | Processing |
/// | AUTO, held, at M0, a tool change, single block | NotExecuting | Processing |
/// | ERROR | OutOfService | None |
/// | a bus fault, in any state | OutOfService | (the state's) |
/// | outside the automaton | NotAvailable | None |
pub fn machinery_states(state: Option<&str>, bus_fault: bool, nc_state: Option<i16>) -> (ItemState, OperationMode) {
    let (item, mode) = match state {
        Some("REBOOT" | "READY") => (ItemState::NotExecuting, OperationMode::Setup),
        Some("INIT" | "MOTION") => (ItemState::Executing, OperationMode::Setup),
        Some("AUTO")
            if nc_state
                .and_then(RunState::from_code)
                .is_some_and(|s| NC_MOVING.contains(&s)) =>
        {
            (ItemState::Executing, OperationMode::Processing)
        }
        Some("AUTO") => (ItemState::NotExecuting, OperationMode::Processing),
        Some("ERROR") => (ItemState::OutOfService, OperationMode::None),
        _ => return (ItemState::NotAvailable, OperationMode::None),
    };
    if bus_fault {
        (ItemState::OutOfService, mode)
    } else {
        (item, mode)
    }
}

/// The Machinery nodes of a built address space and the states last shown.
pub struct Machinery {
    machinery_ns: u16,
    item_state: [NodeId; 3],
    operation_mode: [NodeId; 3],
    nc_state_index: Option<usize>,
    last: Option<(ItemState, OperationMode)>,
}

impl Machinery {
    /// Builds the Machinery nodes of `machine` (its object `object`, in namespace `ns`) into
    /// `space`, where the companions are loaded (`None` if they are not); `nc_state_index` is
    /// where `NC_STATE` is in the process image.
    pub fn build(
        space: &mut AddressSpace,
        (ns, machine, object): (u16, &str, &NodeId),
        nameplate: &Nameplate,
        nc_state_index: Option<usize>,
    ) -> Option<Machinery> {
        let index = |uri: &str| space.namespaces().iter().find(|(_, u)| *u == uri).map(|(i, _)| *i);
        let (di, m) = (index(DI)?, index(MACHINERY)?);
        let id = |path: &str| NodeId::new(ns, format!("{machine}.{path}"));
        space.insert_reference(&NodeId::new(m, ids::MACHINES), object, ReferenceTypeId::Organizes);

        let identification = id("Identification");
        ObjectBuilder::new(
            &identification,
            QualifiedName::new(di, "Identification"),
            "Identification",
        )
        .description("The machine's nameplate (configuration: identification)")
        // A machine tool's where Machine Tools is loaded (a subtype of Machinery's).
        .has_type_definition(super::machine_tool::machine_tool_namespace(space).map_or(
            NodeId::new(m, ids::MACHINE_IDENTIFICATION_TYPE),
            super::machine_tool::identification_type,
        ))
        .insert(space);
        space.insert_reference(object, &identification, ReferenceTypeId::HasAddIn);
        let mut fields = vec![
            (
                di,
                "Manufacturer",
                Variant::from(LocalizedText::new("", &nameplate.manufacturer)),
                DataTypeId::LocalizedText,
            ),
            (
                di,
                "Model",
                Variant::from(LocalizedText::new("", &nameplate.model)),
                DataTypeId::LocalizedText,
            ),
            (
                di,
                "SerialNumber",
                Variant::from(nameplate.serial_number.as_str()),
                DataTypeId::String,
            ),
            (
                di,
                "ProductInstanceUri",
                Variant::from(nameplate.product_instance_uri.as_str()),
                DataTypeId::String,
            ),
            (
                di,
                "SoftwareRevision",
                Variant::from(concat!("pkm-plc ", env!("CARGO_PKG_VERSION"))),
                DataTypeId::String,
            ),
        ];
        if let Some(year) = nameplate.year_of_construction {
            fields.push((m, "YearOfConstruction", Variant::UInt16(year), DataTypeId::UInt16));
        }
        for (field_ns, name, value, ty) in fields {
            VariableBuilder::new(
                &id(&format!("Identification.{name}")),
                QualifiedName::new(field_ns, name),
                name,
            )
            .data_type(ty)
            .value(value)
            .access_level(AccessLevel::CURRENT_READ)
            .user_access_level(AccessLevel::CURRENT_READ)
            .has_type_definition(VariableTypeId::PropertyType)
            .property_of(identification.clone())
            .insert(space);
        }

        let blocks = id("MachineryBuildingBlocks");
        ObjectBuilder::new(
            &blocks,
            QualifiedName::new(m, "MachineryBuildingBlocks"),
            "MachineryBuildingBlocks",
        )
        .description("The Machinery building blocks the machine has")
        .has_type_definition(ObjectTypeId::FolderType)
        .component_of(object.clone())
        .insert(space);
        space.insert_reference(&blocks, &identification, ReferenceTypeId::HasAddIn);
        let (item, mode) = machinery_states(None, false, None);
        let item_state = state_machine(
            space,
            (&blocks, &id, "MachineryBuildingBlocks.MachineryItemState"),
            (m, "MachineryItemState", ids::ITEM_STATE_TYPE),
            "Whether the machine is available, functional and doing something (from the PLC's state)",
            item.state(),
        );
        let operation_mode = state_machine(
            space,
            (&blocks, &id, "MachineryBuildingBlocks.MachineryOperationMode"),
            (m, "MachineryOperationMode", ids::OPERATION_MODE_TYPE),
            "Setup (referencing, jogging, READY) or Processing (an NC program) (from the PLC's state)",
            mode.state(),
        );
        Some(Machinery {
            machinery_ns: m,
            item_state,
            operation_mode,
            nc_state_index,
            last: None,
        })
    }

    /// The nodes [`Machinery::changes`] writes.
    pub fn nodes(&self) -> impl Iterator<Item = &NodeId> {
        self.item_state.iter().chain(&self.operation_mode)
    }

    /// Forgets what was published: the next frame writes every state again.
    pub fn forget(&mut self) {
        self.last = None;
    }

    /// The changes of the state machines' `CurrentState` (its text, `Id` and `Number`) that
    /// `frame` brings, as `value` stamps them.
    pub fn changes(&mut self, frame: &Frame, value: impl Fn(Variant) -> DataValue) -> Vec<(NodeId, DataValue)> {
        let nc_state = self
            .nc_state_index
            .and_then(|k| frame.image.get(k))
            .and_then(|v| match v {
                Value::Int(s) => Some(*s),
                _ => None,
            });
        let state = frame.status.state.as_str();
        let in_automaton = pkm_api::machine::MAIN_STATES.contains(&state);
        let now = machinery_states(in_automaton.then_some(state), frame.bus_fault, nc_state);
        if self.last == Some(now) {
            return Vec::new();
        }
        self.last = Some(now);
        let mut out = Vec::new();
        for (nodes, (name, number, state_number)) in
            [(&self.item_state, now.0.state()), (&self.operation_mode, now.1.state())]
        {
            out.push((nodes[0].clone(), value(Variant::from(LocalizedText::new("en", name)))));
            out.push((
                nodes[1].clone(),
                value(Variant::from(NodeId::new(self.machinery_ns, number))),
            ));
            out.push((nodes[2].clone(), value(Variant::UInt32(state_number))));
        }
        out
    }
}

/// The node id of a path below the machine.
type IdOf<'a> = &'a dyn Fn(&str) -> NodeId;

/// A finite state machine `name` (of type `type_number` in namespace `browse_ns`) at node
/// `id(path)`, an add-in of `blocks`, in state `state` (browse name, node number, state number):
/// the nodes of its `CurrentState`, `CurrentState/Id` and `CurrentState/Number`.
fn state_machine(
    space: &mut AddressSpace,
    (blocks, id, path): (&NodeId, IdOf<'_>, &str),
    (browse_ns, name, type_number): (u16, &str, u32),
    about: &str,
    (state, state_node, state_number): (&str, u32, u32),
) -> [NodeId; 3] {
    let node = id(path);
    ObjectBuilder::new(&node, QualifiedName::new(browse_ns, name), name)
        .description(about)
        .has_type_definition(NodeId::new(browse_ns, type_number))
        .insert(space);
    space.insert_reference(blocks, &node, ReferenceTypeId::HasAddIn);
    let child = |below: &str| id(&format!("{path}.{below}"));
    let current = child("CurrentState");
    VariableBuilder::new(&current, QualifiedName::new(0, "CurrentState"), "CurrentState")
        .data_type(DataTypeId::LocalizedText)
        .value(LocalizedText::new("en", state))
        .access_level(AccessLevel::CURRENT_READ)
        .user_access_level(AccessLevel::CURRENT_READ)
        .has_type_definition(VariableTypeId::FiniteStateVariableType)
        .component_of(node)
        .insert(space);
    let properties = [
        (
            child("CurrentState.Id"),
            "Id",
            Variant::from(NodeId::new(browse_ns, state_node)),
            DataTypeId::NodeId,
        ),
        (
            child("CurrentState.Number"),
            "Number",
            Variant::UInt32(state_number),
            DataTypeId::UInt32,
        ),
    ];
    for (id, property, value, ty) in &properties {
        VariableBuilder::new(id, QualifiedName::new(0, *property), *property)
            .data_type(*ty)
            .value(value.clone())
            .access_level(AccessLevel::CURRENT_READ)
            .user_access_level(AccessLevel::CURRENT_READ)
            .has_type_definition(VariableTypeId::PropertyType)
            .property_of(current.clone())
            .insert(space);
    }
    let [(id, ..), (number, ..)] = properties;
    [current, id, number]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plcs_states_map_onto_machinerys() {
        use ItemState::*;
        use OperationMode::{None as NoMode, Processing, Setup};
        let cases = [
            (Some("REBOOT"), false, Option::None, (NotExecuting, Setup)),
            (Some("INIT"), false, Option::None, (Executing, Setup)),
            (Some("READY"), false, Some(0), (NotExecuting, Setup)),
            (Some("MOTION"), false, Some(0), (Executing, Setup)),
            (Some("AUTO"), false, Some(1), (Executing, Processing)),
            (Some("AUTO"), false, Some(2), (Executing, Processing)),
            (Some("AUTO"), false, Some(3), (NotExecuting, Processing)),
            (Some("AUTO"), false, Some(4), (NotExecuting, Processing)),
            (Some("AUTO"), false, Some(7), (NotExecuting, Processing)),
            (Some("ERROR"), false, Some(0), (OutOfService, NoMode)),
            (Some("READY"), true, Some(0), (OutOfService, Setup)),
            (Some("AUTO"), true, Some(1), (OutOfService, Processing)),
            (Option::None, false, Option::None, (NotAvailable, NoMode)),
        ];
        for (state, bus_fault, nc, expected) in cases {
            assert_eq!(
                machinery_states(state, bus_fault, nc),
                expected,
                "{state:?}, bus fault {bus_fault}, NC_STATE {nc:?}"
            );
        }
    }

    #[test]
    fn the_nameplate_takes_the_configuration_and_says_what_is_missing() {
        let none = Identification::default();
        let shown = Nameplate::new(
            &none,
            "ox-x",
            "O-X glide, crossed X configuration: two sliders …",
            "lab-pc",
        );
        assert_eq!(
            shown,
            Nameplate {
                manufacturer: "unknown".into(),
                model: "O-X glide, crossed X configuration".into(),
                serial_number: "unknown".into(),
                product_instance_uri: "urn:lab-pc:pkm-plc:ox-x".into(),
                year_of_construction: None,
                missing: vec!["manufacturer", "serial_number"],
            }
        );
        let full = Identification {
            manufacturer: Some("Lab".into()),
            model: Some("TRIJOINT 900H".into()),
            serial_number: Some("0001".into()),
            product_instance_uri: Some("urn:lab:trijoint:0001".into()),
            year_of_construction: Some(2004),
        };
        let shown = Nameplate::new(&full, "trijoint", "TRIJOINT 900H lab model: …", "lab-pc");
        assert_eq!(shown.model, "TRIJOINT 900H");
        assert_eq!(shown.product_instance_uri, "urn:lab:trijoint:0001");
        assert_eq!(shown.year_of_construction, Some(2004));
        assert!(shown.missing.is_empty());
    }

    #[test]
    fn byte_strings_lose_their_line_breaks_and_nothing_else_changes() {
        let xml = "<V DataType=\"ByteString\"><uax:ByteString xmlns:uax=\"u\">QU\n  JD\r\n</uax:ByteString>\
                   <ByteString>R U\n</ByteString><ByteString/><S> a b </S></V>";
        assert_eq!(
            compact_byte_strings(xml),
            "<V DataType=\"ByteString\"><uax:ByteString xmlns:uax=\"u\">QUJD</uax:ByteString>\
             <ByteString>RU</ByteString><ByteString/><S> a b </S></V>"
        );
        // Every byte string of the built-in files then decodes.
        for (name, xml) in NODESETS {
            let compact = compact_byte_strings(xml);
            let spans = byte_string_contents(&compact);
            for span in &spans {
                assert!(
                    opcua::types::ByteString::from_base64(&compact[span.clone()]).is_some(),
                    "{name}: a byte string at {} does not decode",
                    span.start
                );
            }
            // Each file's own: its schema's and its model's (Machinery 1.04.1 has none).
            let expected = if name == "Opc.Ua.Machinery.NodeSet2.xml" { 0 } else { 2 };
            assert_eq!(spans.len(), expected, "{name}");
        }
    }

    #[test]
    fn the_built_in_node_sets_are_read_and_own_their_namespaces() {
        let imports = imports().expect("the built-in node sets parse");
        use opcua::nodes::NodeSetImport;
        let own: Vec<String> = imports.iter().map(|i| i.get_own_namespaces()[0].clone()).collect();
        assert_eq!(
            own,
            [
                DI,
                IA,
                MACHINERY,
                "http://opcfoundation.org/UA/ISA95-JOBCONTROL_V2/",
                "http://opcfoundation.org/UA/Machinery/Jobs/",
                super::super::machine_tool::MACHINE_TOOL,
            ]
        );
    }
}
