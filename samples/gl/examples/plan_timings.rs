//! Frame time of a plan against the full configuration (issue 18, "Evidence": frame time):
//! for each `PLAN.json MAP` pair (plans from `ndfmap plan`), every part of the plan drawn with
//! its own specialized shader (`Plan::shader_options`) and textures (its format, dropped lobes
//! and colour, from its first level down to the coarsest), and the full configuration (vMF J = 8 aligned, f32, colour —
//! a white albedo where the map has none) drawn with its shader, on the far and grazing plane
//! views of `Scene::standard` (512²). A scene lit only by an environment is drawn by the
//! environment route the plan compiles (`NDF_LIGHT_ENV_PREFILTERED`) under its environment;
//! the full configuration then shades without colour (the environment shaders shade one
//! channel). A scene with both lights draws the parts whose shader is lit by both
//! (`NDF_LIGHT_BOTH`) under the scene's point light and its environment, and the full
//! configuration the same way without colour; everything else by the scene's point light. The material is the scene's sharpest
//! BRDF.
//!
//! Each part's frame is that of a view where every pixel falls in the part's level range: the
//! plan's frame time is bounded by its costliest part's, which is what the table's "plan" row
//! reports against the full configuration's. Draws go round robin over all renderers (3
//! untimed, then `--frames`, default 15), each between two `glFinish` calls or, with
//! `--gpu-clock` (on a GPU), by a `GL_TIME_ELAPSED` query; medians, in one run.
//!
//! `cargo run --release -p ndfmap-gl --example plan_timings [egl|osmesa] [--frames N] [--gpu-clock]
//! [--json FILE] PLAN.json MAP[,ALBEDO] [PLAN.json MAP[,ALBEDO] ...]`
//!
//! `--json FILE` also writes the medians as a frame-times file
//! (`ndfmap::report::planner::FrameTimes`), each scene named by the folder its plan lies in
//! (`ndfmap plan ... -o out/matte-far` gives `matte-far`): `ndfmap report` shows them in its
//! planner section when the file is `plan_frame_times.json` in its working directory (or
//! named by `NDFMAP_PLAN_FRAME_TIMES`).
//!
//! `NDFMAP_SWITCH_FRAG=FILE` draws FILE instead of each plan's generated LOD-switching shader
//! (an edited copy of `lod_switch.frag`, declaring the same samplers): how the switch's cost
//! was bisected (docs/planner.md, "Issue 18: why the LOD switch was slow").

use ndfmap::bake::{Bake, Method};
use ndfmap::glsl::{ShaderLight, ShaderOptions};
use ndfmap::ingest::IngestOptions;
use ndfmap::plan::{FULL, Plan};
use ndfmap::report::planner::{FRAME_TIMES_FORMAT, FrameTime, FrameTimes};
use ndfmap::{NormalMap, methods};
use ndfmap_gl::glow::{self, HasContext};
use ndfmap_gl::texture::BakeTextures;
use ndfmap_gl::{
    BakeRenderer, BrdfBinding, Camera, Clock, EnvTextures, Gl, Lighting, Mesh, Program,
    RenderTarget, Route, Scene, draw_mesh, env_rotation,
};

const SIZE: u32 = 512;
const WARM_UP: usize = 3;

/// The plan's LOD-switching shader (`Plan::lod_switch_shader`) with every switch part's
/// textures (level 0 = the part's first level), drawn like a part's renderer.
struct Switch {
    gl: Gl,
    program: Program,
    textures: Vec<BakeTextures>,
    options: ShaderOptions,
    sh_lmax: Option<usize>,
    binding: BrdfBinding,
}

