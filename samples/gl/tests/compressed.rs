//! Block-compressed KTX2 on GL (issue 19): bakes written with `--compress` (BC7 vMF lobes and
//! colours, BC6H Olano–North and plain textures) are uploaded straight from their KTX2 files
//! (`BakeTextures::upload_ktx2`, `glCompressedTexImage2D`, Mesa decoding the blocks) and
//! shaded by the product shaders (probe variant, signed channels unbiased in the shader); the
//! CPU twin (`ndfmap::sample::shade_at`) shades the bake decoded from **the same blocks** of
//! the same files (`ndfmap::compress::decode_level`, crate `bcdec_rs`), not the uncompressed
//! bake. Compared at the texel centres of every level (exact reads, no filtering), with the
//! tolerance of the uncompressed formats (`tests/shaders.rs`): two independent block decoders
//! (Mesa's and bcdec's) must agree on every texel.
//!
//! A scene (the standard sphere) rendered from the compressed files must also be lit and
//! differ from the uncompressed bake's render: the blocks are sampled, not a fallback.

use glam::DVec2;
use ndfmap::bake::{Bake, BakeOptions, Method};
use ndfmap::brdf::{Brdf, half_vector};
use ndfmap::compress::{Codec, decode_level};
use ndfmap::container::{Container, texture_file};
use ndfmap::eval::default_directions;
use ndfmap::glsl::{Sampling, ShaderBrdf, ShaderOptions, ShaderSpec, Stage, source_for};
use ndfmap::methods::{bake, bake_with};
use ndfmap::sample::{Filtering, shade_at};
use ndfmap_gl::{
    BakeRenderer, BakeTextures, BrdfBinding, Compression, Gl, Program, RenderTarget, Route, Scene,
    draw_fullscreen, read_rgba_f32,
};

/// The KTX2 files of `bake` compressed with `codec`, and the bake the CPU twin shades: every
/// level decoded from those files' blocks, in the codec's shading format.
fn files_and_twin(bake: &Bake, codec: Codec) -> (Vec<Vec<u8>>, Bake) {
    let files: Vec<Vec<u8>> = (0..bake.textures.len())
        .map(|t| texture_file(bake, t, Container::Ktx2, Some(codec)).unwrap())
        .collect();
    let mut twin = bake.clone();
    twin.format = codec.shading_format();
    for (t, file) in files.iter().enumerate() {
        let reader = ktx2::Reader::new(file.as_slice()).unwrap();
        for (k, level) in reader.levels().enumerate() {
            let (w, h) = bake.sizes[k];
            let ranges = bake.textures[t].ranges;
            twin.textures[t].levels[k] = decode_level(level.data, w, h, ranges, codec).unwrap();
        }
    }
    (files, twin)
}

