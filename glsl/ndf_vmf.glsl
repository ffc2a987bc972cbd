// ndf_vmf.glsl - the vMF lobe shader of Han et al. 2007, Algorithm 2 (lines 5-14).
//
// Texture j < NDF_LOBES holds lobe j as theta = (alpha, alpha*r) (DESIGN.md "Texture
// layouts"); with NDF_COLOR, texture NDF_LOBES + j holds alpha*y. Per lobe (CPU twin:
// shade::vmf_lobe, shade::shade_rgb):
//   lines 7-8    alpha = theta.x, r = theta.yzw / alpha
//                (guard: alpha <= 0, an empty or quantized-away lobe, contributes nothing)
//   line 9       kappa = (3|r| - |r|^3) / (1 - |r|^2), |r| clamped to NDF_R_MAX (the format's)
//   line 10      mu = normalize(r)   (r = 0: the uniform lobe, kappa = 0, mu = +Z)
//   lines 12-13  s' = kappa*s / (kappa + s), B = (s' + 1)/(2 pi) (w_h . mu)^s'     (eq 20)
//                Torrance-Sparrow: the eq 18 lobe with sigma'^2 = sigma^2 + 1/(2 kappa) (eq 21)
//   line 14      rho += alpha*y (K_s B + K_d)(w_i . mu); the K_d and K_s terms are returned apart.

// Decodes one lobe texel: false for an empty lobe.
bool ndf_vmf_decode(vec4 theta, out float alpha, out vec3 mu, out float kappa) {
    alpha = theta.x;
    mu = vec3(0.0, 0.0, 1.0);
    kappa = 0.0;
    if (!(alpha > 0.0)) return false;
    vec3 r = theta.yzw / alpha;
    float len = length(r);
    if (len > 0.0 && len < 1e30) {
        float rc = min(len, NDF_R_MAX);
        kappa = (3.0 * rc - rc * rc * rc) / (1.0 - rc * rc);
        mu = r / len;
    }
    return true;
}

void ndf_shade_texel(vec4 t[NDF_TEXTURES], vec3 l, vec3 h, out vec3 diffuse, out vec3 specular) {
    diffuse = vec3(0.0);
    specular = vec3(0.0);
    for (int j = 0; j < NDF_LOBES; ++j) {
        float alpha;
        vec3 mu;
        float kappa;
        if (!ndf_vmf_decode(t[j], alpha, mu, kappa)) continue;
#ifdef NDF_COLOR
        vec3 weight = t[NDF_LOBES + j].rgb;
#else
        vec3 weight = vec3(alpha);
#endif
        float cos_i = max(dot(mu, l), 0.0);
#ifdef NDF_BRDF_TORRANCE_SPARROW
        float var = kappa > 0.0 ? 1.0 / kappa : 1e6;
        float lobe = ndf_ts_iso(1.0, mu, var, l, h, ndf_sigma);
#else
        float s_eff = kappa + ndf_s > 0.0 ? kappa * ndf_s / (kappa + ndf_s) : 0.0;
        float lobe = ndf_blinn_phong(dot(mu, h), s_eff) * cos_i;
#endif
        diffuse += weight * cos_i;
        specular += weight * lobe;
    }
}
