//! Storage formats of texel values and the value ranges of texture channels: what a GPU
//! texture holds ([`Format`]) and how unsigned-normalized formats encode a channel
//! ([`ValueRange`]). The bottom of the data flow: every stage that stores, packs, uploads or
//! clamps texels reads these.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// The range a channel's values lie in, which decides how unsigned-normalized formats store it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ValueRange {
    /// In [0, 1]: stored as is.
    Unit,
    /// In [−1, 1]: unsigned-normalized formats store `0.5 + 0.5·v` (DESIGN.md "Texture layouts").
    Signed,
    /// Unbounded (LEAN slope moments): float formats only.
    Any,
}

/// Storage format of texel values: what the GPU texture holds (module `pack` converts to it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// 32-bit float RGBA (`GL_RGBA32F`).
    #[default]
    F32,
    /// 16-bit float RGBA (`GL_RGBA16F`).
    F16,
    /// 16-bit unsigned-normalized RGBA (`GL_RGBA16`); signed channels biased.
    Unorm16,
    /// 8-bit unsigned-normalized RGBA (`GL_RGBA8`); signed channels biased.
    Unorm8,
}

impl Format {
    /// Every format, widest first.
    pub const ALL: [Format; 4] = [Format::F32, Format::F16, Format::Unorm16, Format::Unorm8];

    /// The lower-case name used on the command line and in manifests.
    pub fn name(self) -> &'static str {
        match self {
            Format::F32 => "f32",
            Format::F16 => "f16",
            Format::Unorm16 => "unorm16",
            Format::Unorm8 => "unorm8",
        }
    }

    /// Bytes per channel.
    pub fn channel_bytes(self) -> usize {
        match self {
            Format::F32 => 4,
            Format::F16 | Format::Unorm16 => 2,
            Format::Unorm8 => 1,
        }
    }
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Format {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        crate::error::parse_named(s, &Format::ALL, Format::name, "format")
    }
}
