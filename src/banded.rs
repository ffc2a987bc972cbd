//! Bounded-memory mixture bakes (issue 19 item 4, issue 14 item 5; docs/scale.md): the same
//! fits as module `mixture`'s in-memory bake, bit for bit, produced in full-width row bands and
//! streamed to the output files level by level, so that no level finer than a chosen one is
//! ever held whole.
//!
//! **Levels.** With `fine` = m, levels 0..m are *fine*: produced one band of rows at a time
//! (a band is `band_rows` finest rows, a multiple of 2ᵐ, and the matching rows of each fine
//! level) and written out as they are made; levels ≥ m are *coarse*: held whole, as the
//! in-memory bake holds them, each written once fitted and dropped once its finer neighbour
//! no longer needs it.
//!
//! **Why it is exact.** A texel's fit depends only on its inputs (its footprint's normals,
//! sampled by a hash of its *global* coordinates, its children's fits, and in the aligned pass
//! its own unaligned fit, its parent's and four neighbours' aligned fits): computed in any
//! order that respects those dependencies it has the same bits. When the map's height is a
//! multiple of 2ᵐ, a fine texel's footprint and children lie in its own band, so the
//! unaligned pass (finest level up) runs band by band; the aligned pass (eq 29, coarsest level
//! down) chains along rows through the upper-right neighbour, so a fine level runs band after
//! band, in tiles along `x + 2y` inside the band (`mixture`'s tiling), with the previous
//! band's last aligned row kept. The unaligned fits of fine levels 1..m−1, which the aligned pass starts from, are
//! fitted again per band instead of being kept (one unaligned level of extra work at
//! m = 3: level 1 is a closed form); level 0 is always a closed form (the normal in the
//! parent's best slot, or slot 0 unaligned).
//!
//! **Memory.** The source (8-bit samples: 3 bytes per texel, `ingest::CompactNormals`; or
//! a `NormalMap`), the coarse levels (unaligned and aligned, level m at most `texels / 4ᵐ`
//! texels of J components of 16 bytes, plus colours) and one band. [`Bands::for_size`] picks
//! m so that level m has at most 2²² texels: m = 1 up to 4096², 3 at 16384².

use crate::bake::{Bake, BakeOptions, Method, Progress};
use crate::compress::Codec;
use crate::container::{Container, StreamedFile};
use crate::error::{Error, Result};
use crate::format::Format;
use crate::ingest::{Addressing, CompactFeature, CompactNormals, NormalMap};
use crate::mixture::{Levels, Model, Rows, Source, TanModel, VmfModel, assemble};
use crate::output::{InputInfo, MANIFEST};
use crate::pyramid::level_sizes;
use glam::Vec3;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Most texels of the finest coarse level [`Bands::for_size`] chooses (2048²).
pub const COARSE_TEXELS: u64 = 1 << 22;

/// Finest texels per band that [`Bands::for_size`] aims for (rounded to whole rows): enough
/// rows that the fine levels' tiles keep the threads busy (16 rows of level 1 at 16K).
pub const BAND_TEXELS: u64 = 1 << 19;

/// Most finest texels of level 0 made and sent at once (level 0 has no neighbour
/// dependencies, so a band's level 0 goes in pieces of whole rows).
const FINEST_CHUNK: u32 = 1 << 16;

/// How a banded bake cuts the pyramid (module docs): levels below `fine` are produced in bands
/// of `band_rows` finest rows, the others whole.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Bands {
    /// m: the finest level held whole (at least 1; level 0 is always banded).
    pub fine: usize,
    /// Finest rows per band: a multiple of 2^(`fine`) (any positive count when `fine` is 1:
    /// only level 0 is banded then).
    pub band_rows: u32,
}

