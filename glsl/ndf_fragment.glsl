// ndf_fragment.glsl - the fragment stage: light and view in the tangent frame, the level of
// detail, texture sampling (hardware trilinear or manual 8-texel), and the method's shading
// (ndf_shade_texel, from the method file included before this one).
//
// Sampling (Han et al. 2007, Sec 7.3):
//   hardware (default): one trilinear fetch per texture, then one shading - exact for aligned
//     lobes and for the baselines' linear moments;
//   NDF_MANUAL: shade the 4 texels around uv on each of the two nearest levels and blend the
//     results with the trilinear weights - what unaligned lobes need.
//   NDF_ANISO (= the most probes): the anisotropic footprint of GL_EXT_texture_filter_anisotropic's
//     reference rule, done in the shader: N = min(ceil(Pmax/Pmin), NDF_ANISO) trilinear probes at
//     LOD log2(Pmax/N) along the major axis of the pixel's footprint, averaged, then one shading
//     (exact for parameters that filter linearly: SH, aligned lobes, the baselines' moments).
// All use the LOD of ndf_lod() (GL's formula) and GL's LINEAR_MIPMAP_LINEAR rules, so the CPU
// twin (src/sample.rs) can reproduce each bit for bit up to f32 rounding. The BRDF's g factor
// (ndf_g) multiplies the specular term after filtering (it does not depend on the texel).
//
// NDF_PROBE replaces the mesh inputs by uniforms (uv from gl_FragCoord, given LOD, light and half
// vector in tangent space) and writes (diffuse, specular) of one colour channel: what the
// GL-versus-CPU tests compare texel by texel.

layout(location = 0) out vec4 ndf_out;

// Largest MIP level: ndfmap's chains always end at 1x1 (GL's full chain for the base size).
int ndf_max_level() {
    ivec2 size = textureSize(ndf_tex0, 0);
    return int(floor(log2(float(max(size.x, size.y)))));
}

#ifdef NDF_LIGHT_BOTH
// Set by the entry point: the view (tangent frame), the point light's scale (colour x falloff)
// and the environment's (its radiance scale).
vec3 ndf_view = vec3(0.0, 0.0, 1.0);
vec3 ndf_point_scale = vec3(1.0);
vec3 ndf_env_scale = vec3(1.0);
#endif

// The shading of one texel: the method's (ndf_shade_texel) under the point light l with half
// vector h, or with NDF_LIGHT_ENV the environment's (ndf_env.glsl; l then carries the view, h is
// unused, and the g factor is applied per lobe), or with NDF_LIGHT_BOTH both, scaled and summed
// (the point light's g factor applied here: it does not depend on the texel).
void ndf_texel(vec4 t[NDF_TEXTURES], vec3 l, vec3 h, out vec3 diffuse, out vec3 specular) {
#ifdef NDF_LIGHT_ENV
    ndf_env_texel(t, l, diffuse, specular);
#elif defined(NDF_LIGHT_BOTH)
    vec3 de;
    vec3 se;
    ndf_shade_texel(t, l, h, diffuse, specular);
    ndf_env_texel(t, ndf_view, de, se);
    diffuse = ndf_point_scale * diffuse + ndf_env_scale * de;
    specular = ndf_point_scale * specular * ndf_g(l, h) + ndf_env_scale * se;
#else
    ndf_shade_texel(t, l, h, diffuse, specular);
#endif
#ifdef NDF_NO_DIFFUSE
    // K_d = 0: the diffuse term is never used, so the method's Lambert code is dead.
    diffuse = vec3(0.0);
#endif
}

#ifdef NDF_MANUAL
// Texel coordinates wrapped (REPEAT) or clamped (CLAMP_TO_EDGE) like the sampler would.
ivec2 ndf_address(ivec2 q, ivec2 size) {
#ifdef NDF_CLAMP
    return clamp(q, ivec2(0), size - 1);
#else
    return q - size * ivec2(floor(vec2(q) / vec2(size)));
#endif
}

// The shading of the 4 texels around uv on `level`, blended with bilinear weights. Texels of
// zero weight are skipped (the CPU twin skips them too).
void ndf_shade_level(vec2 uv, int level, vec3 l, vec3 h, out vec3 diffuse, out vec3 specular) {
    ivec2 size = textureSize(ndf_tex0, level);
    vec2 p = uv * vec2(size) - 0.5;
    vec2 i0 = floor(p);
    vec2 f = p - i0;
    diffuse = vec3(0.0);
    specular = vec3(0.0);
    for (int k = 0; k < 4; ++k) {
        ivec2 o = ivec2(k & 1, k >> 1);
        float w = (o.x == 1 ? f.x : 1.0 - f.x) * (o.y == 1 ? f.y : 1.0 - f.y);
        if (w == 0.0) continue;
        vec4 t[NDF_TEXTURES];
        ndf_fetch_texel(ndf_address(ivec2(i0) + o, size), level, t);
        vec3 d;
        vec3 s;
        ndf_texel(t, l, h, d, s);
        diffuse += w * d;
        specular += w * s;
    }
}
#endif

