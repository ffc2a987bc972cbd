//! Block compression of a bake's textures — BC6H, BC7, BC5 (and BC4 for a split alpha) — and
//! decoding them again, so the CPU twin shades exactly what a GPU sampling the compressed
//! texture reads, and `eval` measures a codec's error like any storage format.
//!
//! Main types: [`Codec`] (which block format), [`check_layout`] (whether a codec can hold a
//! bake's textures, known before baking), [`encode_level`] / [`decode_level`] (one MIP level to
//! 4×4 blocks and back), [`round_trip`] (a whole bake as the GPU sees it compressed).
//!
//! Encoding is crate `block_compression` (a pure-Rust port of Intel's ISPC texture compressor
//! kernels, run on the CPU), decoding is crate `bcdec_rs` (a port of `bcdec`): two independent
//! implementations of the block formats, neither part of this crate. The encoder makes unsigned BC6H blocks
//! only (`BC6H_UF16`): channels whose range is [`ValueRange::Signed`] are stored biased,
//! `0.5 + 0.5·v`, as in unsigned-normalized formats (DESIGN.md "Texture layouts"), and
//! unbounded ([`ValueRange::Any`]) channels, which may be negative, are refused. BC7 and BC5
//! are unsigned-normalized (8-bit endpoints): unit and signed (biased) channels only.
//! BC6H and BC5 hold no alpha channel (BC5 no blue either): a texture that uses them is refused.
//! [`Codec::Bc6hBc4`] is the exception, for measurement: RGB in BC6H and the alpha channel in
//! a second, BC4 texture — a layout the shaders and containers do not read (yet); `eval` uses
//! it to show what a 4-channel vMF lobe costs in BC6H-class storage.
//!
//! Levels whose sides are not multiples of 4 are padded to whole blocks by repeating their
//! last row and column; decoding returns the level's own texels. A level is encoded in bands
//! of [`BAND_BLOCK_ROWS`] block rows in parallel; every block is encoded from its own 16
//! texels alone, so the same texels give the same blocks whatever the thread count.
//!
//! Encoder settings (measured on 1024² vMF J = 6 and Olano–North textures of rock, bark and
//! facade, docs/containers.md "Cost of encoding"): BC7 uses the ISPC `basic` profile, whose
//! RMS error is within 0.2 % of `slow`'s at a third of the time, and its opaque variant
//! (A encoded as 1) for textures whose A channel is unused; BC6H uses
//! `slow` (2.7 % below `basic`'s RMS error, at 4× its time).

use crate::bake::{Bake, Method};
use crate::error::{Error, Result};
use crate::format::{Format, ValueRange};
use half::f16;
use std::fmt;
use std::str::FromStr;

/// A block-compressed texture format (4×4 texel blocks).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Codec {
    /// BC6H, unsigned half float RGB (`BC6H_UF16`), 16 bytes per block: 1 byte per texel.
    Bc6h,
    /// BC7, unsigned-normalized RGBA, 16 bytes per block: 1 byte per texel.
    Bc7,
    /// BC5, unsigned-normalized RG, 16 bytes per block: 1 byte per texel.
    Bc5,
    /// Measurement only: RGB in BC6H (1 byte per texel) and A in a second BC4 texture
    /// (0.5 byte per texel). Containers refuse it.
    Bc6hBc4,
}

impl Codec {
    /// Every codec.
    pub const ALL: [Codec; 4] = [Codec::Bc6h, Codec::Bc7, Codec::Bc5, Codec::Bc6hBc4];

