//! The rig controller against the simulated trigger box and turntable on a real
//! pseudo-terminal pair: the same serial code as on a USB adapter, every answer checked, and
//! every fault ending in a clear error.

use std::time::{Duration, Instant};

use brdfd_serial::{ControlLine, RigController, RigTimeouts, SerialError, ShutterCable};
use brdfd_sim::serial::{PeerConfig, PeerFaults, SerialPeer};

fn quick() -> RigTimeouts {
    RigTimeouts {
        answer: Duration::from_millis(300),
        min_speed_deg_s: 100.0,
        home: Duration::from_secs(5),
        boot: Duration::from_millis(300),
    }
}

fn rig(config: PeerConfig) -> (SerialPeer, RigController) {
    let (peer, port) = SerialPeer::start(config).unwrap();
    let rig = RigController::new(Box::new(port), quick()).unwrap();
    (peer, rig)
}

#[test]
fn identifies_fires_and_turns() {
    let (peer, mut rig) = rig(PeerConfig::default());
    assert_eq!(rig.identity.name, "brdfd-sim-turntable");
    assert!(rig.identity.can_fire && rig.identity.can_rotate);
    let t = Instant::now();
    rig.fire(120).unwrap();
    assert!(
        t.elapsed() >= Duration::from_millis(120),
        "answered before the pulse ended"
    );
    assert_eq!(peer.fires(), vec![120]);
    assert!((rig.rotate(45.0).unwrap() - 45.0).abs() < 1e-6);
    assert!((rig.rotate(-90.0).unwrap() - 315.0).abs() < 1e-6);
    assert!((rig.position().unwrap() - 315.0).abs() < 1e-6);
    assert_eq!(rig.home().unwrap(), 0.0);
    assert_eq!(peer.position(), 0.0);
    // The device's own "# ..." log lines were skipped: every answer matched its command.
    assert_eq!(peer.log().len(), 8, "{:?}", peer.log());
}

#[test]
fn a_trigger_box_without_turntable_says_so() {
    let (_peer, mut rig) = rig(PeerConfig {
        name: "shutter-box".into(),
        can_rotate: false,
        ..PeerConfig::default()
    });
    rig.fire(5).unwrap();
    let e = rig.rotate(10.0).unwrap_err().to_string();
    assert!(e.contains("shutter-box) has no turntable"), "{e}");
    let e = rig.fire(0).unwrap_err().to_string();
    assert!(e.contains("outside 1..=60000 ms"), "{e}");
}

#[test]
fn each_fault_is_a_clear_error_and_the_link_carries_on() {
    let (peer, mut rig) = rig(PeerConfig::default());

    peer.inject(PeerFaults {
        silent_next: true,
        ..PeerFaults::default()
    });
    let e = rig.fire(10).unwrap_err();
    assert!(matches!(e, SerialError::Timeout { .. }), "{e}");
    assert!(e.to_string().contains("no answer within"), "{e}");
    // The link is out of step after a timeout: the next command resynchronises (with `ID?`,
    // which would take the next fault), so one command runs before the next fault.
    rig.fire(10).unwrap();

    peer.inject(PeerFaults {
        garble_next: true,
        ..PeerFaults::default()
    });
    let e = rig.position().unwrap_err();
    assert!(matches!(e, SerialError::Protocol { .. }), "{e}");
    rig.fire(10).unwrap();

    peer.inject(PeerFaults {
        error_next: Some("motor driver overheated".into()),
        ..PeerFaults::default()
    });
    let e = rig.position().unwrap_err().to_string();
    assert!(e.contains("ERR motor driver overheated"), "{e}");

    peer.inject(PeerFaults {
        slip_deg: Some(3.0),
        ..PeerFaults::default()
    });
    let e = rig.rotate(90.0).unwrap_err().to_string();
    assert!(e.contains("stopped at 87.00° instead of 90.00°"), "{e}");

    // After all that, the link still works.
    rig.fire(10).unwrap();
    assert!((rig.position().unwrap() - 87.0).abs() < 1e-6);
}

#[test]
fn an_unplugged_device_is_named() {
    let (peer, mut rig) = rig(PeerConfig::default());
    peer.inject(PeerFaults {
        unplug_next: true,
        ..PeerFaults::default()
    });
    let e = rig.fire(10).unwrap_err();
    assert!(
        matches!(e, SerialError::Unplugged { .. }),
        "expected Unplugged, got {e}"
    );
    assert!(e.to_string().contains("unplugged or reset"), "{e}");
    // The client saw the port close; the peer's thread ends just after.
    let t = Instant::now();
    while !peer.is_finished() {
        assert!(
            t.elapsed() < Duration::from_secs(2),
            "the peer never closed its end"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[test]
fn a_missing_port_is_named() {
    let e = RigController::open("/dev/ttyUSB-brdfd-none", quick())
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("does not exist") && e.contains("brdfd devices"),
        "{e}"
    );
}

/// A pseudo-terminal has no modem lines, so the cable cannot drive DTR there; it must say so
/// rather than pretend to fire.
#[test]
fn a_cable_on_a_port_without_modem_lines_says_so() {
    let (_peer, port) = SerialPeer::start(PeerConfig::default()).unwrap();
    match ShutterCable::new(Box::new(port), ControlLine::Dtr, false) {
        Ok(mut cable) => {
            // Some kernels accept TIOCMSET on a pty; then a pulse must take its time.
            let t = Instant::now();
            cable.fire(30).unwrap();
            assert!(t.elapsed() >= Duration::from_millis(30));
        }
        Err(e) => assert!(e.to_string().contains("cannot drive Dtr"), "{e}"),
    }
}

/// Issue 20, D15: the link resynchronises. An answer that comes after its command timed out,
/// and a line the device says out of turn, are not taken for the next command's answer.
#[test]
fn late_answers_and_stray_lines_do_not_answer_the_next_command() {
    let (peer, mut rig) = rig(PeerConfig::default());
    rig.rotate(30.0).unwrap();
    // The answer to this pulse comes 0.5 s late, after the host's 0.3 s timeout.
    peer.inject(PeerFaults {
        late_next: Some(Duration::from_millis(500)),
        ..PeerFaults::default()
    });
    let e = rig.fire(5).unwrap_err();
    assert!(matches!(e, SerialError::Timeout { .. }), "{e}");
    // The late "OK" must not answer the position.
    let at = rig.position().unwrap();
    assert!((at - 30.0).abs() < 1e-6, "{at} {:?}", peer.log());
    // Nor a stray "OK 123.00" after an answer.
    peer.inject(PeerFaults {
        stray_next: Some("OK 123.00".into()),
        ..PeerFaults::default()
    });
    rig.fire(5).unwrap();
    let at = rig.position().unwrap();
    assert!((at - 30.0).abs() < 1e-6, "{at} {:?}", peer.log());
    assert!((rig.rotate(10.0).unwrap() - 40.0).abs() < 1e-6);
}