#ifdef NDF_ANISO
// The anisotropic sample (module docs; CPU: sample::anisotropic, sample::aniso_probes).
void ndf_fetch_aniso(vec2 uv, vec2 dx, vec2 dy, out vec4 t[NDF_TEXTURES]) {
    vec2 size = vec2(textureSize(ndf_tex0, 0));
    float px = length(dx * size);
    float py = length(dy * size);
    float pmax = max(px, py);
    float pmin = min(px, py);
    float ratio = pmin > 0.0 ? min(pmax / pmin, float(NDF_ANISO)) : float(NDF_ANISO);
    int n = clamp(int(ceil(ratio)), 1, NDF_ANISO);
    float lod = log2(max(pmax / float(n), 1e-15));
    vec2 major = px >= py ? dx : dy;
    for (int k = 0; k < NDF_TEXTURES; ++k) t[k] = vec4(0.0);
    for (int i = 1; i <= NDF_ANISO; ++i) {
        if (i > n) break;
        vec4 p[NDF_TEXTURES];
        ndf_fetch_lod(uv + major * (float(i) / float(n + 1) - 0.5), lod, p);
        for (int k = 0; k < NDF_TEXTURES; ++k) t[k] += p[k];
    }
    for (int k = 0; k < NDF_TEXTURES; ++k) t[k] /= float(n);
}
#endif

// Filtered shading at uv and level of detail lod, for light l and half vector h in tangent
// space: the diffuse (Lambert) and specular terms, per colour channel, without the g factor.
void ndf_shade(vec2 uv, float lod, vec3 l, vec3 h, out vec3 diffuse, out vec3 specular) {
#ifdef NDF_MANUAL
    float lambda = clamp(lod, 0.0, float(ndf_max_level()));
    int level = int(floor(lambda));
    float f = lambda - float(level);
    ndf_shade_level(uv, level, l, h, diffuse, specular);
    if (f > 0.0) {
        vec3 d;
        vec3 s;
        ndf_shade_level(uv, level + 1, l, h, d, s);
        diffuse = (1.0 - f) * diffuse + f * d;
        specular = (1.0 - f) * specular + f * s;
    }
#else
    vec4 t[NDF_TEXTURES];
    ndf_fetch_lod(uv, lod, t);
    ndf_texel(t, l, h, diffuse, specular);
#endif
}

// Filtered shading at uv with the screen derivatives dx, dy of uv (the pixel's footprint),
// times the g factor: the anisotropic sample with NDF_ANISO, else ndf_shade at GL's LOD.
void ndf_shade_footprint(vec2 uv, vec2 dx, vec2 dy, vec3 l, vec3 h, out vec3 diffuse,
                         out vec3 specular) {
#ifdef NDF_ANISO
    vec4 t[NDF_TEXTURES];
    ndf_fetch_aniso(uv, dx, dy, t);
    ndf_texel(t, l, h, diffuse, specular);
#else
    ndf_shade(uv, ndf_lod(dx, dy, vec2(textureSize(ndf_tex0, 0))), l, h, diffuse, specular);
#endif
#if !defined(NDF_LIGHT_ENV) && !defined(NDF_LIGHT_BOTH)
    specular *= ndf_g(l, h);
#endif
}

#ifdef NDF_PROBE
uniform vec2 ndf_probe_size;   // framebuffer size in pixels: uv = gl_FragCoord.xy / size
#ifdef NDF_ANISO
uniform vec2 ndf_probe_dx;     // screen derivatives of uv (the footprint), anisotropic sampling
uniform vec2 ndf_probe_dy;
#else
uniform float ndf_probe_lod;   // level of detail
#endif
#ifdef NDF_LIGHT_ENV
uniform vec3 ndf_probe_v;      // view direction, tangent frame, unit
uniform mat3 ndf_probe_frame;  // tangent -> environment frame; unset (zero): the identity
#else
uniform vec3 ndf_probe_l;      // light direction, tangent space, unit
uniform vec3 ndf_probe_h;      // half vector, tangent space, unit
#ifdef NDF_LIGHT_BOTH
uniform vec3 ndf_probe_v;      // view direction of the environment term, unit
#endif
#endif
uniform int ndf_probe_channel; // colour channel written (0, 1, 2)

