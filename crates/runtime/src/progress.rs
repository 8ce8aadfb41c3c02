//! Run progress on stderr while the launcher waits for a run.
//!
//! The runtime knows no message that says how far a run is; whoever does registers a
//! [`ProgressSource`] (the CLI: the simulator's `EpisodeStatus`, one per step, with the step
//! budget). The launcher subscribes to every output of that kind and hands each [`StepStatus`]
//! read from it to [`Progress`]. With a
//! terminal on stderr, a single line updates in place (an `indicatif` bar: step/max, percent,
//! steps/s, ETA); in a pipe or CI, one plain line every [`PLAIN_PERCENT`] % of the budget (every
//! [`PLAIN_STEPS`] steps when the budget is unknown). Launcher messages (node finished, crashes)
//! and the end-of-run summary are printed in both modes. The line itself is
//! [`progress_line`] and the plain-mode rule [`PlainSchedule`]: both pure, unit-tested.

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use activemap_schemas::MessageKind;

/// How far a run is, as one progress message tells it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StepStatus {
    /// Steps done.
    pub step: u64,
    /// The step budget, when the message knows it (0: unknown).
    pub max_steps: u64,
    /// `None` while running; how the run ended otherwise.
    pub end: Option<RunEnd>,
    /// Why it ended (shown after the summary), or empty.
    pub message: String,
}

/// How a run ended, as its progress message says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunEnd {
    /// It reached its end (budget, goal, stop).
    Finished,
    /// It failed.
    Failed,
}

/// Which messages tell a run's progress and how to read them (`LaunchOptions::progress`).
#[derive(Debug, Clone, Copy)]
pub struct ProgressSource {
    /// The message kind: the launcher subscribes to every output of this kind (a small kind,
    /// which travels on Zenoh).
    pub kind: MessageKind,
    /// What a run is called in the lines (`episode`).
    pub noun: &'static str,
    /// Reads one payload; `None` for a payload it cannot read (skipped).
    pub read: fn(&[u8]) -> Option<StepStatus>,
}

/// Plain mode prints one line each time the episode crosses another multiple of this percentage.
pub const PLAIN_PERCENT: u64 = 5;

/// Plain mode without a known budget prints one line every this many steps.
pub const PLAIN_STEPS: u64 = 100;

/// `42s`, `3m05s`, `1h02m`.
pub fn format_duration(d: Duration) -> String {
    let s = d.as_secs();
    if s < 60 {
        format!("{s}s")
    } else if s < 3600 {
        format!("{}m{:02}s", s / 60, s % 60)
    } else {
        format!("{}h{:02}m", s / 3600, (s % 3600) / 60)
    }
}

/// One progress line: `step 60/120 (50%), 12.0 steps/s, ETA 5s`, with `elapsed` the time since
/// step 0. The rate and ETA are left out before any step or time has passed; the budget part
/// when `max` is unknown (or 0).
pub fn progress_line(step: u64, max: Option<u64>, elapsed: Duration) -> String {
    let max = max.filter(|&m| m > 0);
    let mut line = match max {
        Some(m) => format!("step {step}/{m} ({}%)", step.min(m) * 100 / m),
        None => format!("step {step}"),
    };
    let secs = elapsed.as_secs_f64();
    if step > 0 && secs > 0.0 {
        let rate = step as f64 / secs;
        line.push_str(&format!(", {rate:.1} steps/s"));
        if let Some(m) = max {
            let left = m.saturating_sub(step) as f64 / rate;
            line.push_str(&format!(
                ", ETA {}",
                format_duration(Duration::from_secs_f64(left))
            ));
        }
    }
    line
}

