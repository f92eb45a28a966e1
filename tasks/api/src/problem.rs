//! The one shape of a problem found while checking configuration and data files: where (a JSON
//! path inside the file) and what. Checks collect problems instead of stopping at the first, so a
//! file is checked as a whole and every problem is reported at once.

use std::fmt;

/// A problem of a configuration or data file: its JSON path and what is wrong there.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Problem {
    /// JSON path of the element that caused it (`task_classes[0].cycle_us`).
    pub at: String,
    /// What is wrong.
    pub message: String,
}

impl Problem {
    /// A problem at `at`.
    pub fn new(at: impl Into<String>, message: impl Into<String>) -> Self {
        Problem {
            at: at.into(),
            message: message.into(),
        }
    }

    /// The same problem seen from a section `prefix` higher up (`plant` + `left.tau_s` →
    /// `plant.left.tau_s`; an empty path becomes the prefix itself).
    pub fn under(self, prefix: &str) -> Self {
        let at = match (prefix.is_empty(), self.at.is_empty()) {
            (true, _) => self.at,
            (false, true) => prefix.to_string(),
            (false, false) if self.at.starts_with('[') => format!("{prefix}{}", self.at),
            (false, false) => format!("{prefix}.{}", self.at),
        };
        Problem { at, ..self }
    }
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "at {}: {}", self.at, self.message)
    }
}

/// Prefixes every problem's path with `prefix` (see [`Problem::under`]).
pub fn under(prefix: &str, problems: impl IntoIterator<Item = Problem>) -> Vec<Problem> {
    problems.into_iter().map(|p| p.under(prefix)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_problem_moves_under_its_section() {
        assert_eq!(Problem::new("left.tau_s", "m").under("plant").at, "plant.left.tau_s");
        assert_eq!(Problem::new("", "m").under("plant").at, "plant");
        assert_eq!(Problem::new("[2]", "m").under("events").at, "events[2]");
        assert_eq!(Problem::new("x", "m").under("").at, "x");
    }
}
