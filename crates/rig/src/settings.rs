//! A capture's settings, resolved once: the plan over the material preset over the rig over
//! the defaults, each value checked, before a session exists (the shape of ripgrep's
//! `HiArgs::from_low_args`). A plan the capture could not finish (a rig it cannot run, a
//! preset tuned for another basis, a material the simulator cannot render) is refused here,
//! and leaves nothing behind; the flow then works from the one resolved value.
//!
//! It does not touch a device or the disk.

use std::path::Path;

use brdfd_theta::BracketPlan;

use super::plan::{self, Roles};
use super::roles::CameraSettings;
use super::Plan;
use crate::config::{MaterialPreset, PixelCount, Rig};
use crate::error::{refuse, Result, RigError};
use crate::session::Session;
use brdfd_core::basis::DEFAULT_K;
use brdfd_core::estimate::{BasisOptions, EstimateOptions, Model, ModelOptions};
use brdfd_core::geometry::{SceneGeometry, Shape};

/// The rig's text as a session keeps it: its mesh and normal map named by the paths this
/// capture found them at (beside the rig file), so that a resume finds them from any folder.
/// The rest of the text, comments too, is kept as it was.
fn with_files_found(rig_text: &str, scene: &SceneGeometry) -> String {
    let Ok(mut doc) = rig_text.parse::<toml_edit::DocumentMut>() else {
        return rig_text.to_string();
    };
    let Some(geometry) = doc.get_mut("geometry").and_then(|g| g.as_table_like_mut()) else {
        return rig_text.to_string();
    };
    let absolute = |p: &Path| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    if let (Some(item), Some(path)) = (geometry.get_mut("normal_map"), &scene.normal_map) {
        *item = toml_edit::value(absolute(path).display().to_string());
    }
    if let (Some(shape), Some(Shape::Mesh { file, .. })) = (
        geometry
            .get_mut("shape")
            .and_then(|s| s.as_table_like_mut()),
        &scene.shape,
    ) {
        if let (Some(item), false) = (shape.get_mut("file"), brdfd_core::mesh::is_builtin(file)) {
            *item = toml_edit::value(absolute(file).display().to_string());
        }
    }
    doc.to_string()
}

/// The rig's text with its `[geometry]` replaced by `scene` (the camera and the object a
/// preset put on the simulated bench); the rest kept as it was.
fn with_geometry(rig_text: &str, scene: &SceneGeometry) -> Result<String> {
    let mut doc: toml_edit::DocumentMut = rig_text.parse()?;
    let geometry: toml_edit::DocumentMut = toml::to_string(scene)?.parse()?;
    doc["geometry"] = toml_edit::Item::Table(geometry.as_table().clone());
    Ok(doc.to_string())
}

/// Pixels the basis model estimates from when neither the plan nor a preset says: the paper's
/// 20, which its experiment found as good as every pixel.
pub const DEFAULT_PIXELS: usize = 20;
/// Degrees between views when neither the plan nor the rig's `[turntable]` says.
pub const DEFAULT_TURN_DEG: f64 = 30.0;

/// An object camera's bracket: the exposure times, and what the camera holds through them.
#[derive(Debug, Clone, PartialEq)]
pub struct Bracket {
    pub exposures_s: Vec<f64>,
    pub camera: CameraSettings,
}

impl Bracket {
    /// The DSLR's bracket at `exposures_s`, with the rig's aperture, ISO and files.
    pub fn dslr(rig: &Rig, exposures_s: Vec<f64>) -> Bracket {
        let b = &rig.brackets;
        Bracket {
            exposures_s,
            camera: CameraSettings {
                f_number: Some(b.dslr_f_number),
                iso: Some(b.dslr_iso),
                files: Some(b.dslr_files),
                frames: 1,
                ..CameraSettings::default()
            },
        }
    }

    /// The fallback camera's bracket, as the rig has it.
    pub fn fallback(rig: &Rig) -> Bracket {
        let b = &rig.brackets;
        Bracket {
            exposures_s: b.fallback_shutters.clone(),
            camera: CameraSettings {
                gain: b.fallback_gain,
                white_balance_k: Some(b.fallback_white_balance_k),
                frames: b.fallback_frames,
                ..CameraSettings::default()
            },
        }
    }
}

/// How the object turns between views.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Turning {
    /// One view: nothing turns.
    None,
    Turntable,
    /// No turntable: the operator turns it, and says so ([`super::Operator`]).
    ByHand,
}

