//! Replay: the recorded inputs of every class cycle are fed to the programs in virtual time and
//! every output and the main state are compared with the record.

use std::collections::HashMap;
use std::path::Path;
use std::time::{Duration, Instant};

use crate::compose::setup::Setup;
use crate::image::{Value, VarIndex, VarType};
use crate::runtime::config::ConfigError;
use crate::runtime::plc::Plc;
use crate::runtime::run::VirtualClock;
use crate::services::trace::read::{Cut, ReadAhead, TraceError, TraceReader};
use crate::services::trace::same;
use crate::services::trace::{Header, TraceJob};
use pkm_api::library::NcLibrary;

/// The first difference between a trace and its replay.
#[derive(Debug, Clone, PartialEq)]
pub struct Difference {
    /// The record's line.
    pub line: usize,
    /// Its task class.
    pub task: String,
    /// Its cycle.
    pub cycle: u64,
    /// Its time (µs).
    pub t_us: u64,
    /// The variable, or `state` / `reason`.
    pub what: String,
    /// As recorded.
    pub recorded: String,
    /// As replayed.
    pub replayed: String,
}

/// Why a replay did not confirm the trace.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// The configuration is invalid.
    #[error("{0}")]
    Config(#[from] ConfigError),
    /// The trace is malformed.
    #[error("{0}")]
    Trace(#[from] TraceError),
    /// The trace does not fit this configuration.
    #[error("{0}")]
    Refused(String),
    /// The replay differs from the record.
    #[error(
        "replay differs at line {} (task {}, cycle {}, t = {:.3} s): {} recorded {}, replayed {}",
        .0.line, .0.task, .0.cycle, .0.t_us as f64 * 1e-6, .0.what, .0.recorded, .0.replayed
    )]
    Differs(Difference),
}

/// What an identical replay covered.
#[derive(Debug, Clone)]
pub struct ReplayReport {
    /// Records replayed.
    pub records: u64,
    /// Recorded time covered (s).
    pub recorded_s: f64,
    /// Wall-clock time of the replay.
    pub wall: Duration,
    /// Where the trace was cut short (a crash during the recording): the replay compared every
    /// record up to there.
    pub cut: Option<Cut>,
}

/// A task class of the trace as the replay runs it.
struct ReplayedClass<'h> {
    /// Its index in this configuration.
    ci: usize,
    /// Its outputs in the header's order (the first that differs is reported): each one's
    /// position among the header's variables and its index here.
    outputs: Vec<(usize, VarIndex)>,
    /// Their names, for a difference.
    names: Vec<&'h str>,
    /// The same outputs grouped by type, with their recorded values in the same order, as they
    /// are compared after every cycle: one loop per type, each a plain comparison of the next
    /// recorded value with the replayed one (compared in the header's order, values of mixed
    /// types took the programs' thread a fifth of its instructions).
    check: Vec<Recorded>,
    /// By the header's position of a variable: where its recorded value is kept, if it is one
    /// of the class's outputs (`check`'s group and place in it).
    output_at: Vec<Option<(usize, usize)>>,
    /// By the header's position of a variable: its index here if the class latches it.
    input_at: Vec<Option<VarIndex>>,
}

/// A class's outputs of one type and their recorded values.
struct Recorded {
    /// The type.
    ty: VarType,
    /// The outputs.
    at: Vec<VarIndex>,
    /// Their values as recorded so far, in the same order.
    values: Vec<Value>,
}

impl Recorded {
    /// Whether the replayed image `got` holds the recorded values (a value of another type
    /// counts as different; REALs as [`same`] has them).
    fn all_same(&self, got: &[Value]) -> bool {
        macro_rules! each {
            ($variant:ident, $eq:expr) => {
                self.at
                    .iter()
                    .zip(&self.values)
                    .all(|(&i, &want)| match (want, got[usize::from(i)]) {
                        (Value::$variant(x), Value::$variant(y)) => $eq(x, y),
                        _ => false,
                    })
            };
        }
        match self.ty {
            VarType::Real => each!(Real, |x: f64, y: f64| x.to_bits() == y.to_bits()
                || (x.is_nan() && y.is_nan())),
            VarType::Bool => each!(Bool, |x, y| x == y),
            VarType::Int => each!(Int, |x, y| x == y),
            VarType::Uint => each!(Uint, |x, y| x == y),
            VarType::Dint => each!(Dint, |x, y| x == y),
        }
    }
}

