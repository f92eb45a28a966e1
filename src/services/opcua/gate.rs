//! The OPC UA port's gate: a bound on the connections held at once, in all and per source
//! address. The server library accepts every connection and keeps each until its hello times
//! out, each with its buffers; so the public port is this gate, which holds at most a set number
//! of connections and relays each to the server on a loopback port of its own.
//!
//! - A connection beyond the bound, or beyond its source address's share of it, is closed at
//!   once: one host cannot take every slot, however fast it opens them again. It is told why
//!   first, in an OPC UA error message (`BadTcpServerTooBusy` with the reason), written without
//!   waiting: a client says why it could not connect instead of a bare closed connection.
//! - A connection that sends nothing within the hello timeout is closed by the gate, and its
//!   slot freed.
//! - A connection ends as soon as either side closes its end: the server closing a connection
//!   whose hello came too late (it answers ERRF) frees the slot, whether or not the client
//!   closes its end.

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Semaphore;
use tracing::warn;

use crate::runtime::log_limit::Limited;

/// The bounds of the gate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Bounds {
    /// Connections held at once.
    pub max: usize,
    /// Connections held at once from one source address.
    pub per_source: usize,
    /// How long a connection may stay silent before its first bytes (the client's hello).
    pub hello: Duration,
}

impl Bounds {
    /// `max` connections, a source address at most half of them (at least 2), and `hello` for
    /// the first bytes.
    pub fn new(max: usize, hello: Duration) -> Bounds {
        Bounds {
            max,
            per_source: (max / 2).max(2).min(max),
            hello,
        }
    }
}

/// The connections held per source address.
#[derive(Default)]
struct Sources(Mutex<HashMap<IpAddr, usize>>);

impl Sources {
    /// Takes a slot for `ip` if it holds fewer than `max`.
    fn take(&self, ip: IpAddr, max: usize) -> bool {
        let mut held = self.0.lock().unwrap_or_else(|p| p.into_inner());
        let n = held.entry(ip).or_insert(0);
        if *n >= max {
            return false;
        }
        *n += 1;
        true
    }

    /// Gives `ip`'s slot back.
    fn give(&self, ip: IpAddr) {
        let mut held = self.0.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(n) = held.get_mut(&ip) {
            *n -= 1;
            if *n == 0 {
                held.remove(&ip);
            }
        }
    }
}

/// A source's slot, given back when dropped.
struct SourceSlot {
    sources: Arc<Sources>,
    ip: IpAddr,
}

impl Drop for SourceSlot {
    fn drop(&mut self) {
        self.sources.give(self.ip);
    }
}

/// Relays the connections of `public` to the server at `inner` within `bounds` (call inside
/// the tokio runtime; runs until the runtime ends).
pub fn spawn(public: TcpListener, inner: SocketAddr, bounds: Bounds) {
    let permits = Arc::new(Semaphore::new(bounds.max));
    let sources = Arc::new(Sources::default());
    tokio::spawn(async move {
        let refused = Limited::new("OPC UA: connections refused");
        let silent = Arc::new(Limited::new("OPC UA: silent connections closed"));
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
            let ip = peer.ip();
            if !sources.take(ip, bounds.per_source) {
                let why = format!(
                    "{} connections from {ip} are open already (a source's share of the {})",
                    bounds.per_source, bounds.max
                );
                tell_refused(&socket, &why);
                refused.warn(ip, || format!("OPC UA: refused a connection from {peer}: {why}"));
                continue;
            }
            let slot = SourceSlot {
                sources: Arc::clone(&sources),
                ip,
            };
            let Ok(permit) = Arc::clone(&permits).try_acquire_owned() else {
                let why = format!("{} connections are open already", bounds.max);
                tell_refused(&socket, &why);
                refused.warn(ip, || format!("OPC UA: refused a connection from {peer}: {why}"));
                continue;
            };
            let silent = Arc::clone(&silent);
            tokio::spawn(async move {
                let _held = (permit, slot);
                relay(socket, peer, inner, bounds.hello, &silent).await;
            });
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
/// something within `hello`.
async fn relay(mut client: TcpStream, peer: SocketAddr, inner: SocketAddr, hello: Duration, silent: &Limited) {
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
