//! The interpreter: RS274NGC's modal state applied block by block, in LinuxCNC's order of
//! execution, each block becoming at most a few [`Block`]s in the machine's world coordinates.
//!
//! Supported (motion.md): G0 G1 G2 G3 (centre by I J K, incremental as in LinuxCNC, or by R;
//! helical with the axis normal to the plane; P full turns), G4 P (dwell, s), G17 G18 G19,
//! G20 G21, G53 (machine coordinates, this block), G54–G59 (work offsets), G61, G64 \[P\], G90 G91,
//! G92, the canned cycles G81 G82 G83 with G98 G99 and G80, F (per minute), S, M0 M1 M2 M30 M3
//! M4 M5, N, axis words X Y Z and A B C (degrees) as far as the machine has them; parameters,
//! expressions and O-words ([`crate::flow`]). Everything else is refused with its line, column
//! and reason.

use crate::NcError;
use crate::budget::{Bounds, Cost, Unwatched, Watch};
use crate::flow::{self, Event, Flow};
use crate::lexer::{self, Word};

/// A pose in the machine's world coordinates: x y z (mm), a b c (degrees); the machine's
/// coordinates first, unused ones zero.
pub type Pose = [f64; 6];

/// The letters of the pose's coordinates, in [`Pose`] order.
pub const AXES: [char; 6] = ['X', 'Y', 'Z', 'A', 'B', 'C'];

/// The slowest feed accepted (program units per minute): slower, a millimetre takes hours and a
/// typing error (F.01 for F10) runs for days.
pub const MIN_FEED: f64 = 0.1;
/// The longest dwell accepted (s): a day.
pub const MAX_DWELL_S: f64 = 86_400.0;
/// The fastest spindle speed accepted (rpm).
pub const MAX_SPINDLE_RPM: f64 = 100_000.0;

/// The plane of arcs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Plane {
    /// G17: X–Y, arcs about Z.
    Xy,
    /// G18: Z–X, arcs about Y.
    Zx,
    /// G19: Y–Z, arcs about X.
    Yz,
}

impl Plane {
    /// The indices of the plane's first and second axis and of its normal, in [`Pose`] order.
    pub fn axes(self) -> [usize; 3] {
        match self {
            Plane::Xy => [0, 1, 2],
            Plane::Zx => [2, 0, 1],
            Plane::Yz => [1, 2, 0],
        }
    }

    /// The offset letters of the plane's centre (I J, K I, J K).
    fn offsets(self) -> [char; 2] {
        match self {
            Plane::Xy => ['I', 'J'],
            Plane::Zx => ['K', 'I'],
            Plane::Yz => ['J', 'K'],
        }
    }
}

/// The path of a move.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Path {
    /// A straight line in world coordinates.
    Line,
    /// An arc (a helix when the normal coordinate changes too).
    Arc {
        /// Its plane.
        plane: Plane,
        /// Its centre in the plane's two axes (machine coordinates, mm).
        center: [f64; 2],
        /// G2 (clockwise, looking down the normal) or G3.
        clockwise: bool,
        /// Full turns beyond the first (P − 1).
        extra_turns: u32,
    },
}

/// How a move ends.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Blend {
    /// G61: at rest at its end point.
    ExactStop,
    /// G64: blended into the next move, within `tolerance` of the corner (mm; `None`:
    /// within [`crate::plan::PLAIN_G64_MM`] — LinuxCNC's G64 without P, with P0 or P-1); lines
    /// that deviate less than `merge` (mm, G64 Q: LinuxCNC's naive CAM detector) from one
    /// straight line are run as that line.
    Within {
        /// The largest distance from a corner (G64 P).
        tolerance: Option<f64>,
        /// The deviation within which consecutive lines merge (G64 Q).
        merge: Option<f64>,
    },
}

/// The spindle's direction.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Spindle {
    /// M3.
    Clockwise,
    /// M4.
    CounterClockwise,
    /// M5.
    Off,
}

/// What a block does.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Action {
    /// A move from `from` to `to`.
    Move {
        /// Where it starts (machine world coordinates).
        from: Pose,
        /// Where it ends.
        to: Pose,
        /// Its path.
        path: Path,
        /// Its feed (mm/min along the path); `None` for a rapid (G0).
        feed_mm_min: Option<f64>,
        /// How it ends.
        blend: Blend,
    },
    /// G4: stand still this long (s).
    Dwell(f64),
    /// M0 (`optional` false) or M1: stop until resumed.
    Pause {
        /// M1, the optional stop.
        optional: bool,
    },
    /// M3/M4/M5 with the speed (S, rpm) in force.
    Spindle {
        /// The direction.
        direction: Spindle,
        /// The speed (rpm).
        speed_rpm: f64,
    },
    /// M2/M30: the end of the program.
    End,
}

/// An action and the program line it comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Block {
    /// The line (1-based).
    pub line: usize,
    /// What it does.
    pub action: Action,
}

/// What the interpreter needs to know of the machine.
#[derive(Clone, Debug)]
pub struct Machine<'a> {
    /// The machine's world coordinates (`x`, `y`, `z`, `a`, `b`, `c`, as the kinematics name
    /// them), in [`Pose`] order.
    pub axes: &'a [&'a str],
    /// Where the tool is when the program starts (machine world coordinates).
    pub start: Pose,
    /// The work offsets of G54 … G59 (machine coordinates of each system's origin).
    pub work_offsets: [Pose; 6],
    /// The block-delete switch: on, lines starting with `/` are skipped; off (LinuxCNC's
    /// default), they run.
    pub block_delete: bool,
}

/// A program read into blocks.
#[derive(Clone, Debug, PartialEq)]
pub struct Program {
    /// Its actions, in order.
    pub blocks: Vec<Block>,
}

/// Tolerance of an arc's end point off its circle (mm): LinuxCNC's default for mm programs.
const ARC_TOLERANCE_MM: f64 = 0.002;
/// … or this fraction of the radius, whichever is larger.
const ARC_TOLERANCE_RELATIVE: f64 = 0.001;

/// Reads `text` for `machine` within the default [`Bounds`]; the first problem is returned with
/// its position.
pub fn read(text: &str, machine: &Machine<'_>) -> Result<Program, NcError> {
    read_bounded(text, machine, &Bounds::default(), &Unwatched)
}

/// Reads `text` for `machine`; the first problem is returned with its position. The program is
/// refused at the line where its moves or the memory of its plan pass `bounds`, and stops with
/// `watch`'s reason when the watch says so.
pub fn read_bounded(text: &str, machine: &Machine<'_>, bounds: &Bounds, watch: &dyn Watch) -> Result<Program, NcError> {
    let mut state = State::new(machine);
    state.bounds = *bounds;
    let mut blocks = Vec::new();
    let mut flow = Flow::new(text, machine.block_delete).watched(watch);
    // A '%' before any other line opens the program, and the next closes it; without it the
    // program ends at M2 or M30. What follows the end is never read (LinuxCNC ignores it).
    let (mut seen, mut opened) = (false, false);
    loop {
        match flow.next(&state)? {
            Event::Percent(number) => {
                if !seen {
                    opened = true;
                } else if opened {
                    blocks.push(Block {
                        line: number,
                        action: Action::End,
                    });
                    break;
                } else {
                    return Err(NcError::new(
                        number,
                        1,
                        "'%' opens a program only on its first line (and then closes it)".to_string(),
                    ));
                }
            }
            Event::Block(block) => {
                let before = blocks.len();
                state.block(&block, &mut blocks)?;
                for made in &blocks[before..] {
                    state.cost.add(made);
                }
                if let Some(why) = state.cost.beyond(bounds) {
                    return Err(NcError::new(block.line, 1, why));
                }
                if matches!(
                    blocks.last(),
                    Some(Block {
                        action: Action::End,
                        ..
                    })
                ) {
                    break;
                }
            }
            Event::End(last_line) => {
                if let Some(open) = flow.unclosed() {
                    return Err(open);
                }
                return Err(NcError::new(
                    last_line,
                    1,
                    if opened {
                        "the file ended without the closing '%' (or M2, M30): is the program complete?"
                    } else {
                        "the file ended with no program end (M2, M30) and no '%' delimiters: is the program complete?"
                    },
                ));
            }
        }
        seen = true;
    }
    // Grown by doubling: the memory past the last block is given back.
    blocks.shrink_to_fit();
    Ok(Program { blocks })
}

