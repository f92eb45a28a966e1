//! The process image: named, typed variables shared by programs, buses and the runtime.
//!
//! Every variable has exactly one writer (a program of one task class, or the bus) and any number
//! of readers. Each task class keeps a private copy of the image: its inputs are latched into that
//! copy before its cycle and its outputs are published from it after the cycle, so a program only
//! ever sees a complete, consistent input set.

use std::collections::HashMap;
use std::fmt;
use std::marker::PhantomData;

use serde::{Deserialize, Serialize};

pub use crate::problem::Problem;

/// The IEC 61131-3 types a process-image variable can have.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "UPPERCASE")]
pub enum VarType {
    /// Boolean (`BOOL`).
    Bool,
    /// Signed 16-bit integer (`INT`).
    Int,
    /// Unsigned 16-bit integer (`UINT`).
    Uint,
    /// Signed 32-bit integer (`DINT`).
    Dint,
    /// 64-bit float (`LREAL`; called `REAL` here as in the original program).
    Real,
}

impl fmt::Display for VarType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            VarType::Bool => "BOOL",
            VarType::Int => "INT",
            VarType::Uint => "UINT",
            VarType::Dint => "DINT",
            VarType::Real => "REAL",
        })
    }
}

/// One variable's value. Small and `Copy`, so images are plain arrays that copy without allocating.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Value {
    /// A `BOOL`.
    Bool(bool),
    /// An `INT`.
    Int(i16),
    /// A `UINT`.
    Uint(u16),
    /// A `DINT`.
    Dint(i32),
    /// A `REAL`.
    Real(f64),
}

impl Value {
    /// The type of this value.
    pub fn ty(&self) -> VarType {
        match self {
            Value::Bool(_) => VarType::Bool,
            Value::Int(_) => VarType::Int,
            Value::Uint(_) => VarType::Uint,
            Value::Dint(_) => VarType::Dint,
            Value::Real(_) => VarType::Real,
        }
    }

    /// The zero (and default safe) value of a type: `false`, `0` or `0.0`.
    pub fn zero(ty: VarType) -> Value {
        match ty {
            VarType::Bool => Value::Bool(false),
            VarType::Int => Value::Int(0),
            VarType::Uint => Value::Uint(0),
            VarType::Dint => Value::Dint(0),
            VarType::Real => Value::Real(0.0),
        }
    }
}

impl Serialize for Value {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match *self {
            Value::Bool(v) => s.serialize_bool(v),
            Value::Int(v) => s.serialize_i16(v),
            Value::Uint(v) => s.serialize_u16(v),
            Value::Dint(v) => s.serialize_i32(v),
            Value::Real(v) => s.serialize_f64(v),
        }
    }
}

/// A Rust type that maps to one [`VarType`]; implemented for `bool`, `i16`, `u16`, `i32`, `f64`.
pub trait PlcType: Copy + Send + 'static + private::Sealed {
    /// The process-image type this Rust type stands for.
    const TYPE: VarType;
    /// Extracts the value. The declaration step guarantees the variable has this type.
    fn from_value(v: Value) -> Self;
    /// Wraps the value.
    fn into_value(self) -> Value;
}

mod private {
    pub trait Sealed {}
}

/// A handle's value of another type than it was declared with: a broken invariant.
#[cold]
#[inline(never)]
fn type_invariant_broken(expected: VarType, found: Value) -> ! {
    panic!(
        "process image invariant broken: expected {expected}, found {}",
        found.ty()
    )
}

macro_rules! plc_type {
    ($t:ty, $variant:ident) => {
        impl private::Sealed for $t {}
        impl PlcType for $t {
            const TYPE: VarType = VarType::$variant;
            // Inlined into the programs' reads and writes (every cycle, every variable).
            #[inline]
            fn from_value(v: Value) -> Self {
                match v {
                    Value::$variant(x) => x,
                    // The variable table checks every handle's type when it is declared, so a
                    // mismatch here is a broken invariant of the runtime, not a user error.
                    other => type_invariant_broken(VarType::$variant, other),
                }
            }
            #[inline]
            fn into_value(self) -> Value {
                Value::$variant(self)
            }
        }
    };
}
plc_type!(bool, Bool);
plc_type!(i16, Int);
plc_type!(u16, Uint);
plc_type!(i32, Dint);
plc_type!(f64, Real);

/// Whether a channel (or a plant's signal) carries data from the field to the PLC or back.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Direction {
    /// Field → PLC.
    Input,
    /// PLC → field.
    Output,
}

