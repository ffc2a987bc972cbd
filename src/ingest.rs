//! Normal-map ingest: decode an image into unit tangent-space normals, with the conventions
//! a user expects (OpenGL/DirectX green, 2-channel maps with z reconstructed, unsigned or signed
//! encoding, wrap or clamp addressing), and report what was wrong with the input.
//!
//! Pixels are linear data: ndfmap never applies sRGB decoding to normals. An optional feature
//! image (albedo colour) of the same size rides along for eq 22's colour filtering.
//!
//! Main types: [`NormalMap`], [`IngestOptions`], [`IngestStats`].

use crate::error::{Error, Result};
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Largest width or height accepted (texels).
pub const MAX_DIMENSION: u32 = 65_536;
/// Largest texel count accepted (width × height): 2^28, a 16384² map.
pub const MAX_TEXELS: u64 = 1 << 28;

/// Direction of the green channel in the tangent frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GreenChannel {
    /// +Y up (OpenGL, Blender, most CC0 libraries): green is the bitangent as stored.
    #[default]
    OpenGl,
    /// −Y (DirectX, Unreal): the green channel is negated on ingest.
    DirectX,
}

/// How stored values map to normal components.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Encoding {
    /// Unsigned-normalized for integer images, signed for float images.
    #[default]
    Auto,
    /// Stored value v in [0, 1] (after dividing by the integer maximum) means 2v − 1.
    Unorm,
    /// Stored values are the components themselves, in [−1, 1].
    Snorm,
}

/// Which channels carry the normal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Channels {
    /// RGB(A) images are read as xyz; 2-channel (grey+alpha, or EXR with only R and G) as xy.
    #[default]
    Auto,
    /// x, y, z from R, G, B.
    Xyz,
    /// x, y from R, G (BC5/"RG" maps); z = sqrt(1 − x² − y²) is reconstructed.
    Xy,
}

/// Texture addressing at the edges: how footprints and filters that cross an edge behave.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Addressing {
    /// The map tiles: texel −1 is texel width−1.
    #[default]
    Wrap,
    /// Coordinates clamp to the edge texel.
    Clamp,
}

/// What to do with zero-length, NaN, or below-horizon normals, and with NaN, infinite or
/// negative values in a feature (colour) image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BadNormals {
    /// Replace zero-length and NaN normals by +Z, clamp below-horizon normals onto the horizon
    /// (z = 0, same azimuth; +Z for a normal pointing straight down), replace NaN and infinite
    /// feature values by 0 and clamp negative ones to 0, and report counts.
    #[default]
    Repair,
    /// Fail with [`Error::BadNormals`] (or [`Error::BadFeatures`]) naming the first bad texel.
    Reject,
}

/// How the feature (colour) image's values are decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FeatureEncoding {
    /// 8/16-bit colour is sRGB-encoded (albedo maps usually are): decode to linear so that
    /// averages are physically meaningful. Float images are taken as linear.
    #[default]
    Srgb,
    /// Values are used as stored (divided by the integer maximum).
    Linear,
}

/// Options for reading a normal map. `Default` gives OpenGL, auto encoding and channels,
/// wrap addressing, repair bad normals, and the machine's default memory budget.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct IngestOptions {
    /// Green channel direction.
    pub green: GreenChannel,
    /// Value encoding.
    pub encoding: Encoding,
    /// Channel layout.
    pub channels: Channels,
    /// Edge addressing (recorded in the map; used by footprints and filters).
    pub addressing: Addressing,
    /// Bad-normal policy (also applied to bad feature values).
    pub bad_normals: BadNormals,
    /// Feature image encoding.
    pub feature_encoding: FeatureEncoding,
    /// Memory budget of one load, in bytes: a file whose decoding would need more (its bytes,
    /// the decoder's buffers and the decoded map, estimated from its header before any pixel
    /// is decoded) is refused with [`Error::MemoryBudget`], as is a file larger than the budget.
    /// `None` (default): [`crate::budget::default_memory_limit`]. Not recorded in manifests.
    #[serde(skip)]
    pub memory_limit: Option<u64>,
}

/// Count and first position (x, y) of one kind of bad normal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct BadCount {
    /// How many texels.
    pub count: u64,
    /// The first one in scan-line order, if any.
    pub first: Option<(u32, u32)>,
}

/// What ingest found in the input.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct IngestStats {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Channels in the source image.
    pub source_channels: u32,
    /// Bits per channel in the source (8, 16, 32 for float; 16 for half EXR).
    pub source_bits: u32,
    /// The encoding actually applied (never `Auto`).
    pub encoding: Encoding,
    /// Whether z was reconstructed from x and y.
    pub reconstructed_z: bool,
    /// Mean z of the normals after renormalization and repair.
    pub mean_z: f64,
    /// Mean length of the decoded vectors before renormalization (finite, non-zero ones).
    pub mean_length: f64,
    /// Zero-length vectors (every component zero; any other length is renormalized in `f64`).
    pub zero_length: BadCount,
    /// Vectors with a NaN or infinite component.
    pub nan: BadCount,
    /// Vectors with z < 0 (below the tangent-plane horizon).
    pub below_horizon: BadCount,
    /// Feature texels with a NaN or infinite value (repaired to 0 unless rejected).
    #[serde(default)]
    pub feature_nan: BadCount,
    /// Feature texels with a negative value (clamped to 0 unless rejected).
    #[serde(default)]
    pub feature_negative: BadCount,
}

impl IngestStats {
    /// Total number of bad normals of every kind.
    pub fn bad_total(&self) -> u64 {
        self.zero_length.count + self.nan.count + self.below_horizon.count
    }
}