    /// The lower-case name on the command line and in manifests.
    pub fn name(self) -> &'static str {
        match self {
            Codec::Bc6h => "bc6h",
            Codec::Bc7 => "bc7",
            Codec::Bc5 => "bc5",
            Codec::Bc6hBc4 => "bc6h+bc4",
        }
    }

    /// Bytes a texel takes (blocks of 16 texels; 16 bytes, or 24 for [`Codec::Bc6hBc4`]).
    pub fn bytes_per_texel(self) -> f64 {
        match self {
            Codec::Bc6hBc4 => 1.5,
            _ => 1.0,
        }
    }

    /// The storage format whose clamps the shaders apply to the decoded values (module `vmf`:
    /// `r_max`, `alpha_min`): f16 for BC6H (it decodes to half floats), unorm8 for BC7 and
    /// BC5 (8-bit endpoints).
    pub fn shading_format(self) -> Format {
        match self {
            Codec::Bc6h | Codec::Bc6hBc4 => Format::F16,
            Codec::Bc7 | Codec::Bc5 => Format::Unorm8,
        }
    }

    /// Channels the block format holds (R, G, B, A).
    fn holds(self) -> usize {
        match self {
            Codec::Bc6h => 3,
            Codec::Bc5 => 2,
            Codec::Bc7 | Codec::Bc6hBc4 => 4,
        }
    }
}

impl fmt::Display for Codec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Codec {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        crate::error::parse_named(s, &Codec::ALL, Codec::name, "block compression")
    }
}

/// Whether `codec` can hold one texture, named `name` (of a bake of `method`), with channel
/// meanings `channels` (`"unused"` for an unused one) and value ranges `ranges`; the error
/// names the texture, the channel and the codec.
pub fn check_texture(
    codec: Codec,
    method: Method,
    name: &str,
    channels: &[&str; 4],
    ranges: &[ValueRange; 4],
) -> Result<()> {
    let refuse = |why: String| {
        Err(Error::InvalidOption(format!(
            "{codec} cannot hold texture '{name}' of {method}: {why}"
        )))
    };
    if let Some(c) = (codec.holds()..4).find(|&c| channels[c] != crate::bake::UNUSED) {
        return refuse(format!(
            "it uses channel {} ('{}') and {codec} holds {} channels; use {}",
            ["R", "G", "B", "A"][c],
            channels[c],
            codec.holds(),
            if codec == Codec::Bc5 {
                "bc7, bc6h"
            } else {
                "bc7"
            }
        ));
    }
    for c in 0..4 {
        if channels[c] != crate::bake::UNUSED && ranges[c] == ValueRange::Any {
            return refuse(format!(
                "channel '{}' is unbounded and may be negative, which {} cannot store; use f16 \
                 or f32",
                channels[c],
                match codec {
                    Codec::Bc7 | Codec::Bc5 => "an unsigned-normalized format",
                    _ => "unsigned BC6H (the encoder makes no signed blocks)",
                }
            ));
        }
    }
    Ok(())
}

/// Whether `codec` can hold every texture of a bake of `method` (`lobes_or_lmax` lobes or
/// band limit, with colour textures when `color`), before any work: the first texture it
/// cannot hold is named ([`check_texture`]).
pub fn check_layout(method: Method, lobes_or_lmax: usize, color: bool, codec: Codec) -> Result<()> {
    for (name, channels, ranges) in crate::methods::texture_layout(method, lobes_or_lmax, color) {
        check_texture(codec, method, &name, &channels, &ranges)?;
    }
    Ok(())
}

/// Whether `codec` can hold every texture of `bake` ([`check_texture`]).
pub fn check(bake: &Bake, codec: Codec) -> Result<()> {
    for t in &bake.textures {
        check_texture(codec, bake.method, t.name, &t.channels, &t.ranges)?;
    }
    Ok(())
}

/// Bytes of one `w`×`h` level in `codec`: 16 per 4×4 block (24 for [`Codec::Bc6hBc4`]).
pub fn level_len(w: u32, h: u32, codec: Codec) -> usize {
    let blocks = w.div_ceil(4) as usize * h.div_ceil(4) as usize;
    match codec {
        Codec::Bc6hBc4 => blocks * 24,
        _ => blocks * 16,
    }
}