impl Direction {
    /// "input" or "output".
    pub fn name(self) -> &'static str {
        match self {
            Direction::Input => "input",
            Direction::Output => "output",
        }
    }
}

/// Index of a variable in the process image.
pub type VarIndex = u16;

/// A typed read handle on a variable that some other party writes.
#[derive(Debug)]
pub struct Input<T> {
    pub(crate) index: VarIndex,
    _type: PhantomData<fn() -> T>,
}

/// A typed write handle on a variable that the holder alone writes.
#[derive(Debug)]
pub struct Output<T> {
    pub(crate) index: VarIndex,
    _type: PhantomData<fn() -> T>,
}

impl<T> Clone for Input<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for Input<T> {}
impl<T> Clone for Output<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for Output<T> {}

impl<T> Input<T> {
    /// The variable's index in the image.
    pub fn index(&self) -> VarIndex {
        self.index
    }
}
impl<T> Output<T> {
    /// The variable's index in the image.
    pub fn index(&self) -> VarIndex {
        self.index
    }
}

/// A variable's name with its type. A machine declares one constant per variable of its
/// programs (`pub const BUTTON_STOP: Var<bool> = Var::new("BUTTON_STOP");`); programs declare
/// through it and tests read through it, so a misspelt name or a wrong type is a compile error,
/// not a configuration problem found at start-up.
#[derive(Debug)]
pub struct Var<T> {
    name: &'static str,
    _type: PhantomData<fn() -> T>,
}

impl<T> Clone for Var<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for Var<T> {}

impl<T> Var<T> {
    /// The variable `name`.
    pub const fn new(name: &'static str) -> Self {
        Var {
            name,
            _type: PhantomData,
        }
    }

    /// Its name in the process image.
    pub const fn name(self) -> &'static str {
        self.name
    }
}

/// Who writes a variable.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Writer {
    /// A program of a task class.
    Program {
        /// Index of the task class in the configuration.
        class: usize,
        /// The program's name.
        program: String,
        /// Where the program is configured (JSON path), for error messages.
        at: String,
    },
    /// The field bus (a physical input), latched before the cycles of the given class.
    Bus {
        /// Index of the task class whose cycle latches this input.
        class: usize,
        /// Where the binding is configured (JSON path), for error messages.
        at: String,
    },
}

impl Writer {
    fn describe(&self) -> String {
        match self {
            Writer::Program { program, at, .. } => format!("program \"{program}\" ({at})"),
            Writer::Bus { at, .. } => format!("the bus ({at})"),
        }
    }
}

/// The name a bus reader (an output channel) goes by, as [`Reader::who`].
pub const BUS_READER: &str = "the bus";

/// A reader of a variable.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Reader {
    /// Index of the reading task class.
    pub class: usize,
    /// The reader's name (program or bus).
    pub who: String,
    /// Where the reader is configured (JSON path).
    pub at: String,
    /// Whether a missing writer is an error. A bus output bound to a variable no program writes
    /// just keeps the variable's safe value.
    pub needs_writer: bool,
}

/// What the runtime knows of one variable.
#[derive(Clone, Debug)]
pub struct VarInfo {
    /// The variable's name.
    pub name: String,
    /// Its type.
    pub ty: VarType,
    /// Its writer, once declared.
    pub writer: Option<Writer>,
    /// Its readers.
    pub readers: Vec<Reader>,
    /// The value written on shutdown and on entry to a safe state (outputs only).
    pub safe: Value,
    /// The value it holds when nothing writes it (the readers' default; zero unless one gave
    /// another).
    pub unwritten: Option<Value>,
}

/// The variable table being built from the declarations of programs and the bus.
///
/// Declaration problems are collected rather than returned one by one, so that a configuration is
/// checked as a whole and every problem is reported at once.
#[derive(Debug, Default)]
pub struct VarTable {
    vars: Vec<VarInfo>,
    by_name: HashMap<String, VarIndex>,
    issues: Vec<Problem>,
    /// The bus's inputs are unknown (its I/O map is invalid): a variable nobody writes may be
    /// one of them, so it is not reported.
    inputs_unknown: bool,
}

impl VarTable {
    /// An empty table.
    pub fn new() -> Self {
        Self::default()
    }

    /// Says that the bus's inputs are unknown (its I/O map could not be loaded): the table is
    /// then only checked, never run, and a variable nobody writes is not a problem of its own.
    pub fn set_inputs_unknown(&mut self) {
        self.inputs_unknown = true;
    }

