// ndf_common.glsl - shared lobe math of the ndfmap shaders (GLSL 3.30 core).
//
// Every function here has a CPU twin in src/shade.rs (named in its comment) that evaluates the
// same formula in f64 from the same texel values; tests render these shaders and compare.
// Guards follow DESIGN.md "Numerics": no pow(0, 0), no division by a zero determinant, no NaN
// from an empty lobe.

const float NDF_PI = 3.14159265358979;

// The BRDF (src/brdf.rs): one NDF_BRDF_* define picks the specular lobe, Blinn-Phong when none
// does. Its parameters are uniforms set by the application (they may change every frame:
// Sec 7.2).
#if !defined(NDF_BRDF_TORRANCE_SPARROW) && !defined(NDF_BRDF_GGX) && !defined(NDF_BRDF_TABULATED)
#ifndef NDF_BRDF_LAMBERT
#define NDF_BRDF_BLINN_PHONG 1
#endif
#endif
#if defined(NDF_BRDF_TORRANCE_SPARROW)
uniform float ndf_sigma;  // eq 18 roughness sigma > 0
#elif defined(NDF_BRDF_GGX)
uniform float ndf_alpha;  // GGX roughness alpha in (0, 1]
uniform float ndf_ggx_c;  // widening alpha'^2 = alpha^2 + c var (brdf::GGX_WIDENING_C)
// GGX's D as a mixture of NDF_GGX_MIXTURE unit-mass vMF lobes, fitted to ndf_alpha on the host
// (brdf::ggx_mixture::GgxMixture::fit): weights and concentrations. The vMF shader's default
// GGX rule (ndf_vmf_ggx_mixture).
const int NDF_GGX_MIXTURE = 5;
uniform float ndf_ggx_w[NDF_GGX_MIXTURE];
uniform float ndf_ggx_eta[NDF_GGX_MIXTURE];
#ifdef NDF_BRDF_G
uniform float ndf_f0;     // Schlick's F0
#endif
#elif defined(NDF_BRDF_TABULATED)
// The tabulated BRDF's table (Tabulated::table): NDF_TAB_GRID angles theta = pi x^2 per row,
// rows k < NDF_TAB_ROWS of the lobe convolved with a vMF lobe of concentration 2^(k/2) - 1
// (eq 14; the last is the lobe itself), then one row of g(theta_d), theta_d = (pi/2) i/(GRID-1).
uniform sampler2D ndf_brdf_table;
#elif defined(NDF_BRDF_BLINN_PHONG)
uniform float ndf_s;      // Blinn-Phong exponent s > 0 (eq 20)
#endif

#if defined(NDF_BRDF_BLINN_PHONG) || defined(NDF_BRDF_GGX)
// The BRDF lobe's concentration eta as a vMF lobe about w_h (shade::cosine_eta), for the vMF
// specular term's cosine at the centre of the NDF lobe's and the BRDF lobe's product: Blinn-Phong
// s + 1, GGX the Blinn-Phong lobe of its peak, max(2/alpha^2 - 2, 1) + 1.
float ndf_cosine_eta() {
#if defined(NDF_BRDF_GGX)
    return max(2.0 / (ndf_alpha * ndf_alpha) - 2.0, 1.0) + 1.0;
#else
    return ndf_s + 1.0;
#endif
}
#endif

// max(x, 0)^y with the CPU's conventions: 0^0 = 1 (an exponent of 0 is a uniform lobe), and
// x <= 0 with y > 0 gives 0. GLSL's pow is undefined at x = 0, y <= 0.
float ndf_pow(float x, float y) {
    if (y <= 0.0) return 1.0;
    if (x <= 0.0) return 0.0;
    return exp2(y * log2(x));
}

// Normalized Blinn-Phong lobe (s+1)/(2 pi) max(c, 0)^s, eq 20's form. CPU: shade::blinn_phong.
float ndf_blinn_phong(float cos_h, float s) {
    return (s + 1.0) / (2.0 * NDF_PI) * ndf_pow(cos_h, s);
}

