//! The one place every method is dispatched: bake a [`NormalMap`] with any [`Method`], and the
//! texture layout each method produces. Above the methods ([`crate::baseline`], [`crate::sh`],
//! [`crate::mixture`]), below the consumers (CLI, C API, eval, report).

use crate::bake::{Bake, BakeOptions, Method, run_with_progress};
use crate::error::{Error, Result};
use crate::format::{Format, ValueRange};
use crate::ingest::NormalMap;

/// The names, channel meanings and value ranges of each texture a bake of `method` has, in
/// texture order, known before baking: the baseline's textures, SH's for band limit
/// `lobes_or_lmax`, for PBR the normal and metallic-roughness textures and, with `color`, the
/// anisotropy texture; for the mixtures `lobes_or_lmax` lobe textures followed, with `color`,
/// by as many colour textures (`α·y`, unit).
pub fn texture_layout(
    method: Method,
    lobes_or_lmax: usize,
    color: bool,
) -> Vec<(String, [&'static str; 4], [ValueRange; 4])> {
    use crate::mixture::{Model, TanModel, VmfModel};
    let owned = |l: Vec<(&'static str, [&'static str; 4], [ValueRange; 4])>| {
        l.into_iter()
            .map(|(n, c, r)| (n.to_string(), c, r))
            .collect()
    };
    let (names, channels, ranges) = match method {
        Method::Vmf => (VmfModel::NAMES, VmfModel::CHANNELS, VmfModel::RANGES),
        Method::Tan2005 => (TanModel::NAMES, TanModel::CHANNELS, TanModel::RANGES),
        Method::Pbr => return owned(crate::pbr::layout(color)),
        Method::Sh => return owned(crate::sh::layout(lobes_or_lmax)),
        _ => return owned(crate::baseline::layout(method)),
    };
    let lobes = lobes_or_lmax.min(names.len());
    let mut out: Vec<_> = names[..lobes]
        .iter()
        .map(|n| (n.to_string(), channels, ranges))
        .collect();
    if color {
        out.extend((0..lobes).map(|j| {
            (
                format!("color{j}"),
                ["alpha*y_r", "alpha*y_g", "alpha*y_b", "alpha*y_a"],
                [ValueRange::Unit; 4],
            )
        }));
    }
    out
}

/// The value ranges of each texture a bake of `method` has, in texture order — what a shader
/// needs to decode unsigned-normalized storage without a bake at hand ([`texture_layout`]).
pub fn texture_ranges(method: Method, lobes_or_lmax: usize, color: bool) -> Vec<[ValueRange; 4]> {
    texture_layout(method, lobes_or_lmax, color)
        .into_iter()
        .map(|(_, _, ranges)| ranges)
        .collect()
}

/// Checks `options` for a bake of `method`, and that `format` (the storage format the bake will
/// be written or packed in, if known) can hold every texture it makes, before any work:
/// [`Error::InvalidOption`] naming the option and its range. The baselines have no options but
/// the memory budget.
pub fn check_options(
    method: Method,
    options: &BakeOptions,
    color: bool,
    format: Option<Format>,
) -> Result<()> {
    if matches!(method, Method::Vmf | Method::Tan2005) {
        crate::mixture::check(options)?;
    }
    if method == Method::Sh {
        crate::sh::check(options.lmax)?;
    }
    if method == Method::Pbr {
        crate::pbr::check_options(&options.pbr)?;
    }
    if let Some(f) = format {
        let lobes = match method {
            Method::Vmf | Method::Tan2005 => options.lobes,
            Method::Sh => options.lmax,
            _ => 0,
        };
        let color = color || (method == Method::Pbr && options.pbr.anisotropic);
        crate::pack::check_ranges(method, &texture_ranges(method, lobes, color), f)?;
    }
    if options.memory_limit == Some(0) {
        return Err(Error::InvalidOption(
            "memory budget 0 (expected a number of bytes, or none for the default)".into(),
        ));
    }
    Ok(())
}

/// Peak memory of a bake, in bytes per texel of the finest level: `base + per_lobe × J`, and
/// with a feature (colour) image `color_base + color_per_lobe × J` more (the baselines have
/// no lobes and no colour). Calibrated on the peak resident memory of the whole `ndfmap bake`
/// command (`/usr/bin/time -f %M`: decoding the PNG, the bake, quantizing and writing the files)
/// on the built-in sample at 512², 1024² and 2048², whose peaks per texel are nearly the same
/// at every size, then rounded up so that the estimate lies above every measured peak (by how
/// much is stated per method).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PeakPerTexel {
    /// Bytes per texel whatever the lobe count.
    pub base: u64,
    /// Bytes per texel per lobe.
    pub per_lobe: u64,
    /// Bytes per texel added by a feature image.
    pub color_base: u64,
    /// Bytes per texel per lobe added by a feature image.
    pub color_per_lobe: u64,
}

