//! C API, normal maps: load one from a file, from an image file in memory or from raw pixels,
//! attach a feature (albedo) image, query it, free it. Wraps [`crate::ingest`].

use super::{
    Out, Outcome, arg, arg_mut, bytes, c_str, choose, guard, guard_value, ndf_status, read_options,
    text,
};
use crate::ingest::{
    Addressing, BadNormals, Channels, Encoding, FeatureEncoding, GreenChannel, IngestOptions,
    NormalMap, Samples,
};
use crate::output::InputInfo;
use std::ffi::{c_char, c_void};

/// Direction of the green channel: one of the `NDF_GREEN_*` values.
pub type ndf_green = u32;
/// +Y up (OpenGL, Blender, most CC0 libraries): green is the bitangent as stored. Default.
pub const NDF_GREEN_OPENGL: ndf_green = 0;
/// −Y (DirectX, Unreal): the green channel is negated on ingest.
pub const NDF_GREEN_DIRECTX: ndf_green = 1;

/// How stored values map to normal components: one of the `NDF_ENCODING_*` values.
pub type ndf_encoding = u32;
/// Unsigned-normalized for integer samples, signed for float samples. Default.
pub const NDF_ENCODING_AUTO: ndf_encoding = 0;
/// A stored value `c` in [0, max] means `2c/max − 1`.
pub const NDF_ENCODING_UNORM: ndf_encoding = 1;
/// Floats are the components themselves; integers are two's complement (GPU SNORM).
pub const NDF_ENCODING_SNORM: ndf_encoding = 2;

/// Which channels carry the normal: one of the `NDF_CHANNELS_*` values.
pub type ndf_channels = u32;
/// 3 or 4 channels are read as x, y, z; 2 channels as x, y with z reconstructed. Default.
pub const NDF_CHANNELS_AUTO: ndf_channels = 0;
/// x, y, z from the first three channels (at least 3 needed).
pub const NDF_CHANNELS_XYZ: ndf_channels = 1;
/// x, y from the first two channels (BC5-style); z = sqrt(1 − x² − y²) is reconstructed.
pub const NDF_CHANNELS_XY: ndf_channels = 2;

/// Texture addressing at the edges: one of the `NDF_ADDRESSING_*` values.
pub type ndf_addressing = u32;
/// The map tiles. Default.
pub const NDF_ADDRESSING_WRAP: ndf_addressing = 0;
/// Coordinates clamp to the edge texel.
pub const NDF_ADDRESSING_CLAMP: ndf_addressing = 1;

/// What to do with zero-length, NaN or below-horizon normals: one of `NDF_BAD_NORMALS_*`.
pub type ndf_bad_normals = u32;
/// Zero-length and NaN normals become +Z, below-horizon ones go onto the horizon. Default.
pub const NDF_BAD_NORMALS_REPAIR: ndf_bad_normals = 0;
/// Fail with `NDF_STATUS_BAD_NORMALS`, naming the first bad texel.
pub const NDF_BAD_NORMALS_REJECT: ndf_bad_normals = 1;

/// How a feature (albedo) image's values are decoded: one of `NDF_FEATURE_ENCODING_*`.
pub type ndf_feature_encoding = u32;
/// 8/16-bit colour is sRGB-encoded and decoded to linear; floats are linear. Default.
pub const NDF_FEATURE_ENCODING_SRGB: ndf_feature_encoding = 0;
/// Values are used as stored (divided by the integer maximum).
pub const NDF_FEATURE_ENCODING_LINEAR: ndf_feature_encoding = 1;

/// The type of each sample of a caller pixel buffer: one of the `NDF_SAMPLE_*` values.
pub type ndf_sample_type = u32;
/// `uint8_t` samples (maximum 255).
pub const NDF_SAMPLE_UINT8: ndf_sample_type = 0;
/// `uint16_t` samples (maximum 65535), in the host's byte order.
pub const NDF_SAMPLE_UINT16: ndf_sample_type = 1;
/// `float` samples, in the host's byte order.
pub const NDF_SAMPLE_FLOAT32: ndf_sample_type = 2;

