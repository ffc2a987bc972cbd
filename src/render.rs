//! Image-space rendering on the CPU (DESIGN.md "Ground truth and error", paper Sec 7.4): views
//! of a normal-mapped plane and sphere, rendered
//! - as **ground truth**, by jittered stratified supersampling of the *unfiltered* normal map:
//!   every sub-sample looks up the nearest finest-level normal (GL `NEAREST` on level 0, the
//!   map's addressing) and shades it exactly ([`crate::brdf::reference_brdf`]); the pixel is the
//!   mean over a box pixel filter;
//! - **filtered**, with a bake's textures through the CPU twin of the shaders: one sample at the
//!   pixel centre, level of detail from the screen derivatives of uv ([`crate::sample::lod`], GL's
//!   formula) and [`crate::sample::shade_at`] (hardware trilinear, or manual per-texel shading
//!   blended, as the shader's specialization decides).
//!
//! Mesh conventions are the shaders' (`glsl/ndf_vertex.glsl`): the tangent runs along +u, the
//! bitangent `± cross(n, t)` points towards decreasing v, image row 0 is at v = 0, so the map's
//! +Y (OpenGL convention) points towards row 0. Light and view are expressed in that tangent
//! frame, as the fragment shader does.
//!
//! Screen derivatives of uv come from ray differentials (Igehy 1999): the rays through the next
//! pixel to the right and below are intersected with the tangent plane at the hit, and the
//! offset solved for (Δu, Δv) in the basis (∂p/∂u, ∂p/∂v) — what GL's `dFdx`/`dFdy` estimate by
//! finite differences over a 2×2 quad. Rows are rendered in parallel; the ground truth seeds a
//! generator per row, so images are bit-identical for any thread count.

use crate::bake::Bake;
use crate::brdf::{Brdf, half_vector, reference_brdf};
use crate::glsl::{ShaderOptions, ShaderSpec, manual_sampling};
use crate::ingest::{Addressing, NormalMap};
use crate::rng::Rng;
use crate::sample::{Filtering, lod, shade_at_lights};
use crate::shade::ShadingRgb;
use glam::{DVec2, DVec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// A pinhole camera; pixel rows run top to bottom.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// Eye position.
    pub eye: DVec3,
    /// Point looked at (the image centre).
    pub target: DVec3,
    /// Up direction (need not be orthogonal to the view).
    pub up: DVec3,
    /// Vertical field of view, degrees.
    pub fov_y_deg: f64,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
}

impl Camera {
    /// The ray through the image point `(px, py)` in pixels (`(0.5, 0.5)` is the centre of the
    /// top-left pixel): origin and unit direction.
    pub fn ray(&self, px: f64, py: f64) -> (DVec3, DVec3) {
        Rays::new(self).ray(px, py)
    }
}

/// What [`Camera::ray`] derives from the camera before the pixel position enters, computed
/// once per image: the renderers' inner loops call [`Rays::ray`], which gives bit for bit what
/// `Camera::ray` gives.
#[derive(Debug, Clone, Copy)]
struct Rays {
    eye: DVec3,
    f: DVec3,
    r: DVec3,
    u: DVec3,
    t: f64,
    w: f64,
    h: f64,
}

impl Rays {
    fn new(c: &Camera) -> Rays {
        let f = (c.target - c.eye).normalize();
        let r = f.cross(c.up).normalize();
        let u = r.cross(f);
        Rays {
            eye: c.eye,
            f,
            r,
            u,
            t: (0.5 * c.fov_y_deg.to_radians()).tan(),
            w: c.width as f64,
            h: c.height as f64,
        }
    }

    fn ray(&self, px: f64, py: f64) -> (DVec3, DVec3) {
        let (t, w, h) = (self.t, self.w, self.h);
        let x = (2.0 * px / w - 1.0) * t * w / h;
        let y = (1.0 - 2.0 * py / h) * t;
        (self.eye, (self.f + x * self.r + y * self.u).normalize())
    }
}

/// Where a ray meets the surface: position, geometric normal, the partial derivatives of the
/// position in u and v, and the texture coordinate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Ray parameter.
    pub t: f64,
    /// Position.
    pub p: DVec3,
    /// Unit geometric normal.
    pub n: DVec3,
    /// ∂p/∂u.
    pub dpdu: DVec3,
    /// ∂p/∂v.
    pub dpdv: DVec3,
    /// Texture coordinate (unwrapped; sampling wraps or clamps).
    pub uv: DVec2,
}

impl Hit {
    /// The tangent frame of the shaders' convention: tangent along +u, bitangent `± n × t`
    /// pointing towards decreasing v.
    pub fn frame(&self) -> (DVec3, DVec3, DVec3) {
        let t = (self.dpdu - self.n * self.n.dot(self.dpdu))
            .try_normalize()
            .unwrap_or_else(|| crate::brdf::tangent_frame(self.n).0);
        let b = self.n.cross(t);
        let b = if b.dot(self.dpdv) > 0.0 { -b } else { b };
        (t, b, self.n)
    }
}

