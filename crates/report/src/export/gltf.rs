//! `material.gltf`: the fitted material as glTF 2.0 metallic-roughness with
//! `KHR_materials_specular`, `KHR_materials_ior` and (when the fit found one)
//! `KHR_materials_clearcoat`, on a sphere, so that every viewer shows it (three.js's
//! `scene.add(gltf.scene)`, Blender's default import).
//!
//! The BRDF is glTF's own ([`GltfBrdf`]: appendix B, with the ratified
//! `KHR_materials_specular`'s `fresnel_mix`, `KHR_materials_ior`'s F₀ and
//! `KHR_materials_clearcoat`'s `fresnel_coat`). The IOR carries the largest channel's F₀ and
//! the specular colour the others' relative to it, so every factor stays within [0, 1].

use base64::Engine as _;

use brdfd_core::analytic::{coat_fresnel, ggx_lobe, schlick_weight, Microfacet};
use brdfd_core::anisotropic::{frame_at, AnisotropicLobe};
use brdfd_core::bivariate::{Bivariate, Grid};
use brdfd_core::brdf::{add, cross, dot, normalize, Cosines, IsotropicBrdf};
use brdfd_core::envmap::LightSet;
use brdfd_core::geometry::PixelGeometry;
use brdfd_core::mesh::Mesh;
use brdfd_core::raster::Raster;
use brdfd_core::render::render_in_frames;
use brdfd_core::{CoreError, Result};

use super::fit::{coat_fresnel_at, Fitted};

/// The sphere's tessellation: a UV sphere whose facets are under 6°, finer than any viewer's
/// shading shows.
const SEGMENTS: usize = 64;
const RINGS: usize = 32;

/// A glTF metallic-roughness material with the specular, IOR and clear coat extensions.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct GltfMaterial {
    pub base_color: [f64; 3],
    pub metallic: f64,
    /// glTF's roughness: √α.
    pub roughness: f64,
    /// `KHR_materials_specular`'s `specularFactor`.
    pub specular: f64,
    /// `KHR_materials_specular`'s `specularColorFactor`: each channel's F₀ relative to the
    /// IOR's, at most 1.
    pub specular_color: [f64; 3],
    /// `KHR_materials_ior`'s `ior`.
    pub ior: f64,
    /// `KHR_materials_clearcoat`'s `clearcoatFactor` (0: no coat, and no extension written).
    pub clearcoat: f64,
    /// `KHR_materials_clearcoat`'s `clearcoatRoughnessFactor`: √α of the coat.
    pub clearcoat_roughness: f64,
    /// `KHR_materials_anisotropy`, when the estimate chose an anisotropic lobe (none: no
    /// extension written).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub anisotropy: Option<GltfAnisotropy>,
}

/// `KHR_materials_anisotropy` and the tangents it is read along. glTF stretches the lobe
/// along the mesh's tangent (turned by `anisotropyRotation`, here 0): α there is
/// mix(α, 1, strength²), with α = roughness² across it. brdfd writes each vertex's tangent
/// (`TANGENT`) along the estimated lobe's rough direction, across the grain, laid on the
/// surface from one axis as the estimate's lobe is ([`brdfd_core::anisotropic`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct GltfAnisotropy {
    /// `anisotropyStrength`.
    pub strength: f64,
    /// The lobe's axis (world frame, unit).
    pub axis: [f64; 3],
    /// Whether the rough direction is the axis laid on the surface (else the direction
    /// across it, n × t).
    pub rough_along_axis: bool,
}

impl GltfAnisotropy {
    /// The unit tangent glTF stretches the lobe along, at a point of normal `n`.
    pub fn tangent(&self, n: [f64; 3]) -> [f64; 3] {
        let (t, b) = frame_at(self.axis, n);
        if self.rough_along_axis {
            t
        } else {
            b
        }
    }
}

impl GltfMaterial {
    pub fn from_fit(f: &Fitted) -> GltfMaterial {
        GltfMaterial {
            base_color: f.base_color,
            metallic: f.metallic,
            roughness: f.alpha.sqrt().clamp(0.0, 1.0),
            specular: f.specular,
            specular_color: f.specular_color(),
            ior: f.ior(),
            clearcoat: f.coat,
            clearcoat_roughness: f.coat_alpha.sqrt().clamp(0.0, 1.0),
            anisotropy: None,
        }
    }

    /// The material with the roughnesses of an anisotropic lobe: its smooth α as glTF's
    /// roughness, and its rough α through `anisotropyStrength`.
    pub fn with_lobe(self, lobe: &AnisotropicLobe) -> GltfMaterial {
        let (smooth, rough) = lobe.smooth_and_rough();
        GltfMaterial {
            roughness: smooth.sqrt().clamp(0.0, 1.0),
            anisotropy: Some(GltfAnisotropy {
                strength: ((rough - smooth) / (1.0 - smooth)).clamp(0.0, 1.0).sqrt(),
                axis: lobe.axis,
                rough_along_axis: lobe.alpha_t >= lobe.alpha_b,
            }),
            ..self
        }
    }

