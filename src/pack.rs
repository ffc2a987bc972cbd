//! Packing: a bake's RGBA f32 chains converted to the formats GPUs sample — f32, f16, unorm16
//! and unorm8 — and back again, so the error a format adds can be measured by shading exactly
//! what the GPU reads.
//!
//! Unsigned-normalized formats store [`ValueRange::Unit`] channels as is and
//! [`ValueRange::Signed`] channels biased, `0.5 + 0.5·v` (DESIGN.md "Texture layouts"); the
//! shader undoes the bias. [`ValueRange::Any`] channels (LEAN's slope moments) need a float
//! format, and f16 refuses values beyond its range rather than storing infinity.
//! Packed bytes are in the host's byte order, rows top to bottom: what `glTexImage2D` takes.

use crate::bake::{Bake, Method};
use crate::error::{Error, Result};
use crate::format::{Format, ValueRange};
use half::f16;

/// The largest finite half float: f16 storage refuses values beyond it.
pub const F16_MAX: f32 = 65504.0;

/// Bytes one level of one texture takes in `format` (4 channels per texel).
pub fn packed_len(bake: &Bake, level: usize, format: Format) -> usize {
    let (w, h) = bake.sizes[level];
    w as usize * h as usize * 4 * format.channel_bytes()
}

/// The integer code of `v` in an unsigned-normalized format with maximum code `max` (255 or
/// 65535): `round(v·max)` for unit channels, `round((0.5 + 0.5·v)·max)` for signed ones,
/// clamped to the range first.
pub fn unorm_code(v: f32, range: ValueRange, max: f32) -> u16 {
    unorm(v, range, max) as u16
}

fn unorm(v: f32, range: ValueRange, max: f32) -> f32 {
    let u = match range {
        ValueRange::Signed => 0.5 + 0.5 * v.clamp(-1.0, 1.0),
        _ => v.clamp(0.0, 1.0),
    };
    (u * max).round()
}

fn from_unorm(c: f32, range: ValueRange, max: f32) -> f32 {
    let u = c / max;
    match range {
        ValueRange::Signed => 2.0 * u - 1.0,
        _ => u,
    }
}

/// Whether `format` can hold the textures a bake of `method` makes, whose value ranges are
/// `ranges` (`methods::texture_ranges`), known before baking: unbounded channels need a float
/// format. (Whether f16 holds every value is known only after: [`check`].)
pub fn check_ranges(method: Method, ranges: &[[ValueRange; 4]], format: Format) -> Result<()> {
    let unbounded = ranges.iter().any(|r| r.contains(&ValueRange::Any));
    if unbounded && matches!(format, Format::Unorm16 | Format::Unorm8) {
        return Err(Error::InvalidOption(format!(
            "format {format} cannot hold the textures of {method} (unbounded values); use f16 or f32"
        )));
    }
    Ok(())
}

/// Whether `format` can hold texture `texture` of `bake`: unbounded channels need a float
/// format, and f16 needs every value within ±65504. The error names the texture and level.
pub fn check(bake: &Bake, texture: usize, format: Format) -> Result<()> {
    let t = &bake.textures[texture];
    let unbounded = t.ranges.contains(&ValueRange::Any);
    if unbounded && matches!(format, Format::Unorm16 | Format::Unorm8) {
        return Err(Error::InvalidOption(format!(
            "format {format} cannot hold texture '{}' of {} (unbounded values); use f16 or f32",
            t.name, bake.method
        )));
    }
    for (k, level) in t.levels.iter().enumerate() {
        check_level(t.name, k, level, format)?;
    }
    Ok(())
}

/// Whether `format` can hold level `level` of the texture named `name` (`texels`): f16 needs
/// every value within ±65504 (the error names the texture, the level and the value). What
/// [`check`] applies to every level, and a streamed writer to each band of rows.
pub fn check_level(name: &str, level: usize, texels: &[[f32; 4]], format: Format) -> Result<()> {
    if format == Format::F16
        && let Some(v) = texels.iter().flatten().find(|v| v.abs() > F16_MAX)
    {
        return Err(Error::InvalidOption(format!(
            "format f16 cannot hold texture '{name}' level {level}: value {v} exceeds {F16_MAX}; use f32"
        )));
    }
    Ok(())
}

/// Packs level `level` of texture `texture` into `out` in `format`, returning the bytes
/// written. `out` must hold at least [`packed_len`] bytes; a shorter buffer is an error and
/// nothing is written.
pub fn pack_level(
    bake: &Bake,
    texture: usize,
    level: usize,
    format: Format,
    out: &mut [u8],
) -> Result<usize> {
    let need = packed_len(bake, level, format);
    if out.len() < need {
        return Err(Error::InvalidOption(format!(
            "buffer of {} bytes is too small: level {level} in {format} needs {need}",
            out.len()
        )));
    }
    check(bake, texture, format)?;
    let t = &bake.textures[texture];
    let b = format.channel_bytes();
    for (i, v) in t.levels[level].iter().flatten().enumerate() {
        let range = t.ranges[i % 4];
        let dst = &mut out[i * b..(i + 1) * b];
        match format {
            Format::F32 => dst.copy_from_slice(&v.to_ne_bytes()),
            Format::F16 => dst.copy_from_slice(&f16::from_f32(*v).to_ne_bytes()),
            Format::Unorm16 => {
                dst.copy_from_slice(&(unorm(*v, range, 65535.0) as u16).to_ne_bytes())
            }
            Format::Unorm8 => dst[0] = unorm(*v, range, 255.0) as u8,
        }
    }
    Ok(need)
}

