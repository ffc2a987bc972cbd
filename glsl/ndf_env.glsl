// ndf_env.glsl - environment lighting (Han et al. 2007 Sec 8, eqs 24-26; the prefiltered lookups
// of the Gaussian-mixture paper's Sec 4). Included after the method file when NDF_LIGHT_ENV_SH or
// NDF_LIGHT_ENV_PREFILTERED is defined; CPU twin: envlight::shade (every clamp and table lookup
// below is the CPU's, in the same order). Data: src/envgpu.rs (an RGB32F equirectangular atlas of
// the prefiltered levels read with texelFetch, the RGB32F L' table, the R32F lobe-energy table).
// RGB: radiance-dependent quantities (L_lm, L'_lm, the lookups, the sums and their clamps at 0)
// are vec3, one channel each; everything else (lobes, basis, table lookups, g) is computed once.
//
// Per texel the method gives isotropic lobes (alpha, mu, |r|, var = 1/kappa; var = 0 is kappa =
// infinity): plain one lobe of var 0; Toksvig |r| = |m| and Banerjee's kappa; LEAN the mean of
// its two slope variances and |r| = A(kappa); Olano-North one lobe about E[n], var the mean of
// its tangent-plane covariance's diagonal (its diffuse term from the moments, below); vMF the
// decoded lobes of Algorithm 2, Tan 2005 its Gaussians (mu lifted from the planar mean, var =
// sigma^2, |r| = A(1/var)) (with NDF_COLOR each mixture lobe's terms are weighted per channel by
// its colour texel alpha*y, texture NDF_LOBES + j, instead of alpha: eq 22 / Algorithm 2 line
// 14 as under a point light). Then
//   diffuse (eq 25)  alpha sum_{l<=2} rhoL_l A_l sum_m L_lm Y_lm(mu), A_1 = |r|,
//                    A_2 = max(1 - 3|r| var, 0), clamped at 0 per lobe; Olano-North instead
//                    max(sum_{l<=2} rhoL_l sum_m L_lm E[Y_lm(n)], 0), E[Y_lm] linear in its
//                    stored E[n] and E[nn^T] (the footprint's band-limited irradiance exactly);
//   specular         per lobe facing the view (co = v.mu > 0), r = 2 co mu - v, times g(r, mu):
//     prefiltered    the BRDF widened by the lobe (s' = s/(1 + s var); GGX alpha', exponent
//                    2/alpha'^2 - 2); its lobe over incident directions replaced by the vMF of the
//                    same first moment (table, envlight::lobe_moments: normalize(b mu + (1 - b) r), kappa_i = 2^(log2 kappa_i)); the environment
//                    convolved with that vMF (LOD = 1/2 log2(kappa_0/kappa_i)) times the lobe
//                    energy E(co, s') (table); GGX: two vMFs, a core (kappa_c, share 1 - t,
//                    looked up at the lobe's mode: block 5's blend) and a tail (kappa_t, share
//                    t, about the mean) of the same total first moment, fitted to the lobe's
//                    angular distribution and peak density (blocks 3-5; t = 0 for
//                    Blinn-Phong: one lookup);
//     SH (eq 26)     max(sum_l rho_l e^{-l^2 var/2} sum_m L'_lm(v) Y_lm(mu), 0) co.
// SH bakes (NDF_METHOD_SH, lit by NDF_LIGHT_ENV_SH only; c_lm the texel's coefficients, bands
// Lambda_l = sqrt(4 pi/(2l+1))):
//   diffuse          max(sum_{l<=min(l*,2)} rhoL_l/Lambda_l sum_m L^t_lm c_lm, 0),
//   specular         max(sum_{l<=min(l*,8)} rho_l/Lambda_l sum_m L'^t_lm c_lm co, 0) g(r, nbar),
//                    co = max(v.nbar, 0), nbar = normalize(c_11, c_1-1, c_10), r = 2 co nbar - v,
// where L^t and L'^t are the environment's L_lm and L'_lm(ndf_env_frame v) rotated into the
// tangent frame per fragment (ndf_env_rotate: z-y-z Euler angles of the frame, rotations about z
// in closed form, the rotation by 90 deg about x a generated constant NDF_ENV_X90; CPU twin
// projection::rotate_zyz). Exact on curved meshes, not only planes.
// Directions: lobes and the view are in the tangent frame; ndf_env_frame (set by the entry point:
// the identity in the probe, tangent -> environment frame on meshes) turns them into the
// environment's frame for the lookups. The g factor uses tangent-frame directions.

const int NDF_ENV_LMAX = 8;
const int NDF_ENV_COUNT = 81;
const int NDF_ENV_MAX_LEVELS = 24;  // envgpu::MAX_LEVELS
const int NDF_ENV_GRID = 16;        // projection::REFLECTED_GRID
const int NDF_ENV_ENERGY_COS = 33;  // envlight::ENERGY_COS
const int NDF_ENV_ENERGY_PARAM = 49;
const int NDF_ENV_ENERGY_SHARES = 9;  // envlight::ENERGY_SHARES

