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

/// What to do with zero-length, NaN, or below-horizon normals.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BadNormals {
    /// Replace zero-length and NaN normals by +Z, clamp below-horizon normals onto the horizon
    /// (z = 0, same azimuth), and report counts.
    #[default]
    Repair,
    /// Fail with [`Error::BadNormals`] naming the first bad texel.
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
/// wrap addressing, repair bad normals.
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
    /// Bad-normal policy.
    pub bad_normals: BadNormals,
    /// Feature image encoding.
    pub feature_encoding: FeatureEncoding,
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
    /// Zero-length vectors (length below 1e-6).
    pub zero_length: BadCount,
    /// Vectors with a NaN or infinite component.
    pub nan: BadCount,
    /// Vectors with z < 0 (below the tangent-plane horizon).
    pub below_horizon: BadCount,
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

    /// Attaches a per-texel feature (linear RGBA, row-major). Its length must be width × height.
    pub fn with_feature(mut self, feature: Vec<[f32; 4]>) -> Result<Self> {
        let needed = self.width as usize * self.height as usize;
        if feature.len() != needed {
            return Err(Error::ShortBuffer {
                what: "feature".into(),
                got: feature.len(),
                needed,
            });
        }
        self.feature = Some(feature);
        Ok(self)
    }
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
    mut stats: IngestStats,
) -> Result<NormalMap> {
    fn note(c: &mut BadCount, i: usize, width: u32) {
        if c.first.is_none() {
            c.first = Some(((i % width as usize) as u32, (i / width as usize) as u32));
        }
        c.count += 1;
    }
    let mut sum_len = 0.0f64;
    let mut n_len = 0u64;
    let mut sum_z = 0.0f64;
    for (i, v) in vectors.iter_mut().enumerate() {
        let mut n = *v;
        if !n.is_finite() {
            note(&mut stats.nan, i, width);
            n = Vec3::Z;
        } else {
            let len = (n.as_dvec3()).length();
            if len < 1e-6 {
                note(&mut stats.zero_length, i, width);
                n = Vec3::Z;
            } else {
                sum_len += len;
                n_len += 1;
                n = (n.as_dvec3() / len).as_vec3();
                if n.z < 0.0 {
                    note(&mut stats.below_horizon, i, width);
                    let xy = glam::DVec2::new(n.x as f64, n.y as f64);
                    let l = xy.length();
                    n = Vec3::new((xy.x / l) as f32, (xy.y / l) as f32, 0.0);
                }
            }
        }
        sum_z += n.z as f64;
        *v = n;
    }
    if policy == BadNormals::Reject && stats.bad_total() > 0 {
        let (kind, first) = [
            ("NaN", stats.nan.first),
            ("zero length", stats.zero_length.first),
            ("below the horizon", stats.below_horizon.first),
        ]
        .into_iter()
        .filter_map(|(k, f)| f.map(|f| (k, f)))
        .min_by_key(|&(_, (x, y))| (y, x))
        .expect("bad_total > 0 implies a first position");
        return Err(Error::BadNormals {
            what: what.to_string(),
            count: stats.bad_total(),
            kind,
            x: first.0,
            y: first.1,
        });
    }
    let n = vectors.len().max(1) as f64;
    stats.mean_z = sum_z / n;
    stats.mean_length = if n_len > 0 {
        sum_len / n_len as f64
    } else {
        0.0
    };
    Ok(NormalMap {
        width,
        height,
        normals: vectors,
        feature: None,
        addressing,
        stats,
    })
}
