//! Operation, response, event, property and data-type codes (ISO 15740, plus the Nikon, Canon
//! and Ricoh vendor codes we use). Numbers only; their meaning is in the names.

pub mod op {
    pub const GET_DEVICE_INFO: u16 = 0x1001;
    pub const OPEN_SESSION: u16 = 0x1002;
    pub const CLOSE_SESSION: u16 = 0x1003;
    pub const GET_STORAGE_IDS: u16 = 0x1004;
    pub const GET_STORAGE_INFO: u16 = 0x1005;
    pub const GET_NUM_OBJECTS: u16 = 0x1006;
    pub const GET_OBJECT_HANDLES: u16 = 0x1007;
    pub const GET_OBJECT_INFO: u16 = 0x1008;
    pub const GET_OBJECT: u16 = 0x1009;
    pub const GET_THUMB: u16 = 0x100A;
    pub const DELETE_OBJECT: u16 = 0x100B;
    pub const INITIATE_CAPTURE: u16 = 0x100E;
    pub const GET_DEVICE_PROP_DESC: u16 = 0x1014;
    pub const GET_DEVICE_PROP_VALUE: u16 = 0x1015;
    pub const SET_DEVICE_PROP_VALUE: u16 = 0x1016;
    pub const GET_PARTIAL_OBJECT: u16 = 0x101B;

    pub const NIKON_INITIATE_CAPTURE_REC_IN_SDRAM: u16 = 0x90C0;
    pub const NIKON_AF_DRIVE: u16 = 0x90C1;
    pub const NIKON_CHANGE_CAMERA_MODE: u16 = 0x90C2;
    pub const NIKON_GET_EVENT: u16 = 0x90C7;
    pub const NIKON_DEVICE_READY: u16 = 0x90C8;
    pub const NIKON_GET_VENDOR_PROP_CODES: u16 = 0x90CA;
    pub const NIKON_INITIATE_CAPTURE_REC_IN_MEDIA: u16 = 0x9207;

    pub const CANON_EOS_GET_STORAGE_IDS: u16 = 0x9101;
    pub const CANON_EOS_GET_STORAGE_INFO: u16 = 0x9102;
    pub const CANON_EOS_SET_DEVICE_PROP_VALUE_EX: u16 = 0x9110;
    pub const CANON_EOS_SET_REMOTE_MODE: u16 = 0x9114;
    pub const CANON_EOS_SET_EVENT_MODE: u16 = 0x9115;
    pub const CANON_EOS_GET_EVENT: u16 = 0x9116;
    pub const CANON_EOS_TRANSFER_COMPLETE: u16 = 0x9117;
    pub const CANON_EOS_PC_HDD_CAPACITY: u16 = 0x911A;
    pub const CANON_EOS_SET_UI_LOCK: u16 = 0x911B;
    pub const CANON_EOS_RESET_UI_LOCK: u16 = 0x911C;
    pub const CANON_EOS_KEEP_DEVICE_ON: u16 = 0x911D;
    pub const CANON_EOS_REMOTE_RELEASE_ON: u16 = 0x9128;
    pub const CANON_EOS_REMOTE_RELEASE_OFF: u16 = 0x9129;

    pub const SONY_SDIO_CONNECT: u16 = 0x9201;
    pub const SONY_SDIO_GET_EXT_DEVICE_INFO: u16 = 0x9202;
    pub const SONY_SDIO_SET_EXT_DEVICE_PROP_VALUE: u16 = 0x9205;
    pub const SONY_SDIO_CONTROL_DEVICE: u16 = 0x9207;
    pub const SONY_SDIO_GET_ALL_EXT_DEVICE_PROP_INFO: u16 = 0x9209;
}

