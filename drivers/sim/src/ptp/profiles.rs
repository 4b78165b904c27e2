//! What the simulated cameras report about themselves. The Nikon D5100, the Canon EOS R6, the
//! Sony a7 IV and the THETA V and Z1 follow the real cameras' dumps published by libgphoto2 (`shared/data/ptp/device-dumps/`):
//! vendor extension, model strings, properties with their types, ranges and values. The Z1's
//! dump answered "device busy" for most properties (it was asleep); those follow the V's,
//! with the Z1's ISOs and apertures from RICOH's API reference.

use brdfd_ptp::codes::{datatype as dt, event, format, op, prop, vendor};
use brdfd_ptp::dataset::{DeviceInfo, DevicePropDesc, Form, StorageInfo, Value};
use brdfd_theta::usb::{code as ricoh, shutter_to_u64};

use crate::theta::THETA_V_SHUTTERS;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Profile {
    /// A still camera of the generic PTP class: InitiateCapture and events.
    Generic,
    /// Nikon D5100: Nikon vendor extension, capture to SDRAM, GetEvent polling.
    NikonD5100,
    /// RICOH THETA V on USB.
    ThetaV,
    /// RICOH THETA Z1 on USB: the V's RICOH properties, its own ISOs, and three apertures.
    ThetaZ1,
    /// Canon EOS R6: Canon's vendor extension, no InitiateCapture, the EOS remote release
    /// with its properties and files reported through GetEvent.
    CanonEosR6,
    /// Sony a7 IV (ILCE-7M4) in PC remote mode: Sony's extension, no InitiateCapture and no
    /// storage, the SDIO connection, its properties in one list, the shutter buttons, and
    /// the shot in its memory.
    SonyA7M4,
}

impl Profile {
    pub fn parse(s: &str) -> Option<Profile> {
        Some(match s {
            "generic" => Profile::Generic,
            "nikon-d5100" | "d5100" => Profile::NikonD5100,
            "theta-v" => Profile::ThetaV,
            "theta-z1" => Profile::ThetaZ1,
            "canon-eos-r6" => Profile::CanonEosR6,
            "sony-a7m4" => Profile::SonyA7M4,
            _ => return None,
        })
    }

    pub const NAMES: [&'static str; 6] = [
        "generic",
        "nikon-d5100",
        "theta-v",
        "theta-z1",
        "canon-eos-r6",
        "sony-a7m4",
    ];

    /// Whether the profile is a Sony body in PC remote mode (SDIO control, no storage).
    pub fn is_sony(self) -> bool {
        self == Profile::SonyA7M4
    }

    /// Whether the profile is a Canon EOS body (the remote release, GetEvent's records).
    pub fn is_canon_eos(self) -> bool {
        self == Profile::CanonEosR6
    }

    /// Whether the profile is a RICOH THETA (RICOH's properties, `R00nnnnn.JPG` names).
    pub fn is_theta(self) -> bool {
        self.theta_model().is_some()
    }

    /// A THETA's model string, as its DeviceInfo gives it.
    pub fn theta_model(self) -> Option<&'static str> {
        match self {
            Profile::ThetaV => Some("RICOH THETA V"),
            Profile::ThetaZ1 => Some("RICOH THETA Z1"),
            _ => None,
        }
    }

    /// The simulated THETA's aperture in hundredths (F-Number, 0x5007), for a profile that
    /// has the property; the V's is fixed at f/2.0.
    pub fn theta_apertures(self) -> &'static [u16] {
        match self {
            Profile::ThetaZ1 => &[210, 350, 560],
            _ => &[],
        }
    }

    /// The one store's ID, as the dumps list it: a DSLR's card is 0x00010001, the THETAs'
    /// built-in memory 0x00020001.
    pub fn storage_id(self) -> u32 {
        if self.is_theta() {
            0x0002_0001
        } else {
            0x0001_0001
        }
    }

    pub fn usb_ids(self) -> (u16, u16) {
        match self {
            Profile::Generic => (0x1d6b, 0x0104),
            Profile::NikonD5100 => (0x04b0, 0x0429),
            Profile::ThetaV => (0x05ca, 0x0368),
            Profile::ThetaZ1 => (0x05ca, 0x036d),
            Profile::CanonEosR6 => (0x04a9, 0x32f5),
            // "PC Control", the mode that captures (its "MTP mode" is 0x0da6).
            Profile::SonyA7M4 => (0x054c, 0x0da7),
        }
    }
}

