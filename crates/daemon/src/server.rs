//! The daemon's HTTP/1 server: the API's router served with limits that a bare `axum::serve`
//! does not set, because the daemon must keep answering, and keep its capture running,
//! whatever a client does before it authenticates.
//!
//! - **Header time.** A connection that has not sent a whole request head within
//!   [`Limits::header_timeout`] is closed, whether it is new or idle between requests
//!   (hyper's header-read timeout, which needs a timer to run at all).
//! - **Connections.** At most [`Limits::max_connections`] are open. A new one beyond that
//!   closes the oldest connection with no request in flight (idle, or with half a request
//!   head), so 1,000 idle sockets cannot lock a bench user out; if every connection is busy,
//!   the new one is refused. A request is busy until its response is handed back; the one
//!   request with a body, a plan, must arrive within 10 s (`api`), so only event streams stay
//!   busy for long. The cap stays below the process's file limit, so a capture always has
//!   descriptors left for its files.
//! - **Write time.** A response the client stops reading fails once a write has waited
//!   [`Limits::write_timeout`], and its connection is dropped ([`WriteTimeout`]): a client that
//!   asks for a large file and never reads it holds neither memory nor its slot for long.
//! - **Shutdown.** On the signal, no connection is accepted; open ones are asked to finish
//!   their response, and after [`Limits::shutdown_grace`] the rest are dropped, so a client
//!   holding a request open cannot keep the daemon from stopping.

use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::{Duration, Instant};

use axum::body::Body;
use axum::extract::Request;
use axum::response::Response;
use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use tokio::net::TcpListener;
use tokio::sync::{watch, Notify};

/// The server's limits (see the module's documentation).
#[derive(Clone, Debug)]
pub struct Limits {
    pub max_connections: usize,
    pub header_timeout: Duration,
    pub write_timeout: Duration,
    pub shutdown_grace: Duration,
}

/// Connections at most, whatever the file limit allows: far more than a bench has clients.
pub const MAX_CONNECTIONS: usize = 4096;

/// File descriptors kept out of the connection cap for the daemon's own work: a capture's
/// session files, device handles, the simulators' sockets.
pub const RESERVED_FILES: usize = 256;

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_connections: connection_cap(raise_file_limit()),
            header_timeout: Duration::from_secs(10),
            // A reader on a slow link still takes a 64 KiB chunk well within this.
            write_timeout: Duration::from_secs(30),
            shutdown_grace: Duration::from_secs(1),
        }
    }
}

/// Raises the soft limit on open files to the hard limit (a server's usual first step) and
/// returns the soft limit now in force.
fn raise_file_limit() -> usize {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit and setrlimit only read and write the struct passed.
    unsafe {
        if libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim) != 0 {
            return 1024;
        }
        if lim.rlim_cur < lim.rlim_max {
            let raised = libc::rlimit {
                rlim_cur: lim.rlim_max,
                rlim_max: lim.rlim_max,
            };
            if libc::setrlimit(libc::RLIMIT_NOFILE, &raised) == 0 {
                lim = raised;
            }
        }
    }
    usize::try_from(lim.rlim_cur).unwrap_or(usize::MAX)
}

/// The connection cap under a file limit of `files`: [`RESERVED_FILES`] kept for the daemon,
/// at least 16 connections, at most [`MAX_CONNECTIONS`].
pub fn connection_cap(files: usize) -> usize {
    files
        .saturating_sub(RESERVED_FILES)
        .clamp(16, MAX_CONNECTIONS)
}

/// One open connection, as the accept loop sees it.
struct Open {
    id: u64,
    opened: Instant,
    /// Requests whose response has not finished.
    in_flight: Arc<AtomicUsize>,
    close: Arc<Notify>,
}

