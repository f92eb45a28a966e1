//! Back-off for refused credentials: each refusal of a key (a source address, a user
//! name, everything) makes the next refusals of that key wait longer before they answer, so that
//! guessing a password or a token gets slow however many clients guess at once. Only refusals
//! wait: the right credentials are answered at once, so no guesser can lock the operator out.

use std::collections::HashMap;
use std::hash::Hash;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// The wait of a first refusal.
pub const FIRST: Duration = Duration::from_millis(300);
/// The longest wait.
pub const LONGEST: Duration = Duration::from_secs(10);
/// A key without refusals for this long starts afresh.
pub const FORGET_AFTER: Duration = Duration::from_secs(60);
/// The most keys remembered; beyond, they share one count (a guesser who varies the key gains
/// nothing).
const KEYS: usize = 1024;

/// Refusals counted per key.
pub struct Backoff<K> {
    state: Mutex<Counts<K>>,
}

struct Counts<K> {
    per_key: HashMap<K, (u32, Instant)>,
    /// The refusals of keys beyond [`KEYS`].
    others: (u32, Instant),
}

impl<K: Hash + Eq + Clone> Default for Backoff<K> {
    fn default() -> Self {
        Backoff {
            state: Mutex::new(Counts {
                per_key: HashMap::new(),
                others: (0, Instant::now()),
            }),
        }
    }
}

/// The wait after `n` refusals in a row: [`FIRST`], doubled each time, up to [`LONGEST`].
pub fn wait_after(n: u32) -> Duration {
    if n == 0 {
        return Duration::ZERO;
    }
    FIRST.saturating_mul(1 << (n - 1).min(16)).min(LONGEST)
}

impl<K: Hash + Eq + Clone> Backoff<K> {
    /// Counts a refusal of `key` at `now`; how long its answer waits.
    pub fn refused(&self, key: &K, now: Instant) -> Duration {
        let mut c = self.state.lock().unwrap_or_else(|p| p.into_inner());
        c.per_key
            .retain(|_, (_, last)| now.duration_since(*last) < FORGET_AFTER);
        let full = c.per_key.len() >= KEYS && !c.per_key.contains_key(key);
        let (n, last) = if full {
            &mut c.others
        } else {
            c.per_key.entry(key.clone()).or_insert((0, now))
        };
        if now.duration_since(*last) >= FORGET_AFTER {
            *n = 0;
        }
        *n = n.saturating_add(1);
        *last = now;
        wait_after(*n)
    }

    /// Forgets `key`'s refusals (its credentials were right).
    pub fn accepted(&self, key: &K) {
        let mut c = self.state.lock().unwrap_or_else(|p| p.into_inner());
        c.per_key.remove(key);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_refusal_waits_longer_up_to_the_longest_and_quiet_or_success_forgets() {
        assert_eq!(
            (1..=8).map(wait_after).collect::<Vec<_>>(),
            [300, 600, 1200, 2400, 4800, 9600, 10_000, 10_000].map(Duration::from_millis)
        );
        let b = Backoff::default();
        let t0 = Instant::now();
        let waits: Vec<Duration> = (0..3).map(|_| b.refused(&"operator", t0)).collect();
        assert_eq!(waits, [300, 600, 1200].map(Duration::from_millis));
        // Another key is counted apart.
        assert_eq!(b.refused(&"cell-7", t0), FIRST);
        // A minute without refusals: afresh.
        assert_eq!(b.refused(&"operator", t0 + FORGET_AFTER), FIRST);
        b.refused(&"operator", t0 + FORGET_AFTER);
        b.accepted(&"operator");
        assert_eq!(b.refused(&"operator", t0 + FORGET_AFTER), FIRST);
    }

    #[test]
    fn keys_beyond_those_remembered_share_one_count() {
        let b = Backoff::default();
        let t0 = Instant::now();
        for k in 0..KEYS as u32 {
            b.refused(&k, t0);
        }
        // A guesser who changes the key each time waits as one key would.
        let waits: Vec<Duration> = (0..3).map(|k| b.refused(&(KEYS as u32 + k), t0)).collect();
        assert_eq!(waits, [300, 600, 1200].map(Duration::from_millis));
    }
}