    /// The material as tables on `grid`, ready to render under any light: its base, and its
    /// coat's lobe when it has one.
    pub fn tables(&self, grid: Grid) -> GltfTables {
        let base = GltfMaterial {
            clearcoat: 0.0,
            ..*self
        };
        GltfTables {
            base: Bivariate::reduce(&GltfBrdf(base), grid),
            coat: (self.clearcoat > 0.0).then(|| {
                let alpha = self.clearcoat_roughness * self.clearcoat_roughness;
                let lobe = Microfacet::one_lobe([0.0; 3], [1.0; 3], [1.0; 3], alpha);
                (self.clearcoat, lobe.bivariate(grid))
            }),
        }
    }

    /// The material rendered on `geometry` under `lights` with point lights and the cap
    /// ([`brdfd_core::render::render_full`]), as a conforming renderer shows it: with its
    /// anisotropy, each pixel in the frame whose tangent it is stretched along.
    pub fn render_full(&self, geometry: &PixelGeometry, lights: &LightSet) -> Raster {
        self.render_bounced(geometry, lights, false)
    }

    /// [`GltfMaterial::render_full`], and with `bounce` the light a concave mesh throws on
    /// itself through the same material ([`brdfd_core::bounce`]).
    pub fn render_bounced(
        &self,
        geometry: &PixelGeometry,
        lights: &LightSet,
        bounce: bool,
    ) -> Raster {
        let brdf = GltfBrdf(*self);
        let frame = |n| match self.anisotropy {
            Some(a) => {
                let t = a.tangent(n);
                (t, cross(n, t))
            }
            None => brdfd_core::brdf::tangent_frame(n),
        };
        let eval = |wi, wo| brdf.eval_local(wi, wo);
        let mut img = match self.anisotropy {
            None => brdfd_core::render::render_full(geometry, lights, &brdf),
            Some(_) => render_in_frames(geometry, lights, frame, eval),
        };
        if bounce {
            brdfd_core::bounce::add_to(&mut img, geometry, lights, frame, eval);
        }
        img
    }