/// Caller-provided pixel samples, interleaved `channels` per texel, rows top to bottom.
#[derive(Debug, Clone, Copy)]
pub enum Samples<'a> {
    /// 8-bit unsigned.
    U8(&'a [u8]),
    /// 16-bit unsigned.
    U16(&'a [u16]),
    /// 32-bit float.
    F32(&'a [f32]),
}

/// A decoded normal map: unit tangent-space normals (z ≥ 0), row-major, top row first, with an
/// optional per-texel feature (linear RGBA) of the same size.
#[derive(Debug, Clone)]
pub struct NormalMap {
    width: u32,
    height: u32,
    normals: Vec<Vec3>,
    feature: Option<Vec<[f32; 4]>>,
    addressing: Addressing,
    stats: IngestStats,
}

impl NormalMap {
    /// Builds a map from already-decoded tangent-space vectors (row-major, top row first).
    /// Vectors are renormalized and bad ones handled per `bad_normals`, exactly as for files.
    pub fn from_vectors(
        width: u32,
        height: u32,
        vectors: Vec<Vec3>,
        addressing: Addressing,
        bad_normals: BadNormals,
    ) -> Result<Self> {
        let what = "normal vectors";
        check_dimensions(what, width as u64, height as u64)?;
        let needed = width as usize * height as usize;
        if vectors.len() != needed {
            return Err(Error::ShortBuffer {
                what: what.into(),
                got: vectors.len(),
                needed,
            });
        }
        let stats = IngestStats {
            width,
            height,
            source_channels: 3,
            source_bits: 32,
            encoding: Encoding::Snorm,
            ..IngestStats::default()
        };
        finish(what, width, height, vectors, addressing, bad_normals, stats)
    }

    /// Width in texels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in texels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// All unit normals, row-major, top row first.
    pub fn normals(&self) -> &[Vec3] {
        &self.normals
    }

    /// The unit normal at column `x`, row `y`.
    pub fn normal(&self, x: u32, y: u32) -> Vec3 {
        self.normals[y as usize * self.width as usize + x as usize]
    }

    /// The per-texel feature (linear RGBA), if a feature image was attached.
    pub fn feature(&self) -> Option<&[[f32; 4]]> {
        self.feature.as_deref()
    }

    /// Edge addressing used by footprints and filters.
    pub fn addressing(&self) -> Addressing {
        self.addressing
    }

    /// Changes the edge addressing.
    pub fn set_addressing(&mut self, addressing: Addressing) {
        self.addressing = addressing;
    }

    /// What ingest found in the input.
    pub fn stats(&self) -> &IngestStats {
        &self.stats
    }

    /// Attaches a per-texel feature (linear RGBA, row-major). Its length must be width × height
    /// and every value finite and ≥ 0 ([`Error::BadFeatures`] otherwise; the image readers
    /// repair or reject such values as [`IngestOptions::bad_normals`] says).
    pub fn with_feature(self, mut feature: Vec<[f32; 4]>) -> Result<Self> {
        let needed = self.width as usize * self.height as usize;
        if feature.len() != needed {
            return Err(Error::ShortBuffer {
                what: "feature".into(),
                got: feature.len(),
                needed,
            });
        }
        self.attach_feature("feature", &mut feature, BadNormals::Reject)
            .map(|map| NormalMap {
                feature: Some(feature),
                ..map
            })
    }

    /// Checks (and under [`BadNormals::Repair`] repairs) feature values, counting NaN or
    /// infinite and negative ones in the statistics; the caller stores `feature`.
    fn attach_feature(
        mut self,
        what: &str,
        feature: &mut [[f32; 4]],
        policy: BadNormals,
    ) -> Result<Self> {
        let (nan, negative) = repair_feature(what, self.width, feature, policy)?;
        self.stats.feature_nan = nan;
        self.stats.feature_negative = negative;
        Ok(self)
    }
}

/// Checks and repairs feature values of a map `width` wide (NaN or infinite → 0, negative → 0),
/// counting both kinds; under [`BadNormals::Reject`] a bad value is [`Error::BadFeatures`].
/// Returns the NaN and the negative counts.
fn repair_feature(
    what: &str,
    width: u32,
    feature: &mut [[f32; 4]],
    policy: BadNormals,
) -> Result<(BadCount, BadCount)> {
    let mut nan = BadCount::default();
    let mut negative = BadCount::default();
    for (i, texel) in feature.iter_mut().enumerate() {
        if texel.iter().any(|v| !v.is_finite()) {
            nan.note(i, width);
            texel
                .iter_mut()
                .filter(|v| !v.is_finite())
                .for_each(|v| *v = 0.0);
        }
        if texel.iter().any(|v| *v < 0.0) {
            negative.note(i, width);
            texel.iter_mut().for_each(|v| *v = v.max(0.0));
        }
    }
    if policy == BadNormals::Reject
        && let Some((kind, (x, y))) = first_bad(&[("NaN or infinite", nan), ("negative", negative)])
    {
        return Err(Error::BadFeatures {
            what: what.to_string(),
            count: nan.count + negative.count,
            kind,
            x,
            y,
        });
    }
    Ok((nan, negative))
}

impl BadCount {
    /// Counts texel `i` (row-major in a map `width` wide), keeping the first position.
    fn note(&mut self, i: usize, width: u32) {
        if self.first.is_none() {
            self.first = Some(((i % width as usize) as u32, (i / width as usize) as u32));
        }
        self.count += 1;
    }
}

/// The kind and position of the first bad texel in scan-line order among `counts`, if any.
fn first_bad(counts: &[(&'static str, BadCount)]) -> Option<(&'static str, (u32, u32))> {
    counts
        .iter()
        .filter_map(|&(k, c)| c.first.map(|f| (k, f)))
        .min_by_key(|&(_, (x, y))| (y, x))
}

/// The first four bytes of every OpenEXR file.
const EXR_MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];

impl NormalMap {
    /// Reads a normal map from a PNG, JPEG, TGA, TIFF or OpenEXR file.
    ///
    /// The format is detected from the file's content (magic bytes); the extension is used
    /// only when the content does not say (TGA has no signature). PNG, JPEG, TGA and TIFF are
    /// decoded with the `image` crate (8 or 16 bits per channel, or 32-bit float TIFF); OpenEXR
    /// with the `exr` crate (half or float channels `R` and `G`, `B` optional, from the first
    /// layer).
    ///
    /// Values are converted as described by `opts` (see [`NormalMap::from_samples`]); pixels are
    /// linear data, no sRGB or gamma decoding is ever applied. A grey + alpha image is not
    /// taken for x and y unless `opts.channels` is [`Channels::Xy`] (it is far more often a
    /// height map with a mask).
    ///
    /// Decoding is bounded (module docs of [`crate::budget`]): only regular files are read (a
    /// FIFO, a device or a folder is refused before it is opened for reading); sizes are checked
    /// from the header, and the memory the decoding needs is estimated from it and checked
    /// against `opts.memory_limit` before any pixel buffer is allocated; OpenEXR files are read
    /// channel by channel, only the channels used. JPEG is decoded strictly: a file that ends
    /// before its end-of-image marker, or whose coded data is corrupt, is an error, never an
    /// image filled with grey.
    ///
    /// # Errors
    ///
    /// [`Error::Read`] if the file cannot be read or is not a regular file, [`Error::Decode`] if
    /// it is empty, corrupt, truncated or of an unknown or unsupported format,
    /// [`Error::Dimensions`] if its size is absurd, [`Error::MemoryBudget`] if decoding it
    /// would exceed the memory budget, [`Error::UnsupportedLayout`] for one-channel (grey)
    /// images, grey + alpha images under [`Channels::Auto`], EXR files without `R` and `G`, or a
    /// channel layout that contradicts `opts.channels`, and [`Error::BadNormals`] if
    /// `opts.bad_normals` is [`BadNormals::Reject`] and a texel is bad.
    pub fn load(path: &Path, opts: &IngestOptions) -> Result<NormalMap> {
        let bytes = read_file(path, opts.memory_limit)?;
        Self::from_decoded(
            path,
            decode_bytes(path, &bytes, Purpose::Normals, opts)?,
            opts,
        )
    }

    /// Reads a normal map from the bytes of an image file held in memory, exactly as
    /// [`NormalMap::load`] reads a file. `name` stands for the file name: errors name it, and
    /// its extension decides the format when the content does not (TGA has no signature).
    ///
    /// # Errors
    ///
    /// Those of [`NormalMap::load`] except [`Error::Read`].
    pub fn load_memory(name: &str, bytes: &[u8], opts: &IngestOptions) -> Result<NormalMap> {
        let path = Path::new(name);
        Self::from_decoded(
            path,
            decode_bytes(path, bytes, Purpose::Normals, opts)?,
            opts,
        )
    }

    fn from_decoded(path: &Path, decoded: Decoded, opts: &IngestOptions) -> Result<NormalMap> {
        if decoded.luma_alpha && opts.channels == Channels::Auto {
            return Err(Error::UnsupportedLayout {
                what: path.display().to_string(),
                layout: "grey + alpha (2 channels): probably a height map with a mask, not a \
                         normal map; if it holds x and y, read it with channels = xy \
                         (--channels xy)"
                    .to_string(),
            });
        }
        convert_normals(
            &path.display().to_string(),
            decoded.width,
            decoded.height,
            decoded.channels,
            decoded.samples.as_samples(),
            decoded.bits,
            opts,
        )
    }

    /// Builds a map from pixel samples in caller memory: `channels` (1 to 4) interleaved
    /// samples per texel, rows top to bottom. `what` names the buffer in error messages.
    ///
    /// Conversion, per texel:
    /// - Encoding ([`IngestOptions::encoding`]): `Auto` is `Unorm` for integer samples and
    ///   `Snorm` for float samples. `Unorm` maps a value `c` to `2c/max − 1` (`max` = 255,
    ///   65535, or 1 for floats). `Snorm` takes floats as they are and reads integers as two's
    ///   complement (GPU SNORM: `max(s / 127, −1)` for 8 bits, `max(s / 32767, −1)` for 16).
    /// - Channels ([`IngestOptions::channels`]): `Auto` reads x, y, z from the first three
    ///   channels of a 3- or 4-channel image and reconstructs z from x and y of a 2-channel
    ///   image; `Xy` always reconstructs z from the first two channels (the third, if any, is
    ///   ignored); `Xyz` requires at least three channels. Reconstruction is
    ///   z = sqrt(1 − x² − y²), and if x² + y² > 1, (x, y) is normalized and z = 0.
    /// - Green ([`IngestOptions::green`]): `DirectX` negates y.
    ///
    /// The vectors are then renormalized and bad ones repaired or rejected
    /// ([`IngestOptions::bad_normals`]); [`NormalMap::stats`] reports what was found.
    ///
    /// # Errors
    ///
    /// [`Error::Dimensions`] for zero, absurd or overflowing sizes, [`Error::UnsupportedLayout`]
    /// for `channels` outside 1..=4, one channel (a grey image is a height map, not a normal
    /// map), or `Xyz` with two channels, [`Error::ShortBuffer`] if `samples` holds fewer than
    /// `width × height × channels` values, and [`Error::BadNormals`] under
    /// [`BadNormals::Reject`].
    pub fn from_samples(
        what: &str,
        width: u32,
        height: u32,
        channels: u32,
        samples: Samples<'_>,
        opts: &IngestOptions,
    ) -> Result<NormalMap> {
        let bits = samples_bits(samples);
        convert_normals(what, width, height, channels, samples, bits, opts)
    }

    /// Reads a feature (albedo colour) image from a file and attaches it to the map.
    ///
    /// Accepts the same formats as [`NormalMap::load`]; OpenEXR feature images need channels
    /// `R`, `G`, `B` (or a grey `Y`), `A` optional. The image is converted to linear RGBA as in
    /// [`NormalMap::with_feature_samples`].
    ///
    /// # Errors
    ///
    /// The decoding errors of [`NormalMap::load`], and [`Error::FeatureSize`] if the image's
    /// size differs from the normal map's.
    pub fn with_feature_file(self, path: &Path, opts: &IngestOptions) -> Result<NormalMap> {
        let bytes = read_file(path, opts.memory_limit)?;
        let size = Some((self.width(), self.height()));
        self.with_feature_decoded(
            path,
            decode_bytes_kept(path, &bytes, Purpose::Feature, opts, false, size)?,
            opts,
        )
    }

    /// Attaches a feature (albedo colour) image read from the bytes of an image file held in
    /// memory, as [`NormalMap::with_feature_file`] reads a file; `name` is as for
    /// [`NormalMap::load_memory`].
    pub fn with_feature_memory(
        self,
        name: &str,
        bytes: &[u8],
        opts: &IngestOptions,
    ) -> Result<NormalMap> {
        let path = Path::new(name);
        let size = Some((self.width(), self.height()));
        self.with_feature_decoded(
            path,
            decode_bytes_kept(path, bytes, Purpose::Feature, opts, false, size)?,
            opts,
        )
    }

    fn with_feature_decoded(
        self,
        path: &Path,
        decoded: Decoded,
        opts: &IngestOptions,
    ) -> Result<NormalMap> {
        self.with_feature_samples(
            &path.display().to_string(),
            decoded.width,
            decoded.height,
            decoded.channels,
            decoded.samples.as_samples(),
            opts,
        )
    }

    /// Attaches a feature (albedo colour) image from pixel samples in caller memory:
    /// `channels` (1 to 4) interleaved samples per texel, rows top to bottom, the normal map's
    /// size.
    ///
    /// Samples are converted to linear RGBA `f32`: grey is replicated to RGB, a missing alpha
    /// is 1. Integer samples are divided by their maximum (255 or 65535) and, when
    /// [`IngestOptions::feature_encoding`] is [`FeatureEncoding::Srgb`], their RGB (not alpha)
    /// is decoded with the sRGB transfer function. Float samples are taken as linear.
    ///
    /// # Errors
    ///
    /// [`Error::FeatureSize`] if `width × height` differs from the normal map's size,
    /// [`Error::UnsupportedLayout`] for `channels` outside 1..=4, [`Error::ShortBuffer`] if
    /// `samples` is too short, and [`Error::BadFeatures`] for NaN, infinite or negative values
    /// under [`BadNormals::Reject`] (under [`BadNormals::Repair`] they become 0 and are counted
    /// in [`IngestStats::feature_nan`] and [`IngestStats::feature_negative`]).
    pub fn with_feature_samples(
        self,
        what: &str,
        width: u32,
        height: u32,
        channels: u32,
        samples: Samples<'_>,
        opts: &IngestOptions,
    ) -> Result<NormalMap> {
        if (width, height) != (self.width, self.height) {
            return Err(Error::FeatureSize {
                what: what.to_string(),
                feature_width: width,
                feature_height: height,
                width: self.width,
                height: self.height,
            });
        }
        let texels = check_buffer(what, width, height, channels, samples)?;
        let mut feature =
            convert_feature(channels as usize, samples, texels, opts.feature_encoding);
        let map = self.attach_feature(what, &mut feature, opts.bad_normals)?;
        Ok(NormalMap {
            feature: Some(feature),
            ..map
        })
    }
}

/// Bits per sample of a caller buffer.
fn samples_bits(samples: Samples<'_>) -> u32 {
    match samples {
        Samples::U8(_) => 8,
        Samples::U16(_) => 16,
        Samples::F32(_) => 32,
    }
}

/// Number of samples in a caller buffer.
fn samples_len(samples: Samples<'_>) -> usize {
    match samples {
        Samples::U8(s) => s.len(),
        Samples::U16(s) => s.len(),
        Samples::F32(s) => s.len(),
    }
}

/// Checks dimensions, channel count and buffer length; returns the texel count.
fn check_buffer(
    what: &str,
    width: u32,
    height: u32,
    channels: u32,
    samples: Samples<'_>,
) -> Result<usize> {
    check_dimensions(what, width as u64, height as u64)?;
    if !(1..=4).contains(&channels) {
        return Err(Error::UnsupportedLayout {
            what: what.to_string(),
            layout: format!("{channels} channels per texel; 1 to 4 are supported"),
        });
    }
    // check_dimensions bounds width × height by MAX_TEXELS (2^28), so these cannot overflow
    // even with a 32-bit usize; checked arithmetic keeps that an error rather than a panic.
    let texels = (width as usize).checked_mul(height as usize);
    let needed = texels.and_then(|t| t.checked_mul(channels as usize));
    let (Some(texels), Some(needed)) = (texels, needed) else {
        return Err(Error::Dimensions {
            what: what.to_string(),
            width: width as u64,
            height: height as u64,
            reason: "the sample count overflows this platform's address space".to_string(),
        });
    };
    let got = samples_len(samples);
    if got < needed {
        return Err(Error::ShortBuffer {
            what: what.to_string(),
            got,
            needed,
        });
    }
    Ok(texels)
}

/// The one conversion from interleaved samples to a [`NormalMap`], shared by
/// [`NormalMap::load`] and [`NormalMap::from_samples`]. `source_bits` is recorded in the
/// statistics (it differs from the sample type for half-float EXR files).
fn convert_normals(
    what: &str,
    width: u32,
    height: u32,
    channels: u32,
    samples: Samples<'_>,
    source_bits: u32,
    opts: &IngestOptions,
) -> Result<NormalMap> {
    let (layout, unorm, stats) =
        source_layout(what, width, height, channels, samples, source_bits, opts)?;
    let vectors = match samples {
        Samples::U8(data) => layout.gather(data, if unorm { unorm8 } else { snorm8 }),
        Samples::U16(data) => layout.gather(data, if unorm { unorm16 } else { snorm16 }),
        Samples::F32(data) => layout.gather(data, if unorm { unorm_f32 } else { snorm_f32 }),
    };
    finish(
        what,
        width,
        height,
        vectors,
        opts.addressing,
        opts.bad_normals,
        stats,
    )
}

/// How `samples` (`channels` per texel) are read as vectors under `opts`: the layout, whether
/// the encoding is unorm, and the statistics so far — or the layout error.
fn source_layout(
    what: &str,
    width: u32,
    height: u32,
    channels: u32,
    samples: Samples<'_>,
    source_bits: u32,
    opts: &IngestOptions,
) -> Result<(Layout, bool, IngestStats)> {
    let texels = check_buffer(what, width, height, channels, samples)?;
    let layout_error = |layout: String| Error::UnsupportedLayout {
        what: what.to_string(),
        layout,
    };
    let reconstruct = match (opts.channels, channels) {
        (_, 1) => {
            return Err(layout_error(
                "one channel (grey): this is probably a height or bump map, not a normal map; \
                 convert it to a normal map first (2 channels x, y or 3 channels x, y, z)"
                    .to_string(),
            ));
        }
        (Channels::Xyz, 2) => {
            return Err(layout_error(
                "2 channels, but channels = xyz needs 3 or 4 (use xy or auto to reconstruct z)"
                    .to_string(),
            ));
        }
        (Channels::Auto, 2) | (Channels::Xy, _) => true,
        (Channels::Auto | Channels::Xyz, _) => false,
    };
    let is_float = matches!(samples, Samples::F32(_));
    let encoding = match opts.encoding {
        Encoding::Auto if is_float => Encoding::Snorm,
        Encoding::Auto => Encoding::Unorm,
        e => e,
    };
    let unorm = encoding == Encoding::Unorm;
    let layout = Layout {
        channels: channels as usize,
        texels,
        reconstruct,
        y_sign: match opts.green {
            GreenChannel::OpenGl => 1.0,
            GreenChannel::DirectX => -1.0,
        },
    };
    let stats = IngestStats {
        width,
        height,
        source_channels: channels,
        source_bits,
        encoding,
        reconstructed_z: reconstruct,
        ..IngestStats::default()
    };
    Ok((layout, unorm, stats))
}

/// How interleaved samples become vectors.
#[derive(Debug, Clone)]
struct Layout {
    channels: usize,
    texels: usize,
    reconstruct: bool,
    /// −1 negates y (DirectX green).
    y_sign: f32,
}

impl Layout {
    /// Decodes every texel with `component` (the value encoding) into a raw vector.
    fn gather<T: Copy>(&self, data: &[T], component: fn(T) -> f32) -> Vec<Vec3> {
        data.chunks_exact(self.channels)
            .take(self.texels)
            .map(|px| self.vector(px, component))
            .collect()
    }

    /// One texel's raw vector from its samples `px`.
    fn vector<T: Copy>(&self, px: &[T], component: fn(T) -> f32) -> Vec3 {
        let x = component(px[0]);
        let y = self.y_sign * component(px[1]);
        if self.reconstruct {
            reconstruct_z(x, y)
        } else {
            Vec3::new(x, y, component(px[2]))
        }
    }
}

/// (x, y, sqrt(1 − x² − y²)); if x² + y² > 1, (x, y) is normalized and z = 0. Non-finite
/// input gives a non-finite vector, which `finish` reports as NaN.
fn reconstruct_z(x: f32, y: f32) -> Vec3 {
    let s = x * x + y * y;
    if s > 1.0 {
        let l = s.sqrt();
        Vec3::new(x / l, y / l, 0.0)
    } else {
        Vec3::new(x, y, (1.0 - s).sqrt())
    }
}

fn unorm8(c: u8) -> f32 {
    2.0 * c as f32 / 255.0 - 1.0
}

fn unorm16(c: u16) -> f32 {
    2.0 * c as f32 / 65535.0 - 1.0
}

fn unorm_f32(v: f32) -> f32 {
    2.0 * v - 1.0
}

/// Two's-complement 8-bit SNORM, as GPUs read it: −128 and −127 both mean −1.
fn snorm8(c: u8) -> f32 {
    (c as i8 as f32 / 127.0).max(-1.0)
}

/// Two's-complement 16-bit SNORM, as GPUs read it.
fn snorm16(c: u16) -> f32 {
    (c as i16 as f32 / 32767.0).max(-1.0)
}

fn snorm_f32(v: f32) -> f32 {
    v
}

/// The sRGB electro-optical transfer function: encoded [0, 1] → linear [0, 1].
fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Converts interleaved feature samples to linear RGBA.
fn convert_feature(
    channels: usize,
    samples: Samples<'_>,
    texels: usize,
    encoding: FeatureEncoding,
) -> Vec<[f32; 4]> {
    let srgb = encoding == FeatureEncoding::Srgb;
    match samples {
        Samples::U8(data) => {
            let alpha: [f32; 256] = std::array::from_fn(|c| c as f32 / 255.0);
            let colour = if srgb {
                alpha.map(srgb_to_linear)
            } else {
                alpha
            };
            to_rgba(
                data,
                channels,
                texels,
                |c| colour[c as usize],
                |c| alpha[c as usize],
            )
        }
        Samples::U16(data) => {
            let alpha = |c: u16| c as f32 / 65535.0;
            if srgb {
                to_rgba(data, channels, texels, |c| srgb_to_linear(alpha(c)), alpha)
            } else {
                to_rgba(data, channels, texels, alpha, alpha)
            }
        }
        Samples::F32(data) => to_rgba(data, channels, texels, |v| v, |v| v),
    }
}

/// Expands 1 to 4 channels to RGBA: grey is replicated, a missing alpha is 1.
fn to_rgba<T: Copy>(
    data: &[T],
    channels: usize,
    texels: usize,
    colour: impl Fn(T) -> f32,
    alpha: impl Fn(T) -> f32,
) -> Vec<[f32; 4]> {
    data.chunks_exact(channels)
        .take(texels)
        .map(|px| texel_rgba(px, &colour, &alpha))
        .collect()
}

/// Which channels an OpenEXR file must provide.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Purpose {
    /// `R`, `G` required, `B` optional.
    Normals,
    /// `R`, `G`, `B` or `Y`; `A` optional.
    Feature,
}

impl Purpose {
    /// Bytes per texel of what ingest keeps from a decoded image: unit normals (3 × f32) or
    /// linear RGBA features (4 × f32).
    fn kept_bytes_per_texel(self) -> u64 {
        match self {
            Purpose::Normals => 12,
            Purpose::Feature => 16,
        }
    }
}

/// Decoded samples owned by ingest.
#[derive(Debug, Clone)]
enum SampleBuf {
    U8(Vec<u8>),
    U16(Vec<u16>),
    F32(Vec<f32>),
}

impl From<Samples<'_>> for SampleBuf {
    /// An owned copy of borrowed samples.
    fn from(samples: Samples<'_>) -> SampleBuf {
        match samples {
            Samples::U8(d) => SampleBuf::U8(d.to_vec()),
            Samples::U16(d) => SampleBuf::U16(d.to_vec()),
            Samples::F32(d) => SampleBuf::F32(d.to_vec()),
        }
    }
}

impl SampleBuf {
    fn as_samples(&self) -> Samples<'_> {
        match self {
            SampleBuf::U8(v) => Samples::U8(v),
            SampleBuf::U16(v) => Samples::U16(v),
            SampleBuf::F32(v) => Samples::F32(v),
        }
    }
}

