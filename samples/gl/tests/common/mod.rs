//! The render checks every route runs; `tests/egl.rs` and `tests/osmesa.rs` instantiate them
//! with [`route_tests!`], one test binary (process) per route.
//!
//! A route that gives no context fails its tests with the error text, unless `NDFMAP_SKIP_GL=1`
//! (then each test prints "skipped" and passes).

use glam::{Mat4, Vec3, Vec4};
use ndfmap::bake::{Bake, BakeOptions, Method};
use ndfmap::format::Format;
use ndfmap::ingest::Addressing;
use ndfmap::methods::{bake, bake_with};
use ndfmap::pack::{pack_level, packed_len};
use ndfmap_gl::texture::sampler_name;
use ndfmap_gl::{
    Accumulator, BakeTextures, Camera, Destination, Error, Gl, Layer, Mesh, Presenter, Program,
    RenderTarget, Route, draw_fullscreen, draw_mesh, read_rgba_f32,
};
use std::time::Instant;

/// Defines one `#[test]` per check for `$route`, each calling the function of the same name.
macro_rules! route_tests {
    ($route:expr) => {
        common::route_tests!(
            $route;
            context_is_3_3_core_and_released,
            upload_reads_back_exactly_in_every_format,
            trilinear_matches_the_cpu_filter,
            sphere_covers_the_middle_front_faces_win,
            plane_attributes_and_orientation,
            uniforms_set_by_name_and_errors_carry_logs,
            presenter_tone_maps_like_the_cpu_and_splits
        );
    };
    ($route:expr; $($check:ident),+) => {
        $(
            #[test]
            fn $check() {
                common::$check($route);
            }
        )+
    };
}
pub(crate) use route_tests;

/// A context by `route`, or `None` (after printing "skipped") when `NDFMAP_SKIP_GL=1`.
/// Panics with the error text when the route gives no context.
fn context(route: Route) -> Option<Gl> {
    if std::env::var("NDFMAP_SKIP_GL").is_ok_and(|v| v == "1") {
        println!("skipped: NDFMAP_SKIP_GL=1");
        return None;
    }
    match Gl::new(route) {
        Ok(gl) => Some(gl),
        Err(e) => panic!("{e}\n(set NDFMAP_SKIP_GL=1 to skip the GL tests)"),
    }
}

pub fn context_is_3_3_core_and_released(route: Route) {
    let start = Instant::now();
    let Some(gl) = context(route) else { return };
    let created = start.elapsed();
    println!(
        "{route}: OpenGL {:?} core={} renderer '{}' created in {created:.1?}",
        gl.version(),
        gl.is_core(),
        gl.renderer()
    );
    assert!(gl.version() >= (3, 3) && gl.is_core());
    assert_eq!(gl.route(), route);
    assert!(matches!(Gl::new(route), Err(Error::ContextOnThread)));
    // A GL object keeps the context alive after the last `Gl` handle goes.
    let target = RenderTarget::new(&gl, 2, 2).unwrap();
    drop(gl);
    assert_eq!(read_rgba_f32(&target).unwrap(), vec![[0.0; 4]; 4]);
    drop(target);
    // Released: the thread can create contexts again, repeatedly.
    for _ in 0..3 {
        let gl = Gl::new(route).unwrap();
        gl.check_error("re-creation").unwrap();
    }
}

/// Maps `gl_FragCoord` to the texel centres of level `ndf_level` of texture `index`.
fn texel_centre_program(gl: &Gl, index: usize) -> Program {
    let s = sampler_name(index);
    let fragment = format!(
        "#version 330 core
uniform sampler2D {s};
uniform float ndf_level;
out vec4 color;
void main() {{
    vec2 size = vec2(textureSize({s}, int(ndf_level)));
    color = textureLod({s}, gl_FragCoord.xy / size, ndf_level);
}}
"
    );
    Program::fullscreen(gl, &fragment).unwrap()
}

/// The values the GPU holds for `texture`, level `level` of `bake` in `format`, decoded from the
/// bytes `pack_level` gives (unorm: the normalized code, biased for signed channels).
fn held_values(bake: &Bake, texture: usize, level: usize, format: Format) -> Vec<[f32; 4]> {
    let mut bytes = vec![0u8; packed_len(bake, level, format)];
    pack_level(bake, texture, level, format, &mut bytes).unwrap();
    let cb = format.channel_bytes();
    let channel = |c: &[u8]| match format {
        Format::F32 => f32::from_ne_bytes(c.try_into().unwrap()),
        Format::F16 => half::f16::from_ne_bytes(c.try_into().unwrap()).to_f32(),
        Format::Unorm16 => u16::from_ne_bytes(c.try_into().unwrap()) as f32 / 65535.0,
        Format::Unorm8 => c[0] as f32 / 255.0,
    };
    bytes
        .chunks_exact(4 * cb)
        .map(|t| std::array::from_fn(|i| channel(&t[i * cb..(i + 1) * cb])))
        .collect()
}