impl Bands {
    /// The bands a `width × height` map is baked in: m the smallest level with at most
    /// [`COARSE_TEXELS`] texels (at least 1), lowered until 2ᵐ divides the height (so
    /// footprints stay inside bands; m = 1 fits any size), and bands of about
    /// [`BAND_TEXELS`] finest texels, rounded up to a multiple of 2ᵐ rows.
    pub fn for_size(width: u32, height: u32) -> Bands {
        let sizes = level_sizes(width, height);
        let mut fine = 1;
        while fine + 1 < sizes.len() && sizes[fine].0 as u64 * sizes[fine].1 as u64 > COARSE_TEXELS
        {
            fine += 1;
        }
        while fine > 1 && !height.is_multiple_of(1 << fine) {
            fine -= 1;
        }
        let step = 1u32 << fine;
        let rows = (BAND_TEXELS / width.max(1) as u64).clamp(1, height.max(1) as u64) as u32;
        Bands {
            fine,
            band_rows: rows.div_ceil(step) * step,
        }
    }

    /// Checks the bands against a `width × height` map: m ≥ 1, below the level count (maps of
    /// one level have nothing to band: m = 1 is accepted and they are baked whole), and with
    /// m ≥ 2 bands a positive multiple of 2ᵐ rows and the height a multiple of 2ᵐ.
    pub fn check(&self, width: u32, height: u32) -> Result<()> {
        let levels = level_sizes(width, height).len();
        let step = 1u64 << self.fine.min(31);
        let bad = |why: &str| {
            Err(Error::InvalidOption(format!(
                "bands of {} rows over {} fine levels for a {width}x{height} map: {why}",
                self.band_rows, self.fine
            )))
        };
        if self.fine == 0 || (self.fine >= levels && self.fine > 1) {
            return bad("the fine levels must be 1 to the level count - 1");
        }
        if self.band_rows == 0 || (self.fine >= 2 && !(self.band_rows as u64).is_multiple_of(step))
        {
            return bad("a band must be a positive multiple of 2^fine rows (any with fine 1)");
        }
        if self.fine >= 2 && !(height as u64).is_multiple_of(step) {
            return bad("with 2 or more fine levels the height must be a multiple of 2^fine");
        }
        Ok(())
    }
}

/// A map whose normals are kept as their samples ([`CompactNormals`]), with an optional
/// feature image: the source of a bounded-memory bake of a map too large for a
/// [`NormalMap`].
pub struct CompactSource<'a> {
    /// The normals.
    pub normals: &'a CompactNormals,
    /// The feature (colour) image, kept as its samples (converted to linear RGBA per texel);
    /// the normals' size.
    pub feature: Option<&'a CompactFeature>,
}

impl Source for CompactSource<'_> {
    fn width(&self) -> u32 {
        self.normals.width()
    }
    fn height(&self) -> u32 {
        self.normals.height()
    }
    #[inline]
    fn normal(&self, i: usize) -> Vec3 {
        self.normals.normal(i)
    }
    #[inline]
    fn feature(&self, i: usize) -> Option<[f32; 4]> {
        self.feature.map(|f| f.texel(i))
    }
    fn has_feature(&self) -> bool {
        self.feature.is_some()
    }
}

/// The map a banded bake reads.
pub enum Map<'a> {
    /// Decoded normals (and feature image).
    Full(&'a NormalMap),
    /// Samples decoded per texel.
    Compact(CompactSource<'a>),
}

impl Map<'_> {
    fn size(&self) -> (u32, u32) {
        match self {
            Map::Full(m) => (m.width(), m.height()),
            Map::Compact(c) => (c.width(), c.height()),
        }
    }
    fn color(&self) -> bool {
        match self {
            Map::Full(m) => m.feature().is_some(),
            Map::Compact(c) => c.has_feature(),
        }
    }
    fn addressing(&self) -> Addressing {
        match self {
            Map::Full(m) => m.addressing(),
            Map::Compact(c) => c.normals.addressing(),
        }
    }
    /// [`Error::FeatureSize`] when a compact map's feature image is not the normals' size.
    fn check(&self) -> Result<()> {
        match self {
            Map::Compact(CompactSource {
                normals,
                feature: Some(f),
            }) => f.check_size("feature", (normals.width(), normals.height())),
            _ => Ok(()),
        }
    }
    /// Bytes per texel the source holds (normals and feature image), as
    /// [`estimate_peak_bytes`] counts them.
    pub fn source_bytes(&self) -> u64 {
        match self {
            Map::Full(m) => DECODED_NORMAL_BYTES + m.feature().map_or(0, |_| DECODED_FEATURE_BYTES),
            Map::Compact(c) => {
                c.normals.bytes_per_texel() + c.feature.map_or(0, |f| f.bytes_per_texel())
            }
        }
    }
}