    /// All variables, indexed by [`VarIndex`].
    pub fn vars(&self) -> &[VarInfo] {
        &self.vars
    }

    /// Looks a variable up by name.
    pub fn index_of(&self, name: &str) -> Option<VarIndex> {
        self.by_name.get(name).copied()
    }

    /// The problems found so far.
    pub fn issues(&self) -> &[Problem] {
        &self.issues
    }

    fn intern(&mut self, name: &str, ty: VarType, at: &str) -> VarIndex {
        if let Some(&i) = self.by_name.get(name) {
            let existing = &self.vars[usize::from(i)];
            if existing.ty != ty {
                let first = existing
                    .writer
                    .as_ref()
                    .map(Writer::describe)
                    .or_else(|| existing.readers.first().map(|r| format!("\"{}\" ({})", r.who, r.at)))
                    .unwrap_or_default();
                self.issues.push(Problem {
                    at: at.to_string(),
                    message: format!(
                        "variable \"{name}\" is used as {ty} here but as {} by {first}",
                        existing.ty
                    ),
                });
            }
            return i;
        }
        let Ok(index) = VarIndex::try_from(self.vars.len()) else {
            self.issues.push(Problem {
                at: at.to_string(),
                message: format!("too many variables (the process image holds at most {})", VarIndex::MAX),
            });
            return 0;
        };
        if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '.') {
            self.issues.push(Problem {
                at: at.to_string(),
                message: format!("variable name \"{name}\" is not valid: use letters, digits, '_' and '.'"),
            });
        }
        self.vars.push(VarInfo {
            name: name.to_string(),
            ty,
            writer: None,
            readers: Vec::new(),
            safe: Value::zero(ty),
            unwritten: None,
        });
        self.by_name.insert(name.to_string(), index);
        index
    }

    /// Declares `writer` as the one writer of `name`; `safe` is the value it falls back to.
    pub fn declare_writer(&mut self, name: &str, ty: VarType, writer: Writer, safe: Value) -> VarIndex {
        let at = match &writer {
            Writer::Program { at, .. } | Writer::Bus { at, .. } => at.clone(),
        };
        let i = self.intern(name, ty, &at);
        let var = &mut self.vars[usize::from(i)];
        if let Some(first) = &var.writer {
            let message = format!(
                "variable \"{name}\" has two writers: {} and {}; a variable has exactly one writer",
                first.describe(),
                writer.describe()
            );
            self.issues.push(Problem { at, message });
        } else {
            var.writer = Some(writer);
            if safe.ty() == ty {
                var.safe = safe;
            }
        }
        i
    }

    /// Declares a reader of `name`.
    pub fn declare_reader(&mut self, name: &str, ty: VarType, reader: Reader) -> VarIndex {
        let i = self.intern(name, ty, &reader.at.clone());
        self.vars[usize::from(i)].readers.push(reader);
        i
    }

    /// Says that `name`, read by a reader configured at `at`, holds `value` when nothing writes
    /// it (a feed override reads 100 %, not 0). Two readers that want different values are a
    /// problem.
    pub fn declare_unwritten(&mut self, index: VarIndex, value: Value, at: &str) {
        let var = &mut self.vars[usize::from(index)];
        match var.unwritten {
            Some(v) if v != value => {
                let message = format!(
                    "variable \"{}\" is read with two defaults for when nothing writes it: {v:?} and {value:?}",
                    var.name
                );
                self.issues.push(Problem {
                    at: at.to_string(),
                    message,
                });
            }
            _ => var.unwritten = Some(value),
        }
    }

    /// Problems of I/O variables exchanged by a slower class than the programs that use them:
    /// an input latched by a slower class than a program that reads it reaches that program late
    /// (BUTTON_STOP in a 100 ms class delays the 10 ms interlock by up to 100 ms), and an output
    /// exchanged by a slower class than the program that writes it reaches the module late (a
    /// PWM set-point). `classes` gives each class's name and cycle (µs), by index.
    pub fn exchange_problems(&self, classes: &[(&str, u32)]) -> Vec<Problem> {
        let class = |c: usize| classes.get(c).copied().unwrap_or(("?", 0));
        let mut problems = Vec::new();
        for var in &self.vars {
            match &var.writer {
                Some(Writer::Bus { class: c, at }) => {
                    for r in var.readers.iter().filter(|r| class(r.class).1 < class(*c).1) {
                        let ((bus_name, bus_cycle), (reader_name, reader_cycle)) = (class(*c), class(r.class));
                        problems.push(Problem {
                            at: at.clone(),
                            message: format!(
                                "input \"{}\" is latched by class \"{bus_name}\" ({} ms) but read by \"{}\" in class \
                                 \"{reader_name}\" ({} ms), which would see it up to {} ms late: bind it to \"{reader_name}\"",
                                var.name,
                                f64::from(bus_cycle) / 1000.0,
                                r.who,
                                f64::from(reader_cycle) / 1000.0,
                                f64::from(bus_cycle) / 1000.0
                            ),
                        });
                    }
                }
                Some(Writer::Program { class: w, program, .. }) => {
                    let bus = var.readers.iter().filter(|r| r.who == BUS_READER);
                    for r in bus.filter(|r| class(r.class).1 > class(*w).1) {
                        let ((bus_name, bus_cycle), (writer_name, writer_cycle)) = (class(r.class), class(*w));
                        problems.push(Problem {
                            at: r.at.clone(),
                            message: format!(
                                "output \"{}\" is written by \"{program}\" in class \"{writer_name}\" ({} ms) but \
                                 exchanged by class \"{bus_name}\" ({} ms), so the module would see it up to {} ms \
                                 late: bind it to \"{writer_name}\"",
                                var.name,
                                f64::from(writer_cycle) / 1000.0,
                                f64::from(bus_cycle) / 1000.0,
                                f64::from(bus_cycle) / 1000.0
                            ),
                        });
                    }
                }
                None => {}
            }
        }
        problems
    }

    /// Finishes the table: every variable that is read must have a writer.
    pub fn finish(mut self) -> Result<VarTable, Vec<Problem>> {
        // A variable nobody writes holds its readers' default from the first cycle on.
        for var in self.vars.iter_mut().filter(|v| v.writer.is_none()) {
            if let Some(value) = var.unwritten {
                var.safe = value;
            }
        }
        for var in self.vars.iter().filter(|_| !self.inputs_unknown) {
            if var.writer.is_none() {
                for r in var.readers.iter().filter(|r| r.needs_writer) {
                    self.issues.push(Problem {
                        at: r.at.clone(),
                        message: format!(
                            "variable \"{}\" read by \"{}\" has no writer: no program writes it and no bus input is bound to it",
                            var.name, r.who
                        ),
                    });
                }
            }
        }
        if self.issues.is_empty() {
            Ok(self)
        } else {
            Err(self.issues)
        }
    }

    /// The initial image: every variable at its safe value.
    pub fn initial_image(&self) -> Vec<Value> {
        self.vars.iter().map(|v| v.safe).collect()
    }
}

