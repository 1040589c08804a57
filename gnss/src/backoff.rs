//! The reconnect schedule (pure): 0.5 s doubling to 30 s, reset after a good connection.

use std::time::Duration;

/// Exponential backoff between connection attempts.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Backoff {
    first: Duration,
    max: Duration,
    next: Duration,
}

impl Default for Backoff {
    /// 0.5 s doubling to 30 s: quick after a gpsd restart, yet a missing gpsd
    /// costs one connect attempt per half minute.
    fn default() -> Self {
        Self::new(Duration::from_millis(500), Duration::from_secs(30))
    }
}

impl Backoff {
    /// A schedule starting at `first`, doubling up to `max`.
    pub fn new(first: Duration, max: Duration) -> Self {
        let first = first.min(max);
        Self {
            first,
            max,
            next: first,
        }
    }

    /// The wait before the next attempt; the one after it is doubled (capped).
    pub fn next_delay(&mut self) -> Duration {
        let delay = self.next;
        self.next = self.next.saturating_mul(2).min(self.max);
        delay
    }

    /// The longest wait.
    pub fn max(&self) -> Duration {
        self.max
    }

    /// After a good connection (one that delivered a report), start over.
    pub fn reset(&mut self) {
        self.next = self.first;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn doubles_to_the_cap_and_resets() {
        let mut b = Backoff::default();
        let ms: Vec<u128> = (0..9).map(|_| b.next_delay().as_millis()).collect();
        assert_eq!(
            ms,
            [500, 1000, 2000, 4000, 8000, 16_000, 30_000, 30_000, 30_000]
        );
        b.reset();
        assert_eq!(b.next_delay(), Duration::from_millis(500));
    }

    proptest! {
        #[test]
        fn never_shrinks_nor_passes_the_cap(first_ms in 1u64..10_000, max_ms in 1u64..100_000, n in 1usize..80) {
            let mut b = Backoff::new(Duration::from_millis(first_ms), Duration::from_millis(max_ms));
            let mut last = Duration::ZERO;
            for _ in 0..n {
                let d = b.next_delay();
                prop_assert!(d >= last);
                prop_assert!(d <= Duration::from_millis(max_ms));
                last = d;
            }
        }
    }
}