/// The normal-mapped surface of a view.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Surface {
    /// The infinite plane z = 0 seen from above, `u = x/tile`, `v = −y/tile` (so +u is +x and
    /// decreasing v is +y: the tangent frame is the world frame).
    Plane {
        /// World size of one repeat of the texture.
        tile: f64,
    },
    /// A sphere, `u = tiles_u·φ/2π`, `v = tiles_v·θ/π` (θ from the +z pole).
    Sphere {
        /// Centre.
        center: DVec3,
        /// Radius.
        radius: f64,
        /// Texture repeats around (must be an integer for a seamless wrap).
        tiles_u: f64,
        /// Texture repeats from pole to pole.
        tiles_v: f64,
    },
}

impl Surface {
    /// The nearest hit of the ray `o + t·d` (t > 0), if any.
    pub fn intersect(&self, o: DVec3, d: DVec3) -> Option<Hit> {
        match *self {
            Surface::Plane { tile } => {
                if d.z.abs() < 1e-300 {
                    return None;
                }
                let t = -o.z / d.z;
                if !(t > 0.0 && t.is_finite()) {
                    return None;
                }
                let p = o + t * d;
                Some(Hit {
                    t,
                    p,
                    n: DVec3::Z,
                    dpdu: DVec3::new(tile, 0.0, 0.0),
                    dpdv: DVec3::new(0.0, -tile, 0.0),
                    uv: DVec2::new(p.x / tile, -p.y / tile),
                })
            }
            Surface::Sphere {
                center,
                radius,
                tiles_u,
                tiles_v,
            } => {
                let oc = o - center;
                let b = oc.dot(d);
                let c = oc.length_squared() - radius * radius;
                let disc = b * b - c;
                if disc < 0.0 {
                    return None;
                }
                let sq = disc.sqrt();
                let t = if -b - sq > 0.0 { -b - sq } else { -b + sq };
                if t <= 0.0 {
                    return None;
                }
                let p = o + t * d;
                let q = (p - center) / radius;
                let theta = q.z.clamp(-1.0, 1.0).acos();
                let phi = q.y.atan2(q.x).rem_euclid(2.0 * PI);
                let (st, ct) = theta.sin_cos();
                let (sp, cp) = phi.sin_cos();
                Some(Hit {
                    t,
                    p,
                    n: q.normalize(),
                    dpdu: radius * (2.0 * PI / tiles_u) * DVec3::new(-st * sp, st * cp, 0.0),
                    dpdv: radius * (PI / tiles_v) * DVec3::new(ct * cp, ct * sp, -st),
                    uv: DVec2::new(tiles_u * phi / (2.0 * PI), tiles_v * theta / PI),
                })
            }
        }
    }
}

/// A light: direction and radiance scale at a point.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Light {
    /// Parallel light arriving from `direction` (towards the light), radiance scale `radiance`.
    Directional {
        /// Unit vector towards the light.
        direction: DVec3,
        /// Scale.
        radiance: f64,
    },
    /// A point light with inverse-square falloff: scale `intensity / d²`.
    Point {
        /// Position.
        position: DVec3,
        /// Scale at distance 1.
        intensity: f64,
    },
}

impl Light {
    /// Unit direction towards the light from `p`, and the radiance scale there (the shader's
    /// `ndf_light_color * falloff`).
    pub fn at(&self, p: DVec3) -> (DVec3, f64) {
        match *self {
            Light::Directional {
                direction,
                radiance,
            } => (direction.normalize(), radiance),
            Light::Point {
                position,
                intensity,
            } => {
                let to = position - p;
                let d2 = to.length_squared().max(1e-12);
                (to / d2.sqrt(), intensity / d2)
            }
        }
    }
}

/// `K_d · diffuse + K_s · specular` with the specular term's BRDF.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Material {
    /// Lambert weight.
    pub kd: f64,
    /// Specular weight.
    pub ks: f64,
    /// The specular lobe.
    pub brdf: Brdf,
}

impl Material {
    /// `scale · (K_d · diffuse + K_s · specular)`: a light's contribution (the shader's
    /// `ndf_light_color * falloff * (ndf_kd * d + ndf_ks * s)`).
    pub fn radiance(&self, scale: f64, diffuse: f64, specular: f64) -> f64 {
        scale * (self.kd * diffuse + self.ks * specular)
    }
}

/// One view: camera, surface, lights and material.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Scene {
    /// Short name (file names, tables).
    pub name: String,
    /// The camera.
    pub camera: Camera,
    /// The surface.
    pub surface: Surface,
    /// The lights (their contributions add).
    pub lights: Vec<Light>,
    /// The material.
    pub material: Material,
}

/// A rendered monochrome image of linear radiance, rows top to bottom, with the fraction of
/// each pixel the surface covers (ground truth: of its sub-samples; filtered: 0 or 1 at the
/// centre).
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Radiance per pixel.
    pub pixels: Vec<f64>,
    /// Covered fraction per pixel.
    pub coverage: Vec<f32>,
}

/// Per-pixel geometry of a view at the pixel centre: the hit, uv's screen derivatives, and the
/// level of detail on a texture of `size`.
#[derive(Debug, Clone, Copy)]
pub struct PixelGeometry {
    /// The hit at the pixel centre.
    pub hit: Hit,
    /// ∂uv/∂x (one pixel to the right).
    pub duv_dx: DVec2,
    /// ∂uv/∂y (one pixel down).
    pub duv_dy: DVec2,
}

