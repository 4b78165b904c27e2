//! What a capture is asked to do, and the limits a plan is checked against before any
//! device moves. A plan is the body of the daemon's "start a capture" request and is stored
//! in the session's manifest, so that a resume repeats it.

use std::fmt;
use std::num::NonZeroUsize;
use std::path::PathBuf;
use std::str::FromStr;

use brdfd_core::estimate::Model;
use brdfd_core::solve::{ColourChoice, Solver};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// Turntable views at most: one per degree, more than any bench turns for one estimate, and a
/// bound on what a plan or rig file can make the capture allocate and shoot.
pub const MAX_VIEWS: usize = 360;
/// Most exposures in one bracket. A bench brackets 3 to 9; a longer list is a mistake, and
/// each exposure is a photo to shoot, download and keep.
pub const MAX_BRACKET: usize = 32;
/// Longest exposure accepted, seconds.
pub const MAX_EXPOSURE_S: f64 = 60.0;
/// The image sizes a simulated camera renders, pixels on a side.
pub const SIZES: std::ops::RangeInclusive<usize> = 8..=8192;

/// Whether `name` is a name brdfd gives files and folders after (a material, a preset, a
/// session id): 1 to 64 lower-case letters, digits and dashes, not starting with a dash.
pub fn is_valid_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= 64
        && !name.starts_with('-')
        && name
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-')
}

/// The sentence for a name [`is_valid_name`] refuses; `kind` says what it names.
pub fn invalid_name(kind: &str, name: &str) -> String {
    format!(
        "{kind} {name:?} is not a valid name: use 1 to 64 lower-case letters, digits and dashes, not starting with a dash"
    )
}

/// Pixels to estimate from: a count, or all the object's pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelCount {
    Count(NonZeroUsize),
    All,
}

impl PixelCount {
    /// The count, or `None` for all pixels (the estimate's own option).
    pub fn limit(self) -> Option<usize> {
        match self {
            PixelCount::Count(n) => Some(n.get()),
            PixelCount::All => None,
        }
    }
}

impl fmt::Display for PixelCount {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PixelCount::Count(n) => write!(f, "{n}"),
            PixelCount::All => f.write_str("all"),
        }
    }
}

/// A pixel count written as text: `all`, or a count from 1 written plainly (no sign, no
/// leading zero, at most nine digits). The plan's `pixels` and `--pixels` take this form.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("pixels takes `all` or a count from 1 (at most nine digits), not {0:?}")]
pub struct PixelCountError(pub String);

impl FromStr for PixelCount {
    type Err = PixelCountError;
    fn from_str(s: &str) -> Result<PixelCount, PixelCountError> {
        if s == "all" {
            return Ok(PixelCount::All);
        }
        let plain = !s.is_empty()
            && s.len() <= 9
            && !s.starts_with('0')
            && s.bytes().all(|b| b.is_ascii_digit());
        match s.parse().ok().and_then(NonZeroUsize::new) {
            Some(n) if plain => Ok(PixelCount::Count(n)),
            _ => Err(PixelCountError(s.to_string())),
        }
    }
}

/// A material preset's `pixels`, in TOML: a number from 1, or `"all"`.
impl<'de> Deserialize<'de> for PixelCount {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<PixelCount, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw {
            N(usize),
            S(String),
        }
        match Raw::deserialize(d)? {
            Raw::N(n) => NonZeroUsize::new(n)
                .map(PixelCount::Count)
                .ok_or_else(|| serde::de::Error::custom("pixels must be at least 1")),
            Raw::S(s) if s == "all" => Ok(PixelCount::All),
            Raw::S(s) => Err(serde::de::Error::custom(format!(
                "pixels is a number or \"all\", not {s:?}"
            ))),
        }
    }
}

/// A plan's `pixels` on the wire: the text [`PixelCount::from_str`] reads, and nothing else
/// (the API's description gives it as a string with that pattern).
mod pixel_text {
    use super::*;