/// How to read a normal map (and its feature image). Initialize with
/// `ndf_ingest_options_default()`, then change fields.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct ndf_ingest_options {
    /// `sizeof(ndf_ingest_options)`, set by `ndf_ingest_options_default()`.
    pub struct_size: usize,
    /// Green channel direction, `NDF_GREEN_*`. Default `NDF_GREEN_OPENGL`.
    pub green: ndf_green,
    /// Value encoding, `NDF_ENCODING_*`. Default `NDF_ENCODING_AUTO`.
    pub encoding: ndf_encoding,
    /// Channel layout, `NDF_CHANNELS_*`. Default `NDF_CHANNELS_AUTO`.
    pub channels: ndf_channels,
    /// Edge addressing, recorded in the bake, `NDF_ADDRESSING_*`. Default `NDF_ADDRESSING_WRAP`.
    pub addressing: ndf_addressing,
    /// Bad-normal policy, `NDF_BAD_NORMALS_*`. Default `NDF_BAD_NORMALS_REPAIR`.
    pub bad_normals: ndf_bad_normals,
    /// Feature image encoding, `NDF_FEATURE_ENCODING_*`. Default `NDF_FEATURE_ENCODING_SRGB`.
    pub feature_encoding: ndf_feature_encoding,
    /// Memory budget of one load in bytes: a file whose decoding would need more (estimated
    /// from its header, before decoding) fails with `NDF_STATUS_MEMORY_BUDGET`. Default 0: half
    /// the machine's memory (its control group's limit when lower).
    pub memory_limit: u64,
}

/// The default ingest options: OpenGL green, automatic encoding and channels, wrap
/// addressing, repair bad normals, sRGB feature images.
#[unsafe(no_mangle)]
pub extern "C" fn ndf_ingest_options_default() -> ndf_ingest_options {
    guard_value(DEFAULT_INGEST, || DEFAULT_INGEST)
}

const DEFAULT_INGEST: ndf_ingest_options = ndf_ingest_options {
    struct_size: size_of::<ndf_ingest_options>(),
    green: NDF_GREEN_OPENGL,
    encoding: NDF_ENCODING_AUTO,
    channels: NDF_CHANNELS_AUTO,
    addressing: NDF_ADDRESSING_WRAP,
    bad_normals: NDF_BAD_NORMALS_REPAIR,
    feature_encoding: NDF_FEATURE_ENCODING_SRGB,
    memory_limit: 0,
};

/// The `NDF_GREEN_*` values, in order.
const GREEN: [GreenChannel; 2] = [GreenChannel::OpenGl, GreenChannel::DirectX];
/// The `NDF_ENCODING_*` values, in order.
const ENCODING: [Encoding; 3] = [Encoding::Auto, Encoding::Unorm, Encoding::Snorm];
/// The `NDF_CHANNELS_*` values, in order.
const CHANNELS: [Channels; 3] = [Channels::Auto, Channels::Xyz, Channels::Xy];
/// The `NDF_ADDRESSING_*` values, in order.
pub(crate) const ADDRESSING: [Addressing; 2] = [Addressing::Wrap, Addressing::Clamp];
/// The `NDF_BAD_NORMALS_*` values, in order.
const BAD_NORMALS: [BadNormals; 2] = [BadNormals::Repair, BadNormals::Reject];
/// The `NDF_FEATURE_ENCODING_*` values, in order.
const FEATURE_ENCODING: [FeatureEncoding; 2] = [FeatureEncoding::Srgb, FeatureEncoding::Linear];

impl ndf_ingest_options {
    /// The library's options, every enumeration validated.
    fn to_rust(self) -> Outcome<IngestOptions> {
        Ok(IngestOptions {
            green: choose("green", self.green, &GREEN)?,
            encoding: choose("encoding", self.encoding, &ENCODING)?,
            channels: choose("channels", self.channels, &CHANNELS)?,
            addressing: choose("addressing", self.addressing, &ADDRESSING)?,
            bad_normals: choose("bad_normals", self.bad_normals, &BAD_NORMALS)?,
            feature_encoding: choose("feature_encoding", self.feature_encoding, &FEATURE_ENCODING)?,
            memory_limit: super::memory_limit(self.memory_limit),
        })
    }
}

/// A decoded normal map (opaque): unit tangent-space normals, optionally a feature image.
/// Created by `ndf_normal_map_load_file`, `ndf_normal_map_load_memory` or
/// `ndf_normal_map_from_pixels`; released by `ndf_normal_map_free`. A map may be read by
/// several threads at once (baking reads it); attaching a feature needs exclusive access.
pub struct ndf_normal_map {
    pub(crate) map: NormalMap,
    /// Where it came from and how it was read, for the manifest of a written bake.
    pub(crate) input: InputInfo,
}

