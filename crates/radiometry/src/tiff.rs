//! The structure of a TIFF-based RAW file (NEF, DNG, CR2, ARW, ORF, RW2, …), checked before
//! a decoder is given it.
//!
//! A camera's file comes from outside brdfd, and the RAW decoder trusts its structure: an IFD
//! chain that links back to itself makes it read without end, and a declared size makes it
//! allocate that size before it reads a pixel (a 21 KB file declaring 131,072 × 131,072 asks
//! for 34 GB and aborts the process). So every IFD a decoder follows is walked here first,
//! each at most once, and the file is refused, with the IFD and the tag named, when:
//! - an IFD or a value lies outside the file, or the chain loops, or nests too deep;
//! - an image is larger than [`MAX_SIDE`] on a side or [`MAX_PIXELS`] in all;
//! - a strip or tile of image data lies outside the file.
//!
//! The IFDs walked are the main chain, SubIFDs, the EXIF and GPS IFDs, and a Nikon maker
//! note's own TIFF. Files that are not TIFF-based (CR3, RAF) are left to the decoder.

/// Largest image side accepted, in pixels: above the largest sensor sold (about 14,000 ×
/// 10,600 for 150 MP), and below what a 32-bit pixel count would overflow at.
pub const MAX_SIDE: u64 = 65_535;
/// Largest image accepted, in pixels: 400 MP, above any single-shot camera's sensor.
pub const MAX_PIXELS: u64 = 400_000_000;
/// IFDs followed in all (a real NEF has about 8, a DNG about 5).
const MAX_IFDS: usize = 256;
/// How deep IFDs may nest (IFD0 → SubIFD → EXIF is 2).
const MAX_DEPTH: usize = 6;

const IMAGE_WIDTH: u16 = 0x0100;
const IMAGE_LENGTH: u16 = 0x0101;
const STRIP_OFFSETS: u16 = 0x0111;
const STRIP_BYTE_COUNTS: u16 = 0x0117;
const TILE_WIDTH: u16 = 0x0142;
const TILE_LENGTH: u16 = 0x0143;
const TILE_OFFSETS: u16 = 0x0144;
const TILE_BYTE_COUNTS: u16 = 0x0145;
const SUB_IFDS: u16 = 0x014A;
const EXIF_IFD: u16 = 0x8769;
const GPS_IFD: u16 = 0x8825;
const MAKER_NOTE: u16 = 0x927C;

/// Checks the structure as the module describes. `Err` says what is wrong and where, in
/// words for the operator.
pub fn check(bytes: &[u8]) -> Result<(), String> {
    let Some((order, first)) = header(bytes, 0) else {
        return Ok(());
    };
    let mut walk = Walk {
        bytes,
        seen: std::collections::HashSet::new(),
        path: Vec::new(),
    };
    walk.chain(Tiff { order, base: 0 }, first, 0, "IFD0")
}

#[derive(Clone, Copy)]
enum Order {
    Little,
    Big,
}

/// A TIFF inside the file: its byte order, and where its offsets count from (a Nikon maker
/// note holds a TIFF of its own, with offsets from its own header).
#[derive(Clone, Copy)]
struct Tiff {
    order: Order,
    base: usize,
}

/// The byte order and first IFD offset of a TIFF header at `at`: classic TIFF, and the
/// vendor variants with another magic number (Olympus ORF, Panasonic RW2).
fn header(bytes: &[u8], at: usize) -> Option<(Order, u32)> {
    let h = bytes.get(at..at + 8)?;
    let order = match &h[..2] {
        b"II" => Order::Little,
        b"MM" => Order::Big,
        _ => return None,
    };
    let t = Tiff { order, base: at };
    let magic = t.u16(h, 2)?;
    // 42: TIFF; 0x4F52 "RO", 0x5352 "RS": Olympus; 0x55: Panasonic.
    if ![42, 0x4F52, 0x5352, 0x55].contains(&magic) {
        return None;
    }
    Some((order, t.u32(h, 4)?))
}

impl Tiff {
    fn u16(&self, b: &[u8], at: usize) -> Option<u16> {
        let v: [u8; 2] = b.get(at..at + 2)?.try_into().ok()?;
        Some(match self.order {
            Order::Little => u16::from_le_bytes(v),
            Order::Big => u16::from_be_bytes(v),
        })
    }

    fn u32(&self, b: &[u8], at: usize) -> Option<u32> {
        let v: [u8; 4] = b.get(at..at + 4)?.try_into().ok()?;
        Some(match self.order {
            Order::Little => u32::from_le_bytes(v),
            Order::Big => u32::from_be_bytes(v),
        })
    }
}

/// One IFD entry, its values located in the file.
struct Entry {
    tag: u16,
    kind: u16,
    count: u64,
    /// Where the values start, in the file.
    at: usize,
}