/// uv's change for a one-pixel step, from the ray through the neighbouring image point
/// intersected with the hit's tangent plane (a ray differential).
fn uv_step(hit: &Hit, o: DVec3, d: DVec3) -> DVec2 {
    let den = d.dot(hit.n);
    if den.abs() < 1e-300 {
        return DVec2::splat(1e30);
    }
    let t = (hit.p - o).dot(hit.n) / den;
    let dp = o + t * d - hit.p;
    let (a, b) = (hit.dpdu, hit.dpdv);
    let (aa, ab, bb) = (a.dot(a), a.dot(b), b.dot(b));
    let det = aa * bb - ab * ab;
    if det.abs() < 1e-300 {
        return DVec2::splat(1e30);
    }
    let (ra, rb) = (a.dot(dp), b.dot(dp));
    DVec2::new((bb * ra - ab * rb) / det, (aa * rb - ab * ra) / det)
}

/// The geometry at the centre of pixel `(x, y)`, or `None` where the surface is missed.
pub fn pixel_geometry(scene: &Scene, x: u32, y: u32) -> Option<PixelGeometry> {
    pixel_geometry_with(&Rays::new(&scene.camera), &scene.surface, x, y)
}

/// [`pixel_geometry`] with the camera's rays prepared.
fn pixel_geometry_with(rays: &Rays, surface: &Surface, x: u32, y: u32) -> Option<PixelGeometry> {
    let (cx, cy) = (x as f64 + 0.5, y as f64 + 0.5);
    let (o, d) = rays.ray(cx, cy);
    let hit = surface.intersect(o, d)?;
    let (ox, dx) = rays.ray(cx + 1.0, cy);
    let (oy, dy) = rays.ray(cx, cy + 1.0);
    Some(PixelGeometry {
        hit,
        duv_dx: uv_step(&hit, ox, dx),
        duv_dy: uv_step(&hit, oy, dy),
    })
}

/// The tangent frame of a hit and the direction to the eye in it: what every light's
/// [`TangentSpace::light`] shares.
struct TangentSpace {
    t: DVec3,
    b: DVec3,
    n: DVec3,
    p: DVec3,
    v: DVec3,
}

impl TangentSpace {
    fn new(hit: &Hit, eye: DVec3) -> TangentSpace {
        let (t, b, n) = hit.frame();
        let mut ts = TangentSpace {
            t,
            b,
            n,
            p: hit.p,
            v: DVec3::ZERO,
        };
        ts.v = ts.to_ts((eye - hit.p).normalize());
        ts
    }

    fn to_ts(&self, w: DVec3) -> DVec3 {
        DVec3::new(w.dot(self.t), w.dot(self.b), w.dot(self.n))
    }

    /// The light, view and half vectors of `light` in the tangent frame, with the light's
    /// radiance scale — what the fragment shader computes before shading.
    fn light(&self, light: &Light) -> (DVec3, DVec3, f64) {
        let (lw, scale) = light.at(self.p);
        let l = self.to_ts(lw);
        (l, half_vector(l, self.v), scale)
    }
}

/// The level of detail at every pixel centre on a texture of `size` (NaN where the surface is
/// missed): what `ndf_lod` gives the shader.
pub fn lod_image(scene: &Scene, size: (u32, u32)) -> Vec<f64> {
    let (w, h) = (scene.camera.width, scene.camera.height);
    let rays = Rays::new(&scene.camera);
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            pixel_geometry_with(&rays, &scene.surface, i % w, i / w)
                .map_or(f64::NAN, |g| lod(g.duv_dx, g.duv_dy, size))
        })
        .collect()
}

/// The nearest finest-level normal at `uv` (GL `NEAREST` on level 0, wrapped or clamped).
pub fn nearest_normal(map: &NormalMap, uv: DVec2) -> DVec3 {
    let (x, y) = nearest_texel(map, uv);
    map.normal(x, y).as_dvec3()
}

/// The texel of `map` that `uv` falls in, by the map's addressing: [`nearest_normal`]'s texel
/// (for reading other per-texel data, e.g. the albedo, at the same place).
pub fn nearest_texel(map: &NormalMap, uv: DVec2) -> (u32, u32) {
    let idx = |u: f64, n: u32| -> u32 {
        let i = (u * n as f64).floor() as i64;
        match map.addressing() {
            Addressing::Wrap => i.rem_euclid(n as i64) as u32,
            Addressing::Clamp => i.clamp(0, n as i64 - 1) as u32,
        }
    };
    (idx(uv.x, map.width()), idx(uv.y, map.height()))
}

/// Mixes a row index into a seed (splitmix64 of both): one independent stream per row.
fn row_seed(seed: u64, row: u32) -> u64 {
    let mut r = Rng(seed ^ (row as u64).wrapping_mul(0xD1B5_4A32_D192_ED03));
    r.next_u64()
}