    /// The first material of a glTF file (`.gltf`, JSON): its metallic-roughness factors and
    /// the specular, IOR, clear coat and anisotropy extensions, with glTF's defaults for what
    /// it leaves out. What else a material can hold (textures, emission, transparency, other
    /// extensions) is refused by name: brdfd would render something else than the file says.
    /// brdfd renders a material on its own shapes, which carry no tangents: an anisotropic
    /// one must name the axis brdfd laid its tangents from (`extras.brdfd`, which brdfd's
    /// exports write).
    pub fn read(path: &std::path::Path) -> Result<GltfMaterial> {
        let what = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| CoreError::io(path, e))?;
        let doc: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| CoreError::format(&what, format!("not glTF JSON: {e}")))?;
        let m = doc["materials"]
            .get(0)
            .ok_or_else(|| CoreError::format(&what, "has no `materials[0]`"))?;
        if let Some(field) = unrendered(m, "materials[0]") {
            return Err(CoreError::format(
                &what,
                format!("{field} is not rendered: brdfd renders glTF's metallic-roughness BRDF with the specular, IOR, clear coat and anisotropy extensions, from factors alone"),
            ));
        }
        let pbr = &m["pbrMetallicRoughness"];
        let spec = &m["extensions"]["KHR_materials_specular"];
        let coat = &m["extensions"]["KHR_materials_clearcoat"];
        let number = |v: &serde_json::Value, field: &str, default: f64, range: (f64, f64)| {
            if v.is_null() {
                return Ok(default);
            }
            v.as_f64()
                .filter(|x| (range.0..=range.1).contains(x))
                .ok_or_else(|| {
                    CoreError::format(
                        &what,
                        format!(
                            "materials[0].{field} is {v}, not a number in [{}, {}]",
                            range.0, range.1
                        ),
                    )
                })
        };
        let unit = (0.0, 1.0);
        let rgb = |v: &serde_json::Value, field: &str, range: (f64, f64)| -> Result<[f64; 3]> {
            let mut out = [1.0; 3];
            if !v.is_null() && v.as_array().is_none_or(|a| a.len() < 3) {
                return Err(CoreError::format(
                    &what,
                    format!("materials[0].{field} is {v}, not a colour of 3 (or 4) numbers"),
                ));
            }
            for (c, o) in out.iter_mut().enumerate() {
                *o = number(&v[c], field, 1.0, range)?;
            }
            Ok(out)
        };
        Ok(GltfMaterial {
            base_color: rgb(&pbr["baseColorFactor"], "baseColorFactor", unit)?,
            metallic: number(&pbr["metallicFactor"], "metallicFactor", 1.0, unit)?,
            roughness: number(&pbr["roughnessFactor"], "roughnessFactor", 1.0, unit)?,
            specular: number(&spec["specularFactor"], "specularFactor", 1.0, unit)?,
            specular_color: rgb(
                &spec["specularColorFactor"],
                "specularColorFactor",
                (0.0, f64::MAX),
            )?,
            ior: number(
                &m["extensions"]["KHR_materials_ior"]["ior"],
                "KHR_materials_ior.ior",
                1.5,
                (1.0, f64::MAX),
            )?,
            clearcoat: number(
                &coat["clearcoatFactor"],
                "KHR_materials_clearcoat.clearcoatFactor",
                0.0,
                unit,
            )?,
            clearcoat_roughness: number(
                &coat["clearcoatRoughnessFactor"],
                "KHR_materials_clearcoat.clearcoatRoughnessFactor",
                0.0,
                unit,
            )?,
            anisotropy: anisotropy(m, &what)?,
        })
    }

    /// The document: the material on a unit sphere at the origin, one node, one scene.
    pub fn document(&self, name: &str) -> String {
        self.document_on(name, "sphere", &sphere_buffer(self.anisotropy.as_ref()))
    }

    /// The document with the material on `mesh` (in the world, as the capture saw it): the
    /// object itself, for a viewer or a renderer to show.
    pub fn document_on_mesh(&self, name: &str, mesh: &Mesh) -> String {
        self.document_on(name, "object", &mesh_buffer(mesh, self.anisotropy.as_ref()))
    }

    fn document_on(&self, name: &str, shape: &str, geometry: &Geometry) -> String {
        document(name, shape, &[(name, self, geometry)])
    }

    /// The material's glTF object, named `name`, with the extensions it uses added to `used`.
    fn material_json(&self, name: &str, used: &mut Vec<&'static str>) -> serde_json::Value {
        for e in ["KHR_materials_specular", "KHR_materials_ior"] {
            if !used.contains(&e) {
                used.push(e);
            }
        }
        let mut extensions = serde_json::json!({
            "KHR_materials_specular": {
                "specularFactor": self.specular,
                "specularColorFactor": self.specular_color,
            },
            "KHR_materials_ior": { "ior": self.ior },
        });
        let mut extras = serde_json::json!({});
        if let Some(a) = &self.anisotropy {
            if !used.contains(&"KHR_materials_anisotropy") {
                used.push("KHR_materials_anisotropy");
            }
            extensions["KHR_materials_anisotropy"] = serde_json::json!({
                "anisotropyStrength": a.strength,
                "anisotropyRotation": 0.0,
            });
            // Where the tangents come from, so that brdfd can lay them on its own shapes.
            extras["brdfd"] = serde_json::json!({
                "anisotropy_axis": a.axis,
                "rough_along_axis": a.rough_along_axis,
            });
        }
        if self.clearcoat > 0.0 {
            if !used.contains(&"KHR_materials_clearcoat") {
                used.push("KHR_materials_clearcoat");
            }
            extensions["KHR_materials_clearcoat"] = serde_json::json!({
                "clearcoatFactor": self.clearcoat,
                "clearcoatRoughnessFactor": self.clearcoat_roughness,
            });
        }
        serde_json::json!({
            "name": name,
            "pbrMetallicRoughness": {
                "baseColorFactor": [self.base_color[0], self.base_color[1], self.base_color[2], 1.0],
                "metallicFactor": self.metallic,
                "roughnessFactor": self.roughness,
            },
            "extensions": extensions,
            "extras": extras,
        })
    }
}

/// Several materials on one object ([`brdfd_core::materials`]): `mesh` with each triangle
/// drawn in the material `labels` gives it (an index into `materials`; a label past them, a
/// triangle no view saw, takes the first). One primitive per material, each with its own
/// buffer; a material with no triangle is left out.
pub fn document_of_materials(
    name: &str,
    materials: &[(&str, &GltfMaterial)],
    mesh: &Mesh,
    labels: &[u8],
) -> String {
    let geometries: Vec<(usize, Geometry)> = (0..materials.len())
        .filter_map(|k| {
            let mine = |l: u8| l as usize == k || (k == 0 && l as usize >= materials.len());
            let triangles: Vec<[u32; 3]> = mesh
                .triangles
                .iter()
                .zip(labels)
                .filter(|(_, l)| mine(**l))
                .map(|(t, _)| *t)
                .collect();
            if triangles.is_empty() {
                return None;
            }
            let corner_normals = mesh.corner_normals.as_ref().map(|c| {
                c.iter()
                    .zip(labels)
                    .filter(|(_, l)| mine(**l))
                    .map(|(n, _)| *n)
                    .collect()
            });
            let part = Mesh {
                positions: mesh.positions.clone(),
                triangles,
                corner_normals,
            };
            Some((k, mesh_buffer(&part, materials[k].1.anisotropy.as_ref())))
        })
        .collect();
    let pieces: Vec<(&str, &GltfMaterial, &Geometry)> = geometries
        .iter()
        .map(|(k, g)| (materials[*k].0, materials[*k].1, g))
        .collect();
    document(name, "object", &pieces)
}

