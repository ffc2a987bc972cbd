// ndf_vmf.glsl - the vMF lobe shader of Han et al. 2007, Algorithm 2 (lines 5-14).
//
// Texture j < NDF_LOBES holds lobe j as theta = (alpha, alpha*r) (DESIGN.md "Texture
// layouts"); with NDF_COLOR, texture NDF_LOBES + j holds alpha*y. Per lobe (CPU twin:
// shade::vmf_lobe, shade::shade_rgb):
//   lines 7-8    alpha = theta.x; a lobe with alpha <= NDF_ALPHA_MIN (the storage format's
//                resolution, vmf::alpha_min: empty, quantized away or below what the format
//                resolves) contributes nothing (the eq 20 path weights it by 0 and computes it
//                anyway, without a branch; the other paths skip it)
//   line 10      mu = theta.yzw * inversesqrt(|theta.yzw|^2)   (= r/|r|; r = 0: mu = +Z)
//   line 9       |r| = |theta.yzw| / alpha, clamped to NDF_R_MAX (the format's), and the lobe's
//                variance 1/kappa = (1 - |r|)(1 + |r|) / (|r| (3 - |r|^2)) (Banerjee's
//                kappa inverted, without the cancellation of 1 - |r|^2; at most 1e6, the
//                uniform lobe's, for r = 0; vmf::inverse_kappa)
//   lines 12-13  Blinn-Phong: the paper's eq 20, s' = kappa*s / (kappa + s), B = (s' + 1)/(2 pi)
//                (w_h . mu)^s' (ndf_vmf_eq20_texel: s' in one division, no branch), or with
//                NDF_VMF_SPECULAR_CONVOLVED the closed-form vMF (*) Blinn-Phong lobe
//                (ndf_vmf_blinn_phong; vmf::blinn_phong_convolved; shade::VmfSpecular);
//                GGX: by default eq 14 of GGX's D as a fitted mixture of vMF lobes, each
//                convolved in closed form (ndf_vmf_ggx_mixture; GgxMixture::lobe); with
//                NDF_VMF_SPECULAR_EQ20 ndf_iso_lobe, alpha'^2 = alpha^2 + c/kappa; with
//                NDF_VMF_SPECULAR_CONVOLVED ndf_vmf_ggx_alpha, alpha'^2 = alpha^2 +
//                c m(kappa alpha^2/2)/kappa with m from 1 (wide lobes) to 2 (narrow): at c = 2
//                the peak of the exact convolution (Ggx::widened_vmf); other BRDFs:
//                ndf_iso_lobe with var = 1/kappa (eq 21 for Torrance-Sparrow, eq 14 tabulated)
//   line 14      rho += alpha*y (K_s B + K_d)(w_i . mu); the K_d and K_s terms are returned apart.
//                Under Blinn-Phong and GGX the K_s term takes its cosine at the centre of the NDF
//                lobe's and the BRDF lobe's product, max(w_i . n_p, 0) with n_p = normalize(mu +
//                eta var w_h), eta = ndf_cosine_eta() (shade::specular_cosine, VmfCosine::Product;
//                kappa = inf gives mu), unless NDF_VMF_COSINE_ALG2 asks for w_i . mu as written.
//                The K_d term uses max(w_i . alpha r, 0) = alpha |r| (w_i . mu) unless
//                NDF_VMF_DIFFUSE_ALG2 asks for line 14 as written (shade::VmfDiffuse).

// Decodes one lobe texel: false for a lobe to skip. var = 1/kappa; rlen is |r| before the clamp.
bool ndf_vmf_decode(vec4 theta, out float alpha, out vec3 mu, out float var, out float rlen) {
    alpha = theta.x;
    mu = vec3(0.0, 0.0, 1.0);
    var = 1e6;
    rlen = 0.0;
    if (!(alpha > NDF_ALPHA_MIN)) return false;
    float m2 = dot(theta.yzw, theta.yzw);
    if (m2 > 0.0 && m2 < 1e30) {
        float inv = inversesqrt(m2);
        mu = theta.yzw * inv;
        rlen = m2 * inv / alpha;
        float rc = min(rlen, NDF_R_MAX);
        var = min((1.0 - rc) * (1.0 + rc) / (rc * (3.0 - rc * rc)), 1e6);
    }
    return true;
}

