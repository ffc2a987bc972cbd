//! Writing a bake to a folder: `manifest.json` plus one OpenEXR file (RGBA, 32-bit or 16-bit
//! float) or PNG file (unorm) per texture per MIP level, named `<texture>_L<level>.exr`.
//!
//! The folder is written as a whole, atomically ([`write_folder`], the one atomic writer):
//! every file goes into a complete sibling staging folder first, which then replaces the
//! destination by rename. A folder therefore always holds one complete bake and nothing its
//! manifest does not list: never a mix of two bakes, never stale files of an earlier one.
//! Concurrent writers of one folder serialize on a lock file beside it; what a killed writer
//! left (a staging folder, or the previous folder set aside) is cleaned up or restored by the
//! next writer. Files are byte-deterministic: the same bake gives the same bytes, whatever the
//! thread count (OpenEXR chunks in increasing order).

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
    /// The storage format (f32, f16, unorm16, unorm8); for block-compressed files the format
    /// whose bias and clamps a shader applies to the sampled values (f16 for BC6H, unorm8 for
    /// BC7 and BC5; module `container`).
    pub texel_format: Format,
    /// The block compression of the files (`bc6h`, `bc7`, `bc5`), if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub compression: Option<String>,
    /// Texture addressing the bake assumes (`wrap` or `clamp`).
    pub addressing: crate::ingest::Addressing,
    /// Level sizes, finest first.
    pub levels: Vec<LevelInfo>,
    /// Texture chains.
    pub textures: Vec<TextureInfo>,
    /// The input and its convention.
    pub input: InputInfo,
    /// The content hash of a batch bake (module `batch`): SHA-256 of the ndfmap version, the
    /// bake's settings and the input's (and feature image's) bytes, `sha256:<hex>`. A build
    /// system or `ndfmap bake` itself skips an input whose folder's manifest has the hash it
    /// would write (`is_up_to_date` of module `batch`). Absent for bakes written without one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub content_hash: Option<String>,
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
            compression: None,
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
            content_hash: None,
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
pub(crate) fn write_level(
    path: &Path,
    w: u32,
    h: u32,
    level: &[[f32; 4]],
    ranges: [ValueRange; 4],
    format: Format,
) -> Result<()> {
    let px = |x: usize, y: usize| level[y * w as usize + x];
    let result = match format {
        Format::F32 => write_exr(path, w, h, |x, y| {
            let v = px(x, y);
            (v[0], v[1], v[2], v[3])
        }),
        Format::F16 => write_exr(path, w, h, |x, y| {
            let v = px(x, y).map(half::f16::from_f32);
            (v[0], v[1], v[2], v[3])
        }),
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

/// Writes an RGBA OpenEXR file: run-length encoded 64×64 tiles (the `exr` crate's default
/// encoding) in increasing order, compressed on the calling thread (the files of a bake are
/// written in parallel instead: `exr`'s parallel writer starts a thread pool per file and
/// writes its chunks in the order they finish), so the file's bytes depend only on its texels.
fn write_exr<S: exr::prelude::IntoSample>(
    path: &Path,
    w: u32,
    h: u32,
    px: impl Fn(usize, usize) -> (S, S, S, S) + Sync,
) -> std::result::Result<(), String> {
    use exr::prelude::WritableImage;
    use exr::prelude::{Blocks, Compression, Encoding, Image, LineOrder, SpecificChannels, Vec2};
    let encoding = Encoding {
        compression: Compression::RLE,
        blocks: Blocks::Tiles(Vec2(64, 64)),
        line_order: LineOrder::Increasing,
    };
    let channels = SpecificChannels::rgba(|Vec2(x, y): Vec2<usize>| px(x, y));
    Image::from_encoded_channels((w as usize, h as usize), encoding, channels)
        .write()
        .non_parallel()
        .to_file(path)
        .map_err(|e| e.to_string())
}

fn write_err(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// Writes `bake` and its manifest as folder `dir` (its parent created if missing), atomically
/// ([`write_folder`]): afterwards `dir` holds this bake and nothing else, or, on failure, what
/// it held before. Returns the manifest's path.
///
/// # Errors
///
/// [`Error::InvalidOption`] for an empty path or one without a folder name (`/`, `..`),
/// [`Error::Write`] when `dir` holds files that no ndfmap bake wrote (it is not replaced), or
/// when a file or folder cannot be written.
pub fn write_bake(bake: &Bake, input: InputInfo, dir: &Path) -> Result<PathBuf> {
    write_bake_with(bake, Manifest::new(bake, input), dir)
}

/// [`write_bake`] with the manifest given (made by [`Manifest::new`] for `bake`, with fields
/// such as [`Manifest::content_hash`] set by the caller).
pub(crate) fn write_bake_with(bake: &Bake, manifest: Manifest, dir: &Path) -> Result<PathBuf> {
    let json = serde_json::to_string_pretty(&manifest).map_err(|e| write_err(dir, e))?;
    write_folder(dir, |staging| {
        use rayon::prelude::*;
        // One job per file, in parallel; each file is written alone (same bytes for any thread
        // count), and the first failure in file order is the one reported.
        let files: Vec<(usize, usize)> = (0..bake.textures.len())
            .flat_map(|t| (0..bake.sizes.len()).map(move |k| (t, k)))
            .collect();
        let results: Vec<Result<()>> = files
            .par_iter()
            .map(|&(t, k)| {
                let (texture, name) = (&bake.textures[t], &manifest.textures[t].files[k]);
                let (w, h) = bake.sizes[k];
                let level = &texture.levels[k];
                write_level(
                    &staging.join(name),
                    w,
                    h,
                    level,
                    texture.ranges,
                    bake.format,
                )
                // Name the final file in the error, not the staging copy.
                .map_err(|e| match e {
                    Error::Write { message, .. } => write_err(&dir.join(name), message),
                    other => other,
                })
            })
            .collect();
        results.into_iter().collect::<Result<()>>()?;
        let staged = staging.join(MANIFEST);
        std::fs::write(&staged, json + "\n").map_err(|e| write_err(&dir.join(MANIFEST), e))
    })?;
    Ok(dir.join(MANIFEST))
}

/// The manifest's file name.
pub const MANIFEST: &str = "manifest.json";

/// What a folder written by [`write_folder`] has beside it while it is written: `.NAME` and one
/// of these suffixes (then the writer's process id and a nonce).
const STAGING: &str = ".ndfmap-staging-";
/// The previous folder, set aside during the swap.
const OLD: &str = ".ndfmap-old-";
/// The lock file beside the folder (kept: removing a lock file races with its next user).
const LOCK: &str = ".ndfmap-lock";

/// Writes folder `dir` as a whole, atomically: `fill` writes every file into an empty staging
/// folder beside `dir`; only when it succeeds does the staging folder replace `dir` (the old
/// folder is renamed aside, the staging folder renamed to `dir`, the old one removed). At every
/// moment `dir` is either the old folder or the new one, complete; a failure of `fill` leaves
/// `dir` as it was.
///
/// - Writers of the same `dir` serialize on an exclusive lock of the file `.NAME.ndfmap-lock`
///   beside it (released by the system when a writer dies): the last to finish wins, complete.
/// - Under the lock, what earlier writers left is cleaned up first: their staging folders are
///   removed, and a folder set aside by a writer killed between its two renames is restored
///   (or removed when `dir` exists).
/// - An existing `dir` is replaced only if it is empty or holds nothing but an ndfmap bake
///   (`manifest.json`, the files it lists, files named like texture levels, and staging
///   folders of older versions): a folder of other files is an error, untouched.
pub fn write_folder(dir: &Path, fill: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    write_folder_of(dir, Owned::Bake, fill)
}

/// What files of an existing folder a writer may replace (with the staging folders of older
/// versions).
#[derive(Clone, Copy)]
enum Owned<'a> {
    /// A bake's: `manifest.json`, the files it lists and files named like texture levels.
    Bake,
    /// The files the function names, and no others; the string names the kind of folder
    /// (`plan`) in errors.
    Named(&'a str, &'a dyn Fn(&str) -> bool),
}

/// [`write_folder`] for a folder of another `kind` (a word for errors: `plan`): an existing
/// `dir` is replaced only if every file in it is one `owns` names, so a writer of one kind
/// never replaces a bake nor a folder of other files. `ndfmap plan -o` writes its plan
/// folders so (`plan::write_plan_folder`).
pub fn write_folder_owning(
    dir: &Path,
    kind: &str,
    owns: &dyn Fn(&str) -> bool,
    fill: impl FnOnce(&Path) -> Result<()>,
) -> Result<()> {
    write_folder_of(dir, Owned::Named(kind, owns), fill)
}

/// [`write_folder`] replacing an existing folder only if it holds nothing but `owned` files.
fn write_folder_of(
    dir: &Path,
    owned: Owned<'_>,
    fill: impl FnOnce(&Path) -> Result<()>,
) -> Result<()> {
    if dir.as_os_str().is_empty() {
        return Err(Error::InvalidOption(
            "the output folder's path is empty".into(),
        ));
    }
    let Some(name) = dir.file_name().map(|n| n.to_string_lossy().into_owned()) else {
        return Err(Error::InvalidOption(format!(
            "output folder '{}' has no name (write into a named folder, e.g. out/bake)",
            dir.display()
        )));
    };
    let parent = parent_of(dir);
    std::fs::create_dir_all(&parent).map_err(|e| write_err(&parent, e))?;
    let lock = lock_writers(&parent, &name)?;
    clean_up(&parent, &name, dir)?;
    check_replaceable(dir, owned)?;
    let nonce = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    let tag = format!("{}-{nonce}", std::process::id());
    let staging = parent.join(format!(".{name}{STAGING}{tag}"));
    std::fs::create_dir(&staging).map_err(|e| write_err(&staging, e))?;
    let result = fill(&staging)
        .and_then(|()| swap_in(&staging, dir, &parent.join(format!(".{name}{OLD}{tag}"))));
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&staging);
    }
    drop(lock);
    result
}