/// The largest error (`|gl − cpu| / (|cpu| + floor)`, as `tests/shaders.rs`) of the probe
/// shader on the compressed textures against the CPU twin, over every level's texel centres,
/// four light/view pairs, diffuse and specular.
fn largest_error(gl: &Gl, bake: &Bake, codec: Codec, brdf: &Brdf) -> f64 {
    let (files, twin) = files_and_twin(bake, codec);
    let slices: Vec<&[u8]> = files.iter().map(Vec::as_slice).collect();
    let textures = BakeTextures::upload_ktx2(gl, &slices, bake.addressing).unwrap();
    assert_eq!(textures.format(), codec.shading_format());
    let options = ShaderOptions {
        brdf: ShaderBrdf::of(brdf),
        sampling: Sampling::Hardware,
        probe: true,
        ..Default::default()
    };
    let spec = ShaderSpec {
        format: textures.format(),
        biased: true,
        ..ShaderSpec::of(bake)
    };
    let vertex = source_for(&spec, Stage::Vertex, &options).unwrap();
    let fragment = source_for(&spec, Stage::Fragment, &options).unwrap();
    let program = Program::new(gl, &vertex, &fragment).unwrap_or_else(|e| panic!("{e}"));
    textures.bind(&program);
    BrdfBinding::default()
        .apply(
            gl,
            &program,
            brdf,
            options.brdf,
            None,
            textures.len() as u32,
        )
        .unwrap();
    let filtering = Filtering::new(brdf.clone());
    let peak = brdf.peak().max(1.0);
    let directions = default_directions();
    let mut worst = 0.0f64;
    for &(l, v) in [directions[0], directions[6], directions[13], directions[22]].iter() {
        let h = half_vector(l, v);
        let floor_s = 1e-3 * peak * brdf.g(l, h).max(1.0);
        program.set_vec3("ndf_probe_l", l.as_vec3());
        program.set_vec3("ndf_probe_h", h.as_vec3());
        program.set_i32("ndf_probe_channel", 0);
        for level in 0..bake.level_count() {
            let (w, hgt) = bake.sizes[level];
            let target = RenderTarget::new(gl, w, hgt).unwrap();
            program.set_vec2("ndf_probe_size", [w as f32, hgt as f32]);
            program.set_f32("ndf_probe_lod", level as f32);
            draw_fullscreen(&program, &target).unwrap();
            for (i, p) in read_rgba_f32(&target).unwrap().iter().enumerate() {
                let (x, y) = (i as u32 % w, i as u32 / w);
                let uv = DVec2::new((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / hgt as f64);
                let cpu = shade_at(&twin, uv, level as f64, l, h, &filtering);
                assert!(p[0].is_finite() && p[1].is_finite());
                let e_d = (p[0] as f64 - cpu.diffuse[0]).abs() / (cpu.diffuse[0].abs() + 1e-3);
                let e_s = (p[1] as f64 - cpu.specular[0]).abs() / (cpu.specular[0].abs() + floor_s);
                worst = worst.max(e_d).max(e_s);
            }
        }
    }
    worst
}

#[test]
fn compressed_ktx2_textures_shade_as_the_cpu_twin_decoding_the_same_blocks() {
    if std::env::var("NDFMAP_SKIP_GL").is_ok_and(|v| v == "1") {
        println!("skipped: NDFMAP_SKIP_GL=1");
        return;
    }
    let gl =
        Gl::new(Route::Egl).unwrap_or_else(|e| panic!("{e}\n(NDFMAP_SKIP_GL=1 skips GL tests)"));
    for c in [Compression::Bc6h, Compression::Bc7] {
        assert!(
            c.is_supported(&gl),
            "{} ({}) lacks {}",
            gl.renderer(),
            gl.version().0,
            c.extension()
        );
    }
    let map = ndfmap::procedural::generate(32, 5).map;
    let vmf = bake_with(
        &map,
        Method::Vmf,
        &BakeOptions {
            lobes: 3,
            align: Some(1.0),
            ..Default::default()
        },
    )
    .unwrap();
    let olano = bake(&map, Method::Olano);
    let plain = bake(&map, Method::Plain);
    // Blinn-Phong s = 64: the tolerance of tests/shaders.rs, 3e-5 + 2e-6 s.
    let brdf = Brdf::BlinnPhong { s: 64.0 };
    let tolerance = 3e-5 + 2e-6 * 64.0;
    let mut failures = Vec::new();
    for (what, b, codec) in [
        ("vmf J=3 aligned", &vmf, Codec::Bc7),
        ("olano", &olano, Codec::Bc6h),
        ("olano", &olano, Codec::Bc7),
        ("plain", &plain, Codec::Bc6h),
    ] {
        let e = largest_error(&gl, b, codec, &brdf);
        println!("{what} {codec}: largest GL-vs-CPU-twin error {e:.2e}");
        if e > tolerance {
            failures.push(format!("{what} {codec}: {e:.2e} > {tolerance:.2e}"));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));

    // A scene from the BC7 files: lit, and not the uncompressed bake's image.
    let files: Vec<Vec<u8>> = (0..vmf.textures.len())
        .map(|t| texture_file(&vmf, t, Container::Ktx2, Some(Codec::Bc7)).unwrap())
        .collect();
    let slices: Vec<&[u8]> = files.iter().map(Vec::as_slice).collect();
    let textures = BakeTextures::upload_ktx2(&gl, &slices, vmf.addressing).unwrap();
    assert_eq!(textures.compression(), Some(Compression::Bc7));
    let mut description = vmf.clone();
    description.format = Codec::Bc7.shading_format();
    let compressed =
        BakeRenderer::with_textures(&gl, &description, textures, &ShaderOptions::default())
            .unwrap();
    let uncompressed = BakeRenderer::new(&gl, &vmf, &ShaderOptions::default()).unwrap();
    let scene = &Scene::standard()[0];
    let a = scene.render(&gl, &compressed, 64).unwrap();
    let u = scene.render(&gl, &uncompressed, 64).unwrap();
    assert!(a.iter().flatten().any(|v| *v > 0.0), "a lit image");
    assert!(a.iter().flatten().all(|v| v.is_finite()));
    assert_ne!(a, u, "the compressed textures are sampled");
}

#[test]
fn bad_compressed_files_are_refused_before_any_texture_is_made() {
    if std::env::var("NDFMAP_SKIP_GL").is_ok_and(|v| v == "1") {
        return;
    }
    let gl =
        Gl::new(Route::Egl).unwrap_or_else(|e| panic!("{e}\n(NDFMAP_SKIP_GL=1 skips GL tests)"));
    let olano = bake(&ndfmap::procedural::generate(16, 2).map, Method::Olano);
    let bc6h = texture_file(&olano, 0, Container::Ktx2, Some(Codec::Bc6h)).unwrap();
    let f32 = texture_file(&olano, 1, Container::Ktx2, None).unwrap();
    // Mixed formats.
    let e = BakeTextures::upload_ktx2(&gl, &[&bc6h, &f32], olano.addressing)
        .err()
        .unwrap();
    assert!(e.to_string().contains("KTX2 file 1"), "{e}");
    // A truncated level: the file is cut inside its data.
    let cut = &bc6h[..bc6h.len() - 16];
    assert!(BakeTextures::upload_ktx2(&gl, &[cut], olano.addressing).is_err());
}