/// Bytes per texel of decoded normals as [`estimate_peak_bytes`] counts them: a
/// [`NormalMap`]'s vectors (12) and the decoded file while the map is made.
pub const DECODED_NORMAL_BYTES: u64 = 16;

/// Bytes per texel of a decoded feature image (linear RGBA f32).
pub const DECODED_FEATURE_BYTES: u64 = 16;

/// Where a banded bake sends its rows: texture `texture`'s rows `first_row..` of `level`,
/// whole rows, row-major, f32 as baked. Every row of every level is sent exactly once.
pub(crate) trait RowSink: Send {
    /// Takes rows of one texture's level.
    fn rows(
        &mut self,
        texture: usize,
        level: usize,
        first_row: u32,
        texels: &[[f32; 4]],
    ) -> Result<()>;
}

/// Collects the rows into an in-memory [`Bake`] (what the tests compare with the untiled bake).
pub(crate) struct Collect(pub(crate) Bake);

impl RowSink for Collect {
    fn rows(
        &mut self,
        texture: usize,
        level: usize,
        first_row: u32,
        texels: &[[f32; 4]],
    ) -> Result<()> {
        let w = self.0.sizes[level].0 as usize;
        let levels = &mut self.0.textures[texture].levels;
        while levels.len() <= level {
            let (lw, lh) = self.0.sizes[levels.len()];
            levels.push(vec![[f32::NAN; 4]; lw as usize * lh as usize]);
        }
        let at = first_row as usize * w;
        levels[level][at..at + texels.len()].copy_from_slice(texels);
        Ok(())
    }
}

impl Rows {
    /// Sends every plane to `sink` as `level`'s rows (components to textures 0..J, colours to
    /// J..2J).
    fn send(&self, sink: &mut dyn RowSink, level: usize, j: usize) -> Result<()> {
        for (s, plane) in self.fit.texels.iter().enumerate().take(j) {
            sink.rows(s, level, self.y0, plane)?;
        }
        if let Some(colors) = &self.fit.colors {
            for (s, plane) in colors.iter().enumerate().take(j) {
                sink.rows(j + s, level, self.y0, plane)?;
            }
        }
        Ok(())
    }
}

/// Sends level 0's rows `y0..y1` ([`Levels::finest_rows`], slots from `parent`) in pieces of
/// at most [`FINEST_CHUNK`] texels.
fn send_finest<M: Model, S: Source>(
    fit: &Levels<M, S>,
    (y0, y1): (u32, u32),
    parent: Option<&Rows>,
    sink: &mut dyn RowSink,
) -> Result<()> {
    let step = (FINEST_CHUNK / fit.sizes[0].0.max(1)).max(1);
    let mut y = y0;
    while y < y1 {
        fit.cancel.check()?;
        let end = (y + step).min(y1);
        fit.finest_rows((y, end), parent).send(sink, 0, fit.j)?;
        y = end;
    }
    Ok(())
}