/// Distance in units in the last place between two finite f32 of the same sign (or zeros).
fn ulps(a: f32, b: f32) -> u32 {
    if a == b {
        0
    } else {
        (a.to_bits() as i64 - b.to_bits() as i64).unsigned_abs() as u32
    }
}

/// The bakes the upload checks use: a `size²` procedural map with its albedo as a feature,
/// baked as Toksvig, two-lobe vMF (lobes + colour textures) and LEAN (unbounded channels,
/// float formats only).
fn sample_bakes(size: u32) -> Vec<Bake> {
    let sample = ndfmap::procedural::generate(size, 7);
    let map = sample.map.with_feature(sample.albedo).unwrap();
    let options = BakeOptions {
        lobes: 2,
        ..Default::default()
    };
    vec![
        bake(&map, Method::Toksvig),
        bake_with(&map, Method::Vmf, &options).unwrap(),
        bake(&map, Method::Lean),
    ]
}

/// Every level of every texture, uploaded in every format the bake fits (the others must be
/// refused), sampled with `textureLod` at its texel centres into a target of the level's size,
/// reads back as the values decoded from the packed bytes, in the bake's row order.
///
/// Measured on llvmpipe (both routes), and asserted:
/// - 32² map (levels 32 … 1, texel centres exact in f32): f32 and f16 are bit-exact, except
///   that f32 subnormals (tiny vMF weights occur) read as 0, the GPU flushing denormals;
///   unorm16 and unorm8 are within 1 ULP of `code / (2ⁿ − 1)` (the driver does not divide
///   with correct rounding).
/// - 37² map (levels 37, 18, 9, 4, 2, 1): `gl_FragCoord.xy / size` is not exactly a texel
///   centre in f32, so the filter mixes in a neighbour with a weight of about 1e-6; measured
///   error ≤ 2.4e-6 of the level's largest magnitude (f32, f16; unorm16 1.2e-6, unorm8, whose
///   8-bit weights round the stray weight to 0, 7.8e-8), asserted ≤ 4e-6 of it.
pub fn upload_reads_back_exactly_in_every_format(route: Route) {
    /// Allowed error on the odd-sized map, as a fraction of the level's value range.
    const ODD_TOLERANCE: f32 = 4e-6;
    let Some(gl) = context(route) else { return };
    for size in [32, 37] {
        let bakes = sample_bakes(size);
        let max_textures = bakes.iter().map(|b| b.textures.len()).max().unwrap();
        let programs: Vec<Program> = (0..max_textures)
            .map(|i| texel_centre_program(&gl, i))
            .collect();
        for b in &bakes {
            for format in Format::ALL {
                let fits = (0..b.textures.len()).all(|t| ndfmap::pack::check(b, t, format).is_ok());
                let uploaded = BakeTextures::upload(&gl, b, format);
                if !fits {
                    assert!(
                        matches!(uploaded, Err(Error::Pack(_))),
                        "{} {format}",
                        b.label()
                    );
                    continue;
                }
                let textures = uploaded.unwrap();
                assert_eq!(textures.len(), b.textures.len());
                let (mut worst_ulps, mut worst_range) = (0, 0.0f32);
                for (t, program) in programs.iter().enumerate().take(b.textures.len()) {
                    textures.bind(program);
                    for (level, &(w, h)) in b.sizes.iter().enumerate() {
                        let target = RenderTarget::new(&gl, w, h).unwrap();
                        program.set_f32("ndf_level", level as f32);
                        draw_fullscreen(program, &target).unwrap();
                        let got = read_rgba_f32(&target).unwrap();
                        let want = held_values(b, t, level, format);
                        let largest = want.iter().flatten().fold(0.0f32, |m, v| m.max(v.abs()));
                        for (i, (g, e)) in got.iter().zip(&want).enumerate() {
                            for c in 0..4 {
                                let e = if e[c].is_subnormal() { 0.0 } else { e[c] };
                                let rel = (g[c] - e).abs() / largest.max(f32::MIN_POSITIVE);
                                let d = ulps(g[c], e);
                                worst_ulps = worst_ulps.max(d);
                                worst_range = worst_range.max(rel);
                                let ok = match (size, format) {
                                    (37, _) => rel <= ODD_TOLERANCE,
                                    (_, Format::F32 | Format::F16) => d == 0,
                                    _ => d <= 1,
                                };
                                assert!(
                                    ok,
                                    "{route} {size}² {} {format} texture {t} level {level} \
                                     texel ({}, {}) channel {c}: GPU {} CPU {e}",
                                    b.label(),
                                    i % w as usize,
                                    i / w as usize,
                                    g[c],
                                );
                            }
                        }
                    }
                }
                let ulps = if size == 32 {
                    format!("{worst_ulps} ULP, ")
                } else {
                    String::new()
                };
                println!(
                    "{route} {size}² {} {format}: worst {ulps}{worst_range:.1e} of the largest \
                     value of the level",
                    b.label()
                );
            }
        }
    }
}

