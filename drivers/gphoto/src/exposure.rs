//! Exposure in libgphoto2's terms: the configuration widgets that hold it and the strings
//! their choices are written in, which libgphoto2 keeps the same across vendors ("1/60",
//! "0.5", "30" seconds; "f/8" or "8"; "100", "Auto").

/// What to set; `None` leaves a setting as the camera has it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Exposure {
    pub shutter_s: Option<f64>,
    pub f_number: Option<f64>,
    pub iso: Option<u32>,
}

/// What the camera holds after setting, read back.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Applied {
    pub shutter_s: Option<f64>,
    pub f_number: Option<f64>,
    pub iso: Option<u32>,
}

/// The widgets a shutter speed is under: most bodies name it `shutterspeed`; some Nikons and
/// Canons `shutterspeed2`, a PTP camera without vendor support `exposuretime`.
pub const SHUTTER: &[&str] = &["shutterspeed", "shutterspeed2", "exposuretime"];
/// The aperture's widgets.
pub const APERTURE: &[&str] = &["f-number", "aperture"];
/// The ISO's widgets.
pub const ISO: &[&str] = &["iso", "isospeed"];

/// Seconds from a shutter choice: "1/60", "1/60s", "0.5", "2.5s", "30\"" ; `None` for "Bulb",
/// "Auto" and the like.
pub fn parse_shutter(s: &str) -> Option<f64> {
    let s = s.trim().trim_end_matches(['s', '"']).trim();
    let v = match s.split_once('/') {
        Some((n, d)) => n.trim().parse::<f64>().ok()? / d.trim().parse::<f64>().ok()?,
        None => s.parse::<f64>().ok()?,
    };
    (v.is_finite() && v > 0.0).then_some(v)
}

/// An f-number from an aperture choice: "f/8", "F8", "8", "5.6".
pub fn parse_f_number(s: &str) -> Option<f64> {
    let s = s.trim();
    let s = s
        .strip_prefix("f/")
        .or_else(|| s.strip_prefix("F/"))
        .or_else(|| s.strip_prefix('f'))
        .or_else(|| s.strip_prefix('F'))
        .unwrap_or(s);
    let v = s.trim().parse::<f64>().ok()?;
    (v.is_finite() && v > 0.0).then_some(v)
}

/// An ISO speed from a choice: "100", "ISO 100", "6400 (extended)"; `None` for "Auto".
pub fn parse_iso(s: &str) -> Option<f64> {
    let s = s.trim();
    let s = s.strip_prefix("ISO").unwrap_or(s).trim_start();
    let digits: String = s.chars().take_while(char::is_ascii_digit).collect();
    let v = digits.parse::<u32>().ok()?;
    (v > 0).then_some(f64::from(v))
}

/// The choice nearest `want` in stops (exposure settings go in ratios), with its value;
/// choices `parse` cannot read are passed over. `None` if none can be read.
pub fn nearest(
    choices: &[String],
    want: f64,
    parse: fn(&str) -> Option<f64>,
) -> Option<(String, f64)> {
    choices
        .iter()
        .filter_map(|c| parse(c).map(|v| (c.clone(), v)))
        .min_by(|a, b| {
            let d = |v: f64| (v / want).ln().abs();
            d(a.1).total_cmp(&d(b.1))
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn libgphoto2_s_strings_read_as_values() {
        assert_eq!(parse_shutter("1/60"), Some(1.0 / 60.0));
        assert_eq!(parse_shutter("1/8000s"), Some(1.0 / 8000.0));
        assert_eq!(parse_shutter("0.5"), Some(0.5));
        assert_eq!(parse_shutter("30\""), Some(30.0));
        assert_eq!(parse_shutter("bulb"), None);
        assert_eq!(parse_shutter("1/0"), None);
        assert_eq!(parse_f_number("f/5.6"), Some(5.6));
        assert_eq!(parse_f_number("F8"), Some(8.0));
        assert_eq!(parse_f_number("11"), Some(11.0));
        assert_eq!(parse_f_number("implicit auto"), None);
        assert_eq!(parse_iso("100"), Some(100.0));
        assert_eq!(parse_iso("ISO 3200"), Some(3200.0));
        assert_eq!(parse_iso("25600 (extended)"), Some(25600.0));
        assert_eq!(parse_iso("Auto"), None);
    }

    #[test]
    fn the_nearest_choice_is_nearest_in_stops() {
        let choices: Vec<String> = ["Auto", "1/30", "1/60", "1/125", "1"]
            .map(String::from)
            .into();
        // 1/42 s is nearer 1/30 in stops (0.49 against 0.51), though nearer 1/60 in seconds.
        assert_eq!(
            nearest(&choices, 1.0 / 42.0, parse_shutter).map(|c| c.0),
            Some("1/30".into())
        );
        assert_eq!(
            nearest(&choices, 0.6, parse_shutter).map(|c| c.0),
            Some("1".into())
        );
        let none: Vec<String> = vec!["Auto".into()];
        assert_eq!(nearest(&none, 0.01, parse_shutter), None);
    }
}