impl Switch {
    /// Compiles the plan's switch shader over `chains` (per plan part, `bake_chains`' bake);
    /// `Ok(None)` with the reason printed where the plan has none.
    fn new(
        gl: &Gl,
        plan: &Plan,
        chains: &[Bake],
    ) -> Result<Option<Switch>, Box<dyn std::error::Error>> {
        let addressing = chains[0].addressing;
        let fragment = match plan.lod_switch_shader(addressing) {
            // NDFMAP_SWITCH_FRAG names a fragment shader drawn instead of the generated one
            // (to time an edited switch; its samplers must be the generated one's).
            Ok(f) => match std::env::var_os("NDFMAP_SWITCH_FRAG") {
                Some(file) => std::fs::read_to_string(file)?,
                None => f,
            },
            Err(e) => {
                println!("note: no LOD-switching shader: {e}");
                return Ok(None);
            }
        };
        let parts = plan.lod_switch_parts(addressing);
        let options = parts[0].0.options;
        let mut textures = Vec::new();
        let mut sh_lmax = None;
        for (p, members) in &parts {
            let mut bake = chains[members[0]].clone();
            bake.sizes = bake.sizes[p.first..].to_vec();
            for t in &mut bake.textures {
                t.levels = t.levels[p.first..].to_vec();
            }
            if bake.method == Method::Sh {
                sh_lmax = Some(ndfmap::sh::lmax_of(&bake));
            }
            textures.push(BakeTextures::upload(gl, &bake, bake.format)?);
        }
        let vertex = ndfmap::glsl::source(&chains[0], ndfmap::glsl::Stage::Vertex, &options)?;
        Ok(Some(Switch {
            gl: gl.clone(),
            program: Program::new(gl, &vertex, &fragment)?,
            textures,
            options,
            sh_lmax,
            binding: BrdfBinding::default(),
        }))
    }

    /// Draws `mesh` like `BakeRenderer::draw` / `draw_env` (by the environment `env` when
    /// the shader is lit by it).
    fn draw(
        &self,
        mesh: &Mesh,
        camera: &Camera,
        lighting: &Lighting,
        env: Option<&EnvTextures>,
        target: &RenderTarget,
    ) -> Result<(), Box<dyn std::error::Error>> {
        let p = &self.program;
        let mut unit = 0u32;
        for (k, t) in self.textures.iter().enumerate() {
            for i in 0..t.len() {
                // SAFETY: the context is current while `self.gl` lives; the texture lives
                // while `self` does; fewer than 32 units (the switch refuses more).
                unsafe {
                    self.gl.glow().active_texture(glow::TEXTURE0 + unit);
                    self.gl
                        .glow()
                        .bind_texture(glow::TEXTURE_2D, Some(t.raw(i)));
                }
                p.set_i32(&ndfmap::glsl::lod_switch_sampler(k, i), unit as i32);
                unit += 1;
            }
        }
        self.binding.apply(
            &self.gl,
            p,
            &lighting.brdf,
            self.options.brdf,
            self.sh_lmax,
            unit,
        )?;
        if let Some(env) = env.filter(|_| self.options.light.is_env()) {
            env.bind(
                p,
                unit + 1,
                &lighting.brdf,
                ndfmap::envlight::Route::Prefiltered,
            );
            p.set_mat3("ndf_env_rotation", &env_rotation(0.0));
            if self.options.light == ShaderLight::PointAndEnvPrefiltered {
                p.set_vec3("ndf_env_color", lighting.color);
            }
        }
        camera.set_uniforms(p, &glam::Mat4::IDENTITY);
        p.set_vec4("ndf_light", lighting.light);
        p.set_vec3("ndf_light_color", lighting.color);
        p.set_vec3("ndf_kd", lighting.kd);
        p.set_vec3("ndf_ks", lighting.ks);
        draw_mesh(p, mesh, target)?;
        Ok(())
    }
}