/// The document: one node and mesh named `shape`, one primitive per piece, each in its
/// material and with its own buffer.
fn document(name: &str, shape: &str, pieces: &[(&str, &GltfMaterial, &Geometry)]) -> String {
    let (mut primitives, mut accessors, mut views, mut buffers, mut materials) =
        (vec![], vec![], vec![], vec![], vec![]);
    let mut used = Vec::new();
    for (i, (material_name, material, geometry)) in pieces.iter().enumerate() {
        let Geometry {
            buffer,
            vertices,
            tangents,
            indices,
            min,
            max,
        } = geometry;
        let vec3s = vertices * 12;
        let mut primitive = serde_json::json!({
            "attributes": { "POSITION": accessors.len(), "NORMAL": accessors.len() + 1 },
            "material": i,
        });
        accessors.push(
            serde_json::json!({ "bufferView": views.len(), "componentType": 5126,
                                           "count": vertices, "type": "VEC3",
                                           "min": min, "max": max }),
        );
        accessors.push(serde_json::json!({ "bufferView": views.len() + 1,
                                           "componentType": 5126, "count": vertices,
                                           "type": "VEC3" }));
        views.push(
            serde_json::json!({ "buffer": i, "byteOffset": 0, "byteLength": vec3s,
                                       "target": 34962 }),
        );
        views.push(
            serde_json::json!({ "buffer": i, "byteOffset": vec3s, "byteLength": vec3s,
                                       "target": 34962 }),
        );
        let mut offset = 2 * vec3s;
        if *tangents {
            primitive["attributes"]["TANGENT"] = accessors.len().into();
            accessors.push(serde_json::json!({ "bufferView": views.len(),
                                               "componentType": 5126, "count": vertices,
                                               "type": "VEC4" }));
            views.push(serde_json::json!({ "buffer": i, "byteOffset": offset,
                                           "byteLength": vertices * 16, "target": 34962 }));
            offset += vertices * 16;
        }
        if let Some(indices) = indices {
            primitive["indices"] = accessors.len().into();
            accessors.push(serde_json::json!({ "bufferView": views.len(),
                                               "componentType": 5123, "count": indices,
                                               "type": "SCALAR" }));
            views.push(serde_json::json!({ "buffer": i, "byteOffset": offset,
                                           "byteLength": indices * 2, "target": 34963 }));
        }
        primitives.push(primitive);
        buffers.push(serde_json::json!({
            "byteLength": buffer.len(),
            "uri": format!(
                "data:application/octet-stream;base64,{}",
                base64::engine::general_purpose::STANDARD.encode(buffer)
            ),
        }));
        materials.push(material.material_json(material_name, &mut used));
    }
    let json = serde_json::json!({
        "asset": { "version": "2.0", "generator": concat!("brdfd ", env!("CARGO_PKG_VERSION")) },
        "extensionsUsed": used,
        "scene": 0,
        "scenes": [{ "name": name, "nodes": [0] }],
        "nodes": [{ "name": shape, "mesh": 0 }],
        "meshes": [{ "name": shape, "primitives": primitives }],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": buffers,
        "materials": materials,
    });
    serde_json::to_string_pretty(&json).expect("a material serialises")
}

/// A material's `KHR_materials_anisotropy` with the axis brdfd lays its tangents from
/// (`extras.brdfd`); `None` without the extension or at strength 0.
fn anisotropy(m: &serde_json::Value, what: &str) -> Result<Option<GltfAnisotropy>> {
    let ext = &m["extensions"]["KHR_materials_anisotropy"];
    if ext.is_null() {
        return Ok(None);
    }
    let bad = |message: String| CoreError::format(what, format!("materials[0].{message}"));
    let strength = match &ext["anisotropyStrength"] {
        serde_json::Value::Null => 0.0,
        v => v
            .as_f64()
            .filter(|x| (0.0..=1.0).contains(x))
            .ok_or_else(|| {
                bad(format!(
                    "KHR_materials_anisotropy.anisotropyStrength is {v}, not a number in [0, 1]"
                ))
            })?,
    };
    let rotation = &ext["anisotropyRotation"];
    if !(rotation.is_null() || rotation.as_f64() == Some(0.0)) {
        return Err(bad(format!("KHR_materials_anisotropy.anisotropyRotation is {rotation}: brdfd renders its tangents unturned")));
    }
    if strength == 0.0 {
        return Ok(None);
    }
    let axis = m["extras"]["brdfd"]["anisotropy_axis"]
        .as_array()
        .filter(|a| a.len() == 3)
        .and_then(|a| a.iter().map(serde_json::Value::as_f64).collect::<Option<Vec<f64>>>())
        .map(|a| [a[0], a[1], a[2]])
        .filter(|a| dot(*a, *a).is_finite() && dot(*a, *a) > 1e-12)
        .ok_or_else(|| bad("extras.brdfd.anisotropy_axis is not 3 numbers of a direction: brdfd lays the tangents KHR_materials_anisotropy follows from it on its own shapes, which carry none (brdfd's exports write it)".into()))?;
    let rough_along_axis = m["extras"]["brdfd"]["rough_along_axis"]
        .as_bool()
        .ok_or_else(|| bad("extras.brdfd.rough_along_axis is not true or false".into()))?;
    Ok(Some(GltfAnisotropy {
        strength,
        axis: normalize(axis),
        rough_along_axis,
    }))
}

