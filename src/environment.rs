//! Environment lighting input (issue 16; Han et al. 2007 Sec 8): an equirectangular panorama of
//! linear radiance, read from Radiance `.hdr` or OpenEXR or generated (a sky gradient, a ground
//! colour and a small, very bright sun disc), with yaw and intensity options and a documented
//! policy for bad texels.
//!
//! **Frame.** Directions are in the environment's own frame, +Z up: `θ` is the angle from the
//! zenith, `φ = atan2(y, x)`. Row 0 is the zenith, column 0 is azimuth −π (the usual lat-long
//! layout of the shared panoramas, with their +Y-up world mapped to +Z). Texel `(x, y)` covers
//! `φ ∈ [−π + 2πx/W, −π + 2π(x+1)/W]`, `θ ∈ [πy/H, π(y+1)/H]`; its solid angle is exactly
//! `(2π/W)(cos θ₀ − cos θ₁)` ([`Radiance::solid_angle`]). Texel-space evaluation puts the
//! surface's tangent frame on this frame (the macro normal at the zenith); a renderer rotates
//! directions into it.
//!
//! **Radiance is piecewise constant over texels** for everything exact in the crate (the ground
//! truth's importance sampling, the SH projection): a texel's value is its radiance over its
//! whole solid angle.
//!
//! **Bad input** (module docs of [`load`]): not 2:1, empty or oversized → [`Error::Dimensions`];
//! undecodable or truncated → [`Error::Decode`]; NaN, ±∞ and negative texels are repaired to 0
//! and counted in [`Environment::repaired`] ([`BadTexels::Repair`], the default) or refused
//! ([`BadTexels::Reject`], [`Error::BadEnvironment`]); an all-black environment is valid and
//! lights everything with exactly 0; a single bright texel is valid.
//!
//! Submodules: [`sampling`] (the 2D CDF for importance sampling), [`prefilter`] (the
//! lobe-prefiltered levels), [`projection`] (SH projection, rotation and the `L′` table),
//! [`lights`] (bright compact sources taken out as analytic lights).
//!
//! Main types: [`Environment`] (RGB), [`Radiance`] (one channel, what the lighting code reads).

pub mod lights;
pub mod prefilter;
pub mod projection;
pub mod sampling;

use crate::error::{Error, Result};
use glam::DVec3;
use std::f64::consts::PI;
use std::path::Path;

/// Largest environment width accepted (texels); the height is half of it.
pub const MAX_WIDTH: u32 = 16_384;

/// Rec. 709 luminance weights of linear R, G, B (they sum to 1): [`Environment::luminance`] and
/// the luminance of RGB shading (`envlight::RgbShading::luminance`).
pub const LUMINANCE: [f64; 3] = [0.2126, 0.7152, 0.0722];

/// What to do with NaN, infinite and negative texels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BadTexels {
    /// Set them to 0 and count them ([`Environment::repaired`]).
    #[default]
    Repair,
    /// Refuse the environment ([`Error::BadEnvironment`]).
    Reject,
}

/// How an environment is read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnvOptions {
    /// Rotation about the zenith in degrees (positive: counter-clockwise seen from above, so the
    /// radiance that was at azimuth φ is at φ + yaw). Default 0.
    pub yaw_deg: f64,
    /// Radiance multiplier, finite and ≥ 0. Default 1.
    pub intensity: f64,
    /// Bad texel policy. Default [`BadTexels::Repair`].
    pub bad_texels: BadTexels,
}

impl Default for EnvOptions {
    fn default() -> Self {
        EnvOptions {
            yaw_deg: 0.0,
            intensity: 1.0,
            bad_texels: BadTexels::Repair,
        }
    }
}

/// An equirectangular RGB environment of linear radiance (module docs for the frame).
#[derive(Debug, Clone, PartialEq)]
pub struct Environment {
    width: u32,
    height: u32,
    texels: Vec<[f32; 3]>,
    repaired: usize,
}