/// Serves `app` on `listener` until `shutdown` resolves, within `limits`.
pub async fn serve(
    listener: TcpListener,
    app: Router,
    limits: Limits,
    shutdown: impl Future<Output = ()>,
) -> std::io::Result<()> {
    let open: Arc<Mutex<Vec<Open>>> = Arc::default();
    let (stop_tx, stop_rx) = watch::channel(false);
    let mut tasks = tokio::task::JoinSet::new();
    let mut next_id = 0u64;
    tokio::pin!(shutdown);
    loop {
        let (stream, peer) = tokio::select! {
            _ = &mut shutdown => break,
            accepted = listener.accept() => match accepted {
                Ok(a) => a,
                Err(e) => {
                    // Out of descriptors or a connection reset before accept: not fatal.
                    // A short pause keeps an EMFILE from spinning the loop.
                    tracing::warn!("accepting a connection: {e}");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            },
        };
        while tasks.try_join_next().is_some() {}
        if !make_room(&open, limits.max_connections) {
            tracing::warn!(%peer, "refused: {} connections, all busy", limits.max_connections);
            drop(stream);
            continue;
        }
        next_id += 1;
        let entry = Open {
            id: next_id,
            opened: Instant::now(),
            in_flight: Arc::default(),
            close: Arc::default(),
        };
        let (id, in_flight, close) = (entry.id, entry.in_flight.clone(), entry.close.clone());
        open.lock().expect("connections").push(entry);
        let service = Counted {
            app: app.clone(),
            in_flight,
            peer,
        };
        let (open, mut stop, limits) = (open.clone(), stop_rx.clone(), limits.clone());
        tasks.spawn(async move {
            let mut builder = hyper::server::conn::http1::Builder::new();
            builder
                .timer(TokioTimer::new())
                .header_read_timeout(limits.header_timeout);
            let conn = builder.serve_connection(
                TokioIo::new(WriteTimeout::new(stream, limits.write_timeout)),
                hyper_util::service::TowerToHyperService::new(service),
            );
            tokio::pin!(conn);
            tokio::select! {
                _ = conn.as_mut() => {}
                _ = close.notified() => {}
                _ = stop.changed() => {
                    conn.as_mut().graceful_shutdown();
                    let _ = tokio::time::timeout(limits.shutdown_grace, conn.as_mut()).await;
                }
            }
            open.lock().expect("connections").retain(|o| o.id != id);
        });
    }
    drop(listener);
    let _ = stop_tx.send(true);
    // Every connection ends within the grace (dropped after it); this bound only guards
    // against a task that does not.
    let _ = tokio::time::timeout(2 * limits.shutdown_grace, async {
        while tasks.join_next().await.is_some() {}
    })
    .await;
    Ok(())
}

/// Makes room for one more connection under `cap`: closes the oldest connection with no
/// request in flight if the cap is reached. False if every connection is busy.
fn make_room(open: &Mutex<Vec<Open>>, cap: usize) -> bool {
    let mut open = open.lock().expect("connections");
    if open.len() < cap {
        return true;
    }
    let idle = open
        .iter()
        .enumerate()
        .filter(|(_, o)| o.in_flight.load(Ordering::SeqCst) == 0)
        .min_by_key(|(_, o)| o.opened)
        .map(|(i, _)| i);
    match idle {
        Some(i) => {
            let evicted = open.swap_remove(i);
            // notify_one stores a permit, so the connection closes even if it is not waiting yet.
            evicted.close.notify_one();
            true
        }
        None => false,
    }
}

/// The router, counting each request in flight on its connection until its response body has
/// been sent (an event stream counts for as long as it runs).
#[derive(Clone)]
struct Counted {
    app: Router,
    in_flight: Arc<AtomicUsize>,
    /// The client's address, for the routes (`ConnectInfo`): the token's throttle.
    peer: std::net::SocketAddr,
}

impl tower::Service<Request<hyper::body::Incoming>> for Counted {
    type Response = Response;
    type Error = std::convert::Infallible;
    type Future = Pin<Box<dyn Future<Output = Result<Response, Self::Error>> + Send>>;

    fn poll_ready(&mut self, _: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        Poll::Ready(Ok(()))
    }

    fn call(&mut self, req: Request<hyper::body::Incoming>) -> Self::Future {
        let guard = InFlight::new(self.in_flight.clone());
        let app = self.app.clone();
        let mut req = req.map(Body::new);
        req.extensions_mut()
            .insert(axum::extract::ConnectInfo(self.peer));
        Box::pin(async move {
            let response = tower::ServiceExt::oneshot(app, req).await?;
            Ok(response.map(|body| {
                Body::new(Guarded {
                    body,
                    _guard: guard,
                })
            }))
        })
    }
}

/// One request in flight; counted down when dropped.
struct InFlight(Arc<AtomicUsize>);

impl InFlight {
    fn new(count: Arc<AtomicUsize>) -> InFlight {
        count.fetch_add(1, Ordering::SeqCst);
        InFlight(count)
    }
}

impl Drop for InFlight {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::SeqCst);
    }
}

