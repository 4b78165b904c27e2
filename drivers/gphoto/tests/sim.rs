//! The libgphoto2 backend against the simulated bodies over PTP/IP: each is opened, set to an
//! exposure, fired and downloaded through the system's libgphoto2, and the file is the one
//! brdfd's own PTP driver downloads at the same exposure, byte for byte. The simulated body
//! writes its exposure into the file, so the comparison also shows the settings arrived.

use std::sync::{Arc, Once};
use std::time::Duration;

use brdfd_gphoto::{Exposure, GphotoCamera};
use brdfd_ptp::transport::ptpip::{Initiator, PtpIpTransport};
use brdfd_ptp::{Camera, CaptureOptions, Timeouts};
use brdfd_sim::ptp::{ptpip::Server, Profile, Responder};
use brdfd_sim::{ImageSource, Shot};

/// A file that says what exposure made it, and nothing of the shot's place in the sequence,
/// so that two shots at one exposure are the same file.
struct ExposureStamp;

const FILE_BYTES: usize = 3 << 20;

impl ImageSource for ExposureStamp {
    fn photo(&self, shot: &Shot) -> Result<Vec<u8>, String> {
        let stamp = format!(
            "shutter {:.6} f/{:.1} ISO {}",
            shot.shutter_s, shot.f_number, shot.iso
        );
        let mut v: Vec<u8> = (0..FILE_BYTES)
            .map(|i| (i as u32).wrapping_mul(2_654_435_761).to_le_bytes()[3])
            .collect();
        v[..2].copy_from_slice(&[0xFF, 0xD8]);
        v[2..2 + stamp.len()].copy_from_slice(stamp.as_bytes());
        v[FILE_BYTES - 2..].copy_from_slice(&[0xFF, 0xD9]);
        Ok(v)
    }
    fn dimensions(&self) -> (u32, u32) {
        (6000, 4000)
    }
}

fn stamp(file: &[u8]) -> String {
    String::from_utf8_lossy(&file[2..40])
        .trim_end_matches(|c: char| !c.is_ascii_digit())
        .to_string()
}

/// libgphoto2 keeps a PTP/IP identity in `$HOME/.gphoto`: the test's is a directory of its
/// own, not the user's.
fn private_home() {
    static HOME: Once = Once::new();
    HOME.call_once(|| {
        let dir = home();
        std::fs::create_dir_all(&dir).unwrap();
        // SAFETY: set once, before this process starts libgphoto2 or any thread that reads
        // the environment (the simulators start after).
        std::env::set_var("HOME", &dir);
    });
}

fn home() -> std::path::PathBuf {
    std::env::temp_dir().join(format!("brdfd-gphoto-test-{}", std::process::id()))
}

/// One body: libgphoto2's download, then brdfd's own at the same exposure. Each picks the
/// body's listed values nearest the exposure asked for, so both must apply the same. The body
/// starts elsewhere, so a setting libgphoto2 did not make would show in its file.
fn body(profile: Profile, model: &str, exposure: Exposure) {
    private_home();
    let responder = Responder::new(profile, Arc::new(ExposureStamp)).shared();
    let start = responder.lock().unwrap().shot_settings();
    assert!(
        Some(start.iso) != exposure.iso && Some(start.f_number) != exposure.f_number,
        "{profile:?} starts at {start:?}"
    );
    let server = Server::start("127.0.0.1:0", responder).unwrap();

    // libgphoto2's PTP/IP port: HOST:COMMANDPORT:EVENTPORT; the simulator takes both on one.
    let port = format!("ptpip:{}:{}", server.addr, server.addr.port());
    let fd0 = || std::fs::read_link("/proc/self/fd/0").ok();
    let fd0_before = fd0();
    let cam = GphotoCamera::open(Some(&port)).unwrap_or_else(|e| panic!("{profile:?}: {e:?}"));
    assert!(cam.model().contains(model), "{profile:?}: {}", cam.model());
    let applied = cam
        .set_exposure(&exposure)
        .unwrap_or_else(|e| panic!("{profile:?}: {e:?}"));
    assert_eq!(applied.f_number, exposure.f_number, "{profile:?}");
    assert_eq!(applied.iso, exposure.iso, "{profile:?}");
    let mut seen = 0;
    let files = cam
        .capture(&mut |done, _| seen = done)
        .unwrap_or_else(|e| panic!("{profile:?}: {e:?}"));
    drop(cam);
    // libgphoto2's PTP/IP disconnect closes fd 0; the backend puts it back (`Fd0Guard`), or
    // the simulator's listening socket would take its place and be closed by the next.
    assert_eq!(
        fd0(),
        fd0_before,
        "{profile:?}: fd 0 after libgphoto2 let go"
    );
    let names: Vec<_> = files.iter().map(|f| &f.0).collect();
    assert_eq!(files.len(), 1, "{profile:?}: {names:?}");
    let theirs = &files[0].1;
    assert_eq!(seen, FILE_BYTES as u64, "{profile:?}");

    let link = PtpIpTransport::connect(server.addr, Initiator::default(), Duration::from_secs(5))
        .unwrap_or_else(|e| panic!("{profile:?}: {e:?}"));
    let mut ours = Camera::open(Box::new(link), Timeouts::default()).unwrap();
    let our_applied = ours
        .set_exposure(&brdfd_ptp::Exposure {
            shutter_s: exposure.shutter_s,
            f_number: exposure.f_number,
            iso: exposure.iso,
        })
        .unwrap();
    let shot = ours
        .capture(&CaptureOptions::default(), &mut |_, _, _| {})
        .unwrap();
    ours.close().unwrap();
    let shutter = |s: Option<f64>| s.map(|s| (s * 1e6).round());
    assert_eq!(
        shutter(applied.shutter_s),
        shutter(our_applied.shutter_s),
        "{profile:?}: {applied:?} against brdfd's {our_applied:?}"
    );
    let want = format!(
        "f/{:.1} ISO {}",
        exposure.f_number.unwrap_or_default(),
        exposure.iso.unwrap_or_default()
    );
    assert!(
        stamp(&shot.data).ends_with(&want),
        "{profile:?}: {}",
        stamp(&shot.data)
    );
    assert_eq!(stamp(theirs), stamp(&shot.data), "{profile:?}");
    assert!(
        theirs == &shot.data,
        "{profile:?}: the two downloads differ"
    );
}

#[test]
fn libgphoto2_sets_fires_and_downloads_each_simulated_body_as_brdfd_s_own_driver_does() {
    // Each body at an aperture and ISO it lists and does not start at. Debian's libgphoto2
    // asks the a7 IV for control protocol 2.00, and so moves its settings a notch at a time
    // (ControlDevice +1 or -1) before setting the value reached.
    let exposure = |f_number, iso| Exposure {
        shutter_s: Some(1.0 / 60.0),
        f_number: Some(f_number),
        iso: Some(iso),
    };
    body(Profile::Generic, "", exposure(5.6, 200));
    body(Profile::NikonD5100, "D5100", exposure(5.6, 200));
    body(Profile::CanonEosR6, "EOS R6", exposure(8.0, 200));
    body(Profile::SonyA7M4, "ILCE-7M4", exposure(5.6, 200));
    let _ = std::fs::remove_dir_all(home());
}