uniform vec3 ndf_env_sh[NDF_ENV_COUNT];   // L_lm, environment frame, RGB
mat3 ndf_env_frame = mat3(1.0);           // tangent -> environment frame (entry point sets it)
#ifdef NDF_ENV_LIGHTS
// The extracted lights (envgpu::Upload::lights, at most NDF_ENV_LIGHTS): direction (environment
// frame, unit), RGB power, concentration (0 encodes kappa = infinity, a point), whether the light
// reaches the diffuse term only (0/1), and how many are set (ndf_env_lights below).
uniform vec3 ndf_env_light_dir[NDF_ENV_LIGHTS];
uniform vec3 ndf_env_light_power[NDF_ENV_LIGHTS];
uniform float ndf_env_light_kappa[NDF_ENV_LIGHTS];
uniform float ndf_env_light_diffuse_only[NDF_ENV_LIGHTS];
uniform float ndf_env_light_count;
#endif

// The azimuth atan(d.y, d.x), taken as 0 at the poles (d.x = d.y = 0, where GLSL's atan is
// undefined: a flat texel seen head on looks up exactly there) (CPU: environment::azimuth).
float ndf_env_azimuth(vec3 d) {
    return (d.x == 0.0 && d.y == 0.0) ? 0.0 : atan(d.y, d.x);
}

#if defined(NDF_LIGHT_ENV_PREFILTERED) && !defined(NDF_BRDF_LAMBERT)
uniform sampler2D ndf_env_atlas;    // prefiltered levels stacked (envgpu::Upload)
uniform sampler2D ndf_env_energy;   // lobe table, RGBA: 9 blocks (energy, blend, log2
                                    // kappa_c, tail share t | log2 kappa_t, core blend,
                                    // energy, blend | log2 kappa shift with the cosine at
                                    // the half vector), four to a texel, 3 x ENERGY_PARAM
                                    // rows x ENERGY_SHARES groups of ENERGY_COS columns
                                    // (GGX: the NDF's share w = j/8, its half-vector energy
                                    // set so the mixed energy is the NDF lobe's exact one;
                                    // Blinn-Phong: one share, repeated) (envgpu::energy)
uniform float ndf_env_kappa0;      // level 0's nominal kappa, W*H/pi
uniform float ndf_env_kappa1;      // level 1's kappa; level k >= 1 has kappa1 / 2^(k-1)
uniform float ndf_env_level_count;
uniform vec4 ndf_env_level[NDF_ENV_MAX_LEVELS];  // width, height, first row, first column

// x wrapped into [0, w) (GLSL 3.30 leaves % of a negative int undefined).
int ndf_env_wrap(int x, int w) {
    return x - w * int(floor(float(x) / float(w)));
}

// Bilinear lookup of level k at direction d (CPU: Radiance::bilinear): wrap in phi within the
// level's rectangle of the atlas; the row beyond a pole is the first (last) row half a turn
// away.
vec3 ndf_env_bilinear(int k, vec3 d) {
    vec4 l = ndf_env_level[k];
    int w = int(l.x);
    int h = int(l.y);
    int row = int(l.z);
    int col = int(l.w);
    d = ndf_normalize_or_z(d);
    float u = (ndf_env_azimuth(d) + NDF_PI) / (2.0 * NDF_PI);
    float v = acos(clamp(d.z, -1.0, 1.0)) / NDF_PI;
    float fu = u * float(w) - 0.5;
    float fv = v * float(h) - 0.5;
    float x0 = floor(fu);
    float y0 = floor(fv);
    float tx = fu - x0;
    float ty = fv - y0;
    int xi = int(x0);
    int ya = int(y0);
    int yb = ya + 1;
    int sa = 0;
    int sb = 0;
    if (ya < 0) {
        ya = -1 - ya;
        sa = w / 2;
    }
    if (yb >= h) {
        yb = 2 * h - 1 - yb;
        sb = w / 2;
    }
    ya = clamp(ya, 0, h - 1) + row;
    yb = clamp(yb, 0, h - 1) + row;
    vec3 a = texelFetch(ndf_env_atlas, ivec2(ndf_env_wrap(xi + sa, w) + col, ya), 0).rgb;
    vec3 b = texelFetch(ndf_env_atlas, ivec2(ndf_env_wrap(xi + 1 + sa, w) + col, ya), 0).rgb;
    vec3 c = texelFetch(ndf_env_atlas, ivec2(ndf_env_wrap(xi + sb, w) + col, yb), 0).rgb;
    vec3 e = texelFetch(ndf_env_atlas, ivec2(ndf_env_wrap(xi + 1 + sb, w) + col, yb), 0).rgb;
    return (1.0 - ty) * ((1.0 - tx) * a + tx * b) + ty * ((1.0 - tx) * c + tx * e);
}

