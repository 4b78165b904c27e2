//! The printed board the camera's pose is found from: a ChArUco board (a checkerboard whose
//! white squares hold ArUco markers, so that every corner found is known by its number, and a
//! board seen in part still counts). `brdfd calibrate target` writes it to print; the board
//! file says what was printed and where it stands on the bench.
//!
//! The detection and the printable files are the `calib-targets` crate's (ChESS corners,
//! marker decoding, SVG and PNG output); what is ours is the board's place in the rig's
//! world, and the conversion of its corners to [`Correspondence`]s.

use calib_targets::aruco::builtins::builtin_dictionary;
use calib_targets::charuco::CharucoParams;
use calib_targets::printable::{
    board_primitives, CharucoTargetSpec, Fill, PageOrientation, PageSize, Primitive,
    PrintableTargetDocument, TargetSpec,
};
use serde::{Deserialize, Serialize};

use super::Correspondence;
use crate::error::{fail, PoseError, Result};
use brdfd_core::brdf::Vec3;

/// A board file: what was printed, and where it stands.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Board {
    /// Squares down the board.
    pub rows: u32,
    /// Squares across the board.
    pub cols: u32,
    /// A square's side as printed, millimetres: measure it on the print (printers scale).
    pub square_mm: f64,
    /// A marker's side over its square's.
    pub marker: f64,
    /// The ArUco dictionary its markers come from (OpenCV's names: `DICT_4X4_50`, ...).
    pub dictionary: String,
    #[serde(default)]
    pub placement: BoardPlacement,
}

/// Where the board stands in the rig's world. Unplaced, it stands upright where the object
/// goes: its centre at the world's origin (on the turntable's axis), its face toward +Z, its
/// rows along +X, its top up (+Y).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoardPlacement {
    /// Where the board's centre is, metres.
    #[serde(default)]
    pub position: Vec3,
    /// Turns about X, then Y, then Z (degrees), as a mesh's `rotation_deg`: `[-90, 0, 0]`
    /// lays the board flat, face up.
    #[serde(default)]
    pub rotation_deg: Vec3,
}

/// Reflectance of the paper and of the ink, for the virtual bench's photos of the board.
pub const PAPER: f64 = 0.85;
pub const INK: f64 = 0.04;

impl Default for Board {
    /// A board for A4 in landscape: 9 × 6 squares of 30 mm (270 × 180 mm), markers of 3/4 of
    /// a square from the 4×4 dictionary (27 markers of its 50).
    fn default() -> Self {
        Board {
            rows: 6,
            cols: 9,
            square_mm: 30.0,
            marker: 0.75,
            dictionary: "DICT_4X4_50".into(),
            placement: BoardPlacement::default(),
        }
    }
}

impl Board {
    /// Whether the board can be drawn and found: its size, marker share and dictionary agree
    /// (a board file's numbers are the user's).
    pub fn check(&self) -> Result<()> {
        self.spec().map(|_| ())
    }

    /// The board as a board file, with comments for the person printing it. Numbers are
    /// written as Rust's `{:?}` writes them, which TOML reads back to the same value: `{}`
    /// wrote 1e300 as 301 digits without a point, an integer too large for TOML.
    pub fn to_toml(&self) -> String {
        let [x, y, z] = self.placement.position;
        let [rx, ry, rz] = self.placement.rotation_deg;
        format!(
            "# A ChArUco board for `brdfd calibrate pose`, written by `brdfd calibrate target`.\n\
             # Print board.svg (or board.png, at 300 dpi) at 100% (no \"fit to page\"), glue it\n\
             # flat to stiff card, measure one square and put its side here if it is not {sq} mm.\n\
             rows = {rows}\n\
             cols = {cols}\n\
             square_mm = {sq:?}\n\
             marker = {marker:?}\n\
             dictionary = \"{dict}\"\n\
             \n\
             # Where the board stands in the rig's world when it is photographed: its centre\n\
             # (metres), and its turns about X, then Y, then Z (degrees). As written: upright\n\
             # where the object goes, its centre on the turntable's axis at the object's\n\
             # centre, facing the camera's side (+Z), its rows level.\n\
             [placement]\n\
             position = [{x:?}, {y:?}, {z:?}]\n\
             rotation_deg = [{rx:?}, {ry:?}, {rz:?}]\n",
            rows = self.rows,
            cols = self.cols,
            sq = self.square_mm,
            marker = self.marker,
            dict = self.dictionary,
        )
    }

