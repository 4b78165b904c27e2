//! Our THETA client against the simulated THETA: over HTTP on loopback (the real server, the
//! real client) and over the in-memory USB pipe (the real PTP code), in single and bracket
//! mode, and through every injected fault. Each fault must end in good frames or a clear
//! error.

use std::sync::Arc;
use std::time::{Duration, Instant};

use brdfd_ptp::transport::usb::UsbTransport;
use brdfd_ptp::{Camera, Timeouts};
use brdfd_sim::ptp::{usb, Profile, Responder};
use brdfd_sim::theta::{OscServer, ThetaConfig, ThetaFaults};
use brdfd_sim::{ImageSource, Shot};
use brdfd_theta::{BracketPlan, Credentials, Exposure, HttpTimeouts, OscClient, Theta, ThetaError};
use serde_json::json;

/// Frames that say how they were exposed, so a test can check each frame's exposure.
struct Labelled;

impl ImageSource for Labelled {
    fn photo(&self, s: &Shot) -> Result<Vec<u8>, String> {
        // Long enough that a download has a middle to drop the connection in.
        let mut v = format!(
            "shutter={:.8} iso={} f={} seq={};",
            s.shutter_s, s.iso, s.f_number, s.sequence
        )
        .into_bytes();
        v.resize(200_000, b'.');
        Ok(v)
    }
    fn dimensions(&self) -> (u32, u32) {
        (1024, 512)
    }
}

fn label(frame: &[u8]) -> String {
    let s = String::from_utf8_lossy(frame);
    s.split(';').next().unwrap_or("").to_string()
}

fn config() -> ThetaConfig {
    ThetaConfig {
        shot_time: Duration::from_millis(20),
        ..ThetaConfig::default()
    }
}

fn quick() -> HttpTimeouts {
    HttpTimeouts {
        request: Duration::from_secs(2),
        poll: Duration::from_millis(10),
        command: Duration::from_secs(10),
        download: Duration::from_secs(5),
        retry_budget: Duration::from_secs(5),
    }
}

fn server() -> OscServer {
    OscServer::start("127.0.0.1:0", Arc::new(Labelled), config()).unwrap()
}

fn connect(s: &OscServer) -> Theta {
    Theta::connect_http(&s.url(), None, quick()).unwrap()
}

fn no_progress() -> impl FnMut(&str, f64) + Send {
    |_, _| {}
}

#[test]
fn prepare_sets_the_camera_up_for_light_measurement() {
    let s = server();
    let mut t = connect(&s);
    assert!(t.describe().starts_with("RICOH THETA V (serial 00165759"));
    let report = t.prepare().unwrap();
    // Seven settings and the JPEG format; the V has no `_function`, which is reported.
    assert_eq!(report.len(), 8, "{report:?}");
    assert!(report.contains(&"skipped (not on this model): normal shooting function".into()));
    assert_eq!(
        s.option("fileFormat"),
        Some(json!({"type": "jpeg", "width": 5376, "height": 2688}))
    );
    assert_eq!(s.option("exposureProgram"), Some(json!(1)));
    assert_eq!(s.option("offDelay"), Some(json!(65535)));
    assert_eq!(s.option("sleepDelay"), Some(json!(65535)));
    assert_eq!(s.option("_filter"), Some(json!("off")));
    assert_eq!(s.option("whiteBalance"), Some(json!("_colorTemperature")));
}

#[test]
fn single_shot_over_http_is_exposed_as_asked() {
    let s = server();
    let mut t = connect(&s);
    t.prepare().unwrap();
    let plan = BracketPlan::single(Exposure {
        shutter_s: 1.0 / 250.0,
        iso: 200,
    });
    let mut fractions = Vec::new();
    let frames = t.capture(&plan, &mut |_, f| fractions.push(f)).unwrap();
    assert_eq!(frames.len(), 1);
    assert_eq!(frames[0].name, "R0010001.JPG");
    assert_eq!(
        label(&frames[0].data),
        "shutter=0.00400000 iso=200 f=2 seq=1"
    );
    assert_eq!(frames[0].data.len(), 200_000);
    assert!(fractions.iter().all(|f| (0.0..=1.0).contains(f)) && fractions.last() == Some(&1.0));
}

