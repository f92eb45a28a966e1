//! The events of the alarms and conditions ([`super::conditions`]): the fields of
//! `BaseEventType`, `ConditionType`, `AcknowledgeableConditionType` and `AlarmConditionType` a
//! client selects in its event filter (`EventId`, `Message`, `Severity`, `ConditionName`,
//! `ActiveState/Id`, `AckedState/Id`, the `ConditionId`, …), answered from one condition's
//! state. A field the event does not have is empty, as the standard asks.

use opcua::nodes::Event;
use opcua::types::{
    AttributeId, ByteString, DateTime, LocalizedText, NodeId, NumericRange, ObjectTypeId, QualifiedName, StatusCode,
    UAString, Variant, event_field::EventField,
};

/// One event of a condition: its state when the event was made (made by
/// [`super::conditions`]).
#[derive(Clone, Debug)]
pub struct ConditionEvent {
    pub(super) event_id: ByteString,
    pub(super) event_type: NodeId,
    pub(super) source_node: NodeId,
    pub(super) source_name: String,
    pub(super) time: DateTime,
    pub(super) message: String,
    pub(super) severity: u16,
    pub(super) condition_id: NodeId,
    pub(super) condition_name: &'static str,
    pub(super) retain: bool,
    pub(super) active: bool,
    pub(super) acked: bool,
    pub(super) acked_by: String,
    pub(super) comment: String,
}

impl ConditionEvent {
    /// Its id (an acknowledgement names it).
    pub fn event_id(&self) -> &ByteString {
        &self.event_id
    }

    /// The condition's name.
    pub fn condition_name(&self) -> &'static str {
        self.condition_name
    }

    /// Its message.
    pub fn message(&self) -> &str {
        &self.message
    }

    /// Whether the condition was active.
    pub fn active(&self) -> bool {
        self.active
    }

    /// Whether the condition was acknowledged.
    pub fn acked(&self) -> bool {
        self.acked
    }

    /// A two-state variable's value: its text, or its `Id` (a Boolean).
    fn two_state(rest: &[QualifiedName], on: bool, texts: (&str, &str)) -> Variant {
        match rest {
            [] => Variant::from(LocalizedText::new("en", if on { texts.0 } else { texts.1 })),
            [id] if id.namespace_index == 0 && id.name.as_ref() == "Id" => Variant::Boolean(on),
            _ => Variant::Empty,
        }
    }

    /// The value of the field at `path` (browse names in namespace 0).
    fn field(&self, path: &[QualifiedName]) -> Variant {
        let Some((first, rest)) = path.split_first() else {
            return Variant::Empty;
        };
        if first.namespace_index != 0 {
            return Variant::Empty;
        }
        let leaf = |v: Variant| if rest.is_empty() { v } else { Variant::Empty };
        match first.name.as_ref() {
            "EventId" => leaf(Variant::from(self.event_id.clone())),
            "EventType" => leaf(Variant::from(self.event_type.clone())),
            "SourceNode" => leaf(Variant::from(self.source_node.clone())),
            "SourceName" => leaf(Variant::from(UAString::from(self.source_name.as_str()))),
            "Time" | "ReceiveTime" => leaf(Variant::from(self.time)),
            "Message" => leaf(Variant::from(LocalizedText::new("en", &self.message))),
            "Severity" => leaf(Variant::UInt16(self.severity)),
            "ConditionName" => leaf(Variant::from(UAString::from(self.condition_name))),
            "ConditionClassId" => leaf(Variant::from(NodeId::from(ObjectTypeId::SystemConditionClassType))),
            "ConditionClassName" => leaf(Variant::from(LocalizedText::new("en", "System"))),
            "BranchId" => leaf(Variant::from(NodeId::null())),
            "Retain" => leaf(Variant::Boolean(self.retain)),
            "EnabledState" => Self::two_state(rest, true, ("Enabled", "Disabled")),
            "ActiveState" => Self::two_state(rest, self.active, ("Active", "Inactive")),
            "AckedState" => Self::two_state(rest, self.acked, ("Acknowledged", "Unacknowledged")),
            "Quality" => leaf(Variant::from(StatusCode::Good)),
            "LastSeverity" => leaf(Variant::UInt16(self.severity)),
            "Comment" => leaf(Variant::from(LocalizedText::new("en", &self.comment))),
            "ClientUserId" => leaf(Variant::from(UAString::from(self.acked_by.as_str()))),
            "SuppressedOrShelved" => leaf(Variant::Boolean(false)),
            _ => Variant::Empty,
        }
    }
}