impl PeakPerTexel {
    /// Bytes per texel for `lobes` lobes, with or without colour.
    pub fn bytes(&self, lobes: u64, color: bool) -> u64 {
        let own = self.base + self.per_lobe * lobes;
        let color = if color {
            self.color_base + self.color_per_lobe * lobes
        } else {
            0
        };
        own + color
    }
}

/// The in-memory vMF bake's peak memory per texel (every mode: unaligned or aligned, exact or
/// fast, any storage format). `ndfmap bake` (module `batch`) bakes vMF and Tan 2005 (block
/// compressed or not, since stop 57) in bands instead, estimated by `banded::estimate_peak_bytes` (1024² J = 6
/// aligned colour: 153 MiB instead of the 380 below; docs/scale.md).
///
/// Calibrated at stop 56 (docs/scale.md, "Stop 56") on the aligned bake, whose aligned pass
/// holds every level's unaligned fits and so peaks highest: the decoded PNG, `bake_with`,
/// `pack::quantize_into` and the KTX2 writer, each in a process of its own, with every
/// texture page made resident (what a host whose allocator reuses freed memory sees; a fresh
/// process leaves the dead lobes' zero pages unmapped and peaks lower). Measured on the
/// built-in sample against the estimate ([`estimate_peak_bytes`]), MiB (rock and mossyrock at
/// 1024² peak within 1 MiB of the sample):
///
/// | map | configuration | measured | estimate |
/// |---|---|---|---|
/// | 1024² | J = 1, aligned / unaligned | 50 / 63 | 126 |
/// | 1024² | J = 8, aligned / unaligned | 236 / 182 | 336 |
/// | 1024² | J = 8, aligned / unaligned, colour | 427 / 357 | 552 |
/// | 2048² | J = 1, aligned, no colour / colour | 187 / 351 | 312 / 504 |
/// | 2048² | J = 6, aligned, no colour / colour | 712 / 1305 | 912 / 1584 |
/// | 2048² | J = 8, aligned / unaligned | 922 / 719 | 1152 |
/// | 2048² | J = 8, aligned / unaligned, colour | 1685 / 1399 | 2016 |
///
/// The estimate lies 20–28 % above the aligned peaks at 2048² with J ≥ 6 (44–67 % at J = 1,
/// and more at smaller sizes, where the fixed 64 MiB dominates). The constants before (36 + 20 J, colour 36 J) lay 3–8 % *below*
/// the aligned bakes without colour at 2048² (712 and 922 MiB against 688 and 848) and far
/// above the colour ones. Update them when the vMF bake's memory changes (`ndfmap bench`
/// prints the measured peak and this estimate side by side).
pub const VMF_PEAK_PER_TEXEL: PeakPerTexel = PeakPerTexel {
    base: 32,
    per_lobe: 30,
    color_base: 24,
    color_per_lobe: 24,
};

/// The Tan 2005 bake's peak memory per texel. Measured at 1024² against the estimate, MiB:
/// J = 8 aligned 254 (480; 393 before issue 14's EM memory reductions); J = 4 unaligned with
/// colour 340 (448; not re-measured). Kept conservative.
pub const TAN2005_PEAK_PER_TEXEL: PeakPerTexel = PeakPerTexel {
    base: 64,
    per_lobe: 44,
    color_base: 48,
    color_per_lobe: 24,
};

/// The baselines' peak memory per texel per moment they average (plain and Toksvig 3, LEAN
/// 5, Olano–North 9), plus [`BASELINE_PEAK_BASE`]. Measured against the estimate, MiB: plain
/// 1024² 86 (152), 2048² 320 (416); Olano–North 1024² 214 (296), 2048² 831 (992).
pub const BASELINE_PEAK_PER_MOMENT: u64 = 24;

/// The baselines' peak memory per texel whatever their moments.
pub const BASELINE_PEAK_BASE: u64 = 16;

