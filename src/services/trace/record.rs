//! Recording: the cyclic thread copies each class cycle's changed values into a pooled buffer
//! and hands it to a writer thread through a preallocated bounded channel; the writer formats
//! JSON Lines into a buffered file. Nothing is ever dropped: should the writer fall behind so far
//! that the channel is full, the cycle waits for it (counted and reported as stalls).
//!
//! The writer flushes the file at least every [`FLUSH_EVERY`] (gzip: a sync flush, after which
//! the compressed stream decodes up to there), so a crash, a power cut or SIGKILL loses at most
//! about that much of the trace: the reader takes every complete record and says where it ends.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError, sync_channel};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::{ClassHeader, FORMAT, Header, TraceProgram, VERSION, same, value_to_json};
use crate::image::{Value, VarIndex};
use crate::runtime::plc::{CycleRecord, CycleSink, Plc, SinkError};

/// Records in flight between the cyclic thread and the writer.
const CHANNEL: usize = 16_384;
/// Buffers made up front.
const POOL: usize = 1024;
/// The longest the writer keeps formatted records in memory before it writes them to the file.
pub const FLUSH_EVERY: Duration = Duration::from_millis(500);

enum Msg {
    /// A state or reason name, interned under this number.
    Name(u16, String),
    /// One class cycle: `changes[..inputs]` are inputs, the rest outputs.
    Cycle {
        class: u16,
        t_ns: u64,
        cycle: u64,
        changes: Vec<(VarIndex, Value)>,
        inputs: usize,
        state: Option<u16>,
        reason: Option<u16>,
        violation: bool,
    },
}

/// The trace file: plain, or gzip-compressed when its name ends in `.gz`.
enum Output {
    Plain(BufWriter<File>),
    /// Boxed: zlib-rs's encoder state is large, and there is one per recording.
    Gzip(Box<flate2::write::GzEncoder<BufWriter<File>>>),
}

impl Output {
    fn create(path: &Path) -> io::Result<Output> {
        let file = BufWriter::with_capacity(1 << 20, File::create(path)?);
        Ok(if path.extension().is_some_and(|e| e == "gz") {
            Output::Gzip(Box::new(flate2::write::GzEncoder::new(
                file,
                flate2::Compression::default(),
            )))
        } else {
            Output::Plain(file)
        })
    }

    fn write_line(&mut self, line: &[u8]) -> io::Result<()> {
        let out: &mut dyn Write = match self {
            Output::Plain(w) => w,
            Output::Gzip(w) => w,
        };
        out.write_all(line)?;
        out.write_all(b"\n")
    }

    /// Writes out what is buffered (gzip: a sync flush, so the stream decodes up to here).
    fn flush(&mut self) -> io::Result<()> {
        match self {
            Output::Plain(w) => w.flush(),
            Output::Gzip(w) => w.flush(),
        }
    }

    fn finish(self) -> io::Result<()> {
        match self {
            Output::Plain(mut w) => w.flush(),
            Output::Gzip(w) => w.finish()?.flush(),
        }
    }
}

/// What the writer reports when it is done.
#[derive(Debug)]
struct Written {
    records: u64,
    bytes: u64,
    error: Option<io::Error>,
}

impl Written {
    /// Takes the outcome of writing the buffer out to the file (what it holds after an error is
    /// read back at the end: [`on_disk`]).
    fn settle(&mut self, result: io::Result<()>) {
        if let Err(e) = result {
            self.fail(e);
        }
    }

    /// Stops the recording at a write error (said at once; the run goes on).
    fn fail(&mut self, e: io::Error) {
        tracing::error!("trace: writing failed: {e}; recording stops here, the run goes on");
        self.error = Some(e);
    }
}

/// Records a run's class cycles to a trace file.
pub struct Recorder {
    path: String,
    tx: Option<SyncSender<Msg>>,
    pool: Receiver<Vec<(VarIndex, Value)>>,
    writer: Option<JoinHandle<Written>>,
    last: Vec<Vec<Value>>,
    started: Vec<bool>,
    names: Vec<String>,
    capacity: usize,
    stalls: u64,
    allocations: u64,
}

impl Recorder {
    /// Creates the trace file, writes its header and starts the writer thread.
    pub fn create(path: &Path, plc: &Plc, config_digest: &str) -> io::Result<Recorder> {
        Recorder::create_with(path, plc, config_digest, None, None)
    }

    /// [`Recorder::create`] for a run with NC programs: the header carries them, and the tool
    /// table they were read with.
    pub fn create_with(
        path: &Path,
        plc: &Plc,
        config_digest: &str,
        library: Option<&pkm_api::library::NcLibrary>,
        tool_table: Option<TraceProgram>,
    ) -> io::Result<Recorder> {
        Recorder::create_for(path, plc, config_digest, library, tool_table, None)
    }

