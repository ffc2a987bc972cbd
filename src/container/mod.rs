//! GPU texture containers: one KTX2 or DDS file per texture of a bake, each holding the
//! texture's whole MIP chain in one format — RGBA32F, RGBA16F, RGBA16 or RGBA8 (the bake's
//! storage format) or a block compression ([`crate::compress::Codec`]) — always linear, never
//! sRGB.
//!
//! Main types: [`Container`] (OpenEXR folders, KTX2 or DDS), [`Encoding`] (what a file's
//! texels are), [`check`] (refuses an impossible combination before any work),
//! [`texture_file`] (one texture's file, in memory) and [`write_bake`] (a whole bake and its
//! `manifest.json`, through the one atomic folder writer, `output::write_folder`).
//!
//! KTX2 files ([`ktx2`]) carry their data-format descriptor (built by the `ktx2` crate) and
//! key/value metadata naming the method, the texture, its channels, ranges and encoding; DDS
//! files ([`dds`]) have the DX10 header and no metadata of their own: the manifest beside them
//! is their sidecar, with the same information. Files are byte-deterministic: the same bake
//! gives the same bytes whatever the thread count.

pub mod dds;
pub mod ktx2;

use crate::bake::{Bake, Method};
use crate::compress::Codec;
use crate::error::{Error, Result};
use crate::format::{Format, ValueRange};
use crate::output::{InputInfo, MANIFEST, Manifest};
use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

/// How a bake's textures are stored on disk.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Container {
    /// One OpenEXR (float) or PNG (unorm) file per texture per level (module `output`).
    #[default]
    Exr,
    /// One KTX2 file per texture with its whole MIP chain.
    Ktx2,
    /// One DDS file (DX10 header) per texture with its whole MIP chain.
    Dds,
}

impl Container {
    /// Every container.
    pub const ALL: [Container; 3] = [Container::Exr, Container::Ktx2, Container::Dds];

    /// The lower-case name on the command line (and the file extension of KTX2 and DDS).
    pub fn name(self) -> &'static str {
        match self {
            Container::Exr => "exr",
            Container::Ktx2 => "ktx2",
            Container::Dds => "dds",
        }
    }
}

impl fmt::Display for Container {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Container {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        crate::error::parse_named(s, &Container::ALL, Container::name, "container")
    }
}

/// What the texels of a container file are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Encoding {
    /// Uncompressed RGBA in a storage format.
    Plain(Format),
    /// Block-compressed.
    Block(Codec),
}

impl Encoding {
    /// The encoding a file of `bake` gets: its storage format, or `codec` when given.
    pub fn of(bake: &Bake, codec: Option<Codec>) -> Encoding {
        codec.map_or(Encoding::Plain(bake.format), Encoding::Block)
    }

    /// The name (`f16`, `bc7`).
    pub fn name(self) -> &'static str {
        match self {
            Encoding::Plain(f) => f.name(),
            Encoding::Block(c) => c.name(),
        }
    }

    /// How values are stored, in words (the manifest's `encoding`, KTX2's `ndfmap.encoding`).
    pub fn description(self) -> String {
        match self {
            Encoding::Plain(Format::F32) => "f32: values as baked".into(),
            Encoding::Plain(Format::F16) => "f16: values as baked, rounded to half floats".into(),
            Encoding::Plain(f) => format!(
                "{f}: unsigned-normalized; channels whose range is 'signed' store 0.5 + 0.5*v"
            ),
            Encoding::Block(Codec::Bc6h) => "bc6h: unsigned half-float blocks (BC6H_UF16); \
                 channels whose range is 'signed' store 0.5 + 0.5*v; no alpha (reads 1)"
                .into(),
            Encoding::Block(c) => format!(
                "{c}: unsigned-normalized blocks; channels whose range is 'signed' store \
                 0.5 + 0.5*v"
            ),
        }
    }

    /// The format a shader decodes the sampled values as (its bias and clamps): the storage
    /// format, or the codec's [`Codec::shading_format`].
    pub fn shading_format(self) -> Format {
        match self {
            Encoding::Plain(f) => f,
            Encoding::Block(c) => c.shading_format(),
        }
    }
}