impl ndf_normal_map {
    fn new(map: NormalMap, path: Option<String>, options: IngestOptions) -> Self {
        let stats = map.stats().clone();
        ndf_normal_map {
            map,
            input: InputInfo {
                path,
                options,
                stats,
            },
        }
    }

    /// A handle for `map` (tests of other C API modules).
    #[cfg(test)]
    pub(crate) fn from_map_for_tests(map: NormalMap) -> Self {
        ndf_normal_map::new(map, None, IngestOptions::default())
    }
}

/// Reads the options argument of a map entry point.
///
/// # Safety
/// As [`options`].
unsafe fn ingest_options(p: *const ndf_ingest_options) -> Outcome<IngestOptions> {
    // SAFETY: forwarded from the entry point's contract.
    unsafe { read_options(p, "options", "ndf_ingest_options_default") }?.to_rust()
}

/// Stores a new map in `out`.
///
/// # Safety
/// `out` is valid for writes of a pointer.
unsafe fn hand_out(map: ndf_normal_map, out: Out<*mut ndf_normal_map>) -> Outcome {
    // SAFETY: forwarded from the caller; the Box is released by ndf_normal_map_free.
    unsafe { out.write(Box::into_raw(Box::new(map))) };
    Ok(())
}

/// Reads a normal map from a PNG, JPEG, TGA, TIFF (8 or 16 bit, or float) or OpenEXR (half or
/// float) file. The format is detected from the content, the extension decides only for TGA.
/// - `path`: a NUL-terminated file name (bytes as the OS takes them).
/// - `options`: from `ndf_ingest_options_default()`, possibly changed.
/// - `map_out`: receives the new map, to be released with `ndf_normal_map_free`.
/// - Fails with `NDF_STATUS_READ`, `_DECODE`, `_DIMENSIONS`, `_UNSUPPORTED_LAYOUT` or
///   `_BAD_NORMALS`, as the message explains.
///
/// # Safety
/// Pointers are NULL or valid as described; `map_out` is writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_normal_map_load_file(
    path: *const c_char,
    options: *const ndf_ingest_options,
    map_out: *mut *mut ndf_normal_map,
) -> ndf_status {
    guard("ndf_normal_map_load_file", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let file = super::path(unsafe { c_str(path, "path") }?, "path")?;
        let opts = unsafe { ingest_options(options) }?;
        let out = Out::new(map_out, "map_out")?;
        let map = NormalMap::load(&file, &opts)?;
        let info = ndf_normal_map::new(map, Some(file.display().to_string()), opts);
        unsafe { hand_out(info, out) }
    })
}

/// Reads a normal map from the bytes of an image file held in memory (any format
/// `ndf_normal_map_load_file` reads).
/// - `data`, `length`: the file's bytes; `data` must not be NULL, even when `length` is 0.
/// - `name`: NUL-terminated; errors name it, and its extension decides the format when the
///   content does not (TGA: pass e.g. `"albedo.tga"`).
/// - `options`, `map_out`: as for `ndf_normal_map_load_file`.
///
/// # Safety
/// `data` is NULL or readable for `length` bytes; the other pointers as for
/// `ndf_normal_map_load_file`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_normal_map_load_memory(
    data: *const c_void,
    length: usize,
    name: *const c_char,
    options: *const ndf_ingest_options,
    map_out: *mut *mut ndf_normal_map,
) -> ndf_status {
    guard("ndf_normal_map_load_memory", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let data = unsafe { bytes(data, length, "data") }?;
        let name = text(unsafe { c_str(name, "name") }?);
        let opts = unsafe { ingest_options(options) }?;
        let out = Out::new(map_out, "map_out")?;
        let map = NormalMap::load_memory(&name, data, &opts)?;
        unsafe { hand_out(ndf_normal_map::new(map, Some(name), opts), out) }
    })
}

/// Interleaved samples of a caller pixel buffer, as the ingest code takes them: borrowed when
/// the buffer is aligned for the sample type, copied otherwise.
enum Pixels<'a> {
    Borrowed(Samples<'a>),
    U16(Vec<u16>),
    F32(Vec<f32>),
}

impl Pixels<'_> {
    fn samples(&self) -> Samples<'_> {
        match self {
            Pixels::Borrowed(s) => *s,
            Pixels::U16(v) => Samples::U16(v),
            Pixels::F32(v) => Samples::F32(v),
        }
    }
}