/// Rounds one value through `format` and back, as the GPU would read it.
pub fn round_trip(v: f32, range: ValueRange, format: Format) -> f32 {
    match format {
        Format::F32 => v,
        Format::F16 => f16::from_f32(v).to_f32(),
        Format::Unorm16 => from_unorm(unorm(v, range, 65535.0), range, 65535.0),
        Format::Unorm8 => from_unorm(unorm(v, range, 255.0), range, 255.0),
    }
}

/// Rounds `texels` (channels of range `ranges`) through `format` in place, each value on its
/// own ([`round_trip`]): what [`quantize_into`] does to every level, and a streamed writer to
/// each band of rows (module `banded`), so both store the same values.
pub fn round_trip_texels(texels: &mut [[f32; 4]], ranges: [ValueRange; 4], format: Format) {
    for texel in texels {
        for (c, v) in texel.iter_mut().enumerate() {
            let r = round_trip(*v, ranges[c], format);
            // Stored only where it changes (bit for bit): a value the format holds exactly, as
            // f32 holds every value and f16 holds 0, leaves its page as it was, so
            // dead lobes' zero pages are not made resident.
            if r.to_bits() != v.to_bits() {
                *v = r;
            }
        }
    }
}

/// The bake as a GPU sampling `format` textures sees it: every value rounded through the
/// format, and [`Bake::format`] set so shading applies the format's clamps.
pub fn quantize(bake: &Bake, format: Format) -> Result<Bake> {
    quantize_into(bake.clone(), format)
}

/// [`quantize`] in place: the bake's own texels are rounded, so that no second copy of its
/// textures is held (what a writer of a large bake wants).
pub fn quantize_into(mut bake: Bake, format: Format) -> Result<Bake> {
    use rayon::prelude::*;
    for i in 0..bake.textures.len() {
        check(&bake, i, format)?;
    }
    bake.format = format;
    if format == Format::F32 {
        // f32 holds every value as it is: nothing to round.
        return Ok(bake);
    }
    for t in &mut bake.textures {
        let ranges = t.ranges;
        for level in &mut t.levels {
            // Each value on its own: the same result for any split and thread count.
            level
                .par_chunks_mut(4096)
                .for_each(|chunk| round_trip_texels(chunk, ranges, format));
        }
    }
    Ok(bake)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::Method;
    use crate::ingest::{Addressing, BadNormals, NormalMap};
    use crate::methods::bake;
    use glam::Vec3;

    fn sample() -> NormalMap {
        let v = (0..64)
            .map(|i| {
                Vec3::new(
                    ((i * 7 % 13) as f32 / 13.0 - 0.5) * 1.4,
                    (i * 5 % 11) as f32 / 11.0 - 0.5,
                    0.8,
                )
            })
            .collect();
        NormalMap::from_vectors(8, 8, v, Addressing::Wrap, BadNormals::Repair).unwrap()
    }

    #[test]
    fn packed_bytes_decode_to_the_round_tripped_values() {
        let b = bake(&sample(), Method::Toksvig);
        for format in Format::ALL {
            let q = quantize(&b, format).unwrap();
            for level in 0..b.level_count() {
                let mut buf = vec![0u8; packed_len(&b, level, format)];
                assert_eq!(
                    pack_level(&b, 0, level, format, &mut buf).unwrap(),
                    buf.len()
                );
                let cb = format.channel_bytes();
                for (i, chunk) in buf.chunks_exact(cb).enumerate() {
                    let range = b.textures[0].ranges[i % 4];
                    let v = match format {
                        Format::F32 => f32::from_ne_bytes(chunk.try_into().unwrap()),
                        Format::F16 => f16::from_ne_bytes(chunk.try_into().unwrap()).to_f32(),
                        Format::Unorm16 => from_unorm(
                            u16::from_ne_bytes(chunk.try_into().unwrap()) as f32,
                            range,
                            65535.0,
                        ),
                        Format::Unorm8 => from_unorm(chunk[0] as f32, range, 255.0),
                    };
                    assert_eq!(v, q.textures[0].levels[level][i / 4][i % 4]);
                }
            }
        }
    }

    #[test]
    fn quantization_error_is_within_half_a_step() {
        let b = bake(&sample(), Method::Olano);
        for (format, step) in [
            (Format::F16, 1.0 / 1024.0),
            (Format::Unorm16, 2.0 / 65535.0),
            (Format::Unorm8, 2.0 / 255.0),
        ] {
            let q = quantize(&b, format).unwrap();
            for (t, qt) in b.textures.iter().zip(&q.textures) {
                for (l, ql) in t.levels.iter().zip(&qt.levels) {
                    for (a, c) in l.iter().flatten().zip(ql.iter().flatten()) {
                        assert!(
                            (a - c).abs() <= 0.5 * step * a.abs().max(1.0) + 1e-7,
                            "{format}: {a} → {c}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn unbounded_textures_refuse_unorm_and_short_buffers_are_errors() {
        let b = bake(&sample(), Method::Lean);
        assert!(quantize(&b, Format::Unorm8).is_err());
        assert!(quantize(&b, Format::F16).is_ok());
        let mut small = vec![0u8; packed_len(&b, 0, Format::F32) - 1];
        assert!(pack_level(&b, 0, 0, Format::F32, &mut small).is_err());
        assert!(small.iter().all(|&x| x == 0), "nothing written");
    }
}
