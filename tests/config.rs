//! Every file shipped in `config/` loads.

use brdfd::core::geometry::SceneGeometry;

#[test]
fn every_shipped_geometry_loads_and_sees_the_object() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/geometry");
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let g = SceneGeometry::read(&path).unwrap_or_else(|e| panic!("{e}"));
        // At a tenth of the resolution, so the D5100 file does not cast 16 million rays.
        let (w, h) = g.camera.size();
        let px = g.pixels(w / 10, h / 10).unwrap();
        assert!(
            px.pixels.len() > (w / 10) * (h / 10) / 50,
            "{}: object covers {} pixels",
            path.display(),
            px.pixels.len()
        );
        n += 1;
    }
    assert!(n >= 2);
}