#[test]
fn light_probe_bracket_over_http_comes_back_in_plan_order() {
    let s = server();
    let mut t = connect(&s);
    t.prepare().unwrap();
    let plan = BracketPlan::light_probe();
    let frames = t.capture(&plan, &mut no_progress()).unwrap();
    assert_eq!(frames.len(), 8);
    for (i, (f, e)) in frames.iter().zip(&plan.shots).enumerate() {
        // 1/16000 and the rest are all THETA V speeds, so nothing is snapped.
        assert_eq!(f.asked, *e);
        assert_eq!(
            label(&f.data),
            format!("shutter={:.8} iso=100 f=2 seq={}", e.shutter_s, i + 1)
        );
    }
    // One bracket, one startCapture.
    let log = s.log();
    assert_eq!(
        log.iter()
            .filter(|l| l.contains("camera.startCapture"))
            .count(),
        1
    );
    assert_eq!(s.file_count(), 8);
}

#[test]
fn a_plan_longer_than_one_bracket_is_shot_as_several_and_snapped_to_the_camera() {
    let s = server();
    let mut t = connect(&s);
    t.prepare().unwrap();
    let plan = BracketPlan {
        // 15 frames; 1/7 s is not a THETA speed (1/8 is nearest in log terms: ln 8/7 = 0.13
        // against ln 7/6 = 0.15), ISO 90 is between 80 and 100 (nearer 100 in log terms).
        shots: (0..15)
            .map(|i| Exposure {
                shutter_s: if i == 0 {
                    1.0 / 7.0
                } else {
                    1.0 / (100.0 * (i as f64))
                },
                iso: if i == 0 { 90 } else { 100 },
            })
            .collect(),
    };
    let frames = t.capture(&plan, &mut no_progress()).unwrap();
    assert_eq!(frames.len(), 15);
    assert_eq!(
        frames[0].asked,
        Exposure {
            shutter_s: 1.0 / 8.0,
            iso: 100
        }
    );
    assert!(label(&frames[0].data).starts_with("shutter=0.12500000 iso=100"));
    let log = s.log();
    assert_eq!(
        log.iter()
            .filter(|l| l.contains("camera.startCapture"))
            .count(),
        2
    );
}

