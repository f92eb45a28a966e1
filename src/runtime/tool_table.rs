//! The run's tool table as the operator and the programs change it: an entry edited on the
//! screen, or set by a program's `G10 L1`/`L10` when the run reaches its line, is written back
//! to the tool table's file — whole, in LinuxCNC's format, so that a crash or a power cut leaves
//! the old file or the new one ([`crate::runtime::files::replace_durably`]) — and the jobs made
//! from then on, and the programs loaded, are planned with it.
//!
//! A simulation (`run --virtual`, paced or not) keeps its changes for the run: it checks
//! programs before they run on the machine, and must not change the machine's tools.

use std::path::PathBuf;
use std::sync::Mutex;

use pkm_nc::tools::{MAX_TOOL, MAX_TOOLS, Tool, ToolTable};
use tracing::{info, warn};

/// The longest comment an entry edited on the screen may have (characters).
pub const MAX_COMMENT_CHARS: usize = 120;
/// The largest offset an entry may have (mm or degrees), as the table's reader bounds it.
pub const MAX_OFFSET: f64 = 10_000.0;
/// The largest diameter (mm), as the table's reader bounds it.
pub const MAX_DIAMETER_MM: f64 = 1000.0;

/// The run's tool table and where it is kept.
pub struct ToolTableKeeper {
    /// The file, as the run named it.
    file: String,
    /// Whether changes are written to the file (a machine's run) or kept for the run (a
    /// simulation).
    writes: bool,
    /// The table now, and its text once it is no longer the one the run started with (as
    /// written: made once a change, not at every look).
    now: Mutex<(ToolTable, Option<String>)>,
    /// How many changes were kept: the screen sends every page the table at each.
    changes: tokio::sync::watch::Sender<u64>,
}

/// What became of a change.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kept {
    /// Written to the file.
    Written,
    /// Kept for this run only (a simulation).
    ForTheRun,
}

impl ToolTableKeeper {
    /// The keeper of `table`, which the run read from `file`; `writes`: whether changes go to
    /// the file.
    pub fn new(file: String, table: ToolTable, writes: bool) -> ToolTableKeeper {
        ToolTableKeeper {
            file,
            writes,
            now: Mutex::new((table, None)),
            changes: tokio::sync::watch::Sender::new(0),
        }
    }

    /// The file, as the run named it.
    pub fn file(&self) -> &str {
        &self.file
    }

    /// Whether changes are written to the file.
    pub fn writes(&self) -> bool {
        self.writes
    }

    /// The table now.
    pub fn table(&self) -> ToolTable {
        self.now.lock().unwrap_or_else(|p| p.into_inner()).0.clone()
    }

    /// A watch of the changes kept (a count): it changes after each.
    pub fn changes(&self) -> tokio::sync::watch::Receiver<u64> {
        self.changes.subscribe()
    }

    /// The table's text (LinuxCNC's format) once it is no longer the one the run started with:
    /// what a job made now is planned with.
    pub fn changed_text(&self) -> Option<String> {
        self.now.lock().unwrap_or_else(|p| p.into_inner()).1.clone()
    }

    /// Whether the table is no longer the one the run started with.
    pub fn changed(&self) -> bool {
        self.now.lock().unwrap_or_else(|p| p.into_inner()).1.is_some()
    }

    /// Sets `tool`'s entry (replaced, or added at the end), checked as the table's reader
    /// checks it; written to the file (blocking: call it off the server's thread). Refused,
    /// and nothing changed, when the entry is not valid or the file cannot be written.
    pub fn set(&self, tool: Tool) -> Result<Kept, String> {
        check(&tool)?;
        self.change(|table| put(table, tool))
    }

    /// Sets `tool`'s entry as the screen edits it, as [`ToolTableKeeper::set`] does: a lathe
    /// tool's orientation and angles, which the screen does not show, kept from the entry it
    /// replaces.
    pub fn edit(&self, mut tool: Tool) -> Result<Kept, String> {
        check(&tool)?;
        self.change(|table| {
            if let Some(was) = table.get(tool.number) {
                tool.orientation = was.orientation;
                tool.angles = was.angles;
            }
            put(table, tool)
        })
    }

