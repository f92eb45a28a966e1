//! The OPC UA port's gate: a bound on the connections held at once. The server library accepts
//! every connection and keeps each until its hello times out, each with its buffers; so the
//! public port is this gate, which holds at most a set number of connections and relays each to
//! the server on a loopback port of its own. A connection beyond the bound is closed at once.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Semaphore;
use tracing::warn;

/// The most refused connections logged in a window; more are counted and summarised.
const LOGGED: u64 = 3;
/// The window of [`LOGGED`].
const WINDOW: Duration = Duration::from_secs(10);

/// Relays the connections of `public` to the server at `inner`, at most `max` at once (call
/// inside the tokio runtime; runs until the runtime ends).
pub fn spawn(public: TcpListener, inner: SocketAddr, max: usize) {
    let permits = Arc::new(Semaphore::new(max));
    tokio::spawn(async move {
        let mut refused = (Instant::now(), 0u64);
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
            let Ok(permit) = Arc::clone(&permits).try_acquire_owned() else {
                if refused.0.elapsed() > WINDOW {
                    if refused.1 > LOGGED {
                        warn!(
                            "OPC UA: {} more connections refused in the last {} s",
                            refused.1 - LOGGED,
                            WINDOW.as_secs()
                        );
                    }
                    refused = (Instant::now(), 0);
                }
                refused.1 += 1;
                if refused.1 <= LOGGED {
                    warn!("OPC UA: refused a connection from {peer}: {max} connections are open already");
                }
                drop(socket);
                continue;
            };
            tokio::spawn(async move {
                let _held = permit;
                relay(socket, inner).await;
            });
        }
    });
}

/// Carries one connection's bytes both ways until either side closes.
async fn relay(mut client: TcpStream, inner: SocketAddr) {
    let Ok(mut server) = TcpStream::connect(inner).await else {
        return;
    };
    // OPC UA messages are small and answered at once: no Nagle delay on either leg.
    let _ = client.set_nodelay(true);
    let _ = server.set_nodelay(true);
    let _ = tokio::io::copy_bidirectional(&mut client, &mut server).await;
}
