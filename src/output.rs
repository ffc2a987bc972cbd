//! Writing a bake to a folder: `manifest.json` plus one OpenEXR file (RGBA, 32-bit float) per
//! texture per MIP level, named `<texture>_L<level>.exr`.
//!
//! Writing is all-or-nothing: every file goes to a staging folder inside the destination first;
//! only when all are written is an older `manifest.json` removed, the files renamed into place,
//! and the new manifest renamed in last. A folder with a `manifest.json` therefore always holds
//! a complete bake, and a failure leaves no partial output behind.

use crate::bake::{Bake, Method};
use crate::error::{Error, Result};
use crate::format::{Format, ValueRange};
use crate::ingest::{IngestOptions, IngestStats};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Version of the manifest layout; bumped when a field changes meaning.
pub const MANIFEST_VERSION: u32 = 1;

/// Where the input came from and how it was read (recorded in the manifest).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InputInfo {
    /// The input file, if the map came from one.
    pub path: Option<String>,
    /// Ingest options (tangent-space convention, encoding, channels, addressing).
    pub options: IngestOptions,
    /// What ingest found.
    pub stats: IngestStats,
}

/// One level's size in the manifest.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LevelInfo {
    /// MIP level, 0 = finest.
    pub level: usize,
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
}

/// One texture chain in the manifest.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct TextureInfo {
    /// Texture name.
    pub name: String,
    /// Meaning of R, G, B, A.
    pub channels: Vec<String>,
    /// Value range of R, G, B, A (`signed` channels are biased in unorm formats).
    pub ranges: Vec<ValueRange>,
    /// One file per level, finest first, relative to the manifest.
    pub files: Vec<String>,
}

/// `manifest.json`: everything an engine needs to load and interpret a bake.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Always `"ndfmap-bake"`.
    pub format: String,
    /// [`MANIFEST_VERSION`].
    pub manifest_version: u32,
    /// The ndfmap version that wrote it.
    pub ndfmap_version: String,
    /// Filtering method.
    pub method: Method,
    /// Method parameters (empty for the baselines, which have none at bake time).
    pub parameters: serde_json::Value,
    /// How the files are organised.
    pub storage: String,
    /// How values are encoded in the files.
    pub encoding: String,
    /// The storage format (f32, f16, unorm16, unorm8).
    pub texel_format: Format,
    /// Texture addressing the bake assumes (`wrap` or `clamp`).
    pub addressing: crate::ingest::Addressing,
    /// Level sizes, finest first.
    pub levels: Vec<LevelInfo>,
    /// Texture chains.
    pub textures: Vec<TextureInfo>,
    /// The input and its convention.
    pub input: InputInfo,
}

impl Manifest {
    /// Describes `bake` (files named as [`write_bake`] names them).
    pub fn new(bake: &Bake, input: InputInfo) -> Self {
        Manifest {
            format: "ndfmap-bake".into(),
            manifest_version: MANIFEST_VERSION,
            ndfmap_version: env!("CARGO_PKG_VERSION").into(),
            method: bake.method,
            parameters: bake.parameters.clone(),
            storage: match bake.format {
                Format::F32 | Format::F16 => {
                    "one OpenEXR file per texture per level (RGBA, scanlines top row first)"
                }
                Format::Unorm16 | Format::Unorm8 => {
                    "one PNG file per texture per level (RGBA, rows top first, linear data, no sRGB)"
                }
            }
            .into(),
            encoding: match bake.format {
                Format::F32 => "f32: values as baked".into(),
                Format::F16 => "f16: values as baked, rounded to half floats".into(),
                f => format!(
                    "{f}: unsigned-normalized; channels whose range is 'signed' store 0.5 + 0.5*v"
                ),
            },
            texel_format: bake.format,
            addressing: bake.addressing,
            levels: bake
                .sizes
                .iter()
                .enumerate()
                .map(|(level, &(width, height))| LevelInfo {
                    level,
                    width,
                    height,
                })
                .collect(),
            textures: bake
                .textures
                .iter()
                .map(|t| TextureInfo {
                    name: t.name.into(),
                    channels: t.channels.iter().map(|c| c.to_string()).collect(),
                    ranges: t.ranges.to_vec(),
                    files: (0..bake.sizes.len())
                        .map(|k| file_name(t.name, k, bake.format))
                        .collect(),
                })
                .collect(),
            input,
        }
    }
}

