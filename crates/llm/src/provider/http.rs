//! The HTTP exchange shared by the providers: one blocking reqwest client (rustls) with
//! connect and per-attempt timeouts, bounded retries with exponential backoff and jitter,
//! `Retry-After` honoured on 429/503, and a cap on the body read.

use std::io::Read;
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use reqwest::header::{CONTENT_TYPE, HeaderMap, RETRY_AFTER};

use super::{Failure, FailureKind};
use crate::config::HttpProviderConfig;
use crate::error::LlmError;

/// A secret (an API key): sent only as the `Authorization` header, never printed.
#[derive(Clone)]
pub struct Secret(String);

impl Secret {
    /// Wraps `value`.
    pub fn new(value: String) -> Self {
        Self(value)
    }
}

impl std::fmt::Debug for Secret {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("<redacted>")
    }
}

/// When to try again.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RetryPolicy {
    /// Retries after the first attempt.
    pub max_retries: u32,
    /// First backoff, seconds (doubled per retry).
    pub backoff_s: f64,
    /// Longest backoff and longest `Retry-After` accepted, seconds.
    pub backoff_max_s: f64,
}

impl RetryPolicy {
    /// The wait before retry `retry` (0-based): `min(max, first·2^retry)` times a jitter
    /// factor in [½, 1].
    pub fn backoff(&self, retry: u32, rng: &mut impl Rng) -> Duration {
        let base = (self.backoff_s * 2f64.powi(retry.min(30) as i32)).min(self.backoff_max_s);
        Duration::from_secs_f64(base * rng.random_range(0.5..=1.0))
    }
}

/// What one POST (with its retries) gave.
#[derive(Debug, Clone, PartialEq)]
pub struct HttpOutcome {
    /// Status of the last answer, if any came.
    pub status: Option<u16>,
    /// Its body (at most the cap).
    pub body: Vec<u8>,
    /// Its `Content-Type`.
    pub content_type: Option<String>,
    /// Attempts made.
    pub attempts: u32,
    /// Wall time, waits included, milliseconds.
    pub latency_ms: f64,
    /// `None` on a 2xx answer read whole.
    pub failure: Option<Failure>,
}

/// A blocking HTTP client with the provider's timeouts, retries, cap and key.
pub struct HttpClient {
    client: reqwest::blocking::Client,
    retry: RetryPolicy,
    max_reply_bytes: usize,
    auth: Option<Secret>,
    rng: ChaCha8Rng,
}

impl HttpClient {
    /// The client of `config`, with `auth` sent as a bearer token; `seed` seeds the jitter.
    pub fn new(
        config: &HttpProviderConfig,
        auth: Option<Secret>,
        seed: u64,
    ) -> Result<Self, LlmError> {
        let mut builder = reqwest::blocking::Client::builder()
            .connect_timeout(Duration::from_secs_f64(config.connect_timeout_s))
            .timeout(Duration::from_secs_f64(config.timeout_s))
            .user_agent(concat!("activemap/", env!("CARGO_PKG_VERSION")));
        if config.is_loopback() {
            // A proxy from the environment must not see (or break) loopback traffic.
            builder = builder.no_proxy();
        }
        let client = builder
            .build()
            .map_err(|e| LlmError::Provider(format!("HTTP client: {e}")))?;
        Ok(Self {
            client,
            retry: RetryPolicy {
                max_retries: config.max_retries,
                backoff_s: config.backoff_s,
                backoff_max_s: config.backoff_max_s,
            },
            max_reply_bytes: config.max_reply_bytes,
            auth,
            rng: ChaCha8Rng::seed_from_u64(seed),
        })
    }

    /// POSTs the JSON `body` to `url`, retrying connection failures, timeouts, 429 and 5xx.
    pub fn post_json(&mut self, url: &str, body: &[u8]) -> HttpOutcome {
        let start = Instant::now();
        let mut out = HttpOutcome {
            status: None,
            body: Vec::new(),
            content_type: None,
            attempts: 0,
            latency_ms: 0.0,
            failure: None,
        };
        for retry in 0..=self.retry.max_retries {
            out.attempts += 1;
            let wait = match self.attempt(url, body, &mut out) {
                Attempt::Done => break,
                Attempt::Retry(wait) => {
                    wait.unwrap_or_else(|| self.retry.backoff(retry, &mut self.rng))
                }
            };
            if retry == self.retry.max_retries {
                break;
            }
            std::thread::sleep(wait);
        }
        out.latency_ms = start.elapsed().as_secs_f64() * 1e3;
        out
    }