const STANDARD_OPS: [u16; 16] = [
    op::GET_DEVICE_INFO,
    op::OPEN_SESSION,
    op::CLOSE_SESSION,
    op::GET_STORAGE_IDS,
    op::GET_STORAGE_INFO,
    op::GET_NUM_OBJECTS,
    op::GET_OBJECT_HANDLES,
    op::GET_OBJECT_INFO,
    op::GET_OBJECT,
    op::GET_THUMB,
    op::DELETE_OBJECT,
    op::INITIATE_CAPTURE,
    op::GET_DEVICE_PROP_DESC,
    op::GET_DEVICE_PROP_VALUE,
    op::SET_DEVICE_PROP_VALUE,
    op::GET_PARTIAL_OBJECT,
];

/// The Canon operations the simulated EOS body answers, of the 182 its dump lists.
const CANON_EOS_OPS: [u16; 13] = [
    op::CANON_EOS_GET_STORAGE_IDS,
    op::CANON_EOS_GET_STORAGE_INFO,
    op::CANON_EOS_SET_DEVICE_PROP_VALUE_EX,
    op::CANON_EOS_SET_REMOTE_MODE,
    op::CANON_EOS_SET_EVENT_MODE,
    op::CANON_EOS_GET_EVENT,
    op::CANON_EOS_TRANSFER_COMPLETE,
    op::CANON_EOS_PC_HDD_CAPACITY,
    op::CANON_EOS_SET_UI_LOCK,
    op::CANON_EOS_RESET_UI_LOCK,
    op::CANON_EOS_KEEP_DEVICE_ON,
    op::CANON_EOS_REMOTE_RELEASE_ON,
    op::CANON_EOS_REMOTE_RELEASE_OFF,
];

/// The Sony operations the simulated a7 IV answers.
const SONY_OPS: [u16; 5] = [
    op::SONY_SDIO_CONNECT,
    op::SONY_SDIO_GET_EXT_DEVICE_INFO,
    op::SONY_SDIO_SET_EXT_DEVICE_PROP_VALUE,
    op::SONY_SDIO_CONTROL_DEVICE,
    op::SONY_SDIO_GET_ALL_EXT_DEVICE_PROP_INFO,
];