// The environment convolved with a normalized vMF lobe of concentration kappa about d: the
// two levels around kappa blended linearly in kappa (CPU: Prefiltered::blend, ::lookup).
vec3 ndf_env_lookup(vec3 d, float kappa) {
    int last = int(ndf_env_level_count) - 1;
    float last_kappa = ndf_env_kappa1 * exp2(-float(last - 1));
    int i = 0;
    float t = 0.0;
    if (isnan(kappa) || kappa >= ndf_env_kappa0 || last == 0) {
        i = 0;
    } else if (kappa <= last_kappa) {
        i = last;
    } else if (kappa >= ndf_env_kappa1) {
        float span = ndf_env_kappa0 - ndf_env_kappa1;
        t = span > 0.0 ? clamp((ndf_env_kappa0 - kappa) / span, 0.0, 1.0) : 1.0;
    } else {
        i = min(1 + int(floor(max(log2(ndf_env_kappa1 / kappa), 0.0))), last - 1);
        float ki = ndf_env_kappa1 * exp2(-float(i - 1));
        t = clamp((ki - kappa) / (0.5 * ki), 0.0, 1.0);
    }
    vec3 a = ndf_env_bilinear(i, d);
    if (t <= 0.0 || i + 1 > last) return a;
    return (1.0 - t) * a + t * ndf_env_bilinear(i + 1, d);
}

// One share's bilinear read of the lobe table at columns col + c0, col + c1 and rows p0, p1
// (weights fc, fp): four blocks per texel.
vec4 ndf_env_energy_share(int col, int c0, int c1, int p0, int p1, float fc, float fp) {
    vec4 a = texelFetch(ndf_env_energy, ivec2(col + c0, p0), 0);
    vec4 b = texelFetch(ndf_env_energy, ivec2(col + c1, p0), 0);
    vec4 c = texelFetch(ndf_env_energy, ivec2(col + c0, p1), 0);
    vec4 e = texelFetch(ndf_env_energy, ivec2(col + c1, p1), 0);
    return (1.0 - fp) * ((1.0 - fc) * a + fc * b) + fp * ((1.0 - fc) * c + fc * e);
}

// Bilinear lookup of the lobe table's blocks 4 group ... 4 group + 3 (one RGBA texel each) at
// fractional row pi and c_o, linear between the shares at fractional share index wi (CPU:
// EnergyTables::lookup; layout: envgpu::energy).
vec4 ndf_env_energy_at(int group, float pi, float wi, float co) {
    pi = clamp(pi, 0.0, float(NDF_ENV_ENERGY_PARAM - 1));
    wi = clamp(wi, 0.0, float(NDF_ENV_ENERGY_SHARES - 1));
    float ci = clamp(co, 0.0, 1.0) * float(NDF_ENV_ENERGY_COS - 1);
    int p0 = int(floor(pi));
    int c0 = int(floor(ci));
    int w0 = int(floor(wi));
    int p1 = min(p0 + 1, NDF_ENV_ENERGY_PARAM - 1);
    int c1 = min(c0 + 1, NDF_ENV_ENERGY_COS - 1);
    float fp = pi - float(p0);
    float fc = ci - float(c0);
    float fw = wi - float(w0);
    p0 += group * NDF_ENV_ENERGY_PARAM;
    p1 += group * NDF_ENV_ENERGY_PARAM;
    int col = w0 * NDF_ENV_ENERGY_COS;
    vec4 v = ndf_env_energy_share(col, c0, c1, p0, p1, fc, fp);
    if (fw > 0.0) {
        // The next share (GGX only: Blinn-Phong's wi is 0).
        vec4 v1 = ndf_env_energy_share(col + NDF_ENV_ENERGY_COS, c0, c1, p0, p1, fc, fp);
        v = (1.0 - fw) * v + fw * v1;
    }
    return v;
}
#endif

#if defined(NDF_LIGHT_ENV_SH) && !defined(NDF_BRDF_LAMBERT)
uniform sampler2D ndf_env_reflected;          // L'_lm, RGB: 81 columns x 256 views
uniform float ndf_env_rho[NDF_ENV_LMAX + 1];  // the BRDF's rho_l, l <= 8

// L'_lm(v) bilinear in (theta_o, phi_o) on the view grid (CPU: ReflectedTable::at).
void ndf_env_reflected_at(vec3 v, out vec3 lp[NDF_ENV_COUNT]) {
    v = ndf_normalize_or_z(v);
    float step_t = 0.5 * NDF_PI / float(NDF_ENV_GRID - 1);
    float t = clamp(acos(clamp(v.z, 0.0, 1.0)) / step_t, 0.0, float(NDF_ENV_GRID - 1));
    float p = (ndf_env_azimuth(v) + NDF_PI) / (2.0 * NDF_PI) * float(NDF_ENV_GRID);
    float t0f = floor(t);
    float p0f = floor(p);
    float ft = t - t0f;
    float fp = p - p0f;
    int t0 = int(t0f);
    int t1 = min(t0 + 1, NDF_ENV_GRID - 1);
    int p0 = int(p0f);
    p0 = p0 - NDF_ENV_GRID * int(floor(float(p0) / float(NDF_ENV_GRID)));
    int p1 = (p0 + 1) - NDF_ENV_GRID * ((p0 + 1) / NDF_ENV_GRID);
    int r00 = t0 * NDF_ENV_GRID + p0;
    int r01 = t0 * NDF_ENV_GRID + p1;
    int r10 = t1 * NDF_ENV_GRID + p0;
    int r11 = t1 * NDF_ENV_GRID + p1;
    float w00 = (1.0 - ft) * (1.0 - fp);
    float w01 = (1.0 - ft) * fp;
    float w10 = ft * (1.0 - fp);
    float w11 = ft * fp;
    for (int k = 0; k < NDF_ENV_COUNT; ++k) {
        lp[k] = w00 * texelFetch(ndf_env_reflected, ivec2(k, r00), 0).rgb
              + w01 * texelFetch(ndf_env_reflected, ivec2(k, r01), 0).rgb
              + w10 * texelFetch(ndf_env_reflected, ivec2(k, r10), 0).rgb
              + w11 * texelFetch(ndf_env_reflected, ivec2(k, r11), 0).rgb;
    }
}
#endif

