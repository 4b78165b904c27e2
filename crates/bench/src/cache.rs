//! Renders of the virtual bench kept on disk, so that a second simulated capture of the same
//! scene does not render it again (rendering is most of a simulated capture's time).
//!
//! An entry is keyed by everything the render depends on: the material's table, the map's
//! pixels and yaw, the geometry, the light count, what was rendered, and the brdfd executable
//! itself (its size and modification time), so that a rebuilt renderer never reads an older
//! one's images. Entries are written atomically; one that cannot be read is rendered again.
//! The directory holds at most [`MAX_ENTRIES`] entries; the oldest go first.

use std::io::Write;
use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

use brdfd_core::raster::Raster;

/// `BRDFD_RENDER_CACHE`: a directory to use, or `off`.
pub const ENV: &str = "BRDFD_RENDER_CACHE";
/// Enough for every preset at a few sizes, each render a few MB at most.
pub const MAX_ENTRIES: usize = 200;
const MAGIC: &[u8; 8] = b"brdfdRC1";

#[derive(Clone, Debug, PartialEq)]
pub struct RenderCache {
    pub dir: PathBuf,
}

impl RenderCache {
    /// The user's cache: `BRDFD_RENDER_CACHE` if set (`off` turns caching off), else
    /// `$XDG_CACHE_HOME/brdfd/renders`, else `~/.cache/brdfd/renders`.
    pub fn user() -> Option<RenderCache> {
        let dir = match std::env::var_os(ENV).filter(|v| !v.is_empty()) {
            Some(v) if v == "off" => return None,
            Some(v) => PathBuf::from(v),
            None => std::env::var_os("XDG_CACHE_HOME")
                .filter(|v| !v.is_empty())
                .map(PathBuf::from)
                .or_else(|| std::env::var_os("HOME").map(|h| Path::new(&h).join(".cache")))?
                .join("brdfd/renders"),
        };
        Some(RenderCache { dir })
    }

    /// The cached render for `key`, or `render()`'s, which is then stored. A cache that cannot
    /// be written is only a slower run: the render is returned all the same.
    pub fn get_or_render<E>(
        &self,
        key: &Key,
        render: impl FnOnce() -> Result<Raster, E>,
    ) -> Result<Raster, E> {
        let path = self.dir.join(format!("{}.bin", key.hex()));
        if let Some(r) = read(&path) {
            tracing::debug!(path = %path.display(), "render cache hit");
            return Ok(r);
        }
        let r = render()?;
        if let Err(e) = self.store(&path, &r) {
            tracing::debug!(path = %path.display(), "render cache not written: {e}");
        }
        Ok(r)
    }

    fn store(&self, path: &Path, r: &Raster) -> std::io::Result<()> {
        std::fs::create_dir_all(&self.dir)?;
        let mut tmp = tempfile::NamedTempFile::new_in(&self.dir)?;
        let mut bytes = Vec::with_capacity(24 + r.pixels.len() * 12);
        bytes.extend_from_slice(MAGIC);
        bytes.extend_from_slice(&(r.width as u64).to_le_bytes());
        bytes.extend_from_slice(&(r.height as u64).to_le_bytes());
        for p in &r.pixels {
            for c in p {
                bytes.extend_from_slice(&c.to_le_bytes());
            }
        }
        tmp.write_all(&bytes)?;
        tmp.persist(path)?;
        self.evict(path);
        Ok(())
    }

    /// Keeps the newest [`MAX_ENTRIES`] entries, and always `just_written`.
    fn evict(&self, just_written: &Path) {
        let Ok(dir) = std::fs::read_dir(&self.dir) else {
            return;
        };
        let mut entries: Vec<(std::time::SystemTime, PathBuf)> = dir
            .flatten()
            .filter(|e| e.path().extension().is_some_and(|x| x == "bin"))
            .filter_map(|e| Some((e.metadata().ok()?.modified().ok()?, e.path())))
            .collect();
        if entries.len() <= MAX_ENTRIES {
            return;
        }
        // Oldest first; among equal times (coarse clocks), the one just written last.
        entries.sort_by_key(|(t, p)| (*t, p == just_written));
        for (_, p) in &entries[..entries.len() - MAX_ENTRIES] {
            let _ = std::fs::remove_file(p);
        }
    }
}

/// A render's identity, built from the parts it depends on.
pub struct Key(Sha256);

impl Key {
    /// Starts a key for a render of kind `what`, tied to this brdfd executable; `None` when
    /// the executable cannot be identified (replaced while running, say), since renders of
    /// another build must never be served as this one's.
    pub fn new(what: &str) -> Option<Key> {
        let exe = std::fs::metadata(std::env::current_exe().ok()?).ok()?;
        let mut h = Sha256::new();
        h.update(MAGIC);
        h.update(env!("CARGO_PKG_VERSION"));
        h.update(exe.len().to_le_bytes());
        h.update(format!("{:?}", exe.modified().ok()?));
        let mut k = Key(h);
        k.add(what.as_bytes());
        Some(k)
    }