    /// Removes tool `number`'s entry; written to the file as [`ToolTableKeeper::set`] writes.
    pub fn remove(&self, number: u32) -> Result<Kept, String> {
        self.change(|table| {
            let before = table.tools.len();
            table.tools.retain(|t| t.number != number);
            if table.tools.len() == before {
                return Err(format!("tool {number} is not in the tool table"));
            }
            Ok(())
        })
    }

    /// Sets the entry a program's `G10 L1`/`L10` made (`line`: its line in the table's format).
    pub fn set_line(&self, line: &str) -> Result<(u32, Kept), String> {
        let table = ToolTable::parse(line).map_err(|e| format!("the entry {line:?}: {e}"))?;
        let Some(tool) = table.tools.into_iter().next() else {
            return Err(format!("the entry {line:?} names no tool"));
        };
        let number = tool.number;
        self.set(tool).map(|kept| (number, kept))
    }

    /// Changes the table by `edit` and keeps it: the file written first, the table changed only
    /// once it is (one change at a time: the lock is held while the file is written).
    fn change(&self, edit: impl FnOnce(&mut ToolTable) -> Result<(), String>) -> Result<Kept, String> {
        let mut now = self.now.lock().unwrap_or_else(|p| p.into_inner());
        let mut table = now.0.clone();
        edit(&mut table)?;
        let text = table.format();
        let kept = if self.writes {
            crate::runtime::files::replace_durably(&PathBuf::from(&self.file), &text)
                .map_err(|e| format!("{}: cannot write the tool table: {e}", self.file))?;
            Kept::Written
        } else {
            Kept::ForTheRun
        };
        *now = (table, Some(text));
        drop(now);
        self.changes.send_modify(|n| *n += 1);
        Ok(kept)
    }
}

/// Puts `tool` in `table`: in place of its entry, or added at the end.
fn put(table: &mut ToolTable, tool: Tool) -> Result<(), String> {
    let full = table.tools.len() >= MAX_TOOLS;
    match table.tools.iter_mut().find(|t| t.number == tool.number) {
        Some(t) => *t = tool,
        None if full => return Err(format!("the tool table holds {MAX_TOOLS} tools already, its most")),
        None => table.tools.push(tool),
    }
    Ok(())
}

/// Writes back the tool table entries among `messages` — a program's `G10 L1`/`L10` as the run
/// reached them — and logs each (blocking: off the cyclic and the server's threads).
pub fn write_back(keeper: &ToolTableKeeper, messages: &[pkm_api::trajectory::NcMessage]) {
    for m in messages
        .iter()
        .filter(|m| m.kind == pkm_api::trajectory::NcMessageKind::ToolEntry)
    {
        match keeper.set_line(&m.text) {
            Ok((n, Kept::Written)) => info!("NC line {}: tool {n}'s entry written to {}", m.line, keeper.file()),
            Ok((n, Kept::ForTheRun)) => info!(
                "NC line {}: tool {n}'s entry kept for this simulation (a simulation does not write the tool table {})",
                m.line,
                keeper.file()
            ),
            Err(why) => warn!("NC line {}: the tool table entry was not kept: {why}", m.line),
        }
    }
}