    fn spec(&self) -> Result<CharucoTargetSpec> {
        if self.rows < 3 || self.cols < 3 {
            fail!(
                Board,
                "a board needs 3 squares each way at least, not {} × {}",
                self.cols,
                self.rows
            );
        }
        if !(self.square_mm.is_finite() && self.square_mm > 0.0) {
            fail!(
                Board,
                "square_mm must be a positive number, not {}",
                self.square_mm
            );
        }
        if !(self.marker > 0.0 && self.marker < 1.0) {
            fail!(
                Board,
                "marker is a marker's side over its square's, between 0 and 1, not {}",
                self.marker
            );
        }
        // Read from a board file, a NaN or infinite placement would put every corner of the
        // board nowhere, and the pose solved from them with it.
        let BoardPlacement {
            position,
            rotation_deg,
        } = self.placement;
        if !position.iter().chain(&rotation_deg).all(|v| v.is_finite()) {
            fail!(
                Board,
                "the board's placement must be numbers: position {position:?}, rotation_deg {rotation_deg:?}"
            );
        }
        let dictionary = builtin_dictionary(&self.dictionary).ok_or_else(|| {
            PoseError::Board(format!(
                "dictionary {:?} is not one brdfd knows (OpenCV's names, such as DICT_4X4_50)",
                self.dictionary
            ))
        })?;
        // Counted in u64: a board file's rows × cols can overflow u32.
        let markers = (self.rows as u64 * self.cols as u64 / 2) as usize;
        if markers > dictionary.codes().len() {
            fail!(
                Board,
                "{} × {} squares need {markers} markers, and {} has {}",
                self.cols,
                self.rows,
                self.dictionary,
                dictionary.codes().len()
            );
        }
        Ok(CharucoTargetSpec::new(
            self.rows,
            self.cols,
            self.square_mm,
            self.marker,
            dictionary,
        ))
    }

    /// The board's width and height, millimetres.
    pub fn size_mm(&self) -> (f64, f64) {
        (
            self.cols as f64 * self.square_mm,
            self.rows as f64 * self.square_mm,
        )
    }

    /// A point of the board (millimetres from its top-left corner, x across, y down) in the
    /// world.
    pub fn world(&self, mm: [f64; 2]) -> Vec3 {
        let (w, h) = self.size_mm();
        let local = [(mm[0] - w / 2.0) / 1000.0, (h / 2.0 - mm[1]) / 1000.0, 0.0];
        let r = brdfd_core::mesh::rotation(self.placement.rotation_deg);
        let p = self.placement.position;
        [0, 1, 2].map(|i| r[i][0] * local[0] + r[i][1] * local[1] + p[i])
    }

    /// The board's face normal in the world.
    pub fn normal(&self) -> Vec3 {
        let r = brdfd_core::mesh::rotation(self.placement.rotation_deg);
        [r[0][2], r[1][2], r[2][2]]
    }

    /// The files to print: SVG and PNG (300 dpi) of the board on the smallest of A4 and A3
    /// (in landscape) that holds it.
    pub fn printable(&self) -> Result<(String, Vec<u8>)> {
        let spec = self.spec()?;
        let (w, h) = self.size_mm();
        let mut doc = PrintableTargetDocument::new(TargetSpec::Charuco(spec));
        doc.page.orientation = PageOrientation::Landscape;
        doc.page.size = if w <= 277.0 && h <= 190.0 {
            PageSize::A4
        } else {
            PageSize::Custom {
                width_mm: 297.0,
                height_mm: 420.0,
            }
        };
        let bundle = calib_targets::printable::render_target_bundle(&doc).map_err(|e| {
            PoseError::Drawing {
                what: "the board does not fit an A3 page",
                reason: e.to_string(),
            }
        })?;
        Ok((bundle.svg_text, bundle.png_bytes))
    }

    /// The board's corners in a photo (8-bit grey), with their places in the world. A photo
    /// where no board is found is an error that says so.
    pub fn detect(&self, photo: &image::GrayImage) -> Result<Vec<Correspondence>> {
        let spec = self.spec()?.to_board_spec();
        let params = CharucoParams::for_board(spec);
        let found = calib_targets::detect::detect_charuco(photo, &params).map_err(|e| {
            PoseError::BoardNotFound(format!(
                "no {} × {} ChArUco board ({}) found in the {}×{} photo ({e}): is the board in the frame, flat, lit evenly and in focus?",
                self.cols,
                self.rows,
                self.dictionary,
                photo.width(),
                photo.height()
            ))
        })?;
        let mut corners: Vec<Correspondence> = found
            .corners
            .iter()
            .map(|c| Correspondence {
                world: self.world([c.target_position.x as f64, c.target_position.y as f64]),
                // The detector puts pixel centres on whole numbers; ours are at + 0.5.
                pixel: [c.position.x as f64 + 0.5, c.position.y as f64 + 0.5],
            })
            .collect();
        refine_corners(photo, &mut corners, self.square_mm / 1000.0, self.marker);
        Ok(corners)
    }

