//! Where the alarms' events are emitted: the machine's object — and so the `Server` object, to
//! which the server passes every event — and, where the Machine Tools view is built, its
//! `Notification/Messages` (OPC 40501-1's place for a machine tool's messages).

use opcua::nodes::Event;
use opcua::server::notify::SubscriptionEventNotifier;
use opcua::types::NodeId;

/// The notifiers the alarms' events are emitted on.
#[derive(Clone, Debug)]
pub struct Emitters {
    /// The machine's object.
    pub object: NodeId,
    /// The Machine Tools view's `Notification/Messages`, where it is built.
    pub messages: Option<NodeId>,
}

impl Emitters {
    /// Emits `event` on every notifier; a subscriber of `Server` gets it once.
    pub fn emit<'a, 'b>(&'a self, notifier: &mut SubscriptionEventNotifier<'a, 'b>, event: &'b dyn Event) {
        notifier.notify(&self.object, event);
        if let Some(messages) = &self.messages {
            notifier.notify_only(messages, event);
        }
    }
}