/// An image file decoded to interleaved samples.
struct Decoded {
    width: u32,
    height: u32,
    channels: u32,
    /// Bits per channel in the file (16 for half floats, which are widened to `f32`).
    bits: u32,
    /// A grey + alpha image (not named channels, as OpenEXR's `R`, `G` are).
    luma_alpha: bool,
    samples: SampleBuf,
}

/// Opens an input file for reading if it is a regular file (a FIFO would block, a device such
/// as `/dev/zero` never ends, a folder is not a file): [`Error::Read`] naming the kind
/// otherwise. Returns the open file and its metadata. Every reader of input files (images,
/// features, tabulated BRDFs, environments, text inputs: [`read_text_file`]) opens through
/// it, then bounds what it reads.
pub(crate) fn open_regular_file(path: &Path) -> Result<(std::fs::File, std::fs::Metadata)> {
    let read_error = |source: std::io::Error| Error::Read {
        path: path.to_path_buf(),
        source,
    };
    let not_regular = |meta: &std::fs::Metadata| {
        read_error(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("not a regular file ({})", file_kind(meta)),
        ))
    };
    // The path is checked before it is opened: opening a FIFO for reading blocks until a
    // writer comes. The open file is checked again (the path may have changed meanwhile).
    let meta = std::fs::metadata(path).map_err(read_error)?;
    if !meta.is_file() {
        return Err(not_regular(&meta));
    }
    let file = std::fs::File::open(path).map_err(read_error)?;
    let meta = file.metadata().map_err(read_error)?;
    if !meta.is_file() {
        return Err(not_regular(&meta));
    }
    Ok((file, meta))
}