/// The SH bake's peak memory per texel whatever its band limit (the decoded map, the
/// program): `SH_PEAK_BASE + SH_PEAK_PER_BATCH_COEFFICIENT × min(c, 32) +
/// SH_PEAK_PER_COEFFICIENT × c` for `c` coefficients rounded up to whole RGBA textures.
/// Measured peaks of `ndfmap bake rock.jpg -m sh` (1024², `/usr/bin/time -f %M`) against the
/// estimate, MiB: l* = 0 82 (168), 2 202 (344), 4 452 (696), 8 767 (1096), 16 1879 (2344).
/// (Before the bake stopped forming the f64 finest image and its level-0 copy: 101, 261, 581,
/// 836, 2043; the estimate was kept.)
pub const SH_PEAK_BASE: u64 = 80;

/// The SH bake's peak memory per texel per coefficient of a batch (at most 32 are computed
/// at once): the f64 x-reduced rows of every coarser level (8 bytes), level 1's y pass
/// (2 bytes) and slack.
pub const SH_PEAK_PER_BATCH_COEFFICIENT: u64 = 16;

/// The SH bake's peak memory per texel per coefficient: the f32 MIP chain (4 × 4/3 bytes)
/// and the writer's slack.
pub const SH_PEAK_PER_COEFFICIENT: u64 = 6;

/// The PBR bake's peak memory per texel whatever its pairs: the decoded map, the material
/// (24), the per-level statistics (12 f64 over the levels, 4/3 × 96), one batch of per-normal
/// values (8 f64) and the lobes. Measured peaks, rock 1024² (`ndfmap bake -m pbr`,
/// `/usr/bin/time -f %M`): 752 MB with the earlier 39-pair set (estimate 893 MB), 981 MB with
/// the 56-pair set (estimate 1107 MB) while every level's targets were kept; 652 MB
/// (`--anisotropic` 705 MB) with the standard 112-pair set and level 0's targets left out
/// (estimate 872 MB).
pub const PBR_PEAK_BASE: u64 = 320;

/// The PBR bake's peak memory per texel (of the finest level) per fit pair: the exact targets
/// of levels 1 and coarser (f64, 1/3 of the finest level's texels: 2.7 bytes), plus slack.
pub const PBR_PEAK_PER_PAIR: u64 = 4;

/// Memory every bake command needs whatever the map's size (the program, its threads, the
/// allocator's slack): 64 MiB.
pub const PEAK_FIXED_BYTES: u64 = 64 << 20;

/// Estimates the peak memory, in bytes, of baking a `width`×`height` map with `method` and
/// `options` (with a feature image when `color`), including the decoded map and writing the
/// result: [`PEAK_FIXED_BYTES`] plus the method's bytes per texel ([`VMF_PEAK_PER_TEXEL`],
/// [`TAN2005_PEAK_PER_TEXEL`], the baselines' per moment) times `width × height`. Conservative:
/// the calibration's measured peaks lie 15–25 % below it (more for small maps).
pub fn estimate_peak_bytes(
    width: u32,
    height: u32,
    method: Method,
    options: &BakeOptions,
    color: bool,
) -> u64 {
    let lobes = options.lobes as u64;
    let per_texel = match method {
        Method::Vmf => VMF_PEAK_PER_TEXEL.bytes(lobes, color),
        Method::Tan2005 => TAN2005_PEAK_PER_TEXEL.bytes(lobes, color),
        Method::Pbr => {
            // The options' pair set (checked before the estimate; the standard set otherwise).
            let pairs = crate::pbr::fit_set(&options.pbr)
                .map_or(crate::pbr::standard_pairs().len(), |s| s.pairs.len());
            PBR_PEAK_BASE + PBR_PEAK_PER_PAIR * pairs as u64
        }
        Method::Sh => {
            let coefficients = crate::harmonics::count(options.lmax).next_multiple_of(4) as u64;
            SH_PEAK_BASE
                + SH_PEAK_PER_BATCH_COEFFICIENT * coefficients.min(32)
                + SH_PEAK_PER_COEFFICIENT * coefficients
        }
        _ => {
            BASELINE_PEAK_BASE
                + BASELINE_PEAK_PER_MOMENT * crate::baseline::moment_count(method) as u64
        }
    };
    let texels = width as u64 * height as u64;
    PEAK_FIXED_BYTES.saturating_add(texels.saturating_mul(per_texel))
}

/// Refuses a bake whose estimated peak ([`estimate_peak_bytes`]) exceeds the budget of
/// `options` ([`Error::MemoryBudget`], naming the method, the size and the budget).
pub fn check_memory(
    width: u32,
    height: u32,
    method: Method,
    options: &BakeOptions,
    color: bool,
) -> Result<()> {
    crate::budget::check(
        &format!("a {method} bake of {width}x{height}"),
        estimate_peak_bytes(width, height, method, options, color),
        options.memory_limit,
    )
}

