//! Alarms and conditions (OPC UA Part 9): what the PLC sees going wrong, as conditions a SCADA
//! subscribes to instead of polling `State` and `Reason`. One condition per cause, each of a
//! standard alarm type with a severity; raised and cleared as the frames show the PLC's state:
//!
//! | condition | type | active while |
//! |---|---|---|
//! | `Stop` | AlarmConditionType | ERROR after STOP |
//! | `LimitSwitch` | OffNormalAlarmType | ERROR for a limit switch |
//! | `EncoderFault` | InstrumentDiagnosticAlarmType | ERROR for an implausible encoder change |
//! | `CycleTime` | SystemDiagnosticAlarmType | ERROR for a cycle time violation, or a second after a class's overrun or violation counter rose |
//! | `BusFault` | SystemOffNormalAlarmType | the bus reports a fault, or ERROR for it |
//! | `Error` | AlarmConditionType | ERROR for any other reason (a drive, referencing, the program) |
//! | `JobRefused` | DiscreteAlarmType | the screen's last job (MDI, a run from a line, a step, a program planned again) was refused, until one is made |
//!
//! The ERROR reason's class comes from the machine's `error_reason` code
//! ([`pkm_api::machine::ReasonClass`]). A condition raised by ERROR is acknowledged by the PLC's
//! acknowledgement: its `Acknowledge` (by a user who may command) acknowledges the PLC as the
//! `Acknowledge` method does — an input of the process image, traced and replayed — and an
//! acknowledgement from the panel or the screen acknowledges it too. Any other condition's
//! `Acknowledge` is the server's alone: the PLC has nothing to acknowledge.
//!
//! This module keeps the conditions' states and makes their events; [`super::alarm_events`]
//! gives the events their fields, the server emits them on the machine's object (and so on the
//! `Server` object).

use opcua::types::{ByteString, DateTime, NodeId, ObjectTypeId, StatusCode};

use super::alarm_events::ConditionEvent;
use crate::runtime::frame::Frame;
use crate::services::hmi::job_news::JobOutcome;
use pkm_api::machine::ReasonClass;

/// How long a rise of a class's overrun or violation counter keeps `CycleTime` active (s of the
/// PLC's time).
pub const CYCLE_TIME_HOLD_S: f64 = 1.0;

/// A condition's cause.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// ERROR after STOP.
    Stop,
    /// ERROR for a limit switch.
    LimitSwitch,
    /// ERROR for an implausible encoder change.
    EncoderFault,
    /// Overruns and cycle time violations.
    CycleTime,
    /// The field bus.
    BusFault,
    /// ERROR for any other reason.
    Error,
    /// The screen's last job was refused.
    JobRefused,
}

impl Kind {
    /// Every kind, in the order of the address space's `Alarms` folder.
    pub const ALL: [Kind; 7] = [
        Kind::Stop,
        Kind::LimitSwitch,
        Kind::EncoderFault,
        Kind::CycleTime,
        Kind::BusFault,
        Kind::Error,
        Kind::JobRefused,
    ];

