//! The CLI's side of the daemon's API: is one running, start or resume a capture there, and
//! follow its events (again from the last one seen when the stream drops).

use std::io::{BufRead, BufReader};
use std::time::Duration;

use anyhow::{bail, Context};
use brdfd_api::answers::{ContinueRequest, Empty, ErrorBody, ErrorCode, Started};
use brdfd_api::event::Event;
use brdfd_api::plan::Plan;
use brdfd_rig::Progress;
use reqwest::blocking::{Client, RequestBuilder, Response};

pub struct Daemon {
    pub base: String,
    token: Option<String>,
    http: Client,
}

/// A capture the daemon refused to start because another is running.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct Busy(pub String);

impl Daemon {
    /// The daemon at `addr` (IP:PORT or a URL), if one answers there. Nothing listening is
    /// `None`; something that answers wrongly is an error.
    pub fn find(addr: &str, token: Option<String>) -> anyhow::Result<Option<Daemon>> {
        let base = if addr.starts_with("http://") {
            addr.trim_end_matches('/').to_string()
        } else {
            format!("http://{addr}")
        };
        let http = Client::builder()
            .connect_timeout(Duration::from_millis(500))
            // Event streams stay open for the whole capture.
            .timeout(None)
            .build()?;
        let d = Daemon { base, token, http };
        match d.get("/health").timeout(Duration::from_secs(5)).send() {
            Ok(r) => {
                d.check(r).context("asking the daemon for its health")?;
                Ok(Some(d))
            }
            Err(e) if e.is_connect() => Ok(None),
            Err(e) => Err(e).with_context(|| format!("asking {} for its health", d.base)),
        }
    }

    fn with_token(&self, r: RequestBuilder) -> RequestBuilder {
        match &self.token {
            Some(t) => r.bearer_auth(t),
            None => r,
        }
    }

    fn get(&self, path: &str) -> RequestBuilder {
        self.with_token(self.http.get(format!("{}/api/v1{path}", self.base)))
    }

    fn post(&self, path: &str) -> RequestBuilder {
        self.with_token(self.http.post(format!("{}/api/v1{path}", self.base)))
    }

    /// The response if it is a success; else the daemon's error message.
    fn check(&self, r: Response) -> anyhow::Result<Response> {
        if r.status().is_success() {
            return Ok(r);
        }
        let status = r.status();
        let text = r.text().unwrap_or_default();
        let Ok(body) = serde_json::from_str::<ErrorBody>(&text) else {
            // A problem with a code this client does not know (a newer daemon's), or another
            // server's: its message still says what went wrong.
            #[derive(serde::Deserialize)]
            struct Message {
                message: String,
            }
            match serde_json::from_str::<Message>(&text) {
                Ok(m) => bail!(
                    "the daemon at {} answered {status}: {}",
                    self.base,
                    m.message
                ),
                Err(_) => bail!(
                    "the daemon at {} answered {status}, with no problem body",
                    self.base
                ),
            }
        };
        if body.error == ErrorCode::Busy {
            return Err(Busy(body.message).into());
        }
        bail!(
            "the daemon at {} answered {status}: {}",
            self.base,
            body.message
        )
    }

    /// An answer read into the type the daemon writes it from (`brdfd_api::answers`).
    pub fn typed<T: serde::de::DeserializeOwned>(&self, path: &str) -> anyhow::Result<T> {
        let r = self.check(self.get(path).send()?)?;
        r.json()
            .with_context(|| format!("the daemon at {} answered {path} otherwise", self.base))
    }

    /// Starts a capture; returns the session id.
    pub fn start(&self, plan: &Plan) -> anyhow::Result<String> {
        let r = self.check(self.post("/sessions").json(plan).send()?)?;
        let started: Started = r
            .json()
            .context("the daemon's answer is not a started capture")?;
        Ok(started.id)
    }

    pub fn resume(&self, id: &str) -> anyhow::Result<String> {
        // Every POST is JSON, a body or not (the daemon refuses others: docs/api.md).
        let r = self.check(
            self.post(&format!("/sessions/{id}/resume"))
                .json(&Empty {})
                .send()?,
        )?;
        let started: Started = r
            .json()
            .context("the daemon's answer is not a resumed capture")?;
        Ok(started.id)
    }