/// GL 3.3 §3.8.11 bilinear filtering of one level (`texels` row-major, `w × h`) at `uv`.
fn bilinear(texels: &[[f32; 4]], (w, h): (u32, u32), uv: [f32; 2], wrap: Addressing) -> Vec4 {
    let axis = |u: f32, n: u32| {
        let x = u as f64 * n as f64 - 0.5;
        let i0 = x.floor() as i64;
        let fix = |i: i64| match wrap {
            Addressing::Wrap => i.rem_euclid(n as i64) as usize,
            Addressing::Clamp => i.clamp(0, n as i64 - 1) as usize,
        };
        (fix(i0), fix(i0 + 1), (x - x.floor()) as f32)
    };
    let (x0, x1, a) = axis(uv[0], w);
    let (y0, y1, b) = axis(uv[1], h);
    let at = |x: usize, y: usize| Vec4::from(texels[y * w as usize + x]);
    (1.0 - a) * (1.0 - b) * at(x0, y0)
        + a * (1.0 - b) * at(x1, y0)
        + (1.0 - a) * b * at(x0, y1)
        + a * b * at(x1, y1)
}

/// GL 3.3 trilinear (`LINEAR_MIPMAP_LINEAR`) at level of detail `lod`: bilinear on levels
/// ⌊λ⌋ and ⌊λ⌋ + 1 (clamped to the last level) blended by the fraction of λ; λ ≤ 0 is the
/// magnification filter (bilinear on level 0).
fn trilinear(
    levels: &[Vec<[f32; 4]>],
    sizes: &[(u32, u32)],
    uv: [f32; 2],
    lod: f32,
    wrap: Addressing,
) -> Vec4 {
    let last = sizes.len() - 1;
    let sample = |k: usize| bilinear(&levels[k], sizes[k], uv, wrap);
    if lod <= 0.0 {
        return sample(0);
    }
    if lod >= last as f32 {
        return sample(last);
    }
    let k = lod.floor() as usize;
    let f = lod - lod.floor();
    (1.0 - f) * sample(k) + f * sample(k + 1)
}

/// Texture coordinates of pixel (x, y): multiples of 3/64 from −0.25, so the GPU's and this
/// test's f32 arithmetic agree exactly, off texel centres, and past both edges.
const UV_STEP: f32 = 0.046875;
const UV_START: f32 = -0.25;