/// The value a block stores for `v` in a channel of range `range`: unit and unbounded values
/// as they are, signed ones biased to `0.5 + 0.5·v`, clamped to [0, 1] unless unbounded.
fn biased(v: f32, range: ValueRange) -> f32 {
    match range {
        ValueRange::Signed => 0.5 + 0.5 * v.clamp(-1.0, 1.0),
        ValueRange::Unit => v.clamp(0.0, 1.0),
        ValueRange::Any => v,
    }
}

/// [`biased`] undone.
fn unbiased(u: f32, range: ValueRange) -> f32 {
    match range {
        ValueRange::Signed => 2.0 * u - 1.0,
        _ => u,
    }
}

/// The level padded to whole blocks (last row and column repeated), as `(width, height,
/// texels)` with sides multiples of 4.
fn padded(w: u32, h: u32, texels: &[[f32; 4]]) -> (u32, u32, Vec<[f32; 4]>) {
    let (pw, ph) = (w.next_multiple_of(4), h.next_multiple_of(4));
    let mut out = Vec::with_capacity(pw as usize * ph as usize);
    for y in 0..ph {
        let sy = y.min(h - 1) as usize;
        for x in 0..pw {
            out.push(texels[sy * w as usize + x.min(w - 1) as usize]);
        }
    }
    (pw, ph, out)
}

/// Encodes one `w`×`h` level (`texels`, row-major, channel ranges `ranges`) into `codec`
/// blocks, row by row of blocks ([`level_len`] bytes; for [`Codec::Bc6hBc4`] the BC6H blocks
/// of the whole level, then its BC4 blocks). The texture's fitness for the codec is the
/// caller's to check ([`check_texture`]); values a block cannot store (NaN, negative or beyond
/// 65504 in BC6H) are an error naming `what`. `alpha` says whether channel A holds data; where
/// it does not, BC7 is encoded as opaque (ISPC's opaque profile, input A = 1; A decodes as 1
/// or 254/255).
pub fn encode_level(
    what: &str,
    w: u32,
    h: u32,
    texels: &[[f32; 4]],
    ranges: [ValueRange; 4],
    alpha: bool,
    codec: Codec,
) -> Result<Vec<u8>> {
    let (pw, ph, px) = padded(w, h, texels);
    // The opaque BC7 modes expect A = 255 (what they decode).
    let unorm8 = |v: f32, c: usize| match c == 3 && !alpha {
        true => 255,
        false => (biased(v, ranges[c]) * 255.0).round() as u8,
    };
    use block_compression::encode::{compress_rgba8, compress_rgba16};
    use block_compression::{BC6HSettings, BC7Settings, CompressionVariant as V};
    // Every encoder reads RGBA rows (BC4 reads R, BC5 R and G).
    let rgba8 = |channels: [usize; 4]| -> Vec<u8> {
        px.iter()
            .flat_map(|t| channels.map(|c| unorm8(t[c], c)))
            .collect()
    };
    let blocks = |variant: V, data: &[u8]| in_bands(variant, data, pw, ph, compress_rgba8);
    let mut out = Vec::with_capacity(level_len(w, h, codec));
    match codec {
        Codec::Bc6h | Codec::Bc6hBc4 => {
            let mut data = Vec::with_capacity(px.len() * 4);
            for t in &px {
                for c in 0..3 {
                    let u = biased(t[c], ranges[c]);
                    if !(0.0..=65504.0).contains(&u) {
                        return Err(Error::InvalidOption(format!(
                            "{codec} cannot hold {what}: value {} in channel {c} (unsigned \
                             BC6H stores 0 to 65504); use f16 or f32",
                            t[c]
                        )));
                    }
                    data.push(f16::from_f32(u));
                }
                data.push(f16::ONE);
            }
            let variant = V::BC6H(BC6HSettings::slow());
            out.extend(in_bands(variant, &data, pw, ph, compress_rgba16));
            if codec == Codec::Bc6hBc4 {
                out.extend(blocks(V::BC4, &rgba8([3, 3, 3, 3])));
            }
        }
        Codec::Bc7 => out.extend(blocks(
            V::BC7(if alpha {
                BC7Settings::alpha_basic()
            } else {
                BC7Settings::opaque_basic()
            }),
            &rgba8([0, 1, 2, 3]),
        )),
        Codec::Bc5 => out.extend(blocks(V::BC5, &rgba8([0, 1, 1, 1]))),
    }
    debug_assert_eq!(out.len(), level_len(w, h, codec));
    Ok(out)
}