/// Everything a capture works from, resolved.
#[derive(Debug, Clone)]
pub struct CaptureSettings {
    /// The plan as it was asked: what the manifest stores, so that a resume resolves the
    /// same settings again.
    pub plan: Plan,
    pub preset: Option<MaterialPreset>,
    /// The rig's devices in their roles.
    pub roles: Roles,
    /// The DSLR's bracket: the plan's shutter speeds, else the preset's, else the rig's.
    pub dslr: Bracket,
    /// The V4L2 fallback camera's: the rig's.
    pub fallback: Bracket,
    /// The THETA's: the rig's shutter speeds, else the light probe.
    pub light: BracketPlan,
    pub views: usize,
    /// Degrees between views.
    pub turn_step: f64,
    pub turning: Turning,
    /// The object camera and the object; a simulated camera sized as the plan asks.
    pub scene: SceneGeometry,
    /// Whether the scene is the preset's `simulate_on` object, not the rig's own: the
    /// session's rig then records it, so that a resume estimates on it.
    pub object_from_preset: bool,
    /// The panorama's yaw in the world, radians.
    pub yaw: f64,
    /// The estimate's model and solve (its white level comes from the merges).
    pub estimate: EstimateOptions,
    /// Settings given that the estimate will not use, said before the capture starts.
    pub warnings: Vec<String>,
}

impl CaptureSettings {
    /// Resolves and checks the plan against the rig.
    pub fn resolve(plan: &Plan, rig: &Rig) -> Result<CaptureSettings> {
        plan.validate()?;
        let roles = plan::check(rig)?;
        let preset = MaterialPreset::embedded(&plan.material).map_err(RigError::invalid)?;
        if let Some(p) = &preset {
            if p.k != DEFAULT_K {
                refuse!(
                    "the {} preset is tuned for K = {}, the basis has K = {DEFAULT_K}",
                    plan.material,
                    p.k
                );
            }
        }
        if rig.simulated {
            crate::simulation::simulator()?.check_scene(plan)?;
        }
        let p = preset.as_ref();
        let b = &rig.brackets;
        let dslr_shutters = if !plan.bracket.is_empty() {
            plan.bracket.clone()
        } else if let Some(s) = p.and_then(|p| p.dslr_shutters.clone()) {
            s
        } else {
            b.dslr_shutters.clone()
        };
        let pixel_count = match (plan.pixels, p) {
            (Some(n), _) => n.limit(),
            (None, Some(p)) => p.pixels.limit(),
            (None, None) => Some(DEFAULT_PIXELS),
        };
        let model = plan.model.or(p.map(|p| p.model)).unwrap_or_default();
        let estimate = EstimateOptions {
            model: match model {
                Model::Basis => ModelOptions::Basis(BasisOptions {
                    pixel_count,
                    solver: plan.solve.or(p.map(|p| p.solve)).unwrap_or_default(),
                    colour: plan.colour.or(p.map(|p| p.colour)).unwrap_or_default(),
                    ..BasisOptions::default()
                }),
                other => ModelOptions::of(other),
            },
            materials: !plan.one_material,
            ..EstimateOptions::default()
        };
        let warnings = unused_basis_settings(
            model,
            &[
                ("pixels", plan.pixels.is_some()),
                ("solve", plan.solve.is_some()),
                ("colour", plan.colour.is_some()),
            ],
        )
        .into_iter()
        .collect();
        let table = rig.turntable.as_ref();
        let views = plan.views.or(table.map(|t| t.views)).unwrap_or(1);
        let turn_step = plan
            .turn
            .or(table.map(|t| t.step_deg))
            .unwrap_or(DEFAULT_TURN_DEG);
        let turning = match (views, roles.turntable) {
            (1, _) => Turning::None,
            (_, true) => Turning::Turntable,
            (_, false) => Turning::ByHand,
        };
        let object = p.and_then(|p| p.simulate_on).filter(|_| rig.shipped);
        let mut scene = object.map_or(rig.geometry.clone(), |o| o.scene());
        if rig.simulated {
            scene.camera = scene.camera.resized(plan.size, plan.size);
        }
        Ok(CaptureSettings {
            plan: plan.clone(),
            dslr: Bracket::dslr(rig, dslr_shutters),
            fallback: Bracket::fallback(rig),
            light: light_plan(rig),
            preset,
            roles,
            views,
            turn_step,
            turning,
            scene,
            object_from_preset: object.is_some(),
            yaw: rig.theta_yaw_deg.to_radians(),
            estimate,
            warnings,
        })
    }