// Orthonormal tangent frame of a unit vector (Duff et al. 2017). CPU: shade::tangent_frame.
void ndf_tangent_frame(vec3 n, out vec3 t1, out vec3 t2) {
    float sgn = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (sgn + n.z);
    float b = n.x * n.y * a;
    t1 = vec3(1.0 + sgn * n.x * n.x * a, sgn * b, -sgn * n.x);
    t2 = vec3(b, sgn + n.y * n.y * a, -n.y);
}

// A symmetric 2x2 matrix (xx, yy, xy) with its eigenvalues clamped to [lo, hi], eigenvectors
// kept. CPU: brdf::clamp_eigenvalues.
vec3 ndf_clamp_eigen(vec3 m, float lo, float hi) {
    float mean = 0.5 * (m.x + m.y);
    float r = sqrt(0.25 * (m.x - m.y) * (m.x - m.y) + m.z * m.z);
    float l1 = min(max(mean + r, lo), hi);
    float l2 = min(max(mean - r, lo), hi);
    if (r < 1e-30) return vec3(l1, l1, 0.0);
    vec2 e = abs(mean + r - m.x) > abs(mean + r - m.y) ? vec2(m.z, mean + r - m.x)
                                                       : vec2(mean + r - m.y, m.z);
    vec2 c = e / length(e);
    return vec3(l1 * c.x * c.x + l2 * c.y * c.y,
                l1 * c.y * c.y + l2 * c.x * c.x,
                (l1 - l2) * c.x * c.y);
}

// A symmetric 2x2 matrix projected onto the positive semi-definite cone (eigenvalues clamped at
// 0). CPU: brdf::psd.
vec3 ndf_psd(vec3 m) {
    return ndf_clamp_eigen(m, 0.0, 1e30);
}

// Anisotropic Blinn-Phong lobe widened by an NDF covariance sigma = (xx, yy, xy):
// S = (I/s + Sigma)^-1, normalization sqrt(det S + tr S + 1)/(2 pi), exponent the Rayleigh
// quotient of S along the offset d. Sigma = 0 gives (s+1)/(2 pi) c^s. CPU: shade::widened_lobe.
float ndf_widened_lobe(float cos_h, vec2 d, vec3 sigma, float s) {
    float a = sigma.x + 1.0 / s;
    float c = sigma.y + 1.0 / s;
    float b = sigma.z;
    float det = max(a * c - b * b, 1e-30);
    float sxx = c / det;
    float syy = a / det;
    float sxy = -b / det;
    float norm = sqrt(max(sxx * syy - sxy * sxy + sxx + syy + 1.0, 0.0)) / (2.0 * NDF_PI);
    float dd = dot(d, d);
    float e = dd > 1e-30 ? (sxx * d.x * d.x + 2.0 * sxy * d.x * d.y + syy * d.y * d.y) / dd
                         : 0.5 * (sxx + syy);
    return norm * ndf_pow(cos_h, e);
}

// Torrance-Sparrow-like lobe of eq 18 widened by an angular NDF covariance cov (xx, yy, xy) in
// the frame of dir: a 2D Gaussian in the angle offset with covariance 2 sigma^2 I + cov.
// cov = 0 gives exp(-beta^2/(4 sigma^2))/(4 pi sigma^2); cov = I/kappa gives eq 21.
// Zero for cos_h <= 0.
// CPU: shade::torrance_sparrow_lobe.
float ndf_ts_lobe(float cos_h, vec2 dir, float sigma, vec3 cov) {
    if (!(cos_h > 0.0)) return 0.0;
    float beta = acos(min(cos_h, 1.0));
    float v = 2.0 * sigma * sigma;
    float a = v + cov.x;
    float c = v + cov.y;
    float b = cov.z;
    float det = max(a * c - b * b, 1e-30);
    float len = length(dir);
    float q;
    if (len > 1e-30) {
        vec2 d = dir * (beta / len);
        q = (c * d.x * d.x - 2.0 * b * d.x * d.y + a * d.y * d.y) / det;
    } else {
        q = beta * beta * 2.0 / (a + c);
    }
    return exp(-0.5 * q) / (2.0 * NDF_PI * sqrt(det));
}