/// Ground truth: `spp` jittered stratified sub-samples per pixel (rounded up to a square,
/// `n × n` strata), each shading the nearest finest normal of the unfiltered `map` exactly; the
/// pixel is their mean (misses count as 0, and as uncovered). Deterministic for `seed`, whatever
/// the thread count.
pub fn render_ground_truth(scene: &Scene, map: &NormalMap, spp: u32, seed: u64) -> Image {
    let n = (spp.max(1) as f64).sqrt().ceil() as u32;
    let count = (n * n) as f64;
    let rays = Rays::new(&scene.camera);
    render_rows(scene, seed, |x, y, rng| {
        let (mut sum, mut hits) = (0.0f64, 0u32);
        for sy in 0..n {
            for sx in 0..n {
                let fx = x as f64 + (sx as f64 + rng.range(0.0, 1.0)) / n as f64;
                let fy = y as f64 + (sy as f64 + rng.range(0.0, 1.0)) / n as f64;
                let (o, d) = rays.ray(fx, fy);
                let Some(hit) = scene.surface.intersect(o, d) else {
                    continue;
                };
                hits += 1;
                let normal = nearest_normal(map, hit.uv);
                let ts = TangentSpace::new(&hit, scene.camera.eye);
                for light in &scene.lights {
                    let (l, hv, scale) = ts.light(light);
                    let s = reference_brdf(normal, l, hv, &scene.material.brdf);
                    sum += scene.material.radiance(scale, s.diffuse, s.specular);
                }
            }
        }
        Some((sum / count, hits as f32 / count as f32))
    })
}

/// Renders every pixel with `pixel(x, y, rng)` → `(radiance, coverage)` (`None`: missed), rows
/// in parallel, each row with its own generator seeded from `seed` and the row: the image is
/// the same for any thread count.
fn render_rows(
    scene: &Scene,
    seed: u64,
    pixel: impl Fn(u32, u32, &mut Rng) -> Option<(f64, f32)> + Sync,
) -> Image {
    let (w, h) = (scene.camera.width, scene.camera.height);
    let mut pixels = vec![0.0f64; (w * h) as usize];
    let mut coverage = vec![0.0f32; (w * h) as usize];
    pixels
        .par_chunks_mut(w as usize)
        .zip(coverage.par_chunks_mut(w as usize))
        .enumerate()
        .for_each(|(y, (row, cov))| {
            let mut rng = Rng(row_seed(seed, y as u32));
            for (x, (px, c)) in row.iter_mut().zip(cov.iter_mut()).enumerate() {
                if let Some((p, k)) = pixel(x as u32, y as u32, &mut rng) {
                    *px = p;
                    *c = k;
                }
            }
        });
    Image {
        width: w,
        height: h,
        pixels,
        coverage,
    }
}

/// The view rendered with `bake`'s filtered textures through the CPU twin of the shader (one
/// sample at each pixel centre; sampling as the specialization with default options decides:
/// manual for unaligned mixtures, hardware trilinear otherwise).
pub fn render_filtered(scene: &Scene, bake: &Bake) -> Image {
    let manual = manual_sampling(&ShaderSpec::of(bake), &ShaderOptions::default());
    render_filtered_with(scene, bake, manual)
}

/// [`render_filtered`] with the sampling mode given: `manual` shades the texels of the
/// trilinear footprint and blends, otherwise the textures are sampled trilinearly.
pub fn render_filtered_with(scene: &Scene, bake: &Bake, manual: bool) -> Image {
    render_prepared_with(scene, &ViewGeometry::new(scene), bake, manual)
}

/// A light's `(l, h, scale)` at a pixel: tangent-space light and half vectors, radiance scale.
type LightFrame = (DVec3, DVec3, f64);

/// One covered pixel of a [`ViewGeometry`].
#[derive(Debug, Clone, Copy)]
struct PixelSetup {
    uv: DVec2,
    duv_dx: DVec2,
    duv_dy: DVec2,
}

/// What every filtered render of a view shares, computed once: per pixel centre the hit's uv,
/// uv's screen derivatives and each light's tangent-space light and half vectors and radiance
/// scale. [`render_filtered_prepared`] renders from it what [`render_filtered`] renders, bit for
/// bit.
#[derive(Debug, Clone)]
pub struct ViewGeometry {
    width: u32,
    height: u32,
    lights: usize,
    pixels: Vec<Option<PixelSetup>>,
    /// Per pixel and light (`lights` per pixel; zeros where missed).
    frames: Vec<LightFrame>,
}

impl ViewGeometry {
    /// The geometry of every pixel centre of `scene` (rows in parallel).
    pub fn new(scene: &Scene) -> ViewGeometry {
        let (w, h) = (scene.camera.width, scene.camera.height);
        let nl = scene.lights.len();
        let rays = Rays::new(&scene.camera);
        let rows: Vec<(Vec<Option<PixelSetup>>, Vec<LightFrame>)> = (0..h)
            .into_par_iter()
            .map(|y| {
                let mut pixels = Vec::with_capacity(w as usize);
                let mut frames = vec![(DVec3::ZERO, DVec3::ZERO, 0.0); w as usize * nl];
                for x in 0..w {
                    let g = pixel_geometry_with(&rays, &scene.surface, x, y);
                    if let Some(g) = &g {
                        let ts = TangentSpace::new(&g.hit, scene.camera.eye);
                        for (i, light) in scene.lights.iter().enumerate() {
                            frames[x as usize * nl + i] = ts.light(light);
                        }
                    }
                    pixels.push(g.map(|g| PixelSetup {
                        uv: g.hit.uv,
                        duv_dx: g.duv_dx,
                        duv_dy: g.duv_dy,
                    }));
                }
                (pixels, frames)
            })
            .collect();
        let mut out = ViewGeometry {
            width: w,
            height: h,
            lights: nl,
            pixels: Vec::with_capacity((w * h) as usize),
            frames: Vec::with_capacity((w * h) as usize * nl),
        };
        for (p, f) in rows {
            out.pixels.extend(p);
            out.frames.extend(f);
        }
        out
    }
}