/// Refuses an entry the table's reader would refuse, or that could not be written as one line.
fn check(tool: &Tool) -> Result<(), String> {
    if !(1..=MAX_TOOL).contains(&tool.number) {
        return Err(format!("a tool's number is 1 … {MAX_TOOL}, got {}", tool.number));
    }
    if tool.pocket > MAX_TOOL {
        return Err(format!("a pocket is 0 … {MAX_TOOL}, got {}", tool.pocket));
    }
    for (letter, v) in pkm_nc::interp::AXES.iter().zip(tool.offsets) {
        if !(v.is_finite() && v.abs() <= MAX_OFFSET) {
            return Err(format!(
                "the {letter} offset must be within ±{MAX_OFFSET} (mm or degrees), got {v}"
            ));
        }
    }
    if !(tool.diameter.is_finite() && (0.0..=MAX_DIAMETER_MM).contains(&tool.diameter)) {
        return Err(format!(
            "the diameter must be 0 … {MAX_DIAMETER_MM} mm, got {}",
            tool.diameter
        ));
    }
    if tool.comment.chars().count() > MAX_COMMENT_CHARS {
        return Err(format!("a tool's comment has at most {MAX_COMMENT_CHARS} characters"));
    }
    if tool.comment.chars().any(char::is_control) {
        return Err("a tool's comment is one line of text".into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn keeper(dir: &std::path::Path, writes: bool) -> (ToolTableKeeper, PathBuf) {
        let path = dir.join("tool.tbl");
        let text = "T1 P1 Z50 D6 ;6 mm end mill\nT2 P2 Z30 D3 Q9 I10 ;drill\n";
        std::fs::write(&path, text).expect("written");
        let table = ToolTable::parse(text).expect("a table");
        (ToolTableKeeper::new(path.display().to_string(), table, writes), path)
    }

    #[test]
    fn an_entry_is_written_whole_and_the_jobs_after_it_plan_with_it() {
        let dir = tempfile::tempdir().expect("tempdir");
        let (keeper, path) = keeper(dir.path(), true);
        assert_eq!(keeper.changed_text(), None);
        let (number, kept) = keeper
            .set_line("T1 P1 Z+20.000000 D4.000000 ;6 mm end mill")
            .expect("set");
        assert_eq!((number, kept), (1, Kept::Written));
        let written = std::fs::read_to_string(&path).expect("the file");
        assert_eq!(
            written,
            "T1 P1 Z+20.000000 D4.000000 ;6 mm end mill\nT2 P2 Z+30.000000 D3.000000 I+10.000000 Q9 ;drill\n"
        );
        assert_eq!(keeper.changed_text().as_deref(), Some(written.as_str()));
        let mut t3 = keeper.table().get(2).cloned().expect("tool 2");
        t3.number = 3;
        t3.comment = "copy".into();
        keeper.set(t3).expect("added");
        keeper.remove(2).expect("removed");
        let numbers: Vec<u32> = ToolTable::parse(&std::fs::read_to_string(&path).expect("the file"))
            .expect("a table")
            .tools
            .iter()
            .map(|t| t.number)
            .collect();
        assert_eq!(numbers, [1, 3]);
    }

    #[test]
    fn a_refused_entry_changes_nothing_and_a_simulation_writes_nothing() {
        let dir = tempfile::tempdir().expect("tempdir");
        let (keeper, path) = keeper(dir.path(), true);
        let before = std::fs::read_to_string(&path).expect("the file");
        let mut bad = keeper.table().get(1).cloned().expect("tool 1");
        for (edit, why) in [
            (
                (|t: &mut Tool| t.diameter = -1.0) as fn(&mut Tool),
                "the diameter must be 0 … 1000 mm, got -1",
            ),
            (
                |t: &mut Tool| t.offsets[2] = f64::NAN,
                "the Z offset must be within ±10000 (mm or degrees), got NaN",
            ),
            (
                |t: &mut Tool| t.comment = "two\nlines".into(),
                "a tool's comment is one line of text",
            ),
            (|t: &mut Tool| t.number = 0, "a tool's number is 1 … 99999, got 0"),
        ] {
            let mut t = bad.clone();
            edit(&mut t);
            assert_eq!(keeper.set(t), Err(why.to_string()));
        }
        bad.comment = "x".repeat(121);
        assert!(keeper.set(bad).is_err());
        assert_eq!(keeper.remove(9), Err("tool 9 is not in the tool table".to_string()));
        assert_eq!(std::fs::read_to_string(&path).expect("the file"), before);
        assert_eq!(keeper.changed_text(), None);
        // A file that cannot be written: refused with why, the table as it was.
        std::fs::remove_file(&path).expect("removed");
        std::fs::create_dir(&path).expect("a directory in its place");
        let refused = keeper.set_line("T1 Z1").expect_err("cannot write");
        assert!(refused.contains("cannot write the tool table"), "{refused}");
        assert_eq!(keeper.table().get(1).map(|t| t.offsets[2]), Some(50.0));
        // A simulation keeps its changes for the run.
        let dir = tempfile::tempdir().expect("tempdir");
        let (sim, path) = self::keeper(dir.path(), false);
        let before = std::fs::read_to_string(&path).expect("the file");
        assert_eq!(sim.set_line("T1 Z1"), Ok((1, Kept::ForTheRun)));
        assert_eq!(std::fs::read_to_string(&path).expect("the file"), before);
        assert_eq!(sim.table().get(1).map(|t| t.offsets[2]), Some(1.0));
    }
}
