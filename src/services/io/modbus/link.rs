//! The link to the station: how it is reached ([`Transport`]), and the exchange loop on its own
//! thread that connects, exchanges every period, counts failures, declares a bus fault beyond
//! the bound and reconnects with backoff.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use tokio_modbus::Slave;
use tokio_modbus::client::{Client, rtu, tcp};
use tokio_serial::SerialStream;

use super::exchange::{Connection, Exchange, Failed, Failure};
use super::mbap::Pipelined;
use super::stats::LinkStats;
use crate::image::Value;
use crate::runtime::bus::{MailboxReader, MailboxWriter};
use crate::services::io::map::Requests;
use crate::services::io::rx_counter::RxCounter;
use crate::services::io::x20bc0087::client::{Registers, RequestError, RequestFailure};
use crate::services::io::x20bc0087::{ErrorBits, compare, rebase};

/// The first pause before connecting again after a lost link.
pub const RECONNECT_FIRST: Duration = Duration::from_millis(50);
/// The longest pause between connection attempts.
pub const RECONNECT_MAX: Duration = Duration::from_secs(2);

/// How the driver reaches the station.
pub enum Transport {
    /// Modbus TCP.
    Tcp(SocketAddr),
    /// Modbus RTU on a serial device at a baud rate (unit 1).
    Serial {
        /// The device (`/dev/ttyUSB0`, a pty, ...).
        path: String,
        /// Baud rate.
        baud: u32,
    },
    /// Modbus RTU over a byte stream that is already open: one end of a socket pair whose other
    /// end an emulated serial line ([`crate::services::io::line`]) or a test's station holds. It
    /// cannot be reopened after the link is lost.
    Stream(Option<std::os::unix::net::UnixStream>),
}

impl Transport {
    /// The bus's name in logs and summaries: `tcp:ADDR`, `serial:PATH@BAUD`, `serial:stream`.
    pub(super) fn describe(&self) -> String {
        match self {
            Transport::Tcp(a) => format!("tcp:{a}"),
            Transport::Serial { path, baud } => format!("serial:{path}@{baud}"),
            Transport::Stream(_) => "serial:stream".into(),
        }
    }

    /// Connects; every byte received on the link is added to `received`. Over TCP, `requests`
    /// says whether an exchange's requests go together; a serial line carries one at a time.
    async fn connect(&mut self, received: &Arc<AtomicU64>, requests: Requests) -> std::io::Result<Connection> {
        let serial = match self {
            Transport::Tcp(a) => {
                let stream = tokio::net::TcpStream::connect(*a).await?;
                // Requests are small and the exchange waits for their answers: send at once.
                stream.set_nodelay(true)?;
                let stream = RxCounter::new(stream, Arc::clone(received));
                return Ok(match requests {
                    Requests::Pipelined => Connection::Pipelined(Pipelined::new(stream, Slave::tcp_device())),
                    Requests::Sequential => Connection::Sequential(tcp::attach(stream)),
                });
            }
            Transport::Serial { path, baud } => SerialStream::open(&tokio_serial::new(path.as_str(), *baud))?,
            Transport::Stream(s) => {
                let stream = s
                    .take()
                    .ok_or_else(|| std::io::Error::other("the line's stream was lost and cannot be reopened"))?;
                stream.set_nonblocking(true)?;
                // Registered with the reactor here, in the exchange loop's runtime.
                let stream = tokio::net::UnixStream::from_std(stream)?;
                return Ok(Connection::Sequential(rtu::attach_slave(
                    RxCounter::new(stream, Arc::clone(received)),
                    Slave(1),
                )));
            }
        };
        Ok(Connection::Sequential(rtu::attach_slave(
            RxCounter::new(serial, Arc::clone(received)),
            Slave(1),
        )))
    }
}