impl Environment {
    /// An environment from RGB texels, row-major from the zenith row (`width = 2·height`),
    /// with `options` applied (bad texels, intensity, yaw). `what` names the source in errors.
    pub fn from_rgb(
        what: &str,
        width: u32,
        height: u32,
        mut texels: Vec<[f32; 3]>,
        options: &EnvOptions,
    ) -> Result<Environment> {
        check_size(what, width, height)?;
        if texels.len() != width as usize * height as usize {
            return Err(Error::ShortBuffer {
                what: what.to_string(),
                got: texels.len() * 3,
                needed: width as usize * height as usize * 3,
            });
        }
        if !(options.intensity.is_finite() && options.intensity >= 0.0) {
            return Err(Error::InvalidOption(format!(
                "environment intensity {} (must be finite and >= 0)",
                crate::error::compact_f64(options.intensity)
            )));
        }
        if !options.yaw_deg.is_finite() {
            return Err(Error::InvalidOption(format!(
                "environment yaw {} (must be finite)",
                options.yaw_deg
            )));
        }
        let mut repaired = 0usize;
        let mut first = None;
        for (i, t) in texels.iter_mut().enumerate() {
            if t.iter().any(|v| !v.is_finite() || *v < 0.0) {
                repaired += 1;
                first.get_or_insert(i);
                for v in t.iter_mut() {
                    if !v.is_finite() || *v < 0.0 {
                        *v = 0.0;
                    }
                }
            }
        }
        if repaired > 0 && options.bad_texels == BadTexels::Reject {
            let i = first.unwrap_or(0);
            return Err(Error::BadEnvironment {
                what: what.to_string(),
                count: repaired,
                x: (i % width as usize) as u32,
                y: (i / width as usize) as u32,
            });
        }
        let k = options.intensity as f32;
        if k != 1.0 {
            for t in texels.iter_mut() {
                for v in t.iter_mut() {
                    // An intensity that overflows f32 saturates at the largest finite value.
                    *v = (*v * k).min(f32::MAX);
                }
            }
        }
        let mut env = Environment {
            width,
            height,
            texels,
            repaired,
        };
        if options.yaw_deg.rem_euclid(360.0) != 0.0 {
            env = env.rotated(options.yaw_deg);
        }
        Ok(env)
    }

    /// Width in texels (twice the height).
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in texels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The RGB texels, row-major from the zenith row.
    pub fn texels(&self) -> &[[f32; 3]] {
        &self.texels
    }

    /// How many texels had NaN, infinite or negative values and were set to 0.
    pub fn repaired(&self) -> usize {
        self.repaired
    }

    /// One channel (0 = R, 1 = G, 2 = B) as a [`Radiance`].
    pub fn channel(&self, c: usize) -> Radiance {
        Radiance {
            width: self.width,
            height: self.height,
            values: self.texels.iter().map(|t| t[c.min(2)]).collect(),
        }
    }

    /// Rec. 709 luminance `0.2126 R + 0.7152 G + 0.0722 B` ([`LUMINANCE`]) as a [`Radiance`]:
    /// what the ground truth of `eval` and `report` integrates (their errors are of one scalar,
    /// the luminance of the RGB shading).
    pub fn luminance(&self) -> Radiance {
        Radiance {
            width: self.width,
            height: self.height,
            values: self
                .texels
                .iter()
                .map(|t| (0..3).map(|c| LUMINANCE[c] * t[c] as f64).sum::<f64>() as f32)
                .collect(),
        }
    }

    /// The environment rotated by `yaw_deg` about the zenith: each row resampled at
    /// `φ − yaw` with linear interpolation (wrapping), so a whole number of texels is an exact
    /// shift and every row keeps its mean radiance.
    pub fn rotated(&self, yaw_deg: f64) -> Environment {
        let w = self.width as usize;
        let shift = yaw_deg.rem_euclid(360.0) / 360.0 * w as f64;
        let (i0, frac) = (shift.floor() as usize, shift - shift.floor());
        let mut out = self.texels.clone();
        for (row_in, row_out) in self.texels.chunks_exact(w).zip(out.chunks_exact_mut(w)) {
            for (x, o) in row_out.iter_mut().enumerate() {
                // Output x takes the input at x − shift.
                let a = row_in[(x + 2 * w - i0) % w];
                let b = row_in[(x + 2 * w - i0 - 1) % w];
                for c in 0..3 {
                    o[c] = ((1.0 - frac) * a[c] as f64 + frac * b[c] as f64) as f32;
                }
            }
        }
        Environment {
            width: self.width,
            height: self.height,
            texels: out,
            repaired: self.repaired,
        }
    }
}

/// The tests' coloured sky: [`Sky`] at 64 × 32 with an orange sun (3·10⁴, 1.5·10⁴, 0.5·10⁴)
/// over its blue sky, so that a swapped or collapsed colour channel shows.
#[cfg(test)]
pub(crate) fn coloured_test_sky() -> Environment {
    Sky {
        width: 64,
        sun: [3.0e4, 1.5e4, 0.5e4],
        ..Sky::default()
    }
    .render()
    .unwrap()
}