/// The samples in `data` (whole samples only; a trailing partial one is ignored).
fn pixels(data: &[u8], sample_type: ndf_sample_type) -> Outcome<Pixels<'_>> {
    const TYPES: [ndf_sample_type; 3] = [NDF_SAMPLE_UINT8, NDF_SAMPLE_UINT16, NDF_SAMPLE_FLOAT32];
    Ok(match choose("sample_type", sample_type, &TYPES)? {
        NDF_SAMPLE_UINT8 => Pixels::Borrowed(Samples::U8(data)),
        NDF_SAMPLE_UINT16 => {
            // SAFETY: u16 has no invalid bit patterns, and align_to never returns a misaligned
            // middle part. Borrowed only when the middle holds every whole sample.
            match unsafe { data.align_to::<u16>() } {
                ([], mid, rest) if rest.len() < 2 => Pixels::Borrowed(Samples::U16(mid)),
                _ => Pixels::U16(
                    data.chunks_exact(2)
                        .map(|c| u16::from_ne_bytes([c[0], c[1]]))
                        .collect(),
                ),
            }
        }
        _ => {
            // SAFETY: as above, f32 has no invalid bit patterns.
            match unsafe { data.align_to::<f32>() } {
                ([], mid, rest) if rest.len() < 4 => Pixels::Borrowed(Samples::F32(mid)),
                _ => Pixels::F32(
                    data.chunks_exact(4)
                        .map(|c| f32::from_ne_bytes([c[0], c[1], c[2], c[3]]))
                        .collect(),
                ),
            }
        }
    })
}

/// Builds a normal map from pixels in caller memory: `channels` interleaved samples per texel,
/// rows top to bottom, tightly packed.
/// - `pixels`, `length`: the buffer and its length in bytes; it must hold at least
///   `width × height × channels` samples (`NDF_STATUS_SHORT_PIXELS` otherwise). Any alignment.
/// - `width`, `height`: at least 1, each at most 65536, at most 2^28 texels in all
///   (`NDF_STATUS_DIMENSIONS` otherwise).
/// - `channels`: 2 (x, y; z reconstructed), 3 or 4 (x, y, z; the fourth is ignored).
/// - `sample_type`: `NDF_SAMPLE_UINT8`, `NDF_SAMPLE_UINT16` or `NDF_SAMPLE_FLOAT32`.
/// - `options`: the convention (encoding, green direction, ...); `map_out` as for
///   `ndf_normal_map_load_file`.
///
/// # Safety
/// `pixels` is NULL or readable for `length` bytes; the other pointers as for
/// `ndf_normal_map_load_file`.
#[unsafe(no_mangle)]
#[allow(clippy::too_many_arguments)]
pub unsafe extern "C" fn ndf_normal_map_from_pixels(
    pixels: *const c_void,
    length: usize,
    width: u32,
    height: u32,
    channels: u32,
    sample_type: ndf_sample_type,
    options: *const ndf_ingest_options,
    map_out: *mut *mut ndf_normal_map,
) -> ndf_status {
    guard("ndf_normal_map_from_pixels", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let data = unsafe { bytes(pixels, length, "pixels") }?;
        let opts = unsafe { ingest_options(options) }?;
        let out = Out::new(map_out, "map_out")?;
        let px = self::pixels(data, sample_type)?;
        let map = NormalMap::from_samples("pixels", width, height, channels, px.samples(), &opts)?;
        unsafe { hand_out(ndf_normal_map::new(map, None, opts), out) }
    })
}

/// Replaces `map`'s feature by `attach(map)`; on failure `map` is left as it was.
fn attach(
    map: &mut ndf_normal_map,
    attach: impl FnOnce(NormalMap) -> crate::Result<NormalMap>,
) -> Outcome {
    map.map = attach(map.map.clone())?;
    Ok(())
}

/// Attaches a feature (albedo colour) image read from a file to `map`; a bake of `map` with
/// colour-capable methods (vMF) then also filters the colour per lobe (eq 22).
/// - The image must have the map's size (`NDF_STATUS_FEATURE_SIZE`); formats as for
///   `ndf_normal_map_load_file`; OpenEXR needs R, G, B (or Y).
/// - `options->feature_encoding` decides sRGB or linear decoding.
/// - On failure `map` is unchanged. `map` must not be used by another thread meanwhile.
///
/// # Safety
/// `map` is NULL or a live map; `path` and `options` as for `ndf_normal_map_load_file`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_normal_map_attach_feature_file(
    map: *mut ndf_normal_map,
    path: *const c_char,
    options: *const ndf_ingest_options,
) -> ndf_status {
    guard("ndf_normal_map_attach_feature_file", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let map = unsafe { arg_mut(map, "map") }?;
        let file = super::path(unsafe { c_str(path, "path") }?, "path")?;
        let opts = unsafe { ingest_options(options) }?;
        attach(map, |m| m.with_feature_file(&file, &opts))
    })
}