/// What the exchange loop and the bus on the cyclic side share.
#[derive(Debug)]
pub(super) struct Shared {
    /// The bus fault: set beyond the failure bound, cleared when exchanges succeed again.
    pub fault: AtomicBool,
    /// Asks the loop to end.
    pub stop: AtomicBool,
    /// When the newest complete input image was published, in ns since `epoch`; [`NO_IMAGE`]
    /// before the first.
    pub image_at_ns: AtomicU64,
    /// The origin of `image_at_ns`.
    pub epoch: Instant,
    /// The counters.
    pub stats: Arc<LinkStats>,
    /// Why the current (or last) fault episode began (empty before the first): its first
    /// cause, kept while the episode lasts, read by the runtime to complete the application's
    /// "bus fault" reason. A station that vanishes is named there, not what failed after it.
    pub cause: Mutex<String>,
    /// Whether the current episode's cause is written: later causes do not replace it. Cleared
    /// once the link works and the inputs are fresh again (the next fault is a new episode).
    pub latched: AtomicBool,
    /// Whether the inputs are stale now (a fault while it lasts, logged once per episode).
    pub stale: AtomicBool,
    /// The first failed exchange's cause since the last one that succeeded.
    pub first_failure: Mutex<Option<String>>,
    /// Why the station was refused at the first connection (the loop then ended without writing).
    pub refused: Mutex<Option<String>>,
    /// When the cycle last handed outputs over, in ns since `epoch`; [`NO_IMAGE`] before.
    pub outputs_at_ns: AtomicU64,
}

/// Joins an episode's first cause and the link's fault declared after it.
const THEN: &str = "; then: ";
/// Joins stale inputs and the exchanges' first failure, where they fail.
pub(super) const FAILING_SINCE: &str = ": the exchanges fail since: ";

/// `image_at_ns` before the first complete input image.
pub(super) const NO_IMAGE: u64 = u64::MAX;

impl Shared {
    pub(super) fn new() -> Shared {
        Shared {
            fault: AtomicBool::new(false),
            stop: AtomicBool::new(false),
            image_at_ns: AtomicU64::new(NO_IMAGE),
            epoch: Instant::now(),
            stats: Arc::new(LinkStats::default()),
            cause: Mutex::new(String::new()),
            latched: AtomicBool::new(false),
            stale: AtomicBool::new(false),
            first_failure: Mutex::new(None),
            refused: Mutex::new(None),
            outputs_at_ns: AtomicU64::new(NO_IMAGE),
        }
    }

    /// Declares a bus fault because of `cause` (logged as a warning with the link's `name` once
    /// per episode: when the fault was not set already). The episode's cause is the first:
    /// where the inputs went stale first before any exchange had failed, this one is added.
    pub(super) fn declare_fault(&self, name: &str, cause: String) {
        if !self.fault.swap(true, Ordering::Relaxed) {
            tracing::warn!("modbus {name}: bus fault: {cause}");
            if !self.latch(&cause) {
                // Added only where the first cause does not name the failing exchanges yet.
                let mut kept = self.cause.lock().unwrap_or_else(|p| p.into_inner());
                if !kept.contains(THEN) && !kept.contains(FAILING_SINCE) {
                    kept.push_str(THEN);
                    kept.push_str(&cause);
                }
            }
        }
    }

    /// Writes `cause` as the episode's, unless one is written already (false then).
    pub(super) fn latch(&self, cause: &str) -> bool {
        if self.latched.swap(true, Ordering::AcqRel) {
            return false;
        }
        let mut kept = self.cause.lock().unwrap_or_else(|p| p.into_inner());
        kept.clear();
        kept.push_str(cause);
        true
    }

    /// Ends the fault episode where the link works and the inputs are fresh.
    pub(super) fn episode_over(&self) {
        if !self.fault.load(Ordering::Acquire) && !self.stale.load(Ordering::Acquire) {
            self.latched.store(false, Ordering::Release);
        }
    }

    /// An exchange failed with `cause`: kept if it is the first since the last that succeeded.
    pub(super) fn exchange_failed(&self, cause: &str) {
        let mut first = self.first_failure.lock().unwrap_or_else(|p| p.into_inner());
        if first.is_none() {
            *first = Some(cause.to_string());
        }
    }

    /// An exchange succeeded: the next failure is a first again.
    pub(super) fn exchange_succeeded(&self) {
        if let Ok(mut first) = self.first_failure.try_lock() {
            *first = None;
        }
    }

    /// Nanoseconds since `epoch`.
    pub(super) fn now_ns(&self) -> u64 {
        self.epoch.elapsed().as_nanos() as u64
    }
}

/// The exchange loop, ready to start.
pub(super) struct Link {
    pub name: String,
    pub transport: Transport,
    pub exchange: Exchange,
    /// Time between exchanges.
    pub period: Duration,
    /// More consecutive failed exchanges than this is a bus fault.
    pub max_failures: u32,
    /// The median time of the last [`SLOW_WINDOW`] exchanges above this is a bus fault.
    pub max_exchange: Duration,
    /// SCHED_FIFO priority of the exchange thread (0: normal scheduling).
    pub priority: u8,
    /// Outputs the cycle handed over longer ago than this are not written: a hung cycle stops
    /// feeding the station's watchdog, which then sets the outputs safe.
    pub max_output_age: Duration,
    pub shared: Arc<Shared>,
}