/// The azimuth `φ = atan2(y, x)` of `d`, taken as 0 at the poles (`x = y = 0`, either sign of
/// zero), as the shaders' `ndf_env_azimuth` does (GLSL leaves `atan(0, 0)` undefined; a flat
/// texel seen head on looks the environment up exactly there).
pub(crate) fn azimuth(d: DVec3) -> f64 {
    if d.x == 0.0 && d.y == 0.0 {
        0.0
    } else {
        d.y.atan2(d.x)
    }
}

/// Refuses an environment size that is empty, not 2:1 or wider than [`MAX_WIDTH`] (`what`
/// names the input in the error).
pub(crate) fn check_size(what: &str, width: u32, height: u32) -> Result<()> {
    let bad = |reason: &str| {
        Err(Error::Dimensions {
            what: what.to_string(),
            width: width as u64,
            height: height as u64,
            reason: reason.to_string(),
        })
    };
    if width == 0 || height == 0 {
        return bad("empty");
    }
    if width != 2 * height {
        return bad("an equirectangular environment must be 2:1 (width = 2 × height)");
    }
    if width > MAX_WIDTH {
        return bad(&format!("wider than {MAX_WIDTH} texels"));
    }
    Ok(())
}

/// Reads an environment from a file: Radiance `.hdr` (RGBE) or OpenEXR (R, G, B of the first
/// layer; a missing channel reads as 0), chosen by the file's magic bytes, linear radiance,
/// any 2:1 size up to [`MAX_WIDTH`]. Only a regular file is read (a FIFO, a device or a
/// folder is refused without blocking), of at most the default memory budget
/// ([`crate::budget::default_memory_limit`]), as images are. Errors: [`Error::Read`],
/// [`Error::MemoryBudget`], [`Error::Decode`] (corrupt, truncated, neither format),
/// [`Error::Dimensions`], [`Error::BadEnvironment`].
pub fn load(path: &Path, options: &EnvOptions) -> Result<Environment> {
    let bytes = crate::ingest::read_file(path, None)?;
    from_memory(&path.display().to_string(), &bytes, options)
}

/// [`load`] from bytes in memory; `what` names the source in errors.
pub fn from_memory(what: &str, bytes: &[u8], options: &EnvOptions) -> Result<Environment> {
    let decode = |message: String| Error::Decode {
        path: what.into(),
        message,
    };
    let (width, height, texels) = if bytes.starts_with(b"#?") {
        decode_hdr(bytes).map_err(decode)?
    } else if bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        decode_exr(bytes).map_err(decode)?
    } else {
        return Err(decode(
            "not a Radiance .hdr (#?) or OpenEXR file".to_string(),
        ));
    };
    Environment::from_rgb(what, width, height, texels, options)
}

fn decode_hdr(bytes: &[u8]) -> std::result::Result<(u32, u32, Vec<[f32; 3]>), String> {
    use image::ImageDecoder;
    let dec = image::codecs::hdr::HdrDecoder::new(std::io::Cursor::new(bytes))
        .map_err(|e| e.to_string())?;
    let (w, h) = dec.dimensions();
    // Refused before the pixels are allocated.
    check_size("hdr", w, h).map_err(|e| e.to_string())?;
    let mut buf = vec![0u8; dec.total_bytes() as usize];
    dec.read_image(&mut buf).map_err(|e| e.to_string())?;
    let texels = buf
        .chunks_exact(12)
        .map(|c| {
            let f = |i: usize| f32::from_ne_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]);
            [f(0), f(4), f(8)]
        })
        .collect();
    Ok((w, h, texels))
}

fn decode_exr(bytes: &[u8]) -> std::result::Result<(u32, u32, Vec<[f32; 3]>), String> {
    use exr::prelude::*;
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), false)
        .map_err(|e| e.to_string())?;
    let header = meta.headers.first().ok_or("no layer")?;
    let size = header.layer_size;
    check_size("exr", size.0 as u32, size.1 as u32).map_err(|e| e.to_string())?;
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .rgba_channels(
            |res, _| (res.0, vec![[0.0f32; 3]; res.0 * res.1]),
            |(w, px): &mut (usize, Vec<[f32; 3]>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                px[pos.1 * *w + pos.0] = [r, g, b];
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .map_err(|e| e.to_string())?;
    let (w, px) = image.layer_data.channel_data.pixels;
    let h = px.len() / w.max(1);
    Ok((w as u32, h as u32, px))
}

/// The generated environment of the demo and of the tests that must run without the shared
/// panoramas: a sky gradient, a ground colour and a small, very bright sun disc.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sky {
    /// Width in texels (the height is half). Default 256.
    pub width: u32,
    /// Sky radiance at the zenith (RGB). Default (0.25, 0.45, 1.0).
    pub zenith: [f32; 3],
    /// Sky radiance at the horizon (RGB). Default (0.9, 0.95, 1.0).
    pub horizon: [f32; 3],
    /// Ground radiance (RGB, below the horizon). Default (0.18, 0.15, 0.12).
    pub ground: [f32; 3],
    /// Sun direction: angle from the zenith and azimuth, degrees. Default (55, 30).
    pub sun_deg: (f64, f64),
    /// Sun disc angular radius, degrees. Default 0.5.
    pub sun_radius_deg: f64,
    /// Sun radiance (RGB). Default 2·10⁴ (white): about 15 times the sky's irradiance.
    pub sun: [f32; 3],
}

