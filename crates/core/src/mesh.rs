//! Triangle meshes of the object: read from OBJ, STL (binary or ASCII) or PLY, in metres
//! after the file's units, and placed in the world by a pose (object to world: rotated about
//! its own origin, then moved). A mesh is checked before it is used: one with no triangles,
//! a vertex that is not a number, an index past its vertices or an edge shared by more than
//! two triangles (not a surface) is refused with the file and the place named.
//!
//! Not here: casting rays against it ([`super::bvh`]), or turning it into per-pixel geometry
//! ([`super::geometry`]).

use std::collections::HashMap;
use std::io::BufReader;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::brdf::{cross, normalize, sub, Vec3};
use super::error::{CoreError, Result};

/// The length unit of a mesh file's coordinates. 3D-printing files are usually millimetres.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Units {
    #[default]
    M,
    Cm,
    Mm,
    In,
}

impl Units {
    /// Metres per unit.
    pub fn metres(self) -> f64 {
        match self {
            Units::M => 1.0,
            Units::Cm => 0.01,
            Units::Mm => 0.001,
            Units::In => 0.0254,
        }
    }
}

/// A triangle mesh in world coordinates (metres).
#[derive(Clone, Debug, PartialEq)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    /// Normals at each triangle's corners, where the file gives them (interpolated across the
    /// face); faces are flat otherwise.
    pub corner_normals: Option<Vec<[Vec3; 3]>>,
}

/// Where a mesh stands: object to world.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    pub units: Units,
    /// Rotations about the world's X, then Y, then Z axes, degrees.
    pub rotation_deg: Vec3,
    /// Where the object's origin goes, metres.
    pub position: Vec3,
}

/// The meshes shipped in `config/geometry/`, compiled in: a geometry names one as
/// `builtin:NAME` (`builtin:grooved-block.obj`), so that an installed binary without the
/// source tree has them.
const BUILTIN: [(&str, &str); 2] = [
    (
        "grooved-block.obj",
        include_str!("../../../config/geometry/grooved-block.obj"),
    ),
    (
        "corrugated-sample.obj",
        include_str!("../../../config/geometry/corrugated-sample.obj"),
    ),
];

/// The prefix of a shipped mesh's name.
pub const BUILTIN_PREFIX: &str = "builtin:";

/// Whether a mesh's file is one of the shipped meshes (`builtin:NAME`), not a path.
pub fn is_builtin(path: &Path) -> bool {
    path.to_str().is_some_and(|p| p.starts_with(BUILTIN_PREFIX))
}

impl Mesh {
    /// Reads a mesh file by its extension (`.obj`, `.stl`, `.ply`), or a shipped mesh
    /// (`builtin:NAME`), checks it, and places it.
    pub fn read(path: &Path, placement: &Placement) -> Result<Mesh> {
        let what = path.display().to_string();
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .unwrap_or_default();
        if is_builtin(path) {
            let name = &what[BUILTIN_PREFIX.len()..];
            let Some((_, text)) = BUILTIN.iter().find(|(n, _)| *n == name) else {
                let names: Vec<String> = BUILTIN
                    .iter()
                    .map(|(n, _)| format!("{BUILTIN_PREFIX}{n}"))
                    .collect();
                return Err(CoreError::format(
                    &what,
                    format!(
                        "no mesh of that name is shipped (there are {})",
                        names.join(", ")
                    ),
                ));
            };
            let mesh = read_obj(&mut std::io::Cursor::new(text.as_bytes()), &what)?;
            mesh.check(&what)?;
            return Ok(mesh.placed(placement));
        }
        let file = std::fs::File::open(path).map_err(|e| CoreError::io(path, e))?;
        let mut reader = BufReader::new(file);
        let mesh = match ext.as_str() {
            "obj" => read_obj(&mut reader, &what)?,
            "stl" => read_stl(&mut reader, &what)?,
            "ply" => read_ply(&mut reader, &what)?,
            _ => {
                return Err(CoreError::format(
                    &what,
                    "a mesh is read from .obj, .stl or .ply".to_string(),
                ))
            }
        };
        mesh.check(&what)?;
        Ok(mesh.placed(placement))
    }

