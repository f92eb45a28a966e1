//! Built-in self-test programs that exercise the runtime on its own.
//!
//! **These are not the TRIJOINT application.** They exist to check and measure the runtime (image
//! consistency, class ordering, overruns, time sources) without a machine. Their variables are
//! all prefixed `selftest_` and their state is reported as `SELFTEST-RUN` / `SELFTEST-ERROR`, so
//! that nobody mistakes a self-test run for the product.

use serde::Deserialize;

use crate::image::{Declare, Input, Output};
use crate::program::{AppStatus, Cycle, Program, ProgramArgs, ProgramInfo, Registry};

/// Parameters that make a self-test program heavy, to provoke overruns.
#[derive(Clone, Copy, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadParams {
    /// Execution time to spend per loaded cycle (µs).
    #[serde(default)]
    pub burn_us: u32,
    /// Spend it every N-th cycle (1 = every cycle; 0 counts as 1).
    #[serde(default)]
    pub burn_every: u32,
    /// Do not burn before this cycle number (lets a run start cleanly).
    #[serde(default)]
    pub burn_from_cycle: u64,
    /// Do not burn from this cycle number on (default: never stop).
    #[serde(default)]
    pub burn_until_cycle: Option<u64>,
}

impl LoadParams {
    fn apply(&self, ctx: &mut Cycle<'_>) {
        let every = u64::from(self.burn_every.max(1));
        let cycle = ctx.cycle();
        let in_window = cycle >= self.burn_from_cycle && self.burn_until_cycle.is_none_or(|u| cycle < u);
        if self.burn_us > 0 && in_window && cycle.is_multiple_of(every) {
            ctx.burn(u64::from(self.burn_us) * 1000);
        }
    }
}

/// The number of copies of the sequence counter; a torn set shows as copies that disagree.
const COPIES: usize = 4;

/// Writes a sequence counter and several copies of it, plus a pseudo-random walk, every cycle.
pub struct Producer {
    load: LoadParams,
    seq: Output<i32>,
    copies: [Output<i32>; COPIES],
    walk: Output<f64>,
    rng: u64,
}

impl Producer {
    fn create(args: &ProgramArgs<'_>, decl: &mut Declare<'_>) -> Box<dyn Program> {
        let load = args.parse::<LoadParams>(decl);
        Box::new(Producer {
            load,
            seq: decl.output("selftest_seq", 0),
            copies: std::array::from_fn(|i| decl.output(&format!("selftest_copy{}", i + 1), 0)),
            walk: decl.output("selftest_walk", 0.0),
            rng: 0x9E37_79B9_7F4A_7C15,
        })
    }
}

impl Program for Producer {
    fn cycle(&mut self, ctx: &mut Cycle<'_>) {
        let seq = ctx.output_value(self.seq).wrapping_add(1);
        ctx.set(self.seq, seq);
        for c in self.copies {
            ctx.set(c, seq);
        }
        // xorshift64*: a deterministic walk, so determinism tests compare non-trivial values.
        self.rng ^= self.rng >> 12;
        self.rng ^= self.rng << 25;
        self.rng ^= self.rng >> 27;
        let step = (self.rng.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
        let walk = ctx.output_value(self.walk) + step;
        ctx.set(self.walk, walk);
        self.load.apply(ctx);
    }
}

/// Reads the producer's set, checks that it is consistent, and keeps a RUN/ERROR state that a
/// cycle time violation (reaction `error`) or a torn input set sends to ERROR.
pub struct Consumer {
    load: LoadParams,
    seq: Input<i32>,
    copies: [Input<i32>; COPIES],
    walk: Input<f64>,
    checked: Output<i32>,
    walk_sum: Output<f64>,
    reason: Option<String>,
}

impl Consumer {
    fn create(args: &ProgramArgs<'_>, decl: &mut Declare<'_>) -> Box<dyn Program> {
        let load = args.parse::<LoadParams>(decl);
        Box::new(Consumer {
            load,
            seq: decl.input("selftest_seq"),
            copies: std::array::from_fn(|i| decl.input(&format!("selftest_copy{}", i + 1))),
            walk: decl.input("selftest_walk"),
            checked: decl.output("selftest_checked", 0),
            walk_sum: decl.output("selftest_walk_sum", 0.0),
            reason: None,
        })
    }
}

impl Program for Consumer {
    fn cycle(&mut self, ctx: &mut Cycle<'_>) {
        if self.reason.is_none() {
            if ctx.violation().is_some() {
                self.reason = Some("cycle time violation".to_string());
            }
            let seq = ctx.get(self.seq);
            if let Some(bad) = self.copies.iter().find(|c| ctx.get(**c) != seq) {
                let copy = ctx.get(*bad);
                self.reason = Some(format!("torn input set: selftest_seq = {seq} but a copy = {copy}"));
            }
        }
        let checked = ctx.output_value(self.checked).wrapping_add(1);
        ctx.set(self.checked, checked);
        let sum = ctx.output_value(self.walk_sum) + ctx.get(self.walk);
        ctx.set(self.walk_sum, sum);
        self.load.apply(ctx);
    }

    fn status(&self) -> Option<AppStatus<'_>> {
        Some(match &self.reason {
            None => AppStatus {
                state: "SELFTEST-RUN",
                reason: None,
                note: None,
                values: &[],
            },
            Some(r) => AppStatus {
                state: "SELFTEST-ERROR",
                reason: Some(r),
                note: None,
                values: &[],
            },
        })
    }
}

/// Does nothing but may burn time: the load of the time-source benchmark.
pub struct Idle {
    load: LoadParams,
}

impl Program for Idle {
    fn cycle(&mut self, ctx: &mut Cycle<'_>) {
        self.load.apply(ctx);
    }
}

/// The self-test program types.
pub fn register(registry: &mut Registry) {
    registry
        .register(ProgramInfo {
            name: "selftest.producer",
            summary: "runtime self-test: writes a counter, copies of it and a random walk",
            factory: Producer::create,
        })
        .register(ProgramInfo {
            name: "selftest.consumer",
            summary: "runtime self-test: checks the producer's set is never torn; RUN/ERROR state",
            factory: Consumer::create,
        })
        .register(ProgramInfo {
            name: "selftest.idle",
            summary: "runtime self-test: an empty cycle (optionally burning time)",
            factory: |args, decl| Box::new(Idle { load: args.parse(decl) }),
        });
}