/// Bakes `method` for `map` with default options: the full MIP chain down to 1×1.
pub fn bake(map: &NormalMap, method: Method) -> Bake {
    bake_with(map, method, &BakeOptions::default()).expect("default options are valid")
}

/// Bakes `method` for `map` with `options`; fails only on invalid options or a bake beyond the
/// memory budget.
pub fn bake_with(map: &NormalMap, method: Method, options: &BakeOptions) -> Result<Bake> {
    bake_with_progress(map, method, options, &mut |_| true)
}

/// Bakes like [`bake_with`], reporting progress to `progress` and letting it cancel.
///
/// Options and the memory budget are checked first ([`check_options`], [`check_memory`]),
/// before any work and before `progress` is called.
///
/// `progress` is called on the calling thread, never from a worker, with the fraction done:
/// first 0.0, then non-decreasing values at least every 0.1 % of the work's progress (per MIP
/// level for the baselines, per chunk of texels or wavefront for the mixtures) and, while the
/// work runs, the last value again at least every [`crate::bake::PROGRESS_POLL`] (50 ms), last
/// 1.0. Returning `false` stops the bake with [`Error::Cancelled`] within a fraction of a
/// second (workers stop between texels); the callback is not called again. The result does
/// not depend on the callback otherwise (same bits as [`bake_with`]).
///
/// Called from a thread of a rayon pool, the bake runs on that thread and `progress` is called
/// only between chunks of work (see `bake::run_with_progress`).
pub fn bake_with_progress(
    map: &NormalMap,
    method: Method,
    options: &BakeOptions,
    progress: &mut dyn FnMut(f32) -> bool,
) -> Result<Bake> {
    let color = map.feature().is_some();
    check_options(method, options, color, None)?;
    check_memory(map.width(), map.height(), method, options, color)?;
    run_with_progress(progress, |progress| {
        progress.report(0.0)?;
        let bake = match method {
            Method::Vmf => crate::mixture::bake_vmf(map, options, progress),
            Method::Tan2005 => crate::mixture::bake_tan2005(map, options, progress),
            Method::Sh => crate::sh::bake(map, options.lmax, progress),
            Method::Pbr => crate::pbr::bake(map, &options.pbr, None, progress),
            _ => crate::baseline::bake(map, method, progress),
        }?;
        progress.report(1.0)?;
        Ok(bake)
    })
}