    /// Refuses what is not a surface, naming the place in the file.
    pub fn check(&self, what: &str) -> Result<()> {
        let bad = |reason: String| Err(CoreError::format(what, reason));
        if self.triangles.is_empty() {
            return bad("the mesh holds no triangles".into());
        }
        if let Some((i, v)) = self
            .positions
            .iter()
            .enumerate()
            .find(|(_, v)| v.iter().any(|c| !c.is_finite()))
        {
            return bad(format!("vertex {i} is not a number: {v:?}"));
        }
        let n = self.positions.len() as u32;
        if let Some((i, t)) = self
            .triangles
            .iter()
            .enumerate()
            .find(|(_, t)| t.iter().any(|&k| k >= n))
        {
            return bad(format!(
                "triangle {i} names vertex {:?}, and the mesh has {n} vertices",
                t
            ));
        }
        // Edges by welded position: files repeat a vertex per face (STL always does).
        let weld = self.welded();
        let mut edges: HashMap<(u32, u32), u32> = HashMap::new();
        for t in &self.triangles {
            let w = t.map(|k| weld[k as usize]);
            if w[0] == w[1] || w[1] == w[2] || w[0] == w[2] {
                continue;
            }
            for (a, b) in [(w[0], w[1]), (w[1], w[2]), (w[2], w[0])] {
                *edges.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        if let Some(((a, b), count)) = edges.iter().find(|(_, c)| **c > 2) {
            return bad(format!(
                "not a surface: the edge from {:?} to {:?} is shared by {count} triangles (at most two share an edge of a manifold mesh)",
                self.positions[*a as usize], self.positions[*b as usize]
            ));
        }
        Ok(())
    }

    /// Each vertex's first vertex at the same position.
    fn welded(&self) -> Vec<u32> {
        let mut first: HashMap<[u64; 3], u32> = HashMap::new();
        self.positions
            .iter()
            .enumerate()
            .map(|(i, p)| *first.entry(p.map(f64::to_bits)).or_insert(i as u32))
            .collect()
    }

    /// The mesh in the world: scaled to metres, rotated, moved.
    pub fn placed(mut self, p: &Placement) -> Mesh {
        let r = rotation(p.rotation_deg);
        let s = p.units.metres();
        let turn = |v: Vec3| [0, 1, 2].map(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2]);
        for v in &mut self.positions {
            let t = turn(v.map(|c| c * s));
            *v = [0, 1, 2].map(|i| t[i] + p.position[i]);
        }
        if let Some(normals) = &mut self.corner_normals {
            for corners in normals {
                for n in corners.iter_mut() {
                    *n = normalize(turn(*n));
                }
            }
        }
        self
    }

    /// The smallest box that holds it: (min, max).
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in &self.positions {
            for c in 0..3 {
                lo[c] = lo[c].min(p[c]);
                hi[c] = hi[c].max(p[c]);
            }
        }
        (lo, hi)
    }

    /// A triangle's corners.
    pub fn corners(&self, t: usize) -> [Vec3; 3] {
        self.triangles[t].map(|k| self.positions[k as usize])
    }

    /// The surface normal at barycentric (u, v) of triangle `t`: the file's normals
    /// interpolated, or the face's, oriented like the file's (or the winding's).
    pub(crate) fn normal_at(&self, t: usize, u: f64, v: f64) -> Vec3 {
        let [a, b, c] = self.corners(t);
        let face = normalize(cross(sub(b, a), sub(c, a)));
        match &self.corner_normals {
            Some(n) => {
                let [na, nb, nc] = n[t];
                let w = 1.0 - u - v;
                let m = [0, 1, 2].map(|i| w * na[i] + u * nb[i] + v * nc[i]);
                let len = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
                if len > 1e-9 {
                    m.map(|x| x / len)
                } else {
                    face
                }
            }
            None => face,
        }
    }
}

/// Rotation matrix for rotations about X, then Y, then Z (degrees): R = Rz·Ry·Rx.
pub fn rotation(deg: Vec3) -> [[f64; 3]; 3] {
    let [(sx, cx), (sy, cy), (sz, cz)] = deg.map(|d| d.to_radians().sin_cos());
    [
        [cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx],
        [sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx],
        [-sy, cy * sx, cy * cx],
    ]
}

