//! The screen's listening socket with bounds on the connections it holds:
//!
//! - at most a set number at once, and one source address at most half of them. A connection
//!   beyond either takes the place of the oldest connection that is not a WebSocket and whose
//!   request head is still coming (a slow or stalled client: of its own source where that
//!   source's share is full), else of the oldest plain HTTP connection; only where every place
//!   is a WebSocket is it closed as it is accepted (counted, and logged at most once per source
//!   and interval). So hosts that open many connections, from however many addresses, neither
//!   lock the operator out nor exhaust file descriptors, and a WebSocket — the operator's — is
//!   never evicted;
//! - a connection's first request head (its request line and headers) must be complete within
//!   [`HEAD_TIMEOUT`] of its opening, and every later one within that time of its first byte: a
//!   client that trickles a header a byte a second is closed, whatever it trickles. Once a
//!   connection has become a WebSocket (the server answered `101`), its frames are the server's
//!   to bound.

use std::collections::HashMap;
use std::future::Future;
use std::net::{IpAddr, SocketAddr};
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use axum::extract::connect_info::Connected;
use axum::serve::{IncomingStream, Listener};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};

use crate::runtime::log_limit::Limited;

/// How long a request's head may take: the first from the connection's opening, a later one from
/// its first byte.
pub const HEAD_TIMEOUT: Duration = Duration::from_secs(10);

/// How long a new connection waits for the place of the connection it evicted to be given
/// back (the evicted one is closed by its own task).
const EVICTION_WAIT: Duration = Duration::from_millis(500);

/// What the listener and a connection share: whether it is a WebSocket, whether its request head
/// is still coming, and its eviction.
#[derive(Debug, Default)]
struct Shared {
    upgraded: std::sync::atomic::AtomicBool,
    in_head: std::sync::atomic::AtomicBool,
    evicted: std::sync::atomic::AtomicBool,
    /// The task reading it, woken to see its eviction.
    waker: Mutex<Option<std::task::Waker>>,
}

impl Shared {
    fn evict(&self) {
        self.evicted.store(true, std::sync::atomic::Ordering::Release);
        if let Some(w) = self.waker.lock().unwrap_or_else(|p| p.into_inner()).take() {
            w.wake();
        }
    }
}

/// The connections held, oldest first: (number, source, what they share).
type Registry = Arc<Mutex<Vec<(u64, IpAddr, Arc<Shared>)>>>;

/// The listener: at most `bound` connections at once, a source at most half of them.
pub struct Bounded {
    inner: TcpListener,
    permits: Arc<Semaphore>,
    bound: usize,
    per_source: usize,
    sources: Arc<Mutex<HashMap<IpAddr, usize>>>,
    held: Registry,
    next: u64,
    refused: Limited,
    evicted: Limited,
}

impl Bounded {
    /// Wraps `inner`, holding at most `bound` connections, and from one source address at most
    /// half of them (at least 2).
    pub fn new(inner: TcpListener, bound: usize) -> Bounded {
        Bounded {
            inner,
            permits: Arc::new(Semaphore::new(bound)),
            bound,
            per_source: (bound / 2).max(2).min(bound),
            sources: Arc::new(Mutex::new(HashMap::new())),
            held: Arc::new(Mutex::new(Vec::new())),
            next: 0,
            refused: Limited::new("operator screen: connections closed at once"),
            evicted: Limited::new("operator screen: connections evicted"),
        }
    }

    /// Evicts the connection whose place a new one from `ip` takes (see the module's notes):
    /// of `ip`'s own where its share is full (`own`), else of anyone's. Returns whom, or `None`
    /// where every candidate place is a WebSocket.
    fn evict_for(&self, ip: IpAddr, own: bool) -> Option<IpAddr> {
        use std::sync::atomic::Ordering::Acquire;
        let held = self.held.lock().unwrap_or_else(|p| p.into_inner());
        let candidates = || {
            held.iter()
                .filter(|(_, from, c)| (!own || *from == ip) && !c.upgraded.load(Acquire) && !c.evicted.load(Acquire))
        };
        let victim = candidates()
            .find(|(_, _, c)| c.in_head.load(Acquire))
            .or_else(|| candidates().next())?;
        victim.2.evict();
        Some(victim.1)
    }