    /// A new session for these settings under `state`, recording the rig and the preset as
    /// used, and the plan, which a resume resolves again.
    pub fn new_session(&self, state: &Path, rig_text: &str) -> Result<Session> {
        Ok(Session::create(
            state,
            &self.plan.material,
            &with_files_found(
                &if self.object_from_preset {
                    with_geometry(rig_text, &self.scene)?
                } else {
                    rig_text.to_string()
                },
                &self.scene,
            ),
            crate::config::preset_text(&self.plan.material),
            serde_json::to_value(&self.plan)?,
        )?)
    }

    /// The preset in a line for the operator, if the material is one.
    pub(crate) fn preset_line(&self, simulated: bool) -> Option<String> {
        let p = self.preset.as_ref()?;
        // The preset's pixel count only matters to the basis model.
        let model = match self.estimate.model.model() {
            Model::Analytic => "analytic model".to_string(),
            Model::Hybrid => "hybrid model".to_string(),
            Model::Basis => match p.pixels {
                PixelCount::All => "basis model, every pixel".to_string(),
                PixelCount::Count(n) => format!("basis model, {n} pixels"),
            },
        };
        Some(format!(
            "material preset {}: {}, {model}{}",
            self.plan.material,
            if simulated {
                format!("simulated as {}", p.simulate_as)
            } else {
                "on the bench".into()
            },
            if p.notes.is_empty() {
                String::new()
            } else {
                format!(" ({})", p.notes)
            }
        ))
    }
}

/// The rig's THETA bracket: its own shutter list, or the light probe.
pub(crate) fn light_plan(rig: &Rig) -> BracketPlan {
    if rig.brackets.theta_shutters.is_empty() {
        return BracketPlan::light_probe();
    }
    BracketPlan {
        shots: rig
            .brackets
            .theta_shutters
            .iter()
            .map(|&shutter_s| brdfd_theta::Exposure {
                shutter_s,
                iso: rig.brackets.theta_iso,
            })
            .collect(),
    }
}