/// Reads a whole regular file ([`open_regular_file`]) of at most `max` bytes: `too_big` is the
/// error for a file of more (called with its length, from its metadata or, if it grew while
/// being read, from what was read). The one bounded read every input reader shares.
pub(crate) fn read_capped(
    path: &Path,
    max: u64,
    too_big: impl Fn(u64) -> Error,
) -> Result<Vec<u8>> {
    use std::io::Read;
    let (file, meta) = open_regular_file(path)?;
    if meta.len() > max {
        return Err(too_big(meta.len()));
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(max.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(|source| Error::Read {
            path: path.to_path_buf(),
            source,
        })?;
    if bytes.len() as u64 > max {
        return Err(too_big(bytes.len() as u64)); // it grew while being read
    }
    Ok(bytes)
}

/// Reads a whole input file, bounded: only a regular file ([`open_regular_file`]), and at most
/// the memory budget's bytes.
pub(crate) fn read_file(path: &Path, limit: Option<u64>) -> Result<Vec<u8>> {
    let limit = crate::budget::resolve(limit);
    read_capped(path, limit, |len| Error::MemoryBudget {
        what: format!(
            "{} (a file of {})",
            path.display(),
            crate::budget::format_bytes(len)
        ),
        needed: len,
        limit,
    })
}

/// The most bytes a text input may hold: a scene, a plan, a batch file, a report's JSON
/// (`report --from-json`), frame times. 64 MiB: the largest real ones are far smaller (a full
/// report's JSON is about 0.6 MiB, scenes, plans and batch files a few KiB), so the bound
/// refuses no real file, while a runaway or hostile one (`/dev/zero` copied to a file, a
/// generated file gone wrong) is refused before it is read into memory and parsed.
pub const MAX_TEXT_FILE_BYTES: u64 = 64 << 20;

/// Reads at most `max` bytes of a regular file ([`read_capped`]); a larger file is
/// [`Error::Read`] naming its size and the bound (`what` names the kind of file).
pub(crate) fn read_bounded(path: &Path, max: u64, what: &str) -> Result<Vec<u8>> {
    read_capped(path, max, |len| Error::Read {
        path: path.to_path_buf(),
        source: std::io::Error::new(
            std::io::ErrorKind::FileTooLarge,
            format!(
                "a file of {}, more than the {} {what} may hold",
                crate::budget::format_bytes(len),
                crate::budget::format_bytes(max)
            ),
        ),
    })
}

/// Reads a whole text input file (a scene, a plan, a batch file, a report's JSON): only a
/// regular file (a FIFO, a device or a folder is refused before it is opened for reading, so
/// nothing blocks), of at most [`MAX_TEXT_FILE_BYTES`], UTF-8.
///
/// # Errors
///
/// [`Error::Read`] naming the path when it is not a regular file, cannot be read, is larger
/// than [`MAX_TEXT_FILE_BYTES`] or is not UTF-8 text.
pub fn read_text_file(path: &Path) -> Result<String> {
    let bytes = read_bounded(path, MAX_TEXT_FILE_BYTES, "a text input")?;
    String::from_utf8(bytes).map_err(|e| Error::Read {
        path: path.to_path_buf(),
        source: std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("not UTF-8 text (byte {})", e.utf8_error().valid_up_to()),
        ),
    })
}

/// What a file that is not a regular file is, in words.
fn file_kind(meta: &std::fs::Metadata) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let t = meta.file_type();
        if t.is_fifo() {
            return "a FIFO";
        } else if t.is_char_device() || t.is_block_device() {
            return "a device";
        } else if t.is_socket() {
            return "a socket";
        }
    }
    if meta.is_dir() {
        "a folder"
    } else {
        "not a file"
    }
}

/// The container formats ingest reads, from the content (the extension only for TGA).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Container {
    Exr,
    Jpeg,
    /// PNG, TGA or TIFF, decoded by the `image` crate.
    Image(image::ImageFormat),
}

/// The supported formats, for messages.
const SUPPORTED: &str = "PNG, JPEG, TGA, TIFF and OpenEXR are supported";

/// Recognizes the format of `bytes` by content: the known signatures first; the extension of
/// `path` only for content without one (TGA has no signature) or for a `.tga` file. Content
/// that another format's signature names (a WebP file named `.png`) is an unsupported format,
/// not a broken PNG.
fn container(path: &Path, bytes: &[u8]) -> Result<Container> {
    use image::ImageFormat;
    if bytes.starts_with(&EXR_MAGIC) {
        return Ok(Container::Exr);
    }
    let from_format = |f: ImageFormat| match f {
        ImageFormat::Jpeg => Some(Container::Jpeg),
        ImageFormat::Png | ImageFormat::Tga | ImageFormat::Tiff => Some(Container::Image(f)),
        _ => None,
    };
    let by_extension = ImageFormat::from_path(path).ok();
    let is_exr = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("exr"));
    match image::guess_format(bytes).ok() {
        Some(f) if from_format(f).is_some() => Ok(from_format(f).expect("checked")),
        _ if by_extension == Some(ImageFormat::Tga) => Ok(Container::Image(ImageFormat::Tga)),
        Some(f) => Err(decode_error(
            path,
            &format!(
                "unsupported image format: the content is {} ({SUPPORTED})",
                f.extensions_str()
                    .first()
                    .map_or("unknown".into(), |e| e.to_uppercase())
            ),
        )),
        None if is_exr => Ok(Container::Exr),
        None => by_extension
            .and_then(from_format)
            .ok_or_else(|| decode_error(path, &format!("unrecognized image format ({SUPPORTED})"))),
    }
}

/// Reads the width and height of the image file at `path` from its header, without decoding
/// its pixels (the file is read as [`NormalMap::load`] reads it: a regular file within the
/// memory budget of `opts`). For checks before any work, such as a bake's memory estimate.
///
/// # Errors
///
/// As [`NormalMap::load`], for what its header shows.
pub fn probe_size(path: &Path, opts: &IngestOptions) -> Result<(u32, u32)> {
    let bytes = read_file(path, opts.memory_limit)?;
    probe_size_bytes(path, &bytes)
}

/// [`probe_size`] of a file already read into `bytes` (`path` names it in errors and gives
/// the extension when the content does not say the format).
pub(crate) fn probe_size_bytes(path: &Path, bytes: &[u8]) -> Result<(u32, u32)> {
    use image::ImageDecoder;
    if bytes.is_empty() {
        return Err(decode_error(path, "the file is empty"));
    }
    let format = container(path, bytes)?;
    let size = std::panic::catch_unwind(|| -> Result<(u32, u32)> {
        match format {
            Container::Exr => {
                let meta =
                    exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), false)
                        .map_err(|e| decode_error(path, &e.to_string()))?;
                let size = meta
                    .headers
                    .first()
                    .ok_or_else(|| decode_error(path, "no layer"))?
                    .layer_size;
                Ok((size.width() as u32, size.height() as u32))
            }
            Container::Jpeg => {
                let mut d = zune_jpeg::JpegDecoder::new(zune_core::bytestream::ZCursor::new(bytes));
                d.decode_headers()
                    .map_err(|e| decode_error(path, &e.to_string()))?;
                let (w, h) = d
                    .dimensions()
                    .ok_or_else(|| decode_error(path, "no frame header"))?;
                check_jpeg_structure(path, bytes, w as u32, h as u32)?;
                Ok((w as u32, h as u32))
            }
            Container::Image(f) => {
                let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes));
                reader.set_format(f);
                let decoder = reader
                    .into_decoder()
                    .map_err(|e| decode_error(path, &e.to_string()))?;
                Ok(decoder.dimensions())
            }
        }
    })
    .unwrap_or_else(|_| Err(decode_error(path, "the decoder failed unexpectedly")))?;
    check_dimensions(&path.display().to_string(), size.0 as u64, size.1 as u64)?;
    Ok(size)
}