/// The first part of a glTF material (`at` names where) that [`GltfBrdf`] does not render:
/// a texture, emission, transparency, or an extension other than the specular, IOR, clear
/// coat and anisotropy ones.
fn unrendered(v: &serde_json::Value, at: &str) -> Option<String> {
    let object = v.as_object()?;
    for (key, value) in object {
        let here = format!("{at}.{key}");
        let emissive = key == "emissiveFactor"
            && value
                .as_array()
                .is_some_and(|a| a.iter().any(|c| c.as_f64() != Some(0.0)));
        let transparent = key == "alphaMode" && value.as_str() != Some("OPAQUE");
        if key.ends_with("Texture") || emissive || transparent {
            return Some(here);
        }
        if key == "extensions" {
            let known = [
                "KHR_materials_specular",
                "KHR_materials_ior",
                "KHR_materials_clearcoat",
                "KHR_materials_anisotropy",
            ];
            if let Some(other) = value
                .as_object()?
                .keys()
                .find(|k| !known.contains(&k.as_str()))
            {
                return Some(format!("{here}.{other}"));
            }
        }
        if let Some(inner) = unrendered(value, &here) {
            return Some(inner);
        }
    }
    None
}

/// A glTF buffer of positions, then normals (f32 VEC3, one per vertex), then tangents (f32
/// VEC4) for an anisotropic material, then u16 indices if any, padded to 4 bytes; with the
/// counts and the positions' bounds glTF asks for.
struct Geometry {
    buffer: Vec<u8>,
    vertices: usize,
    tangents: bool,
    indices: Option<usize>,
    min: [f32; 3],
    max: [f32; 3],
}

impl Geometry {
    fn new(
        points: &[[f32; 3]],
        normals: &[[f32; 3]],
        indices: Option<&[u16]>,
        anisotropy: Option<&GltfAnisotropy>,
    ) -> Geometry {
        let mut buffer = Vec::new();
        for p in points.iter().chain(normals) {
            for v in p {
                buffer.extend_from_slice(&v.to_le_bytes());
            }
        }
        if let Some(a) = anisotropy {
            for n in normals {
                let t = a.tangent(n.map(f64::from));
                // w = 1: glTF's bitangent is n × t; the lobe is the same turned half a turn
                // about the normal, so its sign does not matter.
                for v in [t[0] as f32, t[1] as f32, t[2] as f32, 1.0] {
                    buffer.extend_from_slice(&v.to_le_bytes());
                }
            }
        }
        for i in indices.unwrap_or(&[]) {
            buffer.extend_from_slice(&i.to_le_bytes());
        }
        // A buffer's length is padded to 4 bytes.
        while buffer.len() % 4 != 0 {
            buffer.push(0);
        }
        let bound = |f: fn(f32, f32) -> f32, start: f32| {
            points.iter().fold([start; 3], |acc, p| {
                std::array::from_fn(|i| f(acc[i], p[i]))
            })
        };
        Geometry {
            buffer,
            vertices: points.len(),
            tangents: anisotropy.is_some(),
            indices: indices.map(<[u16]>::len),
            min: bound(f32::min, f32::INFINITY),
            max: bound(f32::max, f32::NEG_INFINITY),
        }
    }
}

/// A unit UV sphere, its positions also its normals, indexed.
fn sphere_buffer(anisotropy: Option<&GltfAnisotropy>) -> Geometry {
    let mut points = Vec::with_capacity((RINGS + 1) * (SEGMENTS + 1));
    for r in 0..=RINGS {
        let theta = std::f64::consts::PI * r as f64 / RINGS as f64;
        for s in 0..=SEGMENTS {
            let phi = 2.0 * std::f64::consts::PI * s as f64 / SEGMENTS as f64;
            points.push([
                (theta.sin() * phi.cos()) as f32,
                theta.cos() as f32,
                (-theta.sin() * phi.sin()) as f32,
            ]);
        }
    }
    let row = SEGMENTS + 1;
    let mut indices: Vec<u16> = Vec::new();
    for r in 0..RINGS {
        for s in 0..SEGMENTS {
            let (a, b) = ((r * row + s) as u16, ((r + 1) * row + s) as u16);
            // Counter-clockwise seen from outside; the poles' degenerate halves are left out.
            if r != 0 {
                indices.extend([a, b, a + 1]);
            }
            if r != RINGS - 1 {
                indices.extend([a + 1, b, b + 1]);
            }
        }
    }
    Geometry::new(&points, &points, Some(&indices), anisotropy)
}

