//! Typed errors for every stage of ndfmap.
//!
//! Each variant names the file (or the option) and the problem in words, so the command-line
//! program can print one clear line and the C API can hand the same text to the caller.

use std::path::PathBuf;

/// Everything that can go wrong in ndfmap's library code.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The file could not be read at all (missing, permission denied, ...).
    #[error("{}: cannot read: {source}", path.display())]
    Read {
        /// The file that was being read.
        path: PathBuf,
        /// The operating system's reason.
        source: std::io::Error,
    },
    /// The file was read but its contents are not a decodable image (corrupt, truncated,
    /// unknown format).
    #[error("{}: cannot decode image: {message}", path.display())]
    Decode {
        /// The file that was being decoded.
        path: PathBuf,
        /// The decoder's reason.
        message: String,
    },
    /// The image decoded, but its channels cannot be read as a normal map (for example a
    /// one-channel height map).
    #[error("{what}: unsupported channel layout: {layout}")]
    UnsupportedLayout {
        /// The file or buffer the image came from.
        what: String,
        /// What was found and what would have been accepted.
        layout: String,
    },
    /// Width or height is zero, absurd, or their product overflows.
    #[error("{what}: invalid dimensions {width}x{height}: {reason}")]
    Dimensions {
        /// The file or buffer the image came from.
        what: String,
        /// Width as declared.
        width: u64,
        /// Height as declared.
        height: u64,
        /// Why it is refused.
        reason: String,
    },
    /// A caller-provided pixel buffer is shorter than its declared size.
    #[error("{what}: pixel buffer holds {got} samples, {needed} are needed")]
    ShortBuffer {
        /// The buffer's description.
        what: String,
        /// Samples provided.
        got: usize,
        /// Samples needed for width × height × channels.
        needed: usize,
    },
    /// The feature (colour) image does not have the normal map's size.
    #[error(
        "{what}: feature image is {feature_width}x{feature_height}, the normal map is {width}x{height}"
    )]
    FeatureSize {
        /// The feature image's file or buffer.
        what: String,
        /// Feature image width.
        feature_width: u32,
        /// Feature image height.
        feature_height: u32,
        /// Normal map width.
        width: u32,
        /// Normal map height.
        height: u32,
    },
    /// The input has bad normals (zero-length, NaN, below the horizon) and the caller asked to
    /// reject rather than repair them.
    #[error("{what}: {count} bad normals ({kind}), the first at x={x}, y={y}")]
    BadNormals {
        /// The file or buffer.
        what: String,
        /// How many texels are bad in total.
        count: u64,
        /// Which kind the first bad texel is.
        kind: &'static str,
        /// Column of the first bad texel.
        x: u32,
        /// Row of the first bad texel.
        y: u32,
    },
    /// An option value is out of range or inconsistent.
    #[error("invalid option: {0}")]
    InvalidOption(String),
    /// Output could not be written.
    #[error("{}: cannot write: {message}", path.display())]
    Write {
        /// The file or folder being written.
        path: PathBuf,
        /// The reason.
        message: String,
    },
    /// A tabulated BRDF (file or arrays) is malformed: not JSON of the documented form, too
    /// few or too many samples, negative or non-finite values, angles out of order.
    #[error("{what}: invalid tabulated BRDF: {message}")]
    Brdf {
        /// The file or buffer.
        what: String,
        /// What is wrong.
        message: String,
    },
    /// A long operation was cancelled by its progress callback.
    #[error("cancelled")]
    Cancelled,
    /// Decoding a file or running a bake would need more memory than the budget allows
    /// (module `budget`); refused before the memory is allocated.
    #[error(
        "{what}: needs about {} of memory, more than the budget of {} (raise it with --memory, \
         or memory_limit in the C API)",
        bytes_in_words(*needed),
        bytes_in_words(*limit)
    )]
    MemoryBudget {
        /// The file (with its size) or the bake (method and size).
        what: String,
        /// The estimated peak, in bytes.
        needed: u64,
        /// The budget, in bytes.
        limit: u64,
    },
    /// The feature (colour) image has NaN, infinite or negative values and the caller asked to
    /// reject rather than repair them.
    #[error("{what}: {count} bad feature values ({kind}), the first at x={x}, y={y}")]
    BadFeatures {
        /// The file or buffer.
        what: String,
        /// How many texels have a bad value.
        count: u64,
        /// Which kind the first bad texel is.
        kind: &'static str,
        /// Column of the first bad texel.
        x: u32,
        /// Row of the first bad texel.
        y: u32,
    },
    /// An environment map has NaN, infinite or negative radiance and the caller asked to
    /// reject rather than repair it (`environment::BadTexels::Reject`).
    #[error(
        "{what}: {count} bad environment texels (NaN, infinite or negative), the first at x={x}, y={y}"
    )]
    BadEnvironment {
        /// The file or buffer.
        what: String,
        /// How many texels have a bad value.
        count: usize,
        /// Column of the first bad texel.
        x: u32,
        /// Row of the first bad texel.
        y: u32,
    },
}

