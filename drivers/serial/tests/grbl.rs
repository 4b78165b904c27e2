//! The GRBL turntable against the simulated GRBL 1.1 controller on a real pseudo-terminal
//! pair: turns that wait for the table to stop, homing, each axis and position report, and
//! every fault a bench meets ending in a clear error.

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use brdfd_serial::{looks_like_grbl, GrblTurntable, RigController, RigTimeouts, SerialError};
use brdfd_sim::grbl::{GrblConfig, GrblFaults, GrblPeer};
use serialport::SerialPort;

fn quick() -> RigTimeouts {
    RigTimeouts {
        answer: Duration::from_millis(500),
        min_speed_deg_s: 100.0,
        home: Duration::from_secs(5),
        boot: Duration::from_millis(300),
    }
}

fn table(config: GrblConfig, axis: char) -> (GrblPeer, GrblTurntable) {
    let (peer, port) = GrblPeer::start(config).unwrap();
    let table = GrblTurntable::new(Box::new(port), axis, quick()).unwrap();
    (peer, table)
}

#[test]
fn turns_wait_for_the_table_to_stop() {
    // 360°/s: a 90° turn takes 250 ms, and its `ok` comes at once, before the move ends.
    let (peer, mut t) = table(GrblConfig::default(), 'A');
    assert_eq!(t.identity.banner, "Grbl 1.1h");
    let start = Instant::now();
    assert!((t.rotate(90.0).unwrap() - 90.0).abs() < 1e-6);
    assert!(
        start.elapsed() >= Duration::from_millis(240),
        "answered before the table stopped: {:?}",
        start.elapsed()
    );
    // The simulated table has arrived when the host says so.
    assert!((peer.position('A') - 90.0).abs() < 1e-6);
    assert!((t.rotate(-120.0).unwrap() - 330.0).abs() < 1e-6);
    assert!((t.position().unwrap() - 330.0).abs() < 1e-6);
    assert!((peer.position('A') + 30.0).abs() < 1e-6);
    // Every move is relative for its own block only: the controller is left absolute.
    let log = peer.log();
    assert!(
        log.iter().any(|l| l == "G21 G91 G0 A90.000") && log.iter().any(|l| l == "G90"),
        "{log:?}"
    );
    assert!(
        log.iter().filter(|l| *l == "G4 P0.01").count() == 2,
        "{log:?}"
    );
}

#[test]
fn a_controller_slower_than_expected_is_waited_for_while_it_turns() {
    // 40°/s where the host expects at least 100°/s: a 90° turn outlasts the time allowed
    // for it, and the host, seeing the table still turning, waits on.
    let config = GrblConfig {
        rate_per_s: 40.0,
        ..GrblConfig::default()
    };
    let (peer, mut t) = table(config, 'A');
    assert!((t.rotate(90.0).unwrap() - 90.0).abs() < 1e-6);
    assert!((peer.position('A') - 90.0).abs() < 1e-6);
}

#[test]
fn a_three_axis_grbl_turns_on_the_axis_named_and_work_positions_are_read() {
    // Stock GRBL on an Uno has X, Y and Z; the table on X, the controller reporting work
    // positions beside a work offset a user's own job left.
    let config = GrblConfig {
        work_positions: true,
        work_offset: [12.5, 0.0, 0.0, 0.0],
        ..GrblConfig::default()
    };
    let (peer, mut t) = table(config, 'x');
    assert!((t.rotate(45.0).unwrap() - 45.0).abs() < 1e-6);
    assert!((peer.position('X') - 45.0).abs() < 1e-6);
    assert_eq!(peer.position('A'), 0.0);
}

#[test]
fn a_controller_locked_at_start_is_homed_when_asked_and_homing_can_be_asked() {
    // Homing enabled, and a startup line GRBL runs (and reports, `>G21:ok`) after homing.
    let config = GrblConfig {
        homing: true,
        startup_line: Some("G21".into()),
        ..GrblConfig::default()
    };
    let (peer, mut t) = table(config, 'A');
    // Opening it does not home it: `brdfd serial info` only looks.
    assert_eq!(peer.homings(), 0);
    assert_eq!(t.status().unwrap().state, "Alarm");
    let e = t.rotate(10.0).unwrap_err().to_string();
    assert!(
        e.contains("state Alarm") && e.contains("brdfd serial home"),
        "{e}"
    );
    // A capture needs it to turn: it homes it.
    assert!(t.unlock_by_homing().unwrap());
    assert_eq!(peer.homings(), 1, "{:?}", peer.log());
    assert!(!t.unlock_by_homing().unwrap());
    t.rotate(200.0).unwrap();
    assert_eq!(t.home().unwrap(), 0.0);
    assert_eq!(peer.homings(), 2);
    assert_eq!(peer.position('A'), 0.0);
}

#[test]
fn a_locked_controller_without_homing_says_how_to_unlock_it() {
    // A hard limit during a move: the controller stops, pushes ALARM:1 and ignores every
    // line until it is reset, which brdfd does; it is then locked in Alarm.
    let (peer, mut t) = table(GrblConfig::default(), 'A');
    peer.inject(GrblFaults {
        limit_after: Some(30.0),
        ..GrblFaults::default()
    });
    let e = t.rotate(90.0).unwrap_err().to_string();
    assert!(
        e.contains("ALARM:1") && e.contains("hard limit") && e.contains("brdfd reset"),
        "the alarm is named: {e}"
    );
    // Locked: the next turn is refused before anything is sent, with what to do.
    let e = t.rotate(10.0).unwrap_err().to_string();
    assert!(
        e.contains("state Alarm") && e.contains("$X"),
        "the lock is named: {e}"
    );
    // Homing is not enabled on this controller: `$H` is refused, and the error says so.
    let e = t.home().unwrap_err().to_string();
    assert!(e.contains("homing is not enabled ($22=0)"), "{e}");
}