    /// The condition's name (its browse name and `ConditionName`).
    pub fn name(self) -> &'static str {
        match self {
            Kind::Stop => "Stop",
            Kind::LimitSwitch => "LimitSwitch",
            Kind::EncoderFault => "EncoderFault",
            Kind::CycleTime => "CycleTime",
            Kind::BusFault => "BusFault",
            Kind::Error => "Error",
            Kind::JobRefused => "JobRefused",
        }
    }

    /// Its standard alarm type.
    pub fn event_type(self) -> ObjectTypeId {
        match self {
            Kind::Stop | Kind::Error => ObjectTypeId::AlarmConditionType,
            Kind::LimitSwitch => ObjectTypeId::OffNormalAlarmType,
            Kind::EncoderFault => ObjectTypeId::InstrumentDiagnosticAlarmType,
            Kind::CycleTime => ObjectTypeId::SystemDiagnosticAlarmType,
            Kind::BusFault => ObjectTypeId::SystemOffNormalAlarmType,
            Kind::JobRefused => ObjectTypeId::DiscreteAlarmType,
        }
    }

    /// Its severity (1 … 1000; 801 and above: high).
    pub fn severity(self) -> u16 {
        match self {
            Kind::JobRefused => 300,
            Kind::Stop => 600,
            Kind::CycleTime => 700,
            Kind::LimitSwitch | Kind::EncoderFault | Kind::BusFault | Kind::Error => 800,
        }
    }

    /// What it says, for its description.
    pub fn description(self) -> &'static str {
        match self {
            Kind::Stop => "the machine is in ERROR after STOP",
            Kind::LimitSwitch => "the machine is in ERROR for a limit switch",
            Kind::EncoderFault => "the machine is in ERROR for an implausible encoder change",
            Kind::CycleTime => {
                "a task class overran its cycle or started late (for a second after its counters rose), or the machine is in ERROR for a cycle time violation"
            }
            Kind::BusFault => "the field bus reports a fault, or the machine is in ERROR for it",
            Kind::Error => {
                "the machine is in ERROR for a reason the other conditions do not name (a drive's bridge or following error, a referencing that failed, the program's path)"
            }
            Kind::JobRefused => {
                "the operator screen's last job (MDI, a run from a line, a step, a program planned again) was refused; it clears when the screen makes one"
            }
        }
    }

    /// The kind an ERROR of reason class `class` raises.
    fn of_error(class: ReasonClass) -> Kind {
        match class {
            ReasonClass::Stop => Kind::Stop,
            ReasonClass::LimitSwitch => Kind::LimitSwitch,
            ReasonClass::EncoderFault => Kind::EncoderFault,
            ReasonClass::CycleTime => Kind::CycleTime,
            ReasonClass::BusFault => Kind::BusFault,
            ReasonClass::None | ReasonClass::Other => Kind::Error,
        }
    }
}

/// One condition's state.
#[derive(Clone, Debug)]
pub struct Condition {
    /// Its cause.
    pub kind: Kind,
    /// Its node (`ConditionId`).
    pub node: NodeId,
    /// Active (`ActiveState`).
    pub active: bool,
    /// Acknowledged (`AckedState`).
    pub acked: bool,
    /// Raised by ERROR: the PLC's acknowledgement acknowledges it.
    pub by_error: bool,
    /// What its latest event said.
    pub message: String,
    /// Its latest event's id (an acknowledgement names it).
    pub event_id: ByteString,
    /// When its state last changed.
    pub time: DateTime,
    /// Who acknowledged it (`ClientUserId`), and the comment given.
    pub acked_by: String,
    /// The acknowledgement's comment.
    pub comment: String,
}

impl Condition {
    /// Whether a client's refresh shows it (`Retain`): active, or not yet acknowledged.
    pub fn retain(&self) -> bool {
        self.active || !self.acked
    }

    /// Its event `id` at `time`, raised on the machine `source` (its object and name).
    pub fn event(&self, source: &(NodeId, String), id: ByteString, time: DateTime) -> ConditionEvent {
        ConditionEvent {
            event_id: id,
            event_type: self.kind.event_type().into(),
            source_node: source.0.clone(),
            source_name: source.1.clone(),
            time,
            message: self.message.clone(),
            severity: self.kind.severity(),
            condition_id: self.node.clone(),
            condition_name: self.kind.name(),
            retain: self.retain(),
            active: self.active,
            acked: self.acked,
            acked_by: self.acked_by.clone(),
            comment: self.comment.clone(),
        }
    }
}

/// Why an acknowledgement is refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AckRefusal {
    /// No condition has this node.
    UnknownCondition,
    /// The event id is not the condition's latest.
    UnknownEvent,
    /// It is acknowledged already.
    AlreadyAcked,
}

impl AckRefusal {
    /// The status code a client is answered with.
    pub fn status(self) -> StatusCode {
        match self {
            AckRefusal::UnknownCondition => StatusCode::BadNodeIdUnknown,
            AckRefusal::UnknownEvent => StatusCode::BadEventIdUnknown,
            AckRefusal::AlreadyAcked => StatusCode::BadConditionBranchAlreadyAcked,
        }
    }
}

/// Every condition of the machine, and what the last frame showed.
pub struct Conditions {
    /// The conditions, in [`Kind::ALL`]'s order.
    pub all: Vec<Condition>,
    /// The machine's object (`SourceNode`) and name (`SourceName`).
    source: (NodeId, String),
    /// Where `error_reason` is in the image, if the run has one.
    reason_index: Option<usize>,
    /// The classes' overrun and violation counters in the last frame.
    counters: Vec<(u64, u64)>,
    /// Until when (PLC time, s) `CycleTime` stays active for a counter's rise, and what rose.
    cycle_time_until: Option<(f64, String)>,
    /// Counts the events made (their ids).
    events: u64,
    /// Tells this run's event ids from another run's (the server's start, in 100 ns ticks).
    run: i64,
}

