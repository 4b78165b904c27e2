//! The ecosystem's own validators judge the exports (issue 38): the Khronos glTF validator
//! (npm `gltf-validator`) reads `material.gltf` with no error and no warning, and MaterialX's
//! Python package validates `material.mtlx` against its standard library. The files are the
//! README's main command's, at a smaller size. CI installs both, points
//! BRDFD_GLTF_VALIDATOR_MODULES at the validator's `node_modules` and BRDFD_MATERIALX_PYTHON at
//! a Python that imports MaterialX, and sets BRDFD_REQUIRE_EXPORT_VALIDATORS=1, so there the
//! test cannot skip.

mod common;

use std::path::Path;
use std::process::Command;

use common::{brdfd, text};

/// The validators' settings, or `None` (and a skip message) where they are not installed.
fn validators() -> Option<(String, String)> {
    let found = (
        std::env::var("BRDFD_GLTF_VALIDATOR_MODULES").ok(),
        std::env::var("BRDFD_MATERIALX_PYTHON").ok(),
    );
    match found {
        (Some(modules), Some(python)) => Some((modules, python)),
        _ => {
            assert!(
                std::env::var_os("BRDFD_REQUIRE_EXPORT_VALIDATORS").is_none(),
                "the glTF validator and MaterialX are required here but not configured"
            );
            eprintln!(
                "skipping: npm install gltf-validator, pip install MaterialX, and set \
                 BRDFD_GLTF_VALIDATOR_MODULES and BRDFD_MATERIALX_PYTHON"
            );
            None
        }
    }
}

fn script(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scripts")
        .join(name)
        .display()
        .to_string()
}

#[test]
fn outside_validators_accept_the_exports() {
    let Some((modules, python)) = validators() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = capture_gold(dir.path(), &["--simulate"]);
    // The summary names each export's verdict with its figure, the .mtlx's measured with
    // OpenPBR's own BRDF.
    assert!(
        out.contains("material.gltf relit ") && out.contains("material.mtlx (OpenPBR) 0."),
        "{out}"
    );

    validate_gltf(&modules, &dir.path().join("result/material.gltf"));
    validate_mtlx(&python, &dir.path().join("result/material.mtlx"));

    // Whether a capture's fit takes a clear coat depends on its material: the writers' coat is
    // checked on a coated material of their own.
    let coated = brdfd_report::export::GltfMaterial {
        base_color: [0.8, 0.5, 0.1],
        metallic: 1.0,
        roughness: 0.5,
        specular: 1.0,
        specular_color: [1.0; 3],
        ior: 1.5,
        clearcoat: 0.9,
        clearcoat_roughness: 0.05,
        anisotropy: None,
    };
    let gltf = dir.path().join("coated.gltf");
    std::fs::write(&gltf, coated.document("coated")).unwrap();
    validate_gltf(&modules, &gltf);
    let openpbr = brdfd_report::export::OpenPbrMaterial {
        base_color: coated.base_color,
        base_metalness: 1.0,
        specular_weight: 1.0,
        specular_color: [1.0; 3],
        specular_roughness: 0.5,
        specular_ior: 1.5,
        coat_weight: 0.9,
        coat_roughness: 0.05,
        specular_roughness_anisotropy: 0.0,
    };
    let mtlx = dir.path().join("coated.mtlx");
    std::fs::write(&mtlx, openpbr.document("coated")).unwrap();
    validate_mtlx(&python, &mtlx);

    // An anisotropic lobe's export: KHR_materials_anisotropy with tangents, and OpenPBR's
    // specular_roughness_anisotropy.
    let lobe = brdfd_core::anisotropic::AnisotropicLobe {
        diffuse: [0.02; 3],
        specular: [0.9; 3],
        axis: brdfd_core::brdf::normalize([0.5, -0.7, 0.5]),
        alpha_t: 0.235,
        alpha_b: 0.062,
    };
    let brushed = brdfd_report::export::GltfMaterial {
        clearcoat: 0.0,
        clearcoat_roughness: 0.0,
        ..coated
    }
    .with_lobe(&lobe);
    let gltf = dir.path().join("brushed.gltf");
    std::fs::write(&gltf, brushed.document("brushed")).unwrap();
    validate_gltf(&modules, &gltf);
    let mtlx = dir.path().join("brushed.mtlx");
    std::fs::write(&mtlx, openpbr.with_lobe(&lobe).document("brushed")).unwrap();
    validate_mtlx(&python, &mtlx);
}

/// MaterialX's verdict on a `.mtlx` file against its standard library: valid.
fn validate_mtlx(python: &str, mtlx: &Path) {
    let o = Command::new(python)
        .arg(script("validate-mtlx.py"))
        .arg(mtlx)
        .output()
        .expect("python runs");
    let (said, err) = text(&o);
    assert!(o.status.success(), "MaterialX: {said}\n{err}");
    assert!(said.contains(": valid"), "{said}");
}