/// File name of texture `name` in `container` (KTX2 or DDS): `lobe0.ktx2`.
pub fn file_name(name: &str, container: Container) -> String {
    format!("{name}.{}", container.name())
}

/// Whether `container` can hold a bake of `method` (`lobes_or_lmax`, `color` as in
/// [`crate::methods::texture_ranges`]) stored in `format`, or block-compressed with `codec`,
/// checked before any work: OpenEXR folders hold no block compression, no container holds the
/// measurement-only [`Codec::Bc6hBc4`], and the codec must hold every texture
/// ([`crate::compress::check_layout`], naming the texture). Unbounded textures in unorm
/// formats are refused by [`crate::methods::check_options`].
pub fn check(
    container: Container,
    method: Method,
    lobes_or_lmax: usize,
    color: bool,
    format: Format,
    codec: Option<Codec>,
) -> Result<()> {
    let Some(codec) = codec else {
        return Ok(());
    };
    if container == Container::Exr {
        return Err(Error::InvalidOption(format!(
            "the exr container (OpenEXR/PNG files) cannot hold {codec} blocks; use --container \
             ktx2 or dds"
        )));
    }
    if codec == Codec::Bc6hBc4 {
        return Err(Error::InvalidOption(format!(
            "{codec} stores one texture as two (RGB and alpha): a measurement for eval that no \
             {container} file holds; use bc7, or bc6h for textures without alpha"
        )));
    }
    if format != Format::F32 {
        return Err(Error::InvalidOption(format!(
            "block compression {codec} encodes the baked f32 values; format {format} would round \
             them twice (leave the format at f32)"
        )));
    }
    crate::compress::check_layout(method, lobes_or_lmax, color, codec)
}

/// Appends `texels` uncompressed in `format` to `out`, little-endian (what
/// [`crate::pack::pack_level`] gives on a little-endian host), channels of range `ranges`.
fn encode_texels(texels: &[[f32; 4]], ranges: [ValueRange; 4], format: Format, out: &mut Vec<u8>) {
    for texel in texels {
        for (c, &v) in texel.iter().enumerate() {
            match format {
                Format::F32 => out.extend_from_slice(&v.to_le_bytes()),
                Format::F16 => out.extend_from_slice(&half::f16::from_f32(v).to_le_bytes()),
                Format::Unorm16 => out.extend_from_slice(
                    &crate::pack::unorm_code(v, ranges[c], 65535.0).to_le_bytes(),
                ),
                Format::Unorm8 => out.push(crate::pack::unorm_code(v, ranges[c], 255.0) as u8),
            }
        }
    }
}

/// The bytes of level `level` of texture `texture` uncompressed in `format`, little-endian,
/// rows top to bottom (what [`crate::pack::pack_level`] gives on a little-endian host).
fn plain_level(bake: &Bake, texture: usize, level: usize, format: Format) -> Vec<u8> {
    let t = &bake.textures[texture];
    let mut out = Vec::with_capacity(crate::pack::packed_len(bake, level, format));
    encode_texels(&t.levels[level], t.ranges, format, &mut out);
    out
}

/// Refuses [`Codec::Bc6hBc4`], which stores one texture as two: a measurement for `eval` that
/// no file of `container` holds.
fn refuse_measurement_codec(codec: Option<Codec>, container: Container) -> Result<()> {
    match codec {
        Some(c @ Codec::Bc6hBc4) => Err(Error::InvalidOption(format!(
            "{c} is a measurement for eval that no {container} file holds"
        ))),
        _ => Ok(()),
    }
}

/// One texture's KTX2 or DDS file written a band of rows at a time, in any order: for bakes
/// too large to hold in memory (issue 19's tiled bakes, docs/scale.md). The header and the
/// level layout depend only on the bake's description — level sizes, method, parameters, the
/// texture's name, channels and ranges, the storage format (`bake`'s textures may hold no
/// levels) — so every level's bytes lie at an offset known before any texel is baked, and
/// [`StreamedFile::write_rows`] writes rows where they belong (positional writes). Block
/// codecs ([`StreamedFile::create_blocks`]) encode whole 4-row blocks: their rows come in
/// pieces of a multiple of 4 rows, the last piece of a level excepted. Written completely, the
/// file is byte-identical to [`texture_file`] of the whole bake (tested), the bytes between
/// levels being zeros as there.
#[derive(Debug)]
pub struct StreamedFile {
    file: std::fs::File,
    path: PathBuf,
    offsets: Vec<u64>,
    sizes: Vec<(u32, u32)>,
    format: Format,
    ranges: [ValueRange; 4],
    /// The block codec, with whether A holds data ([`crate::bake::Texture::uses_alpha`]).
    codec: Option<(Codec, bool)>,
    name: &'static str,
}