fn read_obj(reader: &mut impl std::io::BufRead, what: &str) -> Result<Mesh> {
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
    };
    // Materials are the estimate's business, not the file's: a missing .mtl is no error.
    let (models, _) =
        tobj::load_obj_buf(reader, &options, |_| Err(tobj::LoadError::OpenFileFailed))
            .map_err(|e| CoreError::format(what, format!("OBJ: {e}")))?;
    let mut mesh = Mesh {
        positions: Vec::new(),
        triangles: Vec::new(),
        corner_normals: Some(Vec::new()),
    };
    for m in models {
        let m = m.mesh;
        let base = mesh.positions.len() as u32;
        mesh.positions.extend(
            m.positions
                .chunks_exact(3)
                .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64]),
        );
        let normals: Vec<Vec3> = m
            .normals
            .chunks_exact(3)
            .map(|n| [n[0] as f64, n[1] as f64, n[2] as f64])
            .collect();
        let has_normals = m.normal_indices.len() == m.indices.len() && !normals.is_empty();
        for (f, t) in m.indices.chunks_exact(3).enumerate() {
            mesh.triangles.push([base + t[0], base + t[1], base + t[2]]);
            let corners = has_normals.then(|| {
                [0, 1, 2].map(|k| {
                    normals
                        .get(m.normal_indices[3 * f + k] as usize)
                        .copied()
                        .unwrap_or([0.0; 3])
                })
            });
            match (&mut mesh.corner_normals, corners) {
                (Some(n), Some(c)) => n.push(c),
                // One model without normals makes the whole mesh flat-shaded.
                (n, None) => *n = None,
                _ => {}
            }
        }
    }
    Ok(mesh)
}

fn read_stl(reader: &mut (impl std::io::Read + std::io::Seek), what: &str) -> Result<Mesh> {
    let stl = stl_io::read_stl(reader).map_err(|e| CoreError::format(what, format!("STL: {e}")))?;
    Ok(Mesh {
        positions: stl.vertices.iter().map(|v| v.0.map(|c| c as f64)).collect(),
        triangles: stl
            .faces
            .iter()
            .map(|f| f.vertices.map(|k| k as u32))
            .collect(),
        // STL's facet normals are often wrong or zero: the winding is what counts.
        corner_normals: None,
    })
}

fn read_ply(reader: &mut impl std::io::BufRead, what: &str) -> Result<Mesh> {
    use ply_rs_bw::ply::Property;
    let parser = ply_rs_bw::parser::Parser::<ply_rs_bw::ply::DefaultElement>::new();
    let ply = parser
        .read_ply(reader)
        .map_err(|e| CoreError::format(what, format!("PLY: {e}")))?;
    let number = |p: Option<&Property>| -> Option<f64> {
        Some(match p? {
            Property::Float(v) => *v as f64,
            Property::Double(v) => *v,
            Property::Int(v) => *v as f64,
            Property::UInt(v) => *v as f64,
            Property::Short(v) => *v as f64,
            Property::UShort(v) => *v as f64,
            Property::Char(v) => *v as f64,
            Property::UChar(v) => *v as f64,
            _ => return None,
        })
    };
    let vertices = ply.payload.get("vertex").map(Vec::as_slice).unwrap_or(&[]);
    let mut positions = Vec::with_capacity(vertices.len());
    let mut normals = Vec::with_capacity(vertices.len());
    for (i, v) in vertices.iter().enumerate() {
        let p = ["x", "y", "z"].map(|k| number(v.get(k)));
        let [Some(x), Some(y), Some(z)] = p else {
            return Err(CoreError::format(
                what,
                format!("PLY: vertex {i} has no numeric x, y and z"),
            ));
        };
        positions.push([x, y, z]);
        if let [Some(a), Some(b), Some(c)] = ["nx", "ny", "nz"].map(|k| number(v.get(k))) {
            normals.push([a, b, c]);
        }
    }
    let faces = ply.payload.get("face").map(Vec::as_slice).unwrap_or(&[]);
    let mut triangles = Vec::with_capacity(faces.len());
    for (i, f) in faces.iter().enumerate() {
        let list = f.get("vertex_indices").or_else(|| f.get("vertex_index"));
        let idx: Vec<i64> = match list {
            Some(Property::ListInt(v)) => v.iter().map(|&k| k as i64).collect(),
            Some(Property::ListUInt(v)) => v.iter().map(|&k| k as i64).collect(),
            Some(Property::ListShort(v)) => v.iter().map(|&k| k as i64).collect(),
            Some(Property::ListUShort(v)) => v.iter().map(|&k| k as i64).collect(),
            Some(Property::ListChar(v)) => v.iter().map(|&k| k as i64).collect(),
            Some(Property::ListUChar(v)) => v.iter().map(|&k| k as i64).collect(),
            _ => {
                return Err(CoreError::format(
                    what,
                    format!("PLY: face {i} has no vertex_indices list"),
                ))
            }
        };
        if idx.len() < 3 || idx.iter().any(|&k| k < 0 || k > u32::MAX as i64) {
            return Err(CoreError::format(
                what,
                format!("PLY: face {i} is not a polygon of vertex indices: {idx:?}"),
            ));
        }
        // A polygon as a fan: the files brdfd reads hold triangles and convex quads.
        for k in 1..idx.len() - 1 {
            triangles.push([idx[0] as u32, idx[k] as u32, idx[k + 1] as u32]);
        }
    }
    let corner_normals = (normals.len() == positions.len() && !normals.is_empty()).then(|| {
        triangles
            .iter()
            .map(|t| t.map(|k| normals.get(k as usize).copied().unwrap_or([0.0; 3])))
            .collect()
    });
    Ok(Mesh {
        positions,
        triangles,
        corner_normals,
    })
}