/// Block rows per parallel job when a level is encoded ([`encode_level`]): 64 texel rows, a
/// 1024-wide band is 64 Ki texels (about 0.5 s of BC7 on one core).
pub const BAND_BLOCK_ROWS: usize = 16;

/// The blocks of a padded `pw`×`ph` RGBA level `data` (`ph`, `pw` multiples of 4), made by
/// `encode` (crate `block_compression`'s `compress_rgba8` or `compress_rgba16`) in bands of
/// [`BAND_BLOCK_ROWS`] block rows in parallel, each band written to its own rows of blocks.
fn in_bands<T: Sync>(
    variant: block_compression::CompressionVariant,
    data: &[T],
    pw: u32,
    ph: u32,
    encode: fn(block_compression::CompressionVariant, &[T], &mut [u8], u32, u32, u32),
) -> Vec<u8> {
    use rayon::prelude::*;
    let mut out = vec![0u8; variant.blocks_byte_size(pw, ph)];
    let band_texels = pw as usize * 4 * BAND_BLOCK_ROWS;
    out.par_chunks_mut(variant.blocks_byte_size(pw, 4) * BAND_BLOCK_ROWS)
        .zip(data.par_chunks(band_texels * 4))
        .for_each(|(blocks, rows)| {
            let band_h = (rows.len() / (pw as usize * 4)) as u32;
            encode(variant, rows, blocks, pw, band_h, pw * 4);
        });
    out
}

/// Decodes one `w`×`h` level of `codec` blocks ([`encode_level`]'s layout) into RGBA texels
/// with the bias of `ranges` undone: what a GPU sampling the texture reads. Channels the codec
/// lacks read as a GPU reads them: B = 0 (BC5) and A = 1 (BC6H, BC5). `blocks` shorter than
/// [`level_len`] is an error.
pub fn decode_level(
    blocks: &[u8],
    w: u32,
    h: u32,
    ranges: [ValueRange; 4],
    codec: Codec,
) -> Result<Vec<[f32; 4]>> {
    let need = level_len(w, h, codec);
    if blocks.len() < need {
        return Err(Error::InvalidOption(format!(
            "{codec} level {w}x{h} needs {need} bytes of blocks, got {}",
            blocks.len()
        )));
    }
    let (bw, bh) = (w.div_ceil(4) as usize, h.div_ceil(4) as usize);
    let mut out = vec![[0.0f32, 0.0, 0.0, 1.0]; w as usize * h as usize];
    // Writes texel (i, j) of block (bx, by) when it lies inside the level.
    let mut put = |bx: usize, by: usize, i: usize, j: usize, c: usize, v: f32| {
        let (x, y) = (bx * 4 + i, by * 4 + j);
        if x < w as usize && y < h as usize {
            out[y * w as usize + x][c] = unbiased(v, ranges[c]);
        }
    };
    let alpha_offset = bw * bh * 16;
    for by in 0..bh {
        for bx in 0..bw {
            let block = &blocks[(by * bw + bx) * 16..][..16];
            match codec {
                Codec::Bc6h | Codec::Bc6hBc4 => {
                    let mut rgb = [0.0f32; 48];
                    bcdec_rs::bc6h_float(block, &mut rgb, 12, false);
                    for j in 0..4 {
                        for i in 0..4 {
                            for c in 0..3 {
                                put(bx, by, i, j, c, rgb[j * 12 + i * 3 + c]);
                            }
                        }
                    }
                    if codec == Codec::Bc6hBc4 {
                        let a_block = &blocks[alpha_offset + (by * bw + bx) * 8..][..8];
                        let mut a = [0.0f32; 16];
                        bcdec_rs::bc4_float(a_block, &mut a, 4, false);
                        for j in 0..4 {
                            for i in 0..4 {
                                put(bx, by, i, j, 3, a[j * 4 + i]);
                            }
                        }
                    }
                }
                Codec::Bc7 => {
                    let mut rgba = [0u8; 64];
                    bcdec_rs::bc7(block, &mut rgba, 16);
                    for j in 0..4 {
                        for i in 0..4 {
                            for c in 0..4 {
                                put(bx, by, i, j, c, rgba[j * 16 + i * 4 + c] as f32 / 255.0);
                            }
                        }
                    }
                }
                Codec::Bc5 => {
                    let mut rg = [0u8; 32];
                    bcdec_rs::bc5(block, &mut rg, 8, false);
                    for j in 0..4 {
                        for i in 0..4 {
                            for c in 0..2 {
                                put(bx, by, i, j, c, rg[j * 8 + i * 2 + c] as f32 / 255.0);
                            }
                        }
                    }
                }
            }
        }
    }
    if codec == Codec::Bc5 {
        for t in &mut out {
            t[2] = 0.0;
        }
    }
    Ok(out)
}