/// Declares the variables of one program: the handle it gets back is typed, so a program can only
/// read its inputs and write its outputs.
pub struct Declare<'a> {
    table: &'a mut VarTable,
    class: usize,
    program: String,
    at: String,
}

impl<'a> Declare<'a> {
    /// A declaration scope for `program` in task class `class`, configured at JSON path `at`.
    pub fn new(table: &'a mut VarTable, class: usize, program: &str, at: &str) -> Self {
        Declare {
            table,
            class,
            program: program.to_string(),
            at: at.to_string(),
        }
    }

    /// Declares that this program reads `name` of type `T`.
    pub fn input<T: PlcType>(&mut self, name: &str) -> Input<T> {
        self.reader(name, true)
    }

    /// Declares that this program reads `name` of type `T` if something writes it: unlike
    /// [`Declare::input`], an unwritten variable is no error and reads as zero (for additions
    /// such as a joystick's STOP button that an I/O map may leave out).
    pub fn optional_input<T: PlcType>(&mut self, name: &str) -> Input<T> {
        self.reader(name, false)
    }

    fn reader<T: PlcType>(&mut self, name: &str, needs_writer: bool) -> Input<T> {
        let reader = Reader {
            class: self.class,
            who: self.program.clone(),
            at: self.at.clone(),
            needs_writer,
        };
        let index = self.table.declare_reader(name, T::TYPE, reader);
        Input {
            index,
            _type: PhantomData,
        }
    }

    /// Declares that this program writes `name` of type `T`; `safe` is its value on shutdown.
    pub fn output<T: PlcType>(&mut self, name: &str, safe: T) -> Output<T> {
        let writer = Writer::Program {
            class: self.class,
            program: self.program.clone(),
            at: self.at.clone(),
        };
        let index = self.table.declare_writer(name, T::TYPE, writer, safe.into_value());
        Output {
            index,
            _type: PhantomData,
        }
    }