    /// Asks the daemon to stop a running capture.
    pub fn cancel(&self, id: &str) -> anyhow::Result<()> {
        self.check(
            self.post(&format!("/sessions/{id}/cancel"))
                .json(&Empty {})
                .send()?,
        )?;
        Ok(())
    }

    /// Tells a capture waiting for view `view` to be turned by hand that it is.
    pub fn proceed(&self, id: &str, view: usize) -> anyhow::Result<()> {
        self.check(
            self.post(&format!("/sessions/{id}/continue"))
                .json(&ContinueRequest { view: Some(view) })
                .send()?,
        )?;
        Ok(())
    }

    /// Follows a session's events until it finishes; returns the last one. A stream that
    /// drops before then (a proxy's timeout, a network hiccup, the daemon restarted) is opened
    /// again with the last event's id as `Last-Event-ID`, so it goes on after that event
    /// rather than from the first; [`RECONNECTS`] times in a row at most.
    pub fn follow(&self, id: &str, progress: &dyn Progress) -> anyhow::Result<Event> {
        let mut last_seen: Option<String> = None;
        let mut failures = 0;
        loop {
            let mut request = self.get(&format!("/sessions/{id}/events"));
            if let Some(seen) = &last_seen {
                request = request.header("Last-Event-ID", seen.as_str());
            }
            let dropped = match request.send() {
                // An answer that is not the stream (no such session, a token refused) is the
                // daemon's word, not a drop.
                Ok(r) => match read_events(self.check(r)?, progress, &mut last_seen)? {
                    Stream::Finished(e) => return Ok(e),
                    Stream::Dropped { events, why } => {
                        if events > 0 {
                            failures = 0;
                        }
                        why
                    }
                },
                Err(e) => e.into(),
            };
            failures += 1;
            if failures > RECONNECTS {
                return Err(dropped.context(
                    "the daemon's event stream ended before the capture finished (did the daemon stop?)",
                ));
            }
            tracing::debug!("the event stream dropped ({dropped:#}); opening it again");
            std::thread::sleep(RECONNECT_DELAY);
        }
    }
}

/// Times in a row the event stream is opened again after it dropped with no event between.
const RECONNECTS: u32 = 5;

/// The pause before opening a dropped stream again: a daemon that restarts is back within a
/// few of them.
const RECONNECT_DELAY: Duration = Duration::from_millis(500);

/// How one connection's event stream ended.
enum Stream {
    Finished(Event),
    /// Before `finished`, after `events` events.
    Dropped {
        events: usize,
        why: anyhow::Error,
    },
}

/// Reads Server-Sent Events (`id:` and `data: <json>` lines; comments, the keep-alives, start
/// with ':') until `finished` or the stream's end, noting each event's id in `last_seen`.
fn read_events(
    r: Response,
    progress: &dyn Progress,
    last_seen: &mut Option<String>,
) -> anyhow::Result<Stream> {
    let mut id = None;
    let mut events = 0;
    for line in BufReader::new(r).lines() {
        let line = match line {
            Ok(line) => line,
            Err(e) => {
                let why = anyhow::Error::from(e).context("reading the daemon's event stream");
                return Ok(Stream::Dropped { events, why });
            }
        };
        if let Some(i) = line.strip_prefix("id:") {
            id = Some(i.trim().to_string());
            continue;
        }
        let Some(data) = line.strip_prefix("data:") else {
            continue;
        };
        let e: Event = serde_json::from_str(data.trim())
            .with_context(|| format!("an event from the daemon: {data}"))?;
        events += 1;
        if let Some(id) = id.take() {
            *last_seen = Some(id);
        }
        if matches!(e, Event::Finished { .. }) {
            progress.event(e.clone());
            return Ok(Stream::Finished(e));
        }
        progress.event(e);
    }
    Ok(Stream::Dropped {
        events,
        why: anyhow::anyhow!("the stream ended"),
    })
}