// GGX / Trowbridge-Reitz D = a^2 / (pi (sin^2 + cos^2 a^2)^2) of the angle between mu and h,
// with sin^2 from the cross product (precise for sharp lobes in f32); zero for cos <= 0.
// CPU: brdf::ggx.
float ndf_ggx(vec3 mu, vec3 h, float a) {
    float c = dot(mu, h);
    if (!(c > 0.0)) return 0.0;
    vec3 x = cross(mu, h);
    float d = dot(x, x) + c * c * a * a;
    return d > 0.0 ? a * a / (NDF_PI * d * d) : 0.0;
}

// Anisotropic GGX in slope space: 1 / (pi sqrt(det S) c^4 (1 + d^T S^-1 d)^2) for the slope
// offset d and the matrix S = (xx, yy, xy); zero for c <= 0. CPU: brdf::ggx_aniso.
float ndf_ggx_aniso(float c, vec2 d, vec3 s) {
    if (!(c > 0.0)) return 0.0;
    float det = max(s.x * s.y - s.z * s.z, 1e-30);
    float q = (s.y * d.x * d.x - 2.0 * s.z * d.x * d.y + s.x * d.y * d.y) / det;
    float c1 = min(c, 1.0);
    float t = 1.0 + max(q, 0.0);
    return 1.0 / (NDF_PI * sqrt(det) * c1 * c1 * c1 * c1 * t * t);
}

#ifdef NDF_BRDF_TABULATED
const int NDF_TAB_GRID = 256;
const int NDF_TAB_ROWS = 45;

// One row of the table at fractional index x (linear). CPU: tabulated::lookup.
float ndf_tab_row(int row, float x) {
    int i = min(int(floor(x)), NDF_TAB_GRID - 2);
    float fx = x - float(i);
    float a = texelFetch(ndf_brdf_table, ivec2(i, row), 0).r;
    float b = texelFetch(ndf_brdf_table, ivec2(i + 1, row), 0).r;
    return a + fx * (b - a);
}

// The tabulated lobe at angle theta from the lobe's centre under a vMF lobe of concentration
// kappa: bilinear in x = sqrt(theta/pi)(GRID-1) and t = min(2 log2(1 + kappa), ROWS-1).
// CPU: brdf::tabulated::lookup.
float ndf_tab_lobe(float theta, float kappa) {
    float x = sqrt(clamp(theta / NDF_PI, 0.0, 1.0)) * float(NDF_TAB_GRID - 1);
    float t = min(2.0 * log2(1.0 + max(kappa, 0.0)), float(NDF_TAB_ROWS - 1));
    int j = min(int(floor(t)), NDF_TAB_ROWS - 2);
    float ft = t - float(j);
    float a = ndf_tab_row(j, x);
    float b = ndf_tab_row(j + 1, x);
    return a + ft * (b - a);
}
#endif

// The convolved vMF rule's helpers, only where a shader uses them (a LOD-switch shader, whose
// parts define their options after this file, defines NDF_LOD_SWITCH_VMF_CONVOLVED before it
// when any part does).
#if defined(NDF_VMF_SPECULAR_CONVOLVED) || defined(NDF_LOD_SWITCH_VMF_CONVOLVED) || defined(NDF_BRDF_GGX)
// x / (1 - e^(-2x)), 1/2 at x = 0: 2 pi times the vMF normalization C(x) (eq 15) without sinh
// or e^x; the series 1/2 + x/2 below 1e-3, where f32's 1 - e^(-2x) cancels. CPU: vmf::half_norm.
float ndf_vmf_half_norm(float x) {
    if (x < 1e-3) return 0.5 + 0.5 * x;
    if (x > 19.0) return x;
    return x / (1.0 - exp(-2.0 * x));
}

