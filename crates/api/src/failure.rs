//! Why a capture failed, as a code a program can act on: carried by the failure's event and
//! kept in the session's manifest, so it sits below both.

use serde::{Deserialize, Serialize};

/// Why a capture failed, for programs: what a client can act on without reading the message.
/// Every failed capture keeps what it captured, and `resume` continues it once the cause is
/// gone. `cancelled`: the operator or a client cancelled it. `device_busy`: another program
/// holds a device; close it. `device_permission`: no permission to open a device (udev rules,
/// a group). `device_missing`: a device is not there or cannot be reached. `device_lost`: a
/// device went away during the capture. `device_timeout`: a device did not answer in time.
/// `disk_full`: the disk is full; free space. `failed`: anything else; the message says what.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum FailureCode {
    /// The operator or a client cancelled it.
    Cancelled,
    /// Another program holds a device (a desktop's camera monitor, a serial console, another
    /// capture tool): close it, then resume.
    DeviceBusy,
    /// No permission to open a device: the udev rules or a group are missing.
    DevicePermission,
    /// A device is not there, or cannot be reached: not plugged in, switched off, or not on
    /// this network.
    DeviceMissing,
    /// A device went away during the capture: unplugged, reset or disconnected.
    DeviceLost,
    /// A device did not answer in time.
    DeviceTimeout,
    /// The disk is full: free space, then resume.
    DiskFull,
    /// Anything else: the message says what.
    Failed,
}

impl FailureCode {
    /// The code as the API writes it.
    pub fn name(self) -> &'static str {
        match self {
            FailureCode::Cancelled => "cancelled",
            FailureCode::DeviceBusy => "device_busy",
            FailureCode::DevicePermission => "device_permission",
            FailureCode::DeviceMissing => "device_missing",
            FailureCode::DeviceLost => "device_lost",
            FailureCode::DeviceTimeout => "device_timeout",
            FailureCode::DiskFull => "disk_full",
            FailureCode::Failed => "failed",
        }
    }

    /// A code as a reader takes it: one this version does not know (written by a newer brdfd)
    /// reads as [`FailureCode::Failed`], so that the session and its stream still read.
    pub fn read_lenient<'de, D: serde::Deserializer<'de>>(
        d: D,
    ) -> Result<Option<FailureCode>, D::Error> {
        let code = Option::<String>::deserialize(d)?;
        Ok(code.map(|c| {
            FailureCode::ALL
                .into_iter()
                .find(|k| k.name() == c)
                .unwrap_or(FailureCode::Failed)
        }))
    }

    /// Every code, for the API's description and its test.
    pub const ALL: [FailureCode; 8] = [
        FailureCode::Cancelled,
        FailureCode::DeviceBusy,
        FailureCode::DevicePermission,
        FailureCode::DeviceMissing,
        FailureCode::DeviceLost,
        FailureCode::DeviceTimeout,
        FailureCode::DiskFull,
        FailureCode::Failed,
    ];
}

impl std::fmt::Display for FailureCode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}