    /// Declares that this program reads `var`.
    pub fn read<T: PlcType>(&mut self, var: Var<T>) -> Input<T> {
        self.input(var.name)
    }

    /// Declares that this program reads `var` if something writes it (see
    /// [`Declare::optional_input`]).
    pub fn read_optional<T: PlcType>(&mut self, var: Var<T>) -> Input<T> {
        self.optional_input(var.name)
    }

    /// Declares that this program reads `var` if something writes it, and reads `default` when
    /// nothing does (see [`Declare::optional_input`]).
    pub fn read_optional_or<T: PlcType>(&mut self, var: Var<T>, default: T) -> Input<T> {
        let input = self.optional_input(var.name);
        self.table
            .declare_unwritten(input.index, default.into_value(), &self.at);
        input
    }

    /// Declares that this program writes `var`; `safe` is its value on shutdown.
    pub fn write<T: PlcType>(&mut self, var: Var<T>, safe: T) -> Output<T> {
        self.output(var.name, safe)
    }

    /// Reports a problem with this program's configuration (its parameters, say).
    pub fn issue(&mut self, sub_path: &str, message: impl Into<String>) {
        let at = if sub_path.is_empty() {
            self.at.clone()
        } else {
            format!("{}.{sub_path}", self.at)
        };
        self.table.issues.push(Problem {
            at,
            message: message.into(),
        });
    }

    /// The JSON path of the program entry being declared.
    pub fn at(&self) -> &str {
        &self.at
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_writers_are_refused_with_both_names() {
        let mut t = VarTable::new();
        Declare::new(&mut t, 0, "a", "task_classes[0].programs[0]").output::<i32>("x", 0);
        Declare::new(&mut t, 1, "b", "task_classes[1].programs[0]").output::<i32>("x", 0);
        let issues = t.finish().unwrap_err();
        assert_eq!(issues.len(), 1);
        assert_eq!(issues[0].at, "task_classes[1].programs[0]");
        assert_eq!(
            issues[0].message,
            "variable \"x\" has two writers: program \"a\" (task_classes[0].programs[0]) and \
             program \"b\" (task_classes[1].programs[0]); a variable has exactly one writer"
        );
    }

    #[test]
    fn type_mismatch_and_missing_writer_are_reported_together() {
        let mut t = VarTable::new();
        Declare::new(&mut t, 0, "a", "p0").output::<i32>("x", 0);
        Declare::new(&mut t, 1, "b", "p1").input::<f64>("x");
        Declare::new(&mut t, 1, "b", "p1").input::<bool>("nobody");
        let issues = t.finish().unwrap_err();
        let messages: Vec<_> = issues.iter().map(|i| i.message.as_str()).collect();
        assert_eq!(
            messages,
            [
                "variable \"x\" is used as REAL here but as DINT by program \"a\" (p0)",
                "variable \"nobody\" read by \"b\" has no writer: no program writes it and no bus input is bound to it",
            ]
        );
    }

    #[test]
    fn an_optional_input_with_a_default_holds_it_until_something_writes_the_variable() {
        const OVERRIDE: Var<i16> = Var::new("OVERRIDE");
        // Nothing writes it: the first image holds the default.
        let mut t = VarTable::new();
        let input = Declare::new(&mut t, 0, "a", "p0").read_optional_or(OVERRIDE, 100);
        let t = t.finish().expect("no problem");
        assert_eq!(t.initial_image()[usize::from(input.index)], Value::Int(100));
        // A writer's safe value stands where one writes it.
        let mut t = VarTable::new();
        Declare::new(&mut t, 0, "w", "p1").output::<i16>("OVERRIDE", 50);
        let input = Declare::new(&mut t, 0, "a", "p0").read_optional_or(OVERRIDE, 100);
        let t = t.finish().expect("no problem");
        assert_eq!(t.initial_image()[usize::from(input.index)], Value::Int(50));
        // Two readers that disagree on the default are a problem.
        let mut t = VarTable::new();
        Declare::new(&mut t, 0, "a", "p0").read_optional_or(OVERRIDE, 100);
        Declare::new(&mut t, 0, "b", "p1").read_optional_or(OVERRIDE, 0);
        let issues = t.finish().unwrap_err();
        assert_eq!(
            issues[0].message,
            "variable \"OVERRIDE\" is read with two defaults for when nothing writes it: Int(100) and Int(0)"
        );
        assert_eq!(issues[0].at, "p1");
    }
}
