//! The daemon's OpenAPI description (`GET /api/v1/openapi.json`) against the live daemon:
//! every operation it lists answers only as it says, every route the daemon answers is in it,
//! openapi-spec-validator (PyPI) finds it valid OpenAPI 3.1, and schemathesis (PyPI), an
//! outside client that generates requests from the description, finds no server error, no
//! answer outside it, and with every check of its own no failure. CI installs both and sets
//! BRDFD_REQUIRE_SCHEMATHESIS=1 and BRDFD_REQUIRE_OPENAPI_VALIDATOR=1, so there those tests
//! cannot skip. And the HTTP conventions the description cannot state (issue 42): errors as
//! RFC 9457 problems, `WWW-Authenticate` on a 401, 405 before 415, `Location`, and result
//! files with `ETag` and byte ranges.

mod common;

use std::collections::BTreeSet;
use std::process::Command;

use common::Daemon;
use serde_json::{json, Value};

/// A finished capture on a small simulated bench: what the result routes need to serve.
fn finished_session(daemon: &Daemon) -> String {
    let (status, body) = daemon.post("/sessions", json!({ "material": "gold", "size": 64 }));
    assert_eq!(status, 202, "{body}");
    let id = body["id"].as_str().unwrap().to_string();
    let events = daemon.events(&id);
    let last = events.last().expect("events");
    assert_eq!(last["state"], "done", "{last}");
    id
}

/// A JSON schema, following a `$ref` into the description's components.
fn resolve<'a>(spec: &'a Value, schema: &'a Value) -> &'a Value {
    match schema["$ref"].as_str() {
        Some(r) => {
            let name = r.rsplit('/').next().unwrap();
            &spec["components"]["schemas"][name]
        }
        None => schema,
    }
}

/// Whether `value` has what `schema` requires: the type, the required properties, and the
/// same of each item or property that is itself described (enough to catch a handler and its
/// description drifting apart; schemathesis checks the rest).
fn conforms(spec: &Value, schema: &Value, value: &Value) -> Result<(), String> {
    let schema = resolve(spec, schema);
    if let Some(any) = schema["oneOf"].as_array() {
        return any
            .iter()
            .find_map(|s| conforms(spec, s, value).ok())
            .ok_or_else(|| format!("{value} matches none of {schema}"));
    }
    let types: Vec<&str> = match &schema["type"] {
        Value::String(t) => vec![t.as_str()],
        Value::Array(ts) => ts.iter().filter_map(Value::as_str).collect(),
        _ => return Ok(()),
    };
    let fits = |t: &str| match t {
        "object" => value.is_object(),
        "array" => value.is_array(),
        "string" => value.is_string(),
        "integer" => value.is_i64() || value.is_u64(),
        "number" => value.is_number(),
        "boolean" => value.is_boolean(),
        "null" => value.is_null(),
        _ => true,
    };
    if !types.iter().any(|t| fits(t)) {
        return Err(format!("{value} is not {types:?}"));
    }
    if let Some(values) = schema["enum"].as_array() {
        if !values.contains(value) {
            return Err(format!("{value} is not one of {values:?}"));
        }
    }
    if let (Some(items), Some(array)) = (schema.get("items"), value.as_array()) {
        for v in array {
            conforms(spec, items, v)?;
        }
    }
    if let Some(object) = value.as_object() {
        for name in schema["required"].as_array().into_iter().flatten() {
            let name = name.as_str().unwrap();
            if !object.contains_key(name) {
                return Err(format!("{value} lacks {name:?}"));
            }
        }
        if let Some(properties) = schema["properties"].as_object() {
            for (name, v) in object {
                match properties.get(name) {
                    Some(s) => conforms(spec, s, v).map_err(|e| format!("{name}: {e}"))?,
                    None => return Err(format!("{name:?} is not described in {schema}")),
                }
            }
        }
    }
    Ok(())
}