    /// One attempt; fills `out` and says whether (and after how long, if the server said)
    /// to retry.
    fn attempt(&mut self, url: &str, body: &[u8], out: &mut HttpOutcome) -> Attempt {
        let mut request = self
            .client
            .post(url)
            .header(CONTENT_TYPE, "application/json")
            .body(body.to_vec());
        if let Some(Secret(key)) = &self.auth {
            request = request.bearer_auth(key);
        }
        let response = match request.send() {
            Ok(r) => r,
            Err(e) => {
                let kind = if e.is_timeout() {
                    FailureKind::Timeout
                } else {
                    FailureKind::Connect
                };
                out.failure = Some(Failure::new(kind, error_chain(&e)));
                return Attempt::Retry(None);
            }
        };
        let status = response.status();
        out.status = Some(status.as_u16());
        out.content_type = response
            .headers()
            .get(CONTENT_TYPE)
            .and_then(|v| v.to_str().ok())
            .map(str::to_string);
        let retry_after = retry_after(response.headers());
        out.body.clear();
        let cap = self.max_reply_bytes as u64;
        if let Err(e) = response.take(cap + 1).read_to_end(&mut out.body) {
            let kind = if e.kind() == std::io::ErrorKind::TimedOut
                || error_chain(&e).contains("timed out")
            {
                FailureKind::Timeout
            } else {
                FailureKind::Connect
            };
            out.failure = Some(Failure::new(
                kind,
                format!("reading the reply: {}", error_chain(&e)),
            ));
            return Attempt::Retry(None);
        }
        if out.body.len() as u64 > cap {
            out.failure = Some(Failure::new(
                FailureKind::TooLarge,
                format!("the reply is longer than max_reply_bytes = {cap}"),
            ));
            return Attempt::Done;
        }
        if status.is_success() {
            out.failure = None;
            return Attempt::Done;
        }
        let code = status.as_u16();
        if code == 429 || code == 503 {
            let limit = self.retry.backoff_max_s;
            if let Some(wait) = retry_after
                && wait.as_secs_f64() > limit
            {
                out.failure = Some(Failure::new(
                    FailureKind::RateLimited,
                    format!(
                        "HTTP {code}, Retry-After {:.0} s exceeds backoff_max_s = {limit} s",
                        wait.as_secs_f64()
                    ),
                ));
                return Attempt::Done;
            }
            out.failure = Some(Failure::new(
                FailureKind::RateLimited,
                format!(
                    "HTTP {code}{}",
                    retry_after.map_or(String::new(), |w| format!(
                        ", Retry-After {:.1} s",
                        w.as_secs_f64()
                    ))
                ),
            ));
            return Attempt::Retry(retry_after);
        }
        out.failure = Some(Failure::new(
            FailureKind::HttpStatus,
            format!(
                "HTTP {code}: {}",
                super::excerpt(&out.body[..out.body.len().min(300)])
            ),
        ));
        if status.is_server_error() {
            Attempt::Retry(None)
        } else {
            Attempt::Done
        }
    }
}

enum Attempt {
    Done,
    /// Retry, after the server's wait if it gave one.
    Retry(Option<Duration>),
}

/// `Retry-After` as seconds or an HTTP date.
fn retry_after(headers: &HeaderMap) -> Option<Duration> {
    let value = headers.get(RETRY_AFTER)?.to_str().ok()?.trim();
    if let Ok(seconds) = value.parse::<f64>() {
        return (seconds.is_finite() && seconds >= 0.0).then(|| Duration::from_secs_f64(seconds));
    }
    let date = httpdate::parse_http_date(value).ok()?;
    Some(
        date.duration_since(std::time::SystemTime::now())
            .unwrap_or(Duration::ZERO),
    )
}

/// An error and its sources on one line.
fn error_chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut source = e.source();
    while let Some(inner) = source {
        let text = inner.to_string();
        if !s.contains(&text) {
            s += ": ";
            s += &text;
        }
        source = inner.source();
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_doubles_up_to_the_limit_with_jitter() {
        let policy = RetryPolicy {
            max_retries: 5,
            backoff_s: 1.0,
            backoff_max_s: 6.0,
        };
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for (retry, base) in [(0, 1.0), (1, 2.0), (2, 4.0), (3, 6.0), (9, 6.0)] {
            let w = policy.backoff(retry, &mut rng).as_secs_f64();
            assert!((0.5 * base..=base).contains(&w), "retry {retry}: {w}");
        }
    }

    #[test]
    fn retry_after_in_seconds_or_as_a_date() {
        let mut h = HeaderMap::new();
        h.insert(RETRY_AFTER, "2".parse().unwrap());
        assert_eq!(retry_after(&h), Some(Duration::from_secs(2)));
        h.insert(
            RETRY_AFTER,
            "Wed, 21 Oct 2015 07:28:00 GMT".parse().unwrap(),
        );
        assert_eq!(retry_after(&h), Some(Duration::ZERO), "a past date: now");
        h.insert(RETRY_AFTER, "soon".parse().unwrap());
        assert_eq!(retry_after(&h), None);
    }

    #[test]
    fn a_secret_never_prints() {
        let s = Secret::new("sk-very-secret".into());
        assert_eq!(format!("{s:?}"), "<redacted>");
    }
}
