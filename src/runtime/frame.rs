//! What the cycle publishes for the screen and the OPC UA server: the status (state, reason,
//! note, values, per class figures) and the whole published process image, handed over through a
//! triple buffer — the cyclic thread never waits on the network and allocates nothing once the
//! buffers have grown to the longest texts. Off the cyclic thread, [`FrameFeed`] hands each new
//! frame on to any number of servers.

use std::sync::Arc;
use std::time::Duration;

use crate::image::Value;
use crate::runtime::plc::Plc;
use crate::runtime::snapshot::Snapshot;

/// One published frame.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Counts the frames published (the first is 1; 0: nothing published yet).
    pub seq: u64,
    /// The status, as the status line has it.
    pub status: Snapshot,
    /// The published process image, in the variable table's order.
    pub image: Vec<Value>,
    /// The bus reports a fault.
    pub bus_fault: bool,
    /// While it does: the bus's name and why (`tcp:10.0.0.5:502: 4 failed exchanges in a row, …`),
    /// as an error reason for it names them; empty otherwise.
    pub bus_cause: String,
    /// When it was published, wall clock (µs since the Unix epoch): a browser on the same
    /// computer measures the update's latency against it.
    pub published_unix_us: u64,
}

/// The cyclic thread's end.
pub struct FramePublisher {
    input: triple_buffer::Input<Frame>,
    seq: u64,
    /// Publishes after the passes at multiples of this (ns): the main class's cycle.
    every_ns: u64,
}

/// The server's end.
pub struct FrameReader {
    output: triple_buffer::Output<Frame>,
    /// How often a frame is published (the main cycle's period).
    every: Duration,
}

/// A publisher and a reader for frames of `plc` (allocates; call once, before the run).
pub fn frames(plc: &Plc) -> (FramePublisher, FrameReader) {
    let frame = Frame {
        seq: 0,
        status: Snapshot::for_plc(plc),
        image: plc.global_image().to_vec(),
        bus_fault: false,
        // Room for a cause, so that publishing one does not allocate on the cyclic thread.
        bus_cause: String::with_capacity(512),
        published_unix_us: 0,
    };
    let (input, output) = triple_buffer::triple_buffer(&frame);
    let every_ns = plc.app_period_ns().unwrap_or(50_000_000).max(1);
    (
        FramePublisher {
            input,
            seq: 0,
            every_ns,
        },
        FrameReader {
            output,
            every: Duration::from_nanos(every_ns),
        },
    )
}

impl FramePublisher {
    /// After the pass at schedule time `t_ns`: publishes `plc`'s state if the main class ran
    /// in it.
    pub fn after_pass(&mut self, plc: &Plc, t_ns: u64) {
        if t_ns.is_multiple_of(self.every_ns) {
            self.publish(plc, t_ns);
        }
    }

    /// Publishes `plc`'s state at schedule time `t_ns`.
    pub fn publish(&mut self, plc: &Plc, t_ns: u64) {
        self.seq += 1;
        let frame = self.input.input_buffer_mut();
        frame.seq = self.seq;
        frame.status.update(plc, t_ns);
        frame.image.clear();
        frame.image.extend_from_slice(plc.global_image());
        frame.bus_fault = plc.bus().fault();
        frame.bus_cause.clear();
        if frame.bus_fault {
            plc.write_bus_fault(&mut frame.bus_cause);
        }
        // The runtime's own clock read (a vDSO call), not a program's: the cycle is done.
        frame.published_unix_us = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_micros() as u64);
        self.input.publish();
    }
}

impl FrameReader {
    /// The newest frame, if one was published since the last call.
    pub fn newer(&mut self) -> Option<&Frame> {
        if self.output.update() {
            Some(self.output.output_buffer())
        } else {
            None
        }
    }
}

/// How often the feed looks for a newly published frame while one is due: a small fraction of
/// the main cycle, so a frame reaches the servers within 2 ms of its publication.
pub const FRAME_POLL: Duration = Duration::from_millis(2);

/// How long before the next frame is due the feed starts looking for it: frames come once per
/// main cycle, so between them it sleeps. Looking every [`FRAME_POLL`] all the time woke the
/// process 500 times a second, a standing machine's largest cost with the screen and OPC UA on.
const FRAME_LEAD: Duration = Duration::from_millis(4);

/// The newest frame, for any number of servers on the tokio runtime (the screen, OPC UA): one
/// task takes frames from the [`FrameReader`] and shares each new one, so the cyclic thread
/// publishes once whoever listens.
#[derive(Clone)]
pub struct FrameFeed(tokio::sync::watch::Receiver<Arc<Frame>>);

impl FrameFeed {
    /// Starts the task that feeds frames from `reader` (call inside the tokio runtime). It ends
    /// when every feed has been dropped.
    pub fn spawn(mut reader: FrameReader) -> FrameFeed {
        let first = Arc::new(reader.output.output_buffer().clone());
        let (tx, rx) = tokio::sync::watch::channel(first);
        tokio::spawn(async move {
            // The next frame is due one period after the last came; it is looked for from a
            // little before (the feed may have seen the last one up to FRAME_POLL late).
            let mut due: Option<tokio::time::Instant> = None;
            loop {
                let now = tokio::time::Instant::now();
                match due {
                    Some(at) if at > now + FRAME_POLL => tokio::time::sleep_until(at).await,
                    _ => tokio::time::sleep(FRAME_POLL).await,
                }
                if tx.is_closed() {
                    break;
                }
                if let Some(frame) = reader.newer() {
                    tx.send_replace(Arc::new(frame.clone()));
                    due = reader
                        .every
                        .checked_sub(FRAME_LEAD)
                        .map(|ahead| tokio::time::Instant::now() + ahead);
                }
            }
        });
        FrameFeed(rx)
    }

    /// The newest frame, if one came since the last call on this feed.
    pub fn newer(&mut self) -> Option<Arc<Frame>> {
        match self.0.has_changed() {
            Ok(true) => Some(Arc::clone(&self.0.borrow_and_update())),
            _ => None,
        }
    }

    /// The newest frame (the first, not yet published one before the run's first main cycle).
    pub fn latest(&self) -> Arc<Frame> {
        Arc::clone(&self.0.borrow())
    }

    /// Waits for a frame newer than the last seen on this feed; `None` once the feed's task has
    /// ended.
    pub async fn next(&mut self) -> Option<Arc<Frame>> {
        self.0.changed().await.ok()?;
        Some(Arc::clone(&self.0.borrow_and_update()))
    }
}