/// A response body that holds its request's [`InFlight`] until it is sent or dropped.
struct Guarded {
    body: Body,
    _guard: InFlight,
}

impl http_body::Body for Guarded {
    type Data = axum::body::Bytes;
    type Error = axum::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<http_body::Frame<Self::Data>, Self::Error>>> {
        Pin::new(&mut self.body).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.body.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.body.size_hint()
    }
}

/// A connection whose writes must make progress: a write (or flush) that has waited `limit`
/// for the client to take bytes fails with `TimedOut`, and hyper then drops the connection.
/// Time without writing (an event stream between events) does not count.
pub struct WriteTimeout<S> {
    inner: S,
    limit: Duration,
    /// Running while a write waits.
    stalled: Option<Pin<Box<tokio::time::Sleep>>>,
}

impl<S> WriteTimeout<S> {
    pub fn new(inner: S, limit: Duration) -> Self {
        WriteTimeout {
            inner,
            limit,
            stalled: None,
        }
    }

    /// After the inner write was not ready: still waiting, or past the limit.
    fn wait<T>(&mut self, cx: &mut Context<'_>) -> Poll<std::io::Result<T>> {
        let limit = self.limit;
        let sleep = self
            .stalled
            .get_or_insert_with(|| Box::pin(tokio::time::sleep(limit)));
        match sleep.as_mut().poll(cx) {
            Poll::Ready(()) => Poll::Ready(Err(std::io::Error::new(
                std::io::ErrorKind::TimedOut,
                format!(
                    "the client took nothing for {} s; connection dropped",
                    limit.as_secs_f64()
                ),
            ))),
            Poll::Pending => Poll::Pending,
        }
    }

    fn progress<T>(
        &mut self,
        polled: Poll<std::io::Result<T>>,
        cx: &mut Context<'_>,
    ) -> Poll<std::io::Result<T>> {
        match polled {
            Poll::Pending => self.wait(cx),
            ready => {
                self.stalled = None;
                ready
            }
        }
    }
}

impl<S: tokio::io::AsyncRead + Unpin> tokio::io::AsyncRead for WriteTimeout<S> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_read(cx, buf)
    }
}

impl<S: tokio::io::AsyncWrite + Unpin> tokio::io::AsyncWrite for WriteTimeout<S> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        let polled = Pin::new(&mut self.inner).poll_write(cx, buf);
        self.progress(polled, cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        let polled = Pin::new(&mut self.inner).poll_write_vectored(cx, bufs);
        self.progress(polled, cx)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        let polled = Pin::new(&mut self.inner).poll_flush(cx);
        self.progress(polled, cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cap_leaves_descriptors_for_the_daemon() {
        assert_eq!(connection_cap(1024), 1024 - RESERVED_FILES);
        assert_eq!(connection_cap(100), 16);
        assert_eq!(connection_cap(1 << 20), MAX_CONNECTIONS);
    }

    #[test]
    fn room_is_made_by_closing_the_oldest_idle_connection() {
        let entry = |id, age_ms: u64, busy: usize| Open {
            id,
            opened: Instant::now() - Duration::from_millis(age_ms),
            in_flight: Arc::new(AtomicUsize::new(busy)),
            close: Arc::default(),
        };
        // The oldest (id 1) is busy; the oldest idle one (id 2) goes.
        let open = Mutex::new(vec![entry(1, 300, 1), entry(2, 200, 0), entry(3, 100, 0)]);
        assert!(make_room(&open, 3));
        let ids: Vec<u64> = open.lock().unwrap().iter().map(|o| o.id).collect();
        assert!(!ids.contains(&2) && ids.len() == 2, "{ids:?}");
        // Under the cap nothing is closed; with every connection busy the new one is refused.
        assert!(make_room(&open, 3));
        let busy = Mutex::new(vec![entry(1, 300, 1), entry(2, 200, 2)]);
        assert!(!make_room(&busy, 2));
    }
}
