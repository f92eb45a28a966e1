//! The modal settings a block changes, each group as LinuxCNC converts it: feed and spindle speed
//! (F, S), the spindle (M3 M4 M5), the coolant (M7 M8 M9), the dwell (G4), the plane (G17 G18 G19), the units (G20 G21),
//! the work coordinate system (G54 … G59), path control (G61 G64), the distance modes (G90 G91,
//! G90.1 G91.1), the canned cycles' retract (G98 G99), and the program stops (M0 M1 M2 M30).

use crate::NcError;
use crate::lexer::Word;

use super::block::{Action, Blend, Block, MAX_DWELL_S, MAX_SPINDLE_RPM, MIN_FEED, Plane, Spindle};
use super::state::{FeedMode, State};
use super::words::{Words, g_refusal};

impl State<'_> {
    /// Checks the feed (F, set with the units and the feed mode below) and sets the spindle
    /// speed (S).
    pub(super) fn feed_and_speed(&mut self, words: &Words<'_>) -> Result<(), NcError> {
        let line = words.line;
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        if let Some(w) = words.get('F')
            && !(w.value.is_finite() && w.value > 0.0)
        {
            return Err(at(w, format!("the feed F must be positive, got {}", w.value)));
        }
        // The feed mode this block's F is read in.
        let mode = [
            (930, FeedMode::InverseTime),
            (940, FeedMode::PerMinute),
            (950, FeedMode::PerRevolution),
        ]
        .into_iter()
        .find(|(code, _)| words.has_g(*code))
        .map_or(self.feed_mode, |(_, mode)| mode);
        // Per minute, a feed below MIN_FEED is refused (a typing error, F.01 for F10, would run
        // for days); per revolution it is the product with S that is bounded (at the move); in
        // inverse time the move's feed is raised to MIN_FEED, as LinuxCNC 2.9 raises it.
        if let Some(w) = words.get('F')
            && mode == FeedMode::PerMinute
            && w.value < MIN_FEED
        {
            return Err(at(
                w,
                format!(
                    "the feed F must be at least {MIN_FEED} units/min (slower, a millimetre takes hours), got {}",
                    w.value
                ),
            ));
        }
        if let Some(w) = words.get('S') {
            if !(w.value.is_finite() && w.value >= 0.0) {
                return Err(at(
                    w,
                    format!("the spindle speed S must be zero or positive, got {}", w.value),
                ));
            }
            if w.value > MAX_SPINDLE_RPM {
                return Err(at(
                    w,
                    format!(
                        "the spindle speed S must be at most {MAX_SPINDLE_RPM} rpm, got {}",
                        w.value
                    ),
                ));
            }
            self.speed_rpm = w.value;
        }
        Ok(())
    }

    /// Switches the spindle (M3, M4, M5) at the speed in force.
    pub(super) fn spindle(&self, words: &Words<'_>, out: &mut Vec<Block>) {
        let line = words.line;
        for (code, _) in &words.m {
            let direction = match code {
                30 => Spindle::Clockwise,
                40 => Spindle::CounterClockwise,
                50 => Spindle::Off,
                _ => continue,
            };
            out.push(Block {
                line,
                column: 1,
                action: Action::Spindle {
                    direction,
                    speed_rpm: self.speed_rpm,
                },
            });
        }
    }

    /// Switches the coolant: M7 mist on, M8 flood on, M9 both off.
    pub(super) fn coolant(&mut self, words: &Words<'_>, out: &mut Vec<Block>) {
        let (mut mist, mut flood) = self.coolant;
        for (code, _) in &words.m {
            match code {
                70 => mist = true,
                80 => flood = true,
                90 => (mist, flood) = (false, false),
                _ => continue,
            }
            out.push(Block {
                line: words.line,
                column: 1,
                action: Action::Coolant { mist, flood },
            });
        }
        self.coolant = (mist, flood);
    }

    /// Dwells (G4 P seconds).
    pub(super) fn dwell(&self, words: &Words<'_>, out: &mut Vec<Block>) -> Result<(), NcError> {
        let line = words.line;
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        if let Some(w) = words.g_word(40) {
            let p = words
                .get('P')
                .ok_or_else(|| at(w, "G4 needs P, the dwell in seconds".into()))?;
            if !(p.value.is_finite() && p.value >= 0.0) {
                return Err(at(
                    p,
                    format!("the dwell P must be zero or positive seconds, got {}", p.value),
                ));
            }
            if p.value > MAX_DWELL_S {
                return Err(at(
                    p,
                    format!("the dwell P must be at most {MAX_DWELL_S} s (a day), got {}", p.value),
                ));
            }
            out.push(Block {
                line,
                column: 1,
                action: Action::Dwell(p.value),
            });
        }
        Ok(())
    }

    /// Sets the feed mode and the feed (in the units in force before the block), the plane, the
    /// units, the work coordinate system, path control, the distance modes and the canned cycles' retract.
    pub(super) fn modes(&mut self, words: &Words<'_>) -> Result<(), NcError> {
        let line = words.line;
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        // The feed mode first (a change forgets the feed, as LinuxCNC sets it to zero), then F
        // in it: in G93 a move's own, not modal; otherwise in the units in force before the
        // block's G20 or G21, which LinuxCNC sets after the feed.
        for (code, mode) in [
            (930, FeedMode::InverseTime),
            (940, FeedMode::PerMinute),
            (950, FeedMode::PerRevolution),
        ] {
            if words.has_g(code) && self.feed_mode != mode {
                self.feed_mode = mode;
                self.feed_mm_min = None;
            }
        }
        if let Some(w) = words.g_word(950)
            && self.per_revolution.is_none()
        {
            self.per_revolution = Some((line, w.column));
        }
        self.inverse_time = None;
        if let Some(w) = words.get('F') {
            if self.feed_mode == FeedMode::InverseTime {
                self.inverse_time = Some(w.value);
            } else {
                self.feed_mm_min = Some(w.value * self.unit());
            }
        }
        for (code, w) in &words.g {
            let plane = match code {
                170 => Plane::Xy,
                180 => Plane::Zx,
                190 => Plane::Yz,
                _ => continue,
            };
            if plane != self.plane {
                self.refuse_while_compensating(line, w, "the plane cannot change")?;
            }
            self.plane = plane;
        }
        if words.has_g(200) {
            self.inches = true;
        }
        if words.has_g(210) {
            self.inches = false;
        }
        // Cutter compensation: after the plane and the units, before the offsets and the
        // modes it fixes while on (LinuxCNC's order).
        self.compensation(words)?;
        for (code, w) in &words.g {
            if (540..=590).contains(code) && code.is_multiple_of(10) {
                self.refuse_while_compensating(line, w, "the coordinate system cannot change")?;
                self.system = usize::from(code / 10 - 54);
            }
        }
        for (code, w) in &words.g {
            match code {
                610 | 611 | 640 => self.refuse_while_compensating(line, w, "path control (G61, G64) cannot change")?,
                980 | 990 => {
                    self.refuse_while_compensating(line, w, "the canned cycles' retract (G98, G99) cannot change")?
                }
                _ => {}
            }
        }
        if let Some((code, w)) = words
            .g
            .iter()
            .find(|(c, _)| (540..=590).contains(c) && !c.is_multiple_of(10))
        {
            return Err(at(w, g_refusal(*code)));
        }
        // G61 and G61.1 (exact path: the same here, as every move follows its programmed path).
        if words.has_g(610) || words.has_g(611) {
            self.blend = Blend::ExactStop;
        }
        if words.has_g(640) {
            // P0, and a negative P (LinuxCNC reads P-1 so), is G64 without P: no tolerance.
            let tolerance = words.get('P').map(|p| p.value * self.unit()).filter(|p| *p > 0.0);
            let merge = match words.get('Q') {
                Some(q) if q.value < 0.0 => {
                    return Err(at(
                        q,
                        format!("the merging tolerance Q must be zero or positive, got {}", q.value),
                    ));
                }
                Some(q) => Some(q.value * self.unit()).filter(|q| *q > 0.0),
                // Without Q, LinuxCNC's naive CAM tolerance is P (rs274 prints
                // SET_NAIVECAM_TOLERANCE(P) after G64 P): a CAM post's short lines within P of
                // one straight line run as that line.
                None => tolerance,
            };
            self.blend = Blend::Within { tolerance, merge };
        }
        if words.has_g(901) {
            self.arc_absolute = true;
        }
        if words.has_g(911) {
            self.arc_absolute = false;
        }
        if words.has_g(900) {
            self.incremental = false;
        }
        if words.has_g(910) {
            self.incremental = true;
        }
        if words.has_g(980) {
            self.retract_to_r = false;
        }
        if words.has_g(990) {
            self.retract_to_r = true;
        }
        Ok(())
    }
}