impl StreamedFile {
    /// Creates (or truncates) `path` as texture `texture` of `bake` in `container` (KTX2 or
    /// DDS) in `bake.format`, writes its header and sets its final length.
    ///
    /// # Errors
    ///
    /// [`Error::InvalidOption`] for the exr container or a texture index out of range,
    /// [`Error::Write`] when the file cannot be created or sized (a full disk).
    pub fn create(path: &Path, bake: &Bake, texture: usize, container: Container) -> Result<Self> {
        Self::create_blocks(path, bake, texture, container, None)
    }

    /// [`StreamedFile::create`] with the levels block-compressed with `codec` when given
    /// (the blocks [`texture_file`] makes; the texture's values are then rounded to
    /// `bake.format` by the caller, as [`write_bake`] rounds them before encoding).
    ///
    /// # Errors
    ///
    /// As [`StreamedFile::create`], and [`Error::InvalidOption`] for a codec that cannot hold
    /// the texture ([`crate::compress::check_texture`]) or [`Codec::Bc6hBc4`] (no container
    /// holds it).
    pub fn create_blocks(
        path: &Path,
        bake: &Bake,
        texture: usize,
        container: Container,
        codec: Option<Codec>,
    ) -> Result<Self> {
        let t = bake.textures.get(texture).ok_or_else(|| {
            Error::InvalidOption(format!(
                "texture {texture} out of range: the bake has {}",
                bake.textures.len()
            ))
        })?;
        refuse_measurement_codec(codec, container)?;
        if let Some(c) = codec {
            crate::compress::check_texture(c, bake.method, t.name, &t.channels, &t.ranges)?;
        }
        let encoding = Encoding::of(bake, codec);
        let texel_bytes = 4 * bake.format.channel_bytes() as u64;
        let lengths: Vec<u64> = bake
            .sizes
            .iter()
            .map(|&(w, h)| match codec {
                Some(c) => crate::compress::level_len(w, h, c) as u64,
                None => w as u64 * h as u64 * texel_bytes,
            })
            .collect();
        let (prefix, offsets) = match container {
            Container::Ktx2 => ktx2::layout(bake, texture, encoding, &lengths),
            Container::Dds => dds::layout(bake, encoding, &lengths),
            Container::Exr => {
                return Err(Error::InvalidOption(
                    "a streamed file is one KTX2 or DDS file; the exr container is a folder".into(),
                ));
            }
        };
        let write_err = |e: std::io::Error| Error::Write {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        let end = offsets
            .iter()
            .zip(&lengths)
            .map(|(o, l)| o + l)
            .max()
            .unwrap_or(prefix.len() as u64);
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(path)
            .map_err(write_err)?;
        file.set_len(end).map_err(write_err)?;
        write_at(&file, &prefix, 0).map_err(write_err)?;
        Ok(StreamedFile {
            file,
            path: path.to_path_buf(),
            offsets,
            sizes: bake.sizes.clone(),
            format: bake.format,
            ranges: t.ranges,
            codec: codec.map(|c| (c, t.uses_alpha())),
            name: t.name,
        })
    }

    /// The block codec of the file's levels, if any.
    pub fn codec(&self) -> Option<Codec> {
        self.codec.map(|(c, _)| c)
    }

    /// Writes whole rows `first_row..` of `level` (`texels`: a multiple of the level's width,
    /// row-major), encoded as [`texture_file`] encodes them. Values must already be what the
    /// format holds (f16 within ±65504: [`Error::InvalidOption`] otherwise, naming the level).
    /// In a block-compressed file `first_row` is a multiple of 4, and so is the row count
    /// unless the rows end the level (its last block row is padded as [`texture_file`] pads
    /// it).
    ///
    /// # Errors
    ///
    /// [`Error::InvalidOption`] for rows outside the level, a partial row, or rows not on
    /// block boundaries, and [`Error::Write`] when the write fails (a full disk).
    pub fn write_rows(&self, level: usize, first_row: u32, texels: &[[f32; 4]]) -> Result<()> {
        let Some(&(w, h)) = self.sizes.get(level) else {
            return Err(Error::InvalidOption(format!("level {level} out of range")));
        };
        let rows = texels.len() / w as usize;
        if !texels.len().is_multiple_of(w as usize) || first_row as usize + rows > h as usize {
            return Err(Error::InvalidOption(format!(
                "{} texels from row {first_row} are not whole rows of level {level} ({w}x{h})",
                texels.len()
            )));
        }
        if self.format == Format::F16
            && let Some(v) = texels
                .iter()
                .flatten()
                .find(|v| v.abs() > crate::pack::F16_MAX)
        {
            return Err(Error::InvalidOption(format!(
                "format f16 cannot hold {} level {level}: value {v} exceeds {}; use f32",
                self.path.display(),
                crate::pack::F16_MAX
            )));
        }
        let (bytes, at) = match self.codec {
            Some((codec, alpha)) => {
                let last = first_row as usize + rows == h as usize;
                if !first_row.is_multiple_of(4) || !(rows.is_multiple_of(4) || last) {
                    return Err(Error::InvalidOption(format!(
                        "{rows} rows from row {first_row} of level {level} ({w}x{h}) are not \
                         whole 4-row blocks of a {codec} file"
                    )));
                }
                if rows == 0 {
                    return Ok(());
                }
                let what = format!("texture '{}' level {level}", self.name);
                let blocks = crate::compress::encode_level(
                    &what,
                    w,
                    rows as u32,
                    texels,
                    self.ranges,
                    alpha,
                    codec,
                )?;
                let at =
                    self.offsets[level] + crate::compress::level_len(w, first_row, codec) as u64;
                (blocks, at)
            }
            None => {
                let texel_bytes = 4 * self.format.channel_bytes() as u64;
                let mut bytes = Vec::with_capacity(texels.len() * texel_bytes as usize);
                encode_texels(texels, self.ranges, self.format, &mut bytes);
                (
                    bytes,
                    self.offsets[level] + first_row as u64 * w as u64 * texel_bytes,
                )
            }
        };
        write_at(&self.file, &bytes, at).map_err(|e| Error::Write {
            path: self.path.clone(),
            message: e.to_string(),
        })
    }
}

impl StreamedFile {
    /// Reads back `rows` whole rows of `level` from `first_row` of an f32 file (what a bake
    /// that spills rows before converting them, `banded::write_folder` for the exr container,
    /// reads).
    ///
    /// # Errors
    ///
    /// [`Error::InvalidOption`] for another format or rows outside the level, [`Error::Write`]
    /// (naming the file) when the read fails.
    pub fn read_rows(&self, level: usize, first_row: u32, rows: u32) -> Result<Vec<[f32; 4]>> {
        let Some(&(w, h)) = self.sizes.get(level) else {
            return Err(Error::InvalidOption(format!("level {level} out of range")));
        };
        if self.format != Format::F32
            || self.codec.is_some()
            || first_row as u64 + rows as u64 > h as u64
        {
            return Err(Error::InvalidOption(format!(
                "rows {first_row}..+{rows} of level {level} ({w}x{h}) of an {} file",
                self.format
            )));
        }
        let texels = w as usize * rows as usize;
        let mut bytes = vec![0u8; texels * 16];
        let at = self.offsets[level] + first_row as u64 * w as u64 * 16;
        read_at(&self.file, &mut bytes, at).map_err(|e| Error::Write {
            path: self.path.clone(),
            message: e.to_string(),
        })?;
        Ok(bytes
            .chunks_exact(16)
            .map(|b| {
                let v = |i: usize| f32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
                [v(0), v(4), v(8), v(12)]
            })
            .collect())
    }
}

/// Reads exactly `bytes.len()` bytes at byte `offset` of `file`.
fn read_at(file: &std::fs::File, bytes: &mut [u8], offset: u64) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        std::os::unix::fs::FileExt::read_exact_at(file, bytes, offset)
    }
    #[cfg(not(unix))]
    {
        use std::io::{Read, Seek, SeekFrom};
        let mut f = file;
        f.seek(SeekFrom::Start(offset))?;
        f.read_exact(bytes)
    }
}

