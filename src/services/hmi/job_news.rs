//! What became of the screen's jobs, for whoever reports it beside the screen (OPC UA's
//! `JobRefused` condition): the latest outcome, numbered, on a watch channel — a reader that
//! falls behind sees the newest, and nothing piles up.

use serde_json::Value as Json;

/// A screen job's outcome.
#[derive(Clone, Debug, PartialEq)]
pub enum JobOutcome {
    /// Made and loaded (`file`: the job's name in the library, `MDI`, `program.ngc from line 12`).
    Made {
        /// The job's name.
        file: String,
    },
    /// Refused, with why, for the screen at `peer`.
    Refused {
        /// Why (the reply's first line).
        why: String,
        /// The screen's address.
        peer: String,
    },
}

/// The why of a job the operator cancelled: not a refusal of the PLC's.
const CANCELLED: &str = "cancelled by the operator";

impl JobOutcome {
    /// The outcome a job command's `reply` (to the screen at `peer`) tells, if it tells one: a
    /// refused job (not one the operator cancelled), a job made (also the one a touch-off
    /// planned again).
    pub fn of_reply(reply: &Json, peer: &str) -> Option<JobOutcome> {
        match reply["type"].as_str()? {
            "refused" if reply["job"] == true => {
                let why = reply["why"].as_str()?.lines().next().unwrap_or_default();
                (!why.ends_with(CANCELLED)).then(|| JobOutcome::Refused {
                    why: why.to_string(),
                    peer: peer.to_string(),
                })
            }
            "job" => Some(JobOutcome::Made {
                file: reply["file"].as_str().unwrap_or_default().to_string(),
            }),
            "touch_off" => JobOutcome::of_reply(&reply["job"], peer),
            _ => None,
        }
    }
}

/// The latest outcome, and how many there were.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct JobNews {
    /// Outcomes so far.
    pub count: u64,
    /// The latest.
    pub latest: Option<JobOutcome>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn a_reply_tells_a_refusal_a_job_made_or_nothing() {
        let peer = "127.0.0.1:5000";
        assert_eq!(
            JobOutcome::of_reply(
                &json!({"type": "refused", "why": "a job runs from READY: the machine is INIT\nmore", "job": true}),
                peer
            ),
            Some(JobOutcome::Refused {
                why: "a job runs from READY: the machine is INIT".into(),
                peer: peer.into()
            })
        );
        // The operator's cancel is no refusal; a refusal that is not a job's neither.
        let cancelled = json!({"type": "refused", "why": "abandoned while it was being planned: cancelled by the operator", "job": true});
        assert_eq!(JobOutcome::of_reply(&cancelled, peer), None);
        assert_eq!(
            JobOutcome::of_reply(&json!({"type": "refused", "why": "not a job"}), peer),
            None
        );
        assert_eq!(
            JobOutcome::of_reply(&json!({"type": "job", "program": 3, "file": "MDI"}), peer),
            Some(JobOutcome::Made { file: "MDI".into() })
        );
        assert_eq!(
            JobOutcome::of_reply(
                &json!({"type": "touch_off", "job": {"type": "job", "file": "a.ngc"}}),
                peer
            ),
            Some(JobOutcome::Made { file: "a.ngc".into() })
        );
        assert_eq!(JobOutcome::of_reply(&json!({"type": "touch_off"}), peer), None);
    }
}