pub mod rc {
    pub const OK: u16 = 0x2001;
    pub const GENERAL_ERROR: u16 = 0x2002;
    pub const SESSION_NOT_OPEN: u16 = 0x2003;
    pub const INVALID_TRANSACTION_ID: u16 = 0x2004;
    pub const OPERATION_NOT_SUPPORTED: u16 = 0x2005;
    pub const PARAMETER_NOT_SUPPORTED: u16 = 0x2006;
    pub const INCOMPLETE_TRANSFER: u16 = 0x2007;
    pub const INVALID_STORAGE_ID: u16 = 0x2008;
    pub const INVALID_OBJECT_HANDLE: u16 = 0x2009;
    pub const DEVICE_PROP_NOT_SUPPORTED: u16 = 0x200A;
    pub const STORE_FULL: u16 = 0x200C;
    pub const STORE_READ_ONLY: u16 = 0x200E;
    pub const ACCESS_DENIED: u16 = 0x200F;
    pub const NO_THUMBNAIL_PRESENT: u16 = 0x2010;
    pub const STORE_NOT_AVAILABLE: u16 = 0x2013;
    pub const DEVICE_BUSY: u16 = 0x2019;
    pub const INVALID_PARAMETER: u16 = 0x201D;
    pub const SESSION_ALREADY_OPEN: u16 = 0x201E;
    pub const TRANSACTION_CANCELLED: u16 = 0x201F;

    /// Human name of a response code, for error messages.
    pub fn name(code: u16) -> &'static str {
        match code {
            OK => "OK",
            GENERAL_ERROR => "GeneralError",
            SESSION_NOT_OPEN => "SessionNotOpen",
            INVALID_TRANSACTION_ID => "InvalidTransactionID",
            OPERATION_NOT_SUPPORTED => "OperationNotSupported",
            PARAMETER_NOT_SUPPORTED => "ParameterNotSupported",
            INCOMPLETE_TRANSFER => "IncompleteTransfer",
            INVALID_STORAGE_ID => "InvalidStorageID",
            INVALID_OBJECT_HANDLE => "InvalidObjectHandle",
            DEVICE_PROP_NOT_SUPPORTED => "DevicePropNotSupported",
            STORE_FULL => "StoreFull",
            STORE_READ_ONLY => "StoreReadOnly",
            ACCESS_DENIED => "AccessDenied",
            NO_THUMBNAIL_PRESENT => "NoThumbnailPresent",
            STORE_NOT_AVAILABLE => "StoreNotAvailable",
            DEVICE_BUSY => "DeviceBusy",
            INVALID_PARAMETER => "InvalidParameter",
            SESSION_ALREADY_OPEN => "SessionAlreadyOpen",
            TRANSACTION_CANCELLED => "TransactionCancelled",
            0xA001..=0xAFFF => "vendor-specific",
            _ => "unknown",
        }
    }
}

pub mod event {
    pub const CANCEL_TRANSACTION: u16 = 0x4001;
    pub const OBJECT_ADDED: u16 = 0x4002;
    pub const OBJECT_REMOVED: u16 = 0x4003;
    pub const STORE_ADDED: u16 = 0x4004;
    pub const DEVICE_PROP_CHANGED: u16 = 0x4006;
    pub const DEVICE_INFO_CHANGED: u16 = 0x4008;
    pub const STORE_FULL: u16 = 0x400A;
    pub const CAPTURE_COMPLETE: u16 = 0x400D;
    pub const NIKON_OBJECT_ADDED_IN_SDRAM: u16 = 0xC101;
    pub const NIKON_CAPTURE_COMPLETE_REC_IN_SDRAM: u16 = 0xC102;
    // Canon EOS event records (GetEvent's list, not the event channel): 32-bit codes.
    pub const CANON_EOS_OBJECT_ADDED_EX: u32 = 0xC181;
    pub const CANON_EOS_REQUEST_OBJECT_TRANSFER: u32 = 0xC186;
    pub const CANON_EOS_PROP_VALUE_CHANGED: u32 = 0xC189;
    pub const CANON_EOS_AVAIL_LIST_CHANGED: u32 = 0xC18A;
    pub const CANON_EOS_CAMERA_STATUS_CHANGED: u32 = 0xC18B;
    pub const SONY_OBJECT_ADDED: u16 = 0xC201;
    pub const SONY_DEVICE_PROP_CHANGED: u16 = 0xC203;
}