/// A mesh as three vertices a triangle, not indexed (a mesh may have more than u16 indexes),
/// with the file's corner normals, or the face's where it has none.
fn mesh_buffer(mesh: &Mesh, anisotropy: Option<&GltfAnisotropy>) -> Geometry {
    let mut points = Vec::with_capacity(3 * mesh.triangles.len());
    let mut normals = Vec::with_capacity(3 * mesh.triangles.len());
    for t in 0..mesh.triangles.len() {
        let corners = mesh.corners(t);
        let face = {
            let (a, b, c) = (corners[0], corners[1], corners[2]);
            let (u, v) = (
                [b[0] - a[0], b[1] - a[1], b[2] - a[2]],
                [c[0] - a[0], c[1] - a[1], c[2] - a[2]],
            );
            let n = [
                u[1] * v[2] - u[2] * v[1],
                u[2] * v[0] - u[0] * v[2],
                u[0] * v[1] - u[1] * v[0],
            ];
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt().max(1e-30);
            n.map(|x| x / len)
        };
        for k in 0..3 {
            points.push(corners[k].map(|x| x as f32));
            let n = mesh.corner_normals.as_ref().map_or(face, |c| c[t][k]);
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt().max(1e-30);
            normals.push(n.map(|x| (x / len) as f32));
        }
    }
    Geometry::new(&points, &normals, None, anisotropy)
}

/// A material reduced to bivariate tables, once for every render: glTF's coat hangs on N·V and
/// so is no table of (θh, θd) itself, but a pixel fixes N·V whatever the light.
pub struct GltfTables {
    base: Bivariate,
    /// The coat's weight and its lobe (no Fresnel of its own).
    coat: Option<(f64, Bivariate)>,
}

impl GltfTables {
    /// The material rendered on `geometry` under `lights`, as a conforming renderer shows it:
    /// the base's render and the coat's mixed at each pixel by the coat's weight × its
    /// Fresnel at the pixel's N·V (`fresnel_coat`).
    pub fn render(&self, geometry: &PixelGeometry, lights: &LightSet) -> Raster {
        self.render_beside(geometry, lights, &[]).0
    }

    /// [`GltfTables::render`], and each of `others` rendered under the same lights in the
    /// same pass ([`brdfd_core::render::render_bivariates`]): each image as it renders alone.
    pub fn render_beside(
        &self,
        geometry: &PixelGeometry,
        lights: &LightSet,
        others: &[&Bivariate],
    ) -> (Raster, Vec<Raster>) {
        let mut own = vec![&self.base];
        own.extend(self.coat.as_ref().map(|(_, lobe)| lobe));
        let (own, rest) = super::render_with(geometry, lights, own, others);
        (self.mixed(geometry, own), rest)
    }

    /// The base's render (first) and the coat's, if any, mixed at each pixel.
    fn mixed(&self, geometry: &PixelGeometry, renders: Vec<Raster>) -> Raster {
        let mut renders = renders.into_iter();
        let mut image = renders.next().expect("the base's render");
        if let (Some((weight, _)), Some(coat)) = (&self.coat, renders.next()) {
            for px in &geometry.pixels {
                let i = px.y as usize * image.width + px.x as usize;
                let k = (weight * coat_fresnel_at(px)) as f32;
                image.pixels[i] =
                    std::array::from_fn(|c| image.pixels[i][c] * (1.0 - k) + coat.pixels[i][c] * k);
            }
        }
        image
    }
}

/// glTF's metallic-roughness BRDF with the specular, IOR and clear coat extensions (as an
/// [`IsotropicBrdf`] it leaves `KHR_materials_anisotropy` out, which needs a tangent frame:
/// [`GltfBrdf::eval_local`] and [`GltfMaterial::render_full`] hold it):
/// `material = mix(dielectric, metal, metallic)` with
/// `metal = (c + (1 − c)·w)·S` and
/// `dielectric = (1 − q·max Fr)·c/π + q·Fr·S`, `Fr = F₀ + (1 − F₀)·w` per channel,
/// F₀ = ((η − 1)/(η + 1))² × specular colour; then
/// `coated = mix(material, S_c, k·Fc)`, `Fc = 0.04 + 0.96·(1 − N·V)⁵` (`fresnel_coat`), where
/// the view is the second direction.
pub struct GltfBrdf(pub GltfMaterial);

impl IsotropicBrdf for GltfBrdf {
    fn eval_angles(&self, theta_h: f64, theta_d: f64, phi_d: f64) -> [f64; 3] {
        Cosines::of_angles(theta_h, theta_d, phi_d).map_or([0.0; 3], |c| self.eval_cosines(c))
    }

    /// From the halfway vector, without the angles (`brdfd render --gltf` asks for
    /// directions; [`Cosines::of_dirs`] says why).
    fn eval_dirs(&self, wi: [f64; 3], wo: [f64; 3]) -> [f64; 3] {
        Cosines::of_dirs(wi, wo).map_or([0.0; 3], |c| self.eval_cosines(c))
    }
}