/// The modal state.
struct State<'a> {
    machine: &'a Machine<'a>,
    /// What the program may cost, and what its blocks so far cost.
    bounds: Bounds,
    cost: Cost,
    /// The tool's position (machine world coordinates).
    position: Pose,
    /// The motion mode (G code in tenths: 0, 10, 20, 30, 810, 820, 830).
    motion: Option<u16>,
    plane: Plane,
    inches: bool,
    incremental: bool,
    /// The work coordinate system in force (0 = G54).
    system: usize,
    /// G92's offset.
    g92: Pose,
    feed_mm_min: Option<f64>,
    speed_rpm: f64,
    blend: Blend,
    /// G90.1: an arc's I J K are absolute program coordinates (G91.1, the default: offsets from
    /// its start).
    arc_absolute: bool,
    /// G99 (the default, as LinuxCNC's): a canned cycle retracts to its R plane; G98: to where
    /// the first cycle of a series started, if that is higher.
    retract_to_r: bool,
    /// The canned cycle's values that carry to the next block of the same cycle.
    cycle: Cycle,
    /// The height (normal coordinate, program units) where the present series of canned
    /// cycles started; `None` after any other motion.
    cycle_initial: Option<f64>,
}

/// A canned cycle's values as its last block gave them (program units, as written: in G91, R
/// from the initial level and Z from R).
#[derive(Clone, Copy, Debug, Default)]
struct Cycle {
    r: f64,
    bottom: f64,
    dwell: f64,
    peck: f64,
}

/// How far above the bottom of the last peck a G83 rapid returns (mm): LinuxCNC 2.9's
/// `G83_RAPID_DELTA`, 0.010 inch.
const PECK_CLEARANCE_MM: f64 = 0.254;

/// The modal groups of the supported G codes (RS274NGC's numbering), for the one-per-group rule.
fn g_group(code: u16) -> Option<u8> {
    match code {
        0 | 10 | 20 | 30 | 800 | 810 | 820 | 830 => Some(1),
        40 => Some(0),
        170 | 180 | 190 => Some(2),
        200 | 210 => Some(6),
        530 | 920 => Some(0),
        540..=590 => Some(12),
        610 | 611 | 640 => Some(13),
        900 | 910 => Some(3),
        901 | 911 => Some(4),
        940 => Some(5),
        400 => Some(7),
        490 => Some(8),
        980 | 990 => Some(10),
        _ => None,
    }
}

/// Why a G code is not in the subset.
fn g_refusal(code: u16) -> String {
    let name = format_code('G', code);
    let why = match code {
        50..=52 | 70 | 80 => "lathe and spline modes",
        100 | 110 => "G10/G11 (tables, retraction)",
        280..=309 => "going home through an intermediate point",
        330 | 331 | 760 => "threading",
        382..=385 => "probing",
        400..=429 => "cutter compensation",
        430..=499 => "tool length compensation",
        730..=899 => "canned cycles other than G81, G82, G83",
        921..=923 => "G92 variants",
        930 | 950 => "feed modes other than units per minute",
        960 | 970 => "spindle speed modes",
        _ => "",
    };
    if why.is_empty() {
        format!("{name} is not supported")
    } else {
        format!("{name} is not supported ({why})")
    }
}

/// A word that counts (an arc's turns, a cycle's repeats): a whole number from 1 to `max`, 1
/// where the block has none; the word when it is not such a number.
fn count(word: Option<&Word>, max: u32) -> Result<u32, &Word> {
    match word {
        None => Ok(1),
        Some(w) if w.value >= 1.0 && w.value.fract() == 0.0 && w.value <= f64::from(max) => Ok(w.value as u32),
        Some(w) => Err(w),
    }
}

/// The program stops of a block (M0, M1, M2, M30), after its motion.
fn stops(line: usize, m: &[(u16, &Word)], out: &mut Vec<Block>) {
    for (code, _) in m {
        match code {
            0 | 10 => out.push(Block {
                line,
                action: Action::Pause { optional: *code == 10 },
            }),
            20 | 300 => out.push(Block {
                line,
                action: Action::End,
            }),
            _ => {}
        }
    }
}

/// `G1`, `G64`, `G92.1` from a code in tenths.
fn format_code(letter: char, code: u16) -> String {
    if code.is_multiple_of(10) {
        format!("{letter}{}", code / 10)
    } else {
        format!("{letter}{}.{}", code / 10, code % 10)
    }
}

/// The state as LinuxCNC's system parameters give it, in program units.
impl flow::System for State<'_> {
    fn numbered(&self, index: usize) -> Option<f64> {
        let position = self.program_position();
        match index {
            // G92's offsets.
            5211..=5216 => Some(self.g92[index - 5211] / self.scale(index - 5211)),
            // The coordinate system in force, 1 for G54.
            5220 => Some((self.system + 1) as f64),
            // G54 … G59's origins, 20 parameters per system (X Y Z A B C first).
            5221..=5326 if (index - 5221) % 20 < 6 => {
                let (system, c) = ((index - 5221) / 20, (index - 5221) % 20);
                Some(self.machine.work_offsets[system][c] / self.scale(c))
            }
            // The tool's position in the coordinate system in force.
            5420..=5425 => Some(position[index - 5420]),
            _ => None,
        }
    }

    fn named(&self, name: &str) -> Option<f64> {
        let truth = |b: bool| if b { 1.0 } else { 0.0 };
        let position = self.program_position();
        Some(match name {
            "_x" | "_y" | "_z" | "_a" | "_b" | "_c" => {
                let c = AXES
                    .iter()
                    .position(|a| name[1..].eq_ignore_ascii_case(&a.to_string()))?;
                position[c]
            }
            "_feed" => self.feed_mm_min.map_or(0.0, |f| f / self.unit()),
            "_rpm" => self.speed_rpm,
            "_metric" => truth(!self.inches),
            "_imperial" => truth(self.inches),
            "_absolute" => truth(!self.incremental),
            "_incremental" => truth(self.incremental),
            "_coord_system" => 540.0 + 10.0 * self.system as f64,
            "_motion_mode" => f64::from(self.motion.unwrap_or(800)),
            "_plane" => match self.plane {
                Plane::Xy => 170.0,
                Plane::Zx => 180.0,
                Plane::Yz => 190.0,
            },
            _ => return None,
        })
    }
}