#[test]
fn a_controller_that_resets_mid_turn_is_not_taken_for_one_that_arrived() {
    let (peer, mut t) = table(GrblConfig::default(), 'A');
    peer.inject(GrblFaults {
        reset_after: Some(20.0),
        ..GrblFaults::default()
    });
    // A board that resets (a brown-out) prints only its banner: that is not an arrival.
    let e = t.rotate(90.0).unwrap_err();
    assert!(matches!(e, SerialError::Unplugged { .. }), "{e}");
    assert!(e.to_string().contains("unplugged or reset"), "{e}");
    assert_eq!(peer.position('A'), 0.0);
}

#[test]
fn an_axis_the_controller_lacks_and_a_device_that_is_not_grbl_are_named() {
    let (peer, port) = GrblPeer::start(GrblConfig::default()).unwrap();
    let Err(e) = GrblTurntable::new(Box::new(port), 'C', quick()) else {
        panic!("a C axis was found on a four-axis controller");
    };
    let text = e.to_string();
    assert!(
        text.contains("has no C axis in its status report") && text.contains("grbl:x:"),
        "{text}"
    );
    drop(peer);
    let Err(e) = GrblTurntable::new(
        Box::new(serialport::TTYPort::pair().unwrap().1),
        'Q',
        quick(),
    ) else {
        panic!("Q taken for an axis");
    };
    assert!(e.to_string().contains("not an axis GRBL reports"), "{e}");
    // A device that answers, but not as GRBL (the rig protocol's box): no banner.
    let (mut device, client) = serialport::TTYPort::pair().unwrap();
    let quiet = std::thread::spawn(move || {
        device.set_timeout(Duration::from_millis(50)).unwrap();
        let mut buf = [0u8; 64];
        let until = Instant::now() + Duration::from_secs(6);
        while Instant::now() < until {
            if let Ok(n) = device.read(&mut buf) {
                if n > 0 {
                    let _ = device.write_all(b"ERR unknown command\r\n");
                }
            }
        }
    });
    let Err(e) = GrblTurntable::new(Box::new(client), 'A', quick()) else {
        panic!("a device without a banner was taken for GRBL");
    };
    assert!(
        matches!(e, SerialError::GrblTimeout { .. }) && e.to_string().contains("no GRBL banner"),
        "{e}"
    );
    quiet.join().unwrap();
}

#[test]
fn an_unplugged_controller_is_named() {
    let (peer, mut t) = table(GrblConfig::default(), 'A');
    peer.inject(GrblFaults {
        unplug_next: true,
        ..GrblFaults::default()
    });
    let e = t.rotate(30.0).unwrap_err();
    assert!(matches!(e, SerialError::Unplugged { .. }), "{e}");
    // The host sees the port close as the simulator's thread returns, a moment before the
    // thread counts as finished.
    let until = Instant::now() + Duration::from_secs(2);
    while !peer.is_finished() && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(peer.is_finished());
}

#[test]
fn the_simulated_controller_refuses_what_grbl_refuses() {
    // The simulator itself, spoken to directly: the errors GRBL documents for each mistake.
    let (_peer, mut port) = GrblPeer::start(GrblConfig::default()).unwrap();
    port.set_timeout(Duration::from_millis(50)).unwrap();
    let mut said = String::new();
    let mut ask = |line: &str| -> String {
        port.write_all(format!("{line}\n").as_bytes()).unwrap();
        let until = Instant::now() + Duration::from_millis(400);
        let mut buf = [0u8; 256];
        let mut got = String::new();
        while Instant::now() < until && !(got.contains("ok\r\n") || got.contains("error:")) {
            if let Ok(n) = port.read(&mut buf) {
                got.push_str(&String::from_utf8_lossy(&buf[..n]));
            }
        }
        said.push_str(&got);
        got
    };
    assert!(ask("G91 G1 A10").contains("error:22"), "no feed rate");
    assert!(ask("G91 G1 A10 F600").contains("ok"));
    assert!(ask("G38.2 A1").contains("error:20"), "unsupported");
    assert!(ask("$Q").contains("error:3"), "unknown $ command");
    assert!(ask("G0 A").contains("error:2"), "a letter without a value");
    assert!(ask("1G0").contains("error:1"), "a value without a letter");
    assert!(ask("$H").contains("error:5"), "homing not enabled");
    assert!(ask("$I").contains("[VER:1.1h"), "build info");
}

#[test]
fn a_rig_protocol_probe_tells_a_grbl_controller_for_what_it_is() {
    // `brdfd devices` asks every port `ID?`: GRBL's answer (its banner, or a status report
    // for the `?`) is not the rig protocol's, and is recognised as GRBL's.
    let (_peer, port) = GrblPeer::start(GrblConfig::default()).unwrap();
    let Err(SerialError::Protocol { line, .. }) = RigController::new(Box::new(port), quick())
    else {
        panic!("GRBL taken for a rig-protocol box");
    };
    assert!(looks_like_grbl(&line), "{line}");
    assert!(!looks_like_grbl("OK brdfd-turntable 1 FIRE ROT"));
    assert!(!looks_like_grbl("ERR unknown command"));
}