#[tokio::test]
async fn a_second_capture_while_shooting_is_refused_as_busy() {
    let s = OscServer::start(
        "127.0.0.1:0",
        Arc::new(Labelled),
        ThetaConfig {
            shot_time: Duration::from_millis(300),
            ..ThetaConfig::default()
        },
    )
    .unwrap();
    let c = OscClient::new(&s.url(), None, quick()).unwrap();
    let first = c.execute("camera.takePicture", json!({})).await.unwrap();
    assert!(first.id.is_some());
    let state = c.state().await.unwrap();
    assert_eq!(state.state.capture_status, "shooting");
    match c.execute("camera.takePicture", json!({})).await {
        Err(ThetaError::Command { code, status, .. }) => {
            assert_eq!((code.as_str(), status), ("disabledCommand", 403))
        }
        other => panic!("expected disabledCommand, got {other:?}"),
    }
    let before = c
        .check_for_updates("FIG_0000")
        .await
        .unwrap()
        .state_fingerprint;
    let done = c
        .run(
            "camera.getOptions",
            json!({ "optionNames": ["iso"] }),
            &mut |_, _| {},
        )
        .await
        .unwrap();
    assert_eq!(done.options()["iso"], 0);
    // Wait for the first shot; the fingerprint moves when it lands.
    let id = first.id.unwrap();
    let start = Instant::now();
    loop {
        let st = c.status(&id, "takePicture").await.unwrap();
        if st.file_urls().len() == 1 {
            break;
        }
        assert!(start.elapsed() < Duration::from_secs(5));
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let after = c
        .check_for_updates(&before)
        .await
        .unwrap()
        .state_fingerprint;
    assert_ne!(before, after);
}

#[test]
fn service_unavailable_is_retried_until_the_camera_answers() {
    let s = server();
    let mut t = connect(&s);
    t.prepare().unwrap();
    s.inject(ThetaFaults {
        unavailable: 4,
        ..ThetaFaults::default()
    });
    let frames = t
        .capture(&BracketPlan::light_probe(), &mut no_progress())
        .unwrap();
    assert_eq!(frames.len(), 8);
    let n503 = s.log().len();
    assert!(n503 > 8, "{n503}");
}

#[test]
fn service_unavailable_beyond_the_budget_is_a_clear_error() {
    let s = server();
    let mut t = Theta::connect_http(
        &s.url(),
        None,
        HttpTimeouts {
            retry_budget: Duration::from_millis(300),
            ..quick()
        },
    )
    .unwrap();
    s.inject(ThetaFaults {
        unavailable: 1000,
        ..ThetaFaults::default()
    });
    let e = t.prepare().unwrap_err().to_string();
    assert!(e.contains("serviceUnavailable (HTTP 503)"), "{e}");
    assert!(e.contains("press its shutter or power button"), "{e}");
}

#[test]
fn a_sleeping_camera_is_waited_for_or_named() {
    let s = server();
    let mut t = connect(&s);
    t.prepare().unwrap();
    s.inject(ThetaFaults {
        asleep_for: Some(Duration::from_millis(400)),
        ..ThetaFaults::default()
    });
    let frames = t
        .capture(
            &BracketPlan::single(Exposure {
                shutter_s: 0.01,
                iso: 100,
            }),
            &mut no_progress(),
        )
        .unwrap();
    assert_eq!(frames.len(), 1);

    let mut short = Theta::connect_http(
        &s.url(),
        None,
        HttpTimeouts {
            retry_budget: Duration::from_millis(200),
            ..quick()
        },
    )
    .unwrap();
    s.inject(ThetaFaults {
        asleep_for: Some(Duration::from_secs(3)),
        ..ThetaFaults::default()
    });
    let e = short.prepare().unwrap_err().to_string();
    assert!(e.contains("waking from sleep"), "{e}");
}

#[test]
fn a_slow_answer_is_retried_when_safe_and_named_when_not() {
    let s = server();
    let timeouts = HttpTimeouts {
        request: Duration::from_millis(300),
        ..quick()
    };
    let mut t = Theta::connect_http(&s.url(), None, timeouts).unwrap();
    t.prepare().unwrap();
    // setOptions is idempotent: a slow answer is sent again, and the capture succeeds.
    s.inject(ThetaFaults {
        slow: Some((1, Duration::from_millis(800))),
        ..ThetaFaults::default()
    });
    let plan = BracketPlan::single(Exposure {
        shutter_s: 0.01,
        iso: 100,
    });
    assert_eq!(t.capture(&plan, &mut no_progress()).unwrap().len(), 1);
    // takePicture may have fired: a lost answer is an error, never a second shot.
    let c = OscClient::new(&s.url(), None, timeouts).unwrap();
    s.inject(ThetaFaults {
        slow: Some((1, Duration::from_millis(800))),
        ..ThetaFaults::default()
    });
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let e = rt
        .block_on(c.execute("camera.takePicture", json!({})))
        .unwrap_err();
    assert!(matches!(e, ThetaError::Timeout { .. }), "{e}");
    assert!(e.to_string().contains("no answer from the THETA"), "{e}");
    std::thread::sleep(Duration::from_millis(900));
    let takes = s
        .log()
        .iter()
        .filter(|l| l.contains("camera.takePicture"))
        .count();
    assert_eq!(
        takes, 2,
        "one from the capture above, one from the timed-out request"
    );
}

#[test]
fn a_dropped_download_is_fetched_again_whole() {
    let s = server();
    let mut t = connect(&s);
    t.prepare().unwrap();
    s.inject(ThetaFaults {
        drop_download_after: Some(70_000),
        ..ThetaFaults::default()
    });
    let frames = t
        .capture(&BracketPlan::light_probe(), &mut no_progress())
        .unwrap();
    assert!(frames.iter().all(|f| f.data.len() == 200_000));
    assert!(label(&frames[0].data).starts_with("shutter=0.00006250"));
    let gets = s
        .log()
        .iter()
        .filter(|l| l.starts_with("GET /files/"))
        .count();
    assert_eq!(gets, 9, "8 frames, one of them twice");
}

#[test]
fn file_urls_off_the_camera_are_refused() {
    let s = server();
    let mut t = connect(&s);
    t.prepare().unwrap();
    s.inject(ThetaFaults {
        foreign_file_urls: true,
        ..ThetaFaults::default()
    });
    let e = t
        .capture(
            &BracketPlan::single(Exposure {
                shutter_s: 0.01,
                iso: 100,
            }),
            &mut no_progress(),
        )
        .unwrap_err();
    assert!(matches!(e, ThetaError::ForeignUrl { .. }), "{e}");
    assert!(e.to_string().contains("192.0.2.1"), "{e}");
}

/// Issue 20, dependency: digest_auth 0.3 panics on a challenge that is not ASCII. A camera
/// (or anything on its address) sending one gets a clear error from brdfd, not a panic.
#[test]
fn a_challenge_that_is_not_ascii_is_an_error_not_a_panic() {
    use std::io::{Read, Write};
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    let server = std::thread::spawn(move || {
        // Every request of the connection attempt gets the same 401.
        for stream in listener.incoming().take(4) {
            let Ok(mut s) = stream else { return };
            let mut buf = [0u8; 4096];
            let _ = s.read(&mut buf);
            let answer = b"HTTP/1.1 401 Unauthorized\r\nContent-Length: 0\r\nConnection: close\r\nWWW-Authenticate: Digest realm=\"cam\xc3\xa9ra\", nonce=\"\xff\xfe\", qop=\"auth\"\r\n\r\n".to_vec();
            let _ = s.write_all(&answer);
        }
    });
    let creds = Credentials {
        user: "THETAYL00165759".into(),
        password: "00165759".into(),
    };
    let e = Theta::connect_http(&url, Some(creds), quick())
        .err()
        .expect("a camera whose challenge cannot be read")
        .to_string();
    assert!(e.contains("not ASCII"), "{e}");
    drop(server);
}

#[test]
fn digest_authentication_in_client_mode() {
    let creds = ("THETAYL00165759".to_string(), "00165759".to_string());
    let s = OscServer::start(
        "127.0.0.1:0",
        Arc::new(Labelled),
        ThetaConfig {
            credentials: Some(creds.clone()),
            ..config()
        },
    )
    .unwrap();
    let good = Credentials {
        user: creds.0.clone(),
        password: creds.1.clone(),
    };
    let mut t = Theta::connect_http(&s.url(), Some(good), quick()).unwrap();
    t.prepare().unwrap();
    let frames = t
        .capture(&BracketPlan::light_probe(), &mut no_progress())
        .unwrap();
    assert_eq!(frames.len(), 8);
    // The challenge is answered once and reused (nonce count rising) for every request after.
    let log = s.log();
    let requests = log.iter().filter(|l| !l.starts_with("  ")).count();
    let challenges = log.iter().filter(|l| l.contains("401 challenge")).count();
    assert!(requests > 20, "{requests}");
    assert_eq!(challenges, 1, "{log:?}");

    let e = Theta::connect_http(&s.url(), None, quick())
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("asks for a user and password"), "{e}");
    let bad = Credentials {
        user: creds.0,
        password: "wrong".into(),
    };
    let e = Theta::connect_http(&s.url(), Some(bad), quick())
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("refused the credentials"), "{e}");
}