    pub fn serialize<S: Serializer>(p: &Option<PixelCount>, s: S) -> Result<S::Ok, S::Error> {
        match p {
            Some(p) => s.collect_str(p),
            None => s.serialize_none(),
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<PixelCount>, D::Error> {
        Option::<String>::deserialize(d)?
            .map(|s| s.parse().map_err(serde::de::Error::custom))
            .transpose()
    }
}

/// What a capture was asked to do. Stored in the session's manifest, so that a resume
/// repeats it; also the body of the daemon's "start a capture" request.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct Plan {
    /// A preset in config/materials, a MERL name, or an alias (gold, chrome, paint, ...).
    // The pattern is `is_valid_name`'s rule, which `validate` applies.
    #[cfg_attr(feature = "schema", schema(pattern = "^[a-z0-9][a-z0-9-]{0,63}$"))]
    pub material: String,
    /// Image size of the simulated camera (ignored on a hardware rig).
    #[serde(default = "default_size", deserialize_with = "whole_number")]
    #[cfg_attr(feature = "schema", schema(minimum = 8, maximum = 8192, default = 256))]
    // SIZES
    pub size: usize,
    /// Pixels to estimate from: a number or "all"; the preset's, else 20.
    #[serde(default, with = "pixel_text")]
    #[cfg_attr(
        feature = "schema",
        schema(value_type = Option<String>, pattern = "^(all|[1-9][0-9]{0,8})$")
    )]
    pub pixels: Option<PixelCount>,
    /// The BRDF model: "hybrid", "analytic" or "basis"; the preset's, else hybrid.
    #[serde(default)]
    pub model: Option<Model>,
    /// How the coefficients are solved: "prior" or "least-squares"; the preset's, else prior.
    #[serde(default)]
    pub solve: Option<Solver>,
    /// How colour is modelled: "joint", "per-channel" or "auto"; the preset's, else auto.
    #[serde(default)]
    pub colour: Option<ColourChoice>,
    /// DSLR shutter speeds, seconds; the preset's, else the rig's.
    #[serde(default)]
    #[cfg_attr(feature = "schema", schema(schema_with = bracket_schema))]
    pub bracket: Vec<f64>,
    /// Turntable views (1: no turntable); the rig's `[turntable]` plan, else 1.
    #[serde(default, deserialize_with = "some_whole_number")]
    #[cfg_attr(feature = "schema", schema(minimum = 1, maximum = 360))] // MAX_VIEWS
    pub views: Option<usize>,
    /// Turntable step between views, degrees; the rig's, else 30.
    #[serde(default)]
    pub turn: Option<f64>,
    /// Simulated rig only: the environment map and NBRDF file of the scene, by file name in
    /// the daemon's `scenes` folder.
    // A path is refused (the daemon's `scene_names`): the pattern says so.
    #[serde(default)]
    #[cfg_attr(feature = "schema", schema(value_type = Option<String>, pattern = "^[^/]+$"))]
    pub env: Option<PathBuf>,
    #[serde(default)]
    #[cfg_attr(feature = "schema", schema(value_type = Option<String>, pattern = "^[^/]+$"))]
    pub nbrdf: Option<PathBuf>,
    /// Simulated rig only: the sample is the material's projection onto the basis (its best
    /// K-term approximation) rather than the material itself. Its coefficients are then known
    /// exactly, which checks the capture chain apart from the model's own error.
    #[serde(default)]
    pub in_span: bool,
    /// Fit one BRDF to the whole part, even where its colour departs from place to place:
    /// otherwise such a part is split into two materials, each estimated on its own pixels
    /// (`brdfd estimate --one-material` says the same for an estimate from files).
    // Left out of a manifest when false, so that a session that does not ask for it reads
    // as it did in a brdfd from before the field.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub one_material: bool,
}

fn default_size() -> usize {
    256
}