/// A data image (a PBR roughness, metallic or occlusion map: linear values, never
/// colour-decoded), as [`load_data_image`] reads it.
#[derive(Debug, Clone, PartialEq)]
pub struct DataImage {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Channels in the file (1 grey, 2 grey + alpha, 3 RGB, 4 RGBA).
    pub channels: u32,
    /// Bits per sample in the file (8, 16, or 32 for floats).
    pub bits: u32,
    /// Linear RGBA per texel, rows top to bottom: integer samples divided by their maximum,
    /// grey replicated to RGB, a missing alpha 1 (as [`NormalMap::with_feature_samples`] with
    /// [`FeatureEncoding::Linear`]); NaN and out-of-range values are kept for the caller to
    /// judge.
    pub texels: Vec<[f32; 4]>,
}

/// Reads a data image from `path` (the formats of [`NormalMap::load`]), under the memory
/// budget of `opts`, with no sRGB decoding whatever `opts.feature_encoding` says: roughness,
/// metallic and occlusion are linear data. With `size` (the normal map's), an image of another
/// size is refused with [`Error::FeatureSize`] from its header, before its pixels are decoded.
pub fn load_data_image(
    path: &Path,
    opts: &IngestOptions,
    size: Option<(u32, u32)>,
) -> Result<DataImage> {
    let bytes = read_file(path, opts.memory_limit)?;
    let d = decode_bytes_kept(path, &bytes, Purpose::Feature, opts, false, size)?;
    let texels = d.width as usize * d.height as usize;
    Ok(DataImage {
        width: d.width,
        height: d.height,
        channels: d.channels,
        bits: d.bits,
        texels: convert_feature(
            d.channels as usize,
            d.samples.as_samples(),
            texels,
            FeatureEncoding::Linear,
        ),
    })
}

/// Decodes the bytes of an image file (any supported format) to interleaved samples; `path`
/// names it in errors and gives the extension. The one bounded-decoding policy: dimensions
/// and the memory budget are checked from the header before pixels are decoded.
fn decode_bytes(
    path: &Path,
    bytes: &[u8],
    purpose: Purpose,
    opts: &IngestOptions,
) -> Result<Decoded> {
    decode_bytes_kept(path, bytes, purpose, opts, false, None)
}

/// [`decode_bytes`]; `compact`: the decoded 8/16-bit samples are what the caller keeps
/// ([`CompactNormals`], [`CompactFeature`]), so the budget counts no converted copy for them;
/// `size`: the size the image must have (a feature image's normal map's), refused from the
/// header with [`Error::FeatureSize`] before the pixels are decoded.
fn decode_bytes_kept(
    path: &Path,
    bytes: &[u8],
    purpose: Purpose,
    opts: &IngestOptions,
    compact: bool,
    size: Option<(u32, u32)>,
) -> Result<Decoded> {
    if bytes.is_empty() {
        return Err(decode_error(path, "the file is empty"));
    }
    let format = container(path, bytes)?;
    // Third-party decoders are fuzzed but not proven panic-free; a panic on hostile input
    // becomes a decode error instead of unwinding into the caller (or across the C API).
    let decoded = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let budget = Budget {
            path,
            file_bytes: bytes.len() as u64,
            purpose,
            limit: opts.memory_limit,
            compact,
            size,
        };
        match format {
            Container::Exr => decode_exr(path, bytes, purpose, &budget),
            Container::Jpeg => decode_jpeg(path, bytes, &budget),
            Container::Image(f) => decode_image(path, bytes, f, &budget),
        }
    }))
    .unwrap_or_else(|payload| {
        let message = payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown reason".to_string());
        Err(decode_error(
            path,
            &format!("the decoder failed unexpectedly: {message}"),
        ))
    })?;
    let what = path.display().to_string();
    check_dimensions(&what, decoded.width as u64, decoded.height as u64)?;
    Ok(decoded)
}

/// A decode error naming `path`; the decoder's message on one line.
fn decode_error(path: &Path, message: &str) -> Error {
    Error::Decode {
        path: path.to_path_buf(),
        message: message.split_whitespace().collect::<Vec<_>>().join(" "),
    }
}

/// The memory budget of one decode: what it needs is estimated from the header and refused
/// before the decoder allocates.
struct Budget<'a> {
    path: &'a Path,
    /// The file's bytes, held while decoding.
    file_bytes: u64,
    purpose: Purpose,
    limit: Option<u64>,
    /// The caller keeps the decoded integer samples themselves (no converted copy).
    compact: bool,
    /// The size the image must have (a feature image: its normal map's), refused from the
    /// header with [`Error::FeatureSize`] before any pixel is decoded.
    size: Option<(u32, u32)>,
}

impl Budget<'_> {
    /// Checks a `width`×`height` image whose decoder holds `decoder_bytes` at its peak: the
    /// file, the decoder's buffers, and the normals or features made from them (none when the
    /// caller keeps the samples: compact and not `float`).
    fn check(&self, width: u32, height: u32, decoder_bytes: u64, float: bool) -> Result<()> {
        if let Some((w, h)) = self.size.filter(|&s| s != (width, height)) {
            return Err(Error::FeatureSize {
                what: self.path.display().to_string(),
                feature_width: width,
                feature_height: height,
                width: w,
                height: h,
            });
        }
        let texels = width as u64 * height as u64;
        let kept = if self.compact && !float {
            0
        } else {
            self.purpose.kept_bytes_per_texel()
        };
        let needed = self
            .file_bytes
            .saturating_add(decoder_bytes)
            .saturating_add(texels.saturating_mul(kept));
        crate::budget::check(
            &format!("{} ({width}x{height})", self.path.display()),
            needed,
            self.limit,
        )
    }
}

/// Decodes PNG, TGA or TIFF bytes with the `image` crate, under its [`image::Limits`].
fn decode_image(
    path: &Path,
    bytes: &[u8],
    format: image::ImageFormat,
    budget: &Budget,
) -> Result<Decoded> {
    use image::{DynamicImage, ImageDecoder, ImageReader, Limits};

    let what = path.display().to_string();
    let mut reader = ImageReader::new(std::io::Cursor::new(bytes));
    reader.set_format(format);
    let limit = crate::budget::resolve(budget.limit);
    // Dimensions are checked by ndfmap's own rule first (for a precise error), then by the
    // decoder's limits; the pixel buffer is reserved against `max_alloc` before decoding.
    let mut limits = Limits::default();
    limits.max_alloc = Some(limit);
    reader.limits(limits.clone());
    let mut decoder = reader
        .into_decoder()
        .map_err(|e| decode_error(path, &e.to_string()))?;
    let (width, height) = decoder.dimensions();
    check_dimensions(&what, width as u64, height as u64)?;
    // The pixel buffer, and as much again for the decoder's own (TIFF strips, PNG rows).
    let float = matches!(
        decoder.color_type(),
        image::ColorType::Rgb32F | image::ColorType::Rgba32F
    );
    budget.check(
        width,
        height,
        decoder.total_bytes().saturating_mul(2),
        float,
    )?;
    let too_big = |e: image::ImageError| Error::Dimensions {
        what: what.clone(),
        width: width as u64,
        height: height as u64,
        reason: e.to_string(),
    };
    limits.max_image_width = Some(MAX_DIMENSION);
    limits.max_image_height = Some(MAX_DIMENSION);
    limits.reserve(decoder.total_bytes()).map_err(too_big)?;
    decoder.set_limits(limits).map_err(too_big)?;
    let image = DynamicImage::from_decoder(decoder).map_err(|e| match e {
        image::ImageError::Limits(_) => too_big(e),
        e => decode_error(path, &e.to_string()),
    })?;

    let (width, height) = (image.width(), image.height());
    let luma_alpha = matches!(
        image,
        DynamicImage::ImageLumaA8(_) | DynamicImage::ImageLumaA16(_)
    );
    let (channels, samples) = match image {
        DynamicImage::ImageLuma8(b) => (1, SampleBuf::U8(b.into_raw())),
        DynamicImage::ImageLumaA8(b) => (2, SampleBuf::U8(b.into_raw())),
        DynamicImage::ImageRgb8(b) => (3, SampleBuf::U8(b.into_raw())),
        DynamicImage::ImageRgba8(b) => (4, SampleBuf::U8(b.into_raw())),
        DynamicImage::ImageLuma16(b) => (1, SampleBuf::U16(b.into_raw())),
        DynamicImage::ImageLumaA16(b) => (2, SampleBuf::U16(b.into_raw())),
        DynamicImage::ImageRgb16(b) => (3, SampleBuf::U16(b.into_raw())),
        DynamicImage::ImageRgba16(b) => (4, SampleBuf::U16(b.into_raw())),
        DynamicImage::ImageRgb32F(b) => (3, SampleBuf::F32(b.into_raw())),
        DynamicImage::ImageRgba32F(b) => (4, SampleBuf::F32(b.into_raw())),
        other => {
            return Err(Error::UnsupportedLayout {
                what,
                layout: format!("pixel format {:?} is not supported", other.color()),
            });
        }
    };
    let bits = match samples {
        SampleBuf::U8(_) => 8,
        SampleBuf::U16(_) => 16,
        SampleBuf::F32(_) => 32,
    };
    Ok(Decoded {
        width,
        height,
        channels,
        bits,
        luma_alpha,
        samples,
    })
}