pub mod prop {
    pub const BATTERY_LEVEL: u16 = 0x5001;
    pub const IMAGE_SIZE: u16 = 0x5003;
    pub const COMPRESSION_SETTING: u16 = 0x5004;
    pub const WHITE_BALANCE: u16 = 0x5005;
    pub const F_NUMBER: u16 = 0x5007;
    pub const FOCAL_LENGTH: u16 = 0x5008;
    pub const EXPOSURE_TIME: u16 = 0x500D;
    pub const EXPOSURE_PROGRAM_MODE: u16 = 0x500E;
    pub const EXPOSURE_INDEX: u16 = 0x500F;
    pub const EXPOSURE_BIAS: u16 = 0x5010;
    pub const DATE_TIME: u16 = 0x5011;
    pub const STILL_CAPTURE_MODE: u16 = 0x5013;
    pub const BURST_NUMBER: u16 = 0x5018;
    pub const NIKON_RECORDING_MEDIA: u16 = 0xD10B;
    pub const RICOH_SLEEP: u16 = 0xD80E;
    // Canon EOS properties: read from GetEvent's records, set with SetDevicePropValueEx.
    pub const CANON_EOS_APERTURE: u16 = 0xD101;
    pub const CANON_EOS_SHUTTER_SPEED: u16 = 0xD102;
    pub const CANON_EOS_ISO_SPEED: u16 = 0xD103;
    pub const CANON_EOS_AVAILABLE_SHOTS: u16 = 0xD11B;
    pub const CANON_EOS_CAPTURE_DESTINATION: u16 = 0xD11C;
    pub const CANON_EOS_EVF_OUTPUT_DEVICE: u16 = 0xD1B0;
    pub const FOCUS_MODE: u16 = 0x500A;
    // Sony's, read all at once with GetAllExtDevicePropInfo.
    pub const SONY_SHUTTER_SPEED: u16 = 0xD20D;
    pub const SONY_FOCUS_FOUND: u16 = 0xD213;
    pub const SONY_OBJECT_IN_MEMORY: u16 = 0xD215;
    pub const SONY_ISO: u16 = 0xD21E;
    pub const SONY_CAPTURE_TARGET: u16 = 0xD222;
    pub const SONY_PRIORITY_MODE: u16 = 0xD25A;
    /// Buttons, pressed (2) and let go (1) with ControlDevice.
    pub const SONY_SHUTTER_HALF_RELEASE: u16 = 0xD2C1;
    pub const SONY_SHUTTER_RELEASE: u16 = 0xD2C2;
}

/// Object format codes.
pub mod format {
    pub const UNDEFINED: u16 = 0x3000;
    pub const ASSOCIATION: u16 = 0x3001;
    pub const EXIF_JPEG: u16 = 0x3801;
    pub const TIFF: u16 = 0x380D;
    /// Adobe's Digital Negative (PTP 1.1).
    pub const DNG: u16 = 0x3811;
    /// Nikon NEF files are reported as "undefined" by most bodies.
    pub const RAW: u16 = 0xB101;
    /// Canon's CR2 and CR3 RAW files.
    pub const CANON_CR2: u16 = 0xB103;
    pub const CANON_CR3: u16 = 0xB108;
    pub const MPEG: u16 = 0x300B;
}

/// Vendor extension ids from DeviceInfo.
pub mod vendor {
    pub const EASTMAN_KODAK: u32 = 0x1;
    pub const MICROSOFT: u32 = 0x6;
    pub const NIKON: u32 = 0xA;
    pub const CANON: u32 = 0xB;
    pub const SONY: u32 = 0x11;
}

/// Datatype codes of properties (ISO 15740 table 3).
pub mod datatype {
    pub const INT8: u16 = 0x0001;
    pub const UINT8: u16 = 0x0002;
    pub const INT16: u16 = 0x0003;
    pub const UINT16: u16 = 0x0004;
    pub const INT32: u16 = 0x0005;
    pub const UINT32: u16 = 0x0006;
    pub const INT64: u16 = 0x0007;
    pub const UINT64: u16 = 0x0008;
    pub const ARRAY_FLAG: u16 = 0x4000;
    pub const STRING: u16 = 0xFFFF;
}