/// The plan's `bracket` in the API's description: [`MAX_BRACKET`] shutter speeds at most,
/// each above 0 and at most [`MAX_EXPOSURE_S`] seconds, as [`Plan::validate`] requires.
#[cfg(feature = "schema")]
fn bracket_schema() -> utoipa::openapi::Array {
    use utoipa::openapi::schema::{ArrayBuilder, ObjectBuilder, Type};
    let speed = ObjectBuilder::new()
        .schema_type(Type::Number)
        .exclusive_minimum(Some(0.0))
        .maximum(Some(MAX_EXPOSURE_S));
    ArrayBuilder::new()
        .items(speed)
        .max_items(Some(MAX_BRACKET))
        .description(Some(
            "DSLR shutter speeds, seconds; the preset's, else the rig's.",
        ))
        .build()
}

/// What is wrong with a plan, found before any device moves.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    #[error("{}", invalid_name("material", .0))]
    Material(String),
    #[error("views must be 1 to {MAX_VIEWS}, not {0}")]
    Views(usize),
    #[error("turn must be a number of degrees, not {0}")]
    Turn(f64),
    #[error("size {0} is outside 8..=8192")]
    Size(usize),
    #[error("bracket has {0} shutter speeds; at most {MAX_BRACKET}")]
    BracketLength(usize),
    #[error("bracket shutter speeds must be seconds above 0, at most {MAX_EXPOSURE_S}, not {0}")]
    Shutter(f64),
}

impl Plan {
    /// A plan for `material` with everything else left to the preset and the rig.
    pub fn new(material: impl Into<String>) -> Plan {
        Plan {
            material: material.into(),
            size: default_size(),
            pixels: None,
            model: None,
            solve: None,
            colour: None,
            bracket: Vec::new(),
            views: None,
            turn: None,
            env: None,
            nbrdf: None,
            in_span: false,
            one_material: false,
        }
    }

    /// Checks what can be checked before any device moves. (The pixel count's form is checked
    /// as it is read.)
    pub fn validate(&self) -> Result<(), PlanError> {
        if !is_valid_name(&self.material) {
            return Err(PlanError::Material(self.material.clone()));
        }
        if let Some(views) = self.views.filter(|v| !(1..=MAX_VIEWS).contains(v)) {
            return Err(PlanError::Views(views));
        }
        if let Some(turn) = self.turn.filter(|t| !t.is_finite()) {
            return Err(PlanError::Turn(turn));
        }
        if !SIZES.contains(&self.size) {
            return Err(PlanError::Size(self.size));
        }
        if self.bracket.len() > MAX_BRACKET {
            return Err(PlanError::BracketLength(self.bracket.len()));
        }
        if let Some(&s) = self
            .bracket
            .iter()
            .find(|s| !(s.is_finite() && **s > 0.0 && **s <= MAX_EXPOSURE_S))
        {
            return Err(PlanError::Shutter(s));
        }
        Ok(())
    }
}

/// A count given as a JSON number: `5` or `5.0` alike. JSON Schema's `integer` is any number
/// without a fraction (a client's JSON library may write 5 as `5.0`), where serde takes only
/// the former.
pub fn whole_number<'de, D: Deserializer<'de>>(d: D) -> Result<usize, D::Error> {
    let n = serde_json::Number::deserialize(d)?;
    if let Some(n) = n.as_u64() {
        return usize::try_from(n).map_err(serde::de::Error::custom);
    }
    match n.as_f64() {
        // Up to u32::MAX, which every count a plan holds is far below, and which an f64 holds
        // exactly.
        Some(f) if f >= 0.0 && f.fract() == 0.0 && f <= u32::MAX as f64 => Ok(f as usize),
        _ => Err(serde::de::Error::custom(format!(
            "expected a whole number, not {n}"
        ))),
    }
}

