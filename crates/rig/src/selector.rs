//! Device selectors: the strings that name a device on the command line and in rig files,
//! and that `brdfd devices` prints.
//!
//! | selector | device |
//! |---|---|
//! | `usb`, `usb:VVVV`, `usb:VVVV:PPPP` | a PTP camera on USB (any, a vendor's, a model), ids in hex |
//! | `ptpip:HOST[:PORT]` | a PTP/IP camera (Wi-Fi DSLR), port 15740 by default |
//! | `osc:http://HOST[:PORT]` (or a bare `http://...`) | a THETA on the THETA Web API |
//! | `v4l:/dev/videoN` | a V4L2 camera |
//! | `serial:/dev/ttyUSB0` | a brdfd rig-protocol device (trigger box, turntable) |
//! | `grbl:/dev/ttyUSB0`, `grbl:x:/dev/ttyUSB0` | a turntable on a GRBL G-code controller's A axis (or the axis named) |
//! | `cable:dtr:/dev/ttyUSB0`, `cable:rts:...` | a remote-release cable on a modem line |

use std::fmt;
use std::str::FromStr;

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Selector {
    Usb {
        vendor: Option<u16>,
        product: Option<u16>,
    },
    PtpIp(String),
    Osc(String),
    V4l(String),
    Serial(String),
    /// A turntable on a GRBL controller: the axis it is on (upper case), and the port.
    Grbl {
        axis: char,
        path: String,
    },
    Cable {
        rts: bool,
        path: String,
    },
    /// A camera driven through the system's libgphoto2 (brdfd's `gphoto2` feature): its port
    /// as libgphoto2 writes it (`usb:001,004`, `ptpip:HOST`), or the first it detects.
    Gphoto(Option<String>),
}

#[derive(Debug, thiserror::Error)]
#[error("device selector {given:?}: {reason}; use usb[:VVVV[:PPPP]], ptpip:HOST[:PORT], osc:http://HOST, v4l:/dev/videoN, serial:/dev/ttyX, grbl:[AXIS:]/dev/ttyX, cable:dtr|rts:/dev/ttyX or gphoto2[:PORT]")]
pub struct SelectorError {
    pub given: String,
    pub reason: String,
}

impl FromStr for Selector {
    type Err = SelectorError;

    fn from_str(s: &str) -> Result<Selector, SelectorError> {
        let err = |reason: &str| SelectorError {
            given: s.into(),
            reason: reason.into(),
        };
        let hex = |h: &str| {
            u16::from_str_radix(h, 16).map_err(|_| err(&format!("{h:?} is not a hex USB id")))
        };
        let nonempty = |rest: &str, what: &str| {
            if rest.is_empty() {
                Err(err(&format!("no {what}")))
            } else {
                Ok(rest.to_string())
            }
        };
        if s == "gphoto2" {
            return Ok(Selector::Gphoto(None));
        }
        if let Some(port) = s.strip_prefix("gphoto2:") {
            return Ok(Selector::Gphoto(Some(nonempty(port, "libgphoto2 port")?)));
        }
        if s == "usb" {
            return Ok(Selector::Usb {
                vendor: None,
                product: None,
            });
        }
        if let Some(ids) = s.strip_prefix("usb:") {
            return Ok(match ids.split_once(':') {
                Some((v, p)) => Selector::Usb {
                    vendor: Some(hex(v)?),
                    product: Some(hex(p)?),
                },
                None => Selector::Usb {
                    vendor: Some(hex(ids)?),
                    product: None,
                },
            });
        }
        if let Some(host) = s.strip_prefix("ptpip:") {
            return Ok(Selector::PtpIp(nonempty(host, "host")?));
        }
        if s.starts_with("http://") {
            return Ok(Selector::Osc(s.into()));
        }
        if let Some(url) = s.strip_prefix("osc:") {
            if !url.starts_with("http://") {
                return Err(err("an osc: selector needs an http:// address"));
            }
            return Ok(Selector::Osc(url.into()));
        }
        if let Some(path) = s.strip_prefix("v4l:") {
            return Ok(Selector::V4l(nonempty(path, "device path")?));
        }
        if let Some(path) = s.strip_prefix("serial:") {
            return Ok(Selector::Serial(nonempty(path, "port path")?));
        }
        if let Some(rest) = s.strip_prefix("grbl:") {
            // An axis is one letter before a colon; a port path starts with `/` (or is a
            // name such as COM3).
            let (axis, path) = match rest.split_once(':') {
                Some((a, path)) if a.len() == 1 => {
                    let axis = a.chars().next().unwrap_or('A').to_ascii_uppercase();
                    if !"XYZABC".contains(axis) {
                        return Err(err(&format!(
                            "{a:?} is not a GRBL axis (X, Y, Z, A, B or C)"
                        )));
                    }
                    (axis, path)
                }
                _ => ('A', rest),
            };
            return Ok(Selector::Grbl {
                axis,
                path: nonempty(path, "port path")?,
            });
        }
        if let Some(rest) = s.strip_prefix("cable:") {
            let (line, path) = rest
                .split_once(':')
                .ok_or_else(|| err("a cable needs its line and port: cable:dtr:/dev/ttyUSB0"))?;
            let rts = match line {
                "dtr" => false,
                "rts" => true,
                _ => return Err(err(&format!("{line:?} is not a modem line (dtr or rts)"))),
            };
            return Ok(Selector::Cable {
                rts,
                path: nonempty(path, "port path")?,
            });
        }
        Err(err("unknown kind"))
    }
}