fn show(v: Value) -> String {
    crate::services::trace::value_to_json(v).to_string()
}

/// Replays `trace` against the programs of `loaded`. A trace recorded with another configuration
/// or I/O map is refused unless `force`.
pub fn replay(trace: &Path, setup: &Setup, force: bool) -> Result<ReplayReport, ReplayError> {
    let started = Instant::now();
    let reader = TraceReader::open(trace)?;
    let header = reader.header().clone();
    refuse_other_configuration(trace, &header, &setup.digest()?, force)?;
    // The programs are read with the tool table and planned with the work offsets they were
    // in the run.
    let as_recorded;
    let setup = if header.tool_table.is_some() || header.offsets.is_some() {
        let mut s = setup.clone();
        if let Some(t) = &header.tool_table {
            s.tools = Some(
                crate::compose::setup::ToolTableFile::parse(t.file.clone(), t.text.clone())
                    .map_err(|e| refused(trace, format!("its tool table: {e}")))?,
            );
        }
        if let Some(o) = header.offsets {
            s.persistent = Some(o.into());
        }
        as_recorded = s;
        &as_recorded
    } else {
        setup
    };
    let (mut plc, library) = plc_of(trace, &header, setup)?;
    let (index, by_position) = variables(trace, &header, &plc)?;
    let mut classes = replayed_classes(trace, &header, &plc, &index, &by_position)?;
    let mut changed: Vec<(VarIndex, Value)> = Vec::new();
    let mut cycles = vec![0u64; classes.len()];
    let mut clock = VirtualClock::default();
    plc.init(0, &mut clock);
    let (mut records, mut last_t) = (0u64, 0u64);
    let mut ahead = ReadAhead::start(reader).map_err(|e| refused(trace, format!("cannot start reading: {e}")))?;
    while let Some(r) = ahead.next_record()? {
        let class = &classes[r.class];
        let task = &header.task_classes[r.class].name;
        let differs = |what: &str, recorded: String, replayed: String| {
            ReplayError::Differs(Difference {
                line: r.line,
                task: task.clone(),
                cycle: r.cycle,
                t_us: r.t_us,
                what: what.into(),
                recorded,
                replayed,
            })
        };
        if r.cycle != cycles[r.class] {
            return Err(differs(
                "cycle number",
                r.cycle.to_string(),
                cycles[r.class].to_string(),
            ));
        }
        cycles[r.class] += 1;
        // A job the screen made, planned again before the cycle that loads it.
        if let Some(job) = &r.job {
            replay_job(trace, setup, library.as_ref(), job, r.line)?;
        }
        changed.clear();
        changed.extend(r.inputs.iter().filter_map(|&(k, v)| class.input_at[k].map(|i| (i, v))));
        let class = &mut classes[r.class];
        for &(k, v) in &r.outputs {
            // The reader took only the class's outputs from the record.
            if let Some((g, at)) = class.output_at[k] {
                class.check[g].values[at] = v;
            }
        }
        clock.advance_to(r.t_us * 1000);
        plc.replay_cycle(class.ci, r.t_us * 1000, &changed, r.violation, &mut clock);
        let image = plc.class_image(class.ci);
        if !class.check.iter().all(|group| group.all_same(image)) {
            // The first in the header's order.
            for (k, &(position, i)) in class.outputs.iter().enumerate() {
                let name = class.names[k];
                if let Some((g, at)) = class.output_at[position]
                    && let want = class.check[g].values[at]
                    && !same(want, image[usize::from(i)])
                {
                    return Err(differs(name, show(want), show(image[usize::from(i)])));
                }
            }
        }
        if let Some(state) = &r.state {
            let status = plc.app_status();
            let got = status.map(|s| s.state).unwrap_or("(none)");
            // Compared in words: a library call per record cost a fortieth of the replay.
            if !crate::services::trace::fast::same_bytes(got.as_bytes(), state.as_bytes()) {
                return Err(differs("state", state.to_string(), got.to_string()));
            }
            let got = status.and_then(|s| s.reason);
            if got != r.reason.as_deref() {
                let show = |r: Option<&str>| r.map_or("(none)".to_string(), |r| format!("\"{r}\""));
                return Err(differs("reason", show(r.reason.as_deref()), show(got)));
            }
        }
        records += 1;
        last_t = r.t_us;
    }
    Ok(ReplayReport {
        records,
        recorded_s: last_t as f64 * 1e-6,
        wall: started.elapsed(),
        cut: ahead.cut().cloned(),
    })
}