/// `brdfd capture` of gold at 64² in-process, on the rig `rig_args` name, its results copied
/// to `dir/result`; what it printed.
fn capture_gold(dir: &Path, rig_args: &[&str]) -> String {
    let mut args = vec!["capture"];
    args.extend(rig_args);
    args.extend([
        "--material",
        "gold",
        "--size",
        "64",
        "--in-process",
        "--state-dir",
        "state",
        "--out",
        "result",
    ]);
    let o = brdfd(&args, dir);
    let (out, err) = text(&o);
    assert!(o.status.success(), "{out}\n{err}");
    out
}

/// The Khronos validator's verdict on a glTF file: no error, no warning.
fn validate_gltf(modules: &str, gltf: &std::path::Path) {
    let o = Command::new("node")
        .arg(script("validate-gltf.cjs"))
        .arg(gltf)
        .env("NODE_PATH", modules)
        .output()
        .expect("node runs");
    let (report, err) = text(&o);
    assert!(o.status.success(), "glTF validator: {report}\n{err}");
    let report: serde_json::Value = serde_json::from_str(report.trim()).unwrap();
    assert_eq!(
        (report["errors"].as_u64(), report["warnings"].as_u64()),
        (Some(0), Some(0)),
        "{}: {report}",
        gltf.display()
    );
}

/// On a mesh, `object.gltf` holds the export on the object itself, as the first view saw it:
/// the validator accepts it, and it carries the mesh's every triangle.
#[test]
fn the_export_on_the_object_is_valid_gltf() {
    let Some((modules, _)) = validators() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let rig =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("config/rigs/simulated-grooved-block.toml");
    capture_gold(dir.path(), &["--rig", rig.to_str().unwrap()]);
    let object = dir.path().join("result/object.gltf");
    validate_gltf(&modules, &object);
    let doc: serde_json::Value = serde_json::from_slice(&std::fs::read(&object).unwrap()).unwrap();
    let mesh = brdfd_core::mesh::Mesh::read(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("config/geometry/grooved-block.obj"),
        &brdfd_core::mesh::Placement {
            units: brdfd_core::mesh::Units::M,
            rotation_deg: [0.0; 3],
            position: [0.0; 3],
        },
    )
    .unwrap();
    assert_eq!(
        doc["accessors"][0]["count"].as_u64(),
        Some(3 * mesh.triangles.len() as u64)
    );
    assert_eq!(doc["nodes"][0]["name"], "object");
}

/// A part of two materials ([`brdfd_core::materials`]): `object.gltf` carries each on its own
/// triangles, one primitive per material, each with its own buffer. The validator accepts it,
/// and every triangle is drawn once, in its material (a triangle no view saw, in the
/// commoner).
#[test]
fn the_export_of_two_materials_on_the_object_is_valid_gltf() {
    let Some((modules, _)) = validators() else {
        return;
    };
    use brdfd_report::export::GltfMaterial;
    let material = |base_color: [f64; 3], metallic: f64, clearcoat: f64| GltfMaterial {
        base_color,
        metallic,
        roughness: 0.4,
        specular: 1.0,
        specular_color: [1.0; 3],
        ior: 1.5,
        clearcoat,
        clearcoat_roughness: 0.1,
        anisotropy: None,
    };
    let (gold, blue) = (
        material([0.95, 0.64, 0.54], 1.0, 0.0),
        material([0.08, 0.16, 0.45], 0.0, 1.0),
    );
    let mesh = brdfd_core::mesh::uv_sphere([0.0; 3], 0.03, 16, 32);
    // A band of the second material, and a few triangles no view saw.
    let labels: Vec<u8> = (0..mesh.triangles.len())
        .map(|t| match t % 10 {
            0 => brdfd_core::materials::UNSEEN,
            1..=3 => 1,
            _ => 0,
        })
        .collect();
    let painted = brdfd_report::materials::painted(&labels, 2);
    let text = brdfd_report::export::gltf::document_of_materials(
        "brdfd_estimate",
        &[("gold", &gold), ("blue", &blue)],
        &mesh,
        &painted,
    );
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("object.gltf");
    std::fs::write(&path, &text).unwrap();
    validate_gltf(&modules, &path);
    let doc: serde_json::Value = serde_json::from_str(&text).unwrap();
    let primitives = doc["meshes"][0]["primitives"].as_array().unwrap();
    assert_eq!(primitives.len(), 2);
    let count = |k: usize| {
        doc["accessors"][primitives[k]["attributes"]["POSITION"].as_u64().unwrap() as usize]
            ["count"]
            .as_u64()
            .unwrap()
    };
    let second = labels.iter().filter(|l| **l == 1).count() as u64;
    assert_eq!(count(1), 3 * second);
    assert_eq!(count(0) + count(1), 3 * mesh.triangles.len() as u64);
    assert_eq!(doc["materials"][1]["name"], "blue");
    assert!(doc["materials"][1]["extensions"]["KHR_materials_clearcoat"].is_object());
}