impl State<'_> {
    /// The feed of a feed move `length` long (mm, or degrees where only rotations move) in the
    /// feed mode in force (mm/min): F in G94; `length`·F in G93 (the move takes 1/F minutes, F
    /// in this block); F·S in G95, at the programmed spindle speed (the machine has no spindle
    /// encoder to follow). `first`: where a missing feed is reported; `what`: the move's name.
    pub(super) fn feed_of(&self, length: f64, first: &Word, line: usize, what: &str) -> Result<f64, NcError> {
        let at = |message: String| NcError::new(line, first.column, message);
        match self.feed_mode {
            FeedMode::PerMinute => self
                .feed_mm_min
                .ok_or_else(|| at(format!("no feed rate: an F word is needed before the first {what}"))),
            FeedMode::InverseTime => {
                let f = self.inverse_time.ok_or_else(|| {
                    at(format!(
                        "in inverse time (G93) every {what} needs F in its own block: the move takes 1/F minutes"
                    ))
                })?;
                Ok((length * f).max(MIN_FEED * self.unit()))
            }
            FeedMode::PerRevolution => {
                let per_rev = self.feed_mm_min.ok_or_else(|| {
                    at(format!(
                        "no feed rate: an F word (per revolution, G95) is needed before the first {what}"
                    ))
                })?;
                if self.speed_rpm <= 0.0 {
                    return Err(at(format!(
                        "with the spindle speed S at 0, {what} cannot feed per revolution (G95): set S first"
                    )));
                }
                let feed = per_rev * self.speed_rpm;
                if feed < MIN_FEED * self.unit() {
                    return Err(at(format!(
                        "per revolution (G95) the feed is F × S = {feed:.4} mm/min: it must be at least {MIN_FEED} units/min (slower, a millimetre takes hours)"
                    )));
                }
                Ok(feed)
            }
        }
    }
}

/// The program stops of a block (M0, M1, M2, M30), after its motion.
pub(super) fn stops(line: usize, m: &[(u16, &Word)], out: &mut Vec<Block>) {
    for (code, _) in m {
        match code {
            0 | 10 => out.push(Block {
                line,
                column: 1,
                action: Action::Pause { optional: *code == 10 },
            }),
            20 | 300 => out.push(Block {
                line,
                column: 1,
                action: Action::End,
            }),
            _ => {}
        }
    }
}
