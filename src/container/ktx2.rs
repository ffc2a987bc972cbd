//! KTX 2.0 files (Khronos KTX File Format Specification 2.0): header, level index,
//! data-format descriptor, key/value data and the MIP levels, smallest level first in the file
//! as the specification recommends. The header, level index entries and the DFD block are
//! built and serialized by the `ktx2` crate; this module lays them out.

use super::Encoding;
use crate::bake::Bake;
use crate::compress::Codec;
use crate::format::Format;
use ktx2::Format as VkFormat;

/// The Vulkan format (`VkFormat`) of `encoding`: `R32G32B32A32_SFLOAT`, `R16G16B16A16_SFLOAT`,
/// `R16G16B16A16_UNORM`, `R8G8B8A8_UNORM` (never `_SRGB`), `BC6H_UFLOAT_BLOCK`,
/// `BC7_UNORM_BLOCK`, `BC5_UNORM_BLOCK`.
pub fn vk_format(encoding: Encoding) -> VkFormat {
    match encoding {
        Encoding::Plain(Format::F32) => VkFormat::R32G32B32A32_SFLOAT,
        Encoding::Plain(Format::F16) => VkFormat::R16G16B16A16_SFLOAT,
        Encoding::Plain(Format::Unorm16) => VkFormat::R16G16B16A16_UNORM,
        Encoding::Plain(Format::Unorm8) => VkFormat::R8G8B8A8_UNORM,
        Encoding::Block(Codec::Bc6h | Codec::Bc6hBc4) => VkFormat::BC6H_UFLOAT_BLOCK,
        Encoding::Block(Codec::Bc7) => VkFormat::BC7_UNORM_BLOCK,
        Encoding::Block(Codec::Bc5) => VkFormat::BC5_UNORM_BLOCK,
    }
}

/// Bytes of one texel block: 16 for RGBA32F and the BC formats, 8, 8 and 4 for the others.
fn block_bytes(encoding: Encoding) -> u64 {
    match encoding {
        Encoding::Plain(f) => 4 * f.channel_bytes() as u64,
        Encoding::Block(_) => 16,
    }
}

/// The key/value pairs a file of texture `texture` of `bake` carries, sorted by key as the
/// specification requires: `KTXorientation` (`rd`: rows top to bottom), `KTXwriter`, and
/// `ndfmap.channels`, `ndfmap.encoding`, `ndfmap.method`, `ndfmap.parameters` (JSON),
/// `ndfmap.ranges`, `ndfmap.texture`.
pub fn key_values(bake: &Bake, texture: usize, encoding: Encoding) -> Vec<(String, String)> {
    let t = &bake.textures[texture];
    let ranges: Vec<String> = t
        .ranges
        .iter()
        .map(|r| {
            serde_json::to_value(r)
                .ok()
                .and_then(|v| v.as_str().map(str::to_string))
                .unwrap_or_default()
        })
        .collect();
    let mut kv = vec![
        ("KTXorientation".to_string(), "rd".to_string()),
        (
            "KTXwriter".to_string(),
            format!("ndfmap {}", env!("CARGO_PKG_VERSION")),
        ),
        ("ndfmap.channels".to_string(), t.channels.join(",")),
        ("ndfmap.encoding".to_string(), encoding.description()),
        ("ndfmap.method".to_string(), bake.method.name().to_string()),
        ("ndfmap.parameters".to_string(), bake.parameters.to_string()),
        ("ndfmap.ranges".to_string(), ranges.join(",")),
        ("ndfmap.texture".to_string(), t.name.to_string()),
    ];
    kv.sort();
    kv
}

/// Pads `out` with zeros to a multiple of `align`.
fn pad(out: &mut Vec<u8>, align: u64) {
    while !(out.len() as u64).is_multiple_of(align) {
        out.push(0);
    }
}

