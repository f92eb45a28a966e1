//! The encoder program (10 ms class): unwraps both 16-bit counters to absolute counts, converts
//! them to millimetres of carriage travel, estimates velocities, flags implausible jumps, and
//! latches the position at every rising edge of a limit switch (a touch-probe capture: referencing then
//! knows the switch position to one count, although the main program runs only every 50 ms).

use serde::Deserialize;

use crate::vars;
use pkm_api::image::{Declare, Input, Output};
use pkm_api::program::{Cycle, Program, ProgramArgs};

/// Parameters of the encoder program.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EncoderParams {
    /// Counts per mm of carriage travel (must match the drive: encoder × gearbox ÷ lead).
    pub counts_per_mm: f64,
    /// A change of more than this many counts in one cycle is an encoder fault (must be below
    /// 32768, half the counter range, where the unwrap becomes ambiguous).
    pub max_counts_per_cycle: u16,
}

impl Default for EncoderParams {
    fn default() -> Self {
        // 80 mm/s × 7000 counts/mm × 10 ms = 5600 counts per cycle at full speed.
        EncoderParams {
            counts_per_mm: 7000.0,
            max_counts_per_cycle: 12_000,
        }
    }
}

/// The counter unwrap every joint-driven machine shares (re-exported where the TRIJOINT's tests
/// and tools have always found it).
pub use pkm_drives::counter::unwrap;

/// One drive's encoder state.
#[derive(Clone, Copy, Debug, Default)]
struct Channel {
    started: bool,
    last_raw: i16,
    counts: i64,
    fault: bool,
    last_switch: [bool; 2],
}

struct Vars {
    raw: Input<i16>,
    switches: [Input<bool>; 2],
    counts: Output<i32>,
    position: Output<f64>,
    velocity: Output<f64>,
    fault: Output<bool>,
    capture: [Output<f64>; 2],
    captured: [Output<i32>; 2],
}

/// The encoder program.
pub struct Encoders {
    p: EncoderParams,
    reference: [Input<f64>; 2],
    ack: Input<bool>,
    vars: [Vars; 2],
    state: [Channel; 2],
    last_ack: bool,
}

impl Encoders {
    /// Declares the program's variables (`*_left_*`, `*_right_*`).
    pub fn create(args: &ProgramArgs<'_>, decl: &mut Declare<'_>) -> Box<dyn Program> {
        let p: EncoderParams = args.parse(decl);
        super::control::fast_class_only("trijoint.encoders", "the encoder unwrap and touch probe", args, decl);
        decl.within("params.counts_per_mm", p.counts_per_mm, &pkm_api::ranges::COUNTS_PER_MM);
        if p.max_counts_per_cycle == 0 || p.max_counts_per_cycle >= 32_768 {
            decl.issue(
                "params.max_counts_per_cycle",
                format!(
                    "must be 1 … 32767 (half the counter range), got {}",
                    p.max_counts_per_cycle
                ),
            );
        }
        let side = |d: usize, decl: &mut Declare<'_>| Vars {
            raw: decl.read(vars::ENCODER_COUNTER[d]),
            switches: vars::SWITCHES[d].map(|v| decl.read(v)),
            counts: decl.write(vars::COUNTS[d], 0),
            position: decl.write(vars::POSITION_MM[d], 0.0),
            velocity: decl.write(vars::VELOCITY_MM_S[d], 0.0),
            fault: decl.write(vars::ENCODER_FAULT[d], false),
            capture: vars::CAPTURE_MM[d].map(|v| decl.write(v, 0.0)),
            captured: vars::CAPTURES[d].map(|v| decl.write(v, 0)),
        };
        let channels = [side(0, decl), side(1, decl)];
        Box::new(Encoders {
            p,
            reference: vars::REFERENCE_MM.map(|v| decl.read(v)),
            ack: decl.read(vars::ENCODER_FAULT_ACK),
            vars: channels,
            state: [Channel::default(); 2],
            last_ack: false,
        })
    }
}

impl Program for Encoders {
    fn cycle(&mut self, ctx: &mut Cycle<'_>) {
        let ack = ctx.get(self.ack);
        let ack_edge = ack && !self.last_ack;
        self.last_ack = ack;
        let dt = ctx.period_ns() as f64 * 1e-9;
        for (i, v) in self.vars.iter().enumerate() {
            let s = &mut self.state[i];
            let raw = ctx.get(v.raw);
            if !s.started {
                s.started = true;
                s.last_raw = raw;
                s.counts = i64::from(raw);
            }
            let (counts, delta) = unwrap(s.counts, s.last_raw, raw);
            s.last_raw = raw;
            if ack_edge {
                s.fault = false;
            }
            if delta.unsigned_abs() > u64::from(self.p.max_counts_per_cycle) {
                // Not a plausible motion: keep the last good count and report the fault, rather
                // than a position that may be wrong by a whole counter range.
                s.fault = true;
            } else {
                s.counts = counts;
            }
            let counts32 = i32::try_from(s.counts).unwrap_or(if s.counts < 0 { i32::MIN } else { i32::MAX });
            ctx.set(v.counts, counts32);
            // Counts since power-on, in mm; the reference (set by INIT) moves 0 to the lower switch.
            let absolute = s.counts as f64 / self.p.counts_per_mm;
            let position = absolute - ctx.get(self.reference[i]);
            let previous = ctx.output_value(v.position);
            ctx.set(v.position, position);
            // A first-order filtered difference: one count per cycle is 1.4 mm/s of noise.
            let raw_velocity = if ctx.cycle() == 0 {
                0.0
            } else {
                (position - previous) / dt
            };
            let velocity = ctx.output_value(v.velocity) * 0.5 + raw_velocity * 0.5;
            ctx.set(v.velocity, velocity);
            ctx.set(v.fault, s.fault);
            for end in 0..2 {
                let on = ctx.get(v.switches[end]);
                if on && !s.last_switch[end] {
                    ctx.set(v.capture[end], absolute);
                    let n = ctx.output_value(v.captured[end]).wrapping_add(1);
                    ctx.set(v.captured[end], n);
                }
                s.last_switch[end] = on;
            }
        }
    }
}