/// A mesh whose corner normals are its vertices' `normals`.
fn with_vertex_normals(positions: Vec<Vec3>, triangles: Vec<[u32; 3]>, normals: &[Vec3]) -> Mesh {
    let corner_normals = Some(
        triangles
            .iter()
            .map(|t| t.map(|k| normals[k as usize]))
            .collect(),
    );
    Mesh {
        positions,
        triangles,
        corner_normals,
    }
}

/// A UV sphere of `rings` × `segments` quads, with its exact normals at the vertices: the
/// analytic sphere as a mesh, for tests and the virtual bench.
pub fn uv_sphere(center: Vec3, radius: f64, rings: usize, segments: usize) -> Mesh {
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    for i in 0..=rings {
        let theta = std::f64::consts::PI * i as f64 / rings as f64;
        for j in 0..segments {
            let phi = 2.0 * std::f64::consts::PI * j as f64 / segments as f64;
            let n = [
                theta.sin() * phi.cos(),
                theta.cos(),
                theta.sin() * phi.sin(),
            ];
            normals.push(n);
            positions.push([0, 1, 2].map(|c| center[c] + radius * n[c]));
        }
    }
    let at = |i: usize, j: usize| (i * segments + j % segments) as u32;
    let mut triangles = Vec::new();
    for i in 0..rings {
        for j in 0..segments {
            let (a, b, c, d) = (at(i, j), at(i, j + 1), at(i + 1, j), at(i + 1, j + 1));
            // Outward winding: (b − a) × (c − a) points away from the centre.
            if i > 0 {
                triangles.push([a, b, c]);
            }
            if i + 1 < rings {
                triangles.push([b, d, c]);
            }
        }
    }
    with_vertex_normals(positions, triangles, &normals)
}