/// [`bake_with_progress`] for [`Method::Pbr`] with per-texel material `maps` (checked
/// against the map first, `pbr::PbrMaps::check`): the C API's `ndf_bake_pbr`.
pub fn bake_pbr_with_progress(
    map: &NormalMap,
    options: &BakeOptions,
    maps: &crate::pbr::PbrMaps,
    progress: &mut dyn FnMut(f32) -> bool,
) -> Result<Bake> {
    check_options(Method::Pbr, options, false, None)?;
    maps.check(map.width(), map.height())?;
    check_memory(map.width(), map.height(), Method::Pbr, options, false)?;
    let none = crate::pbr::PbrMaps::default();
    let maps = (maps != &none).then_some(maps);
    run_with_progress(progress, |progress| {
        progress.report(0.0)?;
        let bake = crate::pbr::bake(map, &options.pbr, maps, progress)?;
        progress.report(1.0)?;
        Ok(bake)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::Error;

    /// The built-in sample of side `size` (at least 8).
    fn bumpy(size: u32) -> NormalMap {
        crate::procedural::generate(size, 3).map
    }

    fn cases() -> Vec<(Method, BakeOptions)> {
        let lobes = |n, align| BakeOptions {
            lobes: n,
            align,
            ..BakeOptions::default()
        };
        vec![
            (Method::Plain, BakeOptions::default()),
            (Method::Olano, BakeOptions::default()),
            (Method::Vmf, lobes(2, None)),
            (Method::Vmf, lobes(2, Some(0.1))),
            (Method::Tan2005, lobes(2, Some(1.0))),
        ]
    }

    /// The peaks measured for the calibration (MiB, `VMF_PEAK_PER_TEXEL`'s table and the
    /// others): the estimate must stay above each, by at least 10 %.
    #[test]
    fn estimates_stay_above_the_measured_peaks() {
        let o = |lobes, align| BakeOptions {
            lobes,
            align,
            ..BakeOptions::default()
        };
        let sh = |lmax| BakeOptions {
            lmax,
            ..BakeOptions::default()
        };
        let measured: [(u32, Method, BakeOptions, bool, u64); 25] = [
            // Stop 56, every texture page resident (docs/scale.md).
            (1024, Method::Vmf, o(8, Some(0.03)), false, 236),
            (1024, Method::Vmf, o(8, Some(0.03)), true, 427),
            (2048, Method::Vmf, o(6, Some(0.03)), false, 712),
            (2048, Method::Vmf, o(8, Some(0.03)), false, 922),
            (2048, Method::Vmf, o(8, Some(0.03)), true, 1685),
            (2048, Method::Vmf, o(1, Some(0.03)), true, 351),
            // Earlier calibrations (the whole `ndfmap bake` command).
            (1024, Method::Vmf, o(1, Some(1.0)), true, 110),
            (1024, Method::Vmf, o(6, None), false, 184),
            (1024, Method::Vmf, o(6, None), true, 325),
            (1024, Method::Vmf, o(6, Some(1.0)), true, 356),
            (1024, Method::Vmf, o(8, Some(1.0)), true, 453),
            (512, Method::Vmf, o(8, Some(1.0)), true, 140),
            (2048, Method::Vmf, o(6, None), false, 603),
            (2048, Method::Vmf, o(6, Some(1.0)), true, 1300),
            (1024, Method::Tan2005, o(8, Some(1.0)), false, 393),
            (1024, Method::Tan2005, o(4, None), true, 340),
            (1024, Method::Plain, o(6, None), false, 86),
            (2048, Method::Plain, o(6, None), false, 320),
            (1024, Method::Olano, o(6, None), false, 214),
            (2048, Method::Olano, o(6, None), false, 831),
            (1024, Method::Sh, sh(0), false, 82),
            (1024, Method::Sh, sh(2), false, 202),
            (1024, Method::Sh, sh(4), false, 452),
            (1024, Method::Sh, sh(8), false, 767),
            (1024, Method::Sh, sh(16), false, 1879),
        ];
        for (size, method, options, color, mib) in measured {
            let estimate = estimate_peak_bytes(size, size, method, &options, color);
            assert!(
                estimate as f64 >= 1.1 * (mib << 20) as f64,
                "{method} {size}² J={}: {} MiB estimated, {mib} MiB measured",
                options.lobes,
                estimate >> 20
            );
        }
        // More texels, lobes or colour never need less.
        let base = estimate_peak_bytes(512, 512, Method::Vmf, &o(6, None), false);
        assert!(estimate_peak_bytes(1024, 512, Method::Vmf, &o(6, None), false) > base);
        assert!(estimate_peak_bytes(512, 512, Method::Vmf, &o(7, None), false) > base);
        assert!(estimate_peak_bytes(512, 512, Method::Vmf, &o(6, None), true) > base);
        // The largest map (2^28 texels) with the most lobes: hundreds of GiB, no overflow.
        let huge = estimate_peak_bytes(65536, 4096, Method::Vmf, &o(8, None), true);
        assert!(huge > 100 << 30);
    }

    #[test]
    fn progress_rises_from_zero_to_one_and_leaves_the_bake_unchanged() {
        // 512²: level 1 has four chunks of PROGRESS_CHUNK texels.
        for (map, (method, options)) in [(bumpy(512), (Method::Vmf, cases()[2].1))]
            .into_iter()
            .chain(cases().into_iter().map(|c| (bumpy(9), c)))
        {
            let mut seen = Vec::new();
            let with = bake_with_progress(&map, method, &options, &mut |f| {
                seen.push(f);
                true
            })
            .unwrap();
            assert_eq!(with, bake_with(&map, method, &options).unwrap(), "{method}");
            assert_eq!(seen.first(), Some(&0.0), "{method}: {seen:?}");
            assert_eq!(seen.last(), Some(&1.0), "{method}: {seen:?}");
            // Non-decreasing: while a piece of work runs, the last value comes again.
            assert!(seen.windows(2).all(|p| p[0] <= p[1]), "{method}: {seen:?}");
            let mut distinct = seen.clone();
            distinct.dedup();
            assert!(distinct.len() >= 3, "{method}: {seen:?}");
        }
    }

    #[test]
    fn a_callback_that_says_stop_cancels_the_bake() {
        let map = bumpy(9);
        for (method, options) in cases() {
            for stop_at in [0, 1, 2] {
                let mut calls = 0;
                let r = bake_with_progress(&map, method, &options, &mut |_| {
                    calls += 1;
                    calls <= stop_at
                });
                assert!(
                    matches!(r, Err(Error::Cancelled)),
                    "{method} stop at {stop_at}"
                );
                assert_eq!(calls, stop_at + 1, "{method}: no call after the stop");
            }
        }
    }
}