/// The replay of `trace` refused, with why.
fn refused(trace: &Path, why: String) -> ReplayError {
    ReplayError::Refused(format!("{}: {why}", trace.display()))
}

/// A trace recorded with another configuration or I/O map than `digest`'s is refused, unless
/// `force`, with a hint at the configuration it was recorded with.
fn refuse_other_configuration(trace: &Path, header: &Header, digest: &str, force: bool) -> Result<(), ReplayError> {
    if header.config_digest != digest && !force {
        // Which configuration it was: a machine's own, or a file made for one.
        let hint = match (
            crate::compose::setup::with_digest(&header.config_digest),
            &header.machine,
        ) {
            (Some(name), _) => {
                format!("it was recorded with machine {name}'s own configuration: replay it with --machine {name}")
            }
            (None, Some(name)) => format!(
                "it was recorded on machine {name} with a configuration file of its own: give that file with --config FILE"
            ),
            (None, None) => "give the configuration it was recorded with (--config FILE or --machine NAME)".to_string(),
        };
        Err(refused(
            trace,
            format!(
                "recorded with another configuration or I/O map (digest {}, this one {digest}); {hint}, or use --force to replay anyway",
                header.config_digest
            ),
        ))
    } else {
        Ok(())
    }
}

/// The PLC the trace is replayed on, with the run's programs planned again as they were then.
fn plc_of(trace: &Path, header: &Header, setup: &Setup) -> Result<(Plc, Option<NcLibrary>), ReplayError> {
    let plan = |p: &crate::services::trace::TraceProgram| {
        crate::compose::nc_job::prepare_text(setup, p.file.clone(), p.text.clone())
            .and_then(crate::compose::nc_job::Prepared::into_job)
            .map_err(|e| refused(trace, format!("its program {}: {e}", p.file)))
    };
    let first = header.program.as_ref().map(plan).transpose()?;
    let offered = header.library.iter().map(plan).collect::<Result<Vec<_>, _>>()?;
    let screen = header.variables.contains_key(pkm_api::hmi::HMI_STOP.name());
    let library = crate::compose::nc_job::library(
        first,
        offered,
        screen && setup.machine.is_some(),
        setup.loaded.config.nc.laser,
    );
    // The bus only declares the I/O map's variables (and the operator screen's, if the run had
    // one): replayed cycles never call it.
    let mut bus = setup.declaring_bus()?;
    if screen {
        bus = setup.with_screen(bus).0;
    }
    let plc = setup.plc_with(bus, library.as_ref())?;
    Ok((plc, library))
}

/// The header's variables here, by name: each one's position among them and its index here,
/// and by position its index; refused where one is not here or has another type.
type Variables<'h> = (HashMap<&'h str, (usize, VarIndex)>, Vec<VarIndex>);

/// The trace's variables in this configuration (see [`Variables`]).
fn variables<'h>(trace: &Path, header: &'h Header, plc: &Plc) -> Result<Variables<'h>, ReplayError> {
    let mut index = HashMap::new();
    let mut by_position: Vec<VarIndex> = Vec::new();
    for (position, (name, ty)) in header.variables.iter().enumerate() {
        let i = plc
            .vars()
            .index_of(name)
            .ok_or_else(|| refused(trace, format!("variable \"{name}\" is not in this configuration")))?;
        let have = plc.vars().vars()[usize::from(i)].ty;
        if have != *ty {
            return Err(refused(
                trace,
                format!("variable \"{name}\" is {ty} in the trace but {have} here"),
            ));
        }
        index.insert(name.as_str(), (position, i));
        by_position.push(i);
    }
    Ok((index, by_position))
}