/// The end-of-run line: `episode finished at step 120/120 in 9s (13.1 steps/s): max_steps
/// reached`, with `noun` what a run is called and `elapsed` the time since step 0.
pub fn summary_line(
    noun: &str,
    status: &StepStatus,
    max: Option<u64>,
    elapsed: Duration,
) -> String {
    let state = match status.end {
        Some(RunEnd::Failed) => "failed",
        _ => "finished",
    };
    let mut line = match max.filter(|&m| m > 0) {
        Some(m) => format!("{noun} {state} at step {}/{m}", status.step),
        None => format!("{noun} {state} at step {}", status.step),
    };
    line.push_str(&format!(" in {}", format_duration(elapsed)));
    let secs = elapsed.as_secs_f64();
    if status.step > 0 && secs > 0.0 {
        line.push_str(&format!(" ({:.1} steps/s)", status.step as f64 / secs));
    }
    if !status.message.is_empty() {
        line.push_str(&format!(": {}", status.message));
    }
    line
}

/// When plain mode prints: the first step at or past each multiple of [`PLAIN_PERCENT`] % of the
/// budget (each multiple of [`PLAIN_STEPS`] steps without one); never twice for one mark, and
/// never for step 0.
#[derive(Debug, Default, Clone)]
pub struct PlainSchedule {
    /// The last mark reported (percent bucket, or step bucket without a budget).
    last_mark: u64,
}

impl PlainSchedule {
    /// True when `step` (of `max`) reaches a mark not reported yet; the mark is then consumed.
    pub fn due(&mut self, step: u64, max: Option<u64>) -> bool {
        let mark = match max.filter(|&m| m > 0) {
            Some(m) => step.min(m) * 100 / m / PLAIN_PERCENT,
            None => step / PLAIN_STEPS,
        };
        if mark > self.last_mark {
            self.last_mark = mark;
            true
        } else {
            false
        }
    }
}

/// How progress is shown.
enum Display {
    /// An updating line on the terminal.
    Bar(indicatif::ProgressBar),
    /// Plain lines at the [`PlainSchedule`] marks.
    Plain(PlainSchedule),
}

/// The progress display of one run (see the module doc).
pub struct Progress {
    display: Display,
    /// What a run is called in the lines.
    noun: &'static str,
    /// Budget: from the statuses, else the run's `--max-steps`.
    max: Option<u64>,
    /// When step 0 was seen (the first status), and the step then.
    started: Option<(Instant, u64)>,
    /// Last step seen.
    step: Option<u64>,
    /// The run's end was reported.
    ended: bool,
}

impl Progress {
    /// A display on stderr: a bar when stderr is a terminal, plain lines otherwise. `noun` is
    /// what a run is called (`episode`), `max` the budget known before the first status
    /// (`--max-steps`).
    pub fn new(noun: &'static str, max: Option<u64>) -> Self {
        let display = if std::io::stderr().is_terminal() {
            let bar = indicatif::ProgressBar::new_spinner();
            bar.set_style(
                indicatif::ProgressStyle::with_template("{spinner} {elapsed_precise} {wide_msg}")
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
            );
            bar.enable_steady_tick(Duration::from_millis(200));
            Display::Bar(bar)
        } else {
            Display::Plain(PlainSchedule::default())
        };
        Self {
            display,
            noun,
            max,
            started: None,
            step: None,
            ended: false,
        }
    }

    /// Prints a launcher message above the bar (or as a plain line).
    pub fn println(&self, message: &str) {
        match &self.display {
            Display::Bar(bar) => bar.suspend(|| eprintln!("{message}")),
            Display::Plain(_) => eprintln!("{message}"),
        }
    }

    /// Shows what the launcher is waiting for before the run's first step (bar only).
    pub fn waiting(&self, message: &str) {
        if let (Display::Bar(bar), None) = (&self.display, self.step) {
            bar.set_message(message.to_string());
        }
    }

    /// Takes one status.
    pub fn status(&mut self, status: &StepStatus) {
        if status.max_steps > 0 {
            self.max = Some(status.max_steps);
        }
        let now = Instant::now();
        let (t0, step0) = *self.started.get_or_insert((now, status.step));
        self.step = Some(status.step);
        // Rate over the steps seen here, extrapolated to an elapsed time since step 0.
        let seen = status.step.saturating_sub(step0);
        let elapsed = if seen > 0 {
            now.duration_since(t0)
                .mul_f64(status.step as f64 / seen as f64)
        } else {
            Duration::ZERO
        };
        let line = progress_line(status.step, self.max, elapsed);
        match &mut self.display {
            Display::Bar(bar) => bar.set_message(line),
            Display::Plain(schedule) => {
                if status.end.is_none() && schedule.due(status.step, self.max) {
                    eprintln!("activemap: {line}");
                }
            }
        }
        if status.end.is_some() && !self.ended {
            self.ended = true;
            let line = summary_line(self.noun, status, self.max, now.duration_since(t0));
            self.println(&format!("activemap: {line}"));
        }
    }