/// How often an X20BC0087's error bits are read: every tenth exchange (50 ms at the 5 ms period),
/// so that a cycle's exchange stays at the four requests of the process data.
pub const STATUS_EVERY: u64 = 10;

/// How long an X20BC0087's expired watchdog stands as a bus fault before the link resets it: the
/// application answers a bus fault with ERROR (drives off) in its next main cycle, and the
/// station takes outputs again only after that, and only while the cycle runs.
pub const WATCHDOG_RESET_HOLD: Duration = Duration::from_millis(250);

/// Why an X20BC0087 could not be made ready on a connection.
enum NotReady {
    /// A request failed: counted as a failed exchange, the link reconnects.
    Failed(Failed),
    /// The station is not the I/O map's, or did not take the watchdog setting.
    Refused(String),
}

impl From<RequestError> for Failed {
    fn from(e: RequestError) -> Failed {
        let kind = match e.kind {
            RequestFailure::Timeout => Failure::Timeout,
            RequestFailure::Exception => Failure::Exception,
            RequestFailure::Corrupt => Failure::Corrupt,
            RequestFailure::Disconnected => Failure::Disconnected,
        };
        Failed {
            kind,
            cause: e.to_string(),
        }
    }
}

/// How many of the latest exchanges the slow-link supervision takes the median of: one or two
/// slow exchanges (a scheduler's stall on a busy machine) do not fault, a link that is slow on
/// every exchange faults within three of them — 100 ms when each takes 33 ms, before the
/// regulators it delays start to oscillate.
pub const SLOW_WINDOW: usize = 5;

impl Link {
    /// Starts the loop on a thread named `modbus`: complete input images go to `inputs`, the
    /// newest outputs come from `outputs`. `None` (and a bus fault) if no thread could be made.
    pub fn spawn(self, inputs: MailboxWriter, outputs: MailboxReader) -> Option<JoinHandle<()>> {
        let shared = Arc::clone(&self.shared);
        match std::thread::Builder::new()
            .name("modbus".into())
            .spawn(move || self.run(inputs, outputs))
        {
            Ok(handle) => Some(handle),
            Err(e) => {
                tracing::error!("modbus: cannot start the exchange thread: {e}");
                shared.fault.store(true, Ordering::Relaxed);
                None
            }
        }
    }

