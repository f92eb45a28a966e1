//! The OPC UA port's gate: a bound on the connections held at once. The server library accepts
//! every connection and keeps each until its hello times out, each with its buffers; so the
//! public port is this gate, which holds at most a set number of connections and relays each to
//! the server on a loopback port of its own.
//!
//! Which connection gives way is decided by what it holds, never by where it comes from (a
//! client on several addresses defeats any share per address, and a gateway's clients all come
//! from one): the server says, for each relayed connection, whether it carries a user's session,
//! an anonymous one, or none ([`Standing`]).
//!
//! - When every place is taken, the connection without a session that was opened first is
//!   closed to make room: a user's or an anonymous session is never closed by the gate (the
//!   server bounds the anonymous sessions, so there is always room for a user's to be made).
//!   Only when every connection holds a session is a new one refused, told why first in an OPC
//!   UA error message (`BadTcpServerTooBusy` with the reason), written without waiting.
//! - A connection that sends nothing within the hello timeout is closed, and its place freed.
//! - A connection that holds no session for [`Bounds::sessionless`] (it never made one, or
//!   closed it and stayed) is closed: an idle or leaked connection frees its place.
//! - A connection ends as soon as either side closes its end: the server closing a connection
//!   whose hello came too late (it answers ERRF) frees the place, whether or not the client
//!   closes its end.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Notify;
use tracing::warn;

pub use opcua::server::ConnectionStanding as Standing;

use crate::runtime::log_limit::Limited;

/// The bounds of the gate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Bounds {
    /// Connections held at once.
    pub max: usize,
    /// How long a connection may stay silent before its first bytes (the client's hello).
    pub hello: Duration,
    /// How long a connection may hold no session.
    pub sessionless: Duration,
}

/// What the server says a relayed connection holds, by the address the gate connected to it
/// from.
pub type StandingOf = Arc<dyn Fn(SocketAddr) -> Standing + Send + Sync>;

/// One connection the gate holds.
struct Held {
    /// The client's address.
    peer: SocketAddr,
    /// The address of the gate's connection to the server (`None` before the hello).
    relayed_from: Option<SocketAddr>,
    /// When the gate took it.
    opened: Instant,
    /// Ends its relay.
    close: Arc<Notify>,
}

/// The connections held, by a number of the gate's own.
#[derive(Default)]
struct Connections(Mutex<HashMap<u64, Held>>);

impl Connections {
    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<u64, Held>> {
        self.0.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The connection without a session opened first, among `held` (`None`: every one holds a
    /// session).
    fn first_sessionless(held: &HashMap<u64, Held>, standing: &StandingOf) -> Option<u64> {
        held.iter()
            .filter(|(_, h)| {
                h.relayed_from
                    .is_none_or(|from| standing(from) == Standing::Sessionless)
            })
            .min_by_key(|(_, h)| h.opened)
            .map(|(id, _)| *id)
    }
}

/// A held connection, forgotten when its relay ends.
struct Place {
    connections: Arc<Connections>,
    id: u64,
}

impl Drop for Place {
    fn drop(&mut self) {
        self.connections.lock().remove(&self.id);
    }
}

/// Relays the connections of `public` to the server at `inner` within `bounds`, asking
/// `standing` what each holds (call inside the tokio runtime; runs until the runtime ends).
pub fn spawn(public: TcpListener, inner: SocketAddr, bounds: Bounds, standing: StandingOf) {
    let connections = Arc::new(Connections::default());
    let closed = Arc::new(Limited::new("OPC UA: connections closed by the gate"));
    sweep(
        Arc::clone(&connections),
        bounds,
        Arc::clone(&standing),
        Arc::clone(&closed),
    );
    tokio::spawn(async move {
        let refused = Limited::new("OPC UA: connections refused");
        let silent = Arc::new(Limited::new("OPC UA: silent connections closed"));
        let mut next_id = 0u64;
        loop {
            let (socket, peer) = match public.accept().await {
                Ok(accepted) => accepted,
                Err(e) => {
                    // Out of file descriptors, say: wait rather than spin.
                    warn!("OPC UA: cannot accept a connection: {e}");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            };
            let close = Arc::new(Notify::new());
            {
                let mut held = connections.lock();
                if held.len() >= bounds.max {
                    let Some(victim) = Connections::first_sessionless(&held, &standing) else {
                        let why = format!("{} connections are open, each with a session", bounds.max);
                        tell_refused(&socket, &why);
                        refused.warn(peer.ip(), || format!("OPC UA: refused a connection from {peer}: {why}"));
                        continue;
                    };
                    if let Some(victim) = held.remove(&victim) {
                        victim.close.notify_one();
                        closed.info(victim.peer.ip(), || {
                            format!(
                                "OPC UA: closed the connection from {} (no session, open {:.1} s) to make \
                                 room for one from {peer}: all {} places were taken",
                                victim.peer,
                                victim.opened.elapsed().as_secs_f64(),
                                bounds.max
                            )
                        });
                    }
                }
                next_id += 1;
                held.insert(
                    next_id,
                    Held {
                        peer,
                        relayed_from: None,
                        opened: Instant::now(),
                        close: Arc::clone(&close),
                    },
                );
            }
            let place = Place {
                connections: Arc::clone(&connections),
                id: next_id,
            };
            let silent = Arc::clone(&silent);
            tokio::spawn(async move {
                tokio::select! {
                    () = relay(socket, peer, inner, bounds.hello, &silent, &place) => {}
                    () = close.notified() => {}
                }
            });
        }
    });
}

/// Closes, once a second, the connections that have held no session for `bounds.sessionless`.
fn sweep(connections: Arc<Connections>, bounds: Bounds, standing: StandingOf, closed: Arc<Limited>) {
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tick.tick().await;
            let now = Instant::now();
            let mut held = connections.lock();
            let idle: Vec<u64> = held
                .iter()
                .filter(|(_, h)| {
                    now.duration_since(h.opened) >= bounds.sessionless
                        && h.relayed_from
                            .is_some_and(|from| standing(from) == Standing::Sessionless)
                })
                .map(|(id, _)| *id)
                .collect();
            for id in idle {
                if let Some(h) = held.remove(&id) {
                    h.close.notify_one();
                    closed.info(h.peer.ip(), || {
                        format!(
                            "OPC UA: closed the connection from {}: no session for {} s",
                            h.peer,
                            bounds.sessionless.as_secs()
                        )
                    });
                }
            }
        }
    });
}