/// Bakes `model`'s mixture of `src` in `bands` (module docs), sending every row of every
/// texture to `sink`. The rows are those of `mixture::bake_mixture` for the same map and
/// options, bit for bit.
fn bake_banded<M: Model, S: Source>(
    src: &S,
    options: &BakeOptions,
    bands: Bands,
    sink: &mut dyn RowSink,
    progress: &mut Progress,
) -> Result<()> {
    crate::mixture::check(options)?;
    let (width, height) = (src.width(), src.height());
    bands.check(width, height)?;
    let sizes = level_sizes(width, height);
    let levels = sizes.len();
    let color = src.has_feature();
    let j = options.lobes;
    let aligned = options.align.is_some();
    let ctx = Levels::<M, S>::new(src, options, progress.cancel_flag());
    let band_count = height.div_ceil(bands.band_rows);
    let band = |b: u32, k: usize| -> (u32, u32) {
        let (lo, hi) = (b * bands.band_rows, ((b + 1) * bands.band_rows).min(height));
        (lo >> k, hi >> k)
    };
    // Progress: every level of a pass an equal share (as the in-memory bake).
    let passes = if aligned { 2.0 } else { 1.0 };
    let steps = levels as f64 * passes;
    let cancel = progress.cancel_flag();
    let mut report = |step: f64, f: f64| -> Result<()> {
        cancel.check()?;
        progress.report((step + f.clamp(0.0, 1.0)) / steps)
    };
    if levels == 1 {
        // A 1×1 map: one texel, its normal in slot 0.
        send_finest(&ctx, (0, 1), None, sink)?;
        return Ok(());
    }
    let m = if levels >= 2 {
        bands.fine.min(levels - 1)
    } else {
        1
    };
    // The unaligned pass's texels carry colours only in an unaligned bake (its output).
    let colors = color && !aligned;
    // Pass A: unaligned, finest up. Levels < m in bands (sent when unaligned), level m
    // assembled from the bands' rows, coarser levels whole.
    let mut coarse: Vec<Option<Rows>> = (0..levels).map(|_| None).collect();
    if m == 1 {
        if !aligned {
            for b in 0..band_count {
                send_finest(&ctx, band(b, 0), None, sink)?;
            }
        }
    } else {
        let mut level_m: Option<Rows> = None;
        for b in 0..band_count {
            let mut prev: Option<Rows> = None;
            if !aligned {
                send_finest(&ctx, band(b, 0), None, sink)?;
            }
            for k in 1..=m {
                let rows =
                    ctx.unaligned_rows(k, band(b, k), prev.as_ref(), colors, &mut |_| Ok(()))?;
                if !aligned && k < m {
                    rows.send(sink, k, j)?;
                }
                prev = Some(rows);
            }
            let rows = prev.expect("m ≥ 1 levels fitted");
            match level_m.as_mut() {
                None => level_m = Some(rows),
                Some(l) => l.append(rows),
            }
            // Level 1..m of a band: one level's worth over all bands for each.
            report(
                0.0,
                (b + 1) as f64 / band_count as f64 * (m as f64 - 1.0).max(0.0) / m as f64,
            )?;
        }
        coarse[m] = level_m;
    }
    let first_whole = if m == 1 { 1 } else { m + 1 };
    for k in first_whole..levels {
        let step = (k - 1) as f64;
        let rows = ctx.unaligned_rows(
            k,
            (0, sizes[k].1),
            coarse[k - 1].as_ref(),
            colors,
            &mut |f| report(step, f),
        )?;
        coarse[k] = Some(rows);
    }
    if !aligned {
        for (k, rows) in coarse.iter().enumerate().skip(m) {
            rows.as_ref()
                .expect("every coarse level fitted")
                .send(sink, k, j)?;
        }
        return Ok(());
    }
    // Pass B: aligned, coarsest down. Coarse levels whole, each sent once fitted; its parent
    // and its unaligned fits dropped then.
    let mut parent: Option<Rows> = None;
    for k in (m..levels).rev() {
        let own = coarse[k].take().expect("every coarse level fitted");
        let step = levels as f64 + (levels - 1 - k) as f64;
        let rows = ctx.aligned_rows(k, (0, sizes[k].1), &own, parent.as_ref(), None, &mut |f| {
            report(step, f)
        })?;
        drop(own);
        rows.send(sink, k, j)?;
        parent = Some(rows);
    }
    let level_m = parent.expect("level m fitted");
    // Fine levels band by band: the unaligned fits of levels 1..m−1 again (they depend only
    // on the band's normals), then the aligned levels m−1..1 and level 0.
    let mut above: Vec<Option<Rows>> = (0..m).map(|_| None).collect();
    for b in 0..band_count {
        let mut own: Vec<Option<Rows>> = (0..m).map(|_| None).collect();
        for k in 1..m {
            let rows =
                ctx.unaligned_rows(k, band(b, k), own[k - 1].as_ref(), false, &mut |_| Ok(()))?;
            own[k] = Some(rows);
        }
        let mut band_parent: Option<Rows> = None;
        for k in (1..m).rev() {
            let p = band_parent.as_ref().unwrap_or(&level_m);
            let rows = ctx.aligned_rows(
                k,
                band(b, k),
                own[k].as_ref().expect("fitted above"),
                Some(p),
                above[k].as_ref(),
                &mut |_| Ok(()),
            )?;
            rows.send(sink, k, j)?;
            above[k] = Some(rows.last_row());
            band_parent = Some(rows);
        }
        let p = band_parent.as_ref().unwrap_or(&level_m);
        send_finest(&ctx, band(b, 0), Some(p), sink)?;
        report(
            levels as f64 + (levels - m) as f64,
            (b + 1) as f64 / band_count as f64,
        )?;
    }
    Ok(())
}

