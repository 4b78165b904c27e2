//! The CLI's side of the daemon's API: is one running, start or resume a capture there, and
//! follow its events.

use std::io::{BufRead, BufReader};
use std::time::Duration;

use anyhow::{bail, Context};
use brdfd::rig::{Event, Plan, Progress};
use reqwest::blocking::{Client, RequestBuilder, Response};
use serde_json::Value;

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
        let body: Value = r.json().unwrap_or(Value::Null);
        let message = body["message"].as_str().unwrap_or("no message").to_string();
        if body["error"] == "busy" {
            return Err(Busy(message).into());
        }
        bail!("the daemon at {} answered {status}: {message}", self.base)
    }

    pub fn json(&self, path: &str) -> anyhow::Result<Value> {
        Ok(self.check(self.get(path).send()?)?.json()?)
    }

    /// Starts a capture; returns the session id.
    pub fn start(&self, plan: &Plan) -> anyhow::Result<String> {
        let r = self.check(self.post("/sessions").json(plan).send()?)?;
        let v: Value = r.json()?;
        Ok(v["id"]
            .as_str()
            .context("the daemon's answer has no id")?
            .to_string())
    }

    pub fn resume(&self, id: &str) -> anyhow::Result<String> {
        // Every POST is JSON, a body or not (the daemon refuses others: docs/api.md).
        let r = self.check(
            self.post(&format!("/sessions/{id}/resume"))
                .json(&serde_json::json!({}))
                .send()?,
        )?;
        let v: Value = r.json()?;
        Ok(v["id"]
            .as_str()
            .context("the daemon's answer has no id")?
            .to_string())
    }

    /// Asks the daemon to stop a running capture.
    pub fn cancel(&self, id: &str) -> anyhow::Result<()> {
        self.check(
            self.post(&format!("/sessions/{id}/cancel"))
                .json(&serde_json::json!({}))
                .send()?,
        )?;
        Ok(())
    }

    /// Tells a capture waiting for view `view` to be turned by hand that it is.
    pub fn proceed(&self, id: &str, view: usize) -> anyhow::Result<()> {
        self.check(
            self.post(&format!("/sessions/{id}/continue"))
                .json(&serde_json::json!({ "view": view }))
                .send()?,
        )?;
        Ok(())
    }

    /// Follows a session's events until it finishes; returns the last one.
    pub fn follow(&self, id: &str, progress: &dyn Progress) -> anyhow::Result<Event> {
        let r = self.check(self.get(&format!("/sessions/{id}/events")).send()?)?;
        let mut last = None;
        // Server-Sent Events: `data: <json>` lines; comments (keep-alives) start with ':'.
        for line in BufReader::new(r).lines() {
            let line = line.context("reading the daemon's event stream")?;
            let Some(data) = line.strip_prefix("data:") else {
                continue;
            };
            let e: Event = serde_json::from_str(data.trim())
                .with_context(|| format!("an event from the daemon: {data}"))?;
            let finished = matches!(e, Event::Finished { .. });
            progress.event(e.clone());
            last = Some(e);
            if finished {
                break;
            }
        }
        last.context(
            "the daemon's event stream ended before the capture finished (did the daemon stop?)",
        )
    }
}
