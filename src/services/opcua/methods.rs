//! What the run's OPC UA methods do: each call checked against the machine's state and its
//! arguments, then pressed into the screen's command sink like a button of the page; and the
//! rate at which calls are taken.

use std::time::{Duration, Instant};

use opcua::types::{StatusCode, Variant};
use tracing::warn;

use super::space::Method;
use crate::services::hmi::commands::{CommandSink, press};

/// The most method calls taken per second, all sessions together: far more than an operator or
/// a SCADA sends; a client calling in a loop is refused (`BadTooManyOperations`) rather than
/// flooding the process image and the log.
pub const MAX_CALLS_PER_S: u32 = 20;

/// Counts method calls per second against [`MAX_CALLS_PER_S`].
#[derive(Debug)]
pub struct CallRate {
    window: Instant,
    calls: u32,
    refused: u32,
}

impl CallRate {
    /// A rate whose first window starts `now`.
    pub fn new(now: Instant) -> CallRate {
        CallRate {
            window: now,
            calls: 0,
            refused: 0,
        }
    }

    /// Whether a call at `now` is taken. Refusals are logged once per window, as a count.
    pub fn allow(&mut self, now: Instant) -> bool {
        if now.duration_since(self.window) >= Duration::from_secs(1) {
            if self.refused > 0 {
                warn!(
                    "OPC UA: {} method calls refused in a second: at most {MAX_CALLS_PER_S} are taken",
                    self.refused
                );
            }
            *self = CallRate::new(now);
        }
        self.calls += 1;
        let allowed = self.calls <= MAX_CALLS_PER_S;
        if !allowed {
            self.refused += 1;
        }
        allowed
    }
}

/// Carries out `method` with `args` in main state `state`: what was done, or the status code
/// and why not.
pub fn command(
    method: Method,
    args: &[Variant],
    state: &str,
    programs: &[String],
    sink: &CommandSink,
) -> Result<String, (StatusCode, String)> {
    let invalid_state = |why: String| Err((StatusCode::BadInvalidState, why));
    match method {
        Method::Stop => {
            if state == "ERROR" {
                return invalid_state("the machine is in ERROR already; Acknowledge acknowledges the error".into());
            }
            sink.update(|c| c.presses[press::STOP] += 1);
            Ok("STOP pressed".into())
        }
        Method::Acknowledge => {
            if state != "ERROR" {
                return invalid_state(format!("there is no error to acknowledge: the machine is in {state}"));
            }
            sink.update(|c| c.acknowledgements += 1);
            Ok("the error acknowledged (STOP pressed once released)".into())
        }
        Method::Start | Method::Hold | Method::Resume => {
            // As the program's automaton takes them: start from READY, hold and resume in AUTO.
            let (k, from) = match method {
                Method::Start => (0, "READY"),
                Method::Hold => (1, "AUTO"),
                _ => (2, "AUTO"),
            };
            if state != from {
                return invalid_state(format!(
                    "the machine is in {state}: a program {} in {from}",
                    match method {
                        Method::Start => "starts",
                        Method::Hold => "is held",
                        _ => "resumes",
                    }
                ));
            }
            sink.update(|c| c.presses[press::NC[k]] += 1);
            Ok(format!("program {} pressed", method.name().to_lowercase()))
        }
        Method::Load => {
            let Some(Variant::Int16(n)) = args.first() else {
                return Err((
                    StatusCode::BadInvalidArgument,
                    "Load takes the program's number (Int16)".into(),
                ));
            };
            let n = *n;
            let known = usize::try_from(n).is_ok_and(|k| (1..=programs.len()).contains(&k));
            if !known {
                return Err((
                    StatusCode::BadOutOfRange,
                    format!("no program {n}: the run has {}", programs.len()),
                ));
            }
            if state == "AUTO" {
                return invalid_state("a program runs: another is loaded once it has ended or stopped".into());
            }
            sink.update(|c| c.program = n);
            Ok(format!("program {n} ({}) loaded", programs[n as usize - 1]))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn method_calls_beyond_the_rate_are_refused_until_the_next_second() {
        let start = Instant::now();
        let mut rate = CallRate::new(start);
        let taken = (0..30).filter(|_| rate.allow(start)).count();
        assert_eq!(taken, MAX_CALLS_PER_S as usize);
        assert!(!rate.allow(start + Duration::from_millis(999)));
        assert!(
            rate.allow(start + Duration::from_secs(1)),
            "a new second takes calls again"
        );
    }

    #[test]
    fn methods_check_the_state_and_their_argument() {
        let (_bus, sink) =
            crate::services::hmi::commands::HmiBus::new(Box::new(crate::runtime::bus::NoBus), 0, 500_000_000);
        let programs = vec!["programs/a.ngc".to_string()];
        let run = |m: Method, args: &[Variant], state: &str| command(m, args, state, &programs, &sink);
        assert_eq!(run(Method::Stop, &[], "READY"), Ok("STOP pressed".into()));
        assert_eq!(sink.current().presses[press::STOP], 1);
        assert_eq!(
            run(Method::Stop, &[], "ERROR"),
            Err((
                StatusCode::BadInvalidState,
                "the machine is in ERROR already; Acknowledge acknowledges the error".into()
            ))
        );
        assert_eq!(sink.current().presses[press::STOP], 1, "no press for a refused call");
        assert!(run(Method::Acknowledge, &[], "ERROR").is_ok());
        assert_eq!(sink.current().acknowledgements, 1);
        assert_eq!(
            run(Method::Start, &[], "AUTO"),
            Err((
                StatusCode::BadInvalidState,
                "the machine is in AUTO: a program starts in READY".into()
            ))
        );
        assert!(run(Method::Hold, &[], "AUTO").is_ok());
        assert_eq!(
            run(Method::Load, &[Variant::Int16(2)], "READY"),
            Err((StatusCode::BadOutOfRange, "no program 2: the run has 1".into()))
        );
        assert_eq!(
            run(Method::Load, &[Variant::Int32(1)], "READY"),
            Err((
                StatusCode::BadInvalidArgument,
                "Load takes the program's number (Int16)".into()
            ))
        );
        assert_eq!(
            run(Method::Load, &[Variant::Int16(1)], "READY"),
            Ok("program 1 (programs/a.ngc) loaded".into())
        );
        assert_eq!(sink.current().program, 1);
        assert!(
            run(Method::Load, &[Variant::Int16(1)], "AUTO").is_err(),
            "not while a program runs"
        );
    }
}