// ndf_env_basis(d, y): Y_lm(d), l <= 8, is ndf_sh_basis.glsl instantiated before this file
// (ndfmap::glsl).

// Y_lm, l <= 2, as polynomials of a unit vector (CPU: envlight::moment_basis; the recurrence's
// values, test moment_basis_is_the_harmonics_basis): Y_00, Y_1m = C1 (y, z, x), and the five
// quadratic forms of band 2, written traceless so that they hold for E[nn^T] as well.
const float NDF_ENV_Y0 = 0.28209479177387814;   // 1/sqrt(4 pi)
const float NDF_ENV_Y1 = 0.4886025119029199;    // sqrt(3/(4 pi))
const float NDF_ENV_Y2 = 1.0925484305920792;    // sqrt(15/(4 pi)): xy, yz, xz
const float NDF_ENV_Y20 = 0.31539156525252005;  // sqrt(5/(16 pi)): 2z^2 - x^2 - y^2
const float NDF_ENV_Y22 = 0.5462742152960396;   // sqrt(15/(16 pi)): x^2 - y^2

// Y_lm(d), l <= 2, in closed form: eq 25's basis, all the prefiltered route reads (the
// recurrence to l = 8, 81 values per lobe, cost the prefiltered route half of plain's frame on
// llvmpipe).
void ndf_env_basis2(vec3 d, out float y[9]) {
    d = ndf_normalize_or_z(d);
    y = float[](NDF_ENV_Y0, NDF_ENV_Y1 * d.y, NDF_ENV_Y1 * d.z, NDF_ENV_Y1 * d.x,
                NDF_ENV_Y2 * d.x * d.y, NDF_ENV_Y2 * d.y * d.z,
                NDF_ENV_Y20 * (2.0 * d.z * d.z - d.x * d.x - d.y * d.y), NDF_ENV_Y2 * d.x * d.z,
                NDF_ENV_Y22 * (d.x * d.x - d.y * d.y));
}

// A(kappa) = coth kappa - 1/kappa, the vMF's mean resultant length (CPU: vmf::a_kappa).
float ndf_env_a_kappa(float kappa) {
    if (!(kappa > 0.0)) return 0.0;
    if (kappa < 1.0) {
        float k2 = kappa * kappa;
        float d = 27.0;
        for (float odd = 25.0; odd >= 3.0; odd -= 2.0) d = odd + k2 / d;
        return kappa / d;
    }
    float e = exp(-2.0 * kappa);
    return 1.0 - 1.0 / kappa + 2.0 * e / (1.0 - e);
}

#ifdef NDF_METHOD_SH
// Band-limited coefficients rotated about z by a (CPU: projection::rotate_z): each (m, -m) pair
// turns by m a.
void ndf_env_rotate_z(inout vec3 c[NDF_ENV_COUNT], int lmax, float a) {
    for (int l = 1; l <= lmax; ++l) {
        int centre = l * l + l;
        for (int m = 1; m <= l; ++m) {
            float s = sin(float(m) * a);
            float co = cos(float(m) * a);
            vec3 p = c[centre + m];
            vec3 q = c[centre - m];
            c[centre + m] = p * co - q * s;
            c[centre - m] = p * s + q * co;
        }
    }
}

// Each band times its block of NDF_ENV_X90, transposed for -90 deg (CPU: projection::rotate_x90).
void ndf_env_rotate_x90(inout vec3 c[NDF_ENV_COUNT], int lmax, bool transposed) {
    int offset = 0;
    vec3 tmp[2 * NDF_ENV_LMAX + 1];
    for (int l = 0; l <= lmax; ++l) {
        int w = 2 * l + 1;
        int b = l * l;
        for (int i = 0; i < w; ++i) {
            vec3 acc = vec3(0.0);
            for (int j = 0; j < w; ++j) {
                int k = transposed ? j * w + i : i * w + j;
                acc += NDF_ENV_X90[offset + k] * c[b + j];
            }
            tmp[i] = acc;
        }
        for (int i = 0; i < w; ++i) c[b + i] = tmp[i];
        offset += w * w;
    }
}