/// File name of texture `name` at `level`: `.exr` for float formats, `.png` for unorm ones.
pub fn file_name(name: &str, level: usize, format: Format) -> String {
    let ext = match format {
        Format::F32 | Format::F16 => "exr",
        Format::Unorm16 | Format::Unorm8 => "png",
    };
    format!("{name}_L{level:02}.{ext}")
}

/// Writes one level of one texture in the bake's format.
fn write_level(
    path: &Path,
    w: u32,
    h: u32,
    level: &[[f32; 4]],
    ranges: [ValueRange; 4],
    format: Format,
) -> Result<()> {
    let px = |x: usize, y: usize| level[y * w as usize + x];
    let result = match format {
        Format::F32 => exr::prelude::write_rgba_file(path, w as usize, h as usize, |x, y| {
            let v = px(x, y);
            (v[0], v[1], v[2], v[3])
        })
        .map_err(|e| e.to_string()),
        Format::F16 => exr::prelude::write_rgba_file(path, w as usize, h as usize, |x, y| {
            let v = px(x, y).map(half::f16::from_f32);
            (v[0], v[1], v[2], v[3])
        })
        .map_err(|e| e.to_string()),
        Format::Unorm16 => {
            let data: Vec<u16> = level
                .iter()
                .flat_map(|t| {
                    (0..4).map(move |c| crate::pack::unorm_code(t[c], ranges[c], 65535.0))
                })
                .collect();
            image::ImageBuffer::<image::Rgba<u16>, _>::from_raw(w, h, data)
                .expect("buffer matches the level size")
                .save_with_format(path, image::ImageFormat::Png)
                .map_err(|e| e.to_string())
        }
        Format::Unorm8 => {
            let data: Vec<u8> = level
                .iter()
                .flat_map(|t| {
                    (0..4).map(move |c| crate::pack::unorm_code(t[c], ranges[c], 255.0) as u8)
                })
                .collect();
            image::RgbaImage::from_raw(w, h, data)
                .expect("buffer matches the level size")
                .save_with_format(path, image::ImageFormat::Png)
                .map_err(|e| e.to_string())
        }
    };
    result.map_err(|e| write_err(path, e))
}