impl Conditions {
    /// The conditions of the machine `source` (its object and name), their nodes from `node`;
    /// `reason_index`: where `error_reason` is in the process image.
    pub fn new(source: (NodeId, String), reason_index: Option<usize>, node: impl Fn(Kind) -> NodeId) -> Conditions {
        Conditions {
            all: Kind::ALL
                .iter()
                .map(|&kind| Condition {
                    kind,
                    node: node(kind),
                    active: false,
                    acked: true,
                    by_error: false,
                    message: String::new(),
                    event_id: ByteString::null(),
                    time: DateTime::now(),
                    acked_by: String::new(),
                    comment: String::new(),
                })
                .collect(),
            source,
            reason_index,
            counters: Vec::new(),
            cycle_time_until: None,
            events: 0,
            run: DateTime::now().checked_ticks(),
        }
    }

    /// Takes `frame` (published at `at`): the events of the conditions it changes.
    pub fn observe(&mut self, frame: &Frame, at: DateTime) -> Vec<ConditionEvent> {
        let status = &frame.status;
        let t_s = status.t_ns as f64 * 1e-9;
        let in_error = status.state == "ERROR";
        let class = self
            .reason_index
            .and_then(|k| frame.image.get(k))
            .and_then(|v| match v {
                crate::image::Value::Int(code) => Some(ReasonClass::of(*code)),
                _ => None,
            })
            .unwrap_or(ReasonClass::Other);
        let error_kind = in_error.then(|| Kind::of_error(class));
        // Counters that rose since the last frame (the first frame sets them).
        let counters: Vec<(u64, u64)> = status.classes.iter().map(|c| (c.overruns, c.violations)).collect();
        if self.counters.len() == counters.len() {
            let rose: Vec<String> = status
                .classes
                .iter()
                .zip(&self.counters)
                .filter(|(c, (o, v))| c.overruns > *o || c.violations > *v)
                .map(|(c, (o, v))| {
                    format!(
                        "task class {}: {} overrun(s), {} cycle time violation(s) in all (+{}, +{})",
                        c.name,
                        c.overruns,
                        c.violations,
                        c.overruns - o,
                        c.violations - v
                    )
                })
                .collect();
            if !rose.is_empty() {
                self.cycle_time_until = Some((t_s + CYCLE_TIME_HOLD_S, rose.join("; ")));
            }
        }
        self.counters = counters;
        if self.cycle_time_until.as_ref().is_some_and(|(until, _)| t_s >= *until) {
            self.cycle_time_until = None;
        }
        let mut events = Vec::new();
        for k in 0..self.all.len() {
            let kind = self.all[k].kind;
            if kind == Kind::JobRefused {
                // The screen's jobs, not the frames, raise and clear it.
                continue;
            }
            let by_error = error_kind == Some(kind);
            let (active, message) = if by_error {
                (true, format!("ERROR: {}", status.reason))
            } else {
                match kind {
                    // The station and its cause first, as the PLC's error reason for it names
                    // them (an error that comes after it has its own reason).
                    Kind::BusFault if frame.bus_fault && frame.bus_cause.is_empty() => {
                        (true, "the field bus reports a fault".to_string())
                    }
                    Kind::BusFault if frame.bus_fault => {
                        (true, format!("{}: {}", pkm_api::bus::BUS_FAULT_REASON, frame.bus_cause))
                    }
                    Kind::CycleTime => match &self.cycle_time_until {
                        Some((_, what)) => (true, what.clone()),
                        None => (false, String::new()),
                    },
                    _ => (false, String::new()),
                }
            };
            let c = &mut self.all[k];
            if active && !c.active {
                c.active = true;
                c.acked = false;
                c.by_error = by_error;
                c.message = message;
                c.acked_by.clear();
                c.comment.clear();
                events.push(self.event(k, at));
            } else if !active && c.active {
                c.active = false;
                if c.by_error && !c.acked {
                    // The PLC left ERROR: it was acknowledged (by the panel, a screen or OPC UA).
                    c.acked = true;
                    c.acked_by = "the PLC's acknowledgement".to_string();
                }
                c.message = match (c.by_error, c.kind) {
                    (true, _) => format!("{} after the acknowledgement", status.state),
                    (false, Kind::BusFault) => "the field bus answers again".to_string(),
                    (false, _) => "no new overrun or cycle time violation for a second".to_string(),
                };
                events.push(self.event(k, at));
            } else if active && by_error && !c.by_error {
                // A bus fault (or overrun) that the PLC now answers with ERROR.
                c.by_error = true;
                c.message = message;
                events.push(self.event(k, at));
            }
        }
        events
    }

