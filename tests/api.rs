//! The daemon's OpenAPI description (`GET /api/v1/openapi.json`) against the live daemon:
//! every operation it lists answers only as it says, every route the daemon answers is in it,
//! and schemathesis (from PyPI), an outside client that generates requests from the
//! description, finds no server error and no answer outside it. CI installs schemathesis and
//! sets BRDFD_REQUIRE_SCHEMATHESIS=1, so there that test cannot skip.

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
            files.iter().map(|f| path.replace("{file}", f)).collect()
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
                if media == "application/json" && !path.ends_with("/events") {
                    let body: Value = r.json().unwrap();
                    if let Some(schema) = described.get("schema") {
                        conforms(&spec, schema, &body)
                            .unwrap_or_else(|e| panic!("{method} {url}: {e}"));
                    }
                }
                if path.contains("{file}") {
                    // The session's object is a sphere, which hides nothing from itself: the
                    // visibility picture and the export on the object are written for a mesh
                    // only.
                    let expected =
                        if url.ends_with("/visibility.png") || url.ends_with("/object.gltf") {
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

/// schemathesis, bounded to 100 examples per operation, against a daemon with a finished session: no
/// 500, and no status, media type, header or body the description does not allow.
#[test]
fn schemathesis_finds_no_error_and_no_answer_outside_the_schema() {
    let Some(st) = schemathesis() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let daemon = Daemon::simulated(&dir.path().join("state"));
    finished_session(&daemon);
    let o = Command::new(&st)
        .current_dir(dir.path())
        .args([
            "run",
            &format!("http://{}/api/v1/openapi.json", daemon.addr),
            "--checks",
            "not_a_server_error,status_code_conformance,content_type_conformance,\
             response_headers_conformance,response_schema_conformance",
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
