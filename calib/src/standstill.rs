//! Whether the vehicle stands still, judged from the filter's steps: below a
//! rear-axle speed for a time. Parameters change only at standstill, and the
//! odometry's RESET_POSE asks the same question, so one judge answers both.

/// The standstill judge (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Standstill {
    speed_mps: f64,
    time_s: f64,
    last_step_s: Option<f64>,
    still_since_s: Option<f64>,
}

impl Standstill {
    /// A judge that calls the vehicle still below `speed_mps` held for `time_s`.
    pub fn new(speed_mps: f64, time_s: f64) -> Self {
        Self {
            speed_mps,
            time_s,
            last_step_s: None,
            still_since_s: None,
        }
    }

    /// One step at `t_s` that moved the rear axle `distance_m`; whether the
    /// vehicle moved in it. The first step has no interval, so any distance
    /// is motion, and so is a distance that is not finite.
    pub fn step(&mut self, t_s: f64, distance_m: f64) -> bool {
        let dt_s = self.interval_s(t_s);
        let moving = !distance_m.is_finite() || distance_m.abs() > self.speed_mps * dt_s;
        if moving {
            self.still_since_s = None;
        } else if self.still_since_s.is_none() {
            self.still_since_s = Some(t_s);
        }
        self.last_step_s = Some(t_s);
        moving
    }

    /// Seconds from the previous step to `t_s` (0 before the first step or
    /// for a step back in time).
    pub fn interval_s(&self, t_s: f64) -> f64 {
        self.last_step_s.map_or(0.0, |last| (t_s - last).max(0.0))
    }

    /// Whether the vehicle has stood still long enough at `t_s`. With no
    /// step yet nothing moves the vehicle that could be seen: still.
    pub fn is_still(&self, t_s: f64) -> bool {
        match (self.last_step_s, self.still_since_s) {
            (None, _) => true,
            (Some(_), None) => false,
            (Some(_), Some(since)) => t_s - since >= self.time_s,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn still_only_after_the_time_below_the_speed() {
        let mut s = Standstill::new(0.01, 1.0);
        assert!(s.is_still(0.0), "no step yet: nothing seen moving");
        assert!(s.step(0.0, 0.001), "the first step's distance is motion");
        assert!(!s.is_still(0.0));
        for k in 1..=100 {
            let t = f64::from(k) * 0.01;
            assert!(!s.step(t, 0.000_05), "5 mm/s is below 10 mm/s");
        }
        // Still since 0.01 s: one second later, and not before.
        assert!(!s.is_still(1.0));
        assert!(s.is_still(1.01));
        assert!(s.step(1.02, 0.001), "10 cm/s moves");
        assert!(!s.is_still(5.0));
        assert!(
            s.step(1.03, f64::NAN),
            "a distance that is not finite is motion"
        );
    }

    #[test]
    fn interval_never_negative() {
        let mut s = Standstill::new(0.01, 1.0);
        assert_eq!(s.interval_s(3.0), 0.0);
        s.step(2.0, 0.0);
        assert_eq!(s.interval_s(2.5), 0.5);
        assert_eq!(s.interval_s(1.0), 0.0);
    }
}