pub fn device_info(p: Profile) -> DeviceInfo {
    let mut ops = STANDARD_OPS.to_vec();
    let props = properties(p).iter().map(|d| d.code).collect();
    let events = vec![
        event::OBJECT_ADDED,
        event::OBJECT_REMOVED,
        event::DEVICE_PROP_CHANGED,
        event::STORE_FULL,
        event::CAPTURE_COMPLETE,
    ];
    match p {
        Profile::Generic => DeviceInfo {
            standard_version: 100,
            vendor_extension_id: vendor::MICROSOFT,
            vendor_extension_version: 100,
            vendor_extension_desc: "microsoft.com: 1.0".into(),
            operations: ops,
            events,
            properties: props,
            capture_formats: vec![format::EXIF_JPEG],
            image_formats: vec![format::EXIF_JPEG, format::ASSOCIATION],
            manufacturer: "brdfd".into(),
            model: "Simulated still camera".into(),
            device_version: "1.0".into(),
            serial_number: "SIM0001".into(),
            ..Default::default()
        },
        Profile::NikonD5100 => {
            ops.extend([
                op::NIKON_INITIATE_CAPTURE_REC_IN_SDRAM,
                op::NIKON_AF_DRIVE,
                op::NIKON_CHANGE_CAMERA_MODE,
                op::NIKON_GET_EVENT,
                op::NIKON_DEVICE_READY,
                op::NIKON_GET_VENDOR_PROP_CODES,
                op::NIKON_INITIATE_CAPTURE_REC_IN_MEDIA,
            ]);
            DeviceInfo {
                standard_version: 100,
                vendor_extension_id: vendor::NIKON,
                vendor_extension_version: 100,
                vendor_extension_desc: "microsoft.com: 1.0".into(),
                operations: ops,
                events,
                properties: props,
                capture_formats: vec![format::EXIF_JPEG, format::UNDEFINED],
                image_formats: vec![format::EXIF_JPEG, format::UNDEFINED, format::ASSOCIATION],
                manufacturer: "Nikon Corporation".into(),
                model: "D5100".into(),
                device_version: "V1.01".into(),
                serial_number: "0000000000000000000000000005100".into(),
                ..Default::default()
            }
        }
        Profile::CanonEosR6 => {
            // As the dump: no InitiateCapture ("No Image Capture … Canon EOS Capture").
            ops.retain(|&o| o != op::INITIATE_CAPTURE);
            ops.extend(CANON_EOS_OPS);
            DeviceInfo {
                standard_version: 100,
                vendor_extension_id: vendor::CANON,
                vendor_extension_version: 100,
                vendor_extension_desc: String::new(),
                operations: ops,
                events: vec![
                    event::OBJECT_ADDED,
                    event::OBJECT_REMOVED,
                    event::DEVICE_PROP_CHANGED,
                ],
                properties: props,
                capture_formats: vec![format::EXIF_JPEG],
                image_formats: vec![
                    format::ASSOCIATION,
                    format::EXIF_JPEG,
                    format::CANON_CR2,
                    format::CANON_CR3,
                ],
                manufacturer: "Canon.Inc".into(),
                model: "Canon EOS R6".into(),
                device_version: "3-1.0.0".into(),
                serial_number: "0000000000000000000000000000e0r6".into(),
                ..Default::default()
            }
        }
        Profile::SonyA7M4 => {
            // As the dump: no InitiateCapture ("No Image Capture … Sony Capture"), no file
            // deletion, no capture format; its properties are listed by GetExtDeviceInfo.
            ops.retain(|&o| o != op::INITIATE_CAPTURE && o != op::DELETE_OBJECT);
            ops.extend(SONY_OPS);
            DeviceInfo {
                standard_version: 100,
                vendor_extension_id: vendor::SONY,
                vendor_extension_version: 100,
                vendor_extension_desc: "Sony PTP Extensions".into(),
                operations: ops,
                events: vec![event::SONY_OBJECT_ADDED, event::SONY_DEVICE_PROP_CHANGED],
                properties: Vec::new(),
                capture_formats: Vec::new(),
                image_formats: vec![
                    format::ASSOCIATION,
                    format::EXIF_JPEG,
                    format::RAW,
                    format::MPEG,
                    FORMAT_MP4,
                    FORMAT_HEIF,
                ],
                manufacturer: "Sony Corporation".into(),
                model: "ILCE-7M4".into(),
                device_version: "1.00".into(),
                serial_number: "00000000000000001234567891234567".into(),
                ..Default::default()
            }
        }
        Profile::ThetaV | Profile::ThetaZ1 => {
            // As the dumps: the Z1 lists no capture format, and DNG, MP4 and firmware files
            // besides JPEGs.
            let (capture_formats, image_formats, version, serial) = match p {
                Profile::ThetaZ1 => (
                    Vec::new(),
                    vec![
                        format::ASSOCIATION,
                        format::EXIF_JPEG,
                        FORMAT_MP4,
                        format::DNG,
                        FORMAT_FIRMWARE,
                    ],
                    "1.50.1",
                    "10010065",
                ),
                _ => (
                    vec![format::EXIF_JPEG],
                    vec![format::EXIF_JPEG, format::ASSOCIATION],
                    "3.50.1",
                    "00165759",
                ),
            };
            DeviceInfo {
                standard_version: 100,
                vendor_extension_id: vendor::MICROSOFT,
                vendor_extension_version: 110,
                vendor_extension_desc: String::new(),
                operations: ops,
                events,
                properties: props,
                capture_formats,
                image_formats,
                manufacturer: "Ricoh Company, Ltd.".into(),
                model: p.theta_model().unwrap_or_default().into(),
                device_version: version.into(),
                serial_number: serial.into(),
                ..Default::default()
            }
        }
    }
}

pub fn storage_info(p: Profile, used: u64) -> StorageInfo {
    let max = match p {
        Profile::ThetaV => 21_088_788_480,
        Profile::ThetaZ1 => 21_055_815_680,
        Profile::CanonEosR6 => 64_054_362_112,
        _ => 16_298_016_768,
    };
    StorageInfo {
        // The THETAs' dumps: built-in memory (fixed RAM); a DSLR's card is removable RAM.
        storage_type: if p.is_theta() { 3 } else { 4 },
        // The camera layout (DCIM), as every dump reads.
        filesystem_type: 3,
        // Read-write, as the dumps read, but for the D5100's "Read Only with Object deletion".
        access_capability: if p == Profile::NikonD5100 { 2 } else { 0 },
        max_capacity: max,
        free_space_bytes: max.saturating_sub(used),
        // The R6 does not count images (its dump reads -1).
        free_space_images: match p {
            Profile::CanonEosR6 => u32::MAX,
            _ => (max.saturating_sub(used) / 9_000_000) as u32,
        },
        description: match p {
            Profile::CanonEosR6 => "SD1".into(),
            _ => String::new(),
        },
        volume_label: match p {
            Profile::NikonD5100 => "NIKON D5100".into(),
            _ => String::new(),
        },
    }
}