/// The bake's description for `map` (textures without levels), as the in-memory bake's.
fn description(map: &Map, method: Method, options: &BakeOptions) -> Bake {
    let (w, h) = map.size();
    let sizes = level_sizes(w, h);
    let (color, addressing) = (map.color(), map.addressing());
    match method {
        Method::Tan2005 => assemble::<TanModel>(color, addressing, options, sizes, Vec::new()),
        _ => assemble::<VmfModel>(color, addressing, options, sizes, Vec::new()),
    }
}

/// Runs the banded bake of `method` (vMF or Tan 2005) for `map` into `sink`.
fn run(
    map: &Map,
    method: Method,
    options: &BakeOptions,
    bands: Bands,
    sink: &mut dyn RowSink,
    progress: &mut Progress,
) -> Result<()> {
    match (method, map) {
        (Method::Vmf, Map::Full(m)) => {
            bake_banded::<VmfModel, _>(*m, options, bands, sink, progress)
        }
        (Method::Vmf, Map::Compact(c)) => {
            bake_banded::<VmfModel, _>(c, options, bands, sink, progress)
        }
        (Method::Tan2005, Map::Full(m)) => {
            bake_banded::<TanModel, _>(*m, options, bands, sink, progress)
        }
        (Method::Tan2005, Map::Compact(c)) => {
            bake_banded::<TanModel, _>(c, options, bands, sink, progress)
        }
        _ => Err(Error::InvalidOption(format!(
            "{method} has no banded bake (vmf and tan2005 have)"
        ))),
    }
}

/// Bakes `method` (vMF or Tan 2005) for `map` in `bands` into an in-memory [`Bake`]: the same
/// bits as `methods::bake_with` (what the tests prove; the bake itself holds every level, so
/// this saves no memory: [`write_folder`] does).
pub fn bake_in_bands(
    map: &Map,
    method: Method,
    options: &BakeOptions,
    bands: Bands,
) -> Result<Bake> {
    map.check()?;
    crate::methods::check_options(method, options, map.color(), None)?;
    let mut sink = Collect(description(map, method, options));
    crate::bake::run_with_progress(&mut |_| true, |progress| {
        run(map, method, options, bands, &mut sink, progress)
    })?;
    Ok(sink.0)
}