    /// Adds a part, length-prefixed so that parts cannot run into each other.
    pub fn add(&mut self, part: &[u8]) -> &mut Key {
        self.0.update((part.len() as u64).to_le_bytes());
        self.0.update(part);
        self
    }

    pub fn add_f32s(&mut self, values: impl IntoIterator<Item = f32>) -> &mut Key {
        let bytes: Vec<u8> = values.into_iter().flat_map(f32::to_le_bytes).collect();
        self.add(&bytes)
    }

    /// The values' little-endian bytes as one part, hashed a block at a time: a material's
    /// table is 35 MB, and a copy of it as bytes cost more than the hash.
    pub fn add_f64s(&mut self, values: &[f64]) -> &mut Key {
        self.0
            .update((std::mem::size_of_val(values) as u64).to_le_bytes());
        let mut block = [0u8; 8 * 1024];
        for chunk in values.chunks(block.len() / 8) {
            for (b, v) in block.chunks_exact_mut(8).zip(chunk) {
                b.copy_from_slice(&v.to_le_bytes());
            }
            self.0.update(&block[..8 * chunk.len()]);
        }
        self
    }

    fn hex(&self) -> String {
        self.0
            .clone()
            .finalize()
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect()
    }
}

fn read(path: &Path) -> Option<Raster> {
    let bytes = std::fs::read(path).ok()?;
    let body = bytes.strip_prefix(MAGIC)?;
    let (w, rest) = body.split_first_chunk::<8>()?;
    let (h, rest) = rest.split_first_chunk::<8>()?;
    let (w, h) = (
        u64::from_le_bytes(*w) as usize,
        u64::from_le_bytes(*h) as usize,
    );
    if w.checked_mul(h)?.checked_mul(12)? != rest.len() {
        return None;
    }
    let values: Vec<f32> = rest
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Some(Raster {
        width: w,
        height: h,
        pixels: values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn raster() -> Raster {
        Raster {
            width: 3,
            height: 2,
            pixels: (0..6).map(|i| [i as f32, 0.5, -1.0]).collect(),
        }
    }

    /// A table hashed a block at a time gives the key its bytes as one part gave: renders
    /// cached before stay found.
    #[test]
    fn a_table_hashes_as_its_bytes_in_one_part() {
        let values: Vec<f64> = (0..3000).map(|i| i as f64 * 0.37 - 11.0).collect();
        let mut blocks = Key::new("photo").unwrap();
        blocks.add_f64s(&values);
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let mut whole = Key::new("photo").unwrap();
        whole.add(&bytes);
        assert_eq!(blocks.hex(), whole.hex());
    }

    #[test]
    fn a_render_is_made_once_and_read_back_exactly() {
        let dir = tempfile::tempdir().unwrap();
        let cache = RenderCache {
            dir: dir.path().join("renders"),
        };
        let mut key = Key::new("photo").unwrap();
        key.add(b"gold").add_f64s(&[0.25]);
        let calls = std::cell::Cell::new(0);
        let render = || {
            calls.set(calls.get() + 1);
            Ok::<_, String>(raster())
        };
        assert_eq!(cache.get_or_render(&key, render).unwrap(), raster());
        assert_eq!(cache.get_or_render(&key, render).unwrap(), raster());
        assert_eq!(calls.get(), 1);
        // Another part, another entry.
        let mut other = Key::new("photo").unwrap();
        other.add(b"gold").add_f64s(&[0.26]);
        cache.get_or_render(&other, render).unwrap();
        assert_eq!(calls.get(), 2);
    }

    #[test]
    fn a_damaged_entry_is_rendered_again() {
        let dir = tempfile::tempdir().unwrap();
        let cache = RenderCache {
            dir: dir.path().to_path_buf(),
        };
        let key = Key::new("photo").unwrap();
        cache
            .get_or_render(&key, || Ok::<_, String>(raster()))
            .unwrap();
        let path = dir.path().join(format!("{}.bin", key.hex()));
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 5]).unwrap();
        let mut calls = 0;
        let again = cache
            .get_or_render(&key, || {
                calls += 1;
                Ok::<_, String>(raster())
            })
            .unwrap();
        assert_eq!((again, calls), (raster(), 1));
    }

    #[test]
    fn the_oldest_entries_go_beyond_the_limit() {
        let dir = tempfile::tempdir().unwrap();
        let cache = RenderCache {
            dir: dir.path().to_path_buf(),
        };
        let mut last = None;
        for i in 0..MAX_ENTRIES + 3 {
            let mut key = Key::new("photo").unwrap();
            key.add(&i.to_le_bytes());
            cache
                .get_or_render(&key, || Ok::<_, String>(raster()))
                .unwrap();
            last = Some(key);
        }
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), MAX_ENTRIES);
        let newest = dir.path().join(format!("{}.bin", last.unwrap().hex()));
        assert!(newest.exists(), "the entry just written is kept");
    }
}
