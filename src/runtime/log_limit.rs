//! Bounds on the log a peer can cause: a client flooding the screen or the OPC UA
//! server with malformed messages, wrong passwords or connections must not fill the disk, nor
//! bury the lines that matter.
//!
//! - [`LogBudget`], a layer of the log itself: every line, the libraries' included (the OPC UA
//!   stack logs an ERROR for each malformed chunk), goes through it. A place in the code logs at
//!   most [`PER_PLACE`] lines per [`INTERVAL`]; the places of pkm-plc together at most
//!   [`OURS`], those of the libraries together at most [`LIBRARIES`] (a library's chatter cannot
//!   push out the PLC's own lines); what is held back is counted and said in one summary line per
//!   interval. The machine's state changes ([`STATE_LOG_TARGET`]) always pass: their rate is the
//!   automaton's, not a peer's.
//! - [`Limited`], for a line about a peer: at most one per source address per interval, the rest
//!   counted into the summary of the next.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tracing::callsite::Identifier;
use tracing::{Event, Subscriber, info, warn};
use tracing_subscriber::layer::{Context, Layer};

use super::run::STATE_LOG_TARGET;

/// The window of every bound of the log.
pub const INTERVAL: Duration = Duration::from_secs(10);
/// The most lines one place in the code logs per interval.
pub const PER_PLACE: u32 = 10;
/// The most lines pkm-plc's places log per interval in all (the summaries and the state
/// changes besides).
pub const OURS: u32 = 40;
/// The most lines the libraries' places log per interval in all.
pub const LIBRARIES: u32 = 20;
/// The prefix of pkm-plc's own targets.
const OUR_TARGETS: &str = "pkm_plc";
/// The most source addresses a [`Limited`] names per interval; more are counted together.
const SOURCES_NAMED: usize = 32;

/// The target of the budget's own summaries.
const SUMMARY_TARGET: &str = "pkm_plc::log_limit";
/// The targets whose lines always pass, each exactly (a prefix would let a whole module tree
/// through: `pkm_plc::run` once let every `pkm_plc::runtime::…` line pass): the machine's state
/// changes, and the budget's own summaries.
const ALWAYS: [&str; 2] = [STATE_LOG_TARGET, SUMMARY_TARGET];

/// The log's budget (see the module's documentation). Shared between the layer that applies it
/// and the thread that says what it held back.
#[derive(Default)]
pub struct LogBudget {
    state: Mutex<Budget>,
}

#[derive(Default)]
struct Budget {
    since: Option<Instant>,
    /// Lines logged this interval: pkm-plc's, the libraries'.
    ours: u32,
    libraries: u32,
    /// Per place in the code: lines logged this interval, lines held back, where it is.
    places: HashMap<Identifier, Place>,
}

struct Place {
    logged: u32,
    held: u64,
    /// `target` and line of the place, as the summary names it.
    name: String,
}

impl LogBudget {
    /// A budget with nothing spent.
    pub fn new() -> Arc<LogBudget> {
        Arc::new(LogBudget::default())
    }

    /// Whether a line of the place `callsite` (`target`, `line`) is logged at `now`; one held
    /// back is counted.
    pub fn admit(&self, callsite: Identifier, target: &str, line: Option<u32>, now: Instant) -> bool {
        if ALWAYS.contains(&target) {
            return true;
        }
        let mut b = self.state.lock().unwrap_or_else(|p| p.into_inner());
        let since = *b.since.get_or_insert(now);
        if now.duration_since(since) >= INTERVAL {
            // Nobody has taken the summary of the interval that ended: the next call of
            // `held_back` reports it; the counts of lines logged start afresh.
            b.since = Some(now);
            (b.ours, b.libraries) = (0, 0);
            for p in b.places.values_mut() {
                p.logged = 0;
            }
        }
        let ours = target.starts_with(OUR_TARGETS);
        let spent = if ours { b.ours >= OURS } else { b.libraries >= LIBRARIES };
        let place = b.places.entry(callsite).or_insert_with(|| Place {
            logged: 0,
            held: 0,
            name: match line {
                Some(l) => format!("{target}:{l}"),
                None => target.to_string(),
            },
        });
        if place.logged >= PER_PLACE || spent {
            place.held += 1;
            return false;
        }
        place.logged += 1;
        if ours {
            b.ours += 1;
        } else {
            b.libraries += 1;
        }
        true
    }