    fn run(mut self, mut inputs: MailboxWriter, mut outputs: MailboxReader) {
        // The exchange carries the cycle's outputs to the station: starved by other processes,
        // it delivers set-points late and in bursts (a stepper loses steps on such a jump).
        // Refused where the process may not (the cyclic thread's own warning says so).
        if self.priority > 0
            && let Err(e) = crate::runtime::timing::set_realtime_priority(self.priority)
        {
            tracing::debug!("modbus: the exchange thread runs at normal priority: {e}");
        }
        let runtime = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
            Ok(r) => r,
            Err(e) => {
                tracing::error!("modbus: cannot start the exchange loop: {e}");
                self.shared.fault.store(true, Ordering::Relaxed);
                return;
            }
        };
        runtime.block_on(self.exchange_loop(&mut inputs, &mut outputs));
    }

    /// Connects, makes the station ready and exchanges every period until stopped, counting
    /// failures and reconnecting with a back-off.
    ///
    /// Long, and kept whole: the connection loop and the exchange loop share the link's state
    /// across reconnections (back-off, failures, the station's fault and its watchdog, whether
    /// outputs are written, the slow-link window); split, it would pass in and out of every part.
    async fn exchange_loop(&mut self, inputs: &mut MailboxWriter, outputs: &mut MailboxReader) {
        let shared = Arc::clone(&self.shared);
        let received = Arc::new(AtomicU64::new(0));
        let mut failures = 0u32;
        // The pause before the next connection attempt: doubled after every attempt that gave no
        // successful exchange (a refused connection, or a station that accepts and closes at
        // once — which without it made 4774 attempts in 5 s), back to the first after one that
        // did.
        let mut backoff = RECONNECT_FIRST;
        let mut slowness = Slowness::default();
        let mut out_values: Vec<Value> = self.exchange.outputs.iter().map(|s| Value::zero(s.ty)).collect();
        let mut in_values: Vec<Value> = self.exchange.inputs.iter().map(|s| Value::zero(s.ty)).collect();
        // An X20BC0087's state: whether it was made ready on a connection before (a refusal
        // after that is a bus fault, not the end of the run), whether it reports a fault, and
        // since when its watchdog is expired.
        let mut ready_once = false;
        let mut station_fault = false;
        let mut expired_since: Option<Instant> = None;
        let mut exchanges = 0u64;
        // Whether the outputs are written (false while the cycle publishes none).
        let mut writing = true;
        while !shared.stop.load(Ordering::Relaxed) {
            let connected = tokio::time::timeout(
                self.exchange.timeout,
                self.transport.connect(&received, self.exchange.requests),
            )
            .await;
            let mut link = match connected {
                Ok(Ok(link)) => link,
                other => {
                    let cause = match other {
                        Ok(Err(e)) => format!("cannot connect: {e}"),
                        _ => format!("no connection within {} ms", self.exchange.timeout.as_millis()),
                    };
                    let failed = Failed {
                        kind: Failure::Disconnected,
                        cause,
                    };
                    self.after_failure(&mut failures, &mut backoff, &failed, true).await;
                    continue;
                }
            };
            match self.make_ready(link.client(), !ready_once).await {
                Ok(None) => ready_once = true,
                Ok(Some(faults)) => {
                    ready_once = true;
                    // Found on reconnecting: the station zeroed the outputs while the link was
                    // away. A bus fault, which the status reads keep and end as usual.
                    shared.declare_fault(
                        &self.name,
                        format!("the X20BC0087 reports {}", faults.names().join(", ")),
                    );
                    station_fault = true;
                    if faults.has(ErrorBits::WATCHDOG_EXPIRED) {
                        expired_since.get_or_insert_with(Instant::now);
                    }
                }
                Err(NotReady::Failed(f)) => {
                    self.after_failure(&mut failures, &mut backoff, &f, true).await;
                    continue;
                }
                Err(NotReady::Refused(why)) if !ready_once => {
                    // Said once, by the run that ends on it; nothing was written to the station.
                    shared.latch(&why);
                    *shared.refused.lock().unwrap_or_else(|p| p.into_inner()) = Some(why);
                    shared.fault.store(true, Ordering::Relaxed);
                    return;
                }
                Err(NotReady::Refused(why)) => {
                    shared.declare_fault(&self.name, why);
                    tokio::time::sleep(backoff).await;
                    backoff = (backoff * 2).min(RECONNECT_MAX);
                    continue;
                }
            }
            let mut tick = tokio::time::interval(self.period);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            while !shared.stop.load(Ordering::Relaxed) {
                tick.tick().await;
                outputs.take_latest(&mut out_values);
                writing = self.still_writing(writing);
                let started = Instant::now();
                match self
                    .exchange
                    .run(&mut link, &received, &mut in_values, writing.then_some(&out_values[..]))
                    .await
                {
                    Ok(()) => {
                        backoff = RECONNECT_FIRST;
                        inputs.publish(&in_values);
                        shared.image_at_ns.store(shared.now_ns(), Ordering::Release);
                        let took = started.elapsed().as_nanos() as u64;
                        shared.stats.succeeded(took);
                        if failures > 0 {
                            shared.exchange_succeeded();
                        }
                        failures = 0;
                        if let Some(median) = slowness.took(took, self.max_exchange) {
                            if slowness.began() {
                                shared.stats.slow.fetch_add(1, Ordering::Relaxed);
                            }
                            shared.declare_fault(
                                &self.name,
                                format!(
                                    "the link is too slow: its exchanges take {:.1} ms (the median of the last {SLOW_WINDOW}), over the {} ms the drive regulators are tuned for (--max-exchange-ms)",
                                    median as f64 / 1e6,
                                    self.max_exchange.as_millis()
                                ),
                            );
                            continue;
                        }
                        exchanges += 1;
                        if self.exchange.bus_controller.is_some() && exchanges.is_multiple_of(STATUS_EVERY) {
                            match self.station_status(link.client(), &mut expired_since, writing).await {
                                Ok(fault) => station_fault = fault,
                                Err(f) => {
                                    if self.after_failure(&mut failures, &mut backoff, &f, false).await {
                                        break;
                                    }
                                    continue;
                                }
                            }
                        }
                        if station_fault {
                            continue;
                        }
                        if shared.fault.swap(false, Ordering::Relaxed) {
                            tracing::info!(
                                "modbus {}: the link works again (the machine stays in ERROR until acknowledged)",
                                self.name
                            );
                        }
                        shared.episode_over();
                    }
                    Err(f) => {
                        if self.exchange.pipelining_refused() {
                            // Sequential from the next connection on (a timeout reconnects).
                            tracing::warn!(
                                "modbus {}: the station answered only part of the requests sent together (it keeps \
                                 one request at a time): from now on each waits for the answer before it; write \
                                 \"requests\": \"sequential\" into the I/O map to start that way",
                                self.name
                            );
                            self.exchange.requests = Requests::Sequential;
                        }
                        if self.after_failure(&mut failures, &mut backoff, &f, false).await {
                            break;
                        }
                    }
                }
            }
        }
    }

    /// Whether the outputs are written from now on: while the cycle hands them over fresh
    /// (said when that changes: without them the station's watchdog sets them safe).
    fn still_writing(&self, writing: bool) -> bool {
        let fresh = self.outputs_fresh();
        if fresh != writing {
            if fresh {
                tracing::info!(
                    "modbus {}: the cycle publishes outputs again: they are written",
                    self.name
                );
            } else {
                tracing::warn!(
                    "modbus {}: the cycle has handed over no outputs for {} ms: they are no longer written, so the \
                     station's watchdog sets them safe",
                    self.name,
                    self.max_output_age.as_millis()
                );
            }
        }
        fresh
    }

    /// Counts the failed exchange `f`; when the link is to be opened again after it (`reconnect`,
    /// or a failure that calls for it), waits the back-off and doubles it, and says so (true).
    async fn after_failure(&self, failures: &mut u32, backoff: &mut Duration, f: &Failed, reconnect: bool) -> bool {
        self.shared.stats.failed(f.kind);
        self.failed(failures, f);
        if !(reconnect || self.reconnects_after(f.kind)) {
            return false;
        }
        tokio::time::sleep(*backoff).await;
        *backoff = (*backoff * 2).min(RECONNECT_MAX);
        true
    }

    /// Whether the outputs the cycle handed over last are recent enough to be written (before the
    /// first, the zero outputs are: they are safe, and they keep the station's watchdog fed
    /// while the run waits for its first cycle).
    fn outputs_fresh(&self) -> bool {
        let at = self.shared.outputs_at_ns.load(Ordering::Acquire);
        at == NO_IMAGE || Duration::from_nanos(self.shared.now_ns().saturating_sub(at)) <= self.max_output_age
    }

    /// On an X20BC0087, on every connection: checks the module table against the I/O map,
    /// takes the station's own data indexes, and sets the watchdog (never trusting a stored
    /// setting). Nothing else has been sent on the connection yet. `first`: the run's first
    /// connection (notes about IDs the map does not pin are logged then). On the first
    /// connection the watchdog is reset (an expiry then is a former controller's, and this run's
    /// outputs start safe); on a later one, a station that reports faults — its watchdog expired
    /// while the link was away — keeps them, returned (`Some`) for the link to raise.
    async fn make_ready(&mut self, ctx: &mut dyn Client, first: bool) -> Result<Option<ErrorBits>, NotReady> {
        let Some(bc) = &self.exchange.bus_controller else {
            return Ok(None);
        };
        let mut registers = Registers::new(ctx, self.exchange.timeout);
        let table = registers.module_table().await.map_err(|e| NotReady::Failed(e.into()))?;
        let notes = compare(&bc.expected, &table).map_err(|m| {
            NotReady::Refused(format!(
                "the X20BC0087 at {} holds other modules than the I/O map says, so nothing is written to it: {m}",
                self.name
            ))
        })?;
        if first {
            for note in notes {
                tracing::warn!("modbus {}: {note}", self.name);
            }
        }
        // Every refusal comes before the first write (the watchdog's setting and reset are
        // writes): a refused station has had nothing written to it, as its message says.
        let rebased = rebase(&bc.registers, &table).map_err(|m| {
            NotReady::Refused(format!(
                "the X20BC0087 at {} assigns data the soft-PLC cannot address, so nothing is written to it: {m}",
                self.name
            ))
        })?;
        if let Err(why) = registers
            .configure_watchdog(bc.watchdog_ms)
            .await
            .map_err(|e| NotReady::Failed(e.into()))?
        {
            return Err(NotReady::Refused(format!("the X20BC0087 at {}: {why}", self.name)));
        }
        let (_, bits) = registers.errors().await.map_err(|e| NotReady::Failed(e.into()))?;
        let faults = ErrorBits(bits.0 & ErrorBits::FAULTS);
        let kept = (!first && faults.0 != 0).then_some(faults);
        if kept.is_none() {
            registers
                .reset_watchdog()
                .await
                .map_err(|e| NotReady::Failed(e.into()))?;
        }
        let watchdog_ms = bc.watchdog_ms;
        self.exchange.rebase(&rebased);
        if first {
            tracing::info!(
                "modbus {}: X20BC0087 with the I/O map's {} modules; its watchdog set to {watchdog_ms} ms, reset by \
                 writes only",
                self.name,
                table.len(),
            );
        }
        Ok(kept)
    }

    /// Reads an X20BC0087's error bits: "module mismatch", "module runtime error" and "watchdog
    /// expired" are a bus fault while they last (`Ok(true)`). An expired watchdog is reset
    /// once it has stood [`WATCHDOG_RESET_HOLD`] and only while the cycle's outputs are
    /// written (`writing`).
    async fn station_status(
        &self,
        ctx: &mut dyn Client,
        expired_since: &mut Option<Instant>,
        writing: bool,
    ) -> Result<bool, Failed> {
        let mut registers = Registers::new(ctx, self.exchange.timeout);
        let (_, bits) = registers.errors().await?;
        let faults = ErrorBits(bits.0 & ErrorBits::FAULTS);
        if faults.0 == 0 {
            *expired_since = None;
            return Ok(false);
        }
        self.shared.declare_fault(
            &self.name,
            format!("the X20BC0087 reports {}", faults.names().join(", ")),
        );
        if faults.has(ErrorBits::WATCHDOG_EXPIRED) {
            let since = *expired_since.get_or_insert_with(Instant::now);
            if writing && since.elapsed() >= WATCHDOG_RESET_HOLD {
                registers.reset_watchdog().await?;
                *expired_since = None;
                tracing::info!(
                    "modbus {}: the X20BC0087's watchdog reset: the station takes the outputs again (the machine stays \
                     in ERROR until acknowledged)",
                    self.name
                );
            }
        }
        Ok(true)
    }

    /// Whether the link is opened again after failure `f`. A lost link is. Over TCP a timeout or
    /// a damaged response leaves the stream out of step, so it is too; an RTU decoder finds the
    /// next frame by itself, and a serial port handed over open could not be reopened.
    fn reconnects_after(&self, f: Failure) -> bool {
        match f {
            Failure::Disconnected => true,
            Failure::Timeout | Failure::Corrupt => matches!(self.transport, Transport::Tcp(_)),
            Failure::Exception => false,
        }
    }

    fn failed(&self, failures: &mut u32, last: &Failed) {
        *failures += 1;
        self.shared.exchange_failed(&last.cause);
        if *failures > self.max_failures && !self.shared.fault.load(Ordering::Relaxed) {
            // The first failure names what happened (a station that vanished); the last, what
            // the link meets now.
            let first = self
                .shared
                .first_failure
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .clone();
            let cause = match first {
                Some(first) if first != last.cause => {
                    format!(
                        "{failures} failed exchanges in a row, the first: {first}, the last: {}",
                        last.cause
                    )
                }
                _ => format!("{failures} failed exchanges in a row, the last: {}", last.cause),
            };
            self.shared.declare_fault(&self.name, cause);
        }
    }
}

/// The latest exchanges' durations, for the slow-link supervision: the link is too slow while
/// the median of the last [`SLOW_WINDOW`] is over the bound.
#[derive(Default)]
struct Slowness {
    recent: [u64; SLOW_WINDOW],
    taken: usize,
    /// Too slow at the last exchange.
    slow: bool,
    /// Too slow now, and not at the one before.
    began: bool,
}

impl Slowness {
    /// Takes an exchange of `took_ns`; the median (ns) when the link is too slow for `bound`.
    fn took(&mut self, took_ns: u64, bound: Duration) -> Option<u64> {
        self.recent[self.taken % SLOW_WINDOW] = took_ns;
        self.taken += 1;
        let mut sorted = self.recent;
        sorted.sort_unstable();
        let median = sorted[SLOW_WINDOW / 2];
        let slow = self.taken >= SLOW_WINDOW && Duration::from_nanos(median) > bound;
        self.began = slow && !self.slow;
        self.slow = slow;
        slow.then_some(median)
    }

    /// Whether the last exchange made the link too slow after it was not.
    fn began(&self) -> bool {
        self.began
    }
}
