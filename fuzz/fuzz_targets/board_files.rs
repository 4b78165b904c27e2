//! The pose board's file (`brdfd calibrate pose --board`, written by `brdfd calibrate
//! target`): its TOML read and checked as the CLI reads it (`config::read_board`: the sizes, the
//! marker ratio, the dictionary and the markers the board needs from it), then what
//! `calibrate pose` and the virtual bench do with a board: its place in the world, its
//! drawing, and a detection in a small photo. A board that reads must write back as read.
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;
#[path = "input_file.rs"]
mod input_file;

use brdfd_pose::board::Board;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = input_file::write("toml", data);
    let Ok(board) = brdfd_rig::config::read_board(&path) else {
        return;
    };
    let (w, h) = board.size_mm();
    let _ = board.world([w / 2.0, h / 2.0]);
    let _ = board.normal();
    if let Ok(pattern) = board.pattern() {
        for (x, y) in [
            (0.0, 0.0),
            (w / 3.0, h / 2.0),
            (w - 1e-9, h - 1e-9),
            (-1.0, h),
        ] {
            let _ = pattern.at(x, y);
        }
    }
    // A blank photo: no board is found, but the detector is set up for this board. Small,
    // so that the detection costs little.
    let _ = board.detect(&image::GrayImage::from_pixel(48, 32, image::Luma([128])));
    let written = board.to_toml();
    let back: Board = brdfd_rig::config::parse("board.toml", &written)
        .unwrap_or_else(|e| panic!("the board file written does not read back: {e}\n{written}"));
    assert_eq!(back, board, "the board file written reads back otherwise");
});