/// Writes all of `bytes` at byte `offset` of `file`.
fn write_at(file: &std::fs::File, bytes: &[u8], offset: u64) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        std::os::unix::fs::FileExt::write_all_at(file, bytes, offset)
    }
    #[cfg(not(unix))]
    {
        use std::io::{Seek, SeekFrom, Write};
        let mut f = file;
        f.seek(SeekFrom::Start(offset))?;
        f.write_all(bytes)
    }
}

/// Every level of texture `texture` of `bake` in `encoding`, finest first.
fn levels(bake: &Bake, texture: usize, encoding: Encoding) -> Result<Vec<Vec<u8>>> {
    let t = &bake.textures[texture];
    match encoding {
        Encoding::Plain(format) => {
            crate::pack::check(bake, texture, format)?;
            Ok((0..bake.sizes.len())
                .map(|k| plain_level(bake, texture, k, format))
                .collect())
        }
        Encoding::Block(codec) => {
            crate::compress::check_texture(codec, bake.method, t.name, &t.channels, &t.ranges)?;
            (0..bake.sizes.len())
                .map(|k| {
                    let (w, h) = bake.sizes[k];
                    let what = format!("texture '{}' level {k}", t.name);
                    crate::compress::encode_level(
                        &what,
                        w,
                        h,
                        &t.levels[k],
                        t.ranges,
                        t.uses_alpha(),
                        codec,
                    )
                })
                .collect()
        }
    }
}