/// Milliseconds `draw` takes by `clock` ([`Gl::time_ms`]).
fn timed(
    gl: &Gl,
    clock: Clock,
    draw: impl FnOnce() -> Result<(), Box<dyn std::error::Error>>,
) -> Result<f64, Box<dyn std::error::Error>> {
    let (drawn, ms) = gl.time_ms(clock, draw)?;
    drawn?;
    Ok(ms)
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let route = match args.first().map(String::as_str) {
        Some("osmesa") => {
            args.remove(0);
            Route::OsMesa
        }
        Some("egl") => {
            args.remove(0);
            Route::Egl
        }
        _ => Route::Egl,
    };
    let mut frames = 15usize;
    if let Some(i) = args.iter().position(|a| a == "--frames") {
        frames = args.get(i + 1).ok_or("--frames N")?.parse()?;
        args.drain(i..i + 2);
    }
    let clock = match args.iter().position(|a| a == "--gpu-clock") {
        Some(i) => {
            args.remove(i);
            Clock::Gpu
        }
        None => Clock::Wall,
    };
    let mut json = None;
    if let Some(i) = args.iter().position(|a| a == "--json") {
        json = Some(args.get(i + 1).ok_or("--json FILE")?.clone());
        args.drain(i..i + 2);
    }
    if args.is_empty() || !args.len().is_multiple_of(2) {
        return Err("give PLAN.json MAP pairs".into());
    }
    let gl = Gl::new(route)?;
    println!(
        "{route} ({}), {SIZE}² views, {frames} frames each (medians, ms; {})",
        gl.renderer(),
        clock.describe()
    );
    let target = RenderTarget::new(&gl, SIZE, SIZE)?;
    let views: Vec<Scene> = Scene::standard()
        .into_iter()
        .filter(|s| s.name == "plane-far" || s.name == "plane-grazing")
        .collect();
    let meshes = views
        .iter()
        .map(|s| s.shape.mesh(&gl))
        .collect::<Result<Vec<_>, _>>()?;
    let mut out = FrameTimes {
        format: FRAME_TIMES_FORMAT.into(),
        device: format!("{route} ({})", gl.renderer()),
        frames,
        rows: Vec::new(),
    };
    println!(
        "| plan | view | full ms | plan ms (costliest part) | plan / full | switch ms (/ plan) | \
         parts ms |"
    );
    println!("|---|---|---|---|---|---|---|");
    for pair in args.chunks(2) {
        let text = std::fs::read_to_string(&pair[0])?;
        let name = std::path::Path::new(&pair[0])
            .parent()
            .and_then(|d| d.file_name())
            .map_or_else(|| pair[0].clone(), |d| d.to_string_lossy().into_owned());
        let plan = Plan::from_json(&pair[0], &text)?;
        // MAP or MAP,ALBEDO (the albedo a plan with colour textures was made with).
        let (file, albedo) = match pair[1].split_once(',') {
            Some((m, a)) => (m, Some(a)),
            None => (pair[1].as_str(), None),
        };
        let opts = IngestOptions::default();
        let mut map = NormalMap::load(std::path::Path::new(file), &opts)?;
        if let Some(a) = albedo {
            map = map.with_feature_file(std::path::Path::new(a), &opts)?;
        }
        plan.check_map(&map)?;
        let env_only = plan.shader.environment && !plan.scene.has_direct();
        // Full light: the GPU upload packs the SH route's L′ tables too (envgpu::pack).
        let env = match plan.scene.environment_light(true)? {
            Some(light) if plan.shader.environment => Some(EnvTextures::upload(&gl, &light)?),
            _ => None,
        };
        // Per renderer: whether its shader is lit by the environment (alone or with the
        // point light: drawn by `draw_env`, which binds the environment).
        let mut lit_by_env = Vec::new();
        // The parts, with their specialized shaders; each part's textures hold its first
        // level and every coarser one (a texture whose level 0 is the part's first level, as
        // an engine binds it), so that a view's coarser pixels sample small levels as they
        // do in the full configuration.
        let chains: Vec<Bake> = ndfmap::plan::bake_chains(&plan, &map)?
            .into_iter()
            .map(|(b, _)| b)
            .collect();
        let switch = Switch::new(&gl, &plan, &chains)?;
        let mut renderers = Vec::new();
        for (i, (p, mut bake)) in plan.parts.iter().zip(chains).enumerate() {
            bake.sizes = bake.sizes[p.first..].to_vec();
            for t in &mut bake.textures {
                t.levels = t.levels[p.first..].to_vec();
            }
            let options = plan.shader_options(i);
            lit_by_env.push(options.light.is_env());
            renderers.push(BakeRenderer::new(&gl, &bake, &options)?);
        }
        // The full configuration, with colour (a white albedo where the map has none), lit
        // like the plan (the environment shaders read the colour textures too).
        let full_env = plan.shader_options(0).light.is_env();
        if map.feature().is_none() {
            let n = map.normals().len();
            map = map.with_feature(vec![[1.0; 4]; n])?;
        }
        let full: Bake = methods::bake_with(&map, Method::Vmf, &FULL.bake_options())?;
        let full_options = ShaderOptions {
            color: true,
            light: match (full_env, env_only) {
                (true, true) => ShaderLight::EnvPrefiltered,
                (true, false) => ShaderLight::PointAndEnvPrefiltered,
                _ => ShaderLight::Point,
            },
            ..plan.shader_options(0)
        };
        lit_by_env.push(full_env);
        renderers.push(BakeRenderer::new(&gl, &full, &full_options)?);
        let rotation = env_rotation(0.0);
        for (scene, mesh) in views.iter().zip(&meshes) {
            let mut lighting = scene.lighting.clone();
            lighting.brdf = plan.scene.brdfs()[0].clone();
            let mut times = vec![Vec::new(); renderers.len()];
            let mut switch_times = Vec::new();
            for frame in 0..WARM_UP + frames {
                if let Some(sw) = &switch {
                    target.clear([0.0, 0.0, 0.0, 1.0]);
                    let ms = timed(&gl, clock, || {
                        sw.draw(mesh, &scene.camera, &lighting, env.as_ref(), &target)
                    })?;
                    if frame >= WARM_UP {
                        switch_times.push(ms);
                    }
                }
                for ((r, t), &by_env) in renderers.iter().zip(&mut times).zip(&lit_by_env) {
                    target.clear([0.0, 0.0, 0.0, 1.0]);
                    let ms = timed(&gl, clock, || {
                        match env.as_ref().filter(|_| by_env) {
                            Some(env) => r.draw_env(
                                mesh,
                                &glam::Mat4::IDENTITY,
                                &scene.camera,
                                &lighting,
                                env,
                                &rotation,
                                &target,
                            ),
                            None => r.draw(
                                mesh,
                                &glam::Mat4::IDENTITY,
                                &scene.camera,
                                &lighting,
                                &target,
                            ),
                        }?;
                        Ok(())
                    })?;
                    if frame >= WARM_UP {
                        t.push(ms);
                    }
                }
            }
            let medians: Vec<f64> = times.iter_mut().map(|t| median(t)).collect();
            let (full_ms, part_ms) = medians.split_last().ok_or("no renderer")?;
            let worst = part_ms.iter().copied().fold(0.0, f64::max);
            let switch_ms = (!switch_times.is_empty()).then(|| median(&mut switch_times));
            out.rows.push(FrameTime {
                scene: name.clone(),
                view: scene.name.to_string(),
                full_ms: *full_ms,
                plan_ms: worst,
                parts_ms: part_ms.to_vec(),
                switch_ms,
            });
            println!(
                "| {} | {} | {full_ms:.4} | {worst:.4} | {:.2} | {} | {} |",
                pair[0],
                scene.name,
                worst / full_ms,
                switch_ms.map_or("n/a".into(), |s| format!("{s:.4} ({:.2})", s / worst)),
                part_ms
                    .iter()
                    .map(|m| format!("{m:.4}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
    }
    if let Some(path) = json {
        std::fs::write(&path, out.to_json())?;
        println!("frame times written to {path}");
    }
    Ok(())
}