    /// Places for a connection from `ip`: free ones, else those of a connection it evicts
    /// (waiting at most [`EVICTION_WAIT`] for them); `Err` with why where there are none.
    async fn places(&mut self, peer: SocketAddr) -> Result<(OwnedSemaphorePermit, SourcePlace), String> {
        let ip = peer.ip();
        let deadline = tokio::time::Instant::now() + EVICTION_WAIT;
        let mut evicted = false;
        loop {
            let source = self.take_source(ip);
            let permit = match &source {
                Some(_) => Arc::clone(&self.permits).try_acquire_owned().ok(),
                None => None,
            };
            if let (Some(source), Some(permit)) = (source, permit) {
                return Ok((permit, source));
            }
            if !evicted {
                let own = self.held_by(ip) >= self.per_source;
                let Some(victim) = self.evict_for(ip, own) else {
                    return Err(if own {
                        format!(
                            "{} connections from {ip} are open already (a source's share of the {}), all WebSockets",
                            self.per_source, self.bound
                        )
                    } else {
                        format!("already {} connections (the bound), all WebSockets", self.bound)
                    });
                };
                self.evicted.warn(victim, || {
                    format!(
                        "operator screen: a connection from {victim} that was not a WebSocket closed to make room for {peer}"
                    )
                });
                evicted = true;
            }
            if tokio::time::Instant::now() >= deadline {
                return Err("the connection evicted for it did not give its place back in time".into());
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    }

    /// How many connections `ip` holds.
    fn held_by(&self, ip: IpAddr) -> usize {
        self.sources
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .get(&ip)
            .copied()
            .unwrap_or(0)
    }

    /// Takes a place for `ip` under its share, if it has one left.
    fn take_source(&self, ip: IpAddr) -> Option<SourcePlace> {
        let mut held = self.sources.lock().unwrap_or_else(|p| p.into_inner());
        let n = held.entry(ip).or_insert(0);
        if *n >= self.per_source {
            return None;
        }
        *n += 1;
        Some(SourcePlace {
            sources: Arc::clone(&self.sources),
            ip,
        })
    }
}

/// A source's place, given back when its connection is dropped.
struct SourcePlace {
    sources: Arc<Mutex<HashMap<IpAddr, usize>>>,
    ip: IpAddr,
}

impl Drop for SourcePlace {
    fn drop(&mut self) {
        let mut held = self.sources.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(n) = held.get_mut(&self.ip) {
            *n -= 1;
            if *n == 0 {
                held.remove(&self.ip);
            }
        }
    }
}

/// The peer of a connection (for [`axum::extract::ConnectInfo`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Peer(pub SocketAddr);

impl std::fmt::Display for Peer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.0.fmt(f)
    }
}

impl Connected<IncomingStream<'_, Bounded>> for Peer {
    fn connect_info(stream: IncomingStream<'_, Bounded>) -> Peer {
        Peer(*stream.remote_addr())
    }
}

impl Listener for Bounded {
    type Io = Held;
    type Addr = SocketAddr;

    async fn accept(&mut self) -> (Held, SocketAddr) {
        loop {
            let (stream, peer) = match self.inner.accept().await {
                Ok(accepted) => accepted,
                Err(e) => {
                    // Out of file descriptors, say: the connections there are go on.
                    tracing::warn!("operator screen: accept failed: {e}");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            };
            match self.places(peer).await {
                Ok((permit, source)) => {
                    let _ = stream.set_nodelay(true);
                    self.next += 1;
                    let shared = Arc::new(Shared::default());
                    shared.in_head.store(true, std::sync::atomic::Ordering::Release);
                    self.held.lock().unwrap_or_else(|p| p.into_inner()).push((
                        self.next,
                        peer.ip(),
                        Arc::clone(&shared),
                    ));
                    let held = Held {
                        stream,
                        _places: (permit, source),
                        head: Head::new(),
                        shared,
                        _registration: Registration {
                            id: self.next,
                            held: Arc::clone(&self.held),
                        },
                    };
                    return (held, peer);
                }
                Err(why) => {
                    self.refused.warn(peer.ip(), || {
                        format!("operator screen: connection from {peer} closed: {why}")
                    });
                }
            }
        }
    }

    fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.inner.local_addr()
    }
}

/// Where a connection's request head stands.
struct Head {
    /// Until when the head must be complete; `None` between requests, and for good once the
    /// connection is a WebSocket.
    deadline: Option<Pin<Box<tokio::time::Sleep>>>,
    /// The head's last three bytes, to find its end (`\r\n\r\n`) across reads.
    tail: [u8; 3],
    /// The server answered `101 Switching Protocols`: the connection is a WebSocket now.
    upgraded: bool,
}

impl Head {
    /// A new connection: its first head complete within [`HEAD_TIMEOUT`] of now.
    fn new() -> Head {
        Head {
            deadline: Some(Box::pin(tokio::time::sleep(HEAD_TIMEOUT))),
            tail: [0; 3],
            upgraded: false,
        }
    }

    /// Bytes read: a head ends at its blank line; bytes after the end of one start the next,
    /// with its own deadline.
    fn read(&mut self, bytes: &[u8]) {
        if self.upgraded {
            return;
        }
        for &b in bytes {
            if self.deadline.is_none() {
                // A new request's first byte.
                self.deadline = Some(Box::pin(tokio::time::sleep(HEAD_TIMEOUT)));
                self.tail = [0; 3];
            }
            if self.tail == *b"\r\n\r" && b == b'\n' {
                self.deadline = None;
            }
            self.tail = [self.tail[1], self.tail[2], b];
        }
    }