impl<'a> State<'a> {
    fn new(machine: &'a Machine<'a>) -> State<'a> {
        State {
            machine,
            bounds: Bounds::default(),
            cost: Cost::default(),
            position: machine.start,
            motion: None,
            plane: Plane::Xy,
            inches: false,
            incremental: false,
            system: 0,
            g92: [0.0; 6],
            feed_mm_min: None,
            speed_rpm: 0.0,
            arc_absolute: false,
            retract_to_r: true,
            cycle: Cycle::default(),
            cycle_initial: None,
            blend: Blend::Within {
                tolerance: None,
                merge: None,
            },
        }
    }

    /// mm per program length unit.
    fn unit(&self) -> f64 {
        if self.inches { 25.4 } else { 1.0 }
    }

    /// The offset from program to machine coordinates now.
    fn offset(&self) -> Pose {
        let w = self.machine.work_offsets[self.system];
        std::array::from_fn(|c| w[c] + self.g92[c])
    }

    /// Machine units (mm, degrees) per program unit of coordinate `c`.
    fn scale(&self, c: usize) -> f64 {
        if c < 3 { self.unit() } else { 1.0 }
    }

    /// The tool's position in program coordinates and units.
    fn program_position(&self) -> Pose {
        let offset = self.offset();
        std::array::from_fn(|c| (self.position[c] - offset[c]) / self.scale(c))
    }

    /// Machine coordinates of a point given in program coordinates and units.
    fn machine_position(&self, program: &Pose) -> Pose {
        let offset = self.offset();
        std::array::from_fn(|c| program[c] * self.scale(c) + offset[c])
    }

    fn block(&mut self, block: &lexer::Block, out: &mut Vec<Block>) -> Result<(), NcError> {
        let line = block.line;
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        // Sort the words, refusing what the subset lacks and what a block may not hold twice.
        let mut g: Vec<(u16, &Word)> = Vec::new();
        let mut m: Vec<(u16, &Word)> = Vec::new();
        let mut values: [Option<&Word>; 26] = [None; 26];
        for (i, w) in block.words.iter().enumerate() {
            match w.letter {
                'G' | 'M' => {
                    let tenths = w.value * 10.0;
                    if !(0.0..=9999.0).contains(&tenths) || (tenths - tenths.round()).abs() > 1e-6 {
                        return Err(at(w, format!("{}{} is not a code", w.letter, w.value)));
                    }
                    let code = tenths.round() as u16;
                    if w.letter == 'G' {
                        let group = g_group(code).ok_or_else(|| at(w, g_refusal(code)))?;
                        if let Some((other, _)) = g.iter().find(|(c, _)| g_group(*c) == Some(group) && group != 0) {
                            return Err(at(
                                w,
                                format!(
                                    "{} and {} are in one modal group: a block holds one of them",
                                    format_code('G', *other),
                                    format_code('G', code)
                                ),
                            ));
                        }
                        if g.iter().any(|(c, _)| *c == code) {
                            return Err(at(w, format!("{} twice in one block", format_code('G', code))));
                        }
                        g.push((code, w));
                    } else {
                        let group = match code {
                            0 | 10 | 20 | 300 => 4,
                            30 | 40 | 50 => 7,
                            _ => {
                                let why = match code {
                                    60 => " (tool changes)",
                                    70..=90 => " (coolant)",
                                    480..=530 => " (overrides)",
                                    600..=990 => " (subprograms, user codes)",
                                    1000..=1999 => " (user-defined M codes)",
                                    _ => "",
                                };
                                return Err(at(w, format!("{} is not supported{why}", format_code('M', code))));
                            }
                        };
                        if let Some((other, _)) = m.iter().find(|(c, _)| {
                            let og = if matches!(c, 0 | 10 | 20 | 300) { 4 } else { 7 };
                            og == group
                        }) {
                            return Err(at(
                                w,
                                format!(
                                    "{} and {} are in one modal group: a block holds one of them",
                                    format_code('M', *other),
                                    format_code('M', code)
                                ),
                            ));
                        }
                        m.push((code, w));
                    }
                }
                'N' => {
                    if i != 0 {
                        return Err(at(w, "a line number (N) comes first in its block".into()));
                    }
                }
                'X' | 'Y' | 'Z' | 'A' | 'B' | 'C' | 'I' | 'J' | 'K' | 'R' | 'F' | 'S' | 'P' | 'Q' | 'L' => {
                    let slot = &mut values[(w.letter as u8 - b'A') as usize];
                    if slot.is_some() {
                        return Err(at(w, format!("{} twice in one block", w.letter)));
                    }
                    *slot = Some(w);
                }
                'T' => return Err(at(w, "tool selection (T) is not supported".into())),
                'D' | 'H' => return Err(at(w, format!("{} (tool compensation) is not supported", w.letter))),
                'E' => return Err(at(w, "E (extruders) is not supported".into())),
                'U' | 'V' | 'W' => {
                    return Err(at(w, format!("{}: axes U V W are not supported", w.letter)));
                }
                other => return Err(at(w, format!("{other} is not a word of RS274NGC"))),
            }
        }
        let get = |letter: char| values[(letter as u8 - b'A') as usize];
        let has_g = |code: u16| g.iter().any(|(c, _)| *c == code);
        // Axis words the machine does not have.
        for (c, letter) in AXES.iter().enumerate() {
            if let Some(w) = get(*letter)
                && !self
                    .machine
                    .axes
                    .get(c)
                    .is_some_and(|k| k.eq_ignore_ascii_case(&letter.to_string()))
            {
                let axes: Vec<String> = self.machine.axes.iter().map(|a| a.to_uppercase()).collect();
                return Err(at(w, format!("{letter}: this machine's axes are {}", axes.join(" "))));
            }
        }
        // In LinuxCNC's order of execution: feed, speed, spindle, dwell, plane, units, work
        // offsets, path control, distance mode, G92, motion, stop.
        if let Some(w) = get('F')
            && !(w.value.is_finite() && w.value > 0.0)
        {
            return Err(at(w, format!("the feed F must be positive, got {}", w.value)));
        }
        if let Some(w) = get('F')
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
        if let Some(w) = get('S') {
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
        for (code, _) in &m {
            let direction = match code {
                30 => Spindle::Clockwise,
                40 => Spindle::CounterClockwise,
                50 => Spindle::Off,
                _ => continue,
            };
            out.push(Block {
                line,
                action: Action::Spindle {
                    direction,
                    speed_rpm: self.speed_rpm,
                },
            });
        }
        // P belongs to G4, G64, an arc or G82; Q to G64 or G83; I, J, K to an arc; R to an arc
        // or a canned cycle, L to a canned cycle.
        let motion_word = g
            .iter()
            .find(|(c, _)| matches!(c, 0 | 10 | 20 | 30 | 810 | 820 | 830))
            .map(|(c, w)| (*c, *w));
        let has_axis_word = AXES.iter().any(|a| get(*a).is_some());
        // The motion this block makes, if any.
        let motion_now = match motion_word {
            Some((c, _)) => Some(c),
            None if has_axis_word && !has_g(800) => self.motion,
            None => None,
        };
        let arc_now = matches!(motion_now, Some(20 | 30));
        let cycle_now = matches!(motion_now, Some(810 | 820 | 830));
        if let Some(w) = get('P')
            && !(has_g(40) || has_g(640) || arc_now || motion_now == Some(820))
        {
            return Err(at(
                w,
                "P belongs to G4 (dwell), G64 (tolerance), an arc (turns) or G82 (dwell)".into(),
            ));
        }
        if let Some(w) = get('Q')
            && !(has_g(640) || motion_now == Some(830))
        {
            return Err(at(
                w,
                "Q belongs to G64 (merging lines within it) or G83 (the peck depth)".into(),
            ));
        }
        for letter in ['I', 'J', 'K'] {
            if let Some(w) = get(letter)
                && !arc_now
            {
                return Err(at(w, format!("{letter} belongs to an arc (G2, G3)")));
            }
        }
        if let Some(w) = get('R')
            && !(arc_now || cycle_now)
        {
            return Err(at(
                w,
                "R belongs to an arc (G2, G3) or a canned cycle (G81 … G83)".into(),
            ));
        }
        if let Some(w) = get('L')
            && !cycle_now
        {
            return Err(at(
                w,
                "L belongs to a canned cycle (its repeats); G10 tables are not supported".into(),
            ));
        }
        let g_word = |code: u16| g.iter().find(|(c, _)| *c == code).map(|(_, w)| *w);
        if let Some(w) = g_word(40) {
            let p = get('P').ok_or_else(|| at(w, "G4 needs P, the dwell in seconds".into()))?;
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
                action: Action::Dwell(p.value),
            });
        }
        for (code, _) in &g {
            match code {
                170 => self.plane = Plane::Xy,
                180 => self.plane = Plane::Zx,
                190 => self.plane = Plane::Yz,
                200 => self.inches = true,
                210 => self.inches = false,
                540..=590 if code.is_multiple_of(10) => self.system = usize::from(code / 10 - 54),
                _ => {}
            }
        }
        if let Some((code, w)) = g.iter().find(|(c, _)| (540..=590).contains(c) && !c.is_multiple_of(10)) {
            return Err(at(w, g_refusal(*code)));
        }
        if let Some(w) = get('F') {
            self.feed_mm_min = Some(w.value * self.unit());
        }
        // G61 and G61.1 (exact path: the same here, as every move follows its programmed path).
        if has_g(610) || has_g(611) {
            self.blend = Blend::ExactStop;
        }
        if has_g(640) {
            // P0, and a negative P (LinuxCNC reads P-1 so), is G64 without P: no tolerance.
            let tolerance = get('P').map(|p| p.value * self.unit()).filter(|p| *p > 0.0);
            let merge = match get('Q') {
                Some(q) if q.value < 0.0 => {
                    return Err(at(
                        q,
                        format!("the merging tolerance Q must be zero or positive, got {}", q.value),
                    ));
                }
                Some(q) => Some(q.value * self.unit()).filter(|q| *q > 0.0),
                None => None,
            };
            self.blend = Blend::Within { tolerance, merge };
        }
        if has_g(901) {
            self.arc_absolute = true;
        }
        if has_g(911) {
            self.arc_absolute = false;
        }
        if has_g(900) {
            self.incremental = false;
        }
        if has_g(910) {
            self.incremental = true;
        }
        if has_g(980) {
            self.retract_to_r = false;
        }
        if has_g(990) {
            self.retract_to_r = true;
        }
        let axis_words: Vec<(usize, &Word)> = AXES
            .iter()
            .enumerate()
            .filter_map(|(c, l)| get(*l).map(|w| (c, w)))
            .collect();
        // A length in machine units: mm for X Y Z, degrees for A B C.
        let unit = self.unit();
        let scale = |c: usize| if c < 3 { unit } else { 1.0 };
        if let Some(w) = g_word(920) {
            if axis_words.is_empty() {
                return Err(at(
                    w,
                    "G92 needs at least one axis word: the program coordinates the tool is at".into(),
                ));
            }
            // The tool's position reads as the given values from now on.
            let work = self.machine.work_offsets[self.system];
            for (c, w) in &axis_words {
                self.g92[*c] = self.position[*c] - work[*c] - w.value * scale(*c);
            }
        }
        let machine_coords = has_g(530);
        if has_g(800) {
            // G80 (canned cycle cancel) sets no motion mode; CAM programs write it in their
            // preamble.
            if let Some((_, a)) = axis_words.first() {
                return Err(at(
                    a,
                    "axis words cannot go with G80 (it cancels the motion mode; G80 does not)".into(),
                ));
            }
            self.motion = None;
            self.cycle_initial = None;
        }
        let previous_motion = self.motion;
        if let Some((code, _)) = motion_word {
            self.motion = Some(code);
        }
        if cycle_now {
            if let Some(w) = g_word(530) {
                return Err(at(w, "G53 goes with a G0 or G1 move in this block".into()));
            }
            let first = axis_words.first().map_or(&block.words[0], |(_, w)| *w);
            let code = self.motion.unwrap_or_default();
            return self.cycle(line, code, previous_motion, first, &get, &axis_words, &m, out);
        }
        // An arc without axis words but with its centre is a full circle where the tool stands.
        let full_circle = matches!(motion_word, Some((20 | 30, _))) && axis_words.is_empty() && {
            let [o0, o1] = self.plane.offsets();
            get(o0).is_some() || get(o1).is_some()
        };
        let moves = !has_g(920) && (!axis_words.is_empty() || full_circle);
        if let Some(w) = g_word(530) {
            if !matches!(self.motion, Some(0 | 10)) || !moves {
                return Err(at(w, "G53 goes with a G0 or G1 move in this block".into()));
            }
            if self.incremental {
                return Err(at(w, "G53 needs absolute distances (G90)".into()));
            }
        }
        // G0 or G1 alone sets the motion mode for the lines that follow (LinuxCNC's meaning);
        // an arc alone needs its centre.
        if let Some((20 | 30, w)) = motion_word
            && !moves
            && !has_g(920)
        {
            let [o0, o1] = self.plane.offsets();
            return Err(at(
                w,
                format!("an arc needs its centre ({o0} {o1}) or its end and radius (R)"),
            ));
        }
        if moves {
            self.cycle_initial = None;
            let Some(mode) = self.motion else {
                return Err(at(
                    axis_words[0].1,
                    "an axis word needs a motion mode: G0, G1, G2 or G3 first".into(),
                ));
            };
            let offset = self.offset();
            let mut to = self.position;
            for (c, w) in &axis_words {
                let v = w.value * scale(*c);
                to[*c] = if machine_coords {
                    v
                } else if self.incremental {
                    self.position[*c] + v
                } else {
                    v + offset[*c]
                };
            }
            let first = axis_words
                .first()
                .map_or_else(|| motion_word.map(|(_, w)| w).unwrap_or(&block.words[0]), |(_, w)| *w);
            let feed = match mode {
                0 => None,
                _ => Some(self.feed_mm_min.ok_or_else(|| {
                    at(
                        first,
                        "no feed rate: an F word is needed before the first G1, G2 or G3".into(),
                    )
                })?),
            };
            let path = match mode {
                0 | 10 => Path::Line,
                _ => self.arc(line, first, mode == 20, &to, &get)?,
            };
            out.push(Block {
                line,
                action: Action::Move {
                    from: self.position,
                    to,
                    path,
                    feed_mm_min: feed,
                    blend: self.blend,
                },
            });
            self.position = to;
        }
        stops(line, &m, out);
        Ok(())
    }

    /// A canned cycle (G81, G82, G83: `code`) at the block's position, as LinuxCNC's
    /// `convert_cycle_xy` (and its other planes) makes it: up to the R plane if below it, over
    /// the hole, down to R, the cycle, back to the clearance level (R in G99, the series'
    /// starting height in G98); L times. Every move stops exactly at its end.
    #[allow(clippy::too_many_arguments)]
    fn cycle<'w>(
        &mut self,
        line: usize,
        code: u16,
        previous: Option<u16>,
        first: &Word,
        get: &dyn Fn(char) -> Option<&'w Word>,
        axis_words: &[(usize, &Word)],
        m: &[(u16, &Word)],
        out: &mut Vec<Block>,
    ) -> Result<(), NcError> {
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        let name = format_code('G', code);
        let [a0, a1, n] = self.plane.axes();
        if let Some((_, w)) = axis_words.iter().find(|(c, _)| *c >= 3) {
            return Err(at(
                w,
                format!("{name} moves X Y Z only: {} cannot move in a canned cycle", w.letter),
            ));
        }
        let Some(feed) = self.feed_mm_min else {
            return Err(at(first, format!("no feed rate: an F word is needed before {name}")));
        };
        // The values that carry from the cycle's last block when it continues.
        let same = previous == Some(code);
        let normal = AXES[n];
        let carried = |letter: char, last: f64, what: &str| match get(letter) {
            Some(w) => Ok(w.value),
            None if same => Ok(last),
            None => Err(at(first, format!("{name} needs {letter}, {what}"))),
        };
        let r_given = carried('R', self.cycle.r, "the retract plane")?;
        let bottom_given = carried(normal, self.cycle.bottom, "the bottom of the hole")?;
        let dwell = if code == 820 {
            let p = carried('P', self.cycle.dwell, "the dwell at the bottom in seconds")?;
            if !(0.0..=MAX_DWELL_S).contains(&p) {
                return Err(at(
                    get('P').unwrap_or(first),
                    format!("the dwell P must be between 0 and {MAX_DWELL_S} s, got {p}"),
                ));
            }
            p
        } else {
            self.cycle.dwell
        };
        let peck = if code == 830 {
            let q = carried('Q', self.cycle.peck, "the depth of each peck")?;
            if q <= 0.0 {
                return Err(at(
                    get('Q').unwrap_or(first),
                    format!("the peck depth Q must be positive, got {q}"),
                ));
            }
            q
        } else {
            self.cycle.peck
        };
        let repeats = count(get('L'), 10_000).map_err(|l| {
            at(
                l,
                format!(
                    "L, the number of repeats, is a whole number from 1 to 10000, got {}",
                    l.value
                ),
            )
        })?;
        // In program coordinates: a0, a1 the plane's axes, n its normal (Z in G17).
        let mut p = self.program_position();
        let initial = *self.cycle_initial.get_or_insert(p[n]);
        let given = |c: usize| axis_words.iter().find(|(k, _)| *k == c).map(|(_, w)| w.value);
        let (mut aa, mut bb, step, r, bottom);
        if self.incremental {
            step = [given(a0).unwrap_or(0.0), given(a1).unwrap_or(0.0)];
            r = r_given + initial;
            bottom = r + bottom_given;
            (aa, bb) = (p[a0], p[a1]);
        } else {
            step = [0.0, 0.0];
            (r, bottom) = (r_given, bottom_given);
            (aa, bb) = (given(a0).unwrap_or(p[a0]), given(a1).unwrap_or(p[a1]));
        }
        if r < bottom {
            return Err(at(
                get('R').unwrap_or(first),
                format!("{name}: the retract plane R ({r}) is below the bottom {normal} ({bottom})"),
            ));
        }
        let mut old = initial;
        let mut current = p[n];
        let here = [p[a0], p[a1]];
        let feed = Some(feed);
        let mut go = |this: &mut Self, out: &mut Vec<Block>, point: [f64; 3], feed: Option<f64>| {
            (p[a0], p[a1], p[n]) = (point[0], point[1], point[2]);
            let to = this.machine_position(&p);
            // LinuxCNC writes moves that go nowhere (over the hole when the tool is there
            // already); they change nothing.
            if to != this.position {
                out.push(Block {
                    line,
                    action: Action::Move {
                        from: this.position,
                        to,
                        path: Path::Line,
                        feed_mm_min: feed,
                        blend: Blend::ExactStop,
                    },
                });
                this.position = to;
            }
        };
        // Below the R plane: straight up to it first.
        if old < r {
            go(self, out, [here[0], here[1], r], None);
            old = r;
            current = r;
        }
        let clear = if self.retract_to_r { r } else { old };
        let unit = self.unit();
        // A cycle's repeats and pecks make moves before the program's cost is counted: bounded
        // here, so that a tiny Q or a large L cannot fill the memory within one block.
        let (room, max_moves) = (
            self.bounds.max_moves.saturating_sub(self.cost.moves),
            self.bounds.max_moves,
        );
        let full = |out: &Vec<Block>| {
            (out.len() > room).then(|| {
                at(
                    first,
                    format!(
                        "{name}: the cycle makes more than the {max_moves} moves the program may make (the bound: nc.max_moves): fewer repeats L, or a deeper peck Q"
                    ),
                )
            })
        };
        for turn in 0..repeats {
            if let Some(e) = full(out) {
                return Err(e);
            }
            aa += step[0];
            bb += step[1];
            if turn == 0 && current > r {
                go(self, out, [aa, bb, current], None);
                go(self, out, [aa, bb, r], None);
            } else {
                go(self, out, [aa, bb, clear], None);
                if clear > r {
                    go(self, out, [aa, bb, r], None);
                }
            }
            if code == 830 {
                let mut depth = r - peck;
                while depth > bottom {
                    if let Some(e) = full(out) {
                        return Err(e);
                    }
                    go(self, out, [aa, bb, depth], feed);
                    go(self, out, [aa, bb, r], None);
                    go(self, out, [aa, bb, depth + PECK_CLEARANCE_MM / unit], None);
                    depth -= peck;
                }
            }
            go(self, out, [aa, bb, bottom], feed);
            if code == 820 {
                out.push(Block {
                    line,
                    action: Action::Dwell(dwell),
                });
            }
            go(self, out, [aa, bb, clear], None);
        }
        self.cycle = Cycle {
            r: r_given,
            bottom: bottom_given,
            dwell,
            peck,
        };
        stops(line, m, out);
        Ok(())
    }

    /// The arc from the current position to `to`, by its centre (I J K) or radius (R).
    fn arc<'w>(
        &self,
        line: usize,
        first: &Word,
        clockwise: bool,
        to: &Pose,
        get: &dyn Fn(char) -> Option<&'w Word>,
    ) -> Result<Path, NcError> {
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        let [a0, a1, _] = self.plane.axes();
        let (s, e) = ([self.position[a0], self.position[a1]], [to[a0], to[a1]]);
        let turns = count(get('P'), 1000).map_err(|p| {
            at(
                p,
                format!(
                    "an arc's P is its number of turns, a whole number from 1, got {}",
                    p.value
                ),
            )
        })?;
        let [o0, o1] = self.plane.offsets();
        let plane_name = match self.plane {
            Plane::Xy => "G17 (X–Y)",
            Plane::Zx => "G18 (Z–X)",
            Plane::Yz => "G19 (Y–Z)",
        };
        for letter in ['I', 'J', 'K'] {
            if letter != o0
                && letter != o1
                && let Some(w) = get(letter)
            {
                return Err(at(
                    w,
                    format!("{letter} is not an offset of an arc in {plane_name}: use {o0} and {o1}"),
                ));
            }
        }
        let center = match (get('R'), get(o0), get(o1)) {
            (Some(r), None, None) => {
                let radius = r.value * self.unit();
                let chord = [e[0] - s[0], e[1] - s[1]];
                let d = chord[0].hypot(chord[1]);
                if d < 1e-9 {
                    return Err(at(r, "a full circle is given by its centre (I J K), not by R".into()));
                }
                if radius.abs() < d / 2.0 - ARC_TOLERANCE_MM {
                    return Err(at(
                        r,
                        format!(
                            "the radius {} mm is shorter than half the chord ({:.4} mm)",
                            radius.abs(),
                            d / 2.0
                        ),
                    ));
                }
                let h = (radius * radius - d * d / 4.0).max(0.0).sqrt();
                // The centre lies to the left of the chord for a short counter-clockwise arc;
                // a negative R asks for the long arc (more than half a turn).
                let left = !clockwise ^ (radius < 0.0);
                let sign = if left { 1.0 } else { -1.0 };
                let mid = [(s[0] + e[0]) / 2.0, (s[1] + e[1]) / 2.0];
                [mid[0] - sign * h * chord[1] / d, mid[1] + sign * h * chord[0] / d]
            }
            (Some(r), _, _) => return Err(at(r, "an arc has a radius (R) or a centre (I J K), not both".into())),
            (None, None, None) => {
                return Err(at(
                    first,
                    format!("an arc needs its centre ({o0} {o1}) or its radius (R)"),
                ));
            }
            (None, i, j) => {
                let c = if self.arc_absolute {
                    // G90.1: the centre in program coordinates, both of its words given.
                    let (Some(i), Some(j)) = (i, j) else {
                        return Err(at(
                            first,
                            format!("in G90.1 (absolute arc centres) an arc needs both {o0} and {o1}"),
                        ));
                    };
                    let offset = self.offset();
                    [i.value * self.unit() + offset[a0], j.value * self.unit() + offset[a1]]
                } else {
                    [
                        s[0] + i.map_or(0.0, |w| w.value) * self.unit(),
                        s[1] + j.map_or(0.0, |w| w.value) * self.unit(),
                    ]
                };
                let r_start = (s[0] - c[0]).hypot(s[1] - c[1]);
                let r_end = (e[0] - c[0]).hypot(e[1] - c[1]);
                if r_start < 1e-9 {
                    return Err(at(first, "the arc's centre is its start point".into()));
                }
                let tolerance = ARC_TOLERANCE_MM.max(ARC_TOLERANCE_RELATIVE * r_start);
                if (r_start - r_end).abs() > tolerance {
                    return Err(at(
                        first,
                        format!(
                            "the arc's end is not on its circle: radius {r_start:.4} mm at the start, {r_end:.4} mm at the end"
                        ),
                    ));
                }
                c
            }
        };
        Ok(Path::Arc {
            plane: self.plane,
            center,
            clockwise,
            extra_turns: turns - 1,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const XYZ: [&str; 3] = ["x", "y", "z"];
    const XYZABC: [&str; 6] = ["x", "y", "z", "a", "b", "c"];

    fn machine(axes: &'static [&'static str]) -> Machine<'static> {
        let mut work_offsets = [[0.0; 6]; 6];
        work_offsets[1] = [100.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        Machine {
            axes,
            start: [0.0; 6],
            work_offsets,
            block_delete: false,
        }
    }

    /// `text` with an end: a program must end (M2), and what follows an end is never read.
    fn ended(text: &str) -> String {
        format!("{text}\nM2")
    }

    fn run(text: &str) -> Vec<Block> {
        read(&ended(text), &machine(&XYZ))
            .unwrap_or_else(|e| panic!("{e}"))
            .blocks
    }

    fn refused(text: &str) -> String {
        read(&ended(text), &machine(&XYZ)).expect_err("refused").to_string()
    }

    fn moves(blocks: &[Block]) -> Vec<(Pose, Path, Option<f64>)> {
        blocks
            .iter()
            .filter_map(|b| match b.action {
                Action::Move {
                    to, path, feed_mm_min, ..
                } => Some((to, path, feed_mm_min)),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn rapid_and_feed_moves_absolute_incremental_inch_and_modal() {
        let b = run("G0 X10 Y5\nG1 Z-1 F600\nX20\nG91 X1 Y1\nG20 G90 X1 F10\nG21 G0 X0 Y0 Z0\n");
        let m = moves(&b);
        assert_eq!(m[0], ([10.0, 5.0, 0.0, 0.0, 0.0, 0.0], Path::Line, None));
        assert_eq!(m[1], ([10.0, 5.0, -1.0, 0.0, 0.0, 0.0], Path::Line, Some(600.0)));
        assert_eq!(m[2].0, [20.0, 5.0, -1.0, 0.0, 0.0, 0.0], "G1 is modal");
        assert_eq!(m[3].0, [21.0, 6.0, -1.0, 0.0, 0.0, 0.0], "G91 adds");
        assert_eq!(
            m[4],
            ([25.4, 6.0, -1.0, 0.0, 0.0, 0.0], Path::Line, Some(254.0)),
            "G20: inches"
        );
        assert_eq!(m[5], ([0.0; 6], Path::Line, None));
        assert!(
            b.iter()
                .filter(|b| matches!(b.action, Action::Move { .. }))
                .all(|b| b.line >= 1 && b.line <= 6)
        );
        assert_eq!(b[1].line, 2);
    }

    #[test]
    fn work_offsets_g92_and_g53() {
        // G55 has its origin at machine x = 100.
        let b = run("G55 G0 X1\nG92 X0\nG0 X5\nG53 G0 X2\nG54 G0 X3\n");
        let m = moves(&b);
        assert_eq!(m[0].0[0], 101.0);
        assert_eq!(m[1].0[0], 106.0, "G92 X0 made machine x 101 read 0");
        assert_eq!(m[2].0[0], 2.0, "G53: machine coordinates");
        assert_eq!(m[3].0[0], 4.0, "G54 (origin 0) with G92's offset of 1 still in force");
    }

    #[test]
    fn arcs_by_centre_and_radius_helical_turns_and_planes() {
        let b = run(
            "G0 X10 Y0\nG3 X0 Y10 I-10 J0 F100\nG2 X10 Y0 R10\nG3 X10 Y0 Z5 I-10 P2\nG18 G2 X0 Z-5 K0 I-10\nG19 G3 Y10 Z5 J5 K5\n",
        );
        let m = moves(&b);
        assert_eq!(
            m[1].1,
            Path::Arc {
                plane: Plane::Xy,
                center: [0.0, 0.0],
                clockwise: false,
                extra_turns: 0
            }
        );
        match m[2].1 {
            Path::Arc {
                center,
                clockwise: true,
                ..
            } => {
                assert!(
                    center[0].abs() < 1e-9 && center[1].abs() < 1e-9,
                    "R10 from (0,10) to (10,0) cw: {center:?}"
                )
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(m[3].0[2], 5.0, "helix: Z rises along the arc");
        assert!(matches!(m[3].1, Path::Arc { extra_turns: 1, .. }), "P2: one extra turn");
        assert!(matches!(m[4].1, Path::Arc { plane: Plane::Zx, center, .. } if center == [5.0, 0.0]));
        assert!(matches!(m[5].1, Path::Arc { plane: Plane::Yz, .. }));
        // The long arc: a negative R.
        let b = run("G0 X10 Y0\nG3 X0 Y10 R-10 F100\n");
        match moves(&b)[1].1 {
            Path::Arc { center, .. } => assert!(
                (center[0] - 10.0).abs() < 1e-9 && (center[1] - 10.0).abs() < 1e-9,
                "{center:?}"
            ),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn dwell_pauses_spindle_blending_and_end() {
        let b = run("G64 P0.05\nS1200 M3\nG4 P1.5\nG1 X1 F100\nM1\nG61 X2\nM5\nM0\nM2\n");
        let actions: Vec<Action> = b.iter().map(|b| b.action).collect();
        assert!(
            matches!(actions[0], Action::Spindle { direction: Spindle::Clockwise, speed_rpm } if speed_rpm == 1200.0)
        );
        assert_eq!(actions[1], Action::Dwell(1.5));
        assert!(
            matches!(actions[2], Action::Move { blend: Blend::Within { tolerance: Some(t), .. }, .. } if t == 0.05)
        );
        assert_eq!(actions[3], Action::Pause { optional: true });
        assert!(matches!(
            actions[4],
            Action::Move {
                blend: Blend::ExactStop,
                ..
            }
        ));
        assert!(matches!(
            actions[5],
            Action::Spindle {
                direction: Spindle::Off,
                ..
            }
        ));
        assert_eq!(actions[6], Action::Pause { optional: false });
        assert_eq!(actions[7], Action::End);
        assert_eq!(b[7].line, 9);
        let b = run("M4\nM30\n");
        assert!(matches!(
            b[0].action,
            Action::Spindle {
                direction: Spindle::CounterClockwise,
                ..
            }
        ));
        assert_eq!(b[1].action, Action::End);
    }

    #[test]
    fn rotations_on_the_hexapod_only() {
        let b = read(&ended("G1 X1 A2 B-3 C4 F100"), &machine(&XYZABC)).expect("hexapod");
        assert_eq!(moves(&b.blocks)[0].0, [1.0, 0.0, 0.0, 2.0, -3.0, 4.0]);
        // G20 scales lengths, not angles.
        let b = read(&ended("G20 G1 X1 A2 F1"), &machine(&XYZABC)).expect("hexapod");
        assert_eq!(moves(&b.blocks)[0].0, [25.4, 0.0, 0.0, 2.0, 0.0, 0.0]);
        assert_eq!(refused("G1 X1 A2 F100"), "1:7: A: this machine's axes are X Y Z");
        let planar = read(&ended("G1 X1 Z2 F100"), &machine(&["x", "y"])).expect_err("refused");
        assert_eq!(planar.to_string(), "1:7: Z: this machine's axes are X Y");
    }

    #[test]
    fn what_the_subset_lacks_is_refused_with_line_column_and_reason() {
        for (text, message) in [
            ("G41 X1", "1:1: G41 is not supported (cutter compensation)"),
            (
                "G1 X1 F10\nG84 X1 Z-1 R1",
                "2:1: G84 is not supported (canned cycles other than G81, G82, G83)",
            ),
            ("G43 H1", "1:1: G43 is not supported (tool length compensation)"),
            (
                "G28",
                "1:1: G28 is not supported (going home through an intermediate point)",
            ),
            (
                "G93",
                "1:1: G93 is not supported (feed modes other than units per minute)",
            ),
            ("G54.1", "1:1: G54.1 is not supported"),
            ("G1.5", "1:1: G1.5 is not supported"),
            ("T1 M6", "1:1: tool selection (T) is not supported"),
            ("M6", "1:1: M6 is not supported (tool changes)"),
            ("M8", "1:1: M8 is not supported (coolant)"),
            ("M98 P10", "1:1: M98 is not supported (subprograms, user codes)"),
            ("M100", "1:1: M100 is not supported (user-defined M codes)"),
            ("G1 U1", "1:4: U: axes U V W are not supported"),
            (
                "G10 L2 P1 X0",
                "1:1: G10 is not supported (G10/G11 (tables, retraction))",
            ),
            (
                "G0 G1 X1",
                "1:4: G0 and G1 are in one modal group: a block holds one of them",
            ),
            (
                "G90 G91",
                "1:5: G90 and G91 are in one modal group: a block holds one of them",
            ),
            (
                "M3 M5",
                "1:4: M3 and M5 are in one modal group: a block holds one of them",
            ),
            ("G1 X1 X2 F1", "1:7: X twice in one block"),
            (
                "G1 X1",
                "1:4: no feed rate: an F word is needed before the first G1, G2 or G3",
            ),
            ("X1", "1:1: an axis word needs a motion mode: G0, G1, G2 or G3 first"),
            (
                "G2 F100",
                "1:1: an arc needs its centre (I J) or its end and radius (R)",
            ),
            (
                "G80 X1",
                "1:5: axis words cannot go with G80 (it cancels the motion mode; G80 does not)",
            ),
            (
                "G1 X1 F100\nG80\nX2",
                "3:1: an axis word needs a motion mode: G0, G1, G2 or G3 first",
            ),
            (
                "G1 X1 Q0.1 F100",
                "1:7: Q belongs to G64 (merging lines within it) or G83 (the peck depth)",
            ),
            (
                "G64 P0.1 Q-1",
                "1:10: the merging tolerance Q must be zero or positive, got -1",
            ),
            (
                "G90.1 G2 X10 I5 F100",
                "1:10: in G90.1 (absolute arc centres) an arc needs both I and J",
            ),
            (
                "G1 X1 F100\n%",
                "2:1: '%' opens a program only on its first line (and then closes it)",
            ),
            ("G1 X1 F0", "1:7: the feed F must be positive, got 0"),
            ("G4", "1:1: G4 needs P, the dwell in seconds"),
            ("G4 P-1", "1:4: the dwell P must be zero or positive seconds, got -1"),
            (
                "G1 X1 P2 F1",
                "1:7: P belongs to G4 (dwell), G64 (tolerance), an arc (turns) or G82 (dwell)",
            ),
            ("G1 X1 I2 F1", "1:7: I belongs to an arc (G2, G3)"),
            ("G2 X1 F1", "1:4: an arc needs its centre (I J) or its radius (R)"),
            (
                "G2 X1 Y1 I1 R1 F1",
                "1:13: an arc has a radius (R) or a centre (I J K), not both",
            ),
            (
                "G2 X1 K1 F1",
                "1:7: K is not an offset of an arc in G17 (X–Y): use I and J",
            ),
            (
                "G2 X10 I1 F1",
                "1:4: the arc's end is not on its circle: radius 1.0000 mm at the start, 9.0000 mm at the end",
            ),
            ("G2 X0 I0 J0 F1", "1:4: the arc's centre is its start point"),
            (
                "G2 X10 R2 F1",
                "1:8: the radius 2 mm is shorter than half the chord (5.0000 mm)",
            ),
            (
                "G2 X0 Y0 R2 F1",
                "1:10: a full circle is given by its centre (I J K), not by R",
            ),
            (
                "G2 X0 I1 P1.5 F1",
                "1:10: an arc's P is its number of turns, a whole number from 1, got 1.5",
            ),
            ("G53 X1", "1:1: G53 goes with a G0 or G1 move in this block"),
            ("G91 G53 G0 X1", "1:5: G53 needs absolute distances (G90)"),
            (
                "G92",
                "1:1: G92 needs at least one axis word: the program coordinates the tool is at",
            ),
            ("G0 X1 N5", "1:7: a line number (N) comes first in its block"),
            ("G0 X1 E2", "1:7: E (extruders) is not supported"),
            ("S-5", "1:1: the spindle speed S must be zero or positive, got -5"),
            ("G1.25 X1", "1:1: G1.25 is not a code"),
            // Issue 26: absurd values, refused where they are written.
            (
                "G1 X1 F0.01",
                "1:7: the feed F must be at least 0.1 units/min (slower, a millimetre takes hours), got 0.01",
            ),
            (
                "G4 P86401",
                "1:4: the dwell P must be at most 86400 s (a day), got 86401",
            ),
            (
                "S100001 M3",
                "1:1: the spindle speed S must be at most 100000 rpm, got 100001",
            ),
        ] {
            assert_eq!(refused(text), message, "{text:?}");
        }
        let huge = format!("G1 X1{} F100", "9".repeat(400));
        assert_eq!(
            refused(&huge),
            "1:4: X: the number is out of range (at most 1e9 in magnitude)"
        );
        assert_eq!(
            refused("G0 X1\nG1 Y 1000000000.5 F1"),
            "2:4: Y: the number is out of range (at most 1e9 in magnitude)"
        );
    }

    /// Issue 27: the dialect CAM programs use, with the moves LinuxCNC 2.9's `rs274` prints for
    /// the same text (checked by hand against it; `tests/suite/nc.rs` compares where it is
    /// installed).
    #[test]
    fn the_cam_dialect_means_what_linuxcnc_reads() {
        // A motion mode set alone carries to lines with only axis words.
        let m = moves(&run("G1 F600\nX10\nY5\nG0 X0 Y0"));
        assert_eq!(m.len(), 3);
        assert_eq!(m[0], ([10.0, 0.0, 0.0, 0.0, 0.0, 0.0], Path::Line, Some(600.0)));
        assert_eq!(m[1].0, [10.0, 5.0, 0.0, 0.0, 0.0, 0.0]);
        assert_eq!(m[2], ([0.0; 6], Path::Line, None));
        // The usual preamble sets states; G80 leaves no motion mode.
        let m = moves(&run("G40 G49 G80 G94 G17 G21 G90\nG1 X1 F100"));
        assert_eq!(m[0].0, [1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        // An arc with its centre and no axis word: a full circle where the tool stands.
        let m = moves(&run("G2 I5 F100"));
        assert_eq!(m[0].0, [0.0; 6]);
        assert!(matches!(m[0].1, Path::Arc { center, clockwise: true, .. } if center == [5.0, 0.0]));
        // Absolute arc centres (G90.1), and back (G91.1).
        let m = moves(&run("G0 X2\nG90.1 G2 X10 Y0 I6 J0 F100\nG91.1 G2 X2 Y0 I-4 J0"));
        assert!(matches!(m[1].1, Path::Arc { center, .. } if center == [6.0, 0.0]));
        assert!(matches!(m[2].1, Path::Arc { center, .. } if center == [6.0, 0.0]));
        // G61.1 stops exactly; G64 P0 and P-1 are G64 without a tolerance; Q merges.
        let b = run("G61.1\nG1 X1 F100\nG64 P0\nG1 X2\nG64 P0.01 Q0.02\nX3\nG64 P-1\nX4");
        let blends: Vec<Blend> = b
            .iter()
            .filter_map(|b| match b.action {
                Action::Move { blend, .. } => Some(blend),
                _ => None,
            })
            .collect();
        let within = |tolerance, merge| Blend::Within { tolerance, merge };
        assert_eq!(
            blends,
            [
                Blend::ExactStop,
                within(None, None),
                within(Some(0.01), Some(0.02)),
                within(None, None)
            ]
        );
        // What follows the end is never read (LinuxCNC ignores it), even what is not G-code.
        let p = read("G1 X1 F100\nM2\nG1 X5\nnot a program", &machine(&XYZ)).expect("read to M2");
        assert_eq!(moves(&p.blocks).len(), 1);
        let p = read("%\nG1 X1 F100\n%\nG1 X5\n", &machine(&XYZ)).expect("read to the closing %");
        assert_eq!(moves(&p.blocks).len(), 1);
        // Block delete: off (the default) the line runs; on it is skipped.
        let text = "G1 X1 F100\n/G1 X5\nM2";
        assert_eq!(moves(&read(text, &machine(&XYZ)).expect("read").blocks).len(), 2);
        let on = Machine {
            block_delete: true,
            ..machine(&XYZ)
        };
        assert_eq!(moves(&read(text, &on).expect("read").blocks).len(), 1);
        // A program must end, as LinuxCNC says.
        assert_eq!(
            read("G1 X1 F100\nG1 X2", &machine(&XYZ))
                .expect_err("no end")
                .to_string(),
            "2:1: the file ended with no program end (M2, M30) and no '%' delimiters: is the program complete?"
        );
        assert_eq!(
            read("%\nG1 X1 F100\n", &machine(&XYZ))
                .expect_err("no closing %")
                .to_string(),
            "2:1: the file ended without the closing '%' (or M2, M30): is the program complete?"
        );
    }

    /// The moves LinuxCNC 2.9's `rs274` prints for the same program (also compared with it in
    /// `tests/suite/nc.rs` where it is installed): G83 from above R, G98, G91 with L3.
    #[test]
    fn canned_cycles_make_linuxcncs_moves() {
        let b = run("G0 Z10\nG83 X1 Y1 Z-5 R2 Q2 F100\nG98 G81 X5 Z-1 R1\nG91 G81 X2 Y0 R-3 Z-1 L3\nG90 G0 X0");
        let r = |x: f64, y: f64, z: f64| ([x, y, z, 0.0, 0.0, 0.0], Path::Line, None);
        let f = |x: f64, y: f64, z: f64| ([x, y, z, 0.0, 0.0, 0.0], Path::Line, Some(100.0));
        let expected = [
            r(0.0, 0.0, 10.0),
            // G83: over the hole, down to R, pecks of 2 with a rapid back to R and to 0.254 mm
            // above the last peck, the bottom, back to R (G99).
            r(1.0, 1.0, 10.0),
            r(1.0, 1.0, 2.0),
            f(1.0, 1.0, 0.0),
            r(1.0, 1.0, 2.0),
            r(1.0, 1.0, 0.254),
            f(1.0, 1.0, -2.0),
            r(1.0, 1.0, 2.0),
            r(1.0, 1.0, -1.746),
            f(1.0, 1.0, -4.0),
            r(1.0, 1.0, 2.0),
            r(1.0, 1.0, -3.746),
            f(1.0, 1.0, -5.0),
            r(1.0, 1.0, 2.0),
            // G98: back to where the series started (Z10).
            r(5.0, 1.0, 2.0),
            r(5.0, 1.0, 1.0),
            f(5.0, 1.0, -1.0),
            r(5.0, 1.0, 10.0),
            // G91 L3: X2 each time, R 3 below the start (7), the bottom 1 below R.
            r(7.0, 1.0, 10.0),
            r(7.0, 1.0, 7.0),
            f(7.0, 1.0, 6.0),
            r(7.0, 1.0, 10.0),
            r(9.0, 1.0, 10.0),
            r(9.0, 1.0, 7.0),
            f(9.0, 1.0, 6.0),
            r(9.0, 1.0, 10.0),
            r(11.0, 1.0, 10.0),
            r(11.0, 1.0, 7.0),
            f(11.0, 1.0, 6.0),
            r(11.0, 1.0, 10.0),
            r(0.0, 1.0, 10.0),
        ];
        let got = moves(&b);
        assert_eq!(got.len(), expected.len(), "{got:?}");
        for (g, e) in got.iter().zip(&expected) {
            assert!(
                g.0.iter().zip(&e.0).all(|(a, b)| (a - b).abs() < 1e-9) && g.1 == e.1 && g.2 == e.2,
                "{g:?} vs {e:?}"
            );
        }
        // Every move of a cycle stops exactly; G82 dwells at the bottom; a block with only X
        // and Y repeats the cycle with its values.
        let b = run("G64 G0 Z5\nG82 X1 Z-1 R1 P0.5 F60\nX2\nG80");
        assert!(b.iter().skip(1).filter(|b| b.action != Action::End).all(|b| matches!(
            b.action,
            Action::Move {
                blend: Blend::ExactStop,
                ..
            } | Action::Dwell(_)
        )));
        let dwells: Vec<Action> = b
            .iter()
            .map(|b| b.action)
            .filter(|a| matches!(a, Action::Dwell(_)))
            .collect();
        assert_eq!(dwells, [Action::Dwell(0.5), Action::Dwell(0.5)]);
        let last_move = b.iter().rev().find(|b| matches!(b.action, Action::Move { .. }));
        assert_eq!(last_move.map(|b| b.line), Some(3), "X2 drilled again");
        for (text, message) in [
            ("G81 X1 Z-1 F10", "1:5: G81 needs R, the retract plane"),
            ("G81 X1 R1 F10", "1:5: G81 needs Z, the bottom of the hole"),
            ("G83 X1 Z-1 R1 F10", "1:5: G83 needs Q, the depth of each peck"),
            ("G83 X1 Z-1 R1 Q0 F10", "1:15: the peck depth Q must be positive, got 0"),
            (
                "G82 X1 Z-1 R1 F10",
                "1:5: G82 needs P, the dwell at the bottom in seconds",
            ),
            (
                "G81 X1 Z1 R-1 F10",
                "1:11: G81: the retract plane R (-1) is below the bottom Z (1)",
            ),
            (
                "G81 X1 Z-1 R1 L0 F10",
                "1:15: L, the number of repeats, is a whole number from 1 to 10000, got 0",
            ),
            ("G81 X1 Z-1 R1", "1:5: no feed rate: an F word is needed before G81"),
            (
                "G1 X1 L2 F10",
                "1:7: L belongs to a canned cycle (its repeats); G10 tables are not supported",
            ),
            (
                "G1 X1 R2 F10",
                "1:7: R belongs to an arc (G2, G3) or a canned cycle (G81 … G83)",
            ),
        ] {
            assert_eq!(refused(text), message, "{text}");
        }
        let hexapod = read(&ended("G81 X1 A1 Z-1 R1 F10"), &machine(&XYZABC)).expect_err("refused");
        assert_eq!(
            hexapod.to_string(),
            "1:8: G81 moves X Y Z only: A cannot move in a canned cycle"
        );
    }

    /// The interpreter's state as LinuxCNC's system parameters, in program units.
    #[test]
    fn system_parameters_give_the_state() {
        // G55's origin is at machine x 100.
        let m = moves(&run(
            "G55 G0 X5\nG1 X#5420 Y#5220 Z#5241 F#<_coord_system>\nG20\nG0 X[#<_x>] Y#<_metric> Z#<_motion_mode>\nG21 G92 X0\nG0 Y#5211",
        ));
        assert_eq!(m[0].0[0], 105.0);
        assert_eq!(
            m[1].0[..3],
            [105.0, 2.0, 100.0],
            "position 5, system 2 (G55), G55's x origin 100"
        );
        assert_eq!(m[1].2, Some(550.0));
        let inch = 25.4;
        // A line's values are read before its own codes act: G20 on a line of its own.
        assert!((m[2].0[0] - 105.0).abs() < 1e-9, "#<_x> in inches, moved to in inches");
        assert_eq!(m[2].0[1], 0.0, "G20: not metric");
        assert!(
            (m[2].0[2] - 10.0 * inch).abs() < 1e-9,
            "G1 before the line: motion mode 10"
        );
        assert_eq!(m[3].0[1], 5.0, "G92 X0 at 5: its offset #5211 reads 5");
    }

    #[test]
    fn a_byte_order_mark_is_not_part_of_the_program() {
        let m = machine(&XYZ);
        let with = read("\u{feff}G0 X1\nM2", &m).expect("a BOM then a program");
        let without = read("G0 X1\nM2", &m).expect("the program");
        assert_eq!(format!("{:?}", with.blocks), format!("{:?}", without.blocks));
        // Columns count from the first character after the mark.
        assert_eq!(refused("\u{feff}G1 X1 F0"), refused("G1 X1 F0"));
    }
}