/// `textureLod` at fractional λ and off-centre uv (past the edges too), both addressing modes,
/// every format, compared with [`trilinear`] on the values the GPU holds. The error is measured
/// as a fraction of the spread (largest − smallest value) of the texture's values.
///
/// Measured on llvmpipe (both routes): f32, f16 and unorm16 textures filter in f32, worst
/// 2.0e-7 of the spread (f32 rounding); unorm8 textures take an 8-bit fixed-point path (8-bit
/// weights, 8-bit results), worst 6.2e-3 = 1.58/256 of the spread. Asserted: 1e-6 and 2/256.
pub fn trilinear_matches_the_cpu_filter(route: Route) {
    /// Allowed error as a fraction of the spread of the texture's values.
    fn tolerance(format: Format) -> f32 {
        match format {
            Format::Unorm8 => 2.0 / 256.0,
            _ => 1e-6,
        }
    }
    let Some(gl) = context(route) else { return };
    let sample = ndfmap::procedural::generate(37, 11);
    let fragment = "#version 330 core
uniform sampler2D ndf_tex0;
uniform float ndf_lod;
out vec4 color;
void main() {
    vec2 uv = (gl_FragCoord.xy - 0.5) * 0.046875 - 0.25;
    color = textureLod(ndf_tex0, uv, ndf_lod);
}
";
    let program = Program::fullscreen(&gl, fragment).unwrap();
    let target = RenderTarget::new(&gl, 33, 29).unwrap();
    let mut worst = [0.0f32; 4];
    for wrap in [Addressing::Wrap, Addressing::Clamp] {
        let mut map = sample.map.clone();
        map.set_addressing(wrap);
        let b = bake(&map, Method::Toksvig);
        for (f, format) in Format::ALL.into_iter().enumerate() {
            let textures = BakeTextures::upload(&gl, &b, format).unwrap();
            textures.bind(&program);
            let levels: Vec<_> = (0..b.level_count())
                .map(|k| held_values(&b, 0, k, format))
                .collect();
            let (lo, hi) = levels.iter().flatten().fold(
                (Vec4::splat(f32::MAX), Vec4::splat(f32::MIN)),
                |(lo, hi), v| (lo.min(Vec4::from(*v)), hi.max(Vec4::from(*v))),
            );
            let spread = (hi - lo).max_element();
            for lod in [0.0, 0.4, 1.3, 2.75, 4.5, 9.0] {
                program.set_f32("ndf_lod", lod);
                draw_fullscreen(&program, &target).unwrap();
                let got = read_rgba_f32(&target).unwrap();
                let (w, _) = target.size();
                for (i, g) in got.iter().enumerate() {
                    let (x, y) = (i % w as usize, i / w as usize);
                    let uv = [x as f32 * UV_STEP + UV_START, y as f32 * UV_STEP + UV_START];
                    let want = trilinear(&levels, &b.sizes, uv, lod, wrap);
                    let err = (Vec4::from(*g) - want).abs().max_element() / spread;
                    worst[f] = worst[f].max(err);
                    assert!(
                        err <= tolerance(format),
                        "{route} {wrap:?} {format} λ {lod} uv {uv:?}: GPU {g:?} CPU {want}"
                    );
                }
            }
        }
    }
    for (format, w) in Format::ALL.into_iter().zip(worst) {
        println!("{route}: trilinear {format} worst error {w:.1e} of the spread");
    }
}

const MESH_VERTEX: &str = "#version 330 core
layout(location = 0) in vec3 ndf_position;
layout(location = 1) in vec3 ndf_normal;
layout(location = 2) in vec4 ndf_tangent;
layout(location = 3) in vec2 ndf_uv;
uniform mat4 ndf_model;
uniform mat4 ndf_view_proj;
out vec3 normal;
out vec4 tangent;
out vec2 uv;
void main() {
    normal = mat3(ndf_model) * ndf_normal;
    tangent = ndf_tangent;
    uv = ndf_uv;
    gl_Position = ndf_view_proj * ndf_model * vec4(ndf_position, 1.0);
}
";

/// `mesh` drawn with [`MESH_VERTEX`] and `fragment` through `camera` (identity model) into a
/// cleared `n × n` target, read back.
fn mesh_image(gl: &Gl, mesh: &Mesh, fragment: &str, camera: &Camera, n: u32) -> Vec<[f32; 4]> {
    let program = Program::new(gl, MESH_VERTEX, fragment).unwrap();
    camera.set_uniforms(&program, &Mat4::IDENTITY);
    let target = RenderTarget::new(gl, n, n).unwrap();
    target.clear([0.0; 4]);
    draw_mesh(&program, mesh, &target).unwrap();
    read_rgba_f32(&target).unwrap()
}

/// A unit sphere 3 units from a 45° camera covers a disc of the predicted radius; the middle
/// shows the front (normal towards the camera) and the top of the disc the north pole.
pub fn sphere_covers_the_middle_front_faces_win(route: Route) {
    let Some(gl) = context(route) else { return };
    let fragment = "#version 330 core
in vec3 normal;
out vec4 color;
void main() { color = vec4(normalize(normal), 1.0); }
";
    let camera = Camera::default();
    let n = 64;
    let mesh = Mesh::sphere(&gl, 1.0, 64, 32).unwrap();
    let px = mesh_image(&gl, &mesh, fragment, &camera, n);
    let at = |x: u32, y: u32| Vec4::from(px[(y * n + x) as usize]);
    let centre = at(n / 2, n / 2);
    assert!(centre.w == 1.0 && centre.z > 0.99, "centre {centre}");
    for (x, y) in [(0, 0), (n - 1, 0), (0, n - 1), (n - 1, n - 1)] {
        assert_eq!(at(x, y), Vec4::ZERO, "corner ({x}, {y})");
    }
    // Row n − 1 is the top of the image (read-back rows go up): the north side.
    assert!(at(n / 2, n / 2 + 20).y > 0.5 && at(n / 2, n / 2 - 20).y < -0.5);
    let covered = px.iter().filter(|p| p[3] == 1.0).count() as f32 / (n * n) as f32;
    let angular = (1.0f32 / camera.distance).asin();
    let radius = angular.tan() / (0.5 * camera.fov_y).tan() * 0.5 * n as f32;
    let predicted = std::f32::consts::PI * radius * radius / (n * n) as f32;
    println!("{route}: sphere covers {covered:.4} of the image, disc predicts {predicted:.4}");
    assert!(
        (covered - predicted).abs() < 0.02,
        "{covered} vs {predicted}"
    );
}