#[tokio::test]
async fn list_files_and_delete() {
    let s = server();
    let c = OscClient::new(&s.url(), None, quick()).unwrap();
    let done = c
        .run("camera.takePicture", json!({}), &mut |_, _| {})
        .await
        .unwrap();
    let url = done.file_urls().remove(0);
    let list = c
        .execute(
            "camera.listFiles",
            json!({ "fileType": "image", "entryCount": 10, "maxThumbSize": 0 }),
        )
        .await
        .unwrap();
    let files: brdfd_theta::osc::FileList = serde_json::from_value(list.results.unwrap()).unwrap();
    assert_eq!(files.total_entries, 1);
    assert_eq!(files.entries[0].file_url, url);
    assert_eq!(files.entries[0].size, 200_000);
    c.execute("camera.delete", json!({ "fileUrls": [url] }))
        .await
        .unwrap();
    assert_eq!(s.file_count(), 0);
    let e = c
        .execute("camera.delete", json!({ "fileUrls": [url] }))
        .await
        .unwrap_err();
    assert!(e.to_string().contains("invalidParameterValue"), "{e}");
    let e = c.execute("camera.fly", json!({})).await.unwrap_err();
    assert!(e.to_string().contains("unknownCommand (HTTP 400)"), "{e}");
    let e = c
        .set_options(json!({ "shutterSpeed": 0.0123 }))
        .await
        .unwrap_err();
    assert!(e.to_string().contains("invalidParameterValue"), "{e}");
}

fn usb_theta(r: &brdfd_sim::ptp::SharedResponder) -> Theta {
    let timeouts = Timeouts {
        command: Duration::from_secs(2),
        data: Duration::from_secs(2),
        capture: Duration::from_secs(5),
        busy: Duration::from_secs(3),
        poll: Duration::from_millis(5),
    };
    let cam = Camera::open(Box::new(UsbTransport::new(usb::plug(r.clone()))), timeouts).unwrap();
    Theta::from_ptp(cam).unwrap()
}

