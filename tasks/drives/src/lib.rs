//! What every joint-driven machine shares, written once: the TRIJOINT application and the
//! machine-agnostic application for the other machines both use it.
//!
//! - [`automaton`]: the main states and the STOP press-and-lockout rule.
//! - [`counter`]: absolute positions from 16-bit wrapping counters (encoder counts, emitted steps).
//! - [`pi`]: the PI position regulator with velocity feed-forward and anti-windup.
//! - [`interlock`]: the fast interlock rule (what zeroes the drive outputs in the same cycle).
//! - [`nc`]: executing a planned NC program in the fast class (feed hold, M0, spindle, the
//!   run's contour and following errors).
//! - [`sim`]: simulated drives for the plants: a stepper that loses steps beyond its pull-out
//!   limits.
//!
//! Pure computation: no allocation in the cyclic functions, no clock, no I/O.

pub mod automaton;
pub mod counter;
pub mod interlock;
pub mod nc;
pub mod pi;
pub mod sim;