/// [`render_filtered`] from the view's prepared geometry (`geometry` must be `scene`'s).
pub fn render_filtered_prepared(scene: &Scene, geometry: &ViewGeometry, bake: &Bake) -> Image {
    let manual = manual_sampling(&ShaderSpec::of(bake), &ShaderOptions::default());
    render_prepared_with(scene, geometry, bake, manual)
}

fn render_prepared_with(scene: &Scene, g: &ViewGeometry, bake: &Bake, manual: bool) -> Image {
    let footprint = if manual {
        Footprint::Manual
    } else {
        Footprint::Trilinear
    };
    render_footprint(scene, g, bake, footprint)
}

/// How a filtered render samples the bake (the shader's sampling mode).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Footprint {
    /// One trilinear fetch per texture, then shading.
    Trilinear,
    /// Shade the texels of the trilinear footprint, then blend (unaligned lobes).
    Manual,
    /// The anisotropic footprint of [`crate::sample::aniso_probes`] with at most this many
    /// trilinear probes, averaged, then shading.
    Anisotropic(u32),
}

/// [`render_filtered_prepared`] with the sampling given explicitly (anisotropic included).
pub fn render_footprint(
    scene: &Scene,
    g: &ViewGeometry,
    bake: &Bake,
    footprint: Footprint,
) -> Image {
    assert!(
        g.width == scene.camera.width
            && g.height == scene.camera.height
            && g.lights == scene.lights.len(),
        "the geometry is of another view"
    );
    let size = bake.sizes[0];
    let f = Filtering {
        manual: footprint == Footprint::Manual,
        ..Filtering::new(scene.material.brdf.clone())
    };
    let nl = g.lights;
    render_rows(scene, 0, |x, y, _| {
        let i = (y * g.width + x) as usize;
        let p = g.pixels[i]?;
        let frames = &g.frames[i * nl..(i + 1) * nl];
        let lights: Vec<(DVec3, DVec3)> = frames.iter().map(|&(l, h, _)| (l, h)).collect();
        let mut shaded = vec![ShadingRgb::default(); nl];
        if let Footprint::Anisotropic(max) = footprint {
            let d = (p.duv_dx, p.duv_dy);
            crate::sample::shade_aniso_lights(bake, p.uv, d, max, &lights, &f, &mut shaded);
        } else {
            let lambda = lod(p.duv_dx, p.duv_dy, size);
            shade_at_lights(bake, p.uv, lambda, &lights, &f, &mut shaded);
        }
        let mut sum = 0.0;
        for (s, &(_, _, scale)) in shaded.iter().zip(frames) {
            sum += scene.material.radiance(scale, s.diffuse.x, s.specular.x);
        }
        Some((sum, 1.0))
    })
}

/// The *ideal* NDF method under GL's sampling (the floor every filtered render shares): at
/// each pixel centre, the same LOD, levels, bilinear taps and weights as hardware trilinear
/// filtering, but each tap texel's value is the average of the unfiltered shading over the
/// finest normals its square covers: exact where the level-k texel covers at most
/// `samples_per_texel` finest texels (`2^k × 2^k` strata, one per finest texel), otherwise
/// estimated with `n × n` stratified samples (`samples_per_texel` rounded up to a square;
/// nearest finest normal, as the ground truth). The estimate's noise adds to the measured floor
/// at the far levels.
/// Its difference from the ground truth is the error of GL's footprint (bilinear taps over two
/// levels, a square texel grid) against the box pixel, which no per-texel NDF can remove. For
/// sizes that are not powers of two the texel squares approximate [`crate::pyramid`]'s exact
/// footprints.
pub fn render_oracle(scene: &Scene, map: &NormalMap, samples_per_texel: u32, seed: u64) -> Image {
    render_oracle_footprint(scene, map, samples_per_texel, seed, Footprint::Trilinear)
}

