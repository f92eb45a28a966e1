//! The station's Modbus server: TCP (MBAP framing) and RTU (frames found by their function's
//! length and checked by CRC), built to keep serving whatever arrives.
//!
//! - Every request is decoded by [`super::pdu`], which checks lengths and quantities; a malformed
//!   one is answered with an exception, never passed on.
//! - TCP: at most [`ServerOptions::max_connections`] clients at once (more are closed on accept);
//!   a client silent for [`ServerOptions::idle_timeout`], or that starts a frame and does not
//!   finish it within [`FRAME_TIMEOUT`], is disconnected; an `accept()` error (file descriptors
//!   exhausted, say) is logged and the server goes on after a pause.
//! - Repeated problems are summarised ([`Digest`]): the first of each kind is logged with its
//!   detail, the rest are counted and reported every [`DIGEST_PERIOD`].
//! - **One controller owns the outputs**: the first client to write takes them; writes from any
//!   other client are refused with exception 6 (server device busy) while it holds them. When
//!   its connection closes, every output goes to its safe value at once (a coupler's connection
//!   monitoring).
//! - The **output watchdog** of a real bus coupler: when the owner's writes stop for
//!   [`ServerOptions::watchdog`], every output goes to its safe value (zero) and the outputs are
//!   free, as the station's drives must stop when the controller dies without a safe stop
//!   (SIGKILL, a crash, a cut cable). Only the owner's writes feed it: another client writing
//!   an unused coil cannot keep a dead controller's drives running. The next write takes the
//!   outputs over again.

use std::io::ErrorKind;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::TcpListener;

use super::modbus::{ClientId, SERIAL_LINE, Station, StationReport};
use super::pdu::{MAX_PDU, PduLen, crc16, decode_request, encode_response, request_len};

/// A started frame must be complete within this time (TCP: the PDU after its header).
pub const FRAME_TIMEOUT: Duration = Duration::from_secs(1);

/// Bytes of an RTU frame separated by a silence longer than this start over: the incomplete
/// frame before the silence is discarded. The specification's 3.5 character times are 0.3 ms
/// at 115 200 baud; an emulated line and a scheduler on a busy machine need far more.
pub const RTU_GAP: Duration = Duration::from_millis(50);

/// How often repeated problems are reported.
pub const DIGEST_PERIOD: Duration = Duration::from_secs(10);

/// How the server guards itself and the machine.
#[derive(Clone, Copy, Debug)]
pub struct ServerOptions {
    /// Outputs go to their safe values when no write arrives for this long; `None`: never.
    pub watchdog: Option<Duration>,
    /// TCP clients served at once.
    pub max_connections: usize,
    /// A TCP client that sends no request for this long is disconnected.
    pub idle_timeout: Duration,
}

impl Default for ServerOptions {
    fn default() -> Self {
        ServerOptions {
            watchdog: Some(Duration::from_millis(100)),
            max_connections: 8,
            idle_timeout: Duration::from_secs(60),
        }
    }
}

/// Problems counted by kind: the first of each kind in a period is logged with its detail, the
/// others are summed and reported once per [`DIGEST_PERIOD`] — 2000 bad frames make two log
/// lines, not 2000.
#[derive(Debug)]
pub struct Digest {
    since: Instant,
    counts: Vec<(&'static str, u64)>,
}

impl Default for Digest {
    fn default() -> Self {
        Digest {
            since: Instant::now(),
            counts: Vec::new(),
        }
    }
}

impl Digest {
    /// Notes one problem of `kind`; `detail` is logged if it is the first of its kind in this
    /// period (true then).
    pub fn note(&mut self, kind: &'static str, detail: impl FnOnce() -> String) -> bool {
        match self.counts.iter_mut().find(|(k, _)| *k == kind) {
            Some((_, n)) => {
                *n += 1;
                false
            }
            None => {
                tracing::warn!("io-sim: {kind}: {} (repeats are summarised)", detail());
                self.counts.push((kind, 0));
                true
            }
        }
    }