/// Removes what dead writers of folder `dir` left beside it (staging folders, a folder set
/// aside), under the writers' lock, as [`write_folder`] does before it writes: for callers
/// that find `dir` current and write nothing (module `batch`).
pub(crate) fn tidy(dir: &Path) -> Result<()> {
    let Some(name) = dir.file_name().map(|n| n.to_string_lossy().into_owned()) else {
        return Ok(());
    };
    let parent = parent_of(dir);
    let lock = lock_writers(&parent, &name)?;
    let result = clean_up(&parent, &name, dir);
    drop(lock);
    result
}

/// The folder that holds `dir` (`.` for a bare name).
fn parent_of(dir: &Path) -> PathBuf {
    match dir.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Takes the writers' lock of folder `name` in `parent` (the file `.{name}.ndfmap-lock`
/// beside it), held until the returned file is dropped.
fn lock_writers(parent: &Path, name: &str) -> Result<std::fs::File> {
    let lock_path = parent.join(format!(".{name}{LOCK}"));
    let lock = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&lock_path)
        .map_err(|e| write_err(&lock_path, e))?;
    lock.lock().map_err(|e| write_err(&lock_path, e))?;
    Ok(lock)
}

/// Replaces `dir` by `staging`, setting an existing `dir` aside as `old` first.
fn swap_in(staging: &Path, dir: &Path, old: &Path) -> Result<()> {
    let existed = dir.exists();
    if existed {
        std::fs::rename(dir, old).map_err(|e| write_err(dir, e))?;
    }
    if let Err(e) = std::fs::rename(staging, dir) {
        if existed {
            let _ = std::fs::rename(old, dir);
        }
        return Err(write_err(dir, e));
    }
    if existed {
        // The new folder is in place; a failure to remove the old one is cleaned up by the
        // next writer.
        let _ = std::fs::remove_dir_all(old);
    }
    Ok(())
}