/// A plane seen from straight above: tangent and normal arrive as given, u grows to the right,
/// v grows down the image (bake row 0 at the top), so attributes 1–3 reach their locations.
pub fn plane_attributes_and_orientation(route: Route) {
    let Some(gl) = context(route) else { return };
    let fragment = "#version 330 core
in vec3 normal;
in vec4 tangent;
in vec2 uv;
layout(location = 0) out vec4 color;
void main() {
    bool frame = all(lessThan(abs(tangent - vec4(1.0, 0.0, 0.0, 1.0)), vec4(1e-5)))
        && all(lessThan(abs(normal - vec3(0.0, 1.0, 0.0)), vec3(1e-5)));
    color = vec4(uv, frame ? 1.0 : 0.5, 1.0);
}
";
    let mut camera = Camera::default();
    camera.orbit(0.0, std::f32::consts::FRAC_PI_2);
    let n = 32;
    let mesh = Mesh::plane(&gl, 2.0, 1.0).unwrap();
    let px = mesh_image(&gl, &mesh, fragment, &camera, n);
    let at = |x: u32, y: u32| Vec4::from(px[(y * n + x) as usize]);
    assert!(
        px.iter().all(|p| p[3] == 0.0 || p[2] == 1.0),
        "tangent or normal"
    );
    let (mid, top, bottom, left, right) = (n / 2, n / 2 + 8, n / 2 - 8, n / 2 - 8, n / 2 + 8);
    assert!(at(mid, top).y < at(mid, mid).y && at(mid, mid).y < at(mid, bottom).y);
    assert!(at(left, mid).x < at(mid, mid).x && at(mid, mid).x < at(right, mid).x);
    let c = at(mid, mid);
    assert!(
        (c.x - 0.5).abs() < 0.05 && (c.y - 0.5).abs() < 0.05,
        "centre uv {c}"
    );
}

/// Uniform setters of every type by name (absent names ignored); compile and link errors
/// return the driver's log.
pub fn uniforms_set_by_name_and_errors_carry_logs(route: Route) {
    let Some(gl) = context(route) else { return };
    let fragment = "#version 330 core
uniform float a;
uniform vec2 b;
uniform vec3 c;
uniform vec4 d;
uniform int e;
uniform mat4 m;
out vec4 color;
void main() { color = vec4(a, b.y, c.z, float(e)) + m * d; }
";
    let program = Program::fullscreen(&gl, fragment).unwrap();
    program.set_f32("a", 1.0);
    program.set_vec2("b", [0.0, 2.0]);
    program.set_vec3("c", Vec3::new(0.0, 0.0, 3.0));
    program.set_vec4("d", [1.0, 0.0, 0.0, 0.0]);
    program.set_i32("e", 4);
    let m = Mat4::from_cols_array(&std::array::from_fn(|i| i as f32 * 10.0));
    program.set_mat4("m", &m);
    program.set_f32("not_in_the_program", 9.0);
    let target = RenderTarget::new(&gl, 1, 1).unwrap();
    draw_fullscreen(&program, &target).unwrap();
    // m · (1, 0, 0, 0) is m's first column: 0, 10, 20, 30.
    assert_eq!(
        read_rgba_f32(&target).unwrap(),
        vec![[1.0, 12.0, 23.0, 34.0]]
    );

    let bad = "#version 330 core\nout vec4 color;\nvoid main() { color = undefined_name; }\n";
    match Program::fullscreen(&gl, bad) {
        Err(Error::Compile { stage, log }) => {
            assert_eq!(stage, "fragment");
            assert!(log.contains("undefined_name"), "{log}");
        }
        other => panic!("expected a compile error, got {:?}", other.err()),
    }
    let unlinked =
        "#version 330 core\nvec4 missing();\nout vec4 color;\nvoid main() { color = missing(); }\n";
    assert!(matches!(
        Program::fullscreen(&gl, unlinked),
        Err(Error::Link { log }) if !log.is_empty()
    ));
    gl.check_error("after the failed builds").unwrap();
}