/// The warning for basis-model settings given to an estimate that uses another model: the
/// names of the settings that were given (`(name, given)`), or `None` if none was or the model
/// is the basis. The estimate's options cannot carry them ([`ModelOptions`] holds the basis
/// model's settings in its variant), but a plan's fields and the CLI's flags can name them, and
/// the user is told they go unused rather than have them dropped in silence. The CLI's flags
/// and a capture's plan both say it this way.
pub fn unused_basis_settings(model: Model, settings: &[(&str, bool)]) -> Option<String> {
    let given: Vec<&str> = settings
        .iter()
        .filter_map(|(name, set)| set.then_some(*name))
        .collect();
    (model != Model::Basis && !given.is_empty()).then(|| {
        format!(
            "{} set{} the basis model, which this estimate does not use (--model basis uses {}); the {} model selects no pixels",
            given.join(", "),
            if given.len() == 1 { "s" } else { "" },
            if given.len() == 1 { "it" } else { "them" },
            model.name()
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::said;

    fn plan(material: &str) -> Plan {
        provide_a_simulator();
        serde_json::from_value(serde_json::json!({ "material": material })).unwrap()
    }

    /// These tests resolve plans on simulated rigs, which ask the program's simulator
    /// whether it shows the plan's scene (its material and light map); the simulated rig is a crate above this one
    /// (`brdfd-simrig`), whose own tests check its answer. This one shows any scene and
    /// starts no rig.
    fn provide_a_simulator() {
        use crate::simulation::{SimulatedRig, Simulator};
        struct AnyMaterial;
        impl Simulator for AnyMaterial {
            fn start(&self, _: &Rig) -> Result<Box<dyn SimulatedRig>> {
                Err(RigError::invalid(
                    "the settings' tests start no simulated rig",
                ))
            }
            fn check_scene(&self, _: &Plan) -> Result<()> {
                Ok(())
            }
        }
        crate::simulation::provide(Box::new(AnyMaterial));
    }

    /// A session's rig names its mesh by the path the capture found it at, so that a resume
    /// from another folder reads the same file; the rest of the text stays as it was.
    #[test]
    fn a_session_keeps_the_mesh_path_the_capture_found() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let file = root.join("config/rigs/simulated-grooved-block.toml");
        let text = std::fs::read_to_string(&file).unwrap();
        let rig = Rig::read(&file).unwrap();
        let settings = CaptureSettings::resolve(&plan("gold"), &rig).unwrap();
        let kept = with_files_found(&text, &settings.scene);
        let again = Rig::parse("kept", &kept).unwrap();
        let Some(Shape::Mesh { file: mesh, .. }) = &again.geometry.shape else {
            panic!("no mesh in {kept}");
        };
        assert!(mesh.is_absolute(), "{}", mesh.display());
        assert!(mesh.is_file(), "{}", mesh.display());
        assert!(kept.starts_with("# The simulated rig"), "comments kept");
        assert_eq!(again.geometry.camera, rig.geometry.camera);
    }

    /// A capture splits a part of two materials unless its plan asks for one.
    #[test]
    fn a_plan_for_one_material_turns_the_split_off() {
        let rig = Rig::simulated();
        let split = CaptureSettings::resolve(&plan("gold"), &rig).unwrap();
        assert!(split.estimate.materials);
        let mut one = plan("gold");
        one.one_material = true;
        let one = CaptureSettings::resolve(&one, &rig).unwrap();
        assert!(!one.estimate.materials);
    }

    #[test]
    fn the_plan_wins_over_the_preset_which_wins_over_the_rig() {
        let rig = Rig::simulated();
        let gold = CaptureSettings::resolve(&plan("gold"), &rig).unwrap();
        let preset = MaterialPreset::embedded("gold").unwrap().unwrap();
        // The preset's exposures where it has them, else the rig's.
        let preset_or_rig = preset
            .dslr_shutters
            .clone()
            .unwrap_or(rig.brackets.dslr_shutters.clone());
        assert_eq!(gold.dslr.exposures_s, preset_or_rig);
        let mut asked = plan("gold");
        asked.bracket = vec![0.01, 0.1];
        asked.views = Some(2);
        let s = CaptureSettings::resolve(&asked, &rig).unwrap();
        assert_eq!(s.dslr.exposures_s, [0.01, 0.1]);
        assert_eq!((s.views, s.turning), (2, Turning::Turntable));
        // Neither: the defaults, and the basis model's pixels when it is asked for.
        let none = CaptureSettings::resolve(&plan("nickel"), &rig).unwrap();
        assert_eq!(none.estimate.model, ModelOptions::of(Model::Hybrid));
        let mut basis = plan("nickel");
        basis.model = Some(Model::Basis);
        let basis = CaptureSettings::resolve(&basis, &rig).unwrap();
        let ModelOptions::Basis(b) = basis.estimate.model else {
            panic!("the basis model was asked for: {:?}", basis.estimate.model);
        };
        assert_eq!(b.pixel_count, Some(DEFAULT_PIXELS));
        assert_eq!((none.views, none.turn_step), (1, DEFAULT_TURN_DEG));
        assert_eq!(none.scene.camera.size(), (256, 256));
    }

    #[test]
    fn views_without_a_turntable_are_turned_by_hand() {
        let rig = Rig::parse(
            "rig.toml",
            &format!(
                "{}\n[simulation]\nturntable = \"absent\"\n",
                include_str!("../../../config/rigs/simulated.toml")
            ),
        )
        .unwrap();
        let mut p = plan("gold");
        p.views = Some(3);
        assert_eq!(
            CaptureSettings::resolve(&p, &rig).unwrap().turning,
            Turning::ByHand
        );
    }

    #[test]
    fn what_the_capture_could_not_finish_is_refused_before_a_session_exists() {
        // A rig whose webcam has no gain parses, and is refused here, naming the gain. (A
        // material the simulator has not: brdfd-simrig's tests.)
        let uncalibrated = Rig::parse(
            "rig.toml",
            &include_str!("../../../config/rigs/simulated.toml")
                .replace("[calibration.fallback]\ngain = 62.5\n", ""),
        )
        .unwrap();
        let e = CaptureSettings::resolve(&plan("gold"), &uncalibrated).unwrap_err();
        assert!(
            said(&e).contains("calibration.fallback.gain"),
            "{}",
            said(&e)
        );
    }

    #[test]
    fn the_embedded_basis_has_the_k_presets_are_checked_against() {
        assert_eq!(brdfd_core::basis::Basis::embedded().header.k, DEFAULT_K);
    }
}
