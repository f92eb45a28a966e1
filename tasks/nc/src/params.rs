//! The parameter file, in LinuxCNC's `.var` format: one `NUMBER VALUE` a line, the numbered
//! parameters that outlive a run. Kept here: the origins of G54 … G59 (`#5221` …, twenty numbers
//! a system, x y z a b c first) and the positions G28 and G30 go to (`#5161` …, `#5181` …), in
//! machine units (mm, degrees). A touch-off on the screen writes it; every program starts from
//! it.
//!
//! A file LinuxCNC wrote is read: its other persistent numbers are taken as LinuxCNC's and left
//! aside where this interpreter has nothing for them — axes U V W, G59.1 … G59.3, the coordinate
//! system in force (a program here starts in G54), G92's offset (a program here starts without,
//! as LinuxCNC with `DISABLE_G92_PERSISTENCE`); a rotation of a coordinate system (`#5230` …)
//! other than 0 is refused, as is any number LinuxCNC does not keep, with its line.

pub use pkm_api::offsets::WorkOffsets;

use crate::NcError;

/// The first parameter of G54's origin; each further system's is 20 on.
const G54: usize = 5221;

/// Reads a parameter file; a problem names its line and column (the file's name is the caller's
/// to add).
pub fn parse(text: &str) -> Result<WorkOffsets, NcError> {
    let mut p = WorkOffsets::default();
    // LinuxCNC reads the numbers in increasing order and refuses a file that is not.
    let mut last: Option<usize> = None;
    for (i, line) in text.lines().enumerate() {
        let number = i + 1;
        // The fields with the columns they start at.
        let mut fields = fields_of(line).into_iter();
        let Some(first) = fields.next() else {
            continue;
        };
        let second = fields.next();
        let err = |field: (usize, &str), message: String| NcError::new(number, field.0, message);
        // A problem says where the file is wrong, not what it holds there: a file named by
        // mistake (or by a symbolic link to one that is not a parameter file) is not echoed.
        let index: usize = first
            .1
            .parse()
            .map_err(|_| err(first, "not a parameter's number (a whole number, 5221 say)".to_string()))?;
        if let Some(before) = last.filter(|&before| index <= before) {
            return Err(err(
                first,
                if index == before {
                    format!("#{index} twice: each number once, increasing from line to line, as LinuxCNC reads them")
                } else {
                    format!(
                        "#{index} after #{before}: the numbers must increase from line to line, as LinuxCNC reads them"
                    )
                },
            ));
        }
        last = Some(index);
        let value_field = second.ok_or_else(|| err(first, format!("#{index} has no value")))?;
        if let Some(extra) = fields.next() {
            return Err(err(
                extra,
                "one number and one value a line; a third field here".to_string(),
            ));
        }
        let value: f64 = value_field
            .1
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite() && v.abs() <= 1e6)
            .ok_or_else(|| err(value_field, format!("#{index}: its value is not a number within ±10⁶")))?;
        set(&mut p, index, value).map_err(|why| err(first, why))?;
    }
    Ok(p)
}

/// Takes parameter `index`'s value into `p`, or says why not.
fn set(p: &mut WorkOffsets, index: usize, value: f64) -> Result<(), String> {
    match index {
        // G28's and G30's positions: x y z a b c kept, u v w left aside.
        5161..=5166 => p.homes[0][index - 5161] = value,
        5181..=5186 => p.homes[1][index - 5181] = value,
        5167..=5169 | 5187..=5189 => {}
        // G92's offset and whether it is in force, the coordinate system in force.
        5210..=5220 => {}
        // G54 … G59.3: x y z a b c, u v w, the rotation.
        G54..=5390 => {
            let (system, at) = ((index - G54) / 20, (index - G54) % 20);
            match at {
                0..=5 if system < 6 => p.origins[system][at] = value,
                9 if value != 0.0 => {
                    return Err(format!(
                        "#{index} rotates a coordinate system by {value}°: rotation (G10 R) is not supported"
                    ));
                }
                0..=9 => {}
                _ => return Err(format!("#{index} is not a parameter LinuxCNC keeps in its file")),
            }
        }
        _ => return Err(format!("#{index} is not a parameter LinuxCNC keeps in its file")),
    }
    Ok(())
}

/// The file's text of `p` for a machine of `axes` coordinates (x y z a b c, the first `axes`):
/// LinuxCNC's format, sorted by number.
pub fn format(p: &WorkOffsets, axes: usize) -> String {
    format_keeping(p, axes, &[])
}

/// The numbers of a parameter file that parsed, each with its value as the file wrote it, in
/// the file's order (increasing): what a rewrite keeps of the numbers it does not write.
pub fn entries(text: &str) -> Vec<(usize, String)> {
    text.lines()
        .filter_map(|line| {
            let fields = fields_of(line);
            let (number, value) = (fields.first()?.1.parse().ok()?, fields.get(1)?.1);
            Some((number, value.to_string()))
        })
        .collect()
}

