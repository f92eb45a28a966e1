//! The conditions' standard methods, which the server hands to pkm-plc before any node manager
//! (see `vendor/async-opcua-server/VENDORED.md`): `Acknowledge` on a condition (by a user who
//! may command; a condition ERROR raised acknowledges the PLC through the same input as the
//! `Acknowledge` method, so it is traced and replayed), and `ConditionRefresh` /
//! `ConditionRefresh2`, which send the calling subscription the conditions a client should see
//! between a `RefreshStartEvent` and a `RefreshEndEvent`.

use std::sync::{Arc, Mutex};

use opcua::nodes::{BaseEventType, Event};
use opcua::server::node_manager::{ConditionMethods, MethodCall, RequestContext};
use opcua::types::{ByteString, DateTime, LocalizedText, MethodId, ObjectId, ObjectTypeId, StatusCode, Variant};
use tracing::info;

use super::conditions::Conditions;
use super::nodes::PlcNodeManager;
use super::space::Method;

/// What carries out the conditions' methods.
pub struct AlarmMethods {
    /// The conditions.
    pub conditions: Arc<Mutex<Conditions>>,
    /// The node manager (its commander acknowledges the PLC).
    pub manager: Arc<PlcNodeManager>,
    /// Where the events are emitted (the machine's object, the Machine Tools view's messages).
    pub emitters: super::emitters::Emitters,
}

impl ConditionMethods for AlarmMethods {
    fn call(&self, context: &RequestContext, call: &mut MethodCall) -> bool {
        let Ok(id) = call.method_id().as_method_id() else {
            return false;
        };
        let outcome = match id {
            MethodId::AcknowledgeableConditionType_Acknowledge => self.acknowledge(context, call),
            MethodId::ConditionType_ConditionRefresh | MethodId::ConditionType_ConditionRefresh2 => {
                self.refresh(context, call)
            }
            _ => return false,
        };
        call.set_status(match outcome {
            Ok(()) => StatusCode::Good,
            Err(code) => code,
        });
        true
    }
}

impl AlarmMethods {
    fn lock(&self) -> std::sync::MutexGuard<'_, Conditions> {
        self.conditions.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// `Acknowledge(EventId, Comment)` on the condition `call`'s object.
    fn acknowledge(&self, context: &RequestContext, call: &MethodCall) -> Result<(), StatusCode> {
        if !context
            .authenticator
            .is_user_executable(&context.token, call.method_id())
        {
            return Err(StatusCode::BadUserAccessDenied);
        }
        let (event_id, comment) = match call.arguments() {
            [Variant::ByteString(id), Variant::LocalizedText(c)] => (id.clone(), c.text.as_ref().to_string()),
            [_, _] => return Err(StatusCode::BadInvalidArgument),
            [] | [_] => return Err(StatusCode::BadArgumentsMissing),
            _ => return Err(StatusCode::BadTooManyArguments),
        };
        let user = context.user_token().0.clone();
        let mut conditions = self.lock();
        let node = call.object_id();
        let plc = conditions
            .acknowledging(node, &event_id)
            .map_err(|refused| refused.status())?;
        if plc {
            // The PLC's acknowledgement, as the Acknowledge method gives it (logged there).
            let commander = self
                .manager
                .inner()
                .commander()
                .ok_or(StatusCode::BadServiceUnsupported)?;
            commander.call(Method::Acknowledge, &[], &user)?;
        }
        let event = conditions
            .acknowledge(node, &event_id, &user, &comment)
            .map_err(|refused| refused.status())?;
        drop(conditions);
        info!(
            "OPC UA: user \"{user}\" acknowledged the condition {}{}: {}",
            event.condition_name(),
            if comment.is_empty() {
                String::new()
            } else {
                format!(" ({comment})")
            },
            event.message()
        );
        self.emitters
            .emit(&mut context.subscriptions.event_notifier(), &event as &dyn Event);
        Ok(())
    }

    /// `ConditionRefresh(SubscriptionId)` and `ConditionRefresh2(SubscriptionId, MonitoredItemId)`:
    /// to the calling session's subscription only.
    fn refresh(&self, context: &RequestContext, call: &MethodCall) -> Result<(), StatusCode> {
        let subscription = match call.arguments().first() {
            Some(Variant::UInt32(id)) => *id,
            Some(_) => return Err(StatusCode::BadInvalidArgument),
            None => return Err(StatusCode::BadArgumentsMissing),
        };
        let owned = context
            .subscriptions
            .get_session_subscriptions(context.session_id)
            .is_some_and(|subs| subs.lock().contains(subscription));
        if !owned {
            return Err(StatusCode::BadSubscriptionIdInvalid);
        }
        let marker = |ty: ObjectTypeId, what: &str| BaseEventType {
            event_id: ByteString::from(format!("{what}:{}", DateTime::now().checked_ticks()).into_bytes()),
            event_type: ty.into(),
            source_node: ObjectId::Server.into(),
            source_name: "Server".into(),
            time: DateTime::now(),
            receive_time: DateTime::now(),
            message: LocalizedText::new("en", what),
            severity: 1,
            ..Default::default()
        };
        let start = marker(ObjectTypeId::RefreshStartEventType, "refresh start");
        let states = self.lock().refresh();
        let end = marker(ObjectTypeId::RefreshEndEventType, "refresh end");
        let mut notifier = context.subscriptions.event_notifier();
        self.emitters.emit(&mut notifier, &start as &dyn Event);
        for e in &states {
            self.emitters.emit(&mut notifier, e as &dyn Event);
        }
        self.emitters.emit(&mut notifier, &end as &dyn Event);
        notifier.keep_only(subscription);
        Ok(())
    }
}