impl Default for Sky {
    fn default() -> Self {
        Sky {
            width: 256,
            zenith: [0.25, 0.45, 1.0],
            horizon: [0.9, 0.95, 1.0],
            ground: [0.18, 0.15, 0.12],
            sun_deg: (55.0, 30.0),
            sun_radius_deg: 0.5,
            sun: [2.0e4; 3],
        }
    }
}

impl Sky {
    /// The sun's direction (unit, environment frame).
    pub fn sun_direction(&self) -> DVec3 {
        let (t, p) = (self.sun_deg.0.to_radians(), self.sun_deg.1.to_radians());
        DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
    }

    /// Renders the sky. Each texel is the mean of the gradient over 4×4 sub-samples; the sun's
    /// coverage of each texel is measured with 16×16 sub-samples and rescaled so that the sun's
    /// total power `Σ L_sun·coverage·Ω_texel` is exactly `L_sun · 2π(1 − cos r)`, however small
    /// the disc is against a texel.
    pub fn render(&self) -> Result<Environment> {
        self.render_with(&EnvOptions::default())
    }

    /// [`Sky::render`] read under `options` (yaw, intensity) as a loaded panorama would be:
    /// what the CLI and the viewer use for `--env sky`.
    pub fn render_with(&self, options: &EnvOptions) -> Result<Environment> {
        let w = self.width.max(2) & !1;
        let h = w / 2;
        check_size("generated sky", w, h)?;
        let sun = self.sun_direction();
        let cos_r = self.sun_radius_deg.to_radians().cos();
        let geo = Radiance::geometry(w, h);
        let mut texels = vec![[0.0f32; 3]; (w * h) as usize];
        let mut coverage = vec![0.0f64; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                let mut c = [0.0f64; 3];
                for sy in 0..4 {
                    for sx in 0..4 {
                        let d = geo.sub_direction(
                            x,
                            y,
                            (sx as f64 + 0.5) / 4.0,
                            (sy as f64 + 0.5) / 4.0,
                        );
                        let g = if d.z >= 0.0 {
                            let t = d.z.sqrt();
                            [0, 1, 2].map(|i| {
                                self.horizon[i] as f64 * (1.0 - t) + self.zenith[i] as f64 * t
                            })
                        } else {
                            self.ground.map(|v| v as f64)
                        };
                        for i in 0..3 {
                            c[i] += g[i] / 16.0;
                        }
                    }
                }
                let i = (y * w + x) as usize;
                texels[i] = c.map(|v| v as f32);
                // Sun coverage: only near the disc.
                if geo.direction(x, y).dot(sun)
                    > (self.sun_radius_deg.to_radians() + 4.0 * PI / h as f64)
                        .min(PI)
                        .cos()
                {
                    let mut n = 0;
                    for sy in 0..16 {
                        for sx in 0..16 {
                            let d = geo.sub_direction(
                                x,
                                y,
                                (sx as f64 + 0.5) / 16.0,
                                (sy as f64 + 0.5) / 16.0,
                            );
                            if d.dot(sun) >= cos_r {
                                n += 1;
                            }
                        }
                    }
                    coverage[i] = n as f64 / 256.0;
                }
            }
        }
        // Energy: Σ coverage·Ω = Ω_sun exactly; a disc smaller than every sub-sample lands in
        // the texel that holds its centre.
        let omega_sun = 2.0 * PI * (1.0 - cos_r);
        let mut covered: f64 = coverage
            .iter()
            .enumerate()
            .map(|(i, c)| c * geo.solid_angle(i as u32 / w))
            .sum();
        if covered <= 0.0 {
            let (x, y) = geo.texel_of(sun);
            let i = (y * w + x) as usize;
            coverage[i] = 1.0;
            covered = geo.solid_angle(y);
        }
        let scale = omega_sun / covered;
        for (t, c) in texels.iter_mut().zip(&coverage) {
            if *c > 0.0 {
                for (v, sun) in t.iter_mut().zip(self.sun) {
                    *v = (*v as f64 * (1.0 - c.min(1.0)) + sun as f64 * c * scale) as f32;
                }
            }
        }
        Environment::from_rgb("generated sky", w, h, texels, options)
    }
}