    /// [`Recorder::create_with`] for programs planned with `offsets` (a parameter file's), not
    /// the configuration's.
    pub fn create_for(
        path: &Path,
        plc: &Plc,
        config_digest: &str,
        library: Option<&pkm_api::library::NcLibrary>,
        tool_table: Option<TraceProgram>,
        offsets: Option<super::TraceOffsets>,
    ) -> io::Result<Recorder> {
        let nc = library;
        let (program, library) = Header::programs(library);
        let file = Output::create(path)?;
        let vars = plc.vars().vars();
        let name = |i: &VarIndex| vars[usize::from(*i)].name.clone();
        let header = Header {
            format: FORMAT.into(),
            version: VERSION,
            config_digest: config_digest.into(),
            machine: plc.machine().map(str::to_string),
            bus: plc.bus_name().into(),
            task_classes: plc
                .classes()
                .map(|c| ClassHeader {
                    name: c.name.into(),
                    cycle_us: c.period_ns / 1000,
                    inputs: c.inputs.iter().map(name).collect(),
                    outputs: c.outputs.iter().map(name).collect(),
                })
                .collect(),
            variables: vars.iter().map(|v| (v.name.clone(), v.ty)).collect(),
            program,
            library,
            tool_table,
            offsets,
        };
        let var_names: Vec<String> = vars.iter().map(|v| v.name.clone()).collect();
        // The screen's jobs go into the trace where the screen loads them.
        let jobs = nc
            .zip(plc.vars().index_of(pkm_api::hmi::HMI_NC_PROGRAM.name()))
            .map(|(l, var)| JobWatch {
                library: l.clone(),
                var,
                written: vec![false; pkm_api::screen_jobs::MAX_SCREEN_JOBS],
            });
        let class_names: Vec<String> = plc.classes().map(|c| c.name.to_string()).collect();
        let (tx, rx) = sync_channel::<Msg>(CHANNEL);
        let (pool_tx, pool) = sync_channel::<Vec<(VarIndex, Value)>>(POOL * 2);
        let capacity = vars.len();
        for _ in 0..POOL {
            // Filling an empty channel of twice the size cannot fail.
            let _ = pool_tx.try_send(Vec::with_capacity(capacity));
        }
        let writer = std::thread::Builder::new()
            .name("trace-writer".into())
            .spawn(move || write_all(file, &header, &var_names, &class_names, rx, pool_tx, jobs))?;
        let n = plc.classes().count();
        Ok(Recorder {
            path: path.display().to_string(),
            tx: Some(tx),
            pool,
            writer: Some(writer),
            last: vec![plc.global_image().to_vec(); n],
            started: vec![false; n],
            names: Vec::new(),
            capacity,
            stalls: 0,
            allocations: 0,
        })
    }

    fn intern(&mut self, name: &str) -> u16 {
        if let Some(i) = self.names.iter().position(|n| n == name) {
            return i as u16;
        }
        // New names are rare (a state or reason seen for the first time): the only allocation.
        let i = self.names.len() as u16;
        self.names.push(name.to_string());
        self.send(Msg::Name(i, name.to_string()));
        i
    }

    fn send(&mut self, msg: Msg) {
        let Some(tx) = &self.tx else { return };
        match tx.try_send(msg) {
            Ok(()) => {}
            Err(TrySendError::Full(msg)) => {
                self.stalls += 1;
                // Never lose a record: wait for the writer.
                if tx.send(msg).is_err() {
                    self.tx = None;
                }
            }
            // The writer ended (a write error): it reports that when the recorder finishes.
            Err(TrySendError::Disconnected(_)) => self.tx = None,
        }
    }
}

impl CycleSink for Recorder {
    fn record(&mut self, r: &CycleRecord<'_>) {
        let mut changes = self.pool.try_recv().unwrap_or_else(|_| {
            self.allocations += 1;
            Vec::with_capacity(self.capacity)
        });
        changes.clear();
        let first = !self.started[r.class];
        self.started[r.class] = true;
        let last = &mut self.last[r.class];
        let mut inputs = 0;
        for (k, list) in [r.inputs, r.outputs].into_iter().enumerate() {
            for &i in list {
                let v = r.image[usize::from(i)];
                if first || !same(v, last[usize::from(i)]) {
                    changes.push((i, v));
                    last[usize::from(i)] = v;
                }
            }
            if k == 0 {
                inputs = changes.len();
            }
        }
        let state = r.status.map(|s| s.state);
        let reason = r.status.and_then(|s| s.reason);
        let state = state.map(|s| self.intern(s));
        let reason = reason.map(|s| self.intern(s));
        let msg = Msg::Cycle {
            class: r.class as u16,
            t_ns: r.t_ns,
            cycle: r.cycle,
            changes,
            inputs,
            state,
            reason,
            violation: r.violation,
        };
        self.send(msg);
    }

    fn finish(mut self: Box<Self>) -> Result<String, SinkError> {
        self.tx = None;
        let written = match self.writer.take().map(JoinHandle::join) {
            Some(Ok(w)) => w,
            _ => {
                return Err(SinkError::WriterPanicked {
                    file: self.path.clone(),
                });
            }
        };
        match written.error {
            Some(source) => Err(SinkError::Write {
                file: self.path.clone(),
                source,
                held: on_disk(Path::new(&self.path)),
            }),
            None => Ok(format!(
                "trace {}: {} records, {:.1} MB of JSON; {} stalls, {} extra buffers",
                self.path,
                written.records,
                written.bytes as f64 / 1e6,
                self.stalls,
                self.allocations
            )),
        }
    }
}