fn e(code: u16, ty: u16, writable: bool, current: i64, values: &[i64]) -> DevicePropDesc {
    let v = |x: i64| {
        if matches!(ty, dt::INT8 | dt::INT16 | dt::INT32 | dt::INT64) {
            Value::Int(x)
        } else {
            Value::UInt(x as u64)
        }
    };
    DevicePropDesc {
        code,
        datatype: ty,
        writable,
        factory_default: v(values[0]),
        current: v(current),
        form: Form::Enum(values.iter().map(|&x| v(x)).collect()),
    }
}

fn range(code: u16, ty: u16, writable: bool, current: u64, min: u64, max: u64) -> DevicePropDesc {
    DevicePropDesc {
        code,
        datatype: ty,
        writable,
        factory_default: Value::UInt(current),
        current: Value::UInt(current),
        form: Form::Range {
            min: Value::UInt(min),
            max: Value::UInt(max),
            step: Value::UInt(1),
        },
    }
}

/// The D5100's shutter speeds in manual mode, in 1/10000 s (from the real camera's dump;
/// 0xFFFFFFFF is bulb).
const D5100_EXPOSURE_TIMES: [i64; 53] = [
    2, 3, 4, 5, 6, 8, 10, 12, 15, 20, 25, 31, 40, 50, 62, 80, 100, 125, 166, 200, 250, 333, 400,
    500, 666, 769, 1000, 1250, 1666, 2000, 2500, 3333, 4000, 5000, 6250, 7692, 10000, 13000, 16000,
    20000, 25000, 30000, 40000, 50000, 60000, 80000, 100000, 130000, 150000, 200000, 250000,
    300000, 4294967295,
];
const D5100_F_NUMBERS: [i64; 25] = [
    140, 160, 180, 200, 220, 250, 280, 320, 350, 400, 450, 500, 560, 630, 710, 800, 900, 1000,
    1100, 1300, 1400, 1600, 1800, 2000, 2200,
];
const D5100_ISO: [i64; 23] = [
    100, 125, 160, 200, 250, 320, 400, 500, 640, 800, 1000, 1250, 1600, 2000, 2500, 3200, 4000,
    5000, 6400, 8000, 10000, 12800, 25600,
];

pub fn properties(p: Profile) -> Vec<DevicePropDesc> {
    match p {
        Profile::Generic => vec![
            range(prop::BATTERY_LEVEL, dt::UINT8, false, 100, 0, 100),
            e(prop::COMPRESSION_SETTING, dt::UINT8, true, 2, &[0, 1, 2]),
            e(
                prop::F_NUMBER,
                dt::UINT16,
                true,
                800,
                &[280, 400, 560, 800, 1100, 1600],
            ),
            e(
                prop::EXPOSURE_TIME,
                dt::UINT32,
                true,
                100,
                &[
                    1, 2, 5, 10, 20, 40, 80, 100, 125, 250, 500, 1000, 2000, 4000, 10000, 20000,
                    40000,
                ],
            ),
            e(prop::EXPOSURE_PROGRAM_MODE, dt::UINT16, false, 1, &[1]),
            e(
                prop::EXPOSURE_INDEX,
                dt::UINT16,
                true,
                100,
                &[100, 200, 400, 800, 1600],
            ),
        ],
        Profile::NikonD5100 => vec![
            range(prop::BATTERY_LEVEL, dt::UINT8, false, 100, 0, 100),
            e(
                prop::COMPRESSION_SETTING,
                dt::UINT8,
                true,
                2,
                &[0, 1, 2, 4, 5, 6, 7],
            ),
            e(
                prop::WHITE_BALANCE,
                dt::UINT16,
                true,
                4,
                &[2, 4, 5, 6, 7, 32784, 32785, 32787],
            ),
            e(prop::F_NUMBER, dt::UINT16, true, 800, &D5100_F_NUMBERS),
            range(prop::FOCAL_LENGTH, dt::UINT32, false, 8500, 8500, 8500),
            e(
                prop::EXPOSURE_TIME,
                dt::UINT32,
                true,
                3333,
                &D5100_EXPOSURE_TIMES,
            ),
            e(
                prop::EXPOSURE_PROGRAM_MODE,
                dt::UINT16,
                false,
                1,
                &[
                    1, 2, 3, 4, 32784, 32785, 32786, 32787, 32788, 32790, 32791, 32792, 32793,
                ],
            ),
            e(prop::EXPOSURE_INDEX, dt::UINT16, true, 100, &D5100_ISO),
            e(
                prop::STILL_CAPTURE_MODE,
                dt::UINT16,
                true,
                1,
                &[1, 2, 32785, 32788, 32789, 32790],
            ),
            range(prop::BURST_NUMBER, dt::UINT16, true, 1, 1, 100),
            range(prop::NIKON_RECORDING_MEDIA, dt::UINT8, true, 1, 0, 2),
        ],
        // The R6's standard properties, as its dump lists them (its exposure settings are
        // Canon's own, reported through GetEvent: `crate::ptp::canon`).
        Profile::CanonEosR6 => vec![e(
            prop::BATTERY_LEVEL,
            dt::UINT8,
            false,
            28,
            &[100, 0, 75, 0, 50],
        )],
        // Sony's properties are its own list (`crate::ptp::sony`), not PTP's.
        Profile::SonyA7M4 => Vec::new(),
        Profile::ThetaV => theta_properties(p, &THETA_V_ISOS),
        Profile::ThetaZ1 => theta_properties(p, &THETA_Z1_ISOS),
    }
}