/// The KTX2 file of texture `texture` of `bake` whose levels, finest first, are `levels`
/// (encoded in `encoding`).
pub(super) fn file(bake: &Bake, texture: usize, encoding: Encoding, levels: &[Vec<u8>]) -> Vec<u8> {
    let lengths: Vec<u64> = levels.iter().map(|l| l.len() as u64).collect();
    let (mut out, offsets) = layout(bake, texture, encoding, &lengths);
    for (k, data) in levels.iter().enumerate().rev() {
        out.resize(offsets[k] as usize, 0);
        out.extend_from_slice(data);
    }
    out
}

/// The layout of the KTX2 file of texture `texture` of `bake` whose levels, finest first, are
/// `lengths` bytes long (encoded in `encoding`): the bytes before the first level's data
/// (header, level index, DFD, key/value data) and each level's byte offset in the file. The
/// levels lie smallest first, each aligned to lcm(texel block size, 4), zeros between them: a
/// file is the prefix, then each level's bytes at its offset (what [`file`] and the streamed
/// writer, `container::StreamedFile`, both write).
pub(super) fn layout(
    bake: &Bake,
    texture: usize,
    encoding: Encoding,
    lengths: &[u64],
) -> (Vec<u8>, Vec<u64>) {
    let format = vk_format(encoding);
    // The crate's DFD for the format: its default transfer function is linear for every
    // format here (none is an _SRGB format), BT.709 primaries, straight alpha.
    let (basic, type_size) =
        ktx2::dfd::Basic::from_format(format).expect("the ktx2 crate describes every format used");
    let dfd_block = ktx2::dfd::Block::Basic(basic).to_vec();
    let mut dfd = Vec::with_capacity(4 + dfd_block.len());
    dfd.extend_from_slice(&(4 + dfd_block.len() as u32).to_le_bytes());
    dfd.extend_from_slice(&dfd_block);

    let mut kvd = Vec::new();
    for (k, v) in key_values(bake, texture, encoding) {
        let len = k.len() + 1 + v.len() + 1;
        kvd.extend_from_slice(&(len as u32).to_le_bytes());
        kvd.extend_from_slice(k.as_bytes());
        kvd.push(0);
        kvd.extend_from_slice(v.as_bytes());
        kvd.push(0);
        pad(&mut kvd, 4);
    }

    let (w, h) = bake.sizes[0];
    let index_len = lengths.len() * ktx2::LevelIndex::LENGTH;
    let dfd_offset = ktx2::Header::LENGTH + index_len;
    let kvd_offset = dfd_offset + dfd.len();
    let header = ktx2::Header {
        format: Some(format),
        type_size,
        pixel_width: w,
        pixel_height: h,
        pixel_depth: 0,
        layer_count: 0,
        face_count: 1,
        level_count: lengths.len() as u32,
        supercompression_scheme: None,
        index: ktx2::Index {
            dfd_byte_offset: dfd_offset as u32,
            dfd_byte_length: dfd.len() as u32,
            kvd_byte_offset: kvd_offset as u32,
            kvd_byte_length: kvd.len() as u32,
            sgd_byte_offset: 0,
            sgd_byte_length: 0,
        },
    };
    // Level data: smallest level first, each aligned to lcm(texel block size, 4).
    let align = block_bytes(encoding).max(4);
    let mut out = Vec::new();
    out.extend_from_slice(&header.as_bytes());
    out.resize(dfd_offset, 0); // the level index, filled in below
    out.extend_from_slice(&dfd);
    out.extend_from_slice(&kvd);
    let mut offsets = vec![0u64; lengths.len()];
    let mut end = out.len() as u64;
    for (k, &len) in lengths.iter().enumerate().rev() {
        end = end.next_multiple_of(align);
        offsets[k] = end;
        end += len;
    }
    for (k, &len) in lengths.iter().enumerate() {
        let entry = ktx2::LevelIndex {
            byte_offset: offsets[k],
            byte_length: len,
            uncompressed_byte_length: len,
        };
        let at = ktx2::Header::LENGTH + k * ktx2::LevelIndex::LENGTH;
        out[at..at + ktx2::LevelIndex::LENGTH].copy_from_slice(&entry.as_bytes());
    }
    (out, offsets)
}
