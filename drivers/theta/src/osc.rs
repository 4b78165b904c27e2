//! The THETA Web API's JSON (Open Spherical Camera API v2.1 plus RICOH's `_` extensions): the
//! bodies of `/osc/info`, `/osc/state`, `/osc/checkForUpdates`, and the command objects that
//! `/osc/commands/execute` and `/osc/commands/status` return. Shared by the client and the
//! simulator, so both speak one schema.
//!
//! Unknown fields are kept where a caller may want them (`extra`) and ignored elsewhere: real
//! cameras add fields with each firmware, and a new field must not break a capture.

use serde::{Deserialize, Deserializer, Serialize};
use serde_json::{Map, Value};

/// `GET /osc/info`.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(rename_all = "camelCase", default)]
pub struct Info {
    pub manufacturer: String,
    pub model: String,
    pub serial_number: String,
    pub firmware_version: String,
    pub support_url: String,
    pub api_level: Vec<u32>,
    pub endpoints: Endpoints,
    pub gps: bool,
    pub gyro: bool,
    pub uptime: u64,
    pub api: Vec<String>,
}

#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(rename_all = "camelCase", default)]
pub struct Endpoints {
    pub http_port: u16,
    pub http_updates_port: u16,
}

/// `POST /osc/state`.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct StateResponse {
    pub fingerprint: String,
    pub state: CameraState,
}

/// The camera's state. THETA fields start with `_`; S and SC on API level 1 report
/// `sessionId` and `_latestFileUri` instead of `_latestFileUrl`.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct CameraState {
    #[serde(rename = "batteryLevel")]
    pub battery_level: f64,
    #[serde(rename = "storageUri", skip_serializing_if = "Option::is_none")]
    pub storage_uri: Option<String>,
    #[serde(rename = "_captureStatus")]
    pub capture_status: String,
    #[serde(rename = "_latestFileUrl", skip_serializing_if = "Option::is_none")]
    pub latest_file_url: Option<String>,
    #[serde(rename = "_cameraError")]
    pub camera_error: Vec<String>,
    #[serde(rename = "_apiVersion")]
    pub api_version: u32,
    #[serde(rename = "_batteryState", skip_serializing_if = "Option::is_none")]
    pub battery_state: Option<String>,
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// `POST /osc/checkForUpdates`: the fingerprint changes whenever the state does.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(rename_all = "camelCase", default)]
pub struct Updates {
    pub state_fingerprint: String,
    pub throttle_timeout: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub enum CommandState {
    Done,
    InProgress,
    Error,
}

/// A command's answer from `execute` or `status`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Command {
    #[serde(default)]
    pub name: String,
    pub state: CommandState,
    /// Command id for `/osc/commands/status`. The spec says string; some firmwares send a
    /// number, so both are accepted.
    #[serde(
        default,
        deserialize_with = "string_or_number",
        skip_serializing_if = "Option::is_none"
    )]
    pub id: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub results: Option<Value>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<ErrorBody>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub progress: Option<Progress>,
}

impl Command {
    pub fn done(name: &str, results: Option<Value>) -> Command {
        Command {
            name: name.into(),
            state: CommandState::Done,
            id: None,
            results,
            error: None,
            progress: None,
        }
    }

    pub fn failed(name: &str, code: &str, message: &str) -> Command {
        Command {
            name: name.into(),
            state: CommandState::Error,
            id: None,
            results: None,
            error: Some(ErrorBody {
                code: code.into(),
                message: message.into(),
            }),
            progress: None,
        }
    }

    /// `results.fileUrl` (takePicture) or `results.fileUrls` (startCapture).
    pub fn file_urls(&self) -> Vec<String> {
        let Some(r) = &self.results else {
            return Vec::new();
        };
        if let Some(u) = r.get("fileUrl").and_then(Value::as_str) {
            return vec![u.to_string()];
        }
        r.get("fileUrls")
            .and_then(Value::as_array)
            .map(|a| {
                a.iter()
                    .filter_map(|u| u.as_str().map(String::from))
                    .collect()
            })
            .unwrap_or_default()
    }

    /// `results.options` of getOptions.
    pub fn options(&self) -> Map<String, Value> {
        self.results
            .as_ref()
            .and_then(|r| r.get("options"))
            .and_then(Value::as_object)
            .cloned()
            .unwrap_or_default()
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ErrorBody {
    pub code: String,
    #[serde(default)]
    pub message: String,
}

/// Error codes and their HTTP statuses, from the THETA Web API's error table.
pub mod error_code {
    pub const UNKNOWN_COMMAND: &str = "unknownCommand";
    pub const DISABLED_COMMAND: &str = "disabledCommand";
    pub const MISSING_PARAMETER: &str = "missingParameter";
    pub const INVALID_PARAMETER_NAME: &str = "invalidParameterName";
    pub const INVALID_PARAMETER_VALUE: &str = "invalidParameterValue";
    pub const SERVICE_UNAVAILABLE: &str = "serviceUnavailable";
    pub const CANCELED_SHOOTING: &str = "canceledShooting";
    pub const UNEXPECTED: &str = "unexpected";

    pub fn http_status(code: &str) -> u16 {
        match code {
            DISABLED_COMMAND
            | CANCELED_SHOOTING
            | "tooManyParameters"
            | "corruptedFile"
            | "powerOffSequenceRunning"
            | "invalidFileFormat"
            | "canceledConversion" => 403,
            SERVICE_UNAVAILABLE | UNEXPECTED => 503,
            "notFound" => 404,
            _ => 400,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Progress {
    #[serde(default)]
    pub completion: f64,
}

/// One shot of `_autoBracket` (THETA S firmware 1.82+, SC, V, Z1, X). THETA V takes up to 13
/// shots (19 on recent firmware); the aperture is fixed except on the Z1.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BracketShot {
    #[serde(rename = "shutterSpeed")]
    pub shutter_speed: f64,
    pub iso: u32,
    #[serde(rename = "_colorTemperature", skip_serializing_if = "Option::is_none")]
    pub color_temperature: Option<u32>,
    #[serde(rename = "exposureProgram", skip_serializing_if = "Option::is_none")]
    pub exposure_program: Option<u32>,
    #[serde(rename = "whiteBalance", skip_serializing_if = "Option::is_none")]
    pub white_balance: Option<String>,
    #[serde(
        rename = "exposureCompensation",
        skip_serializing_if = "Option::is_none"
    )]
    pub exposure_compensation: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub aperture: Option<f64>,
}

/// The `_autoBracket` option.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AutoBracket {
    #[serde(rename = "_bracketNumber")]
    pub number: u32,
    #[serde(rename = "_bracketParameters")]
    pub parameters: Vec<BracketShot>,
}

/// One entry of `camera.listFiles`.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(rename_all = "camelCase", default)]
pub struct FileEntry {
    pub name: String,
    pub file_url: String,
    pub size: u64,
    pub date_time_zone: String,
    pub width: u32,
    pub height: u32,
    #[serde(rename = "_projectionType", skip_serializing_if = "Option::is_none")]
    pub projection_type: Option<String>,
}

#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(rename_all = "camelCase", default)]
pub struct FileList {
    pub entries: Vec<FileEntry>,
    pub total_entries: u64,
}

fn string_or_number<'de, D: Deserializer<'de>>(d: D) -> Result<Option<String>, D::Error> {
    Ok(match Option::<Value>::deserialize(d)? {
        Some(Value::String(s)) => Some(s),
        Some(Value::Number(n)) => Some(n.to_string()),
        _ => None,
    })
}