/// Attaches a feature (albedo colour) image held in memory as an image file's bytes.
/// - `data`, `length`, `name`: as for `ndf_normal_map_load_memory`; the rest as for
///   `ndf_normal_map_attach_feature_file`.
///
/// # Safety
/// `map` is NULL or a live map; the other pointers as for `ndf_normal_map_load_memory`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_normal_map_attach_feature_memory(
    map: *mut ndf_normal_map,
    data: *const c_void,
    length: usize,
    name: *const c_char,
    options: *const ndf_ingest_options,
) -> ndf_status {
    guard("ndf_normal_map_attach_feature_memory", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let map = unsafe { arg_mut(map, "map") }?;
        let data = unsafe { bytes(data, length, "data") }?;
        let name = text(unsafe { c_str(name, "name") }?);
        let opts = unsafe { ingest_options(options) }?;
        attach(map, |m| m.with_feature_memory(&name, data, &opts))
    })
}

/// Attaches a feature (albedo colour) image from pixels in caller memory.
/// - `pixels`, `length`, `width`, `height`, `sample_type`: as for
///   `ndf_normal_map_from_pixels`; `width` and `height` must be the map's.
/// - `channels`: 1 (grey), 2 (grey, alpha), 3 (RGB) or 4 (RGBA); missing alpha is 1.
/// - Integer RGB is decoded from sRGB unless `options->feature_encoding` is
///   `NDF_FEATURE_ENCODING_LINEAR`; floats are linear. On failure `map` is unchanged.
///
/// # Safety
/// `map` is NULL or a live map; the other pointers as for `ndf_normal_map_from_pixels`.
#[unsafe(no_mangle)]
#[allow(clippy::too_many_arguments)]
pub unsafe extern "C" fn ndf_normal_map_attach_feature_pixels(
    map: *mut ndf_normal_map,
    pixels: *const c_void,
    length: usize,
    width: u32,
    height: u32,
    channels: u32,
    sample_type: ndf_sample_type,
    options: *const ndf_ingest_options,
) -> ndf_status {
    guard("ndf_normal_map_attach_feature_pixels", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let map = unsafe { arg_mut(map, "map") }?;
        let data = unsafe { bytes(pixels, length, "pixels") }?;
        let opts = unsafe { ingest_options(options) }?;
        let px = self::pixels(data, sample_type)?;
        attach(map, |m| {
            m.with_feature_samples(
                "feature pixels",
                width,
                height,
                channels,
                px.samples(),
                &opts,
            )
        })
    })
}

/// The map's size in texels.
///
/// # Safety
/// `map` is NULL or a live map; the out-pointers are NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_normal_map_size(
    map: *const ndf_normal_map,
    width_out: *mut u32,
    height_out: *mut u32,
) -> ndf_status {
    guard("ndf_normal_map_size", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let map = unsafe { arg(map, "map") }?;
        let (w, h) = (
            Out::new(width_out, "width_out")?,
            Out::new(height_out, "height_out")?,
        );
        unsafe { w.write(map.map.width()) };
        unsafe { h.write(map.map.height()) };
        Ok(())
    })
}

/// How many bad normals (zero-length, NaN, below the horizon) ingest found and repaired.
///
/// # Safety
/// `map` is NULL or a live map; `count_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_normal_map_bad_normal_count(
    map: *const ndf_normal_map,
    count_out: *mut u64,
) -> ndf_status {
    guard("ndf_normal_map_bad_normal_count", || {
        // SAFETY (both blocks): the pointers are NULL or valid, as this function requires.
        let map = unsafe { arg(map, "map") }?;
        let out = Out::new(count_out, "count_out")?;
        unsafe { out.write(map.map.stats().bad_total()) };
        Ok(())
    })
}

/// Releases a map. NULL is fine. Must not be called twice with the same map (undefined
/// behaviour), nor while another call uses it; bakes made from it stay valid.
///
/// # Safety
/// `map` is NULL or a map from this library not yet freed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_normal_map_free(map: *mut ndf_normal_map) {
    guard_value((), || {
        if !map.is_null() {
            // SAFETY: a live map was made by Box::into_raw in hand_out and is freed once.
            drop(unsafe { Box::from_raw(map) });
        }
    })
}