    /// Bytes written: the server's `101` makes the connection a WebSocket.
    fn wrote(&mut self, bytes: &[u8]) {
        if !self.upgraded && bytes.starts_with(b"HTTP/1.1 101") {
            self.upgraded = true;
            self.deadline = None;
        }
    }

    /// Whether the head's time is up (registers the wake-up otherwise).
    fn expired(&mut self, cx: &mut Context<'_>) -> bool {
        self.deadline.as_mut().is_some_and(|d| d.as_mut().poll(cx).is_ready())
    }
}

/// An accepted connection, holding its places under the bounds until it is dropped.
pub struct Held {
    stream: TcpStream,
    _places: (OwnedSemaphorePermit, SourcePlace),
    head: Head,
    shared: Arc<Shared>,
    _registration: Registration,
}

/// A connection's entry in the listener's registry, removed when it is dropped.
struct Registration {
    id: u64,
    held: Registry,
}

impl Drop for Registration {
    fn drop(&mut self) {
        self.held
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .retain(|(id, _, _)| *id != self.id);
    }
}

impl Held {
    /// Tells the listener where the connection stands (a WebSocket, a head coming); whether it
    /// was evicted (then registers the waker that its eviction wakes).
    fn evicted(&mut self, cx: &mut Context<'_>) -> bool {
        use std::sync::atomic::Ordering::{Acquire, Release};
        self.shared.upgraded.store(self.head.upgraded, Release);
        self.shared.in_head.store(self.head.deadline.is_some(), Release);
        let mut waker = self.shared.waker.lock().unwrap_or_else(|p| p.into_inner());
        if !waker.as_ref().is_some_and(|w| w.will_wake(cx.waker())) {
            *waker = Some(cx.waker().clone());
        }
        drop(waker);
        self.shared.evicted.load(Acquire)
    }
}

impl AsyncRead for Held {
    fn poll_read(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<std::io::Result<()>> {
        let this = self.get_mut();
        if this.head.expired(cx) {
            return Poll::Ready(Err(std::io::Error::new(
                std::io::ErrorKind::TimedOut,
                "the request's head was not complete within its time",
            )));
        }
        if this.evicted(cx) {
            return Poll::Ready(Err(std::io::Error::new(
                std::io::ErrorKind::ConnectionAborted,
                "closed to make room for another connection",
            )));
        }
        let before = buf.filled().len();
        let polled = Pin::new(&mut this.stream).poll_read(cx, buf);
        if let Poll::Ready(Ok(())) = polled {
            this.head.read(&buf.filled()[before..]);
        }
        polled
    }
}

impl AsyncWrite for Held {
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<std::io::Result<usize>> {
        let this = self.get_mut();
        this.head.wrote(buf);
        // A WebSocket from its 101 on: never a candidate for eviction.
        this.shared
            .upgraded
            .store(this.head.upgraded, std::sync::atomic::Ordering::Release);
        Pin::new(&mut this.stream).poll_write(cx, buf)
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.get_mut().stream).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.get_mut().stream).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        let this = self.get_mut();
        if let Some(first) = bufs.iter().find(|b| !b.is_empty()) {
            this.head.wrote(first);
            this.shared
                .upgraded
                .store(this.head.upgraded, std::sync::atomic::Ordering::Release);
        }
        Pin::new(&mut this.stream).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn a_head_must_end_within_its_time_from_its_first_byte_until_the_websocket() {
        let waker = futures_waker();
        let mut cx = Context::from_waker(&waker);
        let mut head = Head::new();
        head.read(b"GET / HTTP/1.1\r\nHost: x\r\n");
        tokio::time::advance(HEAD_TIMEOUT - Duration::from_millis(1)).await;
        assert!(!head.expired(&mut cx));
        // Its end, split across reads.
        head.read(b"\r");
        head.read(b"\n");
        tokio::time::advance(Duration::from_secs(60)).await;
        assert!(!head.expired(&mut cx), "between requests there is no deadline");
        // The next request, trickled: closed at its time, whatever it trickles.
        for _ in 0..9 {
            head.read(b"G");
            tokio::time::advance(Duration::from_secs(1)).await;
            assert!(!head.expired(&mut cx));
        }
        tokio::time::advance(Duration::from_secs(1)).await;
        assert!(head.expired(&mut cx));
        // A WebSocket: no head any more.
        let mut head = Head::new();
        head.read(b"GET /ws HTTP/1.1\r\n\r\n");
        head.wrote(b"HTTP/1.1 101 Switching Protocols\r\n");
        head.read(b"\x81\x05hello");
        tokio::time::advance(Duration::from_secs(60)).await;
        assert!(!head.expired(&mut cx));
    }

    /// A waker that does nothing: the test polls by hand.
    fn futures_waker() -> std::task::Waker {
        std::task::Waker::noop().clone()
    }
}
