//! The link to the station: how it is reached ([`Transport`]), and the exchange loop on its own
//! thread that connects, exchanges every period, counts failures, declares a bus fault beyond
//! the bound and reconnects with backoff.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use tokio_modbus::Slave;
use tokio_modbus::client::{self, rtu, tcp};
use tokio_serial::SerialStream;

use super::exchange::{Exchange, Failure};
use super::stats::LinkStats;
use crate::bus::{MailboxReader, MailboxWriter};
use crate::image::Value;
use crate::io::rx_counter::RxCounter;

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
    /// Modbus RTU on a serial port that is already open (one end of a pty pair, say); it cannot
    /// be reopened after the link is lost.
    Port(Option<serialport::TTYPort>),
}

impl Transport {
    /// The bus's name in logs and summaries: `tcp:ADDR`, `serial:PATH@BAUD`, `serial:port`.
    pub(super) fn describe(&self) -> String {
        match self {
            Transport::Tcp(a) => format!("tcp:{a}"),
            Transport::Serial { path, baud } => format!("serial:{path}@{baud}"),
            Transport::Port(_) => "serial:port".into(),
        }
    }

    /// Connects; every byte received on the link is added to `received`.
    async fn connect(&mut self, received: &Arc<AtomicU64>) -> std::io::Result<client::Context> {
        let serial = match self {
            Transport::Tcp(a) => {
                let stream = tokio::net::TcpStream::connect(*a).await?;
                // Requests are small and each waits for its response: send at once.
                stream.set_nodelay(true)?;
                return Ok(tcp::attach(RxCounter::new(stream, Arc::clone(received))));
            }
            Transport::Serial { path, baud } => SerialStream::open(&tokio_serial::new(path.as_str(), *baud))?,
            Transport::Port(p) => {
                let port = p
                    .take()
                    .ok_or_else(|| std::io::Error::other("the serial port was lost and cannot be reopened"))?;
                // Registered with the reactor here, in the exchange loop's runtime.
                SerialStream::try_from(port).map_err(std::io::Error::other)?
            }
        };
        Ok(rtu::attach_slave(
            RxCounter::new(serial, Arc::clone(received)),
            Slave(1),
        ))
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
}

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
    pub shared: Arc<Shared>,
}

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

    async fn exchange_loop(&mut self, inputs: &mut MailboxWriter, outputs: &mut MailboxReader) {
        let shared = Arc::clone(&self.shared);
        let received = Arc::new(AtomicU64::new(0));
        let mut failures = 0u32;
        let mut backoff = Duration::from_millis(50);
        let mut out_values: Vec<Value> = self.exchange.outputs.iter().map(|s| Value::zero(s.ty)).collect();
        let mut in_values: Vec<Value> = self.exchange.inputs.iter().map(|s| Value::zero(s.ty)).collect();
        while !shared.stop.load(Ordering::Relaxed) {
            let connected = tokio::time::timeout(self.exchange.timeout, self.transport.connect(&received)).await;
            let mut ctx = match connected {
                Ok(Ok(ctx)) => {
                    backoff = Duration::from_millis(50);
                    ctx
                }
                _ => {
                    shared.stats.failed(Failure::Disconnected);
                    self.failed(&mut failures);
                    tokio::time::sleep(backoff).await;
                    backoff = (backoff * 2).min(Duration::from_secs(2));
                    continue;
                }
            };
            let mut tick = tokio::time::interval(self.period);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            while !shared.stop.load(Ordering::Relaxed) {
                tick.tick().await;
                outputs.take_latest(&mut out_values);
                let started = Instant::now();
                match self
                    .exchange
                    .run(&mut ctx, &received, &mut in_values, &out_values)
                    .await
                {
                    Ok(()) => {
                        inputs.publish(&in_values);
                        shared.image_at_ns.store(shared.now_ns(), Ordering::Release);
                        shared.stats.succeeded(started.elapsed().as_nanos() as u64);
                        failures = 0;
                        if shared.fault.swap(false, Ordering::Relaxed) {
                            tracing::info!(
                                "modbus {}: the link works again (the machine stays in ERROR until acknowledged)",
                                self.name
                            );
                        }
                    }
                    Err(f) => {
                        shared.stats.failed(f);
                        self.failed(&mut failures);
                        if self.reconnects_after(f) {
                            break;
                        }
                    }
                }
            }
        }
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

    fn failed(&self, failures: &mut u32) {
        *failures += 1;
        if *failures > self.max_failures && !self.shared.fault.swap(true, Ordering::Relaxed) {
            tracing::warn!("modbus {}: bus fault after {failures} failed exchanges", self.name);
        }
    }
}
