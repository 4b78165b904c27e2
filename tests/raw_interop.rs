//! Outside programs read the simulated D5100's RAW files: Debian's exiftool reads the make,
//! model and exposure of its NEF and DNG, and Debian's dcraw decodes them to the same linear
//! values as brdfd's decoder. The files come the way a user gets them: `brdfd sim camera`
//! set to RAW + JPEG, downloaded with `brdfd ptp capture`. CI installs both programs and sets
//! BRDFD_REQUIRE_RAW_TOOLS=1, so there the test cannot skip.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use brdfd_core::raster::Raster;
use brdfd_radiometry::raw::{decode_raw, WhiteBalance};
use common::{brdfd, text, tools_present, Simulator};

/// Shoots one RAW + JPEG frame at 1/60 s on a simulated D5100 writing `raw`, and returns
/// the files `brdfd ptp capture` saved.
fn shoot(raw: &str, dir: &Path) -> Vec<PathBuf> {
    let sim = Simulator::start(&[
        "sim",
        "camera",
        "--profile",
        "nikon-d5100",
        "--size",
        "64",
        "--raw",
        raw,
        "--ptpip",
        "127.0.0.1:0",
    ]);
    let o = brdfd(
        &[
            "ptp",
            "capture",
            "--port",
            &format!("ptpip:{}", sim.addr),
            "--files",
            "raw+jpeg",
            "--shutter",
            "0.0166",
            "--out",
            dir.to_str().unwrap(),
        ],
        dir,
    );
    let (out, err) = text(&o);
    assert!(o.status.success(), "{out}\n{err}");
    out.lines()
        .filter(|l| l.starts_with('/'))
        .map(PathBuf::from)
        .collect()
}

/// dcraw's decode: linear 16-bit (-4), the camera's own colours (-o 0), no white balance
/// (-r 1 1 1 1), bilinear demosaic (-q 0), as a PPM on stdout.
fn dcraw(file: &Path) -> Raster {
    let o = Command::new("dcraw")
        .args(["-4", "-o", "0", "-r", "1", "1", "1", "1", "-q", "0", "-c"])
        .arg(file)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "dcraw: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let b = o.stdout;
    // "P6\n<w> <h>\n65535\n", then big-endian 16-bit RGB.
    let header: Vec<&[u8]> = b.splitn(4, |c| *c == b'\n').take(3).collect();
    assert_eq!(header[0], b"P6", "{:?}", String::from_utf8_lossy(&b[..20]));
    let size = String::from_utf8_lossy(header[1]).to_string();
    let (w, h) = size.split_once(' ').unwrap();
    let (w, h): (usize, usize) = (w.parse().unwrap(), h.parse().unwrap());
    let start = header.iter().map(|l| l.len() + 1).sum::<usize>();
    let pixels = b[start..]
        .chunks_exact(6)
        .map(|p| {
            std::array::from_fn(|c| u16::from_be_bytes([p[2 * c], p[2 * c + 1]]) as f32 / 65535.0)
        })
        .collect::<Vec<[f32; 3]>>();
    assert_eq!(pixels.len(), w * h);
    Raster {
        width: w,
        height: h,
        pixels,
    }
}

#[test]
fn exiftool_and_dcraw_read_the_simulated_nef_and_dng() {
    if !tools_present(
        &["exiftool", "dcraw"],
        "BRDFD_REQUIRE_RAW_TOOLS",
        "apt-get install libimage-exiftool-perl dcraw",
    ) {
        return;
    }
    for raw in ["nef", "dng"] {
        let dir = tempfile::tempdir().unwrap();
        let files = shoot(raw, dir.path());
        let names: Vec<String> = files
            .iter()
            .map(|f| f.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        let ext = raw.to_uppercase();
        assert_eq!(
            names,
            [format!("DSC_0001.{ext}"), "DSC_0001.JPG".to_string()],
            "{raw}: one shot, RAW then JPEG"
        );
        let file = &files[0];
        let bytes = std::fs::read(file).unwrap();
        let ours = decode_raw(&bytes, &names[0], WhiteBalance::Fixed([1.0; 3]))
            .unwrap_or_else(|e| panic!("{e}"));

        // exiftool: make, model and exposure, as brdfd read them.
        let o = Command::new("exiftool")
            .args([
                "-j",
                "-n",
                "-Make",
                "-Model",
                "-ExposureTime",
                "-FNumber",
                "-ISO",
            ])
            .arg(file)
            .output()
            .unwrap();
        let tags: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let tags = &tags[0];
        println!("{raw}: exiftool: {tags}");
        assert_eq!(tags["Make"], "NIKON CORPORATION", "{tags}");
        assert_eq!(tags["Model"], "NIKON D5100", "{tags}");
        let t = tags["ExposureTime"].as_f64().unwrap();
        assert!((t - 1.0 / 60.0).abs() < 1e-4, "{tags}");
        assert!((t - ours.exposure.shutter_s).abs() < 1e-9, "{tags}");
        assert_eq!(
            tags["FNumber"].as_f64(),
            Some(ours.exposure.f_number),
            "{tags}"
        );
        assert_eq!(tags["ISO"].as_f64(), Some(ours.exposure.iso), "{tags}");

        // dcraw: its image is the sensor less the 44 covered columns; the recommended crop
        // that brdfd returns starts 8 pixels in from its top left.
        let theirs = dcraw(file);
        assert_eq!(
            (theirs.width, theirs.height),
            (64 + 8 + 12, 64 + 16),
            "{raw}: dcraw's image"
        );
        let (mut ratios, mut compared) = (Vec::new(), Vec::new());
        for y in 0..64 {
            for x in 0..64 {
                let (a, b) = (ours.values.get(x, y), theirs.get(x + 8, y + 8));
                for c in 0..3 {
                    if a[c] > 0.02 && a[c] < 0.95 {
                        ratios.push(a[c] / b[c]);
                        compared.push((a[c], b[c]));
                    }
                }
            }
        }
        assert!(
            compared.len() > 2000,
            "{raw}: {} values compared",
            compared.len()
        );
        ratios.sort_by(f32::total_cmp);
        // The two scale by their own white level (dcraw's table has 15846 for a D5100 NEF,
        // the file and rawler 15892): a constant ratio, within a per cent of 1.
        let scale = ratios[ratios.len() / 2];
        assert!((scale - 1.0).abs() < 0.01, "{raw}: scale {scale}");
        let worst = compared
            .iter()
            .map(|(a, b)| (a - scale * b).abs() / a)
            .fold(0.0f32, f32::max);
        println!(
            "{raw}: {} values, brdfd / dcraw = {scale:.4}, worst difference beyond that {:.3}%",
            compared.len(),
            worst * 100.0
        );
        // 16-bit rounding of dark values is the only difference left.
        assert!(worst < 0.005, "{raw}: worst {worst}");
    }
}