#if defined(NDF_BRDF_BLINN_PHONG) && !defined(NDF_VMF_SPECULAR_CONVOLVED)
// Algorithm 2 lines 7-14 for the default rule, eq 20, without a branch (issue 14 item 6; CPU:
// shade::vmf_lobe with shade::eq20_exponent). Every lobe is evaluated and a skipped one (alpha <=
// NDF_ALPHA_MIN, or NaN) is weighted by 0 through a select, with inputs that keep its terms
// finite: llvmpipe runs both sides of every branch under a mask, so the per-lobe `continue` only
// added mask work (docs/frame-times.md). With q = min(|theta.yzw|, NDF_R_MAX alpha) = alpha |r|
// clamped, 1/kappa = N/D with N = alpha (alpha - q)(alpha + q) and D = q (3 alpha^2 - q^2)
// (vmf::inverse_kappa with numerator and denominator times alpha^3: no division by alpha, and
// alpha - q has no cancellation), and s' = s/(1 + s N/D) = s D/(D + s N) = kappa s/(kappa + s):
// one division where three were (|r|, 1/kappa, s'). D is raised to 1e-6 N, the uniform lobe's
// bound 1/kappa <= 1e6. One inversesqrt gives mu and |theta.yzw|; the diffuse term
// alpha min(|r|, 1) (w_i . mu) is min(|theta.yzw|, alpha) (w_i . mu).
void ndf_shade_texel(vec4 t[NDF_TEXTURES], vec3 l, vec3 h, out vec3 diffuse, out vec3 specular) {
    diffuse = vec3(0.0);
    specular = vec3(0.0);
    for (int j = 0; j < NDF_LOBES; ++j) {
        vec4 theta = t[j];
        bool live = theta.x > NDF_ALPHA_MIN;
        float a = live ? theta.x : 1.0;
        float m2 = dot(theta.yzw, theta.yzw);
        bool dir = live && m2 > 0.0 && m2 < 1e30;
        float inv = inversesqrt(dir ? m2 : 1.0);
        vec3 mu = dir ? theta.yzw * inv : vec3(0.0, 0.0, 1.0);
        float len = dir ? m2 * inv : 0.0;
        float q = min(len, NDF_R_MAX * a);
        float n = a * (a - q) * (a + q);
        float d = max(q * (3.0 * a * a - q * q), 1e-6 * n);
        float sp = ndf_s * d / (d + ndf_s * n);
        float cos_i = max(dot(mu, l), 0.0);
        float cos_h = dot(mu, h);
        // ndf_pow(cos_h, sp) with selects: 0^0 = 1; cos_h <= 0 with sp > 0 gives 0.
        float p = cos_h > 0.0 ? exp2(sp * log2(cos_h)) : 0.0;
        p = sp > 0.0 ? p : 1.0;
#ifdef NDF_VMF_COSINE_ALG2
        float cos_s = cos_i;
#else
        // The product lobe's centre normalize(mu + eta (N/D) h), scaled by D: no division.
        vec3 np = d * mu + (ndf_cosine_eta() * n) * h;
        float cos_s = max(dot(np, l), 0.0) * inversesqrt(max(dot(np, np), 1e-30));
#endif
        float lobe = (sp + 1.0) * (0.5 / NDF_PI) * p * cos_s;
#ifdef NDF_COLOR
        vec3 weight = live ? t[NDF_LOBES + j].rgb : vec3(0.0);
#ifdef NDF_VMF_DIFFUSE_ALG2
        float dj = cos_i;
#else
        float dj = min(len, a) / a * cos_i;
#endif
#ifndef NDF_NO_DIFFUSE
        diffuse += weight * dj;
#endif
        specular += weight * lobe;
#else
        float w = live ? theta.x : 0.0;
#ifndef NDF_NO_DIFFUSE
#ifdef NDF_VMF_DIFFUSE_ALG2
        diffuse += vec3(w * cos_i);
#else
        diffuse += vec3(live ? min(len, a) * cos_i : 0.0);
#endif
#endif
        specular += vec3(w * lobe);
#endif
    }
}
#else
void ndf_shade_texel(vec4 t[NDF_TEXTURES], vec3 l, vec3 h, out vec3 diffuse, out vec3 specular) {
    diffuse = vec3(0.0);
    specular = vec3(0.0);
    for (int j = 0; j < NDF_LOBES; ++j) {
        float alpha;
        vec3 mu;
        float var;
        float rlen;
        if (!ndf_vmf_decode(t[j], alpha, mu, var, rlen)) continue;
#ifdef NDF_COLOR
        vec3 weight = t[NDF_LOBES + j].rgb;
#else
        vec3 weight = vec3(alpha);
#endif
        float cos_i = max(dot(mu, l), 0.0);
#if (defined(NDF_BRDF_BLINN_PHONG) || defined(NDF_BRDF_GGX)) && !defined(NDF_VMF_COSINE_ALG2)
        vec3 np = mu + (ndf_cosine_eta() * var) * h;
        float cos_s = max(dot(np, l), 0.0) * inversesqrt(max(dot(np, np), 1e-30));
#else
        float cos_s = cos_i;
#endif
#if defined(NDF_BRDF_BLINN_PHONG) && defined(NDF_VMF_SPECULAR_CONVOLVED)
        float lobe = ndf_vmf_blinn_phong(dot(mu, h), ndf_s, var) * cos_s;
#elif defined(NDF_BRDF_GGX) && defined(NDF_VMF_SPECULAR_CONVOLVED)
        float lobe = ndf_ggx(mu, h, ndf_vmf_ggx_alpha(var)) * cos_s;
#elif defined(NDF_BRDF_GGX) && !defined(NDF_VMF_SPECULAR_EQ20)
        float lobe = ndf_vmf_ggx_mixture(mu, h, var) * cos_s;
#else
        float lobe = ndf_iso_lobe(mu, var, h) * cos_s;
#endif
#ifndef NDF_NO_DIFFUSE
#ifdef NDF_VMF_DIFFUSE_ALG2
        diffuse += weight * cos_i;
#else
        diffuse += weight * (min(rlen, 1.0) * cos_i);
#endif
#endif
        specular += weight * lobe;
    }
}
#endif
