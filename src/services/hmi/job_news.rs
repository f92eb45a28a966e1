//! What became of the screen's jobs, for whoever reports it beside the screen (OPC UA's
//! `JobRefused` condition, the machine tool view's active program): the latest outcome and the
//! jobs made, on a watch channel — a reader that falls behind sees the newest, and nothing piles
//! up.

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

/// The latest outcome, and the jobs made: after a refusal the last job made is still the one
/// loaded, under its name.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct JobNews {
    /// The latest.
    pub latest: Option<JobOutcome>,
    /// Jobs made and loaded so far.
    pub made: u64,
    /// The name of the job made last.
    pub loaded: Option<String>,
}

impl JobNews {
    /// Takes `outcome` in.
    pub fn tell(&mut self, outcome: JobOutcome) {
        if let JobOutcome::Made { file } = &outcome {
            self.made += 1;
            self.loaded = Some(file.clone());
        }
        self.latest = Some(outcome);
    }
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

    #[test]
    fn a_refusal_is_the_latest_news_but_leaves_the_job_made_loaded() {
        let mut news = JobNews::default();
        news.tell(JobOutcome::Made { file: "MDI".into() });
        let refused = JobOutcome::Refused {
            why: "a job runs from READY: the machine is AUTO".into(),
            peer: "127.0.0.1:5000".into(),
        };
        news.tell(refused.clone());
        assert_eq!(
            news,
            JobNews {
                latest: Some(refused),
                made: 1,
                loaded: Some("MDI".into()),
            }
        );
        news.tell(JobOutcome::Made {
            file: "a.ngc from line 12".into(),
        });
        assert_eq!((news.made, news.loaded.as_deref()), (2, Some("a.ngc from line 12")));
    }
}
