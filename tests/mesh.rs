//! Issue 22, item 1: meshes of the object, read from OBJ, STL and PLY files and rasterised
//! from the object camera, against the analytic shapes they approximate.

use std::io::Write;

use brdfd_core::brdf::{dot, Vec3};
use brdfd_core::geometry::{scale_warning, Camera, PixelGeometry, SceneGeometry, Shape};
use brdfd_core::mesh::{uv_sphere, Mesh, Placement, Units};

/// The tolerance: a sphere mesh's interpolated normals against the sphere's, at 256².
const NORMAL_TOLERANCE_DEG: f64 = 0.5;

/// A unit UV sphere fine enough for that tolerance between its vertices (its chords are
/// 1.4° long: the normal interpolated across one errs by far less).
fn sphere() -> Mesh {
    uv_sphere([0.0; 3], 1.0, 128, 256)
}

fn obj_text(m: &Mesh) -> String {
    let mut s = String::from("# a UV sphere\n");
    for p in &m.positions {
        s += &format!("v {} {} {}\n", p[0], p[1], p[2]);
    }
    let normals = m.corner_normals.as_ref().unwrap();
    for corners in normals {
        for n in corners {
            s += &format!("vn {} {} {}\n", n[0], n[1], n[2]);
        }
    }
    for (i, t) in m.triangles.iter().enumerate() {
        let k = 3 * i + 1;
        s += &format!(
            "f {}//{} {}//{} {}//{}\n",
            t[0] + 1,
            k,
            t[1] + 1,
            k + 1,
            t[2] + 1,
            k + 2
        );
    }
    s
}

fn angle_deg(a: [f32; 3], b: [f32; 3]) -> f64 {
    let d = a
        .iter()
        .zip(b)
        .map(|(x, y)| *x as f64 * y as f64)
        .sum::<f64>();
    d.clamp(-1.0, 1.0).acos().to_degrees()
}

#[test]
fn a_sphere_mesh_rasterises_as_the_sphere_does() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sphere.obj");
    std::fs::write(&path, obj_text(&sphere())).unwrap();
    let camera = Camera::eval_orthographic(256);
    let analytic = PixelGeometry::rasterize(&camera, &Shape::unit_sphere()).unwrap();
    let mesh = PixelGeometry::rasterize(
        &camera,
        &Shape::Mesh {
            file: path,
            units: Units::M,
            rotation_deg: [0.0; 3],
            position: [0.0; 3],
        },
    )
    .unwrap();
    let by_place: std::collections::HashMap<(u32, u32), [f32; 3]> = analytic
        .pixels
        .iter()
        .map(|p| ((p.x, p.y), p.normal))
        .collect();
    let mut worst: f64 = 0.0;
    for p in &mesh.pixels {
        let n = by_place
            .get(&(p.x, p.y))
            .unwrap_or_else(|| panic!("{:?}: on the mesh, not on the sphere", (p.x, p.y)));
        worst = worst.max(angle_deg(p.normal, *n));
    }
    eprintln!(
        "worst normal of {} mesh pixels: {worst:.4}°",
        mesh.pixels.len()
    );
    assert!(worst < NORMAL_TOLERANCE_DEG, "worst normal {worst}°");
    // The same mask but for the edge: what the mesh leaves out is the sphere's outline, and
    // pixels within the normals' tolerance of the grazing limit, which either may drop.
    let kept: std::collections::HashSet<_> = mesh.pixels.iter().map(|p| (p.x, p.y)).collect();
    let mut outline = analytic.clone();
    outline.drop_outline();
    let limit = (brdfd_core::geometry::GRAZING_LIMIT_DEG - NORMAL_TOLERANCE_DEG)
        .to_radians()
        .cos();
    let inner: std::collections::HashSet<_> = outline
        .pixels
        .iter()
        .filter(|p| dot(p.normal.map(f64::from), p.view.map(f64::from)) > limit)
        .map(|p| (p.x, p.y))
        .collect();
    let missing: Vec<_> = inner.difference(&kept).collect();
    assert!(
        missing.is_empty(),
        "inner pixels of the sphere missing on the mesh: {missing:?}"
    );
    assert!(
        analytic.pixels.len() - mesh.pixels.len() <= analytic.pixels.len() / 50,
        "{} of {}",
        mesh.pixels.len(),
        analytic.pixels.len()
    );
}