/// Fills `target` with a ramp of linear radiance over x and y, times `scale` (negative in a
/// corner, up to a few units), so the tone map is checked over its whole range.
fn ramp(gl: &Gl, target: &RenderTarget, scale: f32) {
    let program = Program::fullscreen(
        gl,
        "#version 330 core
uniform float scale;
out vec4 color;
void main() {
    vec2 p = floor(gl_FragCoord.xy);
    color = vec4(scale * p.x * 0.05, scale * p.y * 0.3, scale * (p.x + p.y) * 0.01 - 0.1, 1.0);
}
",
    )
    .unwrap();
    program.set_f32("scale", scale);
    draw_fullscreen(&program, target).unwrap();
}

/// The presentation pass tone-maps like `ndfmap_gl::tone_map` (the GLSL and CPU twins agree
/// to float rounding), scales each layer, splits at the given column with a white line left of
/// it, and writes the window's default framebuffer or a target alike; the accumulator's mean
/// of passes is their average.
pub fn presenter_tone_maps_like_the_cpu_and_splits(route: Route) {
    let Some(gl) = context(route) else { return };
    let (w, h) = (40, 8);
    let (left, right, out) = (
        RenderTarget::new(&gl, w, h).unwrap(),
        RenderTarget::new(&gl, w, h).unwrap(),
        RenderTarget::new(&gl, w, h).unwrap(),
    );
    ramp(&gl, &left, 1.0);
    ramp(&gl, &right, 3.0);
    let presenter = Presenter::new(&gl).unwrap();
    let layer = |image, scale| Layer { image, scale };
    presenter
        .draw(layer(&left, 2.0), None, Destination::Target(&out))
        .unwrap();
    let (linear, shown) = (read_rgba_f32(&left).unwrap(), read_rgba_f32(&out).unwrap());
    let mut worst = 0.0f32;
    for (l, s) in linear.iter().zip(&shown) {
        for c in 0..3 {
            worst = worst.max((ndfmap_gl::tone_map(2.0 * l[c]) - s[c]).abs());
        }
    }
    println!("{route}: GLSL vs CPU tone map, worst difference {worst:.2e}");
    assert!(worst < 2e-6, "GLSL and CPU tone maps differ by {worst}");

    let split = 17;
    presenter
        .draw(
            layer(&left, 1.0),
            Some((layer(&right, 0.5), split)),
            Destination::Target(&out),
        )
        .unwrap();
    let (right_linear, shown) = (read_rgba_f32(&right).unwrap(), read_rgba_f32(&out).unwrap());
    for y in 0..h as usize {
        for x in 0..w as usize {
            let i = y * w as usize + x;
            let want: [f32; 3] = match x as u32 {
                x if x + 1 < split => std::array::from_fn(|c| ndfmap_gl::tone_map(linear[i][c])),
                x if x + 1 == split => [ndfmap_gl::tone_map(1e6); 3],
                _ => std::array::from_fn(|c| ndfmap_gl::tone_map(0.5 * right_linear[i][c])),
            };
            for c in 0..3 {
                assert!((shown[i][c] - want[c]).abs() < 2e-6, "pixel ({x}, {y})");
            }
        }
    }

    let mut sum = Accumulator::new(&gl, w, h).unwrap();
    assert_eq!(sum.mean().scale, 0.0);
    for scale in [1.0, 2.0, 6.0] {
        sum.add_pass(|t| {
            ramp(&gl, t, scale);
            Ok(())
        })
        .unwrap();
    }
    assert_eq!(sum.passes(), 3);
    presenter
        .draw(sum.mean(), None, Destination::Target(&out))
        .unwrap();
    let shown = read_rgba_f32(&out).unwrap();
    for (i, s) in shown.iter().enumerate() {
        for c in 0..3 {
            // The mean of scales 1, 2, 6 is 3: the right image.
            let want = ndfmap_gl::tone_map(right_linear[i][c]);
            assert!((s[c] - want).abs() < 2e-6, "accumulated pixel {i}");
        }
    }
    sum.reset();
    assert_eq!(sum.passes(), 0);
    gl.check_error("presentation").unwrap();
}