/// [`render_oracle`] under another footprint: [`Footprint::Anisotropic`] averages the ideal
/// trilinear answer of each of the anisotropic probes ([`crate::sample::aniso_probes`]) — the
/// floor of anisotropic filtering; [`Footprint::Manual`] is the trilinear one (the same taps).
pub fn render_oracle_footprint(
    scene: &Scene,
    map: &NormalMap,
    samples_per_texel: u32,
    seed: u64,
    footprint: Footprint,
) -> Image {
    let sizes = crate::pyramid::level_sizes(map.width(), map.height());
    let n = (samples_per_texel.max(1) as f64).sqrt().ceil() as u32;
    let rays = Rays::new(&scene.camera);
    render_rows(scene, seed ^ 0x6F72_6163_6C65, |x, y, rng| {
        let g = pixel_geometry_with(&rays, &scene.surface, x, y)?;
        let ts = TangentSpace::new(&g.hit, scene.camera.eye);
        let frames: Vec<(DVec3, DVec3, f64)> =
            scene.lights.iter().map(|light| ts.light(light)).collect();
        let probes = match footprint {
            Footprint::Anisotropic(max) => {
                let (lambda, offsets) =
                    crate::sample::aniso_probes(g.duv_dx, g.duv_dy, sizes[0], max);
                offsets
                    .into_iter()
                    .map(|o| (g.hit.uv + o, lambda))
                    .collect()
            }
            _ => vec![(g.hit.uv, lod(g.duv_dx, g.duv_dy, sizes[0]))],
        };
        let mut total = 0.0;
        for &(uv, lambda) in &probes {
            let mut sum = 0.0;
            for (level, lw) in crate::sample::level_weights(lambda, sizes.len()) {
                let (tw, th) = sizes[level];
                // Strata per axis: one per finest texel while that is within the budget.
                let n = n.min(1u32 << level.min(31));
                let xs = crate::pyramid::bilinear_taps(uv.x, tw, map.addressing());
                let ys = crate::pyramid::bilinear_taps(uv.y, th, map.addressing());
                for &(ty, wy) in &ys {
                    for &(tx, wx) in &xs {
                        let weight = lw * wx * wy;
                        if weight == 0.0 {
                            continue;
                        }
                        let mut texel = 0.0;
                        for sy in 0..n {
                            for sx in 0..n {
                                let u = (tx as f64 + (sx as f64 + rng.range(0.0, 1.0)) / n as f64)
                                    / tw as f64;
                                let v = (ty as f64 + (sy as f64 + rng.range(0.0, 1.0)) / n as f64)
                                    / th as f64;
                                let normal = nearest_normal(map, DVec2::new(u, v));
                                for &(l, hv, scale) in &frames {
                                    let s = reference_brdf(normal, l, hv, &scene.material.brdf);
                                    texel += scene.material.radiance(scale, s.diffuse, s.specular);
                                }
                            }
                        }
                        sum += weight * texel / (n * n) as f64;
                    }
                }
            }
            total += sum;
        }
        Some((total / probes.len() as f64, 1.0))
    })
}

/// Pixels where both images are fully covered (edge pixels of the ground truth are partly
/// covered, a difference of antialiasing, not of filtering).
pub fn common_mask(a: &Image, b: &Image) -> Vec<bool> {
    a.coverage
        .iter()
        .zip(&b.coverage)
        .map(|(&x, &y)| x >= 1.0 && y >= 1.0)
        .collect()
}

/// Relative RMS error of `test` against `reference` over the pixels of `mask`:
/// `sqrt(Σ (T − R)² / Σ R²)`.
pub fn relative_rmse(reference: &Image, test: &Image, mask: &[bool]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for ((r, t), &m) in reference.pixels.iter().zip(&test.pixels).zip(mask) {
        if m {
            num += (t - r) * (t - r);
            den += r * r;
        }
    }
    crate::eval::relative_rms(num, den)
}

/// The exposure that maps `reference`'s 99th percentile of covered radiance to 0.95 under
/// [`tonemap`] (the same exposure is applied to every render of a view).
pub fn exposure(reference: &Image) -> f64 {
    let mut v: Vec<f64> = reference
        .pixels
        .iter()
        .zip(&reference.coverage)
        .filter(|&(p, &c)| c > 0.0 && p.is_finite())
        .map(|(&p, _)| p)
        .collect();
    if v.is_empty() {
        return 1.0;
    }
    v.sort_by(f64::total_cmp);
    let p99 = v[((v.len() - 1) as f64 * 0.99) as usize];
    if p99 > 0.0 { 3.0 / p99 } else { 1.0 }
}

/// Tone mapping: `1 − e^{−exposure·x}`, then the sRGB transfer curve, as 8-bit grey RGB.
/// Non-finite values show as magenta.
pub fn tonemap(image: &Image, exposure: f64) -> Vec<u8> {
    let mut out = Vec::with_capacity(image.pixels.len() * 3);
    for &p in &image.pixels {
        if !p.is_finite() {
            out.extend_from_slice(&[255, 0, 255]);
            continue;
        }
        let x = 1.0 - (-exposure * p.max(0.0)).exp();
        let s = if x <= 0.003_130_8 {
            12.92 * x
        } else {
            1.055 * x.powf(1.0 / 2.4) - 0.055
        };
        let b = (s.clamp(0.0, 1.0) * 255.0).round() as u8;
        out.extend_from_slice(&[b, b, b]);
    }
    out
}

/// The image's mean radiance over covered pixels (energy check).
pub fn mean_radiance(image: &Image, mask: &[bool]) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for (&p, &m) in image.pixels.iter().zip(mask) {
        if m {
            s += p;
            n += 1;
        }
    }
    if n > 0 { s / n as f64 } else { 0.0 }
}