/// [`format`], keeping every number of `kept` (a file's [`entries`]) that it does not write with
/// the value as it was: LinuxCNC's G92 offset, G59.1 … G59.3, U V W, and a b c on a machine of
/// three coordinates are not this interpreter's, and a touch-off must not delete them.
pub fn format_keeping(p: &WorkOffsets, axes: usize, kept: &[(usize, String)]) -> String {
    let n = axes.min(6);
    let mut lines: Vec<(usize, String)> = Vec::new();
    for (k, home) in p.homes.iter().enumerate() {
        for (c, v) in home.iter().enumerate().take(n) {
            lines.push(([5161, 5181][k] + c, format!("{v:.6}")));
        }
    }
    for (system, origin) in p.origins.iter().enumerate() {
        for (c, v) in origin.iter().enumerate().take(n) {
            lines.push((G54 + 20 * system + c, format!("{v:.6}")));
        }
    }
    let ours = lines.len();
    for (number, value) in kept {
        if !lines[..ours].iter().any(|(n, _)| n == number) {
            lines.push((*number, value.clone()));
        }
    }
    lines.sort_by_key(|(n, _)| *n);
    let mut out = String::new();
    for (number, value) in lines {
        out.push_str(&format!("{number}\t{value}\n"));
    }
    out
}

/// The blank-separated fields of `line`, each with the 1-based column it starts at.
fn fields_of(line: &str) -> Vec<(usize, &str)> {
    let mut out = Vec::new();
    let mut start = None;
    for (column, (at, c)) in line.char_indices().enumerate() {
        match (c.is_whitespace(), start) {
            (false, None) => start = Some((column + 1, at)),
            (true, Some((col, from))) => {
                out.push((col, &line[from..at]));
                start = None;
            }
            _ => {}
        }
    }
    if let Some((col, from)) = start {
        out.push((col, &line[from..]));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_written_is_read_back_and_linuxcncs_other_numbers_are_left_aside() {
        let mut p = WorkOffsets::default();
        p.origins[0] = [10.0, -2.5, 3.0, 0.0, 0.0, 0.0];
        p.origins[5][1] = 7.25;
        p.homes[1][2] = 40.0;
        let text = format(&p, 3);
        assert!(text.starts_with("5161\t0.000000\n"), "{text}");
        assert!(
            text.contains("5221\t10.000000\n5222\t-2.500000\n5223\t3.000000\n"),
            "{text}"
        );
        assert!(text.contains("5322\t7.250000\n"), "{text}");
        assert_eq!(parse(&text), Ok(p));
        // A LinuxCNC file: G92, the system in force, U V W, G59.3, a rotation of 0.
        let linuxcnc = "5161 1\n5167 9\n5210 1\n5211 3\n5220 2\n5221 4\n5227 8\n5230 0\n5381 6\n\n";
        let read = parse(linuxcnc).expect("read");
        assert_eq!((read.homes[0][0], read.origins[0][0]), (1.0, 4.0));
        assert_eq!(read.origins[1], [0.0; 6]);
    }

    #[test]
    fn a_rewrite_keeps_linuxcncs_numbers_it_does_not_write() {
        // G92 (5210 … 5219), G54's a b c on a machine of three coordinates, U, G59.3.
        let file = "5161 1\n5167 9\n5210 1\n5211 3.5\n5221 4\n5224 30\n5227 8\n5381 6\n";
        let mut p = parse(file).expect("read");
        p.origins[0][0] = -12.0;
        let text = format_keeping(&p, 3, &entries(file));
        for kept in [
            "5167\t9\n",
            "5210\t1\n",
            "5211\t3.5\n",
            "5224\t30\n",
            "5227\t8\n",
            "5381\t6\n",
        ] {
            assert!(text.contains(kept), "{kept:?} in {text}");
        }
        assert!(text.contains("5221\t-12.000000\n"), "{text}");
        assert!(text.contains("5161\t1.000000\n"), "{text}");
        // Read back as LinuxCNC reads it: in increasing order, each number once.
        assert_eq!(parse(&text).map(|q| q.origins[0][0]), Ok(-12.0));
    }

    #[test]
    fn problems_name_their_line_and_column() {
        for (text, why) in [
            (
                "5221 1\nfive 2\n",
                "2:1: not a parameter's number (a whole number, 5221 say)",
            ),
            ("5221\n", "1:1: #5221 has no value"),
            ("5221 x\n", "1:6: #5221: its value is not a number within ±10⁶"),
            ("5221 1 2\n", "1:8: one number and one value a line; a third field here"),
            // The first line of /etc/shadow: where, not what.
            (
                "root:$6$salt$hash:19000:0:99999:7:::\n",
                "1:1: not a parameter's number (a whole number, 5221 say)",
            ),
            (
                "5230 90\n",
                "1:1: #5230 rotates a coordinate system by 90°: rotation (G10 R) is not supported",
            ),
            ("  31 4\n", "1:3: #31 is not a parameter LinuxCNC keeps in its file"),
            ("5232 4\n", "1:1: #5232 is not a parameter LinuxCNC keeps in its file"),
            (
                "5221 1\n5223 2\n5222 3\n",
                "3:1: #5222 after #5223: the numbers must increase from line to line, as LinuxCNC reads them",
            ),
            (
                "5221 1\n\n5221 2\n",
                "3:1: #5221 twice: each number once, increasing from line to line, as LinuxCNC reads them",
            ),
        ] {
            assert_eq!(parse(text).map_err(|e| e.to_string()), Err(why.to_string()), "{text}");
        }
    }
}
