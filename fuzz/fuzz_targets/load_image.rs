//! The image loaders (`NormalMap::load_memory`, `with_feature_memory`: PNG, JPEG, TGA, TIFF and
//! OpenEXR through the `image` and `exr` crates) on arbitrary bytes. The first byte picks the
//! name's extension, which decides the format when the content has no signature (TGA) and the
//! ingest options; a decoded map is also read back as its own feature image and baked (plain
//! MIP chain) when small. Loads run under a 512 MiB memory budget, so a file that would decode
//! to more must be refused before it allocates (the fuzzer's RSS limit is 4 GiB). Any panic,
//! abort, out-of-memory or sanitizer report is a finding.
#![no_main]

use libfuzzer_sys::fuzz_target;
use ndfmap::ingest::{BadNormals, Channels, Encoding, GreenChannel};
use ndfmap::{IngestOptions, NormalMap};

/// The memory budget of each load (issue 13: decoding is bounded by it).
const MEMORY_LIMIT: u64 = 512 << 20;

const NAMES: [&str; 7] = ["f.png", "f.tga", "f.tif", "f.jpg", "f.exr", "f", "f.bin"];

fuzz_target!(init: ndfmap_fuzz::contain_dependency_panics(), |data: &[u8]| {
    let Some((&selector, bytes)) = data.split_first() else {
        return;
    };
    let name = NAMES[selector as usize % NAMES.len()];
    let opts = IngestOptions {
        green: if selector & 0x08 != 0 {
            GreenChannel::DirectX
        } else {
            GreenChannel::OpenGl
        },
        encoding: [Encoding::Auto, Encoding::Unorm, Encoding::Snorm][(selector >> 4) as usize % 3],
        channels: [Channels::Auto, Channels::Xyz, Channels::Xy][(selector >> 6) as usize % 3],
        bad_normals: BadNormals::Repair,
        // Well inside the 4 GiB the fuzzer allows: a file claiming more is refused up front.
        memory_limit: Some(MEMORY_LIMIT),
        ..IngestOptions::default()
    };
    if let Ok(map) = NormalMap::load_memory(name, bytes, &opts) {
        let small = u64::from(map.width()) * u64::from(map.height()) <= 4096;
        if let Ok(map) = map.with_feature_memory(name, bytes, &opts)
            && small
        {
            let _ = ndfmap::methods::bake(&map, ndfmap::bake::Method::Toksvig);
        }
    }
});
