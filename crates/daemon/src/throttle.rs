//! Slows down guessing the token. An address may get it wrong [`FREE_FAILURES`] times (a
//! person mistyping); after that each further wrong token locks the address out for a delay
//! that doubles with every failure, up to [`MAX_DELAY`]. While locked out, its requests that
//! need the token are answered 429 with `Retry-After`, without comparing anything. The right
//! token clears the address. Before this, 1,900 guesses a second went unhindered (issue 40).

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Wrong tokens an address may send before it is slowed down.
pub const FREE_FAILURES: u32 = 5;
/// The first lockout; each further failure doubles it.
const FIRST_DELAY: Duration = Duration::from_millis(250);
/// The longest lockout.
pub const MAX_DELAY: Duration = Duration::from_secs(60);
/// Addresses remembered at most: beyond, those no longer locked out are forgotten first.
const MAX_ADDRESSES: usize = 4096;

#[derive(Default)]
pub struct Throttle {
    /// Per address: wrong tokens in a row, and until when it is locked out.
    failures: Mutex<HashMap<IpAddr, (u32, Instant)>>,
}

impl Throttle {
    /// `Err(wait)` while `ip` is locked out.
    pub fn check(&self, ip: IpAddr) -> Result<(), Duration> {
        let now = Instant::now();
        match self.lock().get(&ip) {
            Some((_, until)) if *until > now => Err(*until - now),
            _ => Ok(()),
        }
    }

    /// A wrong token from `ip`.
    pub fn failed(&self, ip: IpAddr) {
        let now = Instant::now();
        let mut map = self.lock();
        if map.len() >= MAX_ADDRESSES && !map.contains_key(&ip) {
            map.retain(|_, (_, until)| *until > now);
            if map.len() >= MAX_ADDRESSES {
                // Every one locked out: the oldest lockout goes.
                if let Some(oldest) = map.iter().min_by_key(|(_, (_, u))| *u).map(|(k, _)| *k) {
                    map.remove(&oldest);
                }
            }
        }
        let entry = map.entry(ip).or_insert((0, now));
        entry.0 += 1;
        if entry.0 > FREE_FAILURES {
            let doublings = (entry.0 - FREE_FAILURES - 1).min(16);
            entry.1 = now + (FIRST_DELAY * 2u32.pow(doublings)).min(MAX_DELAY);
        }
    }

    /// The right token from `ip`.
    pub fn succeeded(&self, ip: IpAddr) {
        self.lock().remove(&ip);
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<IpAddr, (u32, Instant)>> {
        // A panic while holding it leaves a plain map: still usable.
        self.failures.lock().unwrap_or_else(|e| e.into_inner())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn five_mistakes_are_free_then_each_doubles_the_lockout() {
        let t = Throttle::default();
        let (a, b): (IpAddr, IpAddr) = ("192.0.2.1".parse().unwrap(), "192.0.2.2".parse().unwrap());
        for _ in 0..FREE_FAILURES {
            t.failed(a);
            assert!(t.check(a).is_ok());
        }
        t.failed(a);
        let first = t.check(a).unwrap_err();
        assert!(
            first > Duration::from_millis(200) && first <= FIRST_DELAY,
            "{first:?}"
        );
        t.failed(a);
        let second = t.check(a).unwrap_err();
        assert!(second > Duration::from_millis(450), "{second:?}");
        for _ in 0..40 {
            t.failed(a);
        }
        assert!(t.check(a).unwrap_err() <= MAX_DELAY);
        // Another address is not slowed; the right token clears one.
        assert!(t.check(b).is_ok());
        t.succeeded(a);
        assert!(t.check(a).is_ok());
    }
}
