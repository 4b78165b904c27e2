//! brdfd's simulated rig: the rig's devices as simulators that speak the real protocols on
//! loopback, and the virtual bench in front of them. It fills the rig's simulation seam
//! ([`brdfd_rig::simulation`]), above the rig, so that the rig's production code neither
//! imports the bench's renderer nor branches on what it would render.
//!
//! - `simulators.rs`: a Nikon D5100 (or a Canon or a Sony) over PTP/IP, a RICOH THETA V over
//!   HTTP or USB, a turntable and a shutter on a pseudo-terminal, a V4L2 webcam; the rig
//!   opens each through the code that opens hardware.
//! - `stage.rs`: the capture's stage, the virtual bench: the plan's material on the rig's
//!   object, each view shown to the cameras, the estimate judged against the material.
//! - `lib.rs` (here): what the calibrations photograph, and where the bench truly stands
//!   (`[simulation] camera` and `shape`, which the rig's own geometry may not know).
//!
//! A program that offers the simulated rig calls [`provide`] once, at start.

mod simulators;
mod stage;

use std::f64::consts::PI;
use std::sync::Arc;

use brdfd_bench::board_photo::{self, Spoil};
use brdfd_bench::{object_photo, VirtualBench};
use brdfd_core::geometry::{Camera, SceneGeometry, Shape};
use brdfd_core::merl::MerlBrdf;
use brdfd_rig::config::{MaterialPreset, Rig};
use brdfd_rig::devices::Planned;
use brdfd_rig::error::{Result, RigError};
use brdfd_rig::flow::Context;
use brdfd_rig::pose::OnBench;
use brdfd_rig::simulation::{SimulatedRig, Simulator, Stage};
use brdfd_rig::Plan;

use simulators::Simulators;

pub use simulators::SIM_THETA_SHOT_TIME;

/// Gives the rig the simulated rig, for the whole program ([`brdfd_rig::simulation`]).
pub fn provide() {
    brdfd_rig::simulation::provide(Box::new(VirtualRig));
}

/// The simulator the rig is given.
struct VirtualRig;

impl Simulator for VirtualRig {
    fn start(&self, rig: &Rig) -> Result<Box<dyn SimulatedRig>> {
        Ok(Box::new(Running(Arc::new(Simulators::start(rig)?))))
    }

    /// The plan's material must be one the bench can render: a shipped preset, an alias or
    /// embedded test material, or one of the plan's NBRDF file; and its light map, when it
    /// names one, must read.
    fn check_scene(&self, plan: &Plan) -> Result<()> {
        check_material(plan)?;
        if let Some(path) = &plan.env {
            // Read whole: a truncated map fails only where its pixels run out.
            brdfd_radiometry::panorama::load_envmap(path).map_err(|e| {
                RigError::invalid(format!(
                    "the simulated bench's light map (--env; the plan's `env`) cannot be read: {e}"
                ))
            })?;
        }
        Ok(())
    }
}

/// Refuses a plan whose material the simulator cannot render ([`Simulator::check_scene`]).
fn check_material(plan: &Plan) -> Result<()> {
    let preset = MaterialPreset::embedded(&plan.material).map_err(RigError::invalid)?;
    let name = preset
        .as_ref()
        .map_or(plan.material.as_str(), |p| p.simulate_as.as_str());
    let merl = brdfd_bench::resolve_material(name);
    let embedded = brdfd_bench::embedded_materials();
    if embedded.get(merl).is_ok() {
        return Ok(());
    }
    if let Some(path) = &plan.nbrdf {
        let set = brdfd_core::nbrdf::NbrdfSet::read(path)?;
        set.get(merl)?;
        return Ok(());
    }
    let presets = brdfd_rig::config::preset_names();
    let mut known = embedded.names();
    for name in presets.iter().copied().chain(brdfd_bench::alias_names()) {
        known.push(name);
    }
    let suggestion = match nearest_name(&plan.material, known.into_iter()) {
        Some(n) => format!(" Did you mean {n:?}?"),
        None => covering_presets(&plan.material)
            .into_iter()
            .map(|(preset, notes)| format!(" The preset {preset:?} covers it: {notes}"))
            .collect(),
    };
    Err(RigError::invalid(format!(
        "the simulator has no material {:?}.{suggestion} Use a preset ({}), a short name ({}), \
         a test material ({}), or an NBRDF file holding it (the plan's `nbrdf`; `--nbrdf FILE` \
         on the command line)",
        plan.material,
        presets.join(", "),
        brdfd_bench::aliases().join(", "),
        embedded.names().join(", ")
    )))
}