/// What a trace whose writing failed holds: its complete records, counted by reading it back as
/// `replay` would (a buffer written out in part before the error may hold more of them than the
/// last flush), and the time of the last; the records after them are lost.
fn on_disk(path: &Path) -> String {
    let Ok(mut reader) = super::read::TraceReader::open(path) else {
        return "the file holds no complete record".to_string();
    };
    let (mut records, mut last_t_us) = (0u64, None);
    while let Ok(Some(record)) = reader.next_record() {
        records += 1;
        last_t_us = Some(record.t_us);
    }
    match last_t_us {
        Some(t) => format!(
            "the file holds the first {records} records (up to t = {:.3} s), as replay reads them",
            t as f64 * 1e-6
        ),
        None => "the file holds no complete record".to_string(),
    }
}

/// What the writer needs to put the screen's jobs into the trace.
struct JobWatch {
    library: pkm_api::library::NcLibrary,
    /// `HMI_NC_PROGRAM`.
    var: VarIndex,
    /// Per slot: its job is in the trace.
    written: Vec<bool>,
}

impl JobWatch {
    /// The job a record with these input changes loads for the first time, if any.
    fn loaded(&mut self, inputs: &[(VarIndex, Value)]) -> Option<super::TraceJob> {
        let number = inputs.iter().find_map(|(i, v)| match v {
            Value::Int(k) if *i == self.var => Some(*k),
            _ => None,
        })?;
        let slot = self.library.screen_slot(number)?;
        let spec = self.library.screen.spec(slot)?;
        let written = self.written.get_mut(slot)?;
        if std::mem::replace(written, true) {
            return None;
        }
        Some(super::TraceJob::of(number, spec))
    }
}

/// The writer thread: formats every message as one JSON line.
fn write_all(
    mut out: Output,
    header: &Header,
    vars: &[String],
    classes: &[String],
    rx: Receiver<Msg>,
    pool: SyncSender<Vec<(VarIndex, Value)>>,
    mut jobs: Option<JobWatch>,
) -> Written {
    let mut w = Written {
        records: 0,
        bytes: 0,
        error: None,
    };
    let mut names: Vec<String> = Vec::new();
    let emit = |line: String, w: &mut Written, out: &mut Output| {
        if w.error.is_none() {
            match out.write_line(line.as_bytes()) {
                Ok(()) => w.bytes += line.len() as u64 + 1,
                // Said at once; the run goes on, and ends with this error (exit code 1).
                Err(e) => w.fail(e),
            }
        }
    };
    match serde_json::to_string(header) {
        Ok(line) => emit(line, &mut w, &mut out),
        Err(e) => w.error = Some(io::Error::other(e)),
    }
    let mut flushed_at = Instant::now();
    loop {
        let msg = match rx.recv_timeout(FLUSH_EVERY.saturating_sub(flushed_at.elapsed())) {
            Ok(msg) => Some(msg),
            Err(RecvTimeoutError::Timeout) => None,
            Err(RecvTimeoutError::Disconnected) => break,
        };
        if flushed_at.elapsed() >= FLUSH_EVERY {
            flushed_at = Instant::now();
            if w.error.is_none() {
                w.settle(out.flush());
            }
        }
        let Some(msg) = msg else { continue };
        match msg {
            Msg::Name(i, name) => {
                let i = usize::from(i);
                if names.len() <= i {
                    names.resize(i + 1, String::new());
                }
                names[i] = name;
            }
            Msg::Cycle {
                class,
                t_ns,
                cycle,
                changes,
                inputs,
                state,
                reason,
                violation,
            } => {
                let map = |part: &[(VarIndex, Value)]| {
                    part.iter()
                        .map(|(i, v)| (vars[usize::from(*i)].clone(), value_to_json(*v)))
                        .collect::<serde_json::Map<_, _>>()
                };
                let mut line = serde_json::Map::new();
                line.insert("t_us".into(), (t_ns / 1000).into());
                line.insert("task".into(), classes[usize::from(class)].clone().into());
                line.insert("cycle".into(), cycle.into());
                line.insert("in".into(), map(&changes[..inputs]).into());
                line.insert("out".into(), map(&changes[inputs..]).into());
                if let Some(s) = state {
                    line.insert("state".into(), names[usize::from(s)].clone().into());
                }
                if let Some(r) = reason {
                    line.insert("reason".into(), names[usize::from(r)].clone().into());
                }
                if violation {
                    line.insert("violation".into(), true.into());
                }
                if let Some(job) = jobs.as_mut().and_then(|j| j.loaded(&changes[..inputs]))
                    && let Ok(json) = serde_json::to_value(job)
                {
                    line.insert("job".into(), json);
                }
                emit(serde_json::Value::Object(line).to_string(), &mut w, &mut out);
                if w.error.is_none() {
                    w.records += 1;
                }
                // Back to the pool; if it is full, this buffer is simply freed.
                let _ = pool.try_send(changes);
            }
        }
    }
    if w.error.is_none() {
        w.settle(out.finish());
    }
    w
}
