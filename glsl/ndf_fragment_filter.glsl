
// The shading of one texel: the method's (ndf_shade_texel) under the point light l with half
// vector h, or with NDF_LIGHT_ENV the environment's (ndf_env.glsl; l then carries the view, h is
// unused, and the g factor is applied per lobe), or with NDF_LIGHT_BOTH both, scaled and summed
// (the point light's g factor applied here: it does not depend on the texel). With
// NDF_ENV_LIGHTS the environment's extracted lights (ndf_env_lights) are added to its part.
void ndf_texel(vec4 t[NDF_TEXTURES], vec3 l, vec3 h, out vec3 diffuse, out vec3 specular) {
#ifdef NDF_LIGHT_ENV
    ndf_env_texel(t, l, diffuse, specular);
#ifdef NDF_ENV_LIGHTS
    ndf_env_lights(t, l, diffuse, specular);
#endif
#elif defined(NDF_LIGHT_BOTH)
    vec3 de;
    vec3 se;
    ndf_shade_texel(t, l, h, diffuse, specular);
    ndf_env_texel(t, ndf_view, de, se);
#ifdef NDF_ENV_LIGHTS
    ndf_env_lights(t, ndf_view, de, se);
#endif
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

