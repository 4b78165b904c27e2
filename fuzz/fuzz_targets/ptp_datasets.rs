//! The datasets a camera describes itself and its files with (DeviceInfo, StorageInfo,
//! ObjectInfo, DevicePropDesc, property values), Nikon's event list, a Canon EOS body's
//! GetEvent records and a Sony body's property list. The first byte picks
//! the parser; for a property value the next two give its datatype.
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;
use brdfd_ptp::canon::decode_eos_events;
use brdfd_ptp::sony::decode_sony_props;
use brdfd_ptp::dataset::{
    decode_nikon_events, DeviceInfo, DevicePropDesc, ObjectInfo, StorageInfo, Value,
};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&which, rest)) = data.split_first() else {
        return;
    };
    match which % 8 {
        0 => drop(DeviceInfo::decode(rest)),
        1 => drop(StorageInfo::decode(rest)),
        2 => drop(ObjectInfo::decode(rest)),
        3 => drop(DevicePropDesc::decode(rest)),
        4 => drop(decode_nikon_events(rest)),
        5 => drop(decode_eos_events(rest)),
        6 => drop(decode_sony_props(rest)),
        _ => {
            if rest.len() >= 2 {
                let datatype = u16::from_le_bytes([rest[0], rest[1]]);
                drop(Value::from_bytes(&rest[2..], datatype));
            }
        }
    }
});
