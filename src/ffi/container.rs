//! The C API of module `container`: a bake written as KTX2 or DDS files (one per texture with
//! its whole MIP chain), on disk or into a caller's buffer, optionally block-compressed.

use super::bake::{FORMATS, ndf_bake, ndf_format};
use super::{Out, Outcome, arg, c_str, choose, fail, guard, ndf_status, path};
use crate::compress::Codec;
use crate::container::Container;
use crate::error::Error;
use crate::format::Format;
use std::ffi::{c_char, c_void};

/// A file container: one of the `NDF_CONTAINER_*` values.
pub type ndf_container = u32;
/// OpenEXR (float formats) or PNG (unorm formats), one file per texture per level.
pub const NDF_CONTAINER_EXR: ndf_container = 0;
/// KTX 2.0, one file per texture with its whole MIP chain, linear, with `ndfmap.*` metadata.
pub const NDF_CONTAINER_KTX2: ndf_container = 1;
/// DDS with the DX10 header, one file per texture with its whole MIP chain.
pub const NDF_CONTAINER_DDS: ndf_container = 2;

/// The `NDF_CONTAINER_*` values, in order.
const CONTAINERS: [Container; 3] = [Container::Exr, Container::Ktx2, Container::Dds];

/// Block compression of container files: one of the `NDF_COMPRESSION_*` values.
pub type ndf_compression = u32;
/// None: the texels in the `ndf_format` given.
pub const NDF_COMPRESSION_NONE: ndf_compression = 0;
/// BC6H, unsigned half float RGB; for textures that use no alpha and no unbounded channel.
pub const NDF_COMPRESSION_BC6H: ndf_compression = 1;
/// BC7, unsigned-normalized RGBA; for textures without unbounded channels.
pub const NDF_COMPRESSION_BC7: ndf_compression = 2;
/// BC5, unsigned-normalized RG; for textures that use only R and G.
pub const NDF_COMPRESSION_BC5: ndf_compression = 3;

/// The `NDF_COMPRESSION_*` values, in order.
const COMPRESSIONS: [Option<Codec>; 4] =
    [None, Some(Codec::Bc6h), Some(Codec::Bc7), Some(Codec::Bc5)];

/// A checked request: the bake rounded to `format` when the format is not f32.
fn prepared(
    b: &ndf_bake,
    format: ndf_format,
    container: ndf_container,
    compression: ndf_compression,
) -> Outcome<(crate::bake::Bake, Container, Option<Codec>)> {
    let format = choose("format", format, &FORMATS)?;
    let container = choose("container", container, &CONTAINERS)?;
    let codec = choose("compression", compression, &COMPRESSIONS)?;
    let unsupported = |e: Error| fail(ndf_status::UnsupportedFormat, e.to_string());
    if let Some(c) = codec {
        if container == Container::Exr || format != Format::F32 {
            return Err(fail(
                ndf_status::UnsupportedFormat,
                format!(
                    "{c} blocks need container KTX2 or DDS and format NDF_FORMAT_RGBA_F32 (the \
                     baked values), got {container} and {format}"
                ),
            ));
        }
        crate::compress::check(&b.bake, c).map_err(unsupported)?;
    }
    let bake = crate::pack::quantize(&b.bake, format).map_err(unsupported)?;
    Ok((bake, container, codec))
}

/// Writes the bake to folder `directory` (created if missing) in `container`, all-or-nothing,
/// as `ndfmap bake --container --compress` does: `manifest.json` and, for KTX2 and DDS, one
/// file per texture named `<texture>.ktx2` / `<texture>.dds` (for EXR, as `ndf_bake_write`).
/// - `format`: the texel format (`NDF_FORMAT_*`); must be `NDF_FORMAT_RGBA_F32` with a
///   compression.
/// - `compression`: `NDF_COMPRESSION_*`; not with `NDF_CONTAINER_EXR`.
/// - Fails with `NDF_STATUS_UNSUPPORTED_FORMAT` when a texture does not fit the format or
///   compression (the message names the texture), before anything is written, and
///   `NDF_STATUS_WRITE` when the folder or a file cannot be written.
///
/// # Safety
/// `bake` is NULL or a live bake; `directory` is NULL or a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_write_container(
    bake: *const ndf_bake,
    directory: *const c_char,
    format: ndf_format,
    container: ndf_container,
    compression: ndf_compression,
) -> ndf_status {
    guard("ndf_bake_write_container", || {
        // SAFETY (both blocks): the pointers are NULL or valid, as this function requires.
        let b = unsafe { arg(bake, "bake") }?;
        let dir = path(unsafe { c_str(directory, "directory") }?, "directory")?;
        let (to_write, container, codec) = prepared(b, format, container, compression)?;
        crate::container::write_bake(&to_write, b.input.clone(), &dir, container, codec)?;
        Ok(())
    })
}