    /// What was held back since the last call, most first: (place, lines); counts reset.
    pub fn held_back(&self) -> Vec<(String, u64)> {
        let mut b = self.state.lock().unwrap_or_else(|p| p.into_inner());
        let mut held: Vec<(String, u64)> = b
            .places
            .values_mut()
            .filter(|p| p.held > 0)
            .map(|p| (p.name.clone(), std::mem::take(&mut p.held)))
            .collect();
        held.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
        held
    }

    /// Says what was held back once per interval, on a thread of its own, for as long as the
    /// process runs. Logged through the log, at a target the budget always lets pass.
    pub fn spawn_summaries(self: &Arc<Self>) {
        let budget = Arc::clone(self);
        let spawned = std::thread::Builder::new()
            .name("pkm-log-budget".into())
            .spawn(move || {
                loop {
                    std::thread::sleep(INTERVAL);
                    let held = budget.held_back();
                    if held.is_empty() {
                        continue;
                    }
                    let total: u64 = held.iter().map(|(_, n)| n).sum();
                    let places: Vec<String> = held.iter().take(5).map(|(p, n)| format!("{n} at {p}")).collect();
                    warn!(
                        target: SUMMARY_TARGET,
                        "log: {total} lines held back in the last {} s (per {} s at most {PER_PLACE} a place, {OURS} of pkm-plc's and {LIBRARIES} of the libraries'): {}{}",
                        INTERVAL.as_secs(),
                        INTERVAL.as_secs(),
                        places.join(", "),
                        if held.len() > 5 { ", …" } else { "" }
                    );
                }
            });
        if let Err(e) = spawned {
            warn!("log: the lines held back cannot be summarised (no thread: {e})");
        }
    }
}

/// The layer that applies a [`LogBudget`] to every line.
pub struct BudgetLayer(pub Arc<LogBudget>);

impl<S: Subscriber> Layer<S> for BudgetLayer {
    fn event_enabled(&self, event: &Event<'_>, _ctx: Context<'_, S>) -> bool {
        let meta = event.metadata();
        self.0
            .admit(meta.callsite(), meta.target(), meta.line(), Instant::now())
    }
}

/// A line about peers, at most one per source (an address, a user name) per interval (see the
/// module's documentation).
pub struct Limited<K = IpAddr> {
    /// What the lines are about, as the summary says it ("OPC UA: logins refused").
    what: &'static str,
    state: Mutex<Sources<K>>,
}

struct Sources<K> {
    since: Option<Instant>,
    /// Lines per source this interval (the first one was logged).
    seen: HashMap<K, u64>,
    /// Lines of sources beyond those named.
    others: u64,
}

impl<K: std::hash::Hash + Eq> Limited<K> {
    /// Lines about `what`.
    pub fn new(what: &'static str) -> Limited<K> {
        Limited {
            what,
            state: Mutex::new(Sources {
                since: None,
                seen: HashMap::new(),
                others: 0,
            }),
        }
    }

    /// Logs `line` at WARN if it is `source`'s first this interval.
    pub fn warn(&self, source: K, line: impl FnOnce() -> String) {
        if let Some(summary) = self.take(source, Instant::now()) {
            if let Some(s) = summary.1 {
                warn!("{s}");
            }
            if summary.0 {
                warn!("{}", line());
            }
        }
    }

    /// Logs `line` at INFO if it is `source`'s first this interval.
    pub fn info(&self, source: K, line: impl FnOnce() -> String) {
        if let Some(summary) = self.take(source, Instant::now()) {
            if let Some(s) = summary.1 {
                info!("{s}");
            }
            if summary.0 {
                info!("{}", line());
            }
        }
    }