    /// Takes what became of a screen job (at `at`): `JobRefused`'s event, if it changes — raised
    /// (again, unacknowledged) by each refusal, cleared by a job made.
    pub fn job(&mut self, outcome: &JobOutcome, at: DateTime) -> Option<ConditionEvent> {
        let k = self.all.iter().position(|c| c.kind == Kind::JobRefused)?;
        let c = &mut self.all[k];
        match outcome {
            JobOutcome::Refused { why, peer } => {
                c.active = true;
                c.acked = false;
                c.message = format!("job refused (screen {peer}): {why}");
                c.acked_by.clear();
                c.comment.clear();
            }
            JobOutcome::Made { .. } if !c.active => return None,
            JobOutcome::Made { file } => {
                c.active = false;
                c.message = format!("a job was made: {file}");
            }
        }
        Some(self.event(k, at))
    }

    /// Whether the condition at `node` whose latest event is `event_id` may be acknowledged,
    /// and whether that acknowledges the PLC (a condition ERROR raised, still active).
    pub fn acknowledging(&self, node: &NodeId, event_id: &ByteString) -> Result<bool, AckRefusal> {
        let c = self
            .all
            .iter()
            .find(|c| c.node == *node)
            .ok_or(AckRefusal::UnknownCondition)?;
        if c.event_id != *event_id {
            return Err(AckRefusal::UnknownEvent);
        }
        if c.acked {
            return Err(AckRefusal::AlreadyAcked);
        }
        Ok(c.by_error && c.active)
    }

    /// Acknowledges the condition at `node` whose latest event is `event_id`, by `user` with
    /// `comment`: its event.
    pub fn acknowledge(
        &mut self,
        node: &NodeId,
        event_id: &ByteString,
        user: &str,
        comment: &str,
    ) -> Result<ConditionEvent, AckRefusal> {
        self.acknowledging(node, event_id)?;
        let k = self
            .all
            .iter()
            .position(|c| c.node == *node)
            .ok_or(AckRefusal::UnknownCondition)?;
        let c = &mut self.all[k];
        c.acked = true;
        c.acked_by = user.to_string();
        c.comment = comment.to_string();
        Ok(self.event(k, DateTime::now()))
    }

    /// The events a refresh shows: the state of each condition a client should see (active or
    /// not acknowledged), with its latest event's id.
    pub fn refresh(&self) -> Vec<ConditionEvent> {
        self.all
            .iter()
            .filter(|c| c.retain())
            .map(|c| c.event(&self.source, c.event_id.clone(), c.time))
            .collect()
    }