/// Decodes JPEG bytes with `zune-jpeg` in strict mode: a premature end, an unknown marker or
/// an invalid Huffman code in the coded data is an error (the `image` crate's JPEG decoder
/// fills what it could not decode with grey instead). Before decoding, the marker structure
/// must end with an end-of-image marker ([`jpeg_structure`]) and hold enough coded bits for
/// the size the header declares.
fn decode_jpeg(path: &Path, bytes: &[u8], budget: &Budget) -> Result<Decoded> {
    use zune_core::bytestream::ZCursor;
    use zune_core::colorspace::ColorSpace;
    use zune_core::options::DecoderOptions;

    let what = path.display().to_string();
    let jpeg_error = |e: zune_jpeg::errors::DecodeErrors| decode_error(path, &e.to_string());
    let options = DecoderOptions::default()
        .set_strict_mode(true)
        .set_max_width(MAX_DIMENSION as usize)
        .set_max_height(MAX_DIMENSION as usize);
    let mut decoder = zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(bytes), options);
    decoder.decode_headers().map_err(jpeg_error)?;
    let (w, h) = decoder
        .dimensions()
        .ok_or_else(|| decode_error(path, "no frame header"))?;
    check_dimensions(&what, w as u64, h as u64)?;
    let (width, height) = (w as u32, h as u32);
    check_jpeg_structure(path, bytes, width, height)?;
    let grey = matches!(
        decoder.input_colorspace(),
        Some(ColorSpace::Luma | ColorSpace::LumaA)
    );
    let (out, channels) = if grey {
        (ColorSpace::Luma, 1)
    } else {
        (ColorSpace::RGB, 3)
    };
    decoder.set_options(options.jpeg_set_out_colorspace(out));
    // The output, and twice as much for a progressive file's coefficients (i16 per sample).
    let pixels = w as u64 * h as u64 * channels as u64;
    budget.check(width, height, pixels.saturating_mul(3), false)?;
    let data = decoder.decode().map_err(jpeg_error)?;
    if data.len() as u64 != pixels {
        return Err(decode_error(
            path,
            "the decoder returned the wrong amount of pixels",
        ));
    }
    Ok(Decoded {
        width,
        height,
        channels,
        bits: 8,
        luma_alpha: false,
        samples: SampleBuf::U8(data),
    })
}

/// Checks a JPEG declaring `width`×`height` before decoding it: its marker structure ends with
/// an end-of-image marker ([`jpeg_structure`]) and it holds enough coded bits for that size
/// (a decompression bomb's header claims far more than its data can hold).
fn check_jpeg_structure(path: &Path, bytes: &[u8], width: u32, height: u32) -> Result<()> {
    let coded_bytes = jpeg_structure(bytes).map_err(|m| decode_error(path, &m))?;
    // Every 8×8 block of the first component takes at least one bit (its DC code); a block
    // covers at most 32×32 pixels (sampling factors ≤ 4).
    let min_bits = (width as u64).div_ceil(32) * (height as u64).div_ceil(32);
    if coded_bytes.saturating_mul(8) < min_bits {
        return Err(decode_error(
            path,
            &format!(
                "truncated or corrupt: {coded_bytes} bytes of coded data cannot hold a \
                 {width}x{height} image"
            ),
        ));
    }
    Ok(())
}

/// Walks a JPEG's marker segments and returns the number of bytes of entropy-coded data;
/// fails when the file ends before its end-of-image marker (a truncated file) or a segment runs
/// past the end.
fn jpeg_structure(bytes: &[u8]) -> std::result::Result<u64, String> {
    let truncated = || "truncated: the file ends before its end-of-image marker".to_string();
    if !bytes.starts_with(&[0xFF, 0xD8]) {
        return Err("not a JPEG (no start-of-image marker)".into());
    }
    let mut i = 2;
    let mut coded = 0u64;
    loop {
        // A marker: 0xFF, any fill bytes 0xFF, then its code.
        if bytes.get(i) != Some(&0xFF) {
            return Err(match bytes.get(i) {
                None => truncated(),
                Some(_) => format!("corrupt: no marker at byte {i}"),
            });
        }
        while bytes.get(i) == Some(&0xFF) {
            i += 1;
        }
        let code = *bytes.get(i).ok_or_else(truncated)?;
        i += 1;
        match code {
            0xD9 => return Ok(coded),
            0x01 | 0xD0..=0xD7 => continue, // no length
            0xD8 | 0x00 => return Err(format!("corrupt: unexpected marker 0xFF{code:02X}")),
            _ => {}
        }
        let len = match bytes.get(i..i + 2) {
            Some(l) => u16::from_be_bytes([l[0], l[1]]) as usize,
            None => return Err(truncated()),
        };
        if len < 2 || i + len > bytes.len() {
            return Err(truncated());
        }
        i += len;
        if code == 0xDA {
            // Entropy-coded data follows a scan header, up to the next marker that is neither
            // a stuffed 0xFF00 nor a restart marker.
            let start = i;
            loop {
                match bytes.get(i..i + 2) {
                    None => return Err(truncated()),
                    Some([0xFF, 0x00 | 0xD0..=0xD7]) => i += 2,
                    Some([0xFF, _]) => break,
                    Some(_) => i += 1,
                }
            }
            coded += (i - start) as u64;
        }
    }
}

/// Decodes OpenEXR bytes with the `exr` crate: the first layer that has the channels `purpose`
/// needs, full resolution, only those channels (a file with hundreds of other channels costs
/// no memory for them), widened to interleaved `f32`.
fn decode_exr(path: &Path, bytes: &[u8], purpose: Purpose, budget: &Budget) -> Result<Decoded> {
    use exr::meta::attribute::SampleType;
    use std::io::Cursor;

    let what = path.display().to_string();
    let exr_error = |e: exr::error::Error| decode_error(path, &e.to_string());

    // Headers first: refuse absurd sizes before the decoder allocates channel buffers.
    let meta =
        exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false).map_err(exr_error)?;
    for header in &meta.headers {
        let size = header.layer_size;
        check_dimensions(&what, size.width() as u64, size.height() as u64)?;
    }
    let names_in = |header: &exr::meta::header::Header| -> Vec<String> {
        header
            .channels
            .list
            .iter()
            .map(|c| c.name.to_string())
            .collect()
    };
    // The channels to read, in sample order, from the first layer that has them.
    let pick = |header: &exr::meta::header::Header| -> Option<Vec<&'static str>> {
        let names = names_in(header);
        let has = |n: &str| names.iter().any(|c| c == n);
        let with = |base: &[&'static str], optional: &'static str| {
            let mut v = base.to_vec();
            if has(optional) {
                v.push(optional);
            }
            v
        };
        match purpose {
            Purpose::Normals if has("R") && has("G") => Some(with(&["R", "G"], "B")),
            Purpose::Feature if has("R") && has("G") && has("B") => {
                Some(with(&["R", "G", "B"], "A"))
            }
            Purpose::Feature if has("Y") => Some(with(&["Y"], "A")),
            _ => None,
        }
    };
    let Some((header, picked)) = meta
        .headers
        .iter()
        .find_map(|h| pick(h).map(|names| (h, names)))
    else {
        let needed = match purpose {
            Purpose::Normals => "R and G (B optional)",
            Purpose::Feature => "R, G and B, or Y (A optional)",
        };
        let names = meta.headers.first().map(names_in).unwrap_or_default();
        return Err(Error::UnsupportedLayout {
            what,
            layout: format!(
                "OpenEXR layer has channels [{}]; {needed} are needed",
                names.join(", ")
            ),
        });
    };
    let mut bits = 16;
    for name in &picked {
        let c = header
            .channels
            .list
            .iter()
            .find(|c| c.name.eq(name))
            .expect("picked from this list");
        if c.sampling != exr::math::Vec2(1, 1) {
            return Err(Error::UnsupportedLayout {
                what,
                layout: format!("OpenEXR channel {name} is subsampled"),
            });
        }
        match c.sample_type {
            SampleType::U32 => {
                return Err(Error::UnsupportedLayout {
                    what,
                    layout: format!(
                        "OpenEXR channel {name} holds 32-bit integers; half or float is needed"
                    ),
                });
            }
            SampleType::F32 => bits = 32,
            SampleType::F16 => {}
        }
    }
    let (w, h) = (header.layer_size.width(), header.layer_size.height());
    let channels = picked.len();
    // The interleaved samples, and one decompressed block of every channel.
    let samples = (w * h * channels * 4) as u64;
    budget.check(
        w as u32,
        h as u32,
        samples + header.max_block_byte_size() as u64,
        true,
    )?;
    let data = read_exr_channels(bytes, &picked, (w, h)).map_err(exr_error)?;
    Ok(Decoded {
        width: w as u32,
        height: h as u32,
        channels: channels as u32,
        bits,
        luma_alpha: false,
        samples: SampleBuf::F32(data),
    })
}

/// Reads channels `names` (1 to 4 of them, the first layer that has them, full resolution) of
/// an OpenEXR file of `size` as interleaved `f32`, decoding nothing else into memory.
/// Sequential: the parallel decoder runs on a rayon pool, where a panic on hostile input would
/// abort the process instead of reaching ingest's `catch_unwind`.
fn read_exr_channels(
    bytes: &[u8],
    names: &[&str],
    size: (usize, usize),
) -> exr::error::Result<Vec<f32>> {
    use exr::math::Vec2;
    use exr::prelude::{ReadChannels, ReadLayers, ReadSpecificChannel};
    let n = names.len();
    let width = size.0;
    let index = move |at: Vec2<usize>| (at.y() * width + at.x()) * n;
    let reader = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level();
    let cursor = std::io::Cursor::new(bytes);
    // One arm per channel count: each count is its own pixel type (a tuple of f32).
    macro_rules! read {
        ($($name:ident => $sample:ident),+) => {
            reader
                .specific_channels()
                $(.required($name))+
                .collect_pixels(
                    move |s: Vec2<usize>, _: &_| vec![0.0f32; s.area() * n],
                    move |px: &mut Vec<f32>, at: Vec2<usize>, ($($sample,)+): ($(read!(@f32 $sample),)+)| {
                        px[index(at)..][..n].copy_from_slice(&[$($sample),+]);
                    },
                )
                .first_valid_layer()
                .all_attributes()
                .non_parallel()
                .from_buffered(cursor)?
                .layer_data
                .channel_data
                .pixels
        };
        (@f32 $sample:ident) => { f32 };
    }
    let image_data = match *names {
        [a] => read!(a => x),
        [a, b] => read!(a => x, b => y),
        [a, b, c] => read!(a => x, b => y, c => z),
        [a, b, c, d] => read!(a => x, b => y, c => z, d => w),
        _ => unreachable!("1 to 4 channels are picked"),
    };
    Ok(image_data)
}