    /// The board's pattern as reflectance, for rendering photos of it.
    pub fn pattern(&self) -> Result<Pattern> {
        let spec = self.spec()?;
        let primitives =
            board_primitives(&TargetSpec::Charuco(spec)).map_err(|e| PoseError::Drawing {
                what: "drawing the board",
                reason: e.to_string(),
            })?;
        let mut cells = vec![Vec::new(); (self.rows * self.cols) as usize];
        let s = self.square_mm;
        for p in primitives {
            let Primitive::Rect {
                x_mm,
                y_mm,
                width_mm,
                height_mm,
                fill,
            } = p
            else {
                fail!(Board, "the board has a shape other than a rectangle: {p:?}");
            };
            let rect = [x_mm, y_mm, x_mm + width_mm, y_mm + height_mm];
            let ink = matches!(fill, Fill::Black);
            let cell_range = |lo: f64, hi: f64, n: u32| {
                let a = ((lo / s).floor().max(0.0) as u32).min(n - 1);
                let b = (((hi / s).ceil() as u32).max(a + 1)).min(n);
                a..b
            };
            for cy in cell_range(rect[1], rect[3], self.rows) {
                for cx in cell_range(rect[0], rect[2], self.cols) {
                    cells[(cy * self.cols + cx) as usize].push((rect, ink));
                }
            }
        }
        Ok(Pattern {
            cols: self.cols,
            rows: self.rows,
            square_mm: s,
            cells,
        })
    }
}