// The vMF (*) Blinn-Phong lobe, the opt-in vMF rule under Blinn-Phong (NDF_VMF_SPECULAR_CONVOLVED;
// eq 20 is the default): eq 14 for the lobe (s+1)/(2 pi) c^s written A e^(eta(c-1)) q(c),
// eta = s + 1, A = (s+1)/(2 pi), q(c) = c^s e^(eta(1-c)); the vMF-vMF product in closed form and
// q at the product lobe's centre, c_m = (kappa c + eta)/R, R = |kappa mu + eta h|:
// B = A g(kappa)/g(R) exp(R - kappa - eta + eta (1 - c_m) + s ln c_m), with
// R - kappa - eta = -2 kappa eta (1 - c)/(R + kappa + eta) and
// 1 - c_m = kappa^2 (1 - c^2)/(R (R + kappa c + eta)) (no cancellation in f32).
// cos_h = dot(mu, h), var = 1/kappa. 0 where kappa c + eta <= 0. CPU: vmf::blinn_phong_convolved.
float ndf_vmf_blinn_phong(float cos_h, float s, float var) {
    if (!(s > 0.0)) return 1.0 / (2.0 * NDF_PI);
    float k = 1.0 / var;
    float eta = s + 1.0;
    float omc = clamp(1.0 - cos_h, 0.0, 2.0);
    float num = k * (1.0 - omc) + eta;
    if (!(num > 0.0)) return 0.0;
    float k2s2 = k * k * omc * (2.0 - omc);
    float r2 = k2s2 + num * num;
    float ir = inversesqrt(r2);
    float r = r2 * ir;
    float e = -2.0 * k * eta * omc / (r + k + eta) + eta * k2s2 * ir / (r + num) + s * log(num * ir);
    // g(kappa)/g(R) = kappa/R where both are >= 9 (1 - e^(-18) is 1 in f32): the usual case,
    // so the exponentials of ndf_vmf_half_norm run only for broad lobes.
    float g = k * ir;
    if (k < 9.0 || r < 9.0) g = ndf_vmf_half_norm(k) / ndf_vmf_half_norm(r);
    return (s + 1.0) / (2.0 * NDF_PI) * g * exp(e);
}
#endif

#if defined(NDF_BRDF_GGX) && (defined(NDF_VMF_SPECULAR_CONVOLVED) || defined(NDF_LOD_SWITCH_VMF_CONVOLVED))
// The convolved vMF rule under GGX (as above, only where a shader uses it).
// T(a) = a + 1 - 1/(e^a E1(a)) for a > 0: for a >= 1 the continued fraction
// 1/(a + 3 - 4/(a + 5 - 9/(a + 7 - ...))) to 32 terms, below E1 from its series to 16 terms.
// CPU: brdf::vmf_ggx_tail.
float ndf_vmf_ggx_tail(float a) {
    if (a >= 1.0) {
        float s = 0.0;
        for (int n = 32; n >= 1; --n) {
            float nf = float(n);
            s = nf * nf / (a + 2.0 * nf + 1.0 - s);
        }
        return s;
    }
    float term = 1.0;
    float sum = 0.0;
    for (int n = 1; n <= 16; ++n) {
        float nf = float(n);
        term *= -a / nf;
        sum -= term / nf;
    }
    float e1 = -0.5772156649 - log(max(a, 1e-37)) + sum;
    return a + 1.0 - 1.0 / (exp(a) * e1);
}

// The GGX roughness a vMF lobe of variance var = 1/kappa widens ndf_alpha to under point lights
// with NDF_VMF_SPECULAR_CONVOLVED (the default is ndf_iso_lobe's alpha^2 + c var):
// alpha'^2 = alpha^2 + c m(a) var, a = alpha^2/(2 var), m = 1 + a T/(1 - T) (1 for wide NDF
// lobes, 2 for narrow ones); at c = 2 the GGX lobe with the exact convolution's peak. At most 1;
// var <= 0 gives alpha. CPU: Ggx::widened_vmf.
float ndf_vmf_ggx_alpha(float var) {
    float a2 = ndf_alpha * ndf_alpha;
    if (!(var > 0.0)) return min(ndf_alpha, 1.0);
    float a = 0.5 * a2 / var;
    float m = 2.0;
    if (a <= 1e12) {
        float t = ndf_vmf_ggx_tail(a);
        m = 1.0 + a * t / (1.0 - t);
    }
    return min(sqrt(a2 + ndf_ggx_c * m * var), 1.0);
}
#endif

