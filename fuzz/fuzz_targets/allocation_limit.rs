//! Every target's allocator: an allocation above [`LIMIT`] aborts, which libFuzzer reports as
//! a crash and keeps the input for. Without a sanitizer, libFuzzer's own `-malloc_limit_mb`
//! sees no allocations, and a huge `Vec::with_capacity` from a device-declared length (issue
//! 20, D8) costs no resident memory until it is written, so `-rss_limit_mb` misses it too.

use std::alloc::{GlobalAlloc, Layout, System};

/// Above anything brdfd allocates on purpose: the largest image it reads (a 16384 × 8192
/// panorama, 1.6 GB of RGB floats) fits below it; a 4 GiB length does not.
pub const LIMIT: usize = 2 << 30;

pub struct Limited;

fn too_big(layout: Layout) -> ! {
    // No allocation here: the message is written as it is.
    let _ = std::io::Write::write_all(
        &mut std::io::stderr(),
        b"allocation above the fuzz limit (2 GiB): a length read from the input drives it\n",
    );
    let _ = layout;
    std::process::abort()
}

// SAFETY: every call is passed to the system allocator unchanged, or aborts before it.
unsafe impl GlobalAlloc for Limited {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if layout.size() > LIMIT {
            too_big(layout)
        }
        System.alloc(layout)
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if layout.size() > LIMIT {
            too_big(layout)
        }
        System.alloc_zeroed(layout)
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > LIMIT {
            too_big(layout)
        }
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static ALLOCATOR: Limited = Limited;