/// The camera distance at which the level of detail at the image centre is `lambda` for a
/// view tilted `tilt_deg` from the plane's normal, with `texels` texels per texture repeat of
/// world size `tile`, image height `height` and vertical field of view `fov_y_deg` (GL takes the
/// longer axis of the footprint: the one stretched by `1/cos(tilt)`).
pub fn distance_for_lod(
    lambda: f64,
    tilt_deg: f64,
    texels: u32,
    tile: f64,
    height: u32,
    fov_y_deg: f64,
) -> f64 {
    let pixel_angle = 2.0 * (0.5 * fov_y_deg.to_radians()).tan() / height as f64;
    let world_per_pixel = 2f64.powf(lambda) * tile / texels as f64;
    world_per_pixel * tilt_deg.to_radians().cos() / pixel_angle
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::Method;
    use crate::ingest::BadNormals;
    use crate::methods::bake;
    use glam::Vec3;

    fn material() -> Material {
        Material {
            kd: 0.4,
            ks: 0.6,
            brdf: Brdf::BlinnPhong { s: 32.0 },
        }
    }

    fn flat_map() -> NormalMap {
        NormalMap::from_vectors(
            16,
            16,
            vec![Vec3::Z; 256],
            Addressing::Wrap,
            BadNormals::Repair,
        )
        .unwrap()
    }

    fn head_on(lambda: f64, size: u32) -> Scene {
        let (tile, px) = (1.0, 32);
        let d = distance_for_lod(lambda, 0.0, size, tile, px, 30.0);
        Scene {
            name: "head-on".into(),
            camera: Camera {
                eye: DVec3::new(0.0, 0.0, d),
                target: DVec3::ZERO,
                up: DVec3::Y,
                fov_y_deg: 30.0,
                width: px,
                height: px,
            },
            surface: Surface::Plane { tile },
            lights: vec![
                Light::Point {
                    position: DVec3::new(0.1 * d, 0.0, d),
                    intensity: d * d,
                },
                Light::Directional {
                    direction: DVec3::new(0.5, 0.2, 0.8),
                    radiance: 1.0,
                },
            ],
            material: material(),
        }
    }

    #[test]
    fn head_on_plane_has_the_asked_lod_at_the_centre_and_exact_derivatives() {
        for lambda in [0.0, 2.5, 5.0] {
            let scene = head_on(lambda, 64);
            // Pixel (16, 16)'s centre is half a pixel off the axis: λ is within 1e-3.
            let g = pixel_geometry(&scene, 16, 16).unwrap();
            let got = lod(g.duv_dx, g.duv_dy, (64, 64));
            assert!((got - lambda).abs() < 1e-3, "{got} vs {lambda}");
            // Head-on: ∂u/∂x > 0, ∂v/∂y > 0 (image down = world −y = increasing v), no shear.
            assert!(g.duv_dx.x > 0.0 && g.duv_dy.y > 0.0);
            assert!(g.duv_dx.y.abs() < 1e-9 * g.duv_dx.x && g.duv_dy.x.abs() < 1e-9 * g.duv_dy.y);
        }
    }

    #[test]
    fn tangent_frame_follows_the_shader_convention() {
        // Plane: t = +x, b = +y (decreasing v), n = +z.
        let s = Surface::Plane { tile: 2.0 };
        let hit = s.intersect(DVec3::new(0.3, 0.2, 5.0), -DVec3::Z).unwrap();
        let (t, b, n) = hit.frame();
        assert!((t - DVec3::X).length() < 1e-12 && (b - DVec3::Y).length() < 1e-12);
        assert!((n - DVec3::Z).length() < 1e-12);
        assert!((hit.uv - DVec2::new(0.15, -0.1)).length() < 1e-12);
        // Sphere at the equator facing +x: t = +y (φ grows), b = +z (towards θ = 0, v = 0).
        let s = Surface::Sphere {
            center: DVec3::ZERO,
            radius: 1.0,
            tiles_u: 4.0,
            tiles_v: 2.0,
        };
        let hit = s.intersect(DVec3::new(5.0, 0.0, 0.0), -DVec3::X).unwrap();
        let (t, b, n) = hit.frame();
        assert!((t - DVec3::Y).length() < 1e-9 && (b - DVec3::Z).length() < 1e-9);
        assert!((n - DVec3::X).length() < 1e-12 && (hit.t - 4.0).abs() < 1e-12);
        assert!((hit.uv - DVec2::new(0.0, 1.0)).length() < 1e-12);
    }

    #[test]
    fn sphere_uv_derivatives_match_finite_differences() {
        let s = Surface::Sphere {
            center: DVec3::new(0.0, 0.0, 0.0),
            radius: 1.5,
            tiles_u: 8.0,
            tiles_v: 4.0,
        };
        let cam = Camera {
            eye: DVec3::new(0.3, -6.0, 1.0),
            target: DVec3::ZERO,
            up: DVec3::Z,
            fov_y_deg: 35.0,
            width: 400,
            height: 400,
        };
        let scene = Scene {
            name: "s".into(),
            camera: cam,
            surface: s,
            lights: vec![],
            material: material(),
        };
        for (x, y) in [(200, 200), (150, 260), (240, 140)] {
            let g = pixel_geometry(&scene, x, y).unwrap();
            // Finite difference of the actual hits one tenth of a pixel away, scaled to a pixel.
            let uv_at = |fx: f64, fy: f64| {
                let (o, d) = cam.ray(fx, fy);
                s.intersect(o, d).unwrap().uv
            };
            let (cx, cy) = (x as f64 + 0.5, y as f64 + 0.5);
            let fd_x = (uv_at(cx + 0.05, cy) - uv_at(cx - 0.05, cy)) * 10.0;
            let fd_y = (uv_at(cx, cy + 0.05) - uv_at(cx, cy - 0.05)) * 10.0;
            assert!(
                (fd_x - g.duv_dx).length() < 2e-3 * fd_x.length(),
                "{fd_x} {}",
                g.duv_dx
            );
            assert!(
                (fd_y - g.duv_dy).length() < 2e-3 * fd_y.length(),
                "{fd_y} {}",
                g.duv_dy
            );
        }
    }

    #[test]
    fn flat_map_ground_truth_equals_every_filtered_render() {
        // A flat map has no filtering error: the supersampled reference (at full coverage) and
        // each method's filtered render agree up to shading's variation across the pixel
        // (smooth lighting: small) — and exactly at the pixel centre with 1 spp.
        let map = flat_map();
        let scene = head_on(1.5, 16);
        let gt = render_ground_truth(&scene, &map, 64, 7);
        // SH is exact only up to its band limit (its truncation error: docs/sh-brdf.md).
        for method in Method::ALL.into_iter().filter(|&m| m != Method::Sh) {
            let b = bake(&map, method);
            let img = render_filtered(&scene, &b);
            let mask = common_mask(&gt, &img);
            assert!(mask.iter().all(|&m| m));
            let e = relative_rmse(&gt, &img, &mask);
            // The vMF κ cap (s/κ_max) and f32 storage are far below the pixel-integration term.
            assert!(e < 2e-3, "{method}: {e}");
        }
    }

    #[test]
    fn oracle_of_a_flat_map_is_the_filtered_render_and_tends_to_the_footprint_average() {
        let flat = flat_map();
        let scene = head_on(1.5, 16);
        let oracle = render_oracle(&scene, &flat, 4, 3);
        let plain = render_filtered(&scene, &bake(&flat, Method::Plain));
        let mask = common_mask(&oracle, &plain);
        assert!(relative_rmse(&plain, &oracle, &mask) < 1e-12);
        // Bumpy map, Lambert only, a directional light: the tap texels' exact averages are the
        // mean of n·l over their squares, which Olano–North's E[n]·l reproduces exactly when
        // no normal faces away from the light (n·l > 0 everywhere: max() is inactive).
        let bumpy = crate::procedural::generate(16, 9).map;
        let l = DVec3::new(0.1, 0.05, 1.0).normalize();
        assert!(bumpy.normals().iter().all(|n| n.as_dvec3().dot(l) > 0.0));
        let mut scene = head_on(1.5, 16);
        scene.lights = vec![Light::Directional {
            direction: l,
            radiance: 1.0,
        }];
        scene.material = Material {
            kd: 1.0,
            ks: 0.0,
            brdf: Brdf::BlinnPhong { s: 1.0 },
        };
        let oracle = render_oracle(&scene, &bumpy, 1024, 5);
        let olano = render_filtered(&scene, &bake(&bumpy, Method::Olano));
        let mask = common_mask(&oracle, &olano);
        let e = relative_rmse(&olano, &oracle, &mask);
        assert!(e < 2e-3, "{e}");
    }

    #[test]
    fn ground_truth_is_deterministic_across_thread_counts() {
        let map = crate::procedural::generate(16, 3).map;
        let scene = head_on(2.0, 16);
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| render_ground_truth(&scene, &map, 16, 11))
        };
        assert_eq!(run(1), run(3));
    }

    #[test]
    fn ground_truth_converges_to_the_footprint_average_at_a_far_view() {
        // One pixel covering the whole 8×8 map (λ = 3 at the coarsest level) under a
        // directional light, Lambert only: the pixel's value tends to the mean of n·l over the
        // map, the texel-space exact answer. Sub-sample stratification makes the error small.
        let map = crate::procedural::generate(8, 5).map;
        let l = DVec3::new(0.3, -0.2, 0.9).normalize();
        let mean: f64 = map
            .normals()
            .iter()
            .map(|n| n.as_dvec3().dot(l).max(0.0))
            .sum::<f64>()
            / 64.0;
        let d = distance_for_lod(0.0, 0.0, 1, 1.0, 1, 30.0);
        let scene = Scene {
            name: "one".into(),
            camera: Camera {
                eye: DVec3::new(0.5, -0.5, d),
                target: DVec3::new(0.5, -0.5, 0.0),
                up: DVec3::Y,
                fov_y_deg: 30.0,
                width: 1,
                height: 1,
            },
            surface: Surface::Plane { tile: 1.0 },
            lights: vec![Light::Directional {
                direction: l,
                radiance: 1.0,
            }],
            material: Material {
                kd: 1.0,
                ks: 0.0,
                brdf: Brdf::BlinnPhong { s: 1.0 },
            },
        };
        let gt = render_ground_truth(&scene, &map, 4096, 1);
        assert!(
            (gt.pixels[0] - mean).abs() < 0.01 * mean,
            "{} {mean}",
            gt.pixels[0]
        );
    }
}