fn write_err(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// Writes `bake` and its manifest into `dir` (created if missing), all-or-nothing (module docs).
/// Returns the manifest's path.
pub fn write_bake(bake: &Bake, input: InputInfo, dir: &Path) -> Result<PathBuf> {
    std::fs::create_dir_all(dir).map_err(|e| write_err(dir, e))?;
    let staging = dir.join(format!(".ndfmap-staging-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&staging);
    std::fs::create_dir(&staging).map_err(|e| write_err(dir, e))?;
    let result = stage_and_commit(bake, input, dir, &staging);
    let _ = std::fs::remove_dir_all(&staging);
    result
}

fn stage_and_commit(bake: &Bake, input: InputInfo, dir: &Path, staging: &Path) -> Result<PathBuf> {
    let manifest = Manifest::new(bake, input);
    for (t, info) in bake.textures.iter().zip(&manifest.textures) {
        for (k, level) in t.levels.iter().enumerate() {
            let (w, h) = bake.sizes[k];
            let path = staging.join(&info.files[k]);
            // Name the final file in the error, not the staging copy.
            write_level(&path, w, h, level, t.ranges, bake.format).map_err(|e| match e {
                Error::Write { message, .. } => write_err(&dir.join(&info.files[k]), message),
                other => other,
            })?;
        }
    }
    let json = serde_json::to_string_pretty(&manifest).map_err(|e| write_err(dir, e))?;
    let staged_manifest = staging.join("manifest.json");
    std::fs::write(&staged_manifest, json + "\n").map_err(|e| write_err(&staged_manifest, e))?;
    // Commit: the old manifest goes first, the new one comes last.
    let final_manifest = dir.join("manifest.json");
    match std::fs::remove_file(&final_manifest) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(write_err(&final_manifest, e)),
    }
    for info in &manifest.textures {
        for f in &info.files {
            std::fs::rename(staging.join(f), dir.join(f))
                .map_err(|e| write_err(&dir.join(f), e))?;
        }
    }
    std::fs::rename(&staged_manifest, &final_manifest)
        .map_err(|e| write_err(&final_manifest, e))?;
    Ok(final_manifest)
}

/// Reads one written level back as RGBA f32 texels (for tests and tools).
pub fn read_level(path: &Path) -> Result<(u32, u32, Vec<[f32; 4]>)> {
    let image = exr::prelude::read_first_rgba_layer_from_file(
        path,
        |size, _| (size.0, vec![[0.0f32; 4]; size.0 * size.1]),
        |(w, px): &mut (usize, Vec<[f32; 4]>), pos, (r, g, b, a): (f32, f32, f32, f32)| {
            px[pos.1 * *w + pos.0] = [r, g, b, a];
        },
    )
    .map_err(|e| Error::Decode {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    let size = image.layer_data.size;
    Ok((
        size.0 as u32,
        size.1 as u32,
        image.layer_data.channel_data.pixels.1,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::{Addressing, BadNormals, NormalMap};
    use crate::methods::bake;
    use glam::Vec3;

    fn input(map: &NormalMap) -> InputInfo {
        InputInfo {
            path: None,
            options: IngestOptions::default(),
            stats: map.stats().clone(),
        }
    }

    #[test]
    fn written_bake_reads_back_bit_exact_with_a_complete_manifest() {
        let v = (0..15)
            .map(|i| Vec3::new((i as f32).sin() * 0.5, 0.2, 1.0))
            .collect();
        let map = NormalMap::from_vectors(5, 3, v, Addressing::Clamp, BadNormals::Repair).unwrap();
        let b = bake(&map, Method::Olano);
        let dir = tempfile::tempdir().unwrap();
        let m = write_bake(&b, input(&map), dir.path()).unwrap();
        let manifest: Manifest =
            serde_json::from_str(&std::fs::read_to_string(m).unwrap()).unwrap();
        assert_eq!(manifest.method, Method::Olano);
        assert_eq!(manifest.levels.len(), 3);
        assert_eq!(manifest.addressing, Addressing::Clamp);
        for (t, info) in b.textures.iter().zip(&manifest.textures) {
            for (k, f) in info.files.iter().enumerate() {
                let (w, h, px) = read_level(&dir.path().join(f)).unwrap();
                assert_eq!((w, h), b.sizes[k]);
                assert_eq!(px, t.levels[k]);
            }
        }
        // No staging folder is left behind.
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert!(
            names
                .iter()
                .all(|n| !n.to_string_lossy().starts_with(".ndfmap-staging"))
        );
    }

    #[test]
    fn unwritable_destination_is_an_error_naming_the_path() {
        let map =
            NormalMap::from_vectors(1, 1, vec![Vec3::Z], Addressing::Wrap, BadNormals::Repair)
                .unwrap();
        let b = bake(&map, Method::Plain);
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("a-file");
        std::fs::write(&file, b"x").unwrap();
        let err = write_bake(&b, input(&map), &file.join("sub")).unwrap_err();
        assert!(matches!(err, Error::Write { .. }), "{err}");
        assert!(err.to_string().contains("a-file"), "{err}");
    }
}