/// Refuses zero, absurd, or overflowing dimensions.
pub(crate) fn check_dimensions(what: &str, width: u64, height: u64) -> Result<()> {
    let reason = if width == 0 || height == 0 {
        Some("width and height must be at least 1".to_string())
    } else if width > MAX_DIMENSION as u64 || height > MAX_DIMENSION as u64 {
        Some(format!("each side must be at most {MAX_DIMENSION}"))
    } else if width.checked_mul(height).is_none_or(|n| n > MAX_TEXELS) {
        Some(format!("at most {MAX_TEXELS} texels are supported"))
    } else {
        None
    };
    match reason {
        Some(reason) => Err(Error::Dimensions {
            what: what.to_string(),
            width,
            height,
            reason,
        }),
        None => Ok(()),
    }
}

/// Renormalizes, detects and repairs (or rejects) bad normals, and fills in the statistics.
fn finish(
    what: &str,
    width: u32,
    height: u32,
    mut vectors: Vec<Vec3>,
    addressing: Addressing,
    policy: BadNormals,
    stats: IngestStats,
) -> Result<NormalMap> {
    let count = vectors.len();
    let stats = clean_normals(what, width, count, policy, stats, |i| {
        let n = clean_normal(vectors[i]);
        vectors[i] = n.0;
        n
    })?;
    Ok(NormalMap {
        width,
        height,
        normals: vectors,
        feature: None,
        addressing,
        stats,
    })
}

/// What [`clean_normal`] found wrong with a raw vector.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Flaw {
    Nan,
    ZeroLength,
    BelowHorizon,
}

/// One raw vector made a unit tangent-space normal (the one rule every map follows):
/// non-finite → +Z, zero length → +Z, else normalized in f64 (a float map's tiny vectors keep
/// their direction); one below the horizon keeps its azimuth at z = 0 (+Z if it points
/// straight down). Returns the normal, its flaw, and the raw length when it had one.
fn clean_normal(v: Vec3) -> (Vec3, Option<Flaw>, Option<f64>) {
    if !v.is_finite() {
        return (Vec3::Z, Some(Flaw::Nan), None);
    }
    let len = v.as_dvec3().length();
    if len == 0.0 {
        return (Vec3::Z, Some(Flaw::ZeroLength), None);
    }
    let n = (v.as_dvec3() / len).as_vec3();
    if n.z < 0.0 {
        let xy = glam::DVec2::new(n.x as f64, n.y as f64);
        let l = xy.length();
        // A normal pointing (almost) straight down has no azimuth to keep: +Z.
        let n = if l > 1e-6 {
            Vec3::new((xy.x / l) as f32, (xy.y / l) as f32, 0.0)
        } else {
            Vec3::Z
        };
        return (n, Some(Flaw::BelowHorizon), Some(len));
    }
    (n, None, Some(len))
}

/// Cleans `count` vectors in scan-line order (`clean(i)`: texel i's [`clean_normal`]),
/// counting the flaws and the mean z and length into `stats`, and refuses a map with a flaw
/// under [`BadNormals::Reject`] ([`Error::BadNormals`], the first flaw's kind and position).
fn clean_normals(
    what: &str,
    width: u32,
    count: usize,
    policy: BadNormals,
    mut stats: IngestStats,
    mut clean: impl FnMut(usize) -> (Vec3, Option<Flaw>, Option<f64>),
) -> Result<IngestStats> {
    let mut sum_len = 0.0f64;
    let mut n_len = 0u64;
    let mut sum_z = 0.0f64;
    for i in 0..count {
        let (n, flaw, len) = clean(i);
        match flaw {
            Some(Flaw::Nan) => stats.nan.note(i, width),
            Some(Flaw::ZeroLength) => stats.zero_length.note(i, width),
            Some(Flaw::BelowHorizon) => stats.below_horizon.note(i, width),
            None => {}
        }
        if let Some(len) = len {
            sum_len += len;
            n_len += 1;
        }
        sum_z += n.z as f64;
    }
    if policy == BadNormals::Reject
        && let Some((kind, first)) = first_bad(&[
            ("NaN", stats.nan),
            ("zero length", stats.zero_length),
            ("below the horizon", stats.below_horizon),
        ])
    {
        return Err(Error::BadNormals {
            what: what.to_string(),
            count: stats.bad_total(),
            kind,
            x: first.0,
            y: first.1,
        });
    }
    let n = count.max(1) as f64;
    stats.mean_z = sum_z / n;
    stats.mean_length = if n_len > 0 {
        sum_len / n_len as f64
    } else {
        0.0
    };
    Ok(stats)
}

/// A normal map kept as its source samples (8 or 16 bits per channel), each texel's normal
/// decoded when asked for: 3 bytes per texel for an 8-bit RGB map instead of `NormalMap`'s 12,
/// for maps too large to hold as vectors (a 16384² map: 768 MiB instead of 3 GiB; issue 19's
/// tiled bakes, docs/scale.md). [`CompactNormals::normal`] is bit for bit the normal
/// [`NormalMap::from_samples`] stores for the same samples and options, and
/// [`CompactNormals::stats`] the same statistics (one conversion, shared; tested).
#[derive(Debug, Clone)]
pub struct CompactNormals {
    width: u32,
    height: u32,
    samples: SampleBuf,
    layout: Layout,
    unorm: bool,
    addressing: Addressing,
    stats: IngestStats,
}

impl CompactNormals {
    /// Keeps `samples` (8 or 16 bits, `channels` per texel, rows top first) as a normal map
    /// read under `opts`, checking every texel as [`NormalMap::from_samples`] does.
    ///
    /// # Errors
    ///
    /// Those of [`NormalMap::from_samples`], and [`Error::UnsupportedLayout`] for float
    /// samples (keep those as a [`NormalMap`]).
    pub fn from_samples(
        what: &str,
        width: u32,
        height: u32,
        channels: u32,
        samples: Samples<'_>,
        opts: &IngestOptions,
    ) -> Result<CompactNormals> {
        if let Samples::F32(_) = samples {
            return Err(Error::UnsupportedLayout {
                what: what.to_string(),
                layout: "float samples: compact maps hold 8- or 16-bit samples".into(),
            });
        }
        let bits = samples_bits(samples);
        Self::from_owned(what, width, height, channels, samples.into(), bits, opts)
    }

    /// [`CompactNormals::from_samples`] keeping `owned` itself (integer samples; no copy).
    fn from_owned(
        what: &str,
        width: u32,
        height: u32,
        channels: u32,
        owned: SampleBuf,
        bits: u32,
        opts: &IngestOptions,
    ) -> Result<CompactNormals> {
        let (layout, unorm, stats) = source_layout(
            what,
            width,
            height,
            channels,
            owned.as_samples(),
            bits,
            opts,
        )?;
        let mut map = CompactNormals {
            width,
            height,
            samples: owned,
            layout,
            unorm,
            addressing: opts.addressing,
            stats: IngestStats::default(),
        };
        let count = width as usize * height as usize;
        map.stats = clean_normals(what, width, count, opts.bad_normals, stats, |i| {
            clean_normal(map.raw(i))
        })?;
        Ok(map)
    }

    /// Texel `i`'s raw vector.
    fn raw(&self, i: usize) -> Vec3 {
        let c = self.layout.channels;
        match &self.samples {
            SampleBuf::U8(d) => self.layout.vector(
                &d[i * c..(i + 1) * c],
                if self.unorm { unorm8 } else { snorm8 },
            ),
            SampleBuf::U16(d) => self.layout.vector(
                &d[i * c..(i + 1) * c],
                if self.unorm { unorm16 } else { snorm16 },
            ),
            SampleBuf::F32(d) => self.layout.vector(
                &d[i * c..(i + 1) * c],
                if self.unorm { unorm_f32 } else { snorm_f32 },
            ),
        }
    }

    /// The unit normal of row-major texel `i` (as [`NormalMap::normals`]`()[i]`).
    pub fn normal(&self, i: usize) -> Vec3 {
        clean_normal(self.raw(i)).0
    }

    /// Width in texels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in texels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Edge addressing.
    pub fn addressing(&self) -> Addressing {
        self.addressing
    }

    /// What ingest found in the samples (as [`NormalMap::stats`]).
    pub fn stats(&self) -> &IngestStats {
        &self.stats
    }
}

impl CompactNormals {
    /// The statistics of the map with `feature` attached (as [`NormalMap::stats`] of a map
    /// with that feature image: its repaired NaN and negative counts).
    pub fn stats_with(&self, feature: Option<&CompactFeature>) -> IngestStats {
        let mut stats = self.stats.clone();
        if let Some(f) = feature {
            stats.feature_nan = f.nan;
            stats.feature_negative = f.negative;
        }
        stats
    }

    /// Bytes per texel the samples take (3 for 8-bit RGB, 6 for 16-bit RGB, 4 for RGBA8).
    pub fn bytes_per_texel(&self) -> u64 {
        let bytes = match self.samples {
            SampleBuf::U8(_) => 1,
            SampleBuf::U16(_) => 2,
            SampleBuf::F32(_) => 4,
        };
        bytes * self.layout.channels as u64
    }
}

/// A normal map read for a bounded-memory bake ([`load_normals_compact`]).
#[derive(Debug, Clone)]
pub enum LoadedNormals {
    /// 8- or 16-bit samples, kept as they were decoded.
    Compact(CompactNormals),
    /// Float samples (OpenEXR, float TIFF), decoded to vectors.
    Decoded(NormalMap),
}