impl GltfBrdf {
    /// glTF's BRDF with `KHR_materials_anisotropy`, for directions in the frame whose x axis
    /// is the tangent it stretches the lobe along ([`GltfAnisotropy::tangent`]) and z the
    /// normal: α along x is mix(α, 1, strength²). Without anisotropy, the isotropic BRDF.
    pub fn eval_local(&self, wi: [f64; 3], wo: [f64; 3]) -> [f64; 3] {
        let m = &self.0;
        let Some(a) = &m.anisotropy else {
            return self.eval_dirs(wi, wo);
        };
        if wi[2] <= 0.0 || wo[2] <= 0.0 {
            return [0.0; 3];
        }
        let alpha = m.roughness * m.roughness;
        let lobe = AnisotropicLobe {
            diffuse: [0.0; 3],
            specular: [1.0; 3],
            axis: [1.0, 0.0, 0.0],
            alpha_t: alpha + a.strength * a.strength * (1.0 - alpha),
            alpha_b: alpha,
        };
        let specular = lobe.eval_local(wi, wo)[0];
        let h = normalize(add(wi, wo));
        let coat_lobe = self.coat_lobe(h[2], wi[2], wo[2]);
        self.combine(specular, schlick_weight(dot(wi, h)), coat_lobe, wo[2])
    }

    /// The isotropic BRDF.
    fn eval_cosines(&self, c: Cosines) -> [f64; 3] {
        let alpha = self.0.roughness * self.0.roughness;
        let specular = ggx_lobe(c.h, c.i, c.o, alpha);
        let coat_lobe = self.coat_lobe(c.h, c.i, c.o);
        self.combine(specular, schlick_weight(c.d), coat_lobe, c.o)
    }

    /// The coat's lobe (no Fresnel of its own); 0 without a coat.
    fn coat_lobe(&self, cos_h: f64, cos_i: f64, cos_o: f64) -> f64 {
        let m = &self.0;
        if m.clearcoat > 0.0 {
            let alpha = m.clearcoat_roughness * m.clearcoat_roughness;
            ggx_lobe(cos_h, cos_i, cos_o, alpha)
        } else {
            0.0
        }
    }