/// The trace's task classes as the replay runs them.
fn replayed_classes<'h>(
    trace: &Path,
    header: &'h Header,
    plc: &Plc,
    index: &HashMap<&'h str, (usize, VarIndex)>,
    by_position: &[VarIndex],
) -> Result<Vec<ReplayedClass<'h>>, ReplayError> {
    let initial = plc.global_image().to_vec();
    // Per class: its index here, its outputs (compared after every cycle) with their names,
    // and for each of the header's variables where it goes if the class latches it here.
    let mut classes = Vec::new();
    for c in &header.task_classes {
        let ci = plc
            .classes()
            .position(|k| k.name == c.name && k.period_ns == c.cycle_us * 1000)
            .ok_or_else(|| {
                refused(
                    trace,
                    format!(
                        "task class \"{}\" ({} µs) is not in this configuration",
                        c.name, c.cycle_us
                    ),
                )
            })?;
        let outputs: Vec<(usize, VarIndex)> = c.outputs.iter().map(|n| index[n.as_str()]).collect();
        let names: Vec<&str> = c.outputs.iter().map(String::as_str).collect();
        let mut check: Vec<Recorded> = Vec::new();
        let mut output_at = vec![None; by_position.len()];
        for &(position, i) in &outputs {
            // A name listed twice is kept once.
            if output_at[position].is_some() {
                continue;
            }
            let ty = plc.vars().vars()[usize::from(i)].ty;
            let g = match check.iter().position(|r| r.ty == ty) {
                Some(g) => g,
                None => {
                    check.push(Recorded {
                        ty,
                        at: Vec::new(),
                        values: Vec::new(),
                    });
                    check.len() - 1
                }
            };
            output_at[position] = Some((g, check[g].at.len()));
            check[g].at.push(i);
            check[g].values.push(initial[usize::from(i)]);
        }
        let latched = plc.classes().nth(ci).map(|k| k.inputs.to_vec()).unwrap_or_default();
        // A recorded input this configuration's class does not latch (a forced replay) is not
        // fed to it, as the class would not have read it.
        let input_at: Vec<Option<VarIndex>> = by_position.iter().map(|i| latched.contains(i).then_some(*i)).collect();
        classes.push(ReplayedClass {
            ci,
            outputs,
            names,
            check,
            output_at,
            input_at,
        });
    }
    Ok(classes)
}

/// A job the screen made in the run, planned again and put in its slot before the cycle that
/// loads it; the job it replaced is released, as in the run.
fn replay_job(
    trace: &Path,
    setup: &Setup,
    library: Option<&NcLibrary>,
    job: &TraceJob,
    line: usize,
) -> Result<(), ReplayError> {
    let library =
        library.ok_or_else(|| refused(trace, format!("line {}: a screen job in a run without programs", line)))?;
    let spec = job.spec().map_err(|m| refused(trace, format!("line {}: {m}", line)))?;
    let made = crate::compose::screen_job::plan(setup, library, &spec)
        .map_err(|e| refused(trace, format!("line {}: screen job {}: {e}", line, job.number)))?;
    let slot = library.screen_slot(job.number).ok_or_else(|| {
        refused(
            trace,
            format!("line {}: job number {} is a library program's", line, job.number),
        )
    })?;
    library
        .screen
        .set(slot, pkm_api::screen_jobs::ScreenJob { spec, job: made })
        .map_err(|e| refused(trace, format!("line {}: {e}", line)))?;
    // The job before it is replaced, as in the run: its plan is released (a replay of a
    // run of a hundred large jobs holds one or two at a time, as the run did).
    drop(library.screen.release_replaced(Some(slot)));
    Ok(())
}
