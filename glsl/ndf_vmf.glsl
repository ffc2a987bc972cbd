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
//                other BRDFs: ndf_iso_lobe with var = 1/kappa (eq 21 for Torrance-Sparrow,
//                alpha'^2 = alpha^2 + c/kappa for GGX, eq 14 tabulated)
//   line 14      rho += alpha*y (K_s B + K_d)(w_i . mu); the K_d and K_s terms are returned apart.
//                The K_d term uses max(w_i . alpha r, 0) = alpha |r| (w_i . mu) unless
//                NDF_VMF_DIFFUSE_ALG2 asks for line 14 as written (shade::VmfDiffuse).

// Decodes one lobe texel: false for an empty lobe. rlen is |r| before the clamp.
bool ndf_vmf_decode(vec4 theta, out float alpha, out vec3 mu, out float kappa, out float rlen) {
    alpha = theta.x;
    mu = vec3(0.0, 0.0, 1.0);
    kappa = 0.0;
    rlen = 0.0;
    if (!(alpha > 0.0)) return false;
    vec3 r = theta.yzw / alpha;
    float len = length(r);
    rlen = len;
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
        float rlen;
        if (!ndf_vmf_decode(t[j], alpha, mu, kappa, rlen)) continue;
#ifdef NDF_COLOR
        vec3 weight = t[NDF_LOBES + j].rgb;
#else
        vec3 weight = vec3(alpha);
#endif
        float cos_i = max(dot(mu, l), 0.0);
#ifdef NDF_BRDF_BLINN_PHONG
        float s_eff = kappa + ndf_s > 0.0 ? kappa * ndf_s / (kappa + ndf_s) : 0.0;
        float lobe = ndf_blinn_phong(dot(mu, h), s_eff) * cos_i;
#else
        float var = kappa > 0.0 ? 1.0 / kappa : 1e6;
        float lobe = ndf_iso_lobe(mu, var, h) * cos_i;
#endif
#ifdef NDF_VMF_DIFFUSE_ALG2
        diffuse += weight * cos_i;
#else
        diffuse += weight * (min(rlen, 1.0) * cos_i);
#endif
        specular += weight * lobe;
    }
}