/// Tells a refused connection why, as an OPC UA error message (OPC 10000-6, 7.1.2.5:
/// `BadTcpServerTooBusy` and the reason), if its socket takes it at once: the gate never waits
/// for a refused client.
fn tell_refused(socket: &TcpStream, why: &str) {
    const BAD_TCP_SERVER_TOO_BUSY: u32 = 0x807D_0000;
    let reason = format!("pkm-plc refused the connection: {why}");
    let mut message = b"ERRF".to_vec();
    message.extend_from_slice(&((16 + reason.len()) as u32).to_le_bytes());
    message.extend_from_slice(&BAD_TCP_SERVER_TOO_BUSY.to_le_bytes());
    message.extend_from_slice(&(reason.len() as i32).to_le_bytes());
    message.extend_from_slice(reason.as_bytes());
    let _ = socket.try_write(&message);
}

/// Carries one connection's bytes both ways until either side closes, once the client has said
/// something within `hello`; `place` learns the address the server knows it by.
async fn relay(
    mut client: TcpStream,
    peer: SocketAddr,
    inner: SocketAddr,
    hello: Duration,
    silent: &Limited,
    place: &Place,
) {
    let mut first = [0u8; 4096];
    let n = match tokio::time::timeout(hello, client.read(&mut first)).await {
        Ok(Ok(n)) if n > 0 => n,
        Ok(_) => return,
        Err(_) => {
            silent.info(peer.ip(), || {
                format!(
                    "OPC UA: closed the connection from {peer}: nothing received within {} s",
                    hello.as_secs()
                )
            });
            return;
        }
    };
    let Ok(mut server) = TcpStream::connect(inner).await else {
        return;
    };
    // The server knows the connection by this address: the gate asks it by it what it holds.
    let from = server.local_addr().ok();
    if let Some(held) = place.connections.lock().get_mut(&place.id) {
        held.relayed_from = from;
    }
    // OPC UA messages are small and answered at once: no Nagle delay on either leg.
    let _ = client.set_nodelay(true);
    let _ = server.set_nodelay(true);
    if server.write_all(&first[..n]).await.is_err() {
        return;
    }
    let (mut from_client, mut to_client) = client.split();
    let (mut from_server, mut to_server) = server.split();
    // Whichever side ends first ends both: OPC UA has no half-closed connections.
    tokio::select! {
        _ = tokio::io::copy(&mut from_client, &mut to_server) => {}
        _ = tokio::io::copy(&mut from_server, &mut to_client) => {}
    }
}