/// One texture's file in `container` (KTX2 or DDS), in memory: texture `texture` of `bake`
/// with its whole MIP chain, in the bake's storage format or block-compressed with `codec`.
///
/// # Errors
///
/// [`Error::InvalidOption`] for the exr container (a folder of files, [`write_bake`]), a
/// texture index out of range, a codec that cannot hold the texture, or values the format
/// cannot hold (f16 beyond ±65504).
pub fn texture_file(
    bake: &Bake,
    texture: usize,
    container: Container,
    codec: Option<Codec>,
) -> Result<Vec<u8>> {
    if texture >= bake.textures.len() {
        return Err(Error::InvalidOption(format!(
            "texture {texture} out of range: the bake has {}",
            bake.textures.len()
        )));
    }
    refuse_measurement_codec(codec, container)?;
    let encoding = Encoding::of(bake, codec);
    let data = levels(bake, texture, encoding)?;
    match container {
        Container::Exr => Err(Error::InvalidOption(
            "the exr container is a folder of files per level: write it with write_bake".into(),
        )),
        Container::Ktx2 => Ok(ktx2::file(bake, texture, encoding, &data)),
        Container::Dds => Ok(dds::file(bake, encoding, &data)),
    }
}

/// The texels [`stream_texture`] encodes per write: 64 Ki, 1 MiB of f32 texels.
const STREAM_TEXELS: usize = 1 << 16;

/// Writes texture `texture` of `bake` (uncompressed) as its `container` file at `path`
/// through [`StreamedFile`], a few rows at a time: the same bytes as [`texture_file`]
/// (`StreamedFile`'s contract), without building the whole file in memory. Building it held
/// each texture's encoded levels and the file (21 MiB each for a 1024² f32 texture) on every
/// thread at once: about 90 MiB more peak for a 1024² J = 6 f32 bake on two threads
/// (docs/scale.md, "Stop 56").
fn stream_texture(bake: &Bake, texture: usize, container: Container, path: &Path) -> Result<()> {
    crate::pack::check(bake, texture, bake.format)?;
    let file = StreamedFile::create(path, bake, texture, container)?;
    for (k, level) in bake.textures[texture].levels.iter().enumerate() {
        let width = bake.sizes[k].0.max(1) as usize;
        let rows = (STREAM_TEXELS / width).max(1);
        for (i, chunk) in level.chunks(rows * width).enumerate() {
            file.write_rows(k, (i * rows) as u32, chunk)?;
        }
    }
    Ok(())
}