    /// True once a status reported the run's end (finished or failed).
    pub fn ended(&self) -> bool {
        self.ended
    }

    /// Removes the bar (plain mode: nothing to do).
    pub fn finish(self) {
        if let Display::Bar(bar) = self.display {
            bar.finish_and_clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn progress_lines_show_budget_rate_and_eta() {
        assert_eq!(
            progress_line(60, Some(120), Duration::from_secs(5)),
            "step 60/120 (50%), 12.0 steps/s, ETA 5s"
        );
        assert_eq!(
            progress_line(0, Some(120), Duration::ZERO),
            "step 0/120 (0%)"
        );
        assert_eq!(
            progress_line(250, None, Duration::from_secs(10)),
            "step 250, 25.0 steps/s"
        );
        assert_eq!(
            progress_line(100, Some(2000), Duration::from_secs(50)),
            "step 100/2000 (5%), 2.0 steps/s, ETA 15m50s"
        );
        // Past the budget (a final status): capped at 100 %, no negative ETA.
        assert_eq!(
            progress_line(130, Some(120), Duration::from_secs(13)),
            "step 130/120 (100%), 10.0 steps/s, ETA 0s"
        );
    }

    #[test]
    fn the_summary_names_the_end_and_the_rate() {
        let status = |end, message: &str| StepStatus {
            step: 120,
            max_steps: 120,
            end: Some(end),
            message: message.into(),
        };
        assert_eq!(
            summary_line(
                "episode",
                &status(RunEnd::Finished, "max_steps reached"),
                Some(120),
                Duration::from_secs(10)
            ),
            "episode finished at step 120/120 in 10s (12.0 steps/s): max_steps reached"
        );
        assert_eq!(
            summary_line("run", &status(RunEnd::Failed, ""), None, Duration::ZERO),
            "run failed at step 120 in 0s"
        );
    }

    #[test]
    fn durations_read_naturally() {
        assert_eq!(format_duration(Duration::from_secs(42)), "42s");
        assert_eq!(format_duration(Duration::from_secs(185)), "3m05s");
        assert_eq!(format_duration(Duration::from_secs(3720)), "1h02m");
    }

    #[test]
    fn plain_mode_prints_every_five_percent_once() {
        let mut s = PlainSchedule::default();
        let printed: Vec<u64> = (0..=120).filter(|&k| s.due(k, Some(120))).collect();
        // 5 % of 120 is 6 steps: 20 lines, at 6, 12, ..., 120; none at step 0.
        assert_eq!(printed, (1..=20).map(|i| i * 6).collect::<Vec<_>>());
        // Statuses that skip steps still print once per mark crossed.
        let mut s = PlainSchedule::default();
        let printed: Vec<u64> = [3, 40, 41, 99, 500, 2000]
            .into_iter()
            .filter(|&k| s.due(k, Some(2000)))
            .collect();
        assert_eq!(printed, vec![500, 2000]);
        let mut s = PlainSchedule::default();
        let printed: Vec<u64> = [3, 40, 41, 99, 500]
            .into_iter()
            .filter(|&k| s.due(k, Some(400)))
            .collect();
        assert_eq!(printed, vec![40, 99, 500]);
    }

    #[test]
    fn plain_mode_without_a_budget_prints_every_hundred_steps() {
        let mut s = PlainSchedule::default();
        let printed: Vec<u64> = (0..=350).filter(|&k| s.due(k, None)).collect();
        assert_eq!(printed, vec![100, 200, 300]);
    }
}