// c turned by the rotation r, f'(d) = f(r^T d), l <= lmax (CPU: projection::rotate_zyz and
// zyz_angles): r = Rz(alpha) Ry(beta) Rz(gamma), Ry(beta) = Rx(-90) Rz(beta) Rx(90).
void ndf_env_rotate(inout vec3 c[NDF_ENV_COUNT], int lmax, mat3 r) {
    // r[j][i] is row i, column j.
    float s = length(vec2(r[2][0], r[2][1]));
    float alpha;
    float beta;
    float gamma;
    if (s < 1e-6) {
        alpha = 0.0;
        beta = r[2][2] > 0.0 ? 0.0 : NDF_PI;
        gamma = atan(r[0][1], r[2][2] > 0.0 ? r[0][0] : -r[0][0]);
    } else {
        alpha = atan(r[2][1], r[2][0]);
        beta = atan(s, r[2][2]);
        gamma = atan(r[1][2], -r[0][2]);
    }
    ndf_env_rotate_z(c, lmax, gamma);
    ndf_env_rotate_x90(c, lmax, false);
    ndf_env_rotate_z(c, lmax, beta);
    ndf_env_rotate_x90(c, lmax, true);
    ndf_env_rotate_z(c, lmax, alpha);
}

// An SH bake's texel lit by the environment (module header; CPU: envlight::shade_in).
void ndf_env_sh_texel(vec4 t[NDF_TEXTURES], vec3 v,
#ifndef NDF_BRDF_LAMBERT
                      vec3 lp[NDF_ENV_COUNT],
#endif
                      out vec3 diffuse, out vec3 specular) {
    const int LD = NDF_SH_LMAX < 2 ? NDF_SH_LMAX : 2;
    const int LS = NDF_SH_LMAX < NDF_ENV_LMAX ? NDF_SH_LMAX : NDF_ENV_LMAX;
    const float lambert[3] = float[](NDF_PI, 2.0 * NDF_PI / 3.0, NDF_PI / 4.0);
    mat3 to_tangent = transpose(ndf_env_frame);
    vec3 c[NDF_ENV_COUNT];
#ifndef NDF_NO_DIFFUSE
    for (int k = 0; k < NDF_ENV_COUNT; ++k)
        c[k] = k < (LD + 1) * (LD + 1) ? ndf_env_sh[k] : vec3(0.0);
    ndf_env_rotate(c, LD, to_tangent);
    vec3 d = vec3(0.0);
    for (int l = 0; l <= LD; ++l) {
        float w = lambert[l] / sqrt(4.0 * NDF_PI / float(2 * l + 1));
        for (int k = l * l; k < (l + 1) * (l + 1); ++k) d += w * c[k] * t[k >> 2][k & 3];
    }
    diffuse = max(d, 0.0);
#else
    diffuse = vec3(0.0);
#endif
    specular = vec3(0.0);
#ifndef NDF_BRDF_LAMBERT
    for (int k = 0; k < NDF_ENV_COUNT; ++k) c[k] = lp[k];
    ndf_env_rotate(c, LS, to_tangent);
    vec3 sum = vec3(0.0);
    for (int l = 0; l <= LS; ++l) {
        float w = ndf_sh_rho[l] / sqrt(4.0 * NDF_PI / float(2 * l + 1));
        for (int k = l * l; k < (l + 1) * (l + 1); ++k) sum += w * c[k] * t[k >> 2][k & 3];
    }
#if NDF_SH_LMAX >= 1
    vec3 nbar = ndf_normalize_or_z(vec3(t[0].w, t[0].y, t[0].z));
#else
    vec3 nbar = vec3(0.0, 0.0, 1.0);
#endif
    float co = max(dot(v, nbar), 0.0);
    vec3 r = 2.0 * co * nbar - v;
    specular = max(sum * co, 0.0) * ndf_g(r, nbar);
#endif
}
#endif

#if defined(NDF_LIGHT_ENV_PREFILTERED) && !defined(NDF_BRDF_LAMBERT)
// The NDF lobe's share w of the widened lobe's variance (CPU: envlight::ndf_share):
// Blinn-Phong s var / (1 + s var), GGX c var / (alpha^2 + c var); var already clamped.
float ndf_env_share(float var) {
#if defined(NDF_BRDF_GGX)
    float v = ndf_ggx_c * max(var, 0.0);
    float d = ndf_alpha * ndf_alpha + v;
    float w = d > 0.0 ? v / d : 0.0;
#else
    float sv = ndf_s * max(var, 0.0);
    float w = sv / (1.0 + sv);
#endif
    return clamp(w, 0.0, 1.0);
}
#endif

