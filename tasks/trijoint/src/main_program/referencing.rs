//! Referencing (INIT): each drive finds its switches three times, ever slower, then both go to
//! their start positions; the lower switches become 0 mm and the software limits are set.

use pkm_kinematics::Kinematics;
use pkm_kinematics::trijoint::{Trijoint, TrijointParams};

use super::*;

/// Which end of a drive's travel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum End {
    Lower = 0,
    Upper = 1,
}

impl End {
    pub(super) fn direction(self) -> f64 {
        match self {
            End::Lower => -1.0,
            End::Upper => 1.0,
        }
    }

    pub(super) fn other(self) -> End {
        match self {
            End::Lower => End::Upper,
            End::Upper => End::Lower,
        }
    }

    /// Index of drive `i`'s switch at this end in [`SWITCHES`] order.
    pub(super) fn switch(self, drive: usize) -> usize {
        drive * 2 + if self == End::Upper { 0 } else { 1 }
    }
}

/// One drive's progress through referencing. Each switch is found three times, ever slower:
/// stage 0 at the init speed, stage 1 at the approach speed, stage 2 creeping at most one count
/// per 10 ms cycle; the encoder program's capture of the last one is the switch position.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Search {
    /// Moving towards the switch until its capture counter moves past `seen[end]`.
    Seek {
        end: End,
        stage: u8,
        seen: [i32; 2],
        since_s: f64,
    },
    /// Moving back to `target`, clear of the switch, before the next stage.
    Retreat { end: End, stage: u8, target: f64 },
    /// Both switches found; waiting for the other drive.
    Found,
    /// Moving to the start position.
    ToStart { target: f64 },
    /// At the start position.
    Done,
}

impl Main {
    /// One cycle of drive `i`'s referencing.
    pub(super) fn step_search(&mut self, io: &mut Io, i: usize) -> Result<(), Reason> {
        let p = &self.p;
        match self.searches[i] {
            Search::Seek {
                end,
                stage,
                seen,
                since_s,
            } => {
                // The other switch tripping while seeking this one: wrong wiring or direction.
                if io.capture_counts[i][end.other() as usize] != seen[end.other() as usize] {
                    return Err(Reason::InitWrongSwitch(end.other().switch(i)));
                }
                if io.now_s - since_s > p.search_timeout_s {
                    return Err(Reason::InitTimeout(end.switch(i)));
                }
                let speed = [p.init_speed_mm_s, p.approach_speed_mm_s, p.creep_speed_mm_s][usize::from(stage.min(2))];
                if io.capture_counts[i][end as usize] != seen[end as usize] {
                    let edge = io.captures[i][end as usize];
                    io.setpoints[i] = io.positions[i];
                    io.velocities[i] = 0.0;
                    self.searches[i] = match (stage, end) {
                        (0 | 1, _) => {
                            let back = if stage == 0 {
                                p.approach_distance_mm
                            } else {
                                p.creep_distance_mm
                            };
                            Search::Retreat {
                                end,
                                stage: stage + 1,
                                target: edge - end.direction() * back,
                            }
                        }
                        (_, End::Upper) => {
                            self.edges[i][1] = edge;
                            Search::Seek {
                                end: End::Lower,
                                stage: 0,
                                seen: io.capture_counts[i],
                                since_s: io.now_s,
                            }
                        }
                        (_, End::Lower) => {
                            self.edges[i][0] = edge;
                            Search::Found
                        }
                    };
                } else if stage == 0 && io.switches[end.switch(i)] {
                    // Started on the switch: no edge to see from here; back off first.
                    let target = io.positions[i] - end.direction() * p.approach_distance_mm;
                    self.searches[i] = Search::Retreat { end, stage: 0, target };
                } else {
                    io.velocities[i] = end.direction() * speed;
                }
            }
            Search::Retreat { end, stage, target } => {
                let speed = if stage <= 1 {
                    p.init_speed_mm_s
                } else {
                    p.approach_speed_mm_s
                };
                if io.ramp_to(i, target, speed) && (io.positions[i] - target).abs() < 0.005 {
                    if io.switches[end.switch(i)] {
                        // Still on the switch: back off further.
                        let target = target - end.direction() * p.approach_distance_mm;
                        self.searches[i] = Search::Retreat { end, stage, target };
                    } else {
                        self.searches[i] = Search::Seek {
                            end,
                            stage,
                            seen: io.capture_counts[i],
                            since_s: io.now_s,
                        };
                    }
                }
            }
            // Only this drive waits: holding both here would freeze the other drive's search
            // every cycle whenever this one finished first (an asymmetric start).
            Search::Found => io.velocities[i] = 0.0,
            Search::ToStart { target } => {
                if io.ramp_to(i, target, p.init_speed_mm_s) && (io.positions[i] - target).abs() < 0.01 {
                    self.searches[i] = Search::Done;
                }
            }
            Search::Done => io.velocities[i] = 0.0,
        }
        Ok(())
    }

    /// Both drives' switches are known: set the references (0 mm at the lower switches), the
    /// software limits, and send the carriages to their start positions.
    pub(super) fn finish_referencing(&mut self, io: &mut Io) {
        let travel = self.edges.map(|[lower, upper]| upper - lower);
        for (i, [lower, _]) in self.edges.iter().enumerate() {
            io.references[i] = *lower;
            // The set-points move into the referenced frame with the positions.
            io.setpoints[i] -= lower;
        }
        io.referenced = true;
        let m = self.p.soft_limit_margin_mm;
        let limits = Trijoint::new(&TrijointParams {
            h1_travel: [m, travel[0] - m],
            h2_travel: [m, travel[1] - m],
            ..self.geometry.clone()
        });
        // Where the programs were planned from, not the middle of the travel just measured: the
        // edges a link captures differ from run to run by micrometres, and a program starts
        // only where it was planned from (a start 1.4 µm away was refused).
        let start = self.p.start_position(&self.geometry);
        let mut pose = [0.0; 2];
        if limits.forward(&start, None, &mut pose).is_ok() {
            self.m_setpoint = pose;
        }
        self.limits = Some(limits);
        self.soft = travel.map(|t| [m, t - m]);
        self.searches = [0, 1].map(|i| Search::ToStart { target: start[i] });
    }
}