/// The file of texture `texture` in `container` (KTX2 or DDS), built in memory.
fn file_bytes(
    b: &ndf_bake,
    texture: u32,
    format: ndf_format,
    container: ndf_container,
    compression: ndf_compression,
) -> Outcome<Vec<u8>> {
    let (quantized, container, codec) = prepared(b, format, container, compression)?;
    if container == Container::Exr {
        return Err(fail(
            ndf_status::InvalidArgument,
            "NDF_CONTAINER_EXR is a folder of files per level: use ndf_bake_write_container",
        ));
    }
    let t = texture as usize;
    if t >= quantized.textures.len() {
        return Err(fail(
            ndf_status::OutOfRange,
            format!(
                "texture {t} out of range: the bake has {}",
                quantized.textures.len()
            ),
        ));
    }
    Ok(crate::container::texture_file(
        &quantized, t, container, codec,
    )?)
}

/// Bytes that `ndf_bake_container_file` writes for texture `texture` (the whole file; it is
/// built to be measured, so this costs as much as the file itself).
/// - Arguments and failures as for `ndf_bake_container_file`.
///
/// # Safety
/// `bake` is NULL or a live bake; `size_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_container_size(
    bake: *const ndf_bake,
    texture: u32,
    format: ndf_format,
    container: ndf_container,
    compression: ndf_compression,
    size_out: *mut usize,
) -> ndf_status {
    guard("ndf_bake_container_size", || {
        // SAFETY: NULL or a live bake, as this function requires.
        let b = unsafe { arg(bake, "bake") }?;
        let out = Out::new(size_out, "size_out")?;
        let bytes = file_bytes(b, texture, format, container, compression)?;
        // SAFETY: writable, as this function requires.
        unsafe { out.write(bytes.len()) };
        Ok(())
    })
}

/// The KTX2 or DDS file of texture `texture` in memory: `buffer` receives the file's bytes,
/// exactly what `ndf_bake_write_container` writes for that texture.
/// - `container`: `NDF_CONTAINER_KTX2` or `NDF_CONTAINER_DDS` (`NDF_STATUS_INVALID_ARGUMENT`
///   for EXR, a folder of files); `format` and `compression` as for
///   `ndf_bake_write_container`.
/// - `buffer`, `capacity`: the destination and its size in bytes; it must hold
///   `ndf_bake_container_size()` bytes (`NDF_STATUS_BUFFER_TOO_SMALL` otherwise, and nothing
///   is written). Any alignment.
/// - `written_out`: receives the number of bytes written.
/// - `NDF_STATUS_OUT_OF_RANGE` for a texture past the end, `NDF_STATUS_UNSUPPORTED_FORMAT`
///   when the texture does not fit the format or compression.
///
/// # Safety
/// `bake` is NULL or a live bake; `buffer` is NULL or writable for `capacity` bytes;
/// `written_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_container_file(
    bake: *const ndf_bake,
    texture: u32,
    format: ndf_format,
    container: ndf_container,
    compression: ndf_compression,
    buffer: *mut c_void,
    capacity: usize,
    written_out: *mut usize,
) -> ndf_status {
    guard("ndf_bake_container_file", || {
        // SAFETY: NULL or a live bake, as this function requires.
        let b = unsafe { arg(bake, "bake") }?;
        if buffer.is_null() {
            return Err(super::null("buffer"));
        }
        let out = Out::new(written_out, "written_out")?;
        let bytes = file_bytes(b, texture, format, container, compression)?;
        if capacity < bytes.len() {
            return Err(fail(
                ndf_status::BufferTooSmall,
                format!(
                    "buffer of {capacity} bytes is too small: the file of texture {texture} \
                     takes {} (ndf_bake_container_size)",
                    bytes.len()
                ),
            ));
        }
        // SAFETY: `buffer` is writable for `capacity` ≥ `bytes.len()` bytes (the caller's
        // contract) and does not overlap `bytes`, which this call allocated; u8 needs no
        // alignment.
        unsafe { std::ptr::copy_nonoverlapping(bytes.as_ptr(), buffer.cast::<u8>(), bytes.len()) };
        // SAFETY: writable, as this function requires.
        unsafe { out.write(bytes.len()) };
        Ok(())
    })
}