impl EventField for ConditionEvent {
    fn get_value(
        &self,
        attribute_id: AttributeId,
        index_range: &NumericRange,
        remaining_path: &[QualifiedName],
    ) -> Variant {
        if !matches!(index_range, NumericRange::None) {
            return Variant::Empty;
        }
        match attribute_id {
            // The condition's own node id: `ConditionId` (the NodeId attribute, no path).
            AttributeId::NodeId if remaining_path.is_empty() => Variant::from(self.condition_id.clone()),
            AttributeId::Value => self.field(remaining_path),
            _ => Variant::Empty,
        }
    }
}

impl Event for ConditionEvent {
    /// Every field is answered whichever of the condition's types the client named it by
    /// (`BaseEventType`, `ConditionType`, …): their fields' names do not collide.
    fn get_field(
        &self,
        _type_definition_id: &NodeId,
        attribute_id: AttributeId,
        index_range: &NumericRange,
        browse_path: &[QualifiedName],
    ) -> Variant {
        self.get_value(attribute_id, index_range, browse_path)
    }

    fn time(&self) -> &DateTime {
        &self.time
    }

    fn event_type_id(&self) -> &NodeId {
        &self.event_type
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn path(names: &[&str]) -> Vec<QualifiedName> {
        names.iter().map(|n| QualifiedName::new(0, *n)).collect()
    }

    #[test]
    fn a_client_selects_the_fields_of_every_condition_type() {
        let e = ConditionEvent {
            event_id: ByteString::from(b"7".to_vec()),
            event_type: ObjectTypeId::OffNormalAlarmType.into(),
            source_node: NodeId::new(2, "ox-x"),
            source_name: "ox-x".into(),
            time: DateTime::now(),
            message: "ERROR: limit input JOINT1_LIMIT_POS".into(),
            severity: 800,
            condition_id: NodeId::new(2, "ox-x.Alarms.LimitSwitch"),
            condition_name: "LimitSwitch",
            retain: true,
            active: true,
            acked: false,
            acked_by: String::new(),
            comment: String::new(),
        };
        let get = |attribute, names: &[&str]| {
            e.get_field(
                &ObjectTypeId::BaseEventType.into(),
                attribute,
                &NumericRange::None,
                &path(names),
            )
        };
        assert_eq!(
            get(AttributeId::Value, &["Message"]),
            Variant::from(LocalizedText::new("en", "ERROR: limit input JOINT1_LIMIT_POS"))
        );
        assert_eq!(get(AttributeId::Value, &["Severity"]), Variant::UInt16(800));
        assert_eq!(
            get(AttributeId::Value, &["EventType"]),
            Variant::from(NodeId::from(ObjectTypeId::OffNormalAlarmType))
        );
        assert_eq!(get(AttributeId::Value, &["ActiveState", "Id"]), Variant::Boolean(true));
        assert_eq!(get(AttributeId::Value, &["AckedState", "Id"]), Variant::Boolean(false));
        assert_eq!(
            get(AttributeId::Value, &["AckedState"]),
            Variant::from(LocalizedText::new("en", "Unacknowledged"))
        );
        assert_eq!(get(AttributeId::Value, &["Retain"]), Variant::Boolean(true));
        assert_eq!(
            get(AttributeId::NodeId, &[]),
            Variant::from(NodeId::new(2, "ox-x.Alarms.LimitSwitch"))
        );
        assert_eq!(
            get(AttributeId::Value, &["EventId"]),
            Variant::from(ByteString::from(b"7".to_vec()))
        );
        // Fields the event does not have, and paths that go on past a value.
        assert_eq!(
            get(AttributeId::Value, &["ShelvingState", "CurrentState"]),
            Variant::Empty
        );
        assert_eq!(get(AttributeId::Value, &["Severity", "Id"]), Variant::Empty);
        assert_eq!(get(AttributeId::Value, &[]), Variant::Empty);
    }
}