impl fmt::Display for Selector {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Selector::Usb {
                vendor: None,
                product: _,
            } => write!(f, "usb"),
            Selector::Usb {
                vendor: Some(v),
                product: None,
            } => write!(f, "usb:{v:04x}"),
            Selector::Usb {
                vendor: Some(v),
                product: Some(p),
            } => write!(f, "usb:{v:04x}:{p:04x}"),
            Selector::PtpIp(h) => write!(f, "ptpip:{h}"),
            Selector::Osc(u) => write!(f, "osc:{u}"),
            Selector::V4l(p) => write!(f, "v4l:{p}"),
            Selector::Serial(p) => write!(f, "serial:{p}"),
            Selector::Grbl { axis: 'A', path } => write!(f, "grbl:{path}"),
            Selector::Grbl { axis, path } => write!(f, "grbl:{}:{path}", axis.to_ascii_lowercase()),
            Selector::Cable { rts, path } => {
                write!(f, "cable:{}:{path}", if *rts { "rts" } else { "dtr" })
            }
            Selector::Gphoto(None) => write!(f, "gphoto2"),
            Selector::Gphoto(Some(port)) => write!(f, "gphoto2:{port}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selectors_parse_and_print_back() {
        for s in [
            "usb",
            "usb:04b0",
            "usb:04b0:0429",
            "ptpip:192.0.2.7:15740",
            "osc:http://192.168.1.1",
            "v4l:/dev/video0",
            "serial:/dev/ttyUSB0",
            "cable:rts:/dev/ttyACM0",
            "grbl:/dev/ttyUSB1",
            "grbl:x:/dev/ttyUSB1",
            "grbl:COM3",
            "gphoto2",
            "gphoto2:usb:001,004",
            "gphoto2:ptpip:192.0.2.7",
        ] {
            let parsed: Selector = s.parse().unwrap();
            assert_eq!(parsed.to_string(), s);
        }
        // The A axis is the default, named or not; an axis letter may be upper case.
        for s in [
            "grbl:/dev/ttyACM0",
            "grbl:a:/dev/ttyACM0",
            "grbl:A:/dev/ttyACM0",
        ] {
            assert_eq!(
                s.parse::<Selector>().unwrap(),
                Selector::Grbl {
                    axis: 'A',
                    path: "/dev/ttyACM0".into()
                }
            );
        }
        assert_eq!(
            "http://127.0.0.1:8080".parse::<Selector>().unwrap(),
            Selector::Osc("http://127.0.0.1:8080".into())
        );
    }

    #[test]
    fn bad_selectors_say_what_is_wrong() {
        for (s, why) in [
            ("usb:nikon", "\"nikon\" is not a hex USB id"),
            ("osc:192.168.1.1", "needs an http:// address"),
            ("cable:dsr:/dev/ttyUSB0", "\"dsr\" is not a modem line"),
            ("v4l:", "no device path"),
            ("firewire:0", "unknown kind"),
            ("grbl:q:/dev/ttyUSB0", "\"q\" is not a GRBL axis"),
            ("grbl:", "no port path"),
            ("gphoto2:", "no libgphoto2 port"),
        ] {
            let e = s.parse::<Selector>().unwrap_err().to_string();
            assert!(e.contains(why), "{s}: {e}");
        }
    }
}