// One lobe's contribution (CPU: envlight::shade's loop body); v in the tangent frame.
void ndf_env_lobe(float alpha, vec3 mu, float r, float var, vec3 v,
#if defined(NDF_LIGHT_ENV_SH) && !defined(NDF_BRDF_LAMBERT)
                  vec3 lp[NDF_ENV_COUNT],
#endif
                  inout vec3 diffuse, inout vec3 specular) {
#if defined(NDF_LIGHT_ENV_SH) && !defined(NDF_BRDF_LAMBERT)
    // The basis at mu to l = 8: the SH route's specular (eq 26) and eq 25's bands.
    float y[NDF_ENV_COUNT];
    ndf_env_basis(ndf_env_frame * mu, y);
#elif !defined(NDF_NO_DIFFUSE)
    // Eq 25 reads the bands l <= 2 only.
    float y[9];
    ndf_env_basis2(ndf_env_frame * mu, y);
#endif
#ifndef NDF_NO_DIFFUSE
    // Eq 25 (CPU: diffuse_lobe).
    float a[3] = float[](1.0, r, max(1.0 - 3.0 * r * min(var, 1e12), 0.0));
    const float lambert[3] = float[](NDF_PI, 2.0 * NDF_PI / 3.0, NDF_PI / 4.0);
    vec3 dsum = vec3(0.0);
    for (int l = 0; l < 3; ++l) {
        vec3 band = vec3(0.0);
        for (int k = l * l; k < (l + 1) * (l + 1); ++k) band += ndf_env_sh[k] * y[k];
        dsum += lambert[l] * a[l] * band;
    }
    diffuse += alpha * max(dsum, 0.0);
#endif
#ifndef NDF_BRDF_LAMBERT
    float co = dot(v, mu);
    if (!(co > 0.0)) return;
    vec3 r_dir = 2.0 * co * mu - v;
    float g = ndf_g(r_dir, mu);
    float vv = min(var, 1e6);
    vec3 spec;
#ifdef NDF_LIGHT_ENV_PREFILTERED
#if defined(NDF_BRDF_GGX)
    float aw = min(sqrt(ndf_alpha * ndf_alpha + ndf_ggx_c * max(vv, 0.0)), 1.0);
    float pi_row = (log2(max(aw, 1e-30)) / log2(10.0) + 3.0) / 3.0 *
                   float(NDF_ENV_ENERGY_PARAM - 1);
#else
    float kh = ndf_s / (1.0 + ndf_s * vv);
    float pi_row = (log2(max(kh, 1e-30)) + 4.0) / 24.0 * float(NDF_ENV_ENERGY_PARAM - 1);
#endif
    // The NDF's share of the widened lobe's variance (CPU: envlight::ndf_share) mixes the
    // cosine at the lobe's centre (blocks 0, 1, 2) with the cosine at the half vector (6, 7,
    // and 8: the shift of log2 kappa).
    float w = ndf_env_share(vv);
#if defined(NDF_BRDF_GGX)
    // GGX's lobe shape follows the NDF's share (eq 14 of the vMF and GGX; CPU:
    // EnergyTables::ggx).
    float wi = w * float(NDF_ENV_ENERGY_SHARES - 1);
#else
    float wi = 0.0;
#endif
    // Blocks 0-3 (energy, blend, log2 kappa_c, tail share), 4-7 (log2 kappa_t, core blend,
    // energy and blend at the half vector) and 8 (the shift), four to a texel.
    vec4 b03 = ndf_env_energy_at(0, pi_row, wi, co);
    vec4 b47 = ndf_env_energy_at(1, pi_row, wi, co);
    float b8 = ndf_env_energy_at(2, pi_row, wi, co).x;
    float e = (1.0 - w) * b03.x + w * b47.z;
    float blend = (1.0 - w) * b03.y + w * b47.w;
    float shift = w * b8;
    float log_kappa = b03.z + shift;
    float tail = b03.w;
    // The lobe's mean direction: a blend of mu and r (CPU: envlight::tilted).
    vec3 d = ndf_env_frame * ndf_normalize_or_z(mu * blend + r_dir * (1.0 - blend));
    if (tail > 0.0) {
        // Two vMFs (GGX's core at the lobe's mode, its tail about the mean).
        float log_tail = b47.x + shift;
        float blend_core = b47.y;
        vec3 dc = ndf_env_frame *
                  ndf_normalize_or_z(mu * blend_core + r_dir * (1.0 - blend_core));
        spec = ((1.0 - tail) * ndf_env_lookup(dc, exp2(log_kappa)) +
                tail * ndf_env_lookup(d, exp2(log_tail))) * e;
    } else {
        spec = ndf_env_lookup(d, exp2(log_kappa)) * e;
    }
#else
    vec3 sum = vec3(0.0);
    for (int l = 0; l <= NDF_ENV_LMAX; ++l) {
        float att = exp(-0.5 * float(l * l) * var);
        vec3 band = vec3(0.0);
        for (int k = l * l; k < (l + 1) * (l + 1); ++k) band += lp[k] * y[k];
        sum += ndf_env_rho[l] * att * band;
    }
    spec = max(sum, 0.0) * co;
#endif
    specular += alpha * spec * g;
#endif
}

#ifndef NDF_NO_DIFFUSE
// The footprint average of the band-limited irradiance from the normals' moments m = E[n] and
// e = E[nn^T] (environment frame): sum_{l<=2} rhoL_l sum_m L_lm E[Y_lm(n)], the Y_2m as traceless
// quadratic forms (CPU: envlight::moment_basis and moments_diffuse). Olano-North's diffuse term;
// outside any method's #if so that the LOD-switching shader's shared helpers hold it.
vec3 ndf_env_moments_diffuse(vec3 m, mat3 e) {
    // e[j][i] is row i, column j (symmetric).
    float y[9] = float[](NDF_ENV_Y0, NDF_ENV_Y1 * m.y, NDF_ENV_Y1 * m.z, NDF_ENV_Y1 * m.x,
                         NDF_ENV_Y2 * e[1][0], NDF_ENV_Y2 * e[2][1],
                         NDF_ENV_Y20 * (2.0 * e[2][2] - e[0][0] - e[1][1]), NDF_ENV_Y2 * e[2][0],
                         NDF_ENV_Y22 * (e[0][0] - e[1][1]));
    const float lambert[3] = float[](NDF_PI, 2.0 * NDF_PI / 3.0, NDF_PI / 4.0);
    vec3 sum = vec3(0.0);
    for (int k = 0; k < 9; ++k) sum += lambert[k == 0 ? 0 : (k < 4 ? 1 : 2)] * ndf_env_sh[k] * y[k];
    return sum;
}
#endif