/// The bake as a GPU sampling `codec` textures sees it: every level of every texture encoded
/// and decoded again, and [`Bake::format`] set to the codec's [`Codec::shading_format`] so
/// shading applies the matching clamps. Refuses (before any encoding) a bake with a texture
/// the codec cannot hold ([`check`]). Levels are encoded in parallel, each alone: the result
/// does not depend on the thread count.
pub fn round_trip(bake: &Bake, codec: Codec) -> Result<Bake> {
    use rayon::prelude::*;
    check(bake, codec)?;
    let mut out = bake.clone();
    let jobs: Vec<(usize, usize)> = (0..bake.textures.len())
        .flat_map(|t| (0..bake.sizes.len()).map(move |k| (t, k)))
        .collect();
    let decoded: Vec<Result<Vec<[f32; 4]>>> = jobs
        .par_iter()
        .map(|&(t, k)| {
            let texture = &bake.textures[t];
            let (w, h) = bake.sizes[k];
            let what = format!("texture '{}' level {k}", texture.name);
            let blocks = encode_level(
                &what,
                w,
                h,
                &texture.levels[k],
                texture.ranges,
                texture.uses_alpha(),
                codec,
            )?;
            decode_level(&blocks, w, h, texture.ranges, codec)
        })
        .collect();
    for (&(t, k), level) in jobs.iter().zip(decoded) {
        out.textures[t].levels[k] = level?;
    }
    out.format = codec.shading_format();
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::NormalMap;
    use crate::methods::bake;

    /// A smooth map: normals varying slowly (period ≥ 30 texels).
    fn smooth(size: u32) -> NormalMap {
        let v = (0..size * size)
            .map(|i| {
                let (x, y) = ((i % size) as f32, (i / size) as f32);
                glam::Vec3::new(0.4 * (x / 5.0).sin(), 0.3 * (y / 7.0).cos(), 1.0)
            })
            .collect();
        NormalMap::from_vectors(
            size,
            size,
            v,
            crate::ingest::Addressing::Wrap,
            crate::ingest::BadNormals::Repair,
        )
        .unwrap()
    }

    fn sample(size: u32) -> NormalMap {
        crate::procedural::generate(size, 3).map
    }

    #[test]
    fn refusals_name_the_texture_the_channel_and_the_codec() {
        // vMF lobes use alpha: BC6H (RGB) and BC5 (RG) cannot hold them; BC7 can.
        let e = check_layout(Method::Vmf, 6, false, Codec::Bc6h).unwrap_err();
        let m = e.to_string();
        assert!(
            m.contains("bc6h") && m.contains("'lobe0'") && m.contains("A ('alpha*r_z')"),
            "{m}"
        );
        assert!(check_layout(Method::Vmf, 6, true, Codec::Bc7).is_ok());
        assert!(check_layout(Method::Vmf, 6, true, Codec::Bc6hBc4).is_ok());
        // LEAN's slope moments are unbounded and signed: no codec here holds them.
        for codec in Codec::ALL {
            let m = check_layout(Method::Lean, 0, false, codec)
                .unwrap_err()
                .to_string();
            assert!(m.contains(codec.name()) && m.contains("'slopes'"), "{m}");
        }
        // Olano–North's three textures use RGB of bounded values: BC6H and BC7 hold them.
        assert!(check_layout(Method::Pbr, 0, false, Codec::Bc7).is_ok());
        assert!(check_layout(Method::Olano, 0, false, Codec::Bc6h).is_ok());
        assert!(check_layout(Method::Olano, 0, false, Codec::Bc7).is_ok());
        let m = check_layout(Method::Olano, 0, false, Codec::Bc5)
            .unwrap_err()
            .to_string();
        assert!(m.contains("channel B ('E[n_z]')"), "{m}");
        // The pre-bake layout is the bake's own.
        let map = sample(16);
        for (method, n) in [(Method::Olano, 0), (Method::Sh, 3), (Method::Plain, 0)] {
            let options = crate::bake::BakeOptions {
                lmax: n,
                ..Default::default()
            };
            let b = crate::methods::bake_with(&map, method, &options).unwrap();
            let l = crate::methods::texture_layout(method, n, false);
            assert_eq!(l.len(), b.textures.len());
            for ((name, c, r), t) in l.iter().zip(&b.textures) {
                assert_eq!((name.as_str(), c, r), (t.name, &t.channels, &t.ranges));
            }
        }
    }

    #[test]
    fn decoded_blocks_stay_within_the_codecs_error_bound() {
        // A smooth map's Olano–North bake, decoded against the baked values in the channels'
        // own units. n_x varies along x and n_y along y, so a block's colours spread in two
        // directions that one line per subset (both codecs) follows only approximately.
        // Bounds: the measured worst and RMS (BC7 0.092, 0.0085; BC6H 0.113, 0.0156) times
        // 1.5 — a regression bound on these encoders, not a property of the formats.
        let b = bake(&smooth(32), Method::Olano);
        for (codec, max_bound, rms_bound) in [(Codec::Bc7, 0.14, 0.013), (Codec::Bc6h, 0.17, 0.024)]
        {
            let q = round_trip(&b, codec).unwrap();
            assert_eq!(q.format, codec.shading_format());
            let (mut worst, mut sum, mut n) = (0.0f32, 0.0f64, 0usize);
            for (t, qt) in b.textures.iter().zip(&q.textures) {
                for (l, ql) in t.levels.iter().zip(&qt.levels) {
                    for (a, c) in l.iter().zip(ql) {
                        for ch in 0..3 {
                            let e = (a[ch] - c[ch]).abs();
                            worst = worst.max(e);
                            sum += (e as f64).powi(2);
                            n += 1;
                        }
                    }
                }
            }
            let rms = (sum / n as f64).sqrt();
            eprintln!("{codec}: worst {worst}, rms {rms}");
            assert!(
                worst <= max_bound && rms <= rms_bound,
                "{codec}: worst {worst}, rms {rms}"
            );
            assert!(worst > 0.0, "{codec}: lossy, so some value must change");
        }
    }

    #[test]
    fn constant_levels_of_every_size_decode_to_the_stored_value() {
        // A constant block is exact in every codec up to its endpoint precision: unorm8 for
        // BC7/BC5/BC4, and for BC6H the f16 value itself (one endpoint, no interpolation).
        let v = [0.25f32, -0.5, 0.75, 0.5];
        let ranges = [
            ValueRange::Unit,
            ValueRange::Signed,
            ValueRange::Unit,
            ValueRange::Unit,
        ];
        for (w, h) in [(1, 1), (2, 1), (3, 5), (4, 4), (9, 6)] {
            let texels = vec![v; (w * h) as usize];
            for codec in Codec::ALL {
                let blocks = encode_level("test", w, h, &texels, ranges, true, codec).unwrap();
                assert_eq!(blocks.len(), level_len(w, h, codec));
                let d = decode_level(&blocks, w, h, ranges, codec).unwrap();
                assert_eq!(d.len(), (w * h) as usize);
                for t in &d {
                    for c in 0..codec.holds() {
                        assert!(
                            (t[c] - v[c]).abs() <= 2.0 / 255.0,
                            "{codec} {w}x{h}: {t:?} vs {v:?}"
                        );
                    }
                }
            }
        }
        assert!(decode_level(&[0; 15], 4, 4, ranges, Codec::Bc7).is_err());
    }

    #[test]
    fn bands_give_the_blocks_of_one_encoder_call() {
        // 34 block rows: two whole bands and a short one. Noisy texels, so blocks differ.
        use block_compression::encode::{compress_rgba8, compress_rgba16};
        use block_compression::{BC6HSettings, BC7Settings, CompressionVariant as V};
        let (w, h) = (40u32, 136u32);
        let mut rng = crate::rng::Rng(7);
        let bytes: Vec<u8> = (0..w * h * 4)
            .map(|_| (rng.uniform() * 255.0) as u8)
            .collect();
        let halves: Vec<f16> = bytes
            .iter()
            .map(|&b| f16::from_f32(b as f32 / 255.0))
            .collect();
        for variant in [
            V::BC7(BC7Settings::alpha_basic()),
            V::BC7(BC7Settings::opaque_basic()),
        ] {
            let mut whole = vec![0u8; variant.blocks_byte_size(w, h)];
            compress_rgba8(variant, &bytes, &mut whole, w, h, w * 4);
            assert_eq!(in_bands(variant, &bytes, w, h, compress_rgba8), whole);
        }
        let variant = V::BC6H(BC6HSettings::slow());
        let mut whole = vec![0u8; variant.blocks_byte_size(w, h)];
        compress_rgba16(variant, &halves, &mut whole, w, h, w * 4);
        assert_eq!(in_bands(variant, &halves, w, h, compress_rgba16), whole);
    }

    #[test]
    fn opaque_bc7_reads_alpha_as_one_and_keeps_rgb() {
        // Olano–North's mean texture leaves A unused: opaque blocks decode A as 1 (254/255 in
        // blocks of modes 4–6, which still carry an alpha endpoint) and RGB within the bound
        // of the alpha-carrying blocks.
        let b = bake(&smooth(32), Method::Olano);
        let t = &b.textures[0];
        assert!(!t.uses_alpha() && b.textures.iter().all(|t| !t.uses_alpha()));
        let (w, h) = b.sizes[0];
        let err = |alpha: bool| {
            let blocks =
                encode_level("t", w, h, &t.levels[0], t.ranges, alpha, Codec::Bc7).unwrap();
            let d = decode_level(&blocks, w, h, t.ranges, Codec::Bc7).unwrap();
            let mut worst = 0.0f32;
            for (a, q) in t.levels[0].iter().zip(&d) {
                for c in 0..3 {
                    worst = worst.max((a[c] - q[c]).abs());
                }
            }
            (worst, d.iter().all(|q| q[3] >= 254.0 / 255.0))
        };
        let (opaque, ones) = err(false);
        let (with_alpha, _) = err(true);
        eprintln!("worst RGB error: opaque {opaque}, with alpha {with_alpha}");
        assert!(ones, "opaque BC7 decodes A as 1 (254/255 in some blocks)");
        assert!(opaque > 0.0 && opaque <= 0.14, "{opaque}");
    }

    #[test]
    fn negative_values_are_refused_by_unsigned_bc6h() {
        let texels = vec![[-1.0f32, 0.0, 0.0, 0.0]; 16];
        let e = encode_level(
            "texture 't' level 0",
            4,
            4,
            &texels,
            [ValueRange::Any; 4],
            true,
            Codec::Bc6h,
        )
        .unwrap_err();
        assert!(e.to_string().contains("texture 't' level 0"), "{e}");
    }
}
