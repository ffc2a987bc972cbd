//! The one place every method is dispatched: bake a [`NormalMap`] with any [`Method`], and the
//! texture layout each method produces. Above the methods ([`crate::baseline`], [`crate::sh`],
//! [`crate::mixture`]), below the consumers (CLI, C API, eval, report).

use crate::bake::{Bake, BakeOptions, Method, Progress};
use crate::error::Result;
use crate::format::ValueRange;
use crate::ingest::NormalMap;

/// The value ranges of each texture a bake of `method` has, in texture order — what a shader
/// needs to decode unsigned-normalized storage without a bake at hand: the baseline's textures,
/// SH's textures for band limit `lobes_or_lmax`, or `lobes_or_lmax` lobe textures followed,
/// with `color`, by as many colour textures (`α·y`, unit).
pub fn texture_ranges(method: Method, lobes_or_lmax: usize, color: bool) -> Vec<[ValueRange; 4]> {
    use crate::mixture::{Model, TanModel, VmfModel};
    let lobes = lobes_or_lmax;
    let lobe = match method {
        Method::Vmf => VmfModel::RANGES,
        Method::Tan2005 => TanModel::RANGES,
        Method::Sh => {
            return crate::sh::layout(lobes_or_lmax)
                .into_iter()
                .map(|(_, _, ranges)| ranges)
                .collect();
        }
        _ => {
            return crate::baseline::layout(method)
                .into_iter()
                .map(|(_, _, ranges)| ranges)
                .collect();
        }
    };
    let mut ranges = vec![lobe; lobes];
    if color {
        ranges.extend(std::iter::repeat_n([ValueRange::Unit; 4], lobes));
    }
    ranges
}

/// Bakes `method` for `map` with default options: the full MIP chain down to 1×1.
pub fn bake(map: &NormalMap, method: Method) -> Bake {
    bake_with(map, method, &BakeOptions::default()).expect("default options are valid")
}

/// Bakes `method` for `map` with `options`; fails only on invalid options.
pub fn bake_with(map: &NormalMap, method: Method, options: &BakeOptions) -> Result<Bake> {
    bake_with_progress(map, method, options, &mut |_| true)
}

/// Bakes like [`bake_with`], reporting progress to `progress` and letting it cancel.
///
/// `progress` is called on the calling thread (between parallel chunks of work, never from a
/// worker) with the fraction done: first 0.0, then non-decreasing values at least every 0.1 %
/// of the work's progress (per MIP level for the baselines, per chunk of texels or wavefront
/// for the mixtures), last 1.0. Returning `false` stops the bake with [`Error::Cancelled`];
/// the result does not depend on the callback otherwise (same bits as [`bake_with`]).
pub fn bake_with_progress(
    map: &NormalMap,
    method: Method,
    options: &BakeOptions,
    progress: &mut dyn FnMut(f32) -> bool,
) -> Result<Bake> {
    let mut progress = Progress::new(progress);
    progress.report(0.0)?;
    let bake = match method {
        Method::Vmf => crate::mixture::bake_vmf(map, options, &mut progress),
        Method::Tan2005 => crate::mixture::bake_tan2005(map, options, &mut progress),
        Method::Sh => crate::sh::bake(map, options.lmax, &mut progress),
        _ => crate::baseline::bake(map, method, &mut progress),
    }?;
    progress.report(1.0)?;
    Ok(bake)
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
            assert!(seen.len() >= 3, "{method}: {seen:?}");
            assert!(seen.windows(2).all(|p| p[0] < p[1]), "{method}: {seen:?}");
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