// Environment-lit shading of one texel for the view v (tangent frame): (diffuse, specular) per
// colour channel (CPU: envlight::shade).
void ndf_env_texel(vec4 t[NDF_TEXTURES], vec3 v, out vec3 diffuse, out vec3 specular) {
    vec3 d = vec3(0.0);
    vec3 s = vec3(0.0);
#if defined(NDF_LIGHT_ENV_SH) && !defined(NDF_BRDF_LAMBERT)
    vec3 lp[NDF_ENV_COUNT];
    ndf_env_reflected_at(ndf_env_frame * v, lp);
#define NDF_ENV_LP lp,
#else
#define NDF_ENV_LP
#endif
#if defined(NDF_METHOD_PLAIN)
    ndf_env_lobe(1.0, ndf_normalize_or_z(t[0].xyz), 1.0, 0.0, v, NDF_ENV_LP d, s);
#elif defined(NDF_METHOD_TOKSVIG)
    vec3 m = t[0].xyz;
    float len = length(m);
    vec3 mu = len > 1e-12 ? m / len : vec3(0.0, 0.0, 1.0);
    float r = min(min(len, 1.0), NDF_R_MAX);
    // Banerjee's kappa of the clamped |r| (vmf::kappa_from_r), as a variance.
    // Unclamped here (r = 0: kappa = 0); ndf_env_lobe clamps as the CPU's Lobe does.
    float var = r > 0.0 ? (1.0 - r) * (1.0 + r) / (r * (3.0 - r * r)) : 1e30;
    ndf_env_lobe(1.0, mu, r, var, v, NDF_ENV_LP d, s);
#elif defined(NDF_METHOD_LEAN)
    vec2 b = t[0].xy;
    float vx = max(t[0].z - b.x * b.x, 0.0);
    float vy = max(t[0].w - b.y * b.y, 0.0);
    vec3 mu = normalize(vec3(b, 1.0));
    float var = 0.5 * (vx + vy);
    float r = var > 0.0 ? ndf_env_a_kappa(1.0 / var) : 1.0;
    ndf_env_lobe(1.0, mu, r, var, v, NDF_ENV_LP d, s);
#elif defined(NDF_METHOD_OLANO)
    // One lobe about E[n] (the point-light decoding of ndf_baselines.glsl); the lobe's own
    // diffuse term is dropped for the moments' exact one.
    vec3 m;
    mat3 second;
    vec3 mu;
    vec3 t1;
    vec3 t2;
    vec3 cov;
    ndf_olano_moments(t, m, second, mu, t1, t2, cov);
    float var = 0.5 * (cov.x + cov.y);
    vec3 lobe_diffuse = vec3(0.0);
    ndf_env_lobe(1.0, mu, min(length(m), 1.0), var > 0.0 ? var : 0.0, v, NDF_ENV_LP lobe_diffuse,
                 s);
#ifndef NDF_NO_DIFFUSE
    d = max(ndf_env_moments_diffuse(ndf_env_frame * m,
                                    ndf_env_frame * second * transpose(ndf_env_frame)),
            0.0);
#endif
#elif defined(NDF_METHOD_TAN2005)
    for (int j = 0; j < NDF_LOBES; ++j) {
        // The point-light decoding of ndf_tan2005.glsl (CPU: tan2005::Gaussian::from_texel).
        float alpha;
        vec3 mu;
        float var;
        if (!ndf_tan_decode(t[j], alpha, mu, var)) continue;
        float rlen = var > 0.0 ? ndf_env_a_kappa(1.0 / var) : 1.0;
#ifdef NDF_COLOR
        vec3 dj = vec3(0.0);
        vec3 sj = vec3(0.0);
        ndf_env_lobe(1.0, mu, rlen, var, v, NDF_ENV_LP dj, sj);
        vec3 weight = t[NDF_LOBES + j].rgb;
        d += weight * dj;
        s += weight * sj;
#else
        ndf_env_lobe(alpha, mu, rlen, var, v, NDF_ENV_LP d, s);
#endif
    }
#elif defined(NDF_METHOD_SH)
    ndf_env_sh_texel(t, v, NDF_ENV_LP d, s);
#elif defined(NDF_METHOD_VMF)
    for (int j = 0; j < NDF_LOBES; ++j) {
        float alpha;
        vec3 mu;
        float var;
        float rlen;
        if (!ndf_vmf_decode(t[j], alpha, mu, var, rlen)) continue;
#ifdef NDF_COLOR
        // Eq 22: lobe j weighted per channel by its colour texel alpha*y instead of alpha
        // (Algorithm 2 line 14, as ndf_vmf.glsl; CPU: envlight::shade_in_with).
        vec3 dj = vec3(0.0);
        vec3 sj = vec3(0.0);
        ndf_env_lobe(1.0, mu, min(rlen, NDF_R_MAX), var, v, NDF_ENV_LP dj, sj);
        vec3 weight = t[NDF_LOBES + j].rgb;
        d += weight * dj;
        s += weight * sj;
#else
        ndf_env_lobe(alpha, mu, min(rlen, NDF_R_MAX), var, v, NDF_ENV_LP d, s);
#endif
    }
#endif
    diffuse = d;
    specular = s;
}

