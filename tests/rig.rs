//! The rig's device workers against simulated devices over their real protocols.

use std::sync::Arc;
use std::time::{Duration, Instant};

use brdfd_rig::selector::Selector;
use brdfd_rig::worker::{Link, Worker};
use brdfd_rig::{open, Device};
use brdfd_sim::theta::{OscServer, ThetaConfig};
use brdfd_sim::SizedPayload;
use brdfd_theta::Theta;

fn theta_server(addr: &str) -> OscServer {
    OscServer::start(
        addr,
        Arc::new(SizedPayload { bytes: 1000 }),
        ThetaConfig::default(),
    )
    .expect("the simulated THETA starts")
}

fn wait_for(what: &str, mut done: impl FnMut() -> bool) {
    let start = Instant::now();
    while !done() {
        assert!(start.elapsed() < Duration::from_secs(60), "never: {what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A THETA switched off between captures is noticed by the keep-alive, and opened again
/// when it is back, without anyone asking.
#[test]
fn a_theta_that_goes_away_is_noticed_and_reopened_when_it_returns() {
    let server = theta_server("127.0.0.1:0");
    let addr = server.addr.to_string();
    let selector = Selector::Osc(server.url());
    let worker: Worker<Theta> = {
        let s = selector.clone();
        Worker::spawn(
            "theta",
            &selector.to_string(),
            Box::new(move || open::theta(&s, None, open::loopback_timeouts())),
            Duration::from_millis(100),
        )
    };
    let id = worker.call(|t| Ok(t.identity())).unwrap();
    assert!(id.starts_with("RICOH THETA V"), "{id}");
    assert_eq!(worker.status().opened, 1);

    drop(server);
    wait_for("the worker notices the THETA has gone", || {
        worker.status().state == Link::Lost
    });
    let err = worker.status().last_error.unwrap_or_default();
    assert!(!err.is_empty());

    let _back = theta_server(&addr);
    wait_for("the worker opens the THETA again", || {
        worker.status().state == Link::Open
    });
    assert_eq!(worker.status().opened, 2);
    worker.call(|t| Ok(t.keep_alive()?)).unwrap();
}