/// The texel geometry of a `width × height` equirectangular grid (module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Geometry {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
}

/// The fewest rows an integration over a panorama's texels works on ([`Geometry::refinement`]):
/// those of a 64 × 32 panorama, the smallest the SH projection's accuracy is stated for
/// (`projection` module docs; a constant's coefficients of l ≥ 1 are within 5·10⁻³ of 0
/// there, test `small_panoramas_project_like_large_ones`).
pub const FINE_ROWS: u32 = 32;

impl Geometry {
    /// How many times finer per axis an integration over the texels takes them: 1 from
    /// [`FINE_ROWS`] rows on, else enough that a smaller panorama is integrated on the grid of
    /// one with at least [`FINE_ROWS`] rows (each texel split into `m × m` texels equal in φ
    /// and θ, of the same radiance; the split is exact for the piecewise-constant map). A 2 × 1
    /// panorama's one row spans 180°: its centre alone aliases every band (a constant's SH
    /// l = 2 energy came out 0.99 against l = 0's 3.54).
    pub fn refinement(&self) -> u32 {
        FINE_ROWS.div_ceil(self.height.max(1))
    }

    /// This grid with every texel split `m × m` ([`Geometry::refinement`]).
    pub fn refined(&self, m: u32) -> Geometry {
        Geometry {
            width: self.width * m,
            height: self.height * m,
        }
    }

    /// The direction at fractional position `(fx, fy)` ∈ [0, 1]² inside texel `(x, y)`,
    /// uniform in `φ` and in `cos θ` (so uniform in solid angle).
    pub fn sub_direction(&self, x: u32, y: u32, fx: f64, fy: f64) -> DVec3 {
        let phi = -PI + 2.0 * PI * (x as f64 + fx) / self.width as f64;
        let (c0, c1) = self.cos_bounds(y);
        let z = c0 + (c1 - c0) * fy;
        let s = (1.0 - z * z).max(0.0).sqrt();
        DVec3::new(s * phi.cos(), s * phi.sin(), z)
    }

    /// The direction of texel `(x, y)`'s centre in φ and θ.
    pub fn direction(&self, x: u32, y: u32) -> DVec3 {
        let phi = -PI + 2.0 * PI * (x as f64 + 0.5) / self.width as f64;
        let theta = PI * (y as f64 + 0.5) / self.height as f64;
        DVec3::new(
            theta.sin() * phi.cos(),
            theta.sin() * phi.sin(),
            theta.cos(),
        )
    }

    /// `cos θ` at the top and the bottom edge of row `y` (decreasing).
    pub fn cos_bounds(&self, y: u32) -> (f64, f64) {
        let h = self.height as f64;
        ((PI * y as f64 / h).cos(), (PI * (y as f64 + 1.0) / h).cos())
    }

    /// The exact solid angle of a texel of row `y`: `(2π/W)(cos θ₀ − cos θ₁)`.
    pub fn solid_angle(&self, y: u32) -> f64 {
        let (c0, c1) = self.cos_bounds(y);
        2.0 * PI / self.width as f64 * (c0 - c1)
    }

    /// The texel holding direction `d` (any length; zero or non-finite counts as +Z).
    pub fn texel_of(&self, d: DVec3) -> (u32, u32) {
        let d = d.try_normalize().unwrap_or(DVec3::Z);
        let u = (azimuth(d) + PI) / (2.0 * PI);
        let v = d.z.clamp(-1.0, 1.0).acos() / PI;
        let x = ((u * self.width as f64) as i64).clamp(0, self.width as i64 - 1) as u32;
        let y = ((v * self.height as f64) as i64).clamp(0, self.height as i64 - 1) as u32;
        (x, y)
    }

    /// Continuous texel coordinates `(u·W, v·H)` of `d` (texel centres at half-integers).
    pub fn coordinates(&self, d: DVec3) -> (f64, f64) {
        let d = d.try_normalize().unwrap_or(DVec3::Z);
        let u = (azimuth(d) + PI) / (2.0 * PI);
        let v = d.z.clamp(-1.0, 1.0).acos() / PI;
        (u * self.width as f64, v * self.height as f64)
    }
}

/// One channel of an environment: what the lighting code (ground truth, SH projection,
/// prefiltering) reads. Values are finite and ≥ 0 (an [`Environment`] guarantees it).
#[derive(Debug, Clone, PartialEq)]
pub struct Radiance {
    width: u32,
    height: u32,
    values: Vec<f32>,
}