/// The ISOs of manual exposure, in RICOH's USB API reference.
const THETA_V_ISOS: [i64; 18] = [
    64, 80, 100, 125, 160, 200, 250, 320, 400, 500, 640, 800, 1000, 1250, 1600, 2000, 2500, 3200,
];
const THETA_Z1_ISOS: [i64; 20] = [
    80, 100, 125, 160, 200, 250, 320, 400, 500, 640, 800, 1000, 1250, 1600, 2000, 2500, 3200, 4000,
    5000, 6400,
];
/// Object formats of the Z1's dump that PTP's table leaves to vendors.
const FORMAT_MP4: u16 = 0xB982;
const FORMAT_FIRMWARE: u16 = 0xB802;
const FORMAT_HEIF: u16 = 0xB110;

/// A THETA's properties on USB: RICOH's, with the model's ISOs and, on the Z1, its apertures.
fn theta_properties(p: Profile, isos: &[i64]) -> Vec<DevicePropDesc> {
    let mut props = vec![
        range(prop::BATTERY_LEVEL, dt::UINT8, false, 98, 0, 100),
        e(
            prop::WHITE_BALANCE,
            dt::UINT16,
            true,
            2,
            &[
                2, 4, 32769, 32770, 6, 32800, 32771, 32772, 32773, 32774, 32775, 32776,
            ],
        ),
        e(
            prop::EXPOSURE_PROGRAM_MODE,
            dt::UINT16,
            true,
            2,
            &[1, 2, 4, 32771],
        ),
        e(prop::EXPOSURE_INDEX, dt::UINT16, true, 100, isos),
        e(
            prop::STILL_CAPTURE_MODE,
            dt::UINT16,
            true,
            1,
            &[1, 3, 32770, 32772, 32773, 32774, 32775],
        ),
        // Sleep: 1 while asleep; writing 0 wakes the camera.
        e(prop::RICOH_SLEEP, dt::UINT8, true, 0, &[0, 1]),
        theta_shutter_speed(),
        e(ricoh::FILTER, dt::UINT8, true, 0, &[0, 1, 2, 3, 4]),
        range(ricoh::SLEEP_DELAY, dt::UINT16, true, 180, 0, 65534),
        range(
            ricoh::AUTO_POWER_OFF_DELAY_SEC,
            dt::UINT32,
            true,
            64800,
            0,
            2_592_000,
        ),
        range(
            ricoh::COLOR_TEMPERATURE,
            dt::UINT16,
            true,
            5000,
            2500,
            10000,
        ),
    ];
    let apertures: Vec<i64> = p.theta_apertures().iter().map(|a| *a as i64).collect();
    if let Some(first) = apertures.first() {
        props.push(e(prop::F_NUMBER, dt::UINT16, true, *first, &apertures));
    }
    props
}

/// RICOH's shutter speed (0xD00F, UINT64 rationals; 0 is automatic), as the THETA V lists it.
/// Automatic until a client sets manual exposure.
fn theta_shutter_speed() -> DevicePropDesc {
    let mut values = vec![Value::UInt(0)];
    values.extend(
        THETA_V_SHUTTERS
            .iter()
            .map(|&(n, d)| Value::UInt(shutter_to_u64(n, d))),
    );
    DevicePropDesc {
        code: ricoh::SHUTTER_SPEED,
        datatype: dt::UINT64,
        writable: true,
        factory_default: Value::UInt(0),
        current: Value::UInt(0),
        form: Form::Enum(values),
    }
}