/// Every operation of the description, asked on the live daemon with a real session,
/// answers with a status and media type it documents, and a JSON body its schema describes;
/// every result file it names exists (but a mesh's `visibility.png`); and the daemon answers
/// no method or path it leaves out.
#[test]
fn the_openapi_description_is_the_live_api() {
    let dir = tempfile::tempdir().unwrap();
    let daemon = Daemon::simulated(&dir.path().join("state"));
    let id = finished_session(&daemon);
    let (status, spec) = daemon.get("/openapi.json");
    assert_eq!(status, 200);
    assert!(
        spec["openapi"].as_str().unwrap().starts_with("3.1"),
        "{spec}"
    );
    // brdfd's own name, version and licence: not utoipa-axum's (issue 42), which a client
    // generator would have named the client after.
    let info = &spec["info"];
    assert_eq!(info["title"], "brdfd", "{info}");
    assert_eq!(info["version"], env!("CARGO_PKG_VERSION"), "{info}");
    assert_eq!(info["license"]["identifier"], "MIT", "{info}");
    assert!(info["contact"].is_null(), "{info}");
    // Every error code is listed, each with what it means.
    let codes = &spec["components"]["schemas"]["ErrorCode"];
    let listed = codes["enum"]
        .as_array()
        .expect("the error codes are listed");
    let described = codes["description"].as_str().unwrap_or_default();
    assert_eq!(listed.len(), 19, "{codes}");
    for code in listed {
        assert!(
            described.contains(&format!("`{}`: ", code.as_str().unwrap())),
            "{code} is not described in {described}"
        );
    }
    // So is every code a failed capture's `finished` event can carry.
    let failures = &spec["components"]["schemas"]["FailureCode"];
    let described = failures["description"].as_str().unwrap_or_default();
    let listed = failures["enum"]
        .as_array()
        .expect("the failure codes are listed");
    let names: Vec<&str> = brdfd_api::event::FailureCode::ALL
        .iter()
        .map(|c| c.name())
        .collect();
    assert_eq!(
        listed
            .iter()
            .map(|c| c.as_str().unwrap())
            .collect::<Vec<_>>(),
        names,
        "{failures}"
    );
    for code in listed {
        assert!(
            described.contains(&format!("`{}`: ", code.as_str().unwrap())),
            "{code} is not described in {described}"
        );
    }
    let files: Vec<String> = spec["components"]["schemas"]["ResultFile"]["enum"]
        .as_array()
        .expect("the result files are listed")
        .iter()
        .map(|f| f.as_str().unwrap().to_string())
        .collect();
    assert!(files.contains(&"report.html".to_string()), "{files:?}");

    let http = reqwest::blocking::Client::new();
    let base = format!("http://{}", daemon.addr);
    let paths = spec["paths"].as_object().unwrap();
    let mut asked = BTreeSet::new();
    for (path, item) in paths {
        assert!(path.starts_with("/api/v1/"), "{path}");
        let urls: Vec<String> = if path.contains("{file}") {
            files
                .iter()
                .map(|f| {
                    path.replace("{file}", f)
                        .replace("{material}", "material-1")
                })
                .collect()
        } else {
            vec![path.clone()]
        };
        for method in ["get", "post", "put", "delete", "patch"] {
            let op = &item[method];
            for url in &urls {
                let url = format!("{base}{}", url.replace("{id}", &id));
                let request = match method {
                    "get" => http.get(&url),
                    "post" => http.post(&url),
                    "put" => http.put(&url),
                    "delete" => http.delete(&url),
                    _ => http.patch(&url),
                };
                // A plan for a material that does not exist: refused, and nothing started.
                let body = if path.ends_with("/sessions") {
                    json!({ "material": "no-such-material" })
                } else {
                    json!({})
                };
                let r = request.json(&body).send().unwrap();
                let status = r.status().as_u16();
                if op.is_null() {
                    // Not described: not answered.
                    assert_eq!(status, 405, "{method} {url} is answered but not described");
                    continue;
                }
                asked.insert(format!("{method} {path}"));
                let documented = &op["responses"][status.to_string()];
                assert!(
                    documented.is_object(),
                    "{method} {url}: {status} is not among {}",
                    op["responses"]
                );
                let media = r
                    .headers()
                    .get("content-type")
                    .and_then(|v| v.to_str().ok())
                    .map(|v| v.split(';').next().unwrap().trim().to_string())
                    .unwrap_or_default();
                let content = documented["content"]
                    .as_object()
                    .unwrap_or_else(|| panic!("{method} {url}: {status} has no content"));
                let described = content
                    .get(&media)
                    .unwrap_or_else(|| panic!("{method} {url}: {media} is not among {content:?}"));
                let json = media == "application/json" || media == "application/problem+json";
                if json && !path.ends_with("/events") {
                    let body: Value = r.json().unwrap();
                    if let Some(schema) = described.get("schema") {
                        conforms(&spec, schema, &body)
                            .unwrap_or_else(|e| panic!("{method} {url}: {e}"));
                    }
                }
                if path.contains("{file}") {
                    // The session's object is a sphere of one material, which hides nothing
                    // from itself: the visibility picture and the export on the object are
                    // written for a mesh only, and the materials' folders and pictures for a
                    // part split into two.
                    let only_sometimes = [
                        "/visibility.png",
                        "/object.gltf",
                        "/materials.png",
                        "/materials-mask.png",
                    ];
                    let expected = if path.contains("{material}")
                        || only_sometimes.iter().any(|f| url.ends_with(f))
                    {
                        404
                    } else {
                        200
                    };
                    assert_eq!(status, expected, "{url}: a listed result file is missing");
                }
            }
        }
    }
    // Every route of docs/api.md was asked.
    for op in [
        "get /api/v1/health",
        "get /api/v1/devices",
        "get /api/v1/materials",
        "get /api/v1/sessions",
        "post /api/v1/sessions",
        "get /api/v1/sessions/{id}",
        "get /api/v1/sessions/{id}/events",
        "get /api/v1/sessions/{id}/result",
        "get /api/v1/sessions/{id}/result/{file}",
        "get /api/v1/sessions/{id}/result/{material}/{file}",
        "post /api/v1/sessions/{id}/cancel",
        "post /api/v1/sessions/{id}/resume",
    ] {
        assert!(asked.contains(op), "{op} is not described: {asked:?}");
    }
    // A path it does not describe is the fallback's, for every method.
    for path in ["/api/v1/nothing", "/api/v1/sessions/x/y/z/w"] {
        let r = http.get(format!("{base}{path}")).send().unwrap();
        assert_eq!(r.status().as_u16(), 404, "{path}");
        let body: Value = r.json().unwrap();
        assert!(
            body["message"]
                .as_str()
                .unwrap()
                .contains("no such endpoint"),
            "{body}"
        );
    }
}