    /// Reports the problems counted since the last report, if the period is over.
    pub fn report_if_due(&mut self) {
        if self.since.elapsed() < DIGEST_PERIOD {
            return;
        }
        let repeated: Vec<String> = self
            .counts
            .iter()
            .filter(|(_, n)| *n > 0)
            .map(|(k, n)| format!("{n} × {k}"))
            .collect();
        if !repeated.is_empty() {
            tracing::warn!(
                "io-sim: in the last {} s, besides those logged: {}",
                self.since.elapsed().as_secs(),
                repeated.join(", ")
            );
        }
        self.counts.clear();
        self.since = Instant::now();
    }
}

/// The station and its digest, shared by the connections and the watchdog.
struct Shared {
    station: Mutex<Station>,
    digest: Mutex<Digest>,
}

/// A lock that survives a panicked holder: the station's state is plain data, still usable.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

impl Shared {
    /// Answers one request PDU of `client` into `out` (the response PDU or an exception).
    fn answer(&self, pdu: &[u8], client: ClientId, out: &mut Vec<u8>) {
        match decode_request(pdu) {
            Ok(request) => {
                let result = lock(&self.station).handle(request, client);
                if result == Err(tokio_modbus::ExceptionCode::ServerDeviceBusy) {
                    self.note("write refused", || {
                        format!("client {client}: another client owns the outputs")
                    });
                }
                encode_response(pdu[0], &result, out);
            }
            Err(refused) => {
                self.note("malformed request", || {
                    format!("function {:#04x}: {}", refused.function, refused.why)
                });
                encode_response(refused.function, &Err(refused.exception), out);
            }
        }
    }

    fn note(&self, kind: &'static str, detail: impl FnOnce() -> String) {
        lock(&self.digest).note(kind, detail);
    }