/// Peak memory of [`write_folder`] for a `width × height` map (`color`: with a feature image;
/// `source_bytes`: bytes per texel the normals and the feature image take as held,
/// [`Map::source_bytes`]: 3 for 8-bit RGB samples kept compact, [`DECODED_NORMAL_BYTES`] for
/// decoded normals, plus the feature's), in bytes: what the budget checks (module `budget`)
/// and `batch` admits by. The source, the coarse levels (the unaligned pass's level m and coarser, 4/3 × 16 J bytes per
/// level-m texel, while the aligned level m, 16 J, and its parent, 16 J / 4, are held, both
/// doubled by colours), a band of fine levels 1..m−1 (16 J per finest texel of the band,
/// doubled for colour), level 0's piece and [`crate::methods::PEAK_FIXED_BYTES`]. Measured
/// peaks lie below it (docs/scale.md: 1024² J = 6 aligned colour 153 MiB of an estimated
/// 232; 4096² compact 1112 of 1250).
pub fn estimate_peak_bytes(
    width: u32,
    height: u32,
    options: &BakeOptions,
    color: bool,
    source_bytes: u64,
    bands: Bands,
) -> u64 {
    let texels = width as u64 * height as u64;
    let j = options.lobes as u64;
    let source = texels.saturating_mul(source_bytes);
    let coarse_texels = texels >> (2 * bands.fine.min(31) as u64);
    // Unaligned levels ≥ m (4/3 of level m) while the aligned level m (and its colours) is
    // fitted from its parent (1/4 of it), with a third of level m for slack: in twelfths,
    // 20 + 15 (1 + colour).
    let coarse = coarse_texels * 16 * j * (20 + 15 * (1 + color as u64)) / 12;
    // Fine levels 1..m−1 of a band (unaligned again, aligned, kept row) and level 0's piece.
    let band = if bands.fine >= 2 {
        bands.band_rows.min(height) as u64 * width as u64 * 16 * j * (1 + color as u64)
    } else {
        0
    };
    let piece = FINEST_CHUNK as u64 * 16 * j * 3 * (1 + color as u64);
    crate::methods::PEAK_FIXED_BYTES
        .saturating_add(source)
        .saturating_add(coarse)
        .saturating_add(band)
        .saturating_add(piece)
}

/// Writes the rows to one file per texture: KTX2 and DDS files at their final layout
/// ([`StreamedFile`]); for the exr container, a KTX2 f32 spill file per texture, turned into
/// one OpenEXR (or PNG) file per level when the bake ends (in `fill_staging`).
///
/// Block-compressed files take whole 4-row blocks: a level's rows that do not fill one yet
/// wait in `pending` (at most 3 rows per texture and level) until the next rows of that
/// level, which the bake sends in order, complete it.
struct FileSink {
    files: Vec<StreamedFile>,
    ranges: Vec<[crate::format::ValueRange; 4]>,
    names: Vec<&'static str>,
    format: Format,
    /// Level sizes.
    sizes: Vec<(u32, u32)>,
    /// Per texture and level: the first row and the texels of rows not yet written (block
    /// codecs only).
    pending: Vec<Vec<(u32, Vec<[f32; 4]>)>>,
}

/// Texels a [`FileSink`] encodes and writes per piece (rounded up to whole 4-row blocks for
/// block codecs).
const WRITE_CHUNK: usize = 1 << 14;

impl FileSink {
    /// Writes rows `first_row..` of `level` of texture `texture` in pieces of whole rows in
    /// parallel (positional writes: any order).
    fn write(
        &self,
        texture: usize,
        level: usize,
        first_row: u32,
        texels: &[[f32; 4]],
    ) -> Result<()> {
        let ranges = self.ranges[texture];
        let w = self.sizes[level].0 as usize;
        let file = &self.files[texture];
        let mut rows = (WRITE_CHUNK / w).max(1);
        if file.codec().is_some() {
            rows = rows.next_multiple_of(4);
        }
        let format = self.format;
        texels
            .par_chunks(rows * w)
            .enumerate()
            .map(|(i, chunk)| {
                let mut rounded = chunk.to_vec();
                crate::pack::round_trip_texels(&mut rounded, ranges, format);
                file.write_rows(level, first_row + (i * rows) as u32, &rounded)
            })
            .collect::<Vec<Result<()>>>()
            .into_iter()
            .collect()
    }