#if defined(NDF_BRDF_GGX)
// The vMF shader's default GGX rule: eq 14 of GGX's D written as the mixture
// sum_k w_k gamma(eta_k) (uniforms ndf_ggx_w, ndf_ggx_eta), each vMF (*) vMF term in closed form,
// conv = sum_k w_k g(kappa) g(eta_k) / (2 pi g(R_k)) exp(-2 kappa eta_k (1 - c) / (R_k + kappa + eta_k)),
// R_k = sqrt((kappa + eta_k)^2 - 2 kappa eta_k (1 - c)), g = ndf_vmf_half_norm, plus phi times
// the mixture's own error at the widened roughness a_w = min(sqrt(alpha^2 + c var), 1):
// phi (D_{a_w} - sum_k w_k gamma(eta_k alpha^2 / a_w^2)), phi = 1 / (1 + (t / NDF_GGX_T0)^2),
// t = var / alpha^2; clamped to [0, 1/(pi alpha^2)]. Weights all 0 (arrays left unset): eq 20's
// single widened lobe D_{a_w}, the NDF_VMF_SPECULAR_EQ20 rule. c = mu . h; 1 - c = |mu x h|^2 / (1 + c) where c > 0 (no
// cancellation for sharp lobes), clamped to [0, 2]. var = 1/kappa; var <= 0 is kappa =
// infinity: GGX itself. CPU: GgxMixture::lobe.
const float NDF_GGX_T0 = 0.03;
float ndf_vmf_ggx_mixture(vec3 mu, vec3 h, float var) {
    if (!(var > 0.0)) return ndf_ggx(mu, h, ndf_alpha);
    float c = dot(mu, h);
    vec3 x = cross(mu, h);
    float omc = c > 0.0 ? dot(x, x) / (1.0 + c) : 1.0 - c;
    omc = clamp(omc, 0.0, 2.0);
    float a2 = ndf_alpha * ndf_alpha;
    float aw2 = min(a2 + max(ndf_ggx_c, 0.0) * var, 1.0);
    float t = var / a2 / NDF_GGX_T0;
    float phi = 1.0 / (1.0 + t * t);
    float scale = a2 / aw2;
    float k = 1.0 / var;
    float gk = ndf_vmf_half_norm(k);
    float conv = 0.0;
    float wide = 0.0;
    float wsum = 0.0;
    for (int i = 0; i < NDF_GGX_MIXTURE; ++i) {
        wsum += ndf_ggx_w[i];
        float eta = ndf_ggx_eta[i];
        float s = k + eta;
        float r = sqrt(max(s * s - 2.0 * k * eta * omc, 0.0));
        float e = -2.0 * k * eta * omc / (r + s);
        conv += ndf_ggx_w[i] * gk * ndf_vmf_half_norm(eta) / (2.0 * NDF_PI * ndf_vmf_half_norm(r)) * exp(e);
        float ew = eta * scale;
        wide += ndf_ggx_w[i] * ndf_vmf_half_norm(ew) / (2.0 * NDF_PI) * exp(-ew * omc);
    }
    // Arrays never set (GL's default uniform value 0: a host that skipped
    // ndf_material_ggx_mixture): the single widened lobe of NDF_VMF_SPECULAR_EQ20, not the
    // correction term alone, which vanishes for wide NDF lobes (CPU: the same fallback).
    if (!(wsum > 0.0)) return ndf_ggx(mu, h, sqrt(aw2));
    // At most D's peak 1/(pi alpha^2), as eq 14 is (CPU: the same clamp).
    return clamp(conv + phi * (ndf_ggx(mu, h, sqrt(aw2)) - wide), 0.0, 1.0 / (NDF_PI * a2));
}
#endif