/// [`whole_number`] for an optional field (`null` or absent is `None`).
pub fn some_whole_number<'de, D: Deserializer<'de>>(d: D) -> Result<Option<usize>, D::Error> {
    #[derive(Deserialize)]
    struct Whole(#[serde(deserialize_with = "whole_number")] usize);
    Ok(Option::<Whole>::deserialize(d)?.map(|w| w.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pixel_count_is_all_or_a_plain_count_from_one() {
        let count = |n| PixelCount::Count(NonZeroUsize::new(n).unwrap());
        assert_eq!("all".parse(), Ok(PixelCount::All));
        assert_eq!("20".parse(), Ok(count(20)));
        assert_eq!("999999999".parse(), Ok(count(999_999_999)));
        for bad in ["", "0", "020", "+5", "-1", "1e3", "1000000000", "ALL", " 5"] {
            assert!(bad.parse::<PixelCount>().is_err(), "{bad:?} was taken");
        }
    }

    #[test]
    fn a_plans_pixels_travel_as_text_and_are_read_back_typed() {
        let fifty = PixelCount::Count(NonZeroUsize::new(50).unwrap());
        let mut plan = Plan::new("gold");
        plan.pixels = Some(fifty);
        let json = serde_json::to_value(&plan).unwrap();
        assert_eq!(json["pixels"], "50");
        let back: Plan = serde_json::from_value(json).unwrap();
        assert_eq!(back.pixels, Some(fifty));
        let all: Plan = serde_json::from_str(r#"{"material":"gold","pixels":"all"}"#).unwrap();
        assert_eq!(all.pixels, Some(PixelCount::All));
        // The wire form is the text alone: a number, zero or a leading zero is refused.
        for bad in [r#"50"#, r#""0""#, r#""050""#] {
            let body = format!(r#"{{"material":"gold","pixels":{bad}}}"#);
            assert!(
                serde_json::from_str::<Plan>(&body).is_err(),
                "{bad} was taken"
            );
        }
    }

    /// A plan that asks for one material says so on the wire; one that does not is written
    /// without the field, as before it existed, and a manifest without it reads as not asking.
    #[test]
    fn one_material_is_written_only_when_asked_for() {
        let mut plan = Plan::new("gold");
        let json = serde_json::to_value(&plan).unwrap();
        assert!(json.get("one_material").is_none(), "{json}");
        assert!(!serde_json::from_value::<Plan>(json).unwrap().one_material);
        plan.one_material = true;
        let json = serde_json::to_value(&plan).unwrap();
        assert_eq!(json["one_material"], true);
        assert!(serde_json::from_value::<Plan>(json).unwrap().one_material);
        let bad = r#"{"material":"gold","one_material":"yes"}"#;
        assert!(serde_json::from_str::<Plan>(bad).is_err());
    }

    #[test]
    fn a_presets_pixels_are_a_number_from_one_or_all() {
        #[derive(Deserialize)]
        struct Preset {
            pixels: PixelCount,
        }
        let read = |text: &str| serde_json::from_str::<Preset>(text).map(|p| p.pixels);
        assert_eq!(
            read(r#"{"pixels": 20}"#).unwrap(),
            PixelCount::Count(NonZeroUsize::new(20).unwrap())
        );
        assert_eq!(read(r#"{"pixels": "all"}"#).unwrap(), PixelCount::All);
        let zero = read(r#"{"pixels": 0}"#).unwrap_err().to_string();
        assert!(zero.contains("at least 1"), "{zero}");
        assert!(read(r#"{"pixels": "some"}"#).is_err());
    }

    #[test]
    fn a_plan_is_refused_by_what_is_wrong_with_it() {
        let with = |f: fn(&mut Plan)| {
            let mut p = Plan::new("gold");
            f(&mut p);
            p.validate()
        };
        assert_eq!(with(|_| {}), Ok(()));
        assert_eq!(
            with(|p| p.material = "Gold".into()),
            Err(PlanError::Material("Gold".into()))
        );
        assert_eq!(with(|p| p.views = Some(0)), Err(PlanError::Views(0)));
        assert_eq!(with(|p| p.views = Some(361)), Err(PlanError::Views(361)));
        assert!(matches!(
            with(|p| p.turn = Some(f64::NAN)),
            Err(PlanError::Turn(_))
        ));
        assert_eq!(with(|p| p.size = 7), Err(PlanError::Size(7)));
        assert_eq!(
            with(|p| p.bracket = vec![0.01; 33]),
            Err(PlanError::BracketLength(33))
        );
        assert_eq!(
            with(|p| p.bracket = vec![0.01, 61.0]),
            Err(PlanError::Shutter(61.0))
        );
    }
}
