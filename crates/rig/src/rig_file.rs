//! A rig file opened to be written by a calibration: its comments and layout kept, only the
//! values the calibration measured changed, the file before kept beside it.

use std::path::{Path, PathBuf};

use brdfd_core::geometry::{Camera, Shape};
use toml_edit::{value, Array, DocumentMut, Item};

use crate::config::Rig;
pub use crate::error::RigFileError;

pub struct RigFile {
    pub path: PathBuf,
    pub doc: DocumentMut,
}

/// A rig file written: where the file before went, and why the rig cannot capture yet, if
/// it cannot (a calibration may be one step of several).
pub struct Saved {
    pub backup: PathBuf,
    pub not_ready: Option<String>,
}

impl RigFile {
    pub fn open(path: &Path) -> Result<RigFile, RigFileError> {
        let text = std::fs::read_to_string(path).map_err(|source| RigFileError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let doc: DocumentMut = text.parse().map_err(|source| RigFileError::NotToml {
            path: path.to_path_buf(),
            source,
        })?;
        Ok(RigFile {
            path: path.to_path_buf(),
            doc,
        })
    }

    /// The file, opened to be written by a calibration that fills the given tables of
    /// `[geometry]` (`("camera", "pose")`: the table, and what goes into it): each must be
    /// there, so that a file the calibration cannot go into is said before anything is shot.
    pub(crate) fn open_for(path: &Path, tables: &[(&str, &str)]) -> Result<RigFile, RigFileError> {
        let file = RigFile::open(path)?;
        for (table, what) in tables {
            let found = file
                .doc
                .get("geometry")
                .and_then(|g| g.get(table))
                .and_then(Item::as_table_like);
            if found.is_none() {
                return Err(RigFileError::NoTable {
                    path: path.to_path_buf(),
                    table: table.to_string(),
                    what: what.to_string(),
                });
            }
        }
        Ok(file)
    }

    /// Writes the document in place, atomically, once the rig as written parses. The file
    /// before is kept beside it as FILE.bak (FILE.bak.1 and on, if that is taken).
    pub fn save(self) -> Result<Saved, RigFileError> {
        let written = self.doc.to_string();
        let file = self.path.display().to_string();
        let rig = Rig::parse(&file, &written).map_err(RigFileError::Written)?;
        // The first name free: the search ends, as the folder holds finitely many files.
        let backup = (0..)
            .map(|i| match i {
                0 => PathBuf::from(format!("{file}.bak")),
                i => PathBuf::from(format!("{file}.bak.{i}")),
            })
            .find(|p| !p.exists())
            .expect("a free name among endless ones");
        std::fs::copy(&self.path, &backup).map_err(|source| RigFileError::Backup {
            path: backup.clone(),
            source,
        })?;
        crate::session::write_atomic(&self.path, written.as_bytes())?;
        Ok(Saved {
            backup,
            not_ready: crate::plan::check(&rig).err().map(|e| e.to_string()),
        })
    }

    /// Sets the camera's pose and focal lengths in `[geometry.camera]`, with a comment that
    /// says where they came from; the rest of the file as it was.
    pub(crate) fn set_camera(&mut self, camera: &Camera, note: &str) -> Result<(), RigFileError> {
        let Camera::Pinhole { fx, fy, pose, .. } = camera else {
            return Err(RigFileError::NotPinhole);
        };
        let round = |x: f64| (x * 100.0).round() / 100.0;
        self.write_geometry(
            "camera",
            "pose",
            &[
                ("fx", value(round(*fx))),
                ("fy", value(round(*fy))),
                ("position", array(pose.position)),
                ("look_at", array(pose.look_at)),
                ("up", array(pose.up)),
            ],
            &format!("fx, fy, position, look_at and up {note}"),
        )
    }

    /// Sets the mesh's `position` and `rotation_deg` in `[geometry.shape]` to where its
    /// silhouette placed it, with a comment that says so.
    pub(crate) fn set_shape(&mut self, placed: &Shape) -> Result<(), RigFileError> {
        let Shape::Mesh {
            rotation_deg,
            position,
            ..
        } = placed
        else {
            return Err(RigFileError::NotMesh);
        };
        // Hundredths of a degree and hundredths of a millimetre: finer than a silhouette pins.
        let rounded = |v: [f64; 3], decimals: usize| {
            array(v.map(|x| format!("{x:.decimals$}").parse::<f64>().expect("a number") + 0.0))
        };
        self.write_geometry(
            "shape",
            "placement",
            &[
                ("rotation_deg", rounded(*rotation_deg, 2)),
                ("position", rounded(*position, 5)),
            ],
            &format!(
                "rotation_deg and position from the object's silhouette, by `brdfd calibrate pose --refine-object` on {}",
                humantime::format_rfc3339_seconds(std::time::SystemTime::now())
            ),
        )
    }

    /// Sets `values` in `[geometry.TABLE]` (which holds the calibration's `what`), with
    /// `comment` above the first of them; an inline table holds no comment.
    fn write_geometry(
        &mut self,
        table: &str,
        what: &str,
        values: &[(&str, Item)],
        comment: &str,
    ) -> Result<(), RigFileError> {
        let item = self
            .doc
            .get_mut("geometry")
            .and_then(|g| g.get_mut(table))
            .ok_or_else(|| RigFileError::NoTable {
                path: self.path.clone(),
                table: table.into(),
                what: what.into(),
            })?;
        let is_table = item.is_table();
        let t = item
            .as_table_like_mut()
            .ok_or_else(|| RigFileError::NotATable {
                path: self.path.clone(),
                table: table.into(),
            })?;
        for (key, v) in values {
            t.insert(key, v.clone());
        }
        if let (true, Some((first, _))) = (is_table, values.first()) {
            if let Some(mut key) = t.key_mut(first) {
                key.leaf_decor_mut().set_prefix(format!("# {comment}.\n"));
            }
        }
        Ok(())
    }
}

/// Three numbers as a TOML array.
fn array(v: [f64; 3]) -> Item {
    let mut a = Array::new();
    for x in v {
        a.push(x);
    }
    value(a)
}