    /// The material from its specular lobe without Fresnel (D·V), Schlick's weight
    /// (1 − cos θd)⁵, the coat's lobe and the view's cosine.
    fn combine(&self, specular: f64, w: f64, coat_lobe: f64, cos_view: f64) -> [f64; 3] {
        let m = &self.0;
        let ior_f0 = ((m.ior - 1.0) / (m.ior + 1.0)).powi(2);
        let fr: [f64; 3] = std::array::from_fn(|c| {
            let f0 = (ior_f0 * m.specular_color[c]).min(1.0);
            f0 + (1.0 - f0) * w
        });
        let coat = if m.clearcoat > 0.0 {
            m.clearcoat * coat_fresnel(cos_view)
        } else {
            0.0
        };
        // `fresnel_mix` weighs the base by 1 − weight · max(fr).
        let diffuse_weight = 1.0 - m.specular * fr.iter().copied().fold(0.0, f64::max);
        std::array::from_fn(|c| {
            let dielectric = diffuse_weight * m.base_color[c] / std::f64::consts::PI
                + m.specular * fr[c] * specular;
            let metal = (m.base_color[c] + (1.0 - m.base_color[c]) * w) * specular;
            let base = (1.0 - m.metallic) * dielectric + m.metallic * metal;
            base * (1.0 - coat) + coat * coat_lobe
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_written_material_reads_back_and_a_bad_one_is_named() {
        let m = GltfMaterial {
            base_color: [0.9, 0.6, 0.2],
            metallic: 0.75,
            roughness: 0.3,
            specular: 0.5,
            specular_color: [1.0, 0.8, 0.6],
            ior: 1.7,
            clearcoat: 0.4,
            clearcoat_roughness: 0.1,
            anisotropy: None,
        };
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.gltf");
        std::fs::write(&path, m.document("m")).unwrap();
        assert_eq!(GltfMaterial::read(&path).unwrap(), m);
        std::fs::write(&path, m.document("m").replace("0.75", "1.75")).unwrap();
        let e = GltfMaterial::read(&path).unwrap_err().to_string();
        assert!(e.contains("materials[0].metallicFactor is 1.75"), "{e}");
        let with = |key: &str, value: serde_json::Value| {
            let mut doc: serde_json::Value = serde_json::from_str(&m.document("m")).unwrap();
            doc["materials"][0][key] = value;
            std::fs::write(&path, doc.to_string()).unwrap();
            GltfMaterial::read(&path).unwrap_err().to_string()
        };
        let e = with("normalTexture", serde_json::json!({ "index": 0 }));
        assert!(
            e.contains("materials[0].normalTexture is not rendered"),
            "{e}"
        );
        let e = with("alphaMode", serde_json::json!("BLEND"));
        assert!(e.contains("materials[0].alphaMode is not rendered"), "{e}");

        // An anisotropic material reads back with the axis its tangents were laid from; one
        // without that axis is refused by name, since brdfd's shapes carry no tangents.
        let brushed = GltfMaterial {
            anisotropy: Some(GltfAnisotropy {
                strength: 0.43,
                axis: [0.6, 0.0, 0.8],
                rough_along_axis: false,
            }),
            clearcoat: 0.0,
            clearcoat_roughness: 0.0,
            ..m
        };
        std::fs::write(&path, brushed.document("b")).unwrap();
        assert_eq!(GltfMaterial::read(&path).unwrap(), brushed);
        let mut doc: serde_json::Value = serde_json::from_str(&brushed.document("b")).unwrap();
        doc["materials"][0]["extras"] = serde_json::json!({});
        std::fs::write(&path, doc.to_string()).unwrap();
        let e = GltfMaterial::read(&path).unwrap_err().to_string();
        assert!(e.contains("extras.brdfd.anisotropy_axis"), "{e}");
    }

    #[test]
    fn anisotropy_stretches_the_lobe_along_the_tangent_and_none_is_the_isotropic_brdf() {
        let m = GltfMaterial {
            base_color: [0.9, 0.9, 0.9],
            metallic: 1.0,
            roughness: 0.25,
            specular: 1.0,
            specular_color: [1.0; 3],
            ior: 1.5,
            clearcoat: 0.3,
            clearcoat_roughness: 0.1,
            anisotropy: None,
        };
        let (wi, wo) = (normalize([0.2, 0.1, 1.0]), normalize([-0.3, 0.05, 1.0]));
        let (local, iso) = (
            GltfBrdf(m).eval_local(wi, wo),
            GltfBrdf(m).eval_dirs(wi, wo),
        );
        let zero = GltfBrdf(GltfMaterial {
            anisotropy: Some(GltfAnisotropy {
                strength: 0.0,
                axis: [1.0, 0.0, 0.0],
                rough_along_axis: true,
            }),
            ..m
        })
        .eval_local(wi, wo);
        for c in 0..3 {
            assert!(
                (local[c] - iso[c]).abs() < 1e-12 * iso[c],
                "{local:?} {iso:?}"
            );
            assert!((zero[c] - iso[c]).abs() < 1e-9 * iso[c], "{zero:?} {iso:?}");
        }
        // Stretched along x (the tangent): a light tilted along x keeps more of the lobe
        // than one tilted as far along y.
        let stretched = GltfBrdf(GltfMaterial {
            anisotropy: Some(GltfAnisotropy {
                strength: 0.6,
                axis: [1.0, 0.0, 0.0],
                rough_along_axis: true,
            }),
            ..m
        });
        let up = [0.0, 0.0, 1.0];
        let (x, y) = (
            stretched.eval_local(normalize([0.3, 0.0, 1.0]), up)[0],
            stretched.eval_local(normalize([0.0, 0.3, 1.0]), up)[0],
        );
        assert!(x > 2.0 * y, "{x} {y}");
    }

    #[test]
    fn the_sphere_is_closed_and_its_faces_point_out() {
        let Geometry {
            buffer,
            vertices,
            indices,
            ..
        } = sphere_buffer(None);
        let indices = indices.unwrap();
        assert_eq!(
            buffer.len(),
            (vertices * 24 + indices * 2).next_multiple_of(4)
        );
        let f = |i: usize| -> [f32; 3] {
            std::array::from_fn(|k| {
                let o = 12 * i + 4 * k;
                f32::from_le_bytes(buffer[o..o + 4].try_into().unwrap())
            })
        };
        let idx = |i: usize| -> usize {
            let o = vertices * 24 + 2 * i;
            u16::from_le_bytes([buffer[o], buffer[o + 1]]) as usize
        };
        let mut area = 0.0f64;
        for t in 0..indices / 3 {
            let [a, b, c] = [idx(3 * t), idx(3 * t + 1), idx(3 * t + 2)].map(f);
            let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
            let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
            let n = [
                u[1] * v[2] - u[2] * v[1],
                u[2] * v[0] - u[0] * v[2],
                u[0] * v[1] - u[1] * v[0],
            ];
            let centre = [0, 1, 2].map(|k| a[k] + b[k] + c[k]);
            let outward = n[0] * centre[0] + n[1] * centre[1] + n[2] * centre[2];
            assert!(outward > 0.0, "triangle {t} faces in");
            area += 0.5 * (n[0] as f64).hypot(n[1] as f64).hypot(n[2] as f64);
        }
        // A 64 × 32 tessellation keeps 99.6% of the sphere's area.
        let sphere = 4.0 * std::f64::consts::PI;
        assert!((area / sphere - 1.0).abs() < 0.01, "{area}");
    }
}