impl Radiance {
    /// A channel from values (row-major from the zenith row, `width = 2·height`); NaN,
    /// infinite and negative values are set to 0 (as [`BadTexels::Repair`]).
    pub fn new(width: u32, height: u32, mut values: Vec<f32>) -> Result<Radiance> {
        check_size("radiance", width, height)?;
        if values.len() != width as usize * height as usize {
            return Err(Error::ShortBuffer {
                what: "radiance".into(),
                got: values.len(),
                needed: width as usize * height as usize,
            });
        }
        for v in values.iter_mut() {
            if !v.is_finite() || *v < 0.0 {
                *v = 0.0;
            }
        }
        Ok(Radiance {
            width,
            height,
            values,
        })
    }

    /// A constant environment of radiance `value` (tests: closed forms).
    pub fn constant(width: u32, value: f32) -> Radiance {
        let w = width.max(2) & !1;
        Radiance {
            width: w,
            height: w / 2,
            values: vec![value.max(0.0); (w * w / 2) as usize],
        }
    }

    /// The geometry of a `width × height` grid.
    pub fn geometry(width: u32, height: u32) -> Geometry {
        Geometry { width, height }
    }

    /// This channel's grid geometry.
    pub fn grid(&self) -> Geometry {
        Geometry {
            width: self.width,
            height: self.height,
        }
    }

    /// Width in texels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in texels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The values, row-major.
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    /// Exact solid angle of a texel of row `y`.
    pub fn solid_angle(&self, y: u32) -> f64 {
        self.grid().solid_angle(y)
    }

    /// The radiance in direction `d` as the piecewise-constant function it is (the texel's
    /// value): what the ground truth integrates.
    pub fn nearest(&self, d: DVec3) -> f64 {
        self.values[self.index_of(d)] as f64
    }

    /// The index into [`Radiance::values`] of the texel `d` falls in ([`Radiance::nearest`]'s
    /// texel): one lookup for several radiances on the same grid.
    pub fn index_of(&self, d: DVec3) -> usize {
        let (x, y) = self.grid().texel_of(d);
        (y * self.width + x) as usize
    }

    /// Bilinear lookup, wrapping in φ and continued over the poles: within half a row of a
    /// pole the row beyond it is the first (last) row half a turn away, `(θ, φ) → (−θ, φ + π)`,
    /// so the pole itself reads the mean of two opposite texels, exact for a field linear
    /// across the pole (clamping the row instead read one side of the ring: +5 % at the zenith
    /// of a 32 × 16 level of venice_sunset_1k). The shaders' `ndf_env_bilinear` does the same.
    pub fn bilinear(&self, d: DVec3) -> f64 {
        let (u, v) = self.grid().coordinates(d);
        let (w, h) = (self.width as i64, self.height as i64);
        let (fu, fv) = (u - 0.5, v - 0.5);
        let (x0, y0) = (fu.floor(), fv.floor());
        let (tx, ty) = (fu - x0, fv - y0);
        let at = |x: i64, y: i64| -> f64 {
            let (x, y) = if y < 0 {
                (x + w / 2, -1 - y)
            } else if y >= h {
                (x + w / 2, 2 * h - 1 - y)
            } else {
                (x, y)
            };
            let x = x.rem_euclid(w);
            let y = y.clamp(0, h - 1);
            self.values[(y * w + x) as usize] as f64
        };
        let (x0, y0) = (x0 as i64, y0 as i64);
        (1.0 - ty) * ((1.0 - tx) * at(x0, y0) + tx * at(x0 + 1, y0))
            + ty * ((1.0 - tx) * at(x0, y0 + 1) + tx * at(x0 + 1, y0 + 1))
    }

    /// `∫ L dω` (f64, exact for the piecewise-constant radiance).
    pub fn power(&self) -> f64 {
        let mut sum = 0.0;
        for (y, row) in self.values.chunks_exact(self.width as usize).enumerate() {
            let s: f64 = row.iter().map(|&v| v as f64).sum();
            sum += s * self.solid_angle(y as u32);
        }
        sum
    }