// The specular lobe of an isotropic NDF estimate around mu with per-axis angular variance var
// (1/kappa for a vMF lobe), without the cosine and g: eq 21 (Torrance-Sparrow),
// alpha'^2 = alpha^2 + c var (GGX), eq 14 from the table at kappa = 1/var (tabulated), 0 for
// Lambert. Blinn-Phong: s' = s/(1 + s var) (eq 20's form; vMF lobes use ndf_vmf_blinn_phong with
// NDF_VMF_SPECULAR_CONVOLVED). CPU: shade::iso_lobe.
float ndf_iso_lobe(vec3 mu, float var, vec3 h) {
#if defined(NDF_BRDF_TORRANCE_SPARROW)
    vec3 t1;
    vec3 t2;
    ndf_tangent_frame(mu, t1, t2);
    return ndf_ts_lobe(dot(mu, h), vec2(dot(h, t1), dot(h, t2)), ndf_sigma, vec3(var, var, 0.0));
#elif defined(NDF_BRDF_GGX)
    return ndf_ggx(mu, h, min(sqrt(ndf_alpha * ndf_alpha + ndf_ggx_c * max(var, 0.0)), 1.0));
#elif defined(NDF_BRDF_TABULATED)
    float kappa = var > 0.0 ? 1.0 / var : 1e30;
    return ndf_tab_lobe(atan(length(cross(mu, h)), dot(mu, h)), kappa);
#elif defined(NDF_BRDF_BLINN_PHONG)
    return ndf_blinn_phong(dot(mu, h), ndf_s / (1.0 + ndf_s * var));
#else
    return 0.0;
#endif
}

// The BRDF's g factor for light l and half vector h (tangent space; footnote 4: it does not
// depend on the normal, so it multiplies every method's specular term once): GGX with
// NDF_BRDF_G: Schlick's Fresnel times Smith's height-correlated visibility against +Z, the view
// being v = 2 (l.h) h - l; tabulated: g(theta_d) from the table's last row; else 1.
// CPU: Brdf::g.
float ndf_g(vec3 l, vec3 h) {
#if defined(NDF_BRDF_GGX) && defined(NDF_BRDF_G)
    float cd = clamp(dot(l, h), 0.0, 1.0);
    vec3 v = 2.0 * cd * h - l;
    float m = 1.0 - cd;
    float fresnel = ndf_f0 + (1.0 - ndf_f0) * (m * m * m * m * m);
    if (!(l.z > 0.0 && v.z > 0.0)) return 0.0;
    float a2 = ndf_alpha * ndf_alpha;
    float vi = v.z * sqrt(l.z * l.z * (1.0 - a2) + a2);
    float vo = l.z * sqrt(v.z * v.z * (1.0 - a2) + a2);
    float den = vi + vo;
    return den > 0.0 ? fresnel * 0.5 / den : 0.0;
#elif defined(NDF_BRDF_TABULATED)
    float td = acos(clamp(dot(l, h), -1.0, 1.0));
    float x = clamp(td / (0.5 * NDF_PI), 0.0, 1.0) * float(NDF_TAB_GRID - 1);
    return ndf_tab_row(NDF_TAB_ROWS, x);
#else
    return 1.0;
#endif
}

// normalize(v), or +Z for a zero or non-finite v (the CPU's try_normalize fallback).
vec3 ndf_normalize_or_z(vec3 v) {
    float len = length(v);
    return (len > 0.0 && len < 1e30) ? v / len : vec3(0.0, 0.0, 1.0);
}

// The MIP level of detail of the GL specification (3.3 core, eq 3.18-3.21) from the screen
// derivatives dx = dFdx(uv), dy = dFdy(uv) on a texture of base size `size`:
// lambda = log2(max(|dx*size|, |dy*size|)). Computed here rather than left to texture() so that
// hardware and manual sampling, and the CPU twin (src/sample.rs), use one LOD.
float ndf_lod(vec2 dx, vec2 dy, vec2 size) {
    vec2 ex = dx * size;
    vec2 ey = dy * size;
    float rho2 = max(dot(ex, ex), dot(ey, ey));
    return 0.5 * log2(max(rho2, 1e-30));
}