/// The schemathesis to run: `BRDFD_SCHEMATHESIS`, else `st` on the PATH.
fn schemathesis() -> Option<String> {
    let st = std::env::var("BRDFD_SCHEMATHESIS").unwrap_or_else(|_| "st".to_string());
    let present = Command::new(&st).arg("--version").output().is_ok();
    if !present {
        assert!(
            std::env::var_os("BRDFD_REQUIRE_SCHEMATHESIS").is_none(),
            "schemathesis is required here but not installed (pip install schemathesis)"
        );
        eprintln!("skipping: schemathesis is not installed (pip install schemathesis; or set BRDFD_SCHEMATHESIS)");
        return None;
    }
    Some(st)
}

/// schemathesis with `checks`, bounded to 100 examples per operation, against a daemon with a
/// finished session, with tests/schemathesis.toml's settings; its summary's tail is printed.
fn run_schemathesis(st: &str, checks: &str) {
    let dir = tempfile::tempdir().unwrap();
    let daemon = Daemon::simulated(&dir.path().join("state"));
    finished_session(&daemon);
    let settings = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/schemathesis.toml");
    let o = Command::new(st)
        .current_dir(dir.path())
        .args([
            "--config-file",
            settings,
            "run",
            &format!("http://{}/api/v1/openapi.json", daemon.addr),
            "--checks",
            checks,
            "--max-examples",
            "100",
            "--workers",
            "1",
            "--seed",
            "20261130",
            "--no-color",
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    let stderr = String::from_utf8_lossy(&o.stderr);
    let tail: String = stdout
        .lines()
        .rev()
        .take(60)
        .collect::<Vec<_>>()
        .into_iter()
        .rev()
        .collect::<Vec<_>>()
        .join("\n");
    eprintln!("{tail}");
    assert!(
        o.status.success(),
        "schemathesis failed:\n{stdout}\n{stderr}"
    );
    assert!(stdout.contains("passed"), "{stdout}");
}

/// schemathesis, bounded to 100 examples per operation, against a daemon with a finished session: no
/// 500, and no status, media type, header or body the description does not allow.
#[test]
fn schemathesis_finds_no_error_and_no_answer_outside_the_schema() {
    let Some(st) = schemathesis() else {
        return;
    };
    run_schemathesis(
        &st,
        "not_a_server_error,status_code_conformance,content_type_conformance,\
         response_headers_conformance,response_schema_conformance",
    );
}

/// schemathesis with every check it has (issue 42): besides the answers above, schema-valid
/// requests are accepted and invalid ones refused, a method the description lacks gets 405
/// with `Allow`, a deleted or missing resource reads as missing, an operation that declares
/// security refuses a request without it. One operation's settings differ, and
/// tests/schemathesis.toml says why.
#[test]
fn schemathesis_with_every_check_finds_no_failure() {
    let Some(st) = schemathesis() else {
        return;
    };
    run_schemathesis(&st, "all");
}

/// The Python that has openapi-spec-validator: `BRDFD_OPENAPI_VALIDATOR`, else `python3` on
/// the PATH if it has the package.
fn openapi_validator() -> Option<String> {
    let python = std::env::var("BRDFD_OPENAPI_VALIDATOR").unwrap_or_else(|_| "python3".into());
    let present = Command::new(&python)
        .args(["-c", "import openapi_spec_validator"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !present {
        assert!(
            std::env::var_os("BRDFD_REQUIRE_OPENAPI_VALIDATOR").is_none(),
            "openapi-spec-validator is required here but not installed (pip install \
             openapi-spec-validator; BRDFD_OPENAPI_VALIDATOR names the Python that has it)"
        );
        eprintln!("skipping: openapi-spec-validator is not installed (pip install openapi-spec-validator; or set BRDFD_OPENAPI_VALIDATOR)");
        return None;
    }
    Some(python)
}

/// The description the daemon serves is valid OpenAPI 3.1, as openapi-spec-validator judges
/// it, every error counted (issue 42: it found 8, a response without its required
/// `description` each).
#[test]
fn openapi_spec_validator_finds_the_live_description_valid() {
    let Some(python) = openapi_validator() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let daemon = Daemon::simulated(&dir.path().join("state"));
    let (status, spec) = daemon.get_bytes("/openapi.json");
    assert_eq!(status, 200);
    let file = dir.path().join("openapi.json");
    std::fs::write(&file, spec).unwrap();
    let o = Command::new(&python)
        .args([
            "-m",
            "openapi_spec_validator",
            "--schema",
            "3.1",
            "--validation-errors",
            "all",
        ])
        .arg(&file)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.success() && stdout.trim_end().ends_with(": OK"),
        "openapi-spec-validator:\n{stdout}\n{stderr}"
    );
}

/// A client that sends no token of its own.
fn http() -> reqwest::blocking::Client {
    reqwest::blocking::Client::new()
}

/// The media type of a response, without its parameters.
fn media_type(r: &reqwest::blocking::Response) -> String {
    r.headers()
        .get("content-type")
        .and_then(|v| v.to_str().ok())
        .map(|v| v.split(';').next().unwrap().trim().to_string())
        .unwrap_or_default()
}

/// Asserts that `r` is an RFC 9457 problem with `status` and brdfd's `code`: the standard
/// members, and `error` and `message` beside them as before. Returns the body.
fn problem(r: reqwest::blocking::Response, status: u16, code: &str) -> Value {
    assert_eq!(r.status().as_u16(), status, "{:?}", r.headers());
    assert_eq!(media_type(&r), "application/problem+json");
    let body: Value = r.json().unwrap();
    assert_eq!(body["type"], "about:blank", "{body}");
    assert_eq!(body["status"], status, "{body}");
    let reason = reqwest::StatusCode::from_u16(status)
        .unwrap()
        .canonical_reason()
        .unwrap();
    assert_eq!(body["title"], reason, "{body}");
    assert_eq!(body["error"], code, "{body}");
    assert!(
        body["detail"].as_str().is_some_and(|d| !d.is_empty()),
        "{body}"
    );
    assert_eq!(body["detail"], body["message"], "{body}");
    body
}

/// Issue 42: errors are RFC 9457 problems (`application/problem+json`), keeping the `error`
/// and `message` members the CLI and the web page read; a 401 names the scheme that would
/// pass (RFC 9110 §11.6.1); and the description says both.
#[test]
fn errors_are_problem_details_and_a_401_names_its_scheme() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("brdfd.toml"),
        "api = \"127.0.0.1:7878\"\ntoken = \"correct horse\"\n",
    )
    .unwrap();
    let config = dir.path().join("brdfd.toml");
    let daemon = Daemon::start(
        &dir.path().join("state"),
        &["--simulate", "--config", config.to_str().unwrap()],
    );
    let base = format!("http://{}/api/v1", daemon.addr);
    let r = http().get(format!("{base}/health")).send().unwrap();
    let challenge = r.headers()["www-authenticate"]
        .to_str()
        .unwrap()
        .to_string();
    assert_eq!(challenge, r#"Bearer realm="brdfd""#);
    problem(r, 401, "unauthorized");
    let r = http()
        .get(format!("{base}/sessions/no-such-session"))
        .bearer_auth("correct horse")
        .send()
        .unwrap();
    problem(r, 404, "not_found");
    // The fallback's answer, and an answer axum gives itself (a path that is not UTF-8), too.
    let r = http()
        .get(format!("{base}/nothing"))
        .bearer_auth("correct horse")
        .send()
        .unwrap();
    problem(r, 404, "not_found");
    let r = http()
        .get(format!("{base}/sessions/%FF/result"))
        .bearer_auth("correct horse")
        .send()
        .unwrap();
    problem(r, 400, "bad_request");

    let (_, spec) = daemon.get("/openapi.json");
    let schema = &spec["components"]["schemas"]["ErrorBody"];
    for member in ["type", "title", "status", "detail", "error", "message"] {
        assert!(
            schema["required"]
                .as_array()
                .unwrap()
                .contains(&json!(member)),
            "{member}: {schema}"
        );
    }
    let health = &spec["paths"]["/api/v1/health"]["get"]["responses"];
    assert!(
        health["401"]["content"]["application/problem+json"].is_object(),
        "{health}"
    );
    assert!(
        health["401"]["headers"]["WWW-Authenticate"].is_object(),
        "{health}"
    );
    let start = &spec["paths"]["/api/v1/sessions"]["post"]["responses"];
    assert!(
        start["409"]["content"]["application/problem+json"].is_object(),
        "{start}"
    );
    assert!(
        start["409"]["content"]["application/json"].is_null(),
        "{start}"
    );
}

/// Issue 42: a method a route lacks is 405 with `Allow` (RFC 9110 §15.5.6), whatever its
/// content type; it was 415 when the content-type check ran before the method was routed.
/// The check still refuses a POST to a route that takes one.
#[test]
fn a_method_a_route_lacks_gets_405_with_allow_before_the_content_check() {
    let dir = tempfile::tempdir().unwrap();
    let daemon = Daemon::simulated(&dir.path().join("state"));
    let base = format!("http://{}/api/v1", daemon.addr);
    for path in [
        "/health",
        "/devices",
        "/materials",
        "/sessions/x",
        "/sessions/x/events",
        "/sessions/x/result",
        "/sessions/x/result/report.html",
        "/openapi.json",
    ] {
        let r = http().post(format!("{base}{path}")).send().unwrap();
        let allow = r.headers()["allow"].to_str().unwrap().to_string();
        assert!(
            allow.contains("GET") && !allow.contains("POST"),
            "{path}: {allow}"
        );
        problem(r, 405, "method_not_allowed");
    }
    let r = http().delete(format!("{base}/sessions")).send().unwrap();
    let allow = r.headers()["allow"].to_str().unwrap().to_string();
    assert!(allow.contains("GET") && allow.contains("POST"), "{allow}");
    problem(r, 405, "method_not_allowed");
    let r = http()
        .get(format!("{base}/sessions/x/cancel"))
        .send()
        .unwrap();
    assert_eq!(r.headers()["allow"], "POST");
    problem(r, 405, "method_not_allowed");
    // A route that takes POST still wants JSON.
    let r = http().post(format!("{base}/sessions")).send().unwrap();
    problem(r, 415, "unsupported_media_type");
}

/// Issue 42: the material-name rule (`config::validate_name`) is the plan schema's `pattern`,
/// and the daemon draws the line where the pattern does: a name of the wrong shape is a bad
/// request (400), one of the right shape that names no material cannot be carried out (422).
#[test]
fn the_material_name_rule_is_the_schema_pattern() {
    let dir = tempfile::tempdir().unwrap();
    let daemon = Daemon::simulated(&dir.path().join("state"));
    let (_, spec) = daemon.get("/openapi.json");
    let material = &spec["components"]["schemas"]["Plan"]["properties"]["material"];
    assert_eq!(
        material["pattern"], "^[a-z0-9][a-z0-9-]{0,63}$",
        "{material}"
    );
    let long = "a".repeat(65);
    for name in ["", "-gold", "Gold", "go/ld", "gold.", long.as_str()] {
        let (status, body) = daemon.post("/sessions", json!({ "material": name }));
        assert_eq!(
            (status, body["error"].as_str()),
            (400, Some("bad_request")),
            "{name:?}: {body}"
        );
    }
    let longest = "a".repeat(64);
    for name in ["0", "no-such-material", longest.as_str()] {
        let (status, body) = daemon.post("/sessions", json!({ "material": name }));
        assert_eq!(
            (status, body["error"].as_str()),
            (422, Some("invalid_plan")),
            "{name:?}: {body}"
        );
    }
    // JSON Schema's integers include 2.0: a count so written is a count.
    let (status, body) = daemon.post("/sessions/x/continue", json!({ "view": 2.0 }));
    assert_eq!(
        (status, body["error"].as_str()),
        (409, Some("not_waiting")),
        "{body}"
    );
    let (status, body) = daemon.post("/sessions/x/continue", json!({ "view": 2.5 }));
    assert_eq!(
        (status, body["error"].as_str()),
        (400, Some("bad_request")),
        "{body}"
    );
    // `{}` is the body of a cancel and a resume, not any JSON at all.
    let (status, body) = daemon.post("/sessions/x/resume", json!([]));
    assert_eq!(
        (status, body["error"].as_str()),
        (400, Some("bad_request")),
        "{body}"
    );
}

/// Issue 42: what a client can read of an error is about its request, never where the daemon
/// keeps its files: no message names the state directory's path.
#[test]
fn error_messages_do_not_name_the_state_directory() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let daemon = Daemon::simulated(&state);
    std::fs::create_dir_all(state.join("scenes")).unwrap();
    let folders = [
        state.display().to_string(),
        std::fs::canonicalize(&state).unwrap().display().to_string(),
    ];
    let mut answers = vec![
        daemon.get("/sessions/no-such-session"),
        daemon.get("/sessions/no-such-session/result"),
        daemon.get("/sessions/no-such-session/result/report.html"),
        daemon.post("/sessions/no-such-session/resume", json!({})),
    ];
    for plan in [
        json!({ "material": "gold", "env": "missing.hdr" }),
        json!({ "material": "gold", "nbrdf": "missing.nbrdf" }),
        json!({ "material": "gold", "env": "/dev/zero" }),
        json!({ "material": "gold", "nbrdf": ".." }),
        json!({ "material": "gold", "env": "." }),
    ] {
        answers.push(daemon.post("/sessions", plan));
    }
    for (status, body) in answers {
        assert!(status >= 400, "{body}");
        let message = body["message"].as_str().unwrap();
        for folder in &folders {
            assert!(!message.contains(folder.as_str()), "{message}");
        }
    }
}

/// Issue 42: `POST /sessions` says where the new session is (`Location`); a finished session
/// cannot be resumed (409, the session's state, not the request, is what refuses); and result
/// files are served as download tools expect (RFC 9110 §8.8.3, §13, §14): a strong `ETag`,
/// 304 for `If-None-Match`, one byte range as 206 with `Content-Range`, 416 past the end.
#[test]
fn sessions_have_a_location_and_result_files_take_etags_and_ranges() {
    let dir = tempfile::tempdir().unwrap();
    let daemon = Daemon::simulated(&dir.path().join("state"));
    let origin = format!("http://{}", daemon.addr);
    let r = http()
        .post(format!("{origin}/api/v1/sessions"))
        .json(&json!({ "material": "gold", "size": 64 }))
        .send()
        .unwrap();
    assert_eq!(r.status().as_u16(), 202);
    let location = r.headers()["location"].to_str().unwrap().to_string();
    let body: Value = r.json().unwrap();
    let id = body["id"].as_str().unwrap().to_string();
    assert_eq!(location, format!("/api/v1/sessions/{id}"));
    let shown: Value = http()
        .get(format!("{origin}{location}"))
        .send()
        .unwrap()
        .json()
        .unwrap();
    assert_eq!(shown["id"], id.as_str(), "{shown}");
    let events = daemon.events(&id);
    assert_eq!(events.last().unwrap()["state"], "done");

    let r = http()
        .post(format!("{origin}/api/v1/sessions/{id}/resume"))
        .json(&json!({}))
        .send()
        .unwrap();
    problem(r, 409, "already_done");

    let url = format!("{origin}/api/v1/sessions/{id}/result/preview.png");
    let get = |headers: &[(&str, &str)]| {
        let mut r = http().get(&url);
        for (name, value) in headers {
            r = r.header(*name, *value);
        }
        r.send().unwrap()
    };
    let whole = get(&[]);
    assert_eq!(whole.status().as_u16(), 200);
    assert_eq!(whole.headers()["accept-ranges"], "bytes");
    let tag = whole.headers()["etag"].to_str().unwrap().to_string();
    assert!(
        tag.starts_with('"') && tag.ends_with('"') && tag.len() > 2,
        "a strong tag: {tag}"
    );
    let bytes = whole.bytes().unwrap().to_vec();
    let length = bytes.len();
    assert!(length > 100, "{length}");

    // The same file, asked again with its tag, and the tag among others or weakly compared.
    for given in [
        tag.clone(),
        format!("\"other\", {tag}"),
        format!("W/{tag}"),
        "*".into(),
    ] {
        let r = get(&[("If-None-Match", &given)]);
        assert_eq!(r.status().as_u16(), 304, "{given}");
        assert_eq!(r.headers()["etag"], tag.as_str());
        assert!(r.bytes().unwrap().is_empty());
    }
    assert_eq!(
        get(&[("If-None-Match", "\"other\"")]).status().as_u16(),
        200
    );
    // The same tag a second time: the file did not change.
    assert_eq!(get(&[]).headers()["etag"], tag.as_str());

    let part = |range: &str, if_range: Option<&str>| {
        let mut headers = vec![("Range", range)];
        if let Some(v) = if_range {
            headers.push(("If-Range", v));
        }
        let r = get(&headers);
        let status = r.status().as_u16();
        let content_range = r
            .headers()
            .get("content-range")
            .map(|v| v.to_str().unwrap().to_string());
        (status, content_range, r.bytes().unwrap().to_vec())
    };
    assert_eq!(
        part("bytes=10-19", None),
        (
            206,
            Some(format!("bytes 10-19/{length}")),
            bytes[10..20].to_vec()
        )
    );
    assert_eq!(
        part("bytes=-16", None),
        (
            206,
            Some(format!("bytes {}-{}/{length}", length - 16, length - 1)),
            bytes[length - 16..].to_vec()
        )
    );
    assert_eq!(
        part(&format!("bytes={}-", length - 5), None),
        (
            206,
            Some(format!("bytes {}-{}/{length}", length - 5, length - 1)),
            bytes[length - 5..].to_vec()
        )
    );
    // A last byte past the end is the end.
    assert_eq!(
        part(&format!("bytes=0-{}", length * 2), None).1,
        Some(format!("bytes 0-{}/{length}", length - 1))
    );
    // The range of this version only; several ranges, or a range the syntax does not allow,
    // get the whole file (§14.2, §14.1.1).
    for (range, if_range) in [
        ("bytes=10-19", Some("\"another version\"")),
        ("bytes=0-1,5-6", None),
        ("bytes=19-10", None),
        ("bytes=+1-2", None),
        ("lines=1-2", None),
    ] {
        assert_eq!(part(range, if_range), (200, None, bytes.clone()), "{range}");
    }
    assert_eq!(part("bytes=10-19", Some(&tag)).0, 206);
    // Past the end: 416, saying how long the file is.
    for range in [format!("bytes={length}-"), "bytes=-0".to_string()] {
        let r = get(&[("Range", &range)]);
        assert_eq!(
            r.headers()["content-range"].to_str().unwrap(),
            format!("bytes */{length}"),
            "{range}"
        );
        problem(r, 416, "range_not_satisfiable");
    }
    // The result itself (coefficients.json) is served the same way.
    let r = http()
        .get(format!("{origin}/api/v1/sessions/{id}/result"))
        .send()
        .unwrap();
    assert!(r.headers().contains_key("etag"));
    // A result file the session does not have is named as such, not by its path.
    let r = http()
        .get(format!(
            "{origin}/api/v1/sessions/{id}/result/visibility.png"
        ))
        .send()
        .unwrap();
    let body = problem(r, 404, "not_found");
    assert_eq!(
        body["detail"],
        format!("session {id} has no visibility.png")
    );
}

/// A part split into two materials has each material's results in its own folder
/// (`material-1/`, `material-2/`), which the whole part's report links: the daemon serves
/// them as it serves the whole part's, names a missing one by its folder, and serves no
/// folder but a material's. The simulated bench renders one material, so the first
/// material's report here is the session's own, copied where a split writes it.
#[test]
fn a_materials_own_results_are_served_from_its_folder() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let daemon = Daemon::simulated(&state);
    let id = finished_session(&daemon);
    let result = state.join("sessions").join(&id).join("result");
    std::fs::create_dir(result.join("material-1")).unwrap();
    let report = std::fs::read(result.join("report.html")).unwrap();
    std::fs::write(result.join("material-1/report.html"), &report).unwrap();
    let origin = format!("http://{}", daemon.addr);
    let r = http()
        .get(format!(
            "{origin}/api/v1/sessions/{id}/result/material-1/report.html"
        ))
        .send()
        .unwrap();
    assert_eq!(r.status().as_u16(), 200);
    assert_eq!(media_type(&r), "text/html");
    assert!(r.headers().contains_key("etag"));
    assert_eq!(r.bytes().unwrap().to_vec(), report);
    let r = http()
        .get(format!(
            "{origin}/api/v1/sessions/{id}/result/material-2/report.html"
        ))
        .send()
        .unwrap();
    let body = problem(r, 404, "not_found");
    assert_eq!(
        body["detail"],
        format!("session {id} has no material-2/report.html")
    );
    // "material-1/.." reaches the route as one segment, and is no folder of the list.
    for folder in ["material-3", "derived", "material-1%2F.."] {
        let r = http()
            .get(format!(
                "{origin}/api/v1/sessions/{id}/result/{folder}/report.html"
            ))
            .send()
            .unwrap();
        assert_eq!(r.status().as_u16(), 404, "{folder}");
    }
}