    /// Halves the resolution (while the width stays ≥ 4), each new texel the solid-angle
    /// weighted mean of the four it covers: `∫ L dω` is kept exactly (up to f32 storage).
    pub fn downsample(&self) -> Radiance {
        if self.width < 4 {
            return self.clone();
        }
        let (w, h) = (self.width / 2, self.height / 2);
        let mut values = vec![0.0f32; (w * h) as usize];
        for y in 0..h {
            let (a0, a1) = (self.solid_angle(2 * y), self.solid_angle(2 * y + 1));
            for x in 0..w {
                let at = |xx: u32, yy: u32| self.values[(yy * self.width + xx) as usize] as f64;
                let s = a0 * (at(2 * x, 2 * y) + at(2 * x + 1, 2 * y))
                    + a1 * (at(2 * x, 2 * y + 1) + at(2 * x + 1, 2 * y + 1));
                values[(y * w + x) as usize] = (s / (2.0 * (a0 + a1))) as f32;
            }
        }
        Radiance {
            width: w,
            height: h,
            values,
        }
    }

    /// Downsamples until the width is at most `width` (at least 4).
    pub fn downsample_to(&self, width: u32) -> Radiance {
        let mut r = self.clone();
        while r.width > width.max(4) {
            r = r.downsample();
        }
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_poles_have_azimuth_zero_whatever_the_sign_of_zero() {
        // atan2(±0, −0) is ±π in Rust, undefined in GLSL: both sides take 0 at the poles.
        for (x, y) in [(0.0, 0.0), (-0.0, 0.0), (0.0, -0.0), (-0.0, -0.0)] {
            assert_eq!(azimuth(DVec3::new(x, y, 1.0)), 0.0);
            assert_eq!(azimuth(DVec3::new(x, y, -1.0)), 0.0);
        }
        assert_eq!(azimuth(DVec3::new(-1.0, 0.0, 0.0)), PI);
        assert_eq!(azimuth(DVec3::new(0.0, -1.0, 0.0)), -0.5 * PI);
        let g = Radiance::geometry(8, 4);
        assert_eq!(g.coordinates(DVec3::new(-0.0, -0.0, 1.0)), (4.0, 0.0));
        assert_eq!(g.texel_of(DVec3::new(-0.0, 0.0, 1.0)), (4, 0));
    }

    fn hdr_bytes(w: u32, h: u32, f: impl Fn(u32, u32) -> [f32; 3]) -> Vec<u8> {
        let mut out = Vec::new();
        let px: Vec<image::Rgb<f32>> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| image::Rgb(f(x, y)))
            .collect();
        image::codecs::hdr::HdrEncoder::new(&mut out)
            .encode(&px, w as usize, h as usize)
            .unwrap();
        out
    }