    /// Checks that every block-compressed level was written to its last row.
    fn finish(&self) -> Result<()> {
        for (t, levels) in self.pending.iter().enumerate() {
            if let Some(k) = levels.iter().position(|(_, rows)| !rows.is_empty()) {
                return Err(Error::InvalidOption(format!(
                    "texture '{}' level {k}: rows left unwritten (a bug: rows must come in order)",
                    self.names[t]
                )));
            }
        }
        Ok(())
    }
}

impl RowSink for FileSink {
    fn rows(
        &mut self,
        texture: usize,
        level: usize,
        first_row: u32,
        texels: &[[f32; 4]],
    ) -> Result<()> {
        // The values the format holds, as `pack::quantize_into` rounds them (in `write`).
        crate::pack::check_level(self.names[texture], level, texels, self.format)?;
        if self.files[texture].codec().is_none() {
            return self.write(texture, level, first_row, texels);
        }
        let (w, h) = (self.sizes[level].0 as usize, self.sizes[level].1);
        // Rows held back from the last call come first (copied only then); `start`, the first
        // row to write, is a multiple of 4 as the bake sends its rows.
        let (held_from, mut held) = std::mem::take(&mut self.pending[texture][level]);
        let (start, rows): (u32, std::borrow::Cow<[[f32; 4]]>) = if held.is_empty() {
            (first_row, texels.into())
        } else {
            if held_from as usize + held.len() / w != first_row as usize {
                return Err(Error::InvalidOption(format!(
                    "texture '{}' level {level}: rows from {first_row} sent out of order (a bug)",
                    self.names[texture]
                )));
            }
            held.extend_from_slice(texels);
            (held_from, held.into())
        };
        if !start.is_multiple_of(4) {
            return Err(Error::InvalidOption(format!(
                "texture '{}' level {level}: rows from {start} start inside a block (a bug)",
                self.names[texture]
            )));
        }
        let end = start + (rows.len() / w) as u32;
        // Whole blocks now; the level's last rows whatever their count.
        let ready = if end == h { end } else { end & !3 };
        let split = (ready - start) as usize * w;
        if split > 0 {
            self.write(texture, level, start, &rows[..split])?;
        }
        self.pending[texture][level] = (ready, rows[split..].to_vec());
        Ok(())
    }
}

/// Bakes `method` (vMF or Tan 2005) for `map` in `bands` (`None`: [`Bands::for_size`]) and
/// writes it as folder `dir` in `container` and `format`, block-compressed with `codec` when
/// given (KTX2 and DDS), every level streamed to its file as it is produced (module docs):
/// the same files as `methods::bake_with`, `pack::quantize_into` and
/// `container::write_bake_hashed` write, byte for byte, in bounded memory
/// ([`estimate_peak_bytes`]). Atomic like them (`output::write_folder`: the files are made
/// in a staging folder, the manifest last, and the folder swapped in only when complete; an
/// interrupted bake leaves `dir` as it was). Returns the manifest's path.
///
/// # Errors
///
/// Invalid options, bands or combinations (checked before any work), a memory budget the
/// estimate exceeds, a value the format cannot hold, a write failure (full disk), or
/// [`Error::Cancelled`] from `progress`.
#[allow(clippy::too_many_arguments)]
pub fn write_folder(
    map: &Map,
    method: Method,
    options: &BakeOptions,
    format: Format,
    container: Container,
    codec: Option<Codec>,
    dir: &Path,
    input: InputInfo,
    content_hash: Option<String>,
    bands: Option<Bands>,
    progress: &mut (dyn FnMut(f32) -> bool + Send),
) -> Result<PathBuf> {
    let (w, h) = map.size();
    let color = map.color();
    map.check()?;
    crate::methods::check_options(method, options, color, Some(format))?;
    let lobes = options.lobes;
    crate::container::check(container, method, lobes, color, format, codec)?;
    let bands = bands.unwrap_or_else(|| Bands::for_size(w, h));
    bands.check(w, h)?;
    crate::budget::check(
        &format!("a banded {method} bake of {w}x{h}"),
        estimate_peak_bytes(w, h, options, color, map.source_bytes(), bands),
        options.memory_limit,
    )?;
    let mut bake = description(map, method, options);
    bake.format = format;
    for t in 0..bake.textures.len() {
        crate::pack::check(&bake, t, format)?;
    }
    let mut manifest = crate::container::manifest(&bake, input, container, codec);
    manifest.content_hash = content_hash;
    let json = serde_json::to_string_pretty(&manifest).map_err(|e| Error::Write {
        path: dir.to_path_buf(),
        message: e.to_string(),
    })?;
    crate::output::write_folder(dir, |staging| {
        // Errors name the final files, not their staging copies.
        let fill = |staging: &Path| {
            fill_staging(
                staging, dir, map, method, options, format, container, codec, bands, &bake,
                &manifest, json, progress,
            )
        };
        fill(staging).map_err(|e| match e {
            Error::Write { path, message } => Error::Write {
                path: path
                    .strip_prefix(staging)
                    .map_or(path.clone(), |rest| dir.join(rest)),
                message,
            },
            other => other,
        })
    })?;
    Ok(dir.join(MANIFEST))
}