    /// The periodic duties: the output watchdog and the problem report.
    async fn supervise(&self, period: Duration) {
        let mut tick = tokio::time::interval(period);
        loop {
            tick.tick().await;
            lock(&self.station).watch();
            lock(&self.digest).report_if_due();
        }
    }
}

fn shared(mut station: Station, options: &ServerOptions) -> (Arc<Shared>, Duration) {
    station.set_watchdog(options.watchdog);
    // The watchdog acts within a quarter of its time (at least every 5 ms, at most every 50); a
    // bus controller's threshold is its clients' to set, so it is checked every 5 ms.
    let period = match (station.is_bus_controller(), options.watchdog) {
        (true, _) => Duration::from_millis(5),
        (false, None) => Duration::from_millis(50),
        (false, Some(w)) => (w / 4).clamp(Duration::from_millis(5), Duration::from_millis(50)),
    };
    let shared = Arc::new(Shared {
        station: Mutex::new(station),
        digest: Mutex::new(Digest::default()),
    });
    (shared, period)
}

/// Serves `station` as Modbus TCP on `listener` until `stop` completes; then reports what the
/// machine did ([`Station::report`]).
pub async fn serve_tcp(
    listener: TcpListener,
    station: Station,
    options: ServerOptions,
    stop: impl Future<Output = ()>,
) -> std::io::Result<StationReport> {
    let (shared, period) = shared(station, &options);
    let active = Arc::new(AtomicUsize::new(0));
    // Connections are numbered from 1 (0 is a serial line's master).
    let mut next_client: ClientId = SERIAL_LINE;
    let accept = async {
        loop {
            let (stream, peer) = match listener.accept().await {
                Ok(accepted) => accepted,
                Err(e) => {
                    // Out of file descriptors, say: keep serving the clients there are.
                    shared.note("accept failed", || e.to_string());
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            };
            if active.load(Ordering::Relaxed) >= options.max_connections {
                shared.note("connection refused", || {
                    format!("{peer}: already {} clients (the limit)", options.max_connections)
                });
                continue;
            }
            let _ = stream.set_nodelay(true);
            active.fetch_add(1, Ordering::Relaxed);
            next_client += 1;
            let client = next_client;
            lock(&shared.station).connected(client);
            let (shared, active) = (shared.clone(), active.clone());
            tokio::spawn(async move {
                if let Err((kind, detail)) = serve_connection(stream, client, &shared, &options).await {
                    shared.note(kind, || format!("{peer}: {detail}"));
                }
                lock(&shared.station).disconnected(client);
                active.fetch_sub(1, Ordering::Relaxed);
            });
        }
    };
    tokio::select! {
        () = accept => {}
        () = shared.supervise(period) => {}
        () = stop => {}
    }
    Ok(lock(&shared.station).report())
}

/// Serves one TCP client until it leaves or misbehaves; `Err` says how it misbehaved.
/// Requests a client sends together (pipelined, told apart by their transaction ids) are
/// answered in order, and the answers to all that arrived together go back in one write.
async fn serve_connection<S: AsyncRead + AsyncWrite + Unpin>(
    mut stream: S,
    client: ClientId,
    shared: &Shared,
    options: &ServerOptions,
) -> Result<(), (&'static str, String)> {
    // Received bytes not yet answered: less than one frame between reads, since every
    // complete frame is answered before the next read.
    let mut rx: Vec<u8> = Vec::with_capacity(RX_CHUNK + 7 + MAX_PDU);
    let mut chunk = [0u8; RX_CHUNK];
    let mut out = Vec::with_capacity(7 + MAX_PDU);
    // When the first byte of an incomplete frame arrived.
    let mut frame_started: Option<tokio::time::Instant> = None;
    let io = |e: std::io::Error| ("connection error", e.to_string());
    loop {
        out.clear();
        let mut used = 0;
        while let Some(len) = complete_frame(&rx[used..])? {
            let frame = &rx[used..used + len];
            let at = out.len();
            out.extend_from_slice(&frame[..7]);
            shared.answer(&frame[7..], client, &mut out);
            let response_len = (out.len() - at - 6) as u16;
            out[at + 4..at + 6].copy_from_slice(&response_len.to_be_bytes());
            used += len;
        }
        rx.drain(..used);
        // What is left is the start of a frame that came with the last read, or nothing.
        if rx.is_empty() {
            frame_started = None;
        } else if used > 0 {
            frame_started = Some(tokio::time::Instant::now());
        }
        if !out.is_empty() {
            match tokio::time::timeout(FRAME_TIMEOUT, stream.write_all(&out)).await {
                Err(_) => return Err(("client not reading", "response not taken within 1 s".into())),
                Ok(result) => result.map_err(io)?,
            }
        }
        // The first byte may take the idle time; the rest of a frame must follow promptly.
        let read = stream.read(&mut chunk);
        let n = match frame_started {
            None => match tokio::time::timeout(options.idle_timeout, read).await {
                Err(_) => {
                    return Err((
                        "idle client disconnected",
                        format!("no request for {:?}", options.idle_timeout),
                    ));
                }
                Ok(n) => n,
            },
            Some(t0) => match tokio::time::timeout_at(t0 + FRAME_TIMEOUT, read).await {
                Err(_) => return Err(("incomplete frame", format!("not completed within {FRAME_TIMEOUT:?}"))),
                Ok(n) => n,
            },
        };
        match n {
            Ok(0) if rx.is_empty() => return Ok(()),
            Ok(0) => return Err(("incomplete frame", "closed mid-frame".into())),
            Ok(n) => {
                frame_started.get_or_insert_with(tokio::time::Instant::now);
                rx.extend_from_slice(&chunk[..n]);
            }
            Err(e) if e.kind() == ErrorKind::ConnectionReset => return Ok(()),
            Err(e) => return Err(io(e)),
        }
    }
}

/// Bytes read from a TCP client at a time.
const RX_CHUNK: usize = 4096;

/// The length of the Modbus TCP frame at the start of `rx` when it is all there; `None` while
/// it is incomplete. Bytes that are not Modbus TCP (a protocol identifier other than 0, an
/// impossible length) end the connection: the stream cannot be resynchronised after them.
fn complete_frame(rx: &[u8]) -> Result<Option<usize>, (&'static str, String)> {
    let Some(header) = rx.get(..7) else { return Ok(None) };
    let len = usize::from(u16::from_be_bytes([header[4], header[5]]));
    if header[2..4] != [0, 0] || !(2..=MAX_PDU + 1).contains(&len) {
        return Err(("not a Modbus TCP header", format!("{header:02x?}")));
    }
    Ok((rx.len() >= 6 + len).then_some(6 + len))
}

/// Serves `station` as Modbus RTU on a serial stream until the stream ends or `stop`
/// completes; then reports what the machine did ([`Station::report`]). Requests to any unit
/// are answered; broadcasts (unit 0) are carried out unanswered.
pub async fn serve_rtu<S: AsyncRead + AsyncWrite + Unpin>(
    serial: S,
    station: Station,
    options: ServerOptions,
    stop: impl Future<Output = ()>,
) -> std::io::Result<StationReport> {
    let (shared, period) = shared(station, &options);
    tokio::select! {
        result = rtu_loop(serial, &shared) => result?,
        () = shared.supervise(period) => {}
        () = stop => {}
    }
    Ok(lock(&shared.station).report())
}

async fn rtu_loop<S: AsyncRead + AsyncWrite + Unpin>(mut serial: S, shared: &Shared) -> std::io::Result<()> {
    // At most one frame (unit, 10 header bytes, 255 data bytes, CRC) and one read are buffered.
    let mut buf: Vec<u8> = Vec::with_capacity(1024);
    let mut chunk = [0u8; 256];
    let mut out = Vec::with_capacity(3 + MAX_PDU);
    loop {
        let n = if buf.is_empty() {
            serial.read(&mut chunk).await?
        } else {
            match tokio::time::timeout(RTU_GAP, serial.read(&mut chunk)).await {
                Ok(read) => read?,
                Err(_) => {
                    shared.note("incomplete RTU frame discarded", || {
                        format!("{:02x?}", &buf[..buf.len().min(16)])
                    });
                    buf.clear();
                    continue;
                }
            }
        };
        if n == 0 {
            return Ok(());
        }
        buf.extend_from_slice(&chunk[..n]);
        while buf.len() >= 2 {
            let len = match request_len(&buf[1..]) {
                PduLen::Known(len) => len,
                PduLen::NeedMore => break,
                PduLen::Unknown => {
                    // No length to frame it by: resynchronise on the next byte.
                    shared.note("RTU byte skipped (unknown function)", || format!("{:02x?}", &buf[..2]));
                    buf.remove(0);
                    continue;
                }
            };
            let total = 1 + len + 2;
            if buf.len() < total {
                break;
            }
            if crc16(&buf[..1 + len]).to_le_bytes() != buf[1 + len..total] {
                shared.note("RTU byte skipped (CRC error)", || {
                    format!("{:02x?}", &buf[..total.min(16)])
                });
                buf.remove(0);
                continue;
            }
            let unit = buf[0];
            out.clear();
            out.push(unit);
            shared.answer(&buf[1..1 + len], SERIAL_LINE, &mut out);
            buf.drain(..total);
            if unit != 0 {
                let crc = crc16(&out);
                out.extend(crc.to_le_bytes());
                serial.write_all(&out).await?;
                serial.flush().await?;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_digest_logs_each_kind_once_per_period() {
        let mut d = Digest::default();
        let logged = (0..2000).filter(|_| d.note("malformed request", || "x".into())).count();
        assert_eq!(logged, 1);
        assert!(d.note("connection refused", || "y".into()));
        assert_eq!(d.counts, [("malformed request", 1999), ("connection refused", 0)]);
    }
}