    /// The bilinear lookup continues over a pole: a field linear across it, `2 + x`, reads its
    /// value at both poles exactly (the mean of texels half a turn apart) and within a
    /// thousandth half a row from them; clamping the row instead read one side of the ring,
    /// `2 + sin θ₀` (5 % over on a 32 × 16 grid).
    #[test]
    fn bilinear_reads_across_the_poles() {
        let (w, h) = (32u32, 16u32);
        let g = Radiance::geometry(w, h);
        let values: Vec<f32> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| (2.0 + g.direction(x, y).x) as f32)
            .collect();
        let r = Radiance::new(w, h, values).unwrap();
        for z in [1.0, -1.0] {
            let got = r.bilinear(DVec3::new(0.0, 0.0, z));
            assert!((got - 2.0).abs() < 1e-6, "pole z = {z}: {got}");
            for phi in [0.0f64, 0.7, 2.0, -2.5] {
                // Half a row from the pole: the pole side of the first row's centres.
                let t = 0.25 * PI / h as f64;
                let d = DVec3::new(t.sin() * phi.cos(), t.sin() * phi.sin(), z * t.cos());
                let got = r.bilinear(d);
                assert!(
                    (got - (2.0 + d.x)).abs() < 1e-3,
                    "z = {z}, φ = {phi}: {got} against {}",
                    2.0 + d.x
                );
            }
        }
        // What clamping the row gave at the zenith.
        let clamped = 0.5 * (r.values()[(w / 2 - 1) as usize] + r.values()[(w / 2) as usize]);
        assert!(clamped as f64 - 2.0 > 0.09, "{clamped}");
    }

    #[test]
    fn texel_solid_angles_sum_to_the_sphere() {
        for w in [4u32, 6, 64, 1024] {
            let g = Radiance::geometry(w, w / 2);
            let s: f64 = (0..w / 2).map(|y| g.solid_angle(y) * w as f64).sum();
            assert!((s - 4.0 * PI).abs() < 1e-12, "w={w} {s}");
        }
    }

    #[test]
    fn directions_and_texels_round_trip() {
        let g = Radiance::geometry(64, 32);
        for y in 0..32 {
            for x in 0..64 {
                assert_eq!(g.texel_of(g.direction(x, y)), (x, y));
            }
        }
    }

    #[test]
    fn hdr_round_trip_and_bad_input() {
        let bytes = hdr_bytes(8, 4, |x, y| [x as f32, y as f32, 1.0]);
        let env = from_memory("t.hdr", &bytes, &EnvOptions::default()).unwrap();
        assert_eq!((env.width(), env.height()), (8, 4));
        assert_eq!(env.texels()[3 * 8 + 5], [5.0, 3.0, 1.0]);
        // Not 2:1.
        let sq = hdr_bytes(8, 8, |_, _| [1.0; 3]);
        let e = from_memory("sq.hdr", &sq, &EnvOptions::default()).unwrap_err();
        assert!(e.to_string().contains("2:1"), "{e}");
        // Truncated at every length: an error, never a panic or a partial environment.
        let big = hdr_bytes(64, 32, |x, y| [(x * y) as f32 + 0.5, 1.0, 2.0]);
        for len in (0..big.len()).step_by(97) {
            assert!(
                from_memory("cut.hdr", &big[..len], &EnvOptions::default()).is_err(),
                "{len}"
            );
        }
        // Neither format.
        assert!(from_memory("x", b"hello", &EnvOptions::default()).is_err());
    }

    #[test]
    fn exr_is_read() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("e.exr");
        exr::prelude::write_rgb_file(&p, 8, 4, |x, y| (x as f32, y as f32, 0.25f32)).unwrap();
        let env = load(&p, &EnvOptions::default()).unwrap();
        assert_eq!(env.texels()[2 * 8 + 7], [7.0, 2.0, 0.25]);
    }

    #[test]
    fn bad_texels_are_repaired_or_refused() {
        let mut t = vec![[1.0f32; 3]; 32];
        t[5] = [f32::NAN, 1.0, 1.0];
        t[9] = [f32::INFINITY, -2.0, 1.0];
        let env = Environment::from_rgb("m", 8, 4, t.clone(), &EnvOptions::default()).unwrap();
        assert_eq!(env.repaired(), 2);
        assert_eq!(env.texels()[5], [0.0, 1.0, 1.0]);
        assert_eq!(env.texels()[9], [0.0, 0.0, 1.0]);
        let opts = EnvOptions {
            bad_texels: BadTexels::Reject,
            ..Default::default()
        };
        let e = Environment::from_rgb("m", 8, 4, t, &opts).unwrap_err();
        assert!(e.to_string().contains("x=5, y=0"), "{e}");
        let bad = EnvOptions {
            intensity: f64::NAN,
            ..Default::default()
        };
        assert!(Environment::from_rgb("m", 8, 4, vec![[1.0; 3]; 32], &bad).is_err());
    }

    #[test]
    fn yaw_shifts_azimuth_and_keeps_power() {
        let t: Vec<[f32; 3]> = (0..32).map(|i| [(i % 8) as f32, 0.0, 0.0]).collect();
        let env = Environment::from_rgb("m", 8, 4, t, &EnvOptions::default()).unwrap();
        let r = env.rotated(45.0); // one texel
        assert_eq!(r.texels()[1][0], 0.0);
        assert_eq!(r.texels()[2][0], 1.0);
        let r = env.rotated(100.0);
        assert!((r.channel(0).power() - env.channel(0).power()).abs() < 1e-5);
        // A direction's radiance moves to φ + yaw.
        let g = env.channel(0).grid();
        let d = g.direction(3, 1);
        let rot = DVec3::new(
            d.x * 45f64.to_radians().cos() - d.y * 45f64.to_radians().sin(),
            d.x * 45f64.to_radians().sin() + d.y * 45f64.to_radians().cos(),
            d.z,
        );
        assert_eq!(
            env.rotated(45.0).channel(0).nearest(rot),
            env.channel(0).nearest(d)
        );
    }

    #[test]
    fn sky_sun_power_is_exact_and_downsampling_keeps_power() {
        let sky = Sky::default();
        let env = sky.render().unwrap();
        let lum = env.channel(0);
        // Sun power: the difference with a sunless sky.
        let dark = Sky {
            sun: [0.0; 3],
            ..sky
        }
        .render()
        .unwrap()
        .channel(0);
        let omega = 2.0 * PI * (1.0 - sky.sun_radius_deg.to_radians().cos());
        let sun = lum.power() - dark.power();
        // The disc replaces the sky it covers: off by at most the sky under it.
        assert!(
            (sun - 2.0e4 * omega).abs() < 1.0 * omega + 1e-3 * sun,
            "{sun}"
        );
        for w in [128, 64, 8] {
            let d = lum.downsample_to(w);
            assert!((d.power() - lum.power()).abs() < 1e-5 * lum.power(), "{w}");
        }
    }
}
