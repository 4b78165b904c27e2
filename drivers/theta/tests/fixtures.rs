//! Every recorded THETA Web API response in `shared/data/theta/osc-fixtures/` (from RICOH's
//! theta-client test resources: real cameras' answers) parses through our types, and the
//! fields the driver relies on read as the recording says.

use std::path::{Path, PathBuf};

use brdfd_theta::osc::{AutoBracket, Command, CommandState, FileList, Info, StateResponse};

fn fixtures() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/theta/osc-fixtures");
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!("SKIPPED: shared/data/theta/osc-fixtures is missing (CI has it)");
        None
    }
}

fn read(dir: &Path, rel: &str) -> String {
    std::fs::read_to_string(dir.join(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

fn command(dir: &Path, rel: &str) -> Command {
    serde_json::from_str(&read(dir, rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

/// Which of our types a fixture is, from its folder and name.
enum Kind {
    Info,
    State,
    Command,
}

fn kind(rel: &str) -> Kind {
    if rel.starts_with("info/") {
        Kind::Info
    } else if rel.starts_with("state/")
        || rel
            .rsplit('/')
            .next()
            .is_some_and(|f| f.starts_with("state_"))
    {
        Kind::State
    } else {
        Kind::Command
    }
}

#[test]
fn every_fixture_parses_through_our_types() {
    let Some(dir) = fixtures() else { return };
    let mut count = 0;
    for folder in std::fs::read_dir(&dir).unwrap() {
        let folder = folder.unwrap().path();
        if !folder.is_dir() {
            continue;
        }
        for f in std::fs::read_dir(&folder).unwrap() {
            let path = f.unwrap().path();
            if path.extension().and_then(|e| e.to_str()) != Some("json") {
                continue;
            }
            let rel = path
                .strip_prefix(&dir)
                .unwrap()
                .to_string_lossy()
                .replace('\\', "/");
            let text = read(&dir, &rel);
            let parsed = match kind(&rel) {
                Kind::Info => serde_json::from_str::<Info>(&text).map(|_| ()),
                Kind::State => serde_json::from_str::<StateResponse>(&text).map(|_| ()),
                Kind::Command => serde_json::from_str::<Command>(&text).map(|c| {
                    // A command in state error carries its error object; done and
                    // inProgress carry none.
                    assert_eq!(c.error.is_some(), c.state == CommandState::Error, "{rel}");
                }),
            };
            parsed.unwrap_or_else(|e| panic!("{rel} does not parse: {e}"));
            count += 1;
        }
    }
    // 141 files at the recorded commit; fewer means the walk missed a folder.
    assert!(count >= 140, "only {count} fixtures found");
}

#[test]
fn info_fixtures_name_the_model_and_api_level() {
    let Some(dir) = fixtures() else { return };
    let z1: Info = serde_json::from_str(&read(&dir, "info/info_z1.json")).unwrap();
    assert_eq!(z1.model, "RICOH THETA Z1");
    assert_eq!(z1.serial_number, "10010065");
    assert_eq!(z1.firmware_version, "2.10.3");
    assert_eq!(z1.api_level, vec![2]);
    assert_eq!(z1.endpoints.http_port, 80);
    assert!(z1.api.contains(&"/osc/commands/status".to_string()));
    let other: Info = serde_json::from_str(&read(&dir, "info/info_other.json")).unwrap();
    assert_eq!(other.api_level, vec![1, 2]);
}

#[test]
fn state_fixtures_give_capture_status_and_latest_file() {
    let Some(dir) = fixtures() else { return };
    let s: StateResponse =
        serde_json::from_str(&read(&dir, "MultiBracketCapture/state_shooting.json")).unwrap();
    assert_eq!(s.fingerprint, "FIG_0002");
    assert_eq!(s.state.capture_status, "bracket shooting");
    assert_eq!(s.state.api_version, 2);
    assert!(s
        .state
        .latest_file_url
        .unwrap()
        .ends_with("/100RICOH/R0010145.JPG"));
    let x: StateResponse = serde_json::from_str(&read(&dir, "state/state_x.json")).unwrap();
    assert_eq!(x.state.camera_error, vec!["HIGH_TEMPERATURE_WARNING"]);
    // Fields we do not model are kept, not lost.
    assert_eq!(x.state.extra["_currentStorage"], "IN");
    // API level 1 (THETA S): sessionId, and _latestFileUri instead of _latestFileUrl.
    let s1: StateResponse = serde_json::from_str(&read(&dir, "state/state_s_api1.json")).unwrap();
    assert_eq!(s1.state.api_version, 1);
    assert_eq!(s1.state.extra["sessionId"], "SID_0001");
}

#[test]
fn capture_fixtures_give_progress_file_urls_and_errors() {
    let Some(dir) = fixtures() else { return };
    let p = command(&dir, "MultiBracketCapture/start_capture_progress_1.json");
    assert_eq!(p.state, CommandState::InProgress);
    assert_eq!(p.id.as_deref(), Some("3"));
    assert_eq!(p.progress.unwrap().completion, 0.5);
    let done = command(&dir, "MultiBracketCapture/start_capture_done.json");
    let urls = done.file_urls();
    assert_eq!(urls.len(), 2);
    assert!(urls[1].ends_with("/100RICOH/R0010006.JPG"));
    assert!(
        command(&dir, "MultiBracketCapture/start_capture_done_empty.json")
            .file_urls()
            .is_empty()
    );
    assert!(
        command(&dir, "MultiBracketCapture/start_capture_done_stopped.json")
            .file_urls()
            .is_empty()
    );
    let one = command(&dir, "PhotoCapture/takepicture_done.json");
    assert_eq!(one.file_urls().len(), 1);
    let cancel = command(&dir, "PhotoCapture/takepicture_cancel.json");
    assert_eq!(cancel.state, CommandState::Error);
    assert_eq!(cancel.error.unwrap().code, "canceledShooting");
    assert_eq!(
        brdfd_theta::osc::error_code::http_status("canceledShooting"),
        403
    );
}

#[test]
fn option_fixtures_read_the_bracket_and_timers() {
    let Some(dir) = fixtures() else { return };
    let o = command(&dir, "options/option_auto_bracket.json").options();
    let b: AutoBracket = serde_json::from_value(o["_autoBracket"].clone()).unwrap();
    assert_eq!(b.number, 2);
    assert_eq!(b.parameters.len(), 2);
    assert_eq!(b.parameters[0].shutter_speed, 0.004);
    assert_eq!(b.parameters[0].iso, 400);
    assert_eq!(b.parameters[0].exposure_program, Some(1));
    assert_eq!(b.parameters[0].color_temperature, Some(5000));
    let init = command(&dir, "getOptions/get_options_init_z1_done.json").options();
    assert_eq!(init["offDelay"], 3600);
    assert_eq!(init["sleepDelay"], 65535);
    let shutter = command(&dir, "options/option_shutter_speed_10.json").options();
    assert_eq!(shutter["shutterSpeed"], 10);
    let filter = command(&dir, "getOptions/get_options_filter_off.json").options();
    assert_eq!(filter["_filter"], "off");
}

#[test]
fn list_files_fixtures_give_urls_sizes_and_projection() {
    let Some(dir) = fixtures() else { return };
    let c = command(&dir, "listFiles/listfiles_image_10.json");
    let list: FileList = serde_json::from_value(c.results.unwrap()).unwrap();
    assert_eq!(list.entries.len(), 10);
    let e = &list.entries[0];
    assert!(e.file_url.starts_with("http://192.168.1.1/files/"));
    assert!(e.name.ends_with(".JPG") && e.size > 0 && e.width == 2 * e.height);
    assert_eq!(e.projection_type.as_deref(), Some("Equirectangular"));
    let empty = command(&dir, "listFiles/listfiles_zero_entries.json");
    let list: FileList = serde_json::from_value(empty.results.unwrap()).unwrap();
    assert!(list.entries.is_empty());
}