/// Moves each corner to where the image's gradients in a window about it all point across
/// lines through it (the saddle point of the checker: Förstner's operator, as OpenCV's
/// `cornerSubPix`). The detector's corners scatter by about 0.2 px on a sharp rendered
/// board; this brings them to a few hundredths. The window stays inside the white margin
/// around the markers: its half-width is 80% of the margin, from the spacing of the corners
/// in the image.
fn refine_corners(
    photo: &image::GrayImage,
    corners: &mut [Correspondence],
    square_m: f64,
    marker: f64,
) {
    let (w, h) = (photo.width() as i64, photo.height() as i64);
    let value = |x: i64, y: i64| {
        photo
            .get_pixel(x.clamp(0, w - 1) as u32, y.clamp(0, h - 1) as u32)
            .0[0] as f64
    };
    let positions: Vec<([f64; 2], Vec3)> = corners.iter().map(|c| (c.pixel, c.world)).collect();
    for c in corners.iter_mut() {
        // Pixels per metre on the board here, the least over the neighbours a square away:
        // across a slant the margin shrinks in the foreshortened direction.
        let near = positions
            .iter()
            .filter_map(|(px, world)| {
                let d_m = (0..3)
                    .map(|i| (world[i] - c.world[i]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                let d_px = (px[0] - c.pixel[0]).hypot(px[1] - c.pixel[1]);
                (d_m > 0.5 * square_m && d_m < 1.01 * square_m).then_some(d_px / d_m)
            })
            .min_by(f64::total_cmp);
        let Some(px_per_m) = near else { continue };
        let margin_px = (1.0 - marker) / 2.0 * square_m * px_per_m;
        let radius = (0.8 * margin_px).floor() as i64;
        if radius < 2 {
            continue;
        }
        let sigma = radius as f64 / 2.0;
        let start = c.pixel;
        let mut q = start;
        for _ in 0..20 {
            let (cx, cy) = ((q[0] - 0.5).round() as i64, (q[1] - 0.5).round() as i64);
            let (mut a, mut b) = ([0.0f64; 3], [0.0f64; 2]);
            for dy in -radius..=radius {
                for dx in -radius..=radius {
                    let (x, y) = (cx + dx, cy + dy);
                    let gx = (value(x + 1, y) - value(x - 1, y)) / 2.0;
                    let gy = (value(x, y + 1) - value(x, y - 1)) / 2.0;
                    let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                    let r2 = (px - q[0]).powi(2) + (py - q[1]).powi(2);
                    let wgt = (-r2 / (2.0 * sigma * sigma)).exp();
                    let (gxx, gxy, gyy) = (wgt * gx * gx, wgt * gx * gy, wgt * gy * gy);
                    a[0] += gxx;
                    a[1] += gxy;
                    a[2] += gyy;
                    b[0] += gxx * px + gxy * py;
                    b[1] += gxy * px + gyy * py;
                }
            }
            let det = a[0] * a[2] - a[1] * a[1];
            if det.abs() < 1e-9 * (a[0] + a[2]).powi(2).max(1e-30) {
                break;
            }
            let next = [
                (a[2] * b[0] - a[1] * b[1]) / det,
                (a[0] * b[1] - a[1] * b[0]) / det,
            ];
            let moved = (next[0] - q[0]).hypot(next[1] - q[1]);
            q = next;
            if moved < 1e-3 {
                break;
            }
        }
        // A corner that wanders off is the detector's to keep.
        if (q[0] - start[0]).hypot(q[1] - start[1]) < 0.5 * radius as f64 {
            c.pixel = q;
        }
    }
}

/// The board's drawing as reflectance at any point: its rectangles, indexed by square, the
/// last one drawn over a point deciding its colour (as in the SVG).
pub struct Pattern {
    cols: u32,
    rows: u32,
    square_mm: f64,
    cells: Vec<Vec<([f64; 4], bool)>>,
}

impl Pattern {
    /// Reflectance at (x, y) millimetres from the board's top-left corner; `None` off it.
    pub fn at(&self, x: f64, y: f64) -> Option<f64> {
        let (cx, cy) = (x / self.square_mm, y / self.square_mm);
        if !(cx >= 0.0 && cy >= 0.0 && cx < self.cols as f64 && cy < self.rows as f64) {
            return None;
        }
        let cell = &self.cells[cy as usize * self.cols as usize + cx as usize];
        let mut ink = false;
        for (r, black) in cell {
            if x >= r[0] && x < r[2] && y >= r[1] && y < r[3] {
                ink = *black;
            }
        }
        Some(if ink { INK } else { PAPER })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_board_file_reads_back_as_written() {
        let mut b = Board::default();
        b.placement.rotation_deg = [-90.0, 0.0, 0.0];
        b.placement.position = [0.0, 0.01, 0.0];
        let back: Board = toml::from_str(&b.to_toml()).unwrap();
        assert_eq!(back, b);
        // Issue 40 (fuzzing board_files): 1e300 was written as 301 digits, which TOML
        // refuses.
        b.square_mm = 1e300;
        b.placement.position = [1e300, -1e-300, 0.0];
        let back: Board = toml::from_str(&b.to_toml()).unwrap();
        assert_eq!(back, b);
    }

    #[test]
    fn the_board_stands_where_its_placement_says() {
        let b = Board::default();
        // Its top-left corner is up and to the left of the origin, on z = 0.
        assert_eq!(b.world([0.0, 0.0]), [-0.135, 0.09, 0.0]);
        assert_eq!(b.normal(), [0.0, 0.0, 1.0]);
        let mut flat = b.clone();
        flat.placement.rotation_deg = [-90.0, 0.0, 0.0];
        let n = flat.normal();
        assert!((n[1] - 1.0).abs() < 1e-12, "{n:?}");
    }

    #[test]
    fn the_pattern_has_checker_corners_and_markers() {
        let b = Board::default();
        let p = b.pattern().unwrap();
        // The top-left square is black; its right neighbour is white paper with a marker,
        // whose border is ink.
        assert_eq!(p.at(15.0, 15.0), Some(INK));
        assert_eq!(p.at(31.0, 15.0), Some(PAPER));
        assert_eq!(p.at(45.0 - 11.0, 15.0), Some(INK));
        assert_eq!(p.at(-1.0, 15.0), None);
        let (svg, png) = b.printable().unwrap();
        assert!(svg.contains("<svg") && png.starts_with(b"\x89PNG"));
    }

    #[test]
    fn impossible_boards_are_refused() {
        let bad = |f: &dyn Fn(&mut Board)| {
            let mut b = Board::default();
            f(&mut b);
            b.spec().unwrap_err().to_string()
        };
        assert!(bad(&|b| b.dictionary = "DICT_9X9_1".into()).contains("not one brdfd knows"));
        assert!(bad(&|b| b.marker = 1.2).contains("between 0 and 1"));
        assert!(bad(&|b| b.square_mm = f64::NAN).contains("positive"));
        assert!(bad(&|b| b.placement.position[2] = f64::NAN).contains("placement"));
        assert!(bad(&|b| b.placement.rotation_deg[0] = f64::INFINITY).contains("placement"));
        assert!(bad(&|b| {
            b.rows = 12;
            b.cols = 12
        })
        .contains("need 72 markers"));
        // Issue 40: 65,536² overflowed u32 and aborted `calibrate target`.
        assert!(bad(&|b| {
            b.rows = 65_536;
            b.cols = 65_536
        })
        .contains("need 2147483648 markers"));
    }
}