#[test]
fn usb_bracket_sets_ricoh_properties_and_wakes_the_camera() {
    let r = Responder::new(Profile::ThetaV, Arc::new(Labelled)).shared();
    r.lock().unwrap().fall_asleep();
    let mut t = usb_theta(&r);
    assert!(t.describe().contains("RICOH THETA V") && t.describe().contains("USB"));
    let report = t.prepare().unwrap();
    assert_eq!(report[0], "woke up from sleep: true");
    let plan = BracketPlan::light_probe();
    let frames = t.capture(&plan, &mut no_progress()).unwrap();
    assert_eq!(frames.len(), 8);
    for (i, (f, e)) in frames.iter().zip(&plan.shots).enumerate() {
        assert_eq!(f.name, format!("R{:07}.JPG", 10_001 + i));
        assert!((f.asked.shutter_s / e.shutter_s - 1.0).abs() < 1e-9);
        assert_eq!(
            label(&f.data),
            format!("shutter={:.8} iso=100 f=2 seq={}", e.shutter_s, i + 1)
        );
    }
    // It went to sleep again between frames: the next capture wakes it first.
    r.lock().unwrap().fall_asleep();
    let frames = t
        .capture(
            &BracketPlan::single(Exposure {
                shutter_s: 1.0 / 60.0,
                iso: 400,
            }),
            &mut no_progress(),
        )
        .unwrap();
    assert!(label(&frames[0].data).starts_with("shutter=0.01666667 iso=400"));
    t.close().unwrap();
}

#[test]
fn usb_refuses_a_camera_that_is_not_a_theta() {
    let r = Responder::new(Profile::NikonD5100, Arc::new(Labelled)).shared();
    let cam = Camera::open(
        Box::new(UsbTransport::new(usb::plug(r.clone()))),
        Timeouts::default(),
    )
    .unwrap();
    let e = Theta::from_ptp(cam).err().unwrap().to_string();
    assert!(e.contains("is not a RICOH THETA"), "{e}");
}

#[test]
fn usb_recovers_from_a_theta_that_drops_off_mid_download() {
    let r = Responder::new(Profile::ThetaV, Arc::new(Labelled)).shared();
    let mut t = usb_theta(&r);
    t.prepare().unwrap();
    // The link drops 50 kB into the second frame's 200 kB: the PTP layer resets the link,
    // reopens the session and downloads the frame again, whole.
    let plan = BracketPlan {
        shots: [1.0 / 1000.0, 1.0 / 250.0, 1.0 / 60.0]
            .iter()
            .map(|&shutter_s| Exposure {
                shutter_s,
                iso: 100,
            })
            .collect(),
    };
    let mut armed = false;
    let frames = t
        .capture(&plan, &mut |phase, _| {
            if phase.starts_with("frame 2/3 download") && !armed {
                armed = true;
                r.lock().unwrap().faults.disconnect_in_download = Some(50_000);
            }
        })
        .unwrap();
    assert!(armed);
    assert_eq!(frames.len(), 3);
    assert!(frames.iter().all(|f| f.data.len() == 200_000));
    assert!(label(&frames[1].data).starts_with("shutter=0.00400000"));
    // The fault fired: one more object read than frames, and the session was reopened.
    let log = r.lock().unwrap().log.clone();
    let count = |code: u16| log.iter().filter(|&&op| op == code).count();
    assert_eq!(count(brdfd_ptp::codes::op::GET_OBJECT), 4, "{log:x?}");
    assert_eq!(count(brdfd_ptp::codes::op::OPEN_SESSION), 2, "{log:x?}");
}

/// Issue 41: a THETA Z1 on USB (its own product id, ISOs from 80 and three apertures, as the
/// simulated profile gives them) is found, prepared and shot like the V: a plan at ISO 64,
/// which the Z1 lacks, is shot at its lowest, 80, and the frames carry its aperture.
#[test]
fn usb_drives_a_theta_z1() {
    let r = Responder::new(Profile::ThetaZ1, Arc::new(Labelled)).shared();
    assert_eq!(Profile::ThetaZ1.usb_ids(), (0x05ca, 0x036d));
    let mut t = usb_theta(&r);
    assert!(t.describe().contains("RICOH THETA Z1"), "{}", t.describe());
    t.prepare().unwrap();
    let plan = BracketPlan {
        shots: [1.0 / 25000.0, 1.0 / 250.0]
            .iter()
            .map(|&shutter_s| Exposure { shutter_s, iso: 64 })
            .collect(),
    };
    let frames = t.capture(&plan, &mut no_progress()).unwrap();
    assert_eq!(frames.len(), 2);
    for (i, (f, e)) in frames.iter().zip(&plan.shots).enumerate() {
        assert_eq!(f.name, format!("R{:07}.JPG", 10_001 + i));
        assert_eq!(f.asked.iso, 80);
        assert_eq!(
            label(&f.data),
            format!("shutter={:.8} iso=80 f=2.1 seq={}", e.shutter_s, i + 1)
        );
    }
    t.close().unwrap();
}