    /// A line from `source` at `now`: whether to log it, and the summary of the interval that
    /// ended, if one did with lines held back (`None`: nothing to log).
    fn take(&self, source: K, now: Instant) -> Option<(bool, Option<String>)> {
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        let since = *s.since.get_or_insert(now);
        let mut summary = None;
        if now.duration_since(since) >= INTERVAL {
            let held: u64 = s.seen.values().map(|n| n - 1).sum::<u64>() + s.others;
            if held > 0 {
                summary = Some(format!(
                    "{}: {held} more from {} sources in the last {} s (one line per source per {} s)",
                    self.what,
                    s.seen.len() + usize::from(s.others > 0),
                    now.duration_since(since).as_secs(),
                    INTERVAL.as_secs()
                ));
            }
            s.since = Some(now);
            s.seen.clear();
            s.others = 0;
        }
        let known = s.seen.len() < SOURCES_NAMED || s.seen.contains_key(&source);
        let first = if known {
            let n = s.seen.entry(source).or_insert(0);
            *n += 1;
            *n == 1
        } else {
            s.others += 1;
            false
        };
        (first || summary.is_some()).then_some((first, summary))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A place in the code (not zero-sized: each has an address of its own).
    struct Place(#[allow(dead_code)] u8);

    impl tracing::Callsite for Place {
        fn set_interest(&self, _: tracing::subscriber::Interest) {}
        fn metadata(&self) -> &tracing::Metadata<'_> {
            unreachable!("not asked")
        }
    }

    static PLACES: [Place; 8] = [
        Place(0),
        Place(1),
        Place(2),
        Place(3),
        Place(4),
        Place(5),
        Place(6),
        Place(7),
    ];
    static HERE: &Place = &PLACES[0];
    static THERE: &Place = &PLACES[1];

    fn id(c: &'static Place) -> Identifier {
        Identifier(c)
    }

    #[test]
    fn a_place_logs_its_share_per_interval_and_what_is_held_back_is_counted() {
        let budget = LogBudget::new();
        let t0 = Instant::now();
        let admitted = (0..1000)
            .filter(|_| budget.admit(id(HERE), "opcua_server::comms", Some(42), t0))
            .count();
        assert_eq!(admitted, PER_PLACE as usize);
        // Another place still has its share, and the state changes always pass.
        assert!(budget.admit(id(THERE), "pkm_plc::hmi::server", Some(7), t0));
        assert!((0..100).all(|_| budget.admit(id(THERE), STATE_LOG_TARGET, Some(55), t0)));
        assert_eq!(budget.held_back(), [("opcua_server::comms:42".to_string(), 990)]);
        assert!(budget.held_back().is_empty(), "said once");
        // The next interval: a share again.
        assert!(budget.admit(id(HERE), "opcua_server::comms", Some(42), t0 + INTERVAL));
    }

    /// Only the state changes' own target passes always: the rest of the runtime (the cyclic
    /// thread's warnings, a bus's complaints) and anything named like it keeps the budget.
    #[test]
    fn only_the_state_changes_pass_always_not_their_neighbours() {
        assert_eq!(STATE_LOG_TARGET, "pkm_plc::runtime::run");
        let t0 = Instant::now();
        for neighbour in ["pkm_plc::runtime::plc", "pkm_plc::runtime::run::more", "pkm_plc::run"] {
            let budget = LogBudget::new();
            let admitted = (0..100)
                .filter(|_| budget.admit(id(HERE), neighbour, Some(1), t0))
                .count();
            assert_eq!(admitted, PER_PLACE as usize, "{neighbour}");
        }
    }

    #[test]
    fn all_places_together_log_at_most_their_sum_per_interval_the_libraries_apart() {
        let budget = LogBudget::new();
        let t0 = Instant::now();
        // Eight places of a library, each flooding: together no more than the libraries' share.
        let mut admitted = 0;
        for k in 0..PLACES.len() * PER_PLACE as usize {
            if budget.admit(id(&PLACES[k % PLACES.len()]), "opcua_server::x", None, t0) {
                admitted += 1;
            }
        }
        assert_eq!(admitted, LIBRARIES);
        // pkm-plc's own places still log, up to their own share.
        let ours = (0..PLACES.len() * PER_PLACE as usize)
            .filter(|k| budget.admit(id(&PLACES[k % PLACES.len()]), "pkm_plc::hmi", None, t0))
            .count();
        assert_eq!(ours as u32, OURS);
    }

    #[test]
    fn a_source_gets_one_line_per_interval_and_the_rest_are_summarised() {
        let limited: Limited = Limited::new("OPC UA: logins refused");
        let t0 = Instant::now();
        let a: IpAddr = [127, 0, 0, 2].into();
        let b: IpAddr = [127, 0, 0, 3].into();
        assert_eq!(limited.take(a, t0), Some((true, None)));
        for _ in 0..99 {
            assert_eq!(limited.take(a, t0), None);
        }
        assert_eq!(limited.take(b, t0), Some((true, None)));
        let (first, summary) = limited.take(b, t0 + INTERVAL).expect("a new interval");
        assert!(first);
        assert_eq!(
            summary.as_deref(),
            Some("OPC UA: logins refused: 99 more from 2 sources in the last 10 s (one line per source per 10 s)")
        );
        // Sources beyond those named are counted together, not remembered one by one.
        let limited: Limited = Limited::new("x");
        for k in 0..1000u32 {
            let source = IpAddr::from((0x7f00_0000 + k).to_be_bytes());
            let _ = limited.take(source, t0);
        }
        let held = limited.state.lock().expect("lock");
        assert_eq!(
            (held.seen.len(), held.others),
            (SOURCES_NAMED, 1000 - SOURCES_NAMED as u64)
        );
    }
}
