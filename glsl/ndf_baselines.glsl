// ndf_baselines.glsl - the single-lobe baselines: plain MIP-mapping, Toksvig, LEAN and
// Olano-North (DESIGN.md "Texture layouts"). CPU twin: shade::shade and shade::shade_brdf,
// one arm per method; see src/shade.rs for the derivations.

#if defined(NDF_METHOD_OLANO)
// Olano-North's texels decoded (CPU: shade::olano_moments): E[n], E[nn^T], mu = normalize(E[n])
// with its tangent frame, and the covariance of n projected on that frame (PSD-projected).
void ndf_olano_moments(vec4 t[NDF_TEXTURES], out vec3 m, out mat3 second, out vec3 mu,
                       out vec3 t1, out vec3 t2, out vec3 cov) {
    m = t[0].xyz;
    second = mat3(t[1].x, t[2].x, t[2].y,
                  t[2].x, t[1].y, t[2].z,
                  t[2].y, t[2].z, t[1].z);
    mu = ndf_normalize_or_z(m);
    ndf_tangent_frame(mu, t1, t2);
    cov = ndf_psd(vec3(dot(t1, second * t1), dot(t2, second * t2), dot(t1, second * t2)));
}
#endif

void ndf_shade_texel(vec4 t[NDF_TEXTURES], vec3 l, vec3 h, out vec3 diffuse, out vec3 specular) {
#if defined(NDF_METHOD_PLAIN)
    // The normalized mean normal shaded with the unchanged BRDF.
    vec3 mu = ndf_normalize_or_z(t[0].xyz);
    float d = max(dot(mu, l), 0.0);
#if defined(NDF_BRDF_TORRANCE_SPARROW)
    float spec = ndf_ts_lobe(dot(mu, h), vec2(1.0, 0.0), ndf_sigma, vec3(0.0)) * d;
#elif defined(NDF_BRDF_BLINN_PHONG)
    float spec = ndf_blinn_phong(dot(mu, h), ndf_s) * d;
#else
    float spec = ndf_iso_lobe(mu, 0.0, h) * d;
#endif

#elif defined(NDF_METHOD_TOKSVIG)
    // Toksvig: the mean normal m shortens with variation; with f = |m|,
    // s' = f s / (f + s (1 - f)); diffuse from m itself.
    vec3 m = t[0].xyz;
    float len = length(m);
    vec3 mu = len > 1e-12 ? m / len : vec3(0.0, 0.0, 1.0);
    float ft = min(len, 1.0);
#ifndef NDF_NO_DIFFUSE
    float d = max(dot(m, l), 0.0);
#endif
#ifdef NDF_BRDF_BLINN_PHONG
    float den = ft + ndf_s * (1.0 - ft);
    float s_t = den > 0.0 ? ft * ndf_s / den : 0.0;
    float spec = ndf_blinn_phong(dot(mu, h), s_t) * max(dot(mu, l), 0.0);
#else
    float var = ft > 0.0 ? (1.0 - ft) / ft : 1e6;
    float spec = ndf_iso_lobe(mu, var, h) * max(dot(mu, l), 0.0);
#endif

#elif defined(NDF_METHOD_LEAN)
    // LEAN: mean slope b and slope covariance E[bb^T] - E[b]E[b]^T; the lobe is offset in slope
    // space, d = w_h.xy/w_h.z - b.
    vec2 b = t[0].xy;
    vec3 cov = ndf_psd(vec3(t[0].z - b.x * b.x, t[0].w - b.y * b.y, t[1].x - b.x * b.y));
    vec3 mu = normalize(vec3(b, 1.0));
    float d = max(dot(mu, l), 0.0);
    vec2 dir = h.z > 1e-9 ? h.xy / h.z - b : vec2(0.0);
#if defined(NDF_BRDF_TORRANCE_SPARROW)
    float spec = ndf_ts_lobe(dot(mu, h), dir, ndf_sigma, cov) * d;
#elif defined(NDF_BRDF_BLINN_PHONG)
    float spec = h.z > 1e-9 ? ndf_widened_lobe(dot(mu, h), dir, cov, ndf_s) * d : 0.0;
#elif defined(NDF_BRDF_GGX)
    // S = alpha^2 I + c Sigma in slope space (the GGX form of LEAN's rule), the slope offset
    // along dir with the length tan(theta) of the angle between mu and h: GGX about mu at Sigma = 0.
    vec3 sm = ndf_clamp_eigen(vec3(ndf_alpha * ndf_alpha) * vec3(1.0, 1.0, 0.0) + ndf_ggx_c * cov,
                              0.0, 1.0);
    float c = dot(mu, h);
    float len = length(dir);
    vec2 slope = (len > 1e-30 && c > 0.0) ? dir * (length(cross(mu, h)) / c / len) : vec2(0.0);
    float spec = ndf_ggx_aniso(c, slope, sm) * d;
#else
    // The closest isotropic lobe: the mean per-axis variance.
    float spec = ndf_iso_lobe(mu, 0.5 * (cov.x + cov.y), h) * d;
#endif

#elif defined(NDF_METHOD_OLANO)
    // Olano-North: E[n] and E[nn^T]; the covariance of n projected on mu's tangent plane.
    vec3 m;
    mat3 second;
    vec3 mu;
    vec3 t1;
    vec3 t2;
    vec3 cov;
    ndf_olano_moments(t, m, second, mu, t1, t2, cov);
    vec2 dir = vec2(dot(h, t1), dot(h, t2));
#ifndef NDF_NO_DIFFUSE
    float d = max(dot(m, l), 0.0);
#endif
#if defined(NDF_BRDF_TORRANCE_SPARROW)
    float spec = ndf_ts_lobe(dot(mu, h), dir, ndf_sigma, cov) * max(dot(mu, l), 0.0);
#elif defined(NDF_BRDF_BLINN_PHONG)
    float spec = ndf_widened_lobe(dot(mu, h), dir, cov, ndf_s) * max(dot(mu, l), 0.0);
#elif defined(NDF_BRDF_GGX)
    // S = alpha^2 I + c Sigma with the slope of h in mu's frame.
    float c = dot(mu, h);
    vec3 sm = ndf_clamp_eigen(vec3(ndf_alpha * ndf_alpha) * vec3(1.0, 1.0, 0.0) + ndf_ggx_c * cov,
                              0.0, 1.0);
    float spec = c > 0.0 ? ndf_ggx_aniso(c, dir / c, sm) * max(dot(mu, l), 0.0) : 0.0;
#else
    float spec = ndf_iso_lobe(mu, 0.5 * (cov.x + cov.y), h) * max(dot(mu, l), 0.0);
#endif
#endif
#ifndef NDF_NO_DIFFUSE
    diffuse = vec3(d);
#else
    diffuse = vec3(0.0);
#endif
    specular = vec3(spec);
}
