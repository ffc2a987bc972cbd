// ndf_sh.glsl - the spherical-harmonic NDF of Han et al. 2007, Sec 5 (eq 12).
//
// Textures hold c_lm = sqrt(4 pi/(2l+1)) gamma_lm for l <= NDF_SH_LMAX, four per RGBA texture in
// (l, m) order (coefficient i = l*l + l + m is t[i/4][i%4]); they filter linearly, so hardware
// trilinear and anisotropic filtering are exact (DESIGN.md "Texture layouts"). Per texel (CPU
// twin: sh::shade, harmonics::eval_into):
//   diffuse   l* >= 2 (CPU: sh::diffuse_moments): E[max(u, 0)] for a Gaussian u = w_i . n whose
//             mean (c_11, c_1-1, c_10) . w_i and second moment c_00/3 + (2/3) Lambda_2
//             sum_m c_2m Y_2m(w_i) bands 0-2 give exactly (spread v / sqrt(v + 1e-4) for the
//             variance v), clamped to [0, 1];
//             NDF_SH_DIFFUSE_SERIES or l* < 2: clamp(sum_l rhoL_l/Lambda_l sum_m c_lm Y_lm(w_i),
//             0, 1) with Lambert's rho (the generated NDF_SH_LAMBERT): eq 12 with the truncated
//             clamped cosine, exact up to the band limit;
//   specular  clamp(sum_l rho_l/Lambda_l sum_m c_lm Y_lm(w_h), 0, peak) * max(w_i . nbar, 0), rho_l the
//             BRDF's (eq 11, uniform ndf_sh_rho, from Brdf::sh_coefficients) and nbar the
//             MIP-mapped normal normalize(c_11, c_1-1, c_10) (Sec 4.3).
// Ringing of truncated sharp lobes is clamped at 0, and from above where the exact footprint
// average cannot go: the diffuse term at 1 (the truncated clamped cosine overshoots by up to 1/16
// at l* = 2), the specular one at the lobe's peak ndf_sh_peak (Gibbs' overshoot of a lobe with a
// jump). The g factor is applied by ndf_fragment.glsl.

#ifndef NDF_BRDF_LAMBERT
uniform float ndf_sh_rho[NDF_SH_LMAX + 1];  // the BRDF's rho_l, l = 0 .. NDF_SH_LMAX
uniform float ndf_sh_peak;                  // the lobe's largest value (Brdf::peak)
#endif

const int NDF_SH_COUNT = (NDF_SH_LMAX + 1) * (NDF_SH_LMAX + 1);

// ndf_sh_eval(d, y): Y_lm(d), l <= NDF_SH_LMAX, is ndf_sh_basis.glsl instantiated before this
// file (ndfmap::glsl).

// eq 12 for one direction: sum_l w_l / Lambda_l sum_m c_lm y_lm (CPU: sh::series).
float ndf_sh_series(vec4 t[NDF_TEXTURES], float y[NDF_SH_COUNT], float w[NDF_SH_LMAX + 1]) {
    float sum = 0.0;
    for (int l = 0; l <= NDF_SH_LMAX; ++l) {
        if (w[l] == 0.0) continue;
        float band = 0.0;
        for (int i = l * l; i < (l + 1) * (l + 1); ++i) {
            band += t[i >> 2][i & 3] * y[i];
        }
        sum += w[l] / sqrt(4.0 * NDF_PI / float(2 * l + 1)) * band;
    }
    return sum;
}

#if NDF_SH_LMAX >= 2 && !defined(NDF_SH_DIFFUSE_SERIES)
// The error function by Abramowitz & Stegun 7.1.26 (CPU: sh::erf, the same formula).
float ndf_erf(float x) {
    float ax = abs(x);
    float t = 1.0 / (1.0 + 0.3275911 * ax);
    float poly = t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 +
                 t * (-1.453152027 + t * 1.061405429))));
    float y = 1.0 - poly * exp(-ax * ax);
    return x < 0.0 ? -y : y;
}

// E[max(X, 0)] for X ~ N(m, sigma^2) (CPU: sh::clamped_gaussian_mean).
float ndf_clamped_gaussian_mean(float m, float sigma) {
    float z = m / max(sigma, 1e-6);
    float cdf = 0.5 * (1.0 + ndf_erf(z * 0.7071067811865476));
    float pdf = exp(-0.5 * z * z) * 0.3989422804014327;
    return m * cdf + sigma * pdf;
}

// The diffuse term from the moments of bands 0-2 (CPU: sh::diffuse_moments); y is the basis at l.
float ndf_sh_diffuse_moments(vec4 t[NDF_TEXTURES], float y[NDF_SH_COUNT], vec3 l) {
    l = ndf_normalize_or_z(l);
    float mean = dot(vec3(t[0].w, t[0].y, t[0].z), l);
    float band2 = 0.0;
    for (int i = 4; i < 9; ++i) {
        band2 += t[i >> 2][i & 3] * y[i];
    }
    float second = t[0].x / 3.0 + 2.0 / 3.0 * sqrt(4.0 * NDF_PI / 5.0) * band2;
    // The spread v / sqrt(v + 1e-4): sqrt(v) above 0.01 rad, linear below (bounded slope, so
    // f32 rounding of the variance stays small; CPU: sh::MOMENTS_VARIANCE_SOFTENING).
    float v = max(second - mean * mean, 0.0);
    return ndf_clamped_gaussian_mean(mean, v * inversesqrt(v + 1e-4));
}
#endif

void ndf_shade_texel(vec4 t[NDF_TEXTURES], vec3 l, vec3 h, out vec3 diffuse, out vec3 specular) {
    float y[NDF_SH_COUNT];
#ifndef NDF_NO_DIFFUSE
    ndf_sh_eval(l, y);
#if NDF_SH_LMAX >= 2 && !defined(NDF_SH_DIFFUSE_SERIES)
    float d = clamp(ndf_sh_diffuse_moments(t, y, l), 0.0, 1.0);
#else
    float d = clamp(ndf_sh_series(t, y, NDF_SH_LAMBERT), 0.0, 1.0);
#endif
#endif
    float spec = 0.0;
#ifndef NDF_BRDF_LAMBERT
    ndf_sh_eval(h, y);
    float f = clamp(ndf_sh_series(t, y, ndf_sh_rho), 0.0, ndf_sh_peak);
#if NDF_SH_LMAX >= 1
    vec3 nbar = ndf_normalize_or_z(vec3(t[0].w, t[0].y, t[0].z));
#else
    vec3 nbar = vec3(0.0, 0.0, 1.0);
#endif
    spec = f * max(dot(nbar, l), 0.0);
#endif
#ifndef NDF_NO_DIFFUSE
    diffuse = vec3(d);
#else
    diffuse = vec3(0.0);
#endif
    specular = vec3(spec);
}