void main() {
    vec3 d;
    vec3 s;
    vec2 uv = gl_FragCoord.xy / ndf_probe_size;
#if defined(NDF_LIGHT_ENV)
    if (determinant(ndf_probe_frame) > 0.5) ndf_env_frame = ndf_probe_frame;
#ifdef NDF_ANISO
    ndf_shade_footprint(uv, ndf_probe_dx, ndf_probe_dy, ndf_probe_v, ndf_probe_v, d, s);
#else
    ndf_shade(uv, ndf_probe_lod, ndf_probe_v, ndf_probe_v, d, s);
#endif
#else
#ifdef NDF_LIGHT_BOTH
    ndf_view = ndf_probe_v;
#endif
#ifdef NDF_ANISO
    ndf_shade_footprint(uv, ndf_probe_dx, ndf_probe_dy, ndf_probe_l, ndf_probe_h, d, s);
#else
    ndf_shade(uv, ndf_probe_lod, ndf_probe_l, ndf_probe_h, d, s);
#ifndef NDF_LIGHT_BOTH
    s *= ndf_g(ndf_probe_l, ndf_probe_h);
#endif
#endif
#endif
    int c = ndf_probe_channel;
    ndf_out = vec4(c == 0 ? d.x : (c == 1 ? d.y : d.z), c == 0 ? s.x : (c == 1 ? s.y : s.z),
                   0.0, 1.0);
}
#else
in vec3 ndf_v_position;  // world space
in vec3 ndf_v_normal;    // world space, geometric
in vec4 ndf_v_tangent;   // world space, along +u; w = sign of the bitangent cross(n, t)
in vec2 ndf_v_uv;

uniform vec3 ndf_camera_pos;   // world space
uniform vec4 ndf_light;        // w = 0: direction towards the light; w = 1: point light position
uniform vec3 ndf_light_color;  // radiance scale (point lights fall off with 1/d^2)
#ifndef NDF_NO_DIFFUSE
uniform vec3 ndf_kd;           // K_d
#endif
uniform vec3 ndf_ks;           // K_s
#if defined(NDF_LIGHT_ENV) || defined(NDF_LIGHT_BOTH)
uniform mat3 ndf_env_rotation; // world -> environment frame (a rotation)
#endif
#ifdef NDF_LIGHT_BOTH
uniform vec3 ndf_env_color;    // the environment's radiance scale (with the point light)
#endif

void main() {
    vec3 n = normalize(ndf_v_normal);
    vec3 tg = normalize(ndf_v_tangent.xyz - n * dot(n, ndf_v_tangent.xyz));
    vec3 bt = (ndf_v_tangent.w < 0.0 ? -1.0 : 1.0) * cross(n, tg);
#ifdef NDF_LIGHT_ENV
    // Lit by the environment: ndf_light_color scales its radiance, ndf_light is unused.
    ndf_env_frame = ndf_env_rotation * mat3(tg, bt, n);
    vec3 vw = normalize(ndf_camera_pos - ndf_v_position);
    vec3 v = vec3(dot(vw, tg), dot(vw, bt), dot(vw, n));
    vec3 d;
    vec3 s;
    ndf_shade_footprint(ndf_v_uv, dFdx(ndf_v_uv), dFdy(ndf_v_uv), v, v, d, s);
#ifdef NDF_NO_DIFFUSE
    ndf_out = vec4(ndf_light_color * ndf_ks * s, 1.0);
#else
    ndf_out = vec4(ndf_light_color * (ndf_kd * d + ndf_ks * s), 1.0);
#endif
#else
    vec3 to_light = ndf_light.w == 0.0 ? ndf_light.xyz : ndf_light.xyz - ndf_v_position;
    float falloff = ndf_light.w == 0.0 ? 1.0 : 1.0 / max(dot(to_light, to_light), 1e-12);
    vec3 lw = normalize(to_light);
    vec3 vw = normalize(ndf_camera_pos - ndf_v_position);
    vec3 l = vec3(dot(lw, tg), dot(lw, bt), dot(lw, n));
    vec3 v = vec3(dot(vw, tg), dot(vw, bt), dot(vw, n));
    vec3 h = ndf_normalize_or_z(l + v);
    vec3 d;
    vec3 s;
#ifdef NDF_LIGHT_BOTH
    ndf_env_frame = ndf_env_rotation * mat3(tg, bt, n);
    ndf_view = v;
    ndf_point_scale = ndf_light_color * falloff;
    ndf_env_scale = ndf_env_color;
    ndf_shade_footprint(ndf_v_uv, dFdx(ndf_v_uv), dFdy(ndf_v_uv), l, h, d, s);
#ifdef NDF_NO_DIFFUSE
    ndf_out = vec4(ndf_ks * s, 1.0);
#else
    ndf_out = vec4(ndf_kd * d + ndf_ks * s, 1.0);
#endif
#else
    ndf_shade_footprint(ndf_v_uv, dFdx(ndf_v_uv), dFdy(ndf_v_uv), l, h, d, s);
#ifdef NDF_NO_DIFFUSE
    ndf_out = vec4(ndf_light_color * falloff * ndf_ks * s, 1.0);
#else
    ndf_out = vec4(ndf_light_color * falloff * (ndf_kd * d + ndf_ks * s), 1.0);
#endif
#endif
#endif
}
#endif