/// A plate `width` × `length` (X × Y, metres), top face up (+Z) at z = 0, with `grooves`
/// V-grooves along Y of depth `depth`, one in the middle half of each of `grooves` equal
/// bands: a heightfield of `nx` × `ny` cells (`nx` a multiple of 4 × `grooves`, so that the
/// grooves' rims and bottoms are vertices), two triangles each. The concave test part of
/// the occlusion tests and of `brdfd bench`, with flat faces (no vertex normals).
pub fn grooved_plate(
    width: f64,
    length: f64,
    grooves: usize,
    depth: f64,
    nx: usize,
    ny: usize,
) -> Mesh {
    assert!(grooves > 0 && nx.is_multiple_of(4 * grooves) && ny > 0);
    let band = width / grooves as f64;
    let height = |x: f64| {
        // Distance from the nearest groove's centre line, in quarter bands.
        let from = (((x + width / 2.0) / band).fract() - 0.5).abs() * 4.0;
        if from < 1.0 {
            -depth * (1.0 - from)
        } else {
            0.0
        }
    };
    let mut positions = Vec::with_capacity((nx + 1) * (ny + 1));
    for j in 0..=ny {
        let y = -length / 2.0 + length * j as f64 / ny as f64;
        for i in 0..=nx {
            let x = -width / 2.0 + width * i as f64 / nx as f64;
            positions.push([x, y, height(x)]);
        }
    }
    let at = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
    let mut triangles = Vec::with_capacity(2 * nx * ny);
    for j in 0..ny {
        for i in 0..nx {
            // Counter-clockwise seen from +Z: the faces point up.
            triangles.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            triangles.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    Mesh {
        positions,
        triangles,
        corner_normals: None,
    }
}

/// A hemispherical bowl: the half of a sphere of `radius` about the origin below z = 0,
/// open upward, in `rings` × `segments` quads, with the sphere's exact normals (inward).
pub fn bowl(radius: f64, rings: usize, segments: usize) -> Mesh {
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    for i in 0..=rings {
        // From the rim (polar angle π/2 from the bottom) down to the bottom.
        let theta = std::f64::consts::FRAC_PI_2 * (1.0 - i as f64 / rings as f64);
        for j in 0..segments {
            let phi = 2.0 * std::f64::consts::PI * j as f64 / segments as f64;
            let p = [
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                -theta.cos(),
            ];
            normals.push(p.map(|c| -c));
            positions.push(p.map(|c| radius * c));
        }
    }
    let at = |i: usize, j: usize| (i * segments + j % segments) as u32;
    let mut triangles = Vec::new();
    for i in 0..rings {
        for j in 0..segments {
            let (a, b, c, d) = (at(i, j), at(i, j + 1), at(i + 1, j), at(i + 1, j + 1));
            triangles.push([a, c, b]);
            // The last ring is the bottom point, repeated: one triangle per segment there.
            if i + 1 < rings {
                triangles.push([b, c, d]);
            }
        }
    }
    with_vertex_normals(positions, triangles, &normals)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_meshes_are_compiled_in_as_their_files() {
        let placement = Placement {
            units: Units::Mm,
            rotation_deg: [-25.0, 0.0, 0.0],
            position: [0.0; 3],
        };
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/geometry");
        for (name, _) in BUILTIN {
            let built_in = Mesh::read(Path::new(&format!("builtin:{name}")), &placement).unwrap();
            assert_eq!(
                built_in,
                Mesh::read(&dir.join(name), &placement).unwrap(),
                "{name}"
            );
        }
        let err = Mesh::read(Path::new("builtin:teapot.obj"), &placement).unwrap_err();
        assert!(
            err.to_string().contains("builtin:grooved-block.obj"),
            "{err}"
        );
    }

    fn tetrahedron() -> Mesh {
        Mesh {
            positions: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
            ],
            triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
            corner_normals: None,
        }
    }

    #[test]
    fn what_is_not_a_surface_is_refused_by_place() {
        tetrahedron().check("t").unwrap();
        let mut m = tetrahedron();
        m.triangles.clear();
        assert!(m
            .check("t")
            .unwrap_err()
            .to_string()
            .contains("no triangles"));
        let mut m = tetrahedron();
        m.positions[2][1] = f64::NAN;
        assert!(m
            .check("t")
            .unwrap_err()
            .to_string()
            .contains("vertex 2 is not a number"));
        let mut m = tetrahedron();
        m.triangles[1] = [0, 1, 9];
        assert!(m
            .check("t")
            .unwrap_err()
            .to_string()
            .contains("triangle 1 names vertex"));
        // A fin: a third triangle on the edge 0–1.
        let mut m = tetrahedron();
        m.positions.push([0.5, -1.0, 0.0]);
        m.triangles.push([0, 1, 4]);
        let e = m.check("t").unwrap_err().to_string();
        assert!(e.contains("shared by 3 triangles"), "{e}");
    }

    #[test]
    fn placement_scales_turns_and_moves() {
        let m = tetrahedron().placed(&Placement {
            units: Units::Mm,
            rotation_deg: [0.0, 90.0, 0.0],
            position: [1.0, 2.0, 3.0],
        });
        // (1 mm, 0, 0) turned 90° about +Y goes to (0, 0, −1 mm).
        let p = m.positions[1];
        for (got, want) in p.iter().zip([1.0, 2.0, 3.0 - 0.001]) {
            assert!((got - want).abs() < 1e-12, "{p:?}");
        }
    }

    #[test]
    fn a_sphere_mesh_has_outward_normals_and_is_a_closed_surface() {
        let s = uv_sphere([0.0; 3], 1.0, 16, 32);
        s.check("sphere").unwrap();
        for t in 0..s.triangles.len() {
            let [a, b, c] = s.corners(t);
            let face = normalize(cross(sub(b, a), sub(c, a)));
            let centre = [0, 1, 2].map(|i| (a[i] + b[i] + c[i]) / 3.0);
            assert!(
                super::super::brdf::dot(face, centre) > 0.0,
                "triangle {t} faces in"
            );
        }
    }
}