/// The manifest of `bake` written in `container` with `codec`: [`Manifest::new`]'s, with one
/// file per texture, the container's storage and the encoding's description.
pub fn manifest(
    bake: &Bake,
    input: InputInfo,
    container: Container,
    codec: Option<Codec>,
) -> Manifest {
    let mut m = Manifest::new(bake, input);
    if container == Container::Exr {
        return m;
    }
    let encoding = Encoding::of(bake, codec);
    m.storage = match container {
        Container::Ktx2 => {
            "one KTX2 file per texture holding its whole MIP chain (finest level \
             first in the level index, rows top first, linear, key/value metadata ndfmap.*)"
        }
        _ => {
            "one DDS file per texture (DX10 header) holding its whole MIP chain (finest \
             first, rows top first, linear; this manifest is its metadata)"
        }
    }
    .into();
    m.encoding = encoding.description();
    m.texel_format = encoding.shading_format();
    m.compression = codec.map(|c| c.name().to_string());
    for (t, info) in bake.textures.iter().zip(&mut m.textures) {
        info.files = vec![file_name(t.name, container)];
    }
    m
}

/// Writes `bake` and its manifest as folder `dir` in `container` (KTX2 or DDS: one file per
/// texture; exr: [`crate::output::write_bake`]), atomically through
/// [`crate::output::write_folder`]: afterwards `dir` holds this bake and nothing else, or, on
/// failure, what it held before. Returns the manifest's path.
///
/// # Errors
///
/// As [`crate::output::write_bake`], and [`texture_file`]'s (checked per texture before the
/// folder is swapped in).
pub fn write_bake(
    bake: &Bake,
    input: InputInfo,
    dir: &Path,
    container: Container,
    codec: Option<Codec>,
) -> Result<PathBuf> {
    write_bake_hashed(bake, input, dir, container, codec, None)
}

/// [`write_bake`] with `content_hash` recorded in the manifest ([`Manifest::content_hash`],
/// module `batch`). The manifest is the last file written into the staging folder, and the
/// folder replaces `dir` only once complete, so a manifest with a hash always describes
/// complete files.
pub fn write_bake_hashed(
    bake: &Bake,
    input: InputInfo,
    dir: &Path,
    container: Container,
    codec: Option<Codec>,
    content_hash: Option<String>,
) -> Result<PathBuf> {
    if container == Container::Exr {
        if let Some(c) = codec {
            return Err(Error::InvalidOption(format!(
                "the exr container cannot hold {c} blocks; use ktx2 or dds"
            )));
        }
        let mut manifest = Manifest::new(bake, input);
        manifest.content_hash = content_hash;
        return crate::output::write_bake_with(bake, manifest, dir);
    }
    let mut manifest = manifest(bake, input, container, codec);
    manifest.content_hash = content_hash;
    let json = serde_json::to_string_pretty(&manifest).map_err(|e| Error::Write {
        path: dir.to_path_buf(),
        message: e.to_string(),
    })?;
    crate::output::write_folder(dir, |staging| {
        use rayon::prelude::*;
        // One file per job; each is built alone (same bytes whatever the thread count), and
        // the first failure in texture order is reported.
        let results: Vec<Result<()>> = (0..bake.textures.len())
            .into_par_iter()
            .map(|t| {
                let name = &manifest.textures[t].files[0];
                if codec.is_none() {
                    return stream_texture(bake, t, container, &staging.join(name));
                }
                let bytes = texture_file(bake, t, container, codec)?;
                std::fs::write(staging.join(name), bytes).map_err(|e| Error::Write {
                    path: dir.join(name),
                    message: e.to_string(),
                })
            })
            .collect();
        results.into_iter().collect::<Result<()>>()?;
        std::fs::write(staging.join(MANIFEST), json + "\n").map_err(|e| Error::Write {
            path: dir.join(MANIFEST),
            message: e.to_string(),
        })
    })?;
    Ok(dir.join(MANIFEST))
}