/// [`write_folder`]'s work inside the staging folder.
#[allow(clippy::too_many_arguments)]
fn fill_staging(
    staging: &Path,
    dir: &Path,
    map: &Map,
    method: Method,
    options: &BakeOptions,
    format: Format,
    container: Container,
    codec: Option<Codec>,
    bands: Bands,
    bake: &Bake,
    manifest: &crate::output::Manifest,
    json: String,
    progress: &mut (dyn FnMut(f32) -> bool + Send),
) -> Result<()> {
    {
        // The exr container spills to f32 KTX2 files first.
        let spill = container == Container::Exr;
        let mut layout = bake.clone();
        if spill {
            layout.format = Format::F32;
        }
        let paths: Vec<PathBuf> = manifest
            .textures
            .iter()
            .map(|t| {
                if spill {
                    staging.join(format!(".{}.spill", t.name))
                } else {
                    staging.join(&t.files[0])
                }
            })
            .collect();
        let files = paths
            .iter()
            .enumerate()
            .map(|(t, p)| {
                StreamedFile::create_blocks(
                    p,
                    &layout,
                    t,
                    if spill { Container::Ktx2 } else { container },
                    codec,
                )
            })
            .collect::<Result<Vec<_>>>()?;
        let mut sink = FileSink {
            files,
            ranges: bake.textures.iter().map(|t| t.ranges).collect(),
            names: bake.textures.iter().map(|t| t.name).collect(),
            format,
            sizes: bake.sizes.clone(),
            pending: vec![vec![(0, Vec::new()); bake.sizes.len()]; bake.textures.len()],
        };
        crate::bake::run_with_progress(progress, |progress| {
            progress.report(0.0)?;
            run(map, method, options, bands, &mut sink, progress)?;
            sink.finish()?;
            progress.report(1.0)
        })?;
        if spill {
            let levels = &bake.sizes;
            let results: Vec<Result<()>> = (0..bake.textures.len())
                .into_par_iter()
                .map(|t| {
                    for (k, &(lw, lh)) in levels.iter().enumerate() {
                        let texels = sink.files[t].read_rows(k, 0, lh)?;
                        let name = &manifest.textures[t].files[k];
                        crate::output::write_level(
                            &staging.join(name),
                            lw,
                            lh,
                            &texels,
                            bake.textures[t].ranges,
                            format,
                        )?;
                    }
                    std::fs::remove_file(&paths[t]).map_err(|e| Error::Write {
                        path: paths[t].clone(),
                        message: e.to_string(),
                    })
                })
                .collect();
            results.into_iter().collect::<Result<()>>()?;
        }
        std::fs::write(staging.join(MANIFEST), json + "\n").map_err(|e| Error::Write {
            path: dir.join(MANIFEST),
            message: e.to_string(),
        })
    }
}