/// A byte count in words: `512 MiB`, `4.0 GiB`, `3 bytes` (what `budget::format_bytes` gives).
pub(crate) fn bytes_in_words(bytes: u64) -> String {
    const UNITS: [(&str, u64); 4] = [
        ("TiB", 1 << 40),
        ("GiB", 1 << 30),
        ("MiB", 1 << 20),
        ("KiB", 1 << 10),
    ];
    for (name, size) in UNITS {
        if bytes >= size {
            let v = bytes as f64 / size as f64;
            return if v < 10.0 {
                format!("{v:.1} {name}")
            } else {
                format!("{v:.0} {name}")
            };
        }
    }
    format!("{bytes} bytes")
}

/// `v` for a message: as `{}` writes it at moderate magnitudes (and 0, NaN, ±inf), in
/// scientific notation (`1e308`, `1e-300`) outside 10⁻⁴ ≤ |v| < 10¹⁰, so that an absurd value
/// cannot make a one-line error hundreds of digits long.
pub fn compact_f64(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-4..1e10).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// `message` cut to at most `max` characters (on a character boundary) with `…` and the
/// number of characters left out: a parser's error that quotes a megabyte-long line of its
/// input stays one readable line.
pub fn clip_message(message: &str, max: usize) -> String {
    match message.char_indices().nth(max) {
        None => message.to_string(),
        Some((end, _)) => format!(
            "{}… ({} more characters)",
            &message[..end],
            message[end..].chars().count()
        ),
    }
}

/// How long a parse error of a scene, plan or batch file may be, in characters (what
/// [`clip_message`] keeps): room for the place and a few hundred characters of the line.
pub const MAX_PARSE_ERROR_CHARS: usize = 400;

/// The value of `all` whose `name` equals `s` (ASCII case ignored), or
/// [`Error::InvalidOption`] "unknown {what} 's' (expected one of: …)" listing every name: the
/// `FromStr` of ndfmap's named choices (methods, formats, containers, codecs).
pub(crate) fn parse_named<T: Copy>(
    s: &str,
    all: &[T],
    name: impl Fn(T) -> &'static str,
    what: &str,
) -> Result<T> {
    all.iter()
        .copied()
        .find(|&v| name(v).eq_ignore_ascii_case(s))
        .ok_or_else(|| {
            let names: Vec<_> = all.iter().map(|&v| name(v)).collect();
            Error::InvalidOption(format!(
                "unknown {what} '{s}' (expected one of: {})",
                names.join(", ")
            ))
        })
}

/// Shorthand for results carrying [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_print_compactly_at_absurd_magnitudes_only() {
        for (v, want) in [
            (0.0, "0"),
            (-0.0, "-0"),
            (0.05, "0.05"),
            (1e-4, "0.0001"),
            (128.0, "128"),
            (-1.5, "-1.5"),
            (1e9, "1000000000"),
            (1e10, "1e10"),
            (1e308, "1e308"),
            (f64::MAX, "1.7976931348623157e308"),
            (-1e300, "-1e300"),
            (1e-300, "1e-300"),
            (5e-324, "5e-324"),
            (f64::NAN, "NaN"),
            (f64::INFINITY, "inf"),
            (f64::NEG_INFINITY, "-inf"),
        ] {
            assert_eq!(compact_f64(v), want, "{v:?}");
        }
    }

    #[test]
    fn messages_are_clipped_on_a_character_boundary() {
        assert_eq!(clip_message("short", 5), "short");
        assert_eq!(clip_message("", 0), "");
        assert_eq!(clip_message("abcdef", 3), "abc… (3 more characters)");
        // Multi-byte characters count as one and are never split.
        assert_eq!(clip_message("ααααα", 2), "αα… (3 more characters)");
        let long = "x".repeat(1 << 20);
        let c = clip_message(&long, MAX_PARSE_ERROR_CHARS);
        assert_eq!(
            c,
            format!(
                "{}… ({} more characters)",
                "x".repeat(MAX_PARSE_ERROR_CHARS),
                (1 << 20) - MAX_PARSE_ERROR_CHARS
            )
        );
    }
}
