//! `recorded`: serves the replies of a recording in order, with their recorded status,
//! attempts, latency, usage and failure, so that a recorded LLM episode re-runs without any
//! network and takes the same decisions (`activemap replay --node planner` checks them bit
//! for bit). A query whose prompt differs from the recorded one still gets the recorded reply
//! (the decisions stay those of the recording); the difference is counted and logged once.
//! A follow-up turn is served the follow-up recorded with the exchange just served.

use super::{ChatRequest, Completion, FailureKind, Provider};

/// One recorded exchange, as the provider serves it back.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedReply {
    /// The system message that was sent.
    pub system: String,
    /// The user message that was sent.
    pub user: String,
    /// What the provider made of it then.
    pub completion: Completion,
    /// What the provider made of the follow-up turn, if one was asked.
    pub follow_up: Option<Completion>,
    /// The question was asked in the background (`ask.mode: background`): its answer was
    /// taken up at a later replan, ...
    pub background: bool,
    /// ... the one of this frame (`None`: never, the episode ended first). A replay takes it
    /// up at the same frame, so its goals are the recorded ones.
    pub answered_frame: Option<u64>,
}

/// The recorded provider.
pub struct RecordedProvider {
    replies: std::collections::VecDeque<RecordedReply>,
    /// The follow-up recorded with the exchange served last, until asked for.
    follow_up: Option<Completion>,
    served: usize,
    mismatches: usize,
}

impl RecordedProvider {
    /// Serves `replies` in order.
    pub fn new(replies: Vec<RecordedReply>) -> Self {
        Self {
            replies: replies.into(),
            follow_up: None,
            served: 0,
            mismatches: 0,
        }
    }

    /// Queries whose prompt differed from the recorded one.
    pub fn mismatches(&self) -> usize {
        self.mismatches
    }
}

impl Provider for RecordedProvider {
    fn complete(&mut self, request: &ChatRequest<'_>) -> Completion {
        if request.follow_up.is_some() {
            return self.follow_up.take().unwrap_or_else(|| {
                Completion::failed(
                    "recorded",
                    FailureKind::Replay,
                    format!(
                        "the recording holds no follow-up for exchange {}",
                        self.served
                    ),
                )
            });
        }
        self.follow_up = None;
        let Some(next) = self.replies.pop_front() else {
            return Completion::failed(
                "recorded",
                FailureKind::Replay,
                format!("the recording holds only {} replies", self.served),
            );
        };
        self.served += 1;
        if next.system != request.system || next.user != request.user {
            if self.mismatches == 0 {
                eprintln!(
                    "llm (recorded): query {} differs from the recorded prompt; serving the \
                     recorded reply anyway",
                    self.served
                );
            }
            self.mismatches += 1;
        }
        self.follow_up = next.follow_up;
        next.completion
    }

    fn describe(&self) -> String {
        format!("recorded replies ({} exchanges)", self.replies.len())
    }
}