/// The known name nearest `name`, if one is near enough to be a slip of the keyboard: at most
/// two letters' edits away, and fewer than half of its letters.
fn nearest_name<'a>(name: &str, known: impl Iterator<Item = &'a str>) -> Option<&'a str> {
    known
        .map(|k| (strsim::damerau_levenshtein(name, k), k))
        .filter(|(d, k)| *d <= 2 && 2 * d < k.len())
        .min_by_key(|(d, _)| *d)
        .map(|(_, k)| k)
}

/// The shipped presets whose notes name `word` (a surface such as "paper" that is no
/// material's name), with their notes: a user names what is on the bench, and the presets are
/// named for what they simulate.
fn covering_presets(word: &str) -> Vec<(&'static str, String)> {
    if word.len() < 4 || !word.chars().all(|c| c.is_ascii_alphabetic()) {
        return Vec::new();
    }
    brdfd_rig::config::preset_names()
        .into_iter()
        .filter_map(|name| {
            let preset = MaterialPreset::embedded(name).ok().flatten()?;
            preset
                .notes
                .split(|c: char| !c.is_ascii_alphabetic())
                .any(|w| w.eq_ignore_ascii_case(word))
                .then_some((name, preset.notes))
        })
        .collect()
}

/// The simulators of a started rig, shared with the stage of each capture on it.
struct Running(Arc<Simulators>);

impl SimulatedRig for Running {
    fn devices(&self) -> Vec<Planned> {
        self.0.devices()
    }

    fn device_seconds(&self) -> f64 {
        self.0.device_seconds()
    }

    fn stage(&self) -> Box<dyn Stage> {
        Box::new(stage::SimulatedStage::new(self.0.clone()))
    }

    fn show_target(&self, cx: &Context, scene: &SceneGeometry, albedo: [f64; 3]) -> Result<()> {
        let rig = cx.rig;
        let truth = truth_scene(rig, scene);
        let bench = VirtualBench {
            material_name: format!("a Lambertian target of albedo {albedo:?}"),
            material: Arc::new(MerlBrdf::from_cells(|_, _, _| albedo.map(|a| a / PI))),
            env: brdfd_bench::studio_envmap(512),
            yaw: rig.theta_yaw_deg.to_radians(),
            geometry: truth,
            cache: brdfd_bench::cache::RenderCache::user(),
            stop: Default::default(),
        };
        self.0.show_light(&bench);
        self.0.show_object(&bench)
    }

    fn show_for_pose(&self, cx: &Context, on_bench: OnBench, turn_deg: f64) -> Result<()> {
        let rig = cx.rig;
        // The bench turned by θ is, in its own frame, the camera and the light turned by −θ.
        let theta = turn_deg.to_radians();
        let camera = truth_camera(rig, &rig.geometry.camera).turned_about_y(-theta);
        let env = brdfd_bench::studio_envmap(512);
        let yaw = rig.theta_yaw_deg.to_radians() - theta;
        let photo = |mesh| object_photo::render(mesh, &camera, &env, yaw, Spoil::default());
        let radiance = match on_bench {
            OnBench::Board(board) => {
                board_photo::render(board, &camera, &env, yaw, Spoil::default())
                    .map_err(simulator_error)?
            }
            OnBench::Nothing => photo(None).map_err(simulator_error)?.0,
            OnBench::Object => {
                let shape = truth_shape(rig, rig.geometry.shape.as_ref());
                let Some(mesh) = shape.as_ref().map(Shape::mesh).transpose()?.flatten() else {
                    return Err(RigError::invalid(
                        "the rig's [geometry.shape] is no mesh: a silhouette is aligned for a mesh",
                    ));
                };
                photo(Some(&mesh)).map_err(simulator_error)?.0
            }
        };
        self.0.show_radiance(radiance, &camera);
        cx.say(match on_bench {
            OnBench::Board(_) => "simulated rig: the board stands where the object goes, under the studio light",
            OnBench::Nothing => "simulated rig: the bench is empty, under the studio light",
            OnBench::Object => "simulated rig: the object stands on the bench (where [simulation] shape says, else where [geometry.shape] does), under the studio light",
        });
        Ok(())
    }
}

/// The bench's renderer's error, as the rig carries it.
fn simulator_error(e: impl std::error::Error + Send + Sync + 'static) -> RigError {
    RigError::Simulator(Box::new(e))
}

/// `scene` (as the rig believes it) where the simulated bench truly has it: its camera and
/// its object placed as [`truth_camera`] and [`truth_shape`] say.
fn truth_scene(rig: &Rig, scene: &SceneGeometry) -> SceneGeometry {
    SceneGeometry {
        camera: truth_camera(rig, &scene.camera),
        shape: truth_shape(rig, scene.shape.as_ref()),
        ..scene.clone()
    }
}

