//! A line's message comment as LinuxCNC reads it: `(MSG,…)`, `(DEBUG,…)`, `(PRINT,…)`, the last
//! comment of the line, DEBUG and PRINT with their parameters' values written in.

use pkm_api::trajectory::{NcMessage, NcMessageKind};

use super::Parameters;

/// What line `number`'s message comment asks for: its last comment in parentheses (LinuxCNC
/// acts on a line's last comment only) if it starts, after blanks, with `MSG,`, `DEBUG,` or
/// `PRINT,` in any case. DEBUG and PRINT have their parameters substituted as LinuxCNC does:
/// `#1` and `#<name>` by their value with six decimals, one that is not set by `######`; a `#`
/// at the text's end is dropped, any other `#` kept. A line skipped by block delete has none.
pub(super) fn message_of(text: &str, number: usize, block_delete: bool, params: &dyn Parameters) -> Option<NcMessage> {
    if block_delete && text.trim_start().starts_with('/') {
        return None;
    }
    let code = text.split(';').next().unwrap_or("");
    let mut last = None;
    let mut rest = code;
    while let Some(open) = rest.find('(') {
        let after = &rest[open + 1..];
        let close = after.find(')')?;
        last = Some(&after[..close]);
        rest = &after[close + 1..];
    }
    let comment = last?.trim_start();
    let (kind, body) = [NcMessageKind::Msg, NcMessageKind::Debug, NcMessageKind::Print]
        .into_iter()
        .find_map(|kind| {
            let head = kind.keyword().len() + 1;
            let starts = comment.len() >= head
                && comment[..head - 1].eq_ignore_ascii_case(kind.keyword())
                && comment.as_bytes()[head - 1] == b',';
            starts.then(|| (kind, &comment[head..]))
        })?;
    let text = match kind {
        NcMessageKind::Msg => body.to_string(),
        NcMessageKind::Debug | NcMessageKind::Print => substitute(body, params),
        NcMessageKind::ToolEntry => unreachable!("a comment is MSG, DEBUG or PRINT"),
    };
    Some(NcMessage {
        line: u32::try_from(number).unwrap_or(u32::MAX),
        kind,
        text,
    })
}

/// `body` with its parameters' values written in, as LinuxCNC's DEBUG and PRINT write them.
fn substitute(body: &str, params: &dyn Parameters) -> String {
    const UNSET: &str = "######";
    let chars: Vec<char> = body.chars().collect();
    let mut out = String::with_capacity(body.len());
    let mut at = 0;
    while at < chars.len() {
        let c = chars[at];
        at += 1;
        if c != '#' {
            out.push(c);
            continue;
        }
        match chars.get(at) {
            None => {}
            Some(d) if d.is_ascii_digit() => {
                let start = at;
                while chars.get(at).is_some_and(char::is_ascii_digit) {
                    at += 1;
                }
                let index: String = chars[start..at].iter().collect();
                match index.parse::<usize>().ok().map(|i| params.numbered(i)) {
                    Some(Ok(v)) => out.push_str(&format!("{v:.6}")),
                    _ => out.push_str(UNSET),
                }
            }
            Some('<') => match chars[at..].iter().position(|c| *c == '>') {
                Some(end) => {
                    let name: String = chars[at + 1..at + end]
                        .iter()
                        .filter(|c| !c.is_whitespace())
                        .map(|c| c.to_ascii_lowercase())
                        .collect();
                    at += end + 1;
                    match params.named(&name) {
                        Some(v) => out.push_str(&format!("{v:.6}")),
                        None => out.push_str(UNSET),
                    }
                }
                None => out.push('#'),
            },
            Some(_) => out.push('#'),
        }
    }
    out
}
