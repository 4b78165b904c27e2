//! A rig file opened to be written by a calibration: its comments and layout kept, only the
//! values the calibration measured changed, the file before kept beside it.

use std::path::{Path, PathBuf};

use anyhow::Context as _;
use brdfd_rig::config::Rig;
use toml_edit::DocumentMut;

pub struct RigFile {
    pub path: PathBuf,
    pub doc: DocumentMut,
}

impl RigFile {
    pub fn open(path: &Path) -> anyhow::Result<RigFile> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let doc: DocumentMut = text
            .parse()
            .with_context(|| format!("{} is not TOML", path.display()))?;
        Ok(RigFile {
            path: path.to_path_buf(),
            doc,
        })
    }

    /// Writes the document in place, atomically, once the rig as written parses. The file
    /// before is kept beside it as FILE.bak (FILE.bak.1 and on, if that is taken); its path
    /// is returned.
    pub fn save(self) -> anyhow::Result<PathBuf> {
        let written = self.doc.to_string();
        let file = self.path.display().to_string();
        let rig = Rig::parse(&file, &written).context("the rig as written")?;
        let backup = (0..)
            .map(|i| match i {
                0 => PathBuf::from(format!("{file}.bak")),
                i => PathBuf::from(format!("{file}.bak.{i}")),
            })
            .find(|p| !p.exists())
            .context("no name for the backup")?;
        std::fs::copy(&self.path, &backup)
            .with_context(|| format!("keeping {}", backup.display()))?;
        brdfd_rig::session::write_atomic(&self.path, written.as_bytes())?;
        if let Err(e) = brdfd_rig::plan::check(&rig) {
            eprintln!("  warning: the rig is not ready to capture yet: {e}");
        }
        Ok(backup)
    }
}