/// Reads a normal map from the bytes of an image file as [`NormalMap::load_memory`] does, but
/// keeps 8- and 16-bit images as their decoded samples ([`CompactNormals`]: the `image` or
/// JPEG decoder's own buffer, 3 bytes per texel for 8-bit RGB, 6 for 16-bit RGB; no vectors
/// are made), so a 16384² 8-bit map takes 768 MiB instead of `NormalMap`'s 3 GiB. 16-bit
/// samples stay 16-bit: rounding them to 8 bits would change the normals, and the bake must
/// equal the one from a `NormalMap` bit for bit. Float images are decoded to a [`NormalMap`]
/// as before (their samples are as large as the vectors). Same errors and statistics as
/// [`NormalMap::load_memory`]; the memory budget counts no converted copy for kept samples.
pub fn load_normals_compact(
    name: &str,
    bytes: &[u8],
    opts: &IngestOptions,
) -> Result<LoadedNormals> {
    let path = Path::new(name);
    let decoded = decode_bytes_kept(path, bytes, Purpose::Normals, opts, true, None)?;
    if matches!(decoded.samples, SampleBuf::F32(_)) {
        return NormalMap::from_decoded(path, decoded, opts).map(LoadedNormals::Decoded);
    }
    if decoded.luma_alpha && opts.channels == Channels::Auto {
        // The same refusal as the decoded path's.
        return NormalMap::from_decoded(path, decoded, opts).map(LoadedNormals::Decoded);
    }
    CompactNormals::from_owned(
        name,
        decoded.width,
        decoded.height,
        decoded.channels,
        decoded.samples,
        decoded.bits,
        opts,
    )
    .map(LoadedNormals::Compact)
}

/// A feature (colour) image kept as its 8- or 16-bit samples, each texel converted to linear
/// RGBA when asked for, bit for bit as [`NormalMap::with_feature_samples`] converts it (sRGB
/// decoding through a table of every sample value): 3 bytes per texel for 8-bit RGB instead
/// of 16. Float images are held converted (16 bytes per texel). For the bounded-memory bake
/// of large maps (module `banded`).
#[derive(Debug, Clone)]
pub struct CompactFeature {
    width: u32,
    height: u32,
    texels: FeatureTexels,
    nan: BadCount,
    negative: BadCount,
}

/// How a [`CompactFeature`] holds its texels.
#[derive(Debug, Clone)]
enum FeatureTexels {
    /// 8-bit samples with the colour and alpha value of every sample.
    U8 {
        samples: Vec<u8>,
        channels: usize,
        colour: Box<[f32; 256]>,
        alpha: Box<[f32; 256]>,
    },
    /// 16-bit samples with the colour value of every sample (alpha is `c / 65535`).
    U16 {
        samples: Vec<u16>,
        channels: usize,
        colour: Vec<f32>,
    },
    /// Converted (float images).
    Rgba(Vec<[f32; 4]>),
}

/// One texel of `channels` samples as RGBA: grey replicated, a missing alpha 1 (what
/// `to_rgba` does per texel).
#[inline]
fn texel_rgba<T: Copy>(px: &[T], colour: impl Fn(T) -> f32, alpha: impl Fn(T) -> f32) -> [f32; 4] {
    match *px {
        [g] => {
            let g = colour(g);
            [g, g, g, 1.0]
        }
        [g, a] => {
            let g = colour(g);
            [g, g, g, alpha(a)]
        }
        [r, g, b] => [colour(r), colour(g), colour(b), 1.0],
        [r, g, b, a, ..] => [colour(r), colour(g), colour(b), alpha(a)],
        [] => [0.0, 0.0, 0.0, 1.0],
    }
}

impl CompactFeature {
    /// Keeps `samples` (`channels` per texel, rows top first, `width × height`) as a feature
    /// image read under `opts` ([`IngestOptions::feature_encoding`], and
    /// [`IngestOptions::bad_normals`] for float values), as
    /// [`NormalMap::with_feature_samples`] would attach it to a map of that size.
    ///
    /// # Errors
    ///
    /// Those of [`NormalMap::with_feature_samples`] (the size check is the caller's:
    /// [`CompactFeature::check_size`]).
    pub fn from_samples(
        what: &str,
        width: u32,
        height: u32,
        channels: u32,
        samples: Samples<'_>,
        opts: &IngestOptions,
    ) -> Result<CompactFeature> {
        Self::from_owned(what, width, height, channels, samples.into(), opts)
    }

    /// [`CompactFeature::from_samples`] keeping `owned` itself.
    fn from_owned(
        what: &str,
        width: u32,
        height: u32,
        channels: u32,
        owned: SampleBuf,
        opts: &IngestOptions,
    ) -> Result<CompactFeature> {
        let texel_count = check_buffer(what, width, height, channels, owned.as_samples())?;
        let srgb = opts.feature_encoding == FeatureEncoding::Srgb;
        let c = channels as usize;
        let (texels, nan, negative) = match owned {
            SampleBuf::U8(mut samples) => {
                // Integer samples convert to finite values in [0, 1]: nothing to repair.
                samples.truncate(texel_count * c);
                let alpha: [f32; 256] = std::array::from_fn(|c| c as f32 / 255.0);
                let colour = if srgb {
                    alpha.map(srgb_to_linear)
                } else {
                    alpha
                };
                let texels = FeatureTexels::U8 {
                    samples,
                    channels: c,
                    colour: Box::new(colour),
                    alpha: Box::new(alpha),
                };
                (texels, BadCount::default(), BadCount::default())
            }
            SampleBuf::U16(mut samples) => {
                samples.truncate(texel_count * c);
                let alpha = |c: u16| c as f32 / 65535.0;
                let colour = (0..=u16::MAX)
                    .map(|c| {
                        if srgb {
                            srgb_to_linear(alpha(c))
                        } else {
                            alpha(c)
                        }
                    })
                    .collect();
                let texels = FeatureTexels::U16 {
                    samples,
                    channels: c,
                    colour,
                };
                (texels, BadCount::default(), BadCount::default())
            }
            SampleBuf::F32(samples) => {
                let mut rgba = convert_feature(
                    c,
                    Samples::F32(&samples),
                    texel_count,
                    opts.feature_encoding,
                );
                drop(samples);
                let (nan, negative) = repair_feature(what, width, &mut rgba, opts.bad_normals)?;
                (FeatureTexels::Rgba(rgba), nan, negative)
            }
        };
        Ok(CompactFeature {
            width,
            height,
            texels,
            nan,
            negative,
        })
    }

    /// Reads a feature image from the bytes of an image file as
    /// [`NormalMap::with_feature_memory`] does, keeping 8- and 16-bit samples, for a normal
    /// map of `size` ([`Error::FeatureSize`] if the image's differs).
    pub fn load_memory(
        name: &str,
        bytes: &[u8],
        size: (u32, u32),
        opts: &IngestOptions,
    ) -> Result<CompactFeature> {
        let path = Path::new(name);
        let d = decode_bytes_kept(path, bytes, Purpose::Feature, opts, true, Some(size))?;
        let f = CompactFeature {
            width: d.width,
            height: d.height,
            texels: FeatureTexels::Rgba(Vec::new()),
            nan: BadCount::default(),
            negative: BadCount::default(),
        };
        f.check_size(name, size)?;
        Self::from_owned(name, d.width, d.height, d.channels, d.samples, opts)
    }

    /// [`Error::FeatureSize`] unless the image is `size` (the normal map's), as
    /// [`NormalMap::with_feature_samples`] checks.
    pub fn check_size(&self, what: &str, size: (u32, u32)) -> Result<()> {
        if (self.width, self.height) != size {
            return Err(Error::FeatureSize {
                what: what.to_string(),
                feature_width: self.width,
                feature_height: self.height,
                width: size.0,
                height: size.1,
            });
        }
        Ok(())
    }

    /// Width in texels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in texels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Bytes per texel the image takes as held.
    pub fn bytes_per_texel(&self) -> u64 {
        match &self.texels {
            FeatureTexels::U8 { channels, .. } => *channels as u64,
            FeatureTexels::U16 { channels, .. } => 2 * *channels as u64,
            FeatureTexels::Rgba(_) => 16,
        }
    }

    /// Linear RGBA of row-major texel `i` (as [`NormalMap::feature`]`()[i]`).
    #[inline]
    pub fn texel(&self, i: usize) -> [f32; 4] {
        match &self.texels {
            FeatureTexels::U8 {
                samples,
                channels,
                colour,
                alpha,
            } => texel_rgba(
                &samples[i * channels..(i + 1) * channels],
                |c| colour[c as usize],
                |c| alpha[c as usize],
            ),
            FeatureTexels::U16 {
                samples,
                channels,
                colour,
            } => texel_rgba(
                &samples[i * channels..(i + 1) * channels],
                |c| colour[c as usize],
                |c| c as f32 / 65535.0,
            ),
            FeatureTexels::Rgba(t) => t[i],
        }
    }
}

/// What an image file's header says about the samples ingest would decode from it
/// ([`probe_bytes`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Probe {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Bytes per texel of the decoded samples (channels × bytes per sample).
    pub bytes_per_texel: u32,
    /// Float samples (OpenEXR, float TIFF): decoded to vectors, not kept compact.
    pub float: bool,
}

/// [`probe_size`] of a file read into `bytes`, with the decoded samples' size per texel: what
/// a bake's memory estimate needs before anything is decoded.
///
/// # Errors
///
/// As [`probe_size`].
pub fn probe_bytes(path: &Path, bytes: &[u8]) -> Result<Probe> {
    let (width, height) = probe_size_bytes(path, bytes)?;
    let (bytes_per_texel, float) = match container(path, bytes)? {
        // At most four channels of f32 (ingest widens half floats).
        Container::Exr => (16, true),
        Container::Jpeg => (3, false),
        Container::Image(f) => {
            let probe = std::panic::catch_unwind(|| {
                use image::ImageDecoder;
                let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes));
                reader.set_format(f);
                reader.into_decoder().ok().map(|d| d.color_type())
            })
            .ok()
            .flatten()
            .ok_or_else(|| decode_error(path, "the decoder failed unexpectedly"))?;
            (
                u32::from(probe.bytes_per_pixel()),
                matches!(probe, image::ColorType::Rgb32F | image::ColorType::Rgba32F),
            )
        }
    };
    Ok(Probe {
        width,
        height,
        bytes_per_texel,
        float,
    })
}