    /// A new event of condition `k` at `at` (its id becomes the condition's latest).
    fn event(&mut self, k: usize, at: DateTime) -> ConditionEvent {
        self.events += 1;
        let id = ByteString::from(format!("{:x}:{}:{}", self.run, self.all[k].kind.name(), self.events).into_bytes());
        let c = &mut self.all[k];
        c.event_id = id.clone();
        c.time = at;
        c.event(&self.source, id, at)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Value;
    use crate::runtime::snapshot::{ClassSnapshot, Snapshot};
    use opcua::types::event_field::EventField;

    fn conditions() -> Conditions {
        Conditions::new((NodeId::new(2, "ox-x"), "ox-x".into()), Some(0), |kind| {
            NodeId::new(2, format!("ox-x.Alarms.{}", kind.name()))
        })
    }

    /// A frame at `t_s` in `state` with ERROR reason `code` and `reason`, the fast class's
    /// overruns, the bus fault.
    fn frame(t_s: f64, state: &str, code: i16, reason: &str, overruns: u64, bus_fault: bool) -> Frame {
        Frame {
            seq: 1,
            status: Snapshot {
                t_ns: (t_s * 1e9) as u64,
                classes: vec![ClassSnapshot {
                    name: "fast".into(),
                    overruns,
                    ..ClassSnapshot::default()
                }],
                state: state.into(),
                reason: reason.into(),
                ..Snapshot::default()
            },
            image: vec![Value::Int(code)],
            bus_fault,
            bus_cause: String::new(),
            published_unix_us: 1,
        }
    }

    fn node(kind: Kind) -> NodeId {
        NodeId::new(2, format!("ox-x.Alarms.{}", kind.name()))
    }

    /// (condition, active, acked, retain, message) of each event.
    fn seen(events: &[ConditionEvent]) -> Vec<(String, bool, bool, String)> {
        events
            .iter()
            .map(|e| {
                let name = match e.get_value(
                    opcua::types::AttributeId::Value,
                    &opcua::types::NumericRange::None,
                    &[opcua::types::QualifiedName::new(0, "ConditionName")],
                ) {
                    opcua::types::Variant::String(s) => s.as_ref().to_string(),
                    other => format!("{other:?}"),
                };
                (name, e.active(), e.acked(), e.message().to_string())
            })
            .collect()
    }

    #[test]
    fn an_error_raises_the_condition_of_its_cause_and_its_acknowledgement_acknowledges_the_plc() {
        let mut c = conditions();
        let now = DateTime::now();
        assert!(c.observe(&frame(0.0, "READY", 0, "", 0, false), now).is_empty());
        let raised = c.observe(
            &frame(0.05, "ERROR", 100, "limit input JOINT1_LIMIT_NEG", 0, false),
            now,
        );
        assert_eq!(
            seen(&raised),
            [(
                "LimitSwitch".into(),
                true,
                false,
                "ERROR: limit input JOINT1_LIMIT_NEG".into()
            )]
        );
        // Still in ERROR: nothing new.
        assert!(
            c.observe(&frame(0.1, "ERROR", 100, "limit input JOINT1_LIMIT_NEG", 0, false), now)
                .is_empty()
        );
        // Another event's id, then the right one: the PLC is to be acknowledged.
        let id = raised[0].event_id().clone();
        assert_eq!(
            c.acknowledging(&node(Kind::LimitSwitch), &ByteString::from(b"old".to_vec())),
            Err(AckRefusal::UnknownEvent)
        );
        assert_eq!(c.acknowledging(&node(Kind::Stop), &id), Err(AckRefusal::UnknownEvent));
        assert_eq!(c.acknowledging(&node(Kind::LimitSwitch), &id), Ok(true));
        let acked = c
            .acknowledge(&node(Kind::LimitSwitch), &id, "operator", "switch freed")
            .expect("acknowledged");
        assert!(acked.active() && acked.acked());
        assert_eq!(
            c.acknowledge(&node(Kind::LimitSwitch), acked.event_id(), "operator", "")
                .map(|_| ()),
            Err(AckRefusal::AlreadyAcked)
        );
        // The PLC leaves ERROR: inactive, no longer retained.
        let cleared = c.observe(&frame(0.2, "REBOOT", 0, "", 0, false), now);
        assert_eq!(
            seen(&cleared),
            [(
                "LimitSwitch".into(),
                false,
                true,
                "REBOOT after the acknowledgement".into()
            )]
        );
        assert!(c.refresh().is_empty());
    }

    #[test]
    fn an_error_the_panel_acknowledges_is_acknowledged_by_the_plc() {
        let mut c = conditions();
        let now = DateTime::now();
        c.observe(&frame(0.0, "READY", 0, "", 0, false), now);
        let raised = c.observe(&frame(0.05, "ERROR", 1, "STOP", 0, false), now);
        assert_eq!(seen(&raised), [("Stop".into(), true, false, "ERROR: STOP".into())]);
        // Unacknowledged: a refresh shows it.
        assert_eq!(seen(&c.refresh()), seen(&raised));
        let cleared = c.observe(&frame(0.5, "INIT", 0, "", 0, false), now);
        assert_eq!(
            seen(&cleared),
            [("Stop".into(), false, true, "INIT after the acknowledgement".into())]
        );
        let stop = &c.all[0];
        assert_eq!(
            (stop.kind, stop.acked_by.as_str()),
            (Kind::Stop, "the PLC's acknowledgement")
        );
        // Other reasons: their own conditions.
        for (code, kind) in [
            (20, Kind::EncoderFault),
            (50, Kind::CycleTime),
            (55, Kind::BusFault),
            (41, Kind::Error),
            (11, Kind::LimitSwitch),
        ] {
            let e = c.observe(&frame(1.0, "ERROR", code, "why", 0, false), now);
            assert_eq!(seen(&e)[0].0, kind.name(), "{code}");
            c.observe(&frame(1.5, "INIT", 0, "", 0, false), now);
        }
    }

    #[test]
    fn a_bus_fault_and_overruns_without_error_are_the_servers_to_acknowledge() {
        let mut c = conditions();
        let now = DateTime::now();
        c.observe(&frame(0.0, "READY", 0, "", 0, false), now);
        let fault = c.observe(&frame(0.05, "READY", 0, "", 0, true), now);
        assert_eq!(
            seen(&fault),
            [("BusFault".into(), true, false, "the field bus reports a fault".into())]
        );
        // Its acknowledgement does not acknowledge the PLC: there is nothing to.
        assert_eq!(c.acknowledging(&node(Kind::BusFault), fault[0].event_id()), Ok(false));
        c.acknowledge(&node(Kind::BusFault), fault[0].event_id(), "operator", "")
            .expect("acknowledged");
        let back = c.observe(&frame(0.1, "READY", 0, "", 0, false), now);
        assert_eq!(
            seen(&back),
            [("BusFault".into(), false, true, "the field bus answers again".into())]
        );
        // The station and its cause, where the bus says them: named first, whatever error
        // comes after it (the PLC's reason then is that error's).
        let mut named = frame(0.15, "READY", 0, "", 0, true);
        named.bus_cause = "tcp:127.0.0.1:5020: 4 failed exchanges in a row, the last: cannot connect".into();
        let fault = c.observe(&named, now);
        assert_eq!(
            seen(&fault),
            [(
                "BusFault".into(),
                true,
                false,
                "bus fault: tcp:127.0.0.1:5020: 4 failed exchanges in a row, the last: cannot connect".into()
            )]
        );
        c.acknowledge(&node(Kind::BusFault), fault[0].event_id(), "operator", "")
            .expect("acknowledged");
        c.observe(&frame(0.2, "READY", 0, "", 0, false), now);
        // Two overruns of the fast class: CycleTime for a second of the PLC's time.
        let over = c.observe(&frame(1.0, "READY", 0, "", 2, false), now);
        assert_eq!(
            seen(&over),
            [(
                "CycleTime".into(),
                true,
                false,
                "task class fast: 2 overrun(s), 0 cycle time violation(s) in all (+2, +0)".into()
            )]
        );
        assert!(c.observe(&frame(1.5, "READY", 0, "", 2, false), now).is_empty());
        let quiet = c.observe(&frame(2.0, "READY", 0, "", 2, false), now);
        assert!(!seen(&quiet)[0].1, "{:?}", seen(&quiet));
        // Not acknowledged: retained until it is.
        assert_eq!(c.refresh().len(), 1);
    }

    #[test]
    fn a_refused_job_raises_job_refused_until_a_job_is_made_and_frames_leave_it_alone() {
        let mut c = conditions();
        let now = DateTime::now();
        let made = JobOutcome::Made { file: "MDI".into() };
        // Nothing refused yet: a job made says nothing.
        assert!(c.job(&made, now).is_none());
        let refused = |why: &str| JobOutcome::Refused {
            why: why.into(),
            peer: "127.0.0.1:5000".into(),
        };
        let raised = c
            .job(&refused("a job runs from READY: the machine is INIT"), now)
            .expect("raised");
        assert_eq!(
            seen(std::slice::from_ref(&raised)),
            [(
                "JobRefused".into(),
                true,
                false,
                "job refused (screen 127.0.0.1:5000): a job runs from READY: the machine is INIT".into()
            )]
        );
        assert_eq!(raised.severity, 300);
        // Frames do not clear it; its acknowledgement is the server's alone.
        assert!(c.observe(&frame(0.0, "READY", 0, "", 0, false), now).is_empty());
        assert_eq!(c.acknowledging(&node(Kind::JobRefused), raised.event_id()), Ok(false));
        c.acknowledge(&node(Kind::JobRefused), raised.event_id(), "operator", "")
            .expect("acknowledged");
        // Refused again: unacknowledged again, with the new why.
        let again = c.job(&refused("another job is being planned"), now).expect("raised");
        assert!(again.active() && !again.acked());
        let cleared = c.job(&made, now).expect("cleared");
        assert_eq!(
            seen(&[cleared]),
            [("JobRefused".into(), false, false, "a job was made: MDI".into())]
        );
        // Not acknowledged: retained until it is.
        assert_eq!(c.refresh().len(), 1);
    }
}