/// The camera the simulated bench photographs through, for a scene whose camera is `believed`
/// (the rig's, at the capture's size): `[simulation] camera` at that size, or `believed`
/// itself.
fn truth_camera(rig: &Rig, believed: &Camera) -> Camera {
    match rig.simulation.as_ref().and_then(|s| s.camera.as_ref()) {
        Some(truth) => {
            let (w, h) = believed.size();
            truth.resized(w, h)
        }
        None => believed.clone(),
    }
}

/// The object as the simulated bench places it, for a scene whose shape is `believed`:
/// `[simulation] shape` where `believed` is the rig's own `[geometry.shape]`, else `believed`
/// itself (a preset's object is where the preset says).
fn truth_shape(rig: &Rig, believed: Option<&Shape>) -> Option<Shape> {
    match rig.simulation.as_ref().and_then(|s| s.shape.as_ref()) {
        Some(truth) if believed == rig.geometry.shape.as_ref() => Some(truth.clone()),
        _ => believed.cloned(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use brdfd_rig::error::said;
    use brdfd_rig::settings::CaptureSettings;

    fn plan(material: &str) -> Plan {
        serde_json::from_value(serde_json::json!({ "material": material })).unwrap()
    }

    /// A material the bench cannot render is refused when the capture's settings are
    /// resolved, through the rig's seam, before a session exists; presets, short names and
    /// test materials are taken.
    #[test]
    fn a_material_the_bench_has_not_is_refused_before_a_session_exists() {
        provide();
        let rig = Rig::simulated();
        let e = CaptureSettings::resolve(&plan("unobtainium"), &rig).unwrap_err();
        let words = said(&e);
        assert!(
            words.contains("the simulator has no material \"unobtainium\""),
            "{words}"
        );
        assert!(
            words.contains("gold") && words.contains("chrome-steel"),
            "{words}"
        );
        for name in ["gold", "chrome", "chrome-steel"] {
            assert!(
                CaptureSettings::resolve(&plan(name), &rig).is_ok(),
                "{name}"
            );
        }
        // A slip of the keyboard is answered with the name it is nearest; a name far from
        // every one is not.
        let e = CaptureSettings::resolve(&plan("platsic"), &rig).unwrap_err();
        assert!(
            said(&e).contains("Did you mean \"plastic\"?"),
            "{}",
            said(&e)
        );
        let e = CaptureSettings::resolve(&plan("unobtainium"), &rig).unwrap_err();
        assert!(!said(&e).contains("Did you mean"), "{}", said(&e));
    }

    /// A light map the bench cannot read is refused before a session exists, named as the
    /// plan's `env`: a session that failed on it would fail the same way on every resume.
    #[test]
    fn a_light_map_the_bench_cannot_read_is_refused_before_a_session_exists() {
        provide();
        let dir = std::env::temp_dir().join(format!("brdfd-simrig-env-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let garbled = dir.join("garbled.hdr");
        std::fs::write(&garbled, "not a Radiance picture").unwrap();
        for path in [dir.join("missing.exr"), garbled] {
            let mut p = plan("gold");
            p.env = Some(path.clone());
            let e = CaptureSettings::resolve(&p, &Rig::simulated()).unwrap_err();
            let words = said(&e);
            assert!(
                words.contains("the simulated bench's light map (--env; the plan's `env`)")
                    && words.contains(&path.display().to_string()),
                "{words}"
            );
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn only_a_near_name_is_suggested() {
        let known = ["gold", "gold-part", "chrome", "plastic"];
        assert_eq!(nearest_name("glod", known.into_iter()), Some("gold"));
        assert_eq!(
            nearest_name("gold-prat", known.into_iter()),
            Some("gold-part")
        );
        assert_eq!(nearest_name("chrom", known.into_iter()), Some("chrome"));
        assert_eq!(nearest_name("paper", known.into_iter()), None);
        assert_eq!(nearest_name("ab", known.into_iter()), None);
    }

    #[test]
    fn a_surface_no_name_matches_is_pointed_to_the_preset_that_covers_it() {
        let paper = covering_presets("Paper");
        assert_eq!(
            paper.iter().map(|(n, _)| *n).collect::<Vec<_>>(),
            ["paint"],
            "{paper:?}"
        );
        assert!(paper[0].1.contains("paper"), "{paper:?}");
        let metal = covering_presets("metal");
        assert!(metal.iter().any(|(n, _)| *n == "gold"), "{metal:?}");
        // Short words and other characters are never read as surfaces.
        assert!(covering_presets("and").is_empty());
        assert!(covering_presets("paper/x").is_empty());
        assert!(covering_presets("velvet").is_empty());
    }
}