/// Bytes per value of each TIFF field type; 0 for types a reader ignores.
fn type_size(kind: u16) -> u64 {
    match kind {
        1 | 2 | 6 | 7 => 1,
        3 | 8 => 2,
        4 | 9 | 11 | 13 => 4,
        5 | 10 | 12 => 8,
        _ => 0,
    }
}

struct Walk<'a> {
    bytes: &'a [u8],
    /// IFDs checked, by their place in the file: one that two pointers share is checked once.
    seen: std::collections::HashSet<u64>,
    /// The IFDs that lead to the one being checked (its chain's earlier IFDs and its parents'):
    /// one of these reached again is a loop.
    path: Vec<u64>,
}

impl Walk<'_> {
    /// An IFD chain from `offset`: each IFD, then the one its link names, until a zero link
    /// (or an IFD checked before, with the rest of its chain).
    fn chain(&mut self, t: Tiff, offset: u32, depth: usize, name: &str) -> Result<(), String> {
        let depth_of_path = self.path.len();
        let mut next = offset;
        let mut index = 0;
        while next != 0 {
            let label = if index == 0 {
                name.to_string()
            } else {
                format!("{name} (+{index} in its chain)")
            };
            match self.ifd(t, next, depth, &label)? {
                Some(link) => next = link,
                None => break,
            }
            index += 1;
        }
        self.path.truncate(depth_of_path);
        Ok(())
    }

    /// Checks one IFD and the IFDs it points to; returns its link to the next, or `None` if
    /// it was checked before. It stays on the path for the rest of its chain.
    fn ifd(
        &mut self,
        t: Tiff,
        offset: u32,
        depth: usize,
        name: &str,
    ) -> Result<Option<u32>, String> {
        // In u64: on a 32-bit machine an offset from the file must not wrap.
        let at = t.base as u64 + offset as u64;
        if self.path.contains(&at) {
            return Err(format!(
                "{name} at byte {at} is an IFD that leads to itself: the file's IFDs form a loop"
            ));
        }
        if !self.seen.insert(at) {
            return Ok(None);
        }
        if depth > MAX_DEPTH {
            return Err(format!(
                "{name} at byte {at} is nested more than {MAX_DEPTH} IFDs deep"
            ));
        }
        if self.seen.len() > MAX_IFDS {
            return Err(format!("the file has more than {MAX_IFDS} IFDs"));
        }
        let b = self.bytes;
        let outside = || {
            format!(
                "{name} at byte {at} lies outside the file ({} bytes)",
                b.len()
            )
        };
        let start = usize::try_from(at).map_err(|_| outside())?;
        let n = t.u16(b, start).ok_or_else(outside)? as usize;
        // An IFD's entries must lie in the file; then these sums fit in usize.
        let link_at = start
            .checked_add(2 + 12 * n)
            .filter(|e| e + 4 <= b.len())
            .ok_or_else(outside)?;
        let link = t.u32(b, link_at).ok_or_else(outside)?;
        let entries: Vec<Entry> = (0..n)
            .map(|i| self.entry(t, start + 2 + 12 * i, name))
            .collect::<Result<_, _>>()?;
        self.image(t, &entries, name)?;
        self.path.push(at);
        for e in &entries {
            let child = match e.tag {
                SUB_IFDS => "SubIFD",
                EXIF_IFD => "EXIF IFD",
                GPS_IFD => "GPS IFD",
                MAKER_NOTE => {
                    self.maker_note(e, depth, name)?;
                    continue;
                }
                _ => continue,
            };
            if !matches!(e.kind, 4 | 13) {
                continue;
            }
            for k in 0..e.count as usize {
                let offset = t.u32(b, e.at + 4 * k).ok_or_else(outside)?;
                let label = format!("{name} → {child} {}", k + 1);
                self.chain(t, offset, depth + 1, &label)?;
            }
        }
        Ok(Some(link))
    }

    /// An entry at `at` (inside the file), its values checked to lie in the file.
    fn entry(&self, t: Tiff, at: usize, name: &str) -> Result<Entry, String> {
        let b = self.bytes;
        let (tag, kind, count) = (
            t.u16(b, at).unwrap_or(0),
            t.u16(b, at + 2).unwrap_or(0),
            t.u32(b, at + 4).unwrap_or(0) as u64,
        );
        let size = count * type_size(kind);
        let values = if size <= 4 {
            at as u64 + 8
        } else {
            t.base as u64 + t.u32(b, at + 8).unwrap_or(0) as u64
        };
        if size > 0 && values + size > b.len() as u64 {
            return Err(format!(
                "{name}: tag 0x{tag:04X} has {count} values at byte {values}, past the file's end ({} bytes)",
                b.len()
            ));
        }
        Ok(Entry {
            tag,
            kind,
            count,
            // Within the file (checked above), so within usize.
            at: values as usize,
        })
    }

    /// Value `k` of an entry as a number, of any numeric type: the decoder reads a size
    /// written as a byte, a signed long, a rational or a double as readily as a LONG.
    fn value(&self, t: Tiff, e: &Entry, k: usize) -> Option<f64> {
        if k as u64 >= e.count {
            return None;
        }
        let b = self.bytes;
        let at = e.at + k * type_size(e.kind) as usize;
        let (high, low) = match t.order {
            Order::Little => (4, 0),
            Order::Big => (0, 4),
        };
        Some(match e.kind {
            1 | 7 => *b.get(at)? as f64,
            6 => *b.get(at)? as i8 as f64,
            3 => t.u16(b, at)? as f64,
            8 => t.u16(b, at)? as i16 as f64,
            4 | 13 => t.u32(b, at)? as f64,
            9 => t.u32(b, at)? as i32 as f64,
            5 => t.u32(b, at)? as f64 / t.u32(b, at + 4)? as f64,
            10 => t.u32(b, at)? as i32 as f64 / t.u32(b, at + 4)? as i32 as f64,
            11 => f32::from_bits(t.u32(b, at)?) as f64,
            12 => {
                f64::from_bits(((t.u32(b, at + high)? as u64) << 32) | t.u32(b, at + low)? as u64)
            }
            _ => return None,
        })
    }

    /// An IFD's image: its size, and its strips or tiles inside the file.
    fn image(&self, t: Tiff, entries: &[Entry], name: &str) -> Result<(), String> {
        let find = |tag| entries.iter().find(|e| e.tag == tag);
        // The largest of every entry with the tag: a file may repeat a tag, and the decoder
        // keeps the last. NaN counts as too large.
        let get = |tag| {
            entries
                .iter()
                .filter(|e| e.tag == tag)
                .filter_map(|e| self.value(t, e, 0))
                .map(|v| if v.is_nan() { f64::INFINITY } else { v })
                .reduce(f64::max)
        };
        let size = |w: Option<f64>, h: Option<f64>, what: &str| match (w, h) {
            (Some(w), Some(h))
                if w > MAX_SIDE as f64 || h > MAX_SIDE as f64 || w * h > MAX_PIXELS as f64 =>
            {
                Err(format!(
                    "{name} declares {what} of {w} × {h} pixels, larger than any camera's \
                     ({MAX_SIDE} a side, {} megapixels at most)",
                    MAX_PIXELS / 1_000_000
                ))
            }
            _ => Ok(()),
        };
        size(get(IMAGE_WIDTH), get(IMAGE_LENGTH), "an image")?;
        size(get(TILE_WIDTH), get(TILE_LENGTH), "tiles")?;
        for (offsets, counts, what) in [
            (STRIP_OFFSETS, STRIP_BYTE_COUNTS, "strip"),
            (TILE_OFFSETS, TILE_BYTE_COUNTS, "tile"),
        ] {
            let (Some(offsets), Some(counts)) = (find(offsets), find(counts)) else {
                continue;
            };
            // Only types with a size: their counts were checked against the file's length,
            // so this loop is no longer than the file (an unknown type's count is anything).
            if type_size(offsets.kind) == 0 || type_size(counts.kind) == 0 {
                continue;
            }
            for k in 0..offsets.count.min(counts.count) as usize {
                let (Some(o), Some(c)) = (self.value(t, offsets, k), self.value(t, counts, k))
                else {
                    continue;
                };
                let start = t.base as f64 + o;
                // Negative, NaN or past the end: all refused.
                if !(o >= 0.0 && c >= 0.0 && start + c <= self.bytes.len() as f64) {
                    return Err(format!(
                        "{name}: {what} {} of {c} bytes at byte {start} runs past the file's end ({} bytes)",
                        k + 1,
                        self.bytes.len()
                    ));
                }
            }
        }
        Ok(())
    }

    /// A Nikon maker note ("Nikon\0", a version, then a TIFF whose offsets count from its own
    /// header): its IFDs are walked too, since the decoder reads them. Other vendors' notes
    /// have layouts of their own, which the decoder reads with bounds of its own.
    fn maker_note(&mut self, e: &Entry, depth: usize, name: &str) -> Result<(), String> {
        let b = self.bytes;
        if e.count < 18 || b.get(e.at..e.at + 6) != Some(b"Nikon\0") {
            return Ok(());
        }
        let Some((order, first)) = header(b, e.at + 10) else {
            return Ok(());
        };
        let t = Tiff {
            order,
            base: e.at + 10,
        };
        self.chain(t, first, depth + 1, &format!("{name} → Nikon maker note"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A little-endian TIFF with one IFD of `entries` (tag, type, count, value), whose link
    /// is `link`, and `tail` bytes after it.
    fn tiff(entries: &[(u16, u16, u32, u32)], link: u32, tail: usize) -> Vec<u8> {
        let mut b = b"II*\0\x08\0\0\0".to_vec();
        b.extend((entries.len() as u16).to_le_bytes());
        for (tag, kind, count, value) in entries {
            b.extend(tag.to_le_bytes());
            b.extend(kind.to_le_bytes());
            b.extend(count.to_le_bytes());
            b.extend(value.to_le_bytes());
        }
        b.extend(link.to_le_bytes());
        b.resize(b.len() + tail, 0);
        b
    }

    #[test]
    fn a_sound_file_passes_and_each_fault_is_named() {
        let image = |w, h, offset, count| {
            vec![
                (IMAGE_WIDTH, 4, 1, w),
                (IMAGE_LENGTH, 4, 1, h),
                (STRIP_OFFSETS, 4, 1, offset),
                (STRIP_BYTE_COUNTS, 4, 1, count),
            ]
        };
        // 8 + 2 + 4·12 + 4 = 62 bytes of structure, then 64 of pixels.
        assert_eq!(check(&tiff(&image(8, 8, 62, 64), 0, 64)), Ok(()));
        assert_eq!(check(b"not a TIFF at all"), Ok(()));

        let huge = check(&tiff(&image(131_072, 131_072, 62, 64), 0, 64)).unwrap_err();
        assert!(
            huge.contains("IFD0 declares an image of 131072 × 131072"),
            "{huge}"
        );
        // Each side below the limit, but too many pixels in all.
        let wide = check(&tiff(&image(60_000, 60_000, 62, 64), 0, 64)).unwrap_err();
        assert!(wide.contains("60000 × 60000"), "{wide}");

        // The first IFD's link points back at itself: a loop.
        let looped = check(&tiff(&image(8, 8, 62, 64), 8, 64)).unwrap_err();
        assert!(looped.contains("the file's IFDs form a loop"), "{looped}");
        assert!(looped.contains("at byte 8"), "{looped}");

        let strip = check(&tiff(&image(8, 8, 62, 1_000_000), 0, 64)).unwrap_err();
        assert!(
            strip.contains("strip 1 of 1000000 bytes at byte 62 runs past"),
            "{strip}"
        );

        let truncated = tiff(&image(8, 8, 62, 64), 0, 64);
        let cut = check(&truncated[..30]).unwrap_err();
        assert!(
            cut.contains("IFD0 at byte 8 lies outside the file (30 bytes)"),
            "{cut}"
        );

        // An EXIF IFD pointing back at IFD0.
        let mut entries = image(8, 8, 74, 64);
        entries.push((EXIF_IFD, 4, 1, 8));
        let back = check(&tiff(&entries, 0, 64)).unwrap_err();
        assert!(back.contains("IFD0 → EXIF IFD 1 at byte 8"), "{back}");

        // A size the decoder reads from another type (a DOUBLE, a signed LONG), or a second
        // ImageWidth after a small one: the decoder keeps the last.
        // Two entries: 8 + 2 + 2 · 12 + 4 = 38 bytes, then the DOUBLE.
        let entries = [(IMAGE_WIDTH, 12, 1, 38), (IMAGE_LENGTH, 3, 1, 8)];
        let mut b = tiff(&entries, 0, 0);
        assert_eq!(b.len(), 38);
        b.extend(131_072f64.to_le_bytes());
        let e = check(&b).unwrap_err();
        assert!(e.contains("131072 × 8 pixels"), "{e}");
        let e = check(&tiff(
            &[(IMAGE_WIDTH, 9, 1, 131_072), (IMAGE_LENGTH, 3, 1, 8)],
            0,
            0,
        ));
        assert!(e.unwrap_err().contains("131072 × 8"));
        let twice = [
            (IMAGE_WIDTH, 3, 1, 8),
            (IMAGE_LENGTH, 3, 1, 8),
            (IMAGE_WIDTH, 4, 1, 131_072),
        ];
        assert!(check(&tiff(&twice, 0, 0))
            .unwrap_err()
            .contains("131072 × 8"));

        // Two pointers to one IFD are no loop: the EXIF IFD and the GPS IFD both at IFD0's
        // end, where an empty IFD stands.
        let mut shared = image(8, 8, 0, 0);
        shared.truncate(2);
        shared.push((EXIF_IFD, 4, 1, 8 + 2 + 4 * 12 + 4));
        shared.push((GPS_IFD, 4, 1, 8 + 2 + 4 * 12 + 4));
        assert_eq!(check(&tiff(&shared, 0, 6)), Ok(()));

        // A value array past the end.
        let far = check(&tiff(&[(0x010F, 2, 100, 1_000_000)], 0, 0)).unwrap_err();
        assert!(
            far.contains("tag 0x010F has 100 values at byte 1000000"),
            "{far}"
        );
    }
}