#ifdef NDF_ENV_LIGHTS
// The texel with its NDF convolved with a vMF of concentration k (a light's spread; CPU:
// envlight::spread_texels): vMF lobes' and Toksvig's mean vectors times A(k), LEAN's second
// moments plus 1/k, Olano-North's moments convolved exactly, Tan 2005's sigma^2 plus 1/k, an SH
// bake's band l times e^{-l^2/2k}; plain unchanged.
void ndf_env_spread(inout vec4 t[NDF_TEXTURES], float k) {
#if defined(NDF_METHOD_VMF)
    float a = ndf_env_a_kappa(k);
    for (int j = 0; j < NDF_LOBES; ++j) t[j].yzw *= a;
#elif defined(NDF_METHOD_TOKSVIG)
    t[0].xyz *= ndf_env_a_kappa(k);
#elif defined(NDF_METHOD_LEAN)
    t[0].zw += vec2(1.0 / k);
#elif defined(NDF_METHOD_OLANO)
    // E[n] times A(k); E[nn^T] -> (A/k) I + (1 - 3A/k) E[nn^T].
    float a = ndf_env_a_kappa(k);
    float iso = a / k;
    float keep = 1.0 - 3.0 * iso;
    t[0].xyz *= a;
    t[1].xyz = vec3(iso) + keep * t[1].xyz;
    t[2].xyz *= keep;
#elif defined(NDF_METHOD_TAN2005)
    // Each Gaussian's sigma^2 raised by 1/k: its fourth number by alpha/k.
    for (int j = 0; j < NDF_LOBES; ++j) t[j].w += t[j].x / k;
#elif defined(NDF_METHOD_SH)
    for (int l = 1; l <= NDF_SH_LMAX; ++l) {
        float f = exp(-float(l * l) / (2.0 * k));
        for (int i = l * l; i < (l + 1) * (l + 1); ++i) {
            if (i / 4 < NDF_TEXTURES) t[i / 4][i % 4] *= f;
        }
    }
#endif
}

// v with non-finite components counted 0 (CPU: envlight::light_term).
vec3 ndf_env_finite(vec3 v) {
    return vec3(isnan(v.x) || isinf(v.x) ? 0.0 : v.x, isnan(v.y) || isinf(v.y) ? 0.0 : v.y,
                isnan(v.z) || isinf(v.z) ? 0.0 : v.z);
}

// Adds the extracted lights' term for the view v (tangent frame) (CPU: envlight::add_lights and
// light_term): per light l = ndf_env_frame^T dir, h = normalize(l + v) (skipped when l + v = 0),
// the method's point-light shading (ndf_shade_texel) of the texel spread by the light's kappa
// for the diffuse term and by 4 kappa for the specular one (the half vector sees half the
// light's angle; kappa = infinity: the texel itself), the specular times g(l, h), plain's
// diffuse times A(kappa); a diffuse-only light adds its diffuse term only; every term times the
// light's RGB power, non-finite terms counted 0.
void ndf_env_lights(vec4 t[NDF_TEXTURES], vec3 v, inout vec3 diffuse, inout vec3 specular) {
    mat3 to_tangent = transpose(ndf_env_frame);
    for (int i = 0; i < NDF_ENV_LIGHTS; ++i) {
        if (float(i) >= ndf_env_light_count) break;
        vec3 l = to_tangent * ndf_env_light_dir[i];
        vec3 lv = l + v;
        if (!(dot(lv, lv) > 0.0)) continue;
        vec3 h = normalize(lv);
        float k = ndf_env_light_kappa[i];
        bool point = !(k > 0.0);
        vec4 tl[NDF_TEXTURES] = t;
        if (!point) ndf_env_spread(tl, k);
        vec3 d;
        vec3 s;
        ndf_shade_texel(tl, l, h, d, s);
#ifdef NDF_METHOD_PLAIN
        float scale = point ? 1.0 : ndf_env_a_kappa(k);
#else
        float scale = 1.0;
#endif
        diffuse += ndf_env_light_power[i] * scale * ndf_env_finite(d);
#ifndef NDF_BRDF_LAMBERT
        if (ndf_env_light_diffuse_only[i] != 0.0) continue;
        if (!point) {
            tl = t;
            ndf_env_spread(tl, 4.0 * k);
            ndf_shade_texel(tl, l, h, d, s);
        }
        specular += ndf_env_light_power[i] * ndf_env_finite(s * ndf_g(l, h));
#endif
    }
}
#endif
