//! Wall-clock time per pass, in the order the passes ran.

use std::time::{Duration, Instant};

/// Named pass durations, kept in first-run order. Recording a name twice adds the durations.
///
/// Top-level passes are plain names (`clear`, `capture`, `resolve`); stages inside a pass are
/// written `pass.stage` (`capture.vertex`), so a table can show both without double counting.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PassTimings {
    passes: Vec<(&'static str, Duration)>,
}

impl PassTimings {
    /// No passes yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds `elapsed` to the pass `name`.
    pub fn add(&mut self, name: &'static str, elapsed: Duration) {
        match self.passes.iter_mut().find(|(n, _)| *n == name) {
            Some((_, d)) => *d += elapsed,
            None => self.passes.push((name, elapsed)),
        }
    }

    /// Runs `f` and records its duration under `name`.
    pub fn time<R>(&mut self, name: &'static str, f: impl FnOnce() -> R) -> R {
        let start = Instant::now();
        let result = f();
        self.add(name, start.elapsed());
        result
    }

    /// The duration of `name`, if it ran.
    pub fn get(&self, name: &str) -> Option<Duration> {
        self.passes
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, d)| *d)
    }

    /// All passes and stages in run order.
    pub fn iter(&self) -> impl Iterator<Item = (&'static str, Duration)> + '_ {
        self.passes.iter().copied()
    }

    /// Top-level passes only (names without a `.`).
    pub fn passes(&self) -> impl Iterator<Item = (&'static str, Duration)> + '_ {
        self.iter().filter(|(n, _)| !n.contains('.'))
    }

    /// Sum of the top-level passes.
    pub fn total(&self) -> Duration {
        self.passes().map(|(_, d)| d).sum()
    }

    /// Appends another set of timings (stages of a sub-step, say) to these.
    pub fn extend(&mut self, other: &PassTimings) {
        for (n, d) in other.iter() {
            self.add(n, d);
        }
    }

    /// `{ "pass": milliseconds, ... }` in run order.
    pub fn to_json_ms(&self) -> serde_json::Value {
        let map = self
            .iter()
            .map(|(n, d)| (n.to_owned(), serde_json::json!(d.as_secs_f64() * 1e3)))
            .collect::<serde_json::Map<_, _>>();
        serde_json::Value::Object(map)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accumulates_and_keeps_order() {
        let mut t = PassTimings::new();
        t.add("clear", Duration::from_millis(1));
        t.add("capture", Duration::from_millis(5));
        t.add("capture.vertex", Duration::from_millis(2));
        t.add("clear", Duration::from_millis(1));
        let names: Vec<_> = t.iter().map(|(n, _)| n).collect();
        assert_eq!(names, ["clear", "capture", "capture.vertex"]);
        assert_eq!(t.get("clear"), Some(Duration::from_millis(2)));
        assert_eq!(t.total(), Duration::from_millis(7));
        assert_eq!(t.to_json_ms()["capture"], serde_json::json!(5.0));
    }
}