/// Under the lock: removes the staging folders writers of `dir` (named `name` in `parent`)
/// left, and restores (or removes) a folder set aside by a writer killed between its renames.
fn clean_up(parent: &Path, name: &str, dir: &Path) -> Result<()> {
    let (staging, old) = (format!(".{name}{STAGING}"), format!(".{name}{OLD}"));
    let entries = std::fs::read_dir(parent).map_err(|e| write_err(parent, e))?;
    let mut leftovers: Vec<(bool, PathBuf)> = entries
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let n = e.file_name().to_string_lossy().into_owned();
            let is_old = n.starts_with(&old);
            (is_old || n.starts_with(&staging)).then(|| (is_old, e.path()))
        })
        .collect();
    leftovers.sort();
    for (is_old, path) in leftovers {
        if is_old && !dir.exists() {
            std::fs::rename(&path, dir).map_err(|e| write_err(dir, e))?;
        } else {
            std::fs::remove_dir_all(&path).map_err(|e| write_err(&path, e))?;
        }
    }
    Ok(())
}

/// Whether `dir` may be replaced: missing, empty, or holding only `owned` files.
fn check_replaceable(dir: &Path, owned: Owned<'_>) -> Result<()> {
    let meta = match std::fs::symlink_metadata(dir) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(write_err(dir, e)),
        Ok(m) => m,
    };
    if !meta.is_dir() {
        return Err(write_err(dir, "exists and is not a folder"));
    }
    let listed: Vec<String> = match owned {
        Owned::Bake => std::fs::read_to_string(dir.join(MANIFEST))
            .ok()
            .and_then(|text| serde_json::from_str::<Manifest>(&text).ok())
            .map(|m| m.textures.into_iter().flat_map(|t| t.files).collect())
            .unwrap_or_default(),
        Owned::Named(..) => Vec::new(),
    };
    for entry in std::fs::read_dir(dir).map_err(|e| write_err(dir, e))? {
        let entry = entry.map_err(|e| write_err(dir, e))?;
        let n = entry.file_name().to_string_lossy().into_owned();
        let ours = match owned {
            Owned::Bake => n == MANIFEST || listed.contains(&n) || is_level_file(&n),
            Owned::Named(_, owns) => owns(&n),
        };
        if ours || n.starts_with(STAGING) {
            continue;
        }
        return Err(write_err(
            dir,
            format!(
                "holds '{n}', which no ndfmap {} wrote: not replacing a folder of other \
                 files (write into a new or empty folder)",
                match owned {
                    Owned::Bake => "bake",
                    Owned::Named(kind, _) => kind,
                }
            ),
        ));
    }
    Ok(())
}

/// Whether `n` is named like a level file of a bake (`lobe0_L03.exr`, `mean_L00.png`).
fn is_level_file(n: &str) -> bool {
    let Some((stem, ext)) = n.rsplit_once('.') else {
        return false;
    };
    let Some((texture, level)) = stem.rsplit_once("_L") else {
        return false;
    };
    matches!(ext, "exr" | "png")
        && !texture.is_empty()
        && texture.chars().all(|c| c.is_ascii_alphanumeric())
        && level.len() >= 2
        && level.chars().all(|c| c.is_ascii_digit())
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
        // A folder inside the temporary one, so that its lock file is removed with it.
        let out = dir.path().join("bake");
        let m = write_bake(&b, input(&map), &out).unwrap();
        let manifest: Manifest =
            serde_json::from_str(&std::fs::read_to_string(m).unwrap()).unwrap();
        assert_eq!(manifest.method, Method::Olano);
        assert_eq!(manifest.levels.len(), 3);
        assert_eq!(manifest.addressing, Addressing::Clamp);
        for (t, info) in b.textures.iter().zip(&manifest.textures) {
            for (k, f) in info.files.iter().enumerate() {
                let (w, h, px) = read_level(&out.join(f)).unwrap();
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
