//! The THETA models the simulator can be, and what each takes and reports on the THETA Web
//! API where they differ. From RICOH's THETA API reference (each option's page gives its
//! models and values) and the recorded `/osc/info` answers of a THETA X (firmware 1.30.0) and
//! a Z1 (2.10.3) in `shared/data/theta/osc-fixtures/info/`.

use serde_json::{json, Value};

use super::THETA_V_SHUTTERS;

/// A THETA model on sale (the X and Z1) or the one brdfd was first built for (the V).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ThetaModel {
    #[default]
    V,
    Z1,
    X,
}

impl ThetaModel {
    pub const ALL: [ThetaModel; 3] = [ThetaModel::V, ThetaModel::Z1, ThetaModel::X];

    /// `v`, `z1` or `x`, as `brdfd sim theta --model` takes it.
    pub fn parse(name: &str) -> Option<ThetaModel> {
        match name.to_ascii_lowercase().as_str() {
            "v" => Some(ThetaModel::V),
            "z1" => Some(ThetaModel::Z1),
            "x" => Some(ThetaModel::X),
            _ => None,
        }
    }

    /// The model as `/osc/info` names it.
    pub fn name(self) -> &'static str {
        match self {
            ThetaModel::V => "RICOH THETA V",
            ThetaModel::Z1 => "RICOH THETA Z1",
            ThetaModel::X => "RICOH THETA X",
        }
    }

    /// The firmware the simulated body reports: the recorded answers' for the X and Z1.
    pub fn firmware(self) -> &'static str {
        match self {
            ThetaModel::V => "3.50.1",
            ThetaModel::Z1 => "2.10.3",
            ThetaModel::X => "1.30.0",
        }
    }

    /// Whether `/osc/info` says it has GPS (the X's answer does, the Z1's does not).
    pub fn gps(self) -> bool {
        self == ThetaModel::X
    }

    /// Manual exposure's shutter speeds, as rationals (seconds = num/den). The V and Z1 go
    /// from 1/25000 s; the X from 1/16000 s, with 1/12800 where the others have 1/12500, and
    /// with 40 and 50 s (on a V or Z1 only with later firmware than simulated here).
    pub fn shutters(self) -> Vec<(u32, u32)> {
        match self {
            ThetaModel::V | ThetaModel::Z1 => THETA_V_SHUTTERS.to_vec(),
            ThetaModel::X => THETA_V_SHUTTERS
                .iter()
                .copied()
                .filter(|s| !matches!(s, (1, 25000) | (1, 20000)))
                .map(|s| if s == (1, 12500) { (1, 12800) } else { s })
                .chain([(40, 1), (50, 1)])
                .fold(Vec::new(), |mut all, s| {
                    let at = all.partition_point(|(n, d): &(u32, u32)| {
                        (*n as u64) * (s.1 as u64) < (s.0 as u64) * (*d as u64)
                    });
                    all.insert(at, s);
                    all
                }),
        }
    }

    /// Manual exposure's ISO settings for still images.
    pub fn isos(self) -> &'static [u32] {
        match self {
            ThetaModel::V => &[
                64, 80, 100, 125, 160, 200, 250, 320, 400, 500, 640, 800, 1000, 1250, 1600, 2000,
                2500, 3200,
            ],
            ThetaModel::Z1 => &[
                80, 100, 125, 160, 200, 250, 320, 400, 500, 640, 800, 1000, 1250, 1600, 2000, 2500,
                3200, 4000, 5000, 6400,
            ],
            ThetaModel::X => &[
                50, 64, 80, 100, 125, 160, 200, 250, 320, 400, 500, 640, 800, 1000, 1250, 1600,
                2000, 2500, 3200,
            ],
        }
    }

    /// The apertures: fixed on the V and X, three on the Z1 in manual exposure.
    pub fn apertures(self) -> &'static [f64] {
        match self {
            ThetaModel::V => &[2.0],
            ThetaModel::Z1 => &[2.1, 3.5, 5.6],
            ThetaModel::X => &[2.4],
        }
    }

    /// The aperture a fresh body is at.
    pub fn aperture(self) -> f64 {
        self.apertures()[0]
    }

    /// Most shots one `_autoBracket` takes: 13 on the X; 19 on a V with firmware 3.00.1 or
    /// later. The reference gives no figure for the Z1; 13, the smallest, is assumed.
    pub fn max_bracket(self) -> u64 {
        match self {
            ThetaModel::V => 19,
            ThetaModel::Z1 | ThetaModel::X => 13,
        }
    }

    /// The still-image `fileFormat`s, the default first. The Z1 also writes RAW (DNG) beside
    /// the JPEG; the X has a smaller JPEG as well.
    pub fn image_formats(self) -> Vec<Value> {
        let jpeg = |w: u32, h: u32| json!({"type": "jpeg", "width": w, "height": h});
        match self {
            ThetaModel::V => vec![jpeg(5376, 2688)],
            ThetaModel::Z1 => vec![
                jpeg(6720, 3360),
                json!({"type": "raw+", "width": 6720, "height": 3360}),
            ],
            ThetaModel::X => vec![jpeg(11008, 5504), jpeg(5504, 2752)],
        }
    }

    /// The `_filter` values (the X has no DR compensation nor handheld HDR).
    pub fn filters(self) -> &'static [&'static str] {
        match self {
            ThetaModel::V | ThetaModel::Z1 => {
                &["off", "DR Comp", "Noise Reduction", "hdr", "Hh hdr"]
            }
            ThetaModel::X => &["off", "Noise Reduction", "hdr"],
        }
    }

    /// The `_function` values (shooting function), on the models that have the option: the
    /// Z1's self-timer and both models' "my setting" shoot otherwise than asked.
    pub fn functions(self) -> Option<&'static [&'static str]> {
        match self {
            ThetaModel::V => None,
            ThetaModel::Z1 => Some(&["normal", "selfTimer", "mySetting"]),
            ThetaModel::X => Some(&["normal", "mySetting"]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_back() {
        for m in ThetaModel::ALL {
            let short = m.name().rsplit(' ').next().unwrap();
            assert_eq!(ThetaModel::parse(short), Some(m));
        }
        assert_eq!(ThetaModel::parse("s"), None);
    }

    #[test]
    fn the_x_starts_at_1_16000_s_with_1_12800() {
        let x = ThetaModel::X.shutters();
        assert_eq!(x[0], (1, 16000));
        assert!(x.contains(&(1, 12800)) && !x.contains(&(1, 12500)));
        assert!(
            x.windows(2).all(|w| w[0].0 * w[1].1 < w[1].0 * w[0].1),
            "ascending"
        );
        assert!(x.contains(&(50, 1)) && x.last() == Some(&(60, 1)));
        assert_eq!(ThetaModel::Z1.shutters()[0], (1, 25000));
    }
}