/// A mesh with four vertices and four faces, in each format, to check that every reader gives
/// the same triangles.
#[test]
fn obj_stl_and_ply_files_give_the_same_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let v: [Vec3; 4] = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
    ];
    let faces = [[0usize, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
    let mut obj = String::new();
    for p in &v {
        obj += &format!("v {} {} {}\n", p[0], p[1], p[2]);
    }
    for f in &faces {
        obj += &format!("f {} {} {}\n", f[0] + 1, f[1] + 1, f[2] + 1);
    }
    std::fs::write(dir.path().join("t.obj"), obj).unwrap();
    let mut ascii = String::from("solid t\n");
    for f in &faces {
        ascii += "facet normal 0 0 0\nouter loop\n";
        for &k in f {
            ascii += &format!("vertex {} {} {}\n", v[k][0], v[k][1], v[k][2]);
        }
        ascii += "endloop\nendfacet\n";
    }
    ascii += "endsolid t\n";
    std::fs::write(dir.path().join("ascii.stl"), ascii).unwrap();
    // Binary STL (80-byte header, a count, 50 bytes a facet), written here byte by byte.
    let mut bin = vec![0u8; 80];
    bin.extend((faces.len() as u32).to_le_bytes());
    for f in &faces {
        bin.extend([0f32; 3].iter().flat_map(|c| c.to_le_bytes()));
        for &k in f {
            bin.extend(v[k].iter().flat_map(|c| (*c as f32).to_le_bytes()));
        }
        bin.extend([0u8; 2]);
    }
    std::fs::write(dir.path().join("binary.stl"), bin).unwrap();
    let mut ply = format!(
        "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        faces.len()
    );
    for p in &v {
        ply += &format!("{} {} {}\n", p[0], p[1], p[2]);
    }
    for f in &faces {
        ply += &format!("3 {} {} {}\n", f[0], f[1], f[2]);
    }
    std::fs::write(dir.path().join("t.ply"), ply).unwrap();
    let placed = Placement {
        units: Units::Mm,
        rotation_deg: [0.0; 3],
        position: [0.0; 3],
    };
    for name in ["t.obj", "ascii.stl", "binary.stl", "t.ply"] {
        let m =
            Mesh::read(&dir.path().join(name), &placed).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(m.triangles.len(), 4, "{name}");
        let corners: Vec<Vec<[i64; 3]>> = (0..4)
            .map(|t| {
                m.corners(t)
                    .iter()
                    .map(|p| p.map(|c| (c * 1e6).round() as i64))
                    .collect()
            })
            .collect();
        // In millimetres: a metre-long edge of the file is a millimetre of the world.
        assert_eq!(
            corners[3],
            vec![[1000, 0, 0], [0, 1000, 0], [0, 0, 1000]],
            "{name}"
        );
    }
}

#[test]
fn bad_meshes_are_refused_with_what_and_where() {
    let dir = tempfile::tempdir().unwrap();
    let placed = Placement {
        units: Units::M,
        rotation_deg: [0.0; 3],
        position: [0.0; 3],
    };
    let read = |name: &str, text: &[u8]| {
        let path = dir.path().join(name);
        std::fs::File::create(&path)
            .unwrap()
            .write_all(text)
            .unwrap();
        Mesh::read(&path, &placed)
            .map(|_| ())
            .unwrap_err()
            .to_string()
    };
    let e = read("empty.obj", b"# nothing\n");
    assert!(e.contains("empty.obj") && e.contains("no triangles"), "{e}");
    let e = read("nan.obj", b"v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n");
    assert!(
        e.contains("nan.obj") && e.contains("vertex 2 is not a number"),
        "{e}"
    );
    let e = read(
        "fin.obj",
        b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 2 5\n",
    );
    assert!(e.contains("shared by 3 triangles"), "{e}");
    // A binary STL that says 10 facets and holds one.
    let mut cut = vec![0u8; 80];
    cut.extend(10u32.to_le_bytes());
    cut.extend([0u8; 50]);
    let e = read("cut.stl", &cut);
    assert!(e.contains("cut.stl") && e.contains("STL"), "{e}");
    let e = read("part.step", b"ISO-10303-21;");
    assert!(e.contains("read from .obj, .stl or .ply"), "{e}");
    // Out of the view: a clear error, not an empty image.
    let path = dir.path().join("far.obj");
    std::fs::write(&path, obj_text(&uv_sphere([50.0, 0.0, 0.0], 1.0, 8, 16))).unwrap();
    let g = SceneGeometry {
        camera: Camera::eval_orthographic(32),
        shape: Some(Shape::Mesh {
            file: path,
            units: Units::M,
            rotation_deg: [0.0; 3],
            position: [0.0; 3],
        }),
        normal_map: None,
    };
    let e = g.pixels(32, 32).unwrap_err().to_string();
    assert!(e.contains("outside the camera's view"), "{e}");
    // A part in millimetres read as metres is 1000 times too big: the size is said.
    let big = uv_sphere([0.0; 3], 500.0, 8, 16);
    let w = scale_warning(&Camera::eval_orthographic(32), &big).unwrap();
    assert!(
        w.contains("1000.0000 m across") && w.contains("units = \"mm\""),
        "{w}"
    );
    assert!(scale_warning(&Camera::eval_orthographic(32), &sphere()).is_none());
}

/// A depth discontinuity drops the pixels on either side: a small sphere in front of a large
/// one keeps neither's pixels along the small one's outline.
#[test]
fn pixels_across_a_depth_discontinuity_are_dropped() {
    let front = uv_sphere([0.0, 0.0, 2.0], 0.3, 32, 64);
    let back = uv_sphere([0.0; 3], 1.0, 64, 128);
    let n = front.positions.len() as u32;
    let both = Mesh {
        positions: [front.positions.clone(), back.positions].concat(),
        triangles: front
            .triangles
            .iter()
            .copied()
            .chain(back.triangles.iter().map(|t| t.map(|k| k + n)))
            .collect(),
        corner_normals: Some(
            [
                front.corner_normals.clone().unwrap(),
                back.corner_normals.unwrap(),
            ]
            .concat(),
        ),
    };
    let camera = Camera::eval_orthographic(128);
    let g = PixelGeometry::of_mesh(&camera, &both).unwrap();
    // The front sphere's outline is a circle of radius 0.3 (19.2 pixels): no kept pixel is
    // within a pixel of it.
    let px = 2.0 / 128.0;
    for p in &g.pixels {
        let (x, y) = ((p.x as f64 + 0.5) * px - 1.0, 1.0 - (p.y as f64 + 0.5) * px);
        let r = (x * x + y * y).sqrt();
        assert!((r - 0.3).abs() > 0.7 * px, "{:?} at r {r}", (p.x, p.y));
        // And each kept pixel's normal is its own sphere's.
        let z = if r < 0.3 {
            (0.09 - r * r).sqrt() / 0.3
        } else {
            (1.0 - r * r).max(0.0).sqrt()
        };
        let want = if r < 0.3 {
            [x / 0.3, y / 0.3, z]
        } else {
            [x, y, z]
        };
        let n = p.normal.map(|c| c as f64);
        assert!(
            dot(n, want) > 0.999,
            "{:?}: {n:?} against {want:?}",
            (p.x, p.y)
        );
    }
}

/// The shipped corrugated sample as a mesh is the analytic corrugated sheet it was made from.
#[test]
fn the_shipped_corrugated_mesh_is_the_analytic_sheet() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/geometry");
    let mesh = SceneGeometry::read(&root.join("corrugated-mesh-d5100.toml")).unwrap();
    let analytic = SceneGeometry::read(&root.join("corrugated-d5100.toml")).unwrap();
    let (w, h) = (4928 / 8, 3264 / 8);
    let m = mesh.pixels(w, h).unwrap();
    let a = analytic.pixels(w, h).unwrap();
    let by_place: std::collections::HashMap<(u32, u32), [f32; 3]> =
        a.pixels.iter().map(|p| ((p.x, p.y), p.normal)).collect();
    let mut angles: Vec<f64> = m
        .pixels
        .iter()
        .filter_map(|p| by_place.get(&(p.x, p.y)).map(|n| angle_deg(p.normal, *n)))
        .collect();
    assert!(
        angles.len() > m.pixels.len() * 9 / 10,
        "{} of {}",
        angles.len(),
        m.pixels.len()
    );
    angles.sort_by(f64::total_cmp);
    let median = angles[angles.len() / 2];
    let worst = angles[angles.len() - 1];
    eprintln!("corrugated mesh against the sheet: median {median:.4}°, worst {worst:.4}°");
    // 150 segments over 100 mm: a chord of a 30 mm period turns the normal by up to 1.5°,
    // and the interpolated normal is exact at the vertices.
    assert!(
        median < 0.1 && worst < 1.0,
        "median {median}°, worst {worst}°"
    );
}
