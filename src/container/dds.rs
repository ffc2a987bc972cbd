//! DDS files with the DX10 header extension (Microsoft "DDS programming guide": `DDS_HEADER`
//! and `DDS_HEADER_DXT10`): one 2D texture, its MIP levels finest first, tightly packed.
//! DDS has no metadata of its own: the bake's `manifest.json` is the sidecar naming method,
//! channels and encoding.

use super::Encoding;
use crate::bake::Bake;
use crate::compress::Codec;
use crate::format::Format;

/// The DXGI format (`DXGI_FORMAT`) of `encoding`: `R32G32B32A32_FLOAT` (2),
/// `R16G16B16A16_FLOAT` (10), `R16G16B16A16_UNORM` (11), `R8G8B8A8_UNORM` (28, not `_SRGB`),
/// `BC5_UNORM` (83), `BC6H_UF16` (95), `BC7_UNORM` (98).
pub fn dxgi_format(encoding: Encoding) -> u32 {
    match encoding {
        Encoding::Plain(Format::F32) => 2,
        Encoding::Plain(Format::F16) => 10,
        Encoding::Plain(Format::Unorm16) => 11,
        Encoding::Plain(Format::Unorm8) => 28,
        Encoding::Block(Codec::Bc5) => 83,
        Encoding::Block(Codec::Bc6h | Codec::Bc6hBc4) => 95,
        Encoding::Block(Codec::Bc7) => 98,
    }
}

const DDSD_CAPS: u32 = 0x1;
const DDSD_HEIGHT: u32 = 0x2;
const DDSD_WIDTH: u32 = 0x4;
const DDSD_PITCH: u32 = 0x8;
const DDSD_PIXELFORMAT: u32 = 0x1000;
const DDSD_MIPMAPCOUNT: u32 = 0x20000;
const DDSD_LINEARSIZE: u32 = 0x80000;
const DDPF_FOURCC: u32 = 0x4;
const DDSCAPS_COMPLEX: u32 = 0x8;
const DDSCAPS_TEXTURE: u32 = 0x1000;
const DDSCAPS_MIPMAP: u32 = 0x40_0000;
const D3D10_RESOURCE_DIMENSION_TEXTURE2D: u32 = 3;
/// `DDS_ALPHA_MODE_CUSTOM`: the alpha channel is data, not transparency.
const DDS_ALPHA_MODE_CUSTOM: u32 = 4;

/// The DDS file of a texture of `bake` whose levels, finest first, are `levels` (encoded in
/// `encoding`).
pub(super) fn file(bake: &Bake, encoding: Encoding, levels: &[Vec<u8>]) -> Vec<u8> {
    let lengths: Vec<u64> = levels.iter().map(|l| l.len() as u64).collect();
    let (mut out, _) = layout(bake, encoding, &lengths);
    for data in levels {
        out.extend_from_slice(data);
    }
    out
}

/// The layout of the DDS file of a texture of `bake` whose levels, finest first, are
/// `lengths` bytes long: the header bytes (magic, `DDS_HEADER`, `DDS_HEADER_DXT10`) and each
/// level's byte offset (tightly packed after the header, finest first).
pub(super) fn layout(bake: &Bake, encoding: Encoding, lengths: &[u64]) -> (Vec<u8>, Vec<u64>) {
    let (w, h) = bake.sizes[0];
    let (flags, pitch_or_linear_size) = match encoding {
        Encoding::Plain(f) => (DDSD_PITCH, w * 4 * f.channel_bytes() as u32),
        Encoding::Block(_) => (DDSD_LINEARSIZE, lengths[0] as u32),
    };
    let mut header = [0u32; 31];
    header[0] = 124; // dwSize
    header[1] = DDSD_CAPS | DDSD_HEIGHT | DDSD_WIDTH | DDSD_PIXELFORMAT | DDSD_MIPMAPCOUNT | flags;
    header[2] = h;
    header[3] = w;
    header[4] = pitch_or_linear_size;
    header[5] = 0; // depth
    header[6] = lengths.len() as u32;
    // header[7..18]: dwReserved1; the pixel format (DDS_PIXELFORMAT) from header[18]:
    header[18] = 32;
    header[19] = DDPF_FOURCC;
    header[20] = u32::from_le_bytes(*b"DX10");
    header[26] = DDSCAPS_COMPLEX | DDSCAPS_TEXTURE | DDSCAPS_MIPMAP;
    let dx10 = [
        dxgi_format(encoding),
        D3D10_RESOURCE_DIMENSION_TEXTURE2D,
        0, // miscFlag
        1, // arraySize
        DDS_ALPHA_MODE_CUSTOM,
    ];
    let mut out = Vec::with_capacity(4 + 124 + 20);
    out.extend_from_slice(b"DDS ");
    for v in header.iter().chain(&dx10) {
        out.extend_from_slice(&v.to_le_bytes());
    }
    let mut offsets = Vec::with_capacity(lengths.len());
    let mut at = out.len() as u64;
    for &len in lengths {
        offsets.push(at);
        at += len;
    }
    (out, offsets)
}
