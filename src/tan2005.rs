//! The planar Gaussian-mixture method of Tan, Lin, Quan, Guo and Shum 2005, "Multiresolution
//! Reflectance Filtering" (`papers/tan2005-multiresolution-reflectance-filtering.md`): the
//! comparison row of Han et al. 2007 (Sec 2 and Sec 7.1, Fig 7). One texel at a time; the
//! per-level driver, the bake layout and the shader live elsewhere.
//!
//! - **Model** (Tan Sec 3, first equation): a texel's normals are described by a mixture of
//!   isotropic 2D Gaussians `G(p) = Σ_i α_i g(p; μ_i, σ_i)`, with
//!   `g(p; μ, σ) = e^{−|p − μ|²/(2σ²)} / (2πσ²)`, over the *planar projection* of the unit normal,
//!   `p(n) = (n.x, n.y)` ([`project`]; Tan: "a unit normal n can be represented as a 2D vector in
//!   x-y space"). This projection compresses directions near the horizon radially by `cos θ`,
//!   so an isotropic Gaussian in the plane is not isotropic on the sphere — the distortion that
//!   Han 2007 Fig 7 shows at the boundary of the hemisphere. Measured (test
//!   `planar_projection_distorts_near_the_horizon`): an isotropic cluster of 1° per axis gets
//!   a planar σ² of 0.98 δ² at the pole but 0.51 δ² at 80° (the radial spread is compressed
//!   by cos 80° = 0.17); read back on the sphere that isotropic planar Gaussian is ×17 as wide
//!   in polar angle as the pole's fit and ×0.52 in azimuth (it cannot represent the cluster's
//!   33:1 planar anisotropy), and the shaded highlight (s = 1000, l = v = the cluster centre)
//!   is 12.6 % too bright at 80° against 0.1 % at the pole. Normals below the
//!   horizon (`z < 0`) project onto the same disk as their mirror images; [`lift`] maps a mean
//!   back to the upper hemisphere.
//! - **EM** (Tan Sec 4.1, after Bilmes 1997) in [`fit`]: E-step
//!   `Ez_ij = α_i g(p_j; μ_i, σ_i) / Σ_k α_k g(p_j; μ_k, σ_k)` in log space (log-sum-exp, so
//!   σ² at [`VARIANCE_MIN`] never gives 0/0); M-step `α_i = Σ_j w_j Ez_ij / Σ_j w_j`, the MAP
//!   mean with Tan's alignment prior `P(Θ|N(Θ)) = Π_k Π_i exp(−α_ki |μ_ki − μ_i|²)`,
//!   `μ_i = (Σ_j Ez_ij p_j + c Σ_k α_ki μ_ki) / (Σ_j Ez_ij + c Σ_k α_ki)` ([`GaussianAlignment`]),
//!   and `σ_i² = Σ_j Ez_ij |p_j − μ_i|² / (d Σ_j Ez_ij)` with `d = 2`, floored at
//!   [`VARIANCE_MIN`].
//!   - *Weights.* Sample `j` counts as `w_j / max_k w_k` samples (the weights are footprint
//!     fractions), so `Σ_j Ez_ij` in the mean update is Tan's count of samples when all weights
//!     are equal — the prior's strength relative to the data is Tan's — and nothing depends on
//!     the scale of the weights.
//!   - *The σ² divisor.* Tan prints `M·d` (M = number of samples) as the divisor of σ_i². That
//!     is not the maximizer of the EM objective (it would shrink every variance by `α_i` per
//!     iteration); we read it as `d Σ_j Ez_ij`, the standard maximum-likelihood update, with
//!     which the likelihood never decreases (tested).
//!   - Sums are accumulated around the component's current mean (a shifted second moment), so a
//!     tight component loses no precision to `E|p|² − |E p|²` cancellation.
//! - **Storage and interpolation** (Tan Sec 4.2 and the Appendix): component `i` is stored as
//!   `(α, α μx, α μy, α(σ² + |μ|²))` ([`Gaussian::texel`]). These are linear in the samples, so
//!   hardware trilinear filtering `T(·)` of the four numbers is Tan's optimal interpolation:
//!   `α̂ = T(α)`, `μ̂ = T(αμ)/T(α)`, `σ̂² = T(α(σ² + |μ|²))/T(α) − |μ̂|²`
//!   ([`Gaussian::from_texel`]; empty and negative-variance guards there). Implemented as
//!   printed, although it is not quite consistent with the per-axis σ² of the M-step: for
//!   components of variance σ² per axis, moment matching gives
//!   `σ̂² = T(α(σ² + |μ|²/2))/T(α) − |μ̂|²/2` (the spread of the interpolated means counts once
//!   per axis, i.e. half of `|μ − μ̂|²`), so Tan's filtered components are wider than the
//!   moment-matched ones by half the spread of the interpolated means, `(T(α|μ|²)/T(α) −
//!   |μ̂|²)/2`. Within a texel the fit itself is exact; only filtering between texels and
//!   levels carries this.
//! - **Initialization** (Tan Sec 4.1: "normal samples are clustered into N groups"): as for the
//!   vMF baker, [`init_single`] at the finest level and [`farthest_first`] (furthest-point
//!   clustering of the 2D means of the finer texels' components) above it.
//! - **Shading** ([`shade`], [`shade_gaussian`]; the CPU twin of the Tan shader). Tan shades a
//!   Cook–Torrance lobe per Gaussian; for ndfmap's BRDF (Lambert + normalized Blinn-Phong, both
//!   times the cosine; [`crate::brdf::reference`]) each component is lifted to the unit normal
//!   `μ3 = lift(μ)` and gives diffuse `α max(μ3·l, 0)` and specular
//!   `α B(μ3·h; s') max(μ3·l, 0)`, where the Blinn-Phong lobe is widened by the component's
//!   variance added isotropically in μ3's tangent frame: `(I/s + σ² I)⁻¹ = s' I`,
//!   `s' = s / (1 + s σ²)` (this is [`crate::brdf::widened_lobe`] with `Σ = σ² I`, reduced in
//!   closed form so that `σ² = 0` gives exactly the unfiltered BRDF; it is also eq 20 of Han 2007
//!   with `κ = 1/σ²`).
//!
//! # Numerics
//! - [`VARIANCE_MIN`] `= 1/KAPPA_MAX ≈ 2.4·10⁻⁷` is a single normal's Gaussian: with it a
//!   finest-level texel widens Blinn-Phong to `s' = s/(1 + s·VARIANCE_MIN)`, exactly the vMF
//!   baker's level-0 `κs/(κ + s)` at `κ = KAPPA_MAX` (0.024 % at s = 1000).
//! - The stored second moment `α(σ² + |μ|²)` is close to `α|μ|²` for tight components, so σ²
//!   is recovered by cancellation: from an f32 texel to about ±2·10⁻⁷ absolute (measured in
//!   the test `texel_round_trip_and_appendix_interpolation`), and from f16 only to about
//!   ±2.4·10⁻⁴ (half an f16 ulp just below 1), which can turn a finest-level highlight of
//!   exponent 1000 into one of about 800 — prefer f32 storage for this method. Decoded
//!   variances are clamped at 0.
//!
//! Main items: [`Gaussian`], [`fit`], [`TanFit`], [`TanScratch`], [`GaussianAlignment`],
//! [`init_single`], [`farthest_first`], [`shade`].
//!
//! Run time per texel: see [`fit`].

use crate::brdf::{Shading, blinn_phong};
use crate::em::{EmInput, EmOptions, KAPPA_INIT_MAX, MAX_LOBES};
use crate::vmf::{KAPPA_MAX, is_positive, normalize_robust};
use glam::{DVec2, DVec3, Vec3};
use std::f64::consts::PI;

/// Smallest variance σ² a fitted component gets (the M-step's floor): `1/KAPPA_MAX` ≈
/// 2.39·10⁻⁷, an RMS offset of 4.9·10⁻⁴ per axis (0.028°). It is the Gaussian of a single
/// normal ([`init_single`]) and keeps a collapsed component's density finite (its peak
/// `1/(2π σ²)` ≈ 6.7·10⁵, log 13.4). Shading a component at the floor differs from the
/// unfiltered BRDF by `s' = s/(1 + s·VARIANCE_MIN)`, the vMF baker's level-0 factor.
pub const VARIANCE_MIN: f64 = 1.0 / KAPPA_MAX;

/// Smallest variance an EM run starts from at a coarser texel ([`farthest_first`]): `1/2048`
/// (an RMS offset of 1.27° per axis near the pole), the planar twin of
/// [`crate::em::KAPPA_INIT_MAX`]. Starting a coarser texel's EM from finest-level needles at
/// [`VARIANCE_MIN`] would let the broadest component absorb every normal not within a fraction
/// of a degree of another; this lets the components compete.
pub const INIT_VARIANCE_MIN: f64 = 1.0 / KAPPA_INIT_MAX;

/// Largest variance accepted from initial components: 2, the largest `E|p − μ|²/2` any
/// distribution on the unit disk can have about a mean in the disk. (EM's own estimates never
/// exceed it.)
pub const VARIANCE_MAX: f64 = 2.0;

/// Two candidate means closer than this planar distance (1 µrad of tilt near the pole, more
/// towards the horizon) count as the same in [`farthest_first`].
pub const DUPLICATE_DISTANCE: f64 = 1e-6;

/// Tan's planar projection of a normal: `p(n) = (n.x, n.y)` (Tan Sec 3). For a unit normal it
/// lies in the closed unit disk; `n` and its mirror image `(n.x, n.y, −n.z)` share it.
pub fn project(n: DVec3) -> DVec2 {
    DVec2::new(n.x, n.y)
}

/// The unit normal of the upper hemisphere whose projection is `mean`:
/// `(μx, μy, sqrt(max(0, 1 − |μ|²)))`; a mean outside the unit disk is first moved radially onto
/// its boundary (`z = 0`), and a non-finite one gives +Z.
pub fn lift(mean: DVec2) -> DVec3 {
    let m = clamp_to_disk(mean);
    let len2 = m.length_squared();
    DVec3::new(m.x, m.y, (1.0 - len2).max(0.0).sqrt())
}

/// `mean` moved into the closed unit disk: radially onto the circle when outside it, 0 when
/// non-finite. Every projected normal lies in the disk, and EM's means are convex combinations
/// of projected normals and (clamped) neighbour means, so this only ever changes bad input.
fn clamp_to_disk(mean: DVec2) -> DVec2 {
    if !mean.is_finite() {
        return DVec2::ZERO;
    }
    let len2 = mean.length_squared();
    if len2 <= 1.0 {
        return mean;
    }
    // Scale first so a huge finite mean does not overflow to an infinite length.
    let m = mean / mean.abs().max_element();
    m / m.length()
}

/// `v` clamped to `[lo, VARIANCE_MAX]`; NaN gives `lo`.
fn clamp_variance(v: f64, lo: f64) -> f64 {
    if v >= lo { v.min(VARIANCE_MAX) } else { lo }
}

/// One isotropic 2D Gaussian of Tan's mixture over the projected normal `p(n) = (n.x, n.y)`:
/// weight α, mean μ (a point of the unit disk) and variance σ² per axis.
///
/// An empty component has `α = 0`; it contributes nothing and never produces NaN.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gaussian {
    /// Mixture weight α_i, ≥ 0 (`Σα = 1` within a fitted texel).
    pub alpha: f64,
    /// Mean μ_i of the projected normals, in the unit disk.
    pub mean: DVec2,
    /// Variance σ_i² per axis (≥ [`VARIANCE_MIN`] for fitted components; ≥ 0 when decoded).
    pub variance: f64,
}

impl Default for Gaussian {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl Gaussian {
    /// The empty component: `α = 0`, `μ = 0` (the pole), `σ² = VARIANCE_MIN`. What an all-zero
    /// (or `α ≤ 0`) texel decodes to.
    pub const EMPTY: Gaussian = Gaussian {
        alpha: 0.0,
        mean: DVec2::ZERO,
        variance: VARIANCE_MIN,
    };

    /// Whether the component is empty (`α` not positive).
    pub fn is_empty(&self) -> bool {
        !is_positive(self.alpha)
    }

    /// The texture form `[α, α μx, α μy, α(σ² + |μ|²)]` (Tan Sec 4.2; DESIGN.md "Texture
    /// layouts"). All four are linear in the samples, so trilinear filtering of them is Tan's
    /// optimal interpolation (Appendix). An empty component encodes as zeros.
    ///
    /// Ranges, for the packer: `α ∈ [0, 1]`, `αμ ∈ [−α, α]²`; the fourth channel lies in
    /// `[0, α(1 + VARIANCE_MIN)]` for components fitted without alignment (there
    /// `σ² + |μ|² = (E|p|² + |μ|²)/2 ≤ 1`, plus the floor); a strong alignment prior, which can
    /// move μ away from the data, can raise it up to `3α`.
    pub fn texel(&self) -> [f64; 4] {
        if self.is_empty() {
            return [0.0; 4];
        }
        let a = self.alpha;
        [
            a,
            a * self.mean.x,
            a * self.mean.y,
            a * (self.variance + self.mean.length_squared()),
        ]
    }

    /// Decodes the (possibly filtered) texture form `(α, αμ, α(σ² + |μ|²))` in `f64` (Tan's
    /// Appendix): `μ = αμ/α`, `σ² = max(0, α(σ² + |μ|²)/α − |μ|²)`. Guards: `α ≤ 0` or non-finite,
    /// or a non-finite `αμ`, gives [`Gaussian::EMPTY`] (zero contribution, never NaN); a NaN
    /// second moment gives `σ² = 0`.
    pub fn from_moments(alpha: f64, alpha_mean: DVec2, second: f64) -> Self {
        if !is_positive(alpha) || !alpha.is_finite() {
            return Gaussian::EMPTY;
        }
        let mean = alpha_mean / alpha;
        if !mean.is_finite() {
            return Gaussian::EMPTY;
        }
        let variance = second / alpha - mean.length_squared();
        Gaussian {
            alpha,
            mean,
            variance: if variance > 0.0 && variance.is_finite() {
                variance
            } else {
                0.0
            },
        }
    }

    /// Decodes one texel `[α, αμx, αμy, α(σ² + |μ|²)]` as read from a texture (see
    /// [`Gaussian::from_moments`] for the formulas and guards).
    pub fn from_texel(t: [f32; 4]) -> Self {
        let t = t.map(f64::from);
        Self::from_moments(t[0], DVec2::new(t[1], t[2]), t[3])
    }

    /// `ln g(p; μ, σ²)`, the log of the component's normalized density (without α) at a
    /// projected normal `p`. `σ²` is floored at [`VARIANCE_MIN`].
    pub fn log_density(&self, p: DVec2) -> f64 {
        let var = self.variance.max(VARIANCE_MIN);
        -(2.0 * PI * var).ln() - (p - self.mean).length_squared() / (2.0 * var)
    }

    /// The component's term of the mixture density at projected normal `p`: `α g(p; μ, σ²)`.
    /// Zero for an empty component.
    pub fn eval(&self, p: DVec2) -> f64 {
        if self.is_empty() {
            return 0.0;
        }
        self.alpha * self.log_density(p).exp()
    }
}

/// The component for a finest-level texel: `α = 1`, `μ = p(n)`, `σ² = VARIANCE_MIN`. A zero or
/// non-finite `n` gives `μ = 0` (+Z).
pub fn init_single(n: Vec3) -> Gaussian {
    let n = normalize_robust(n.as_dvec3()).unwrap_or(DVec3::Z);
    Gaussian {
        alpha: 1.0,
        mean: project(n),
        variance: VARIANCE_MIN,
    }
}

/// Initial components for a coarser texel: picks `j` of the `candidates` (the components of
/// the finer texels) by furthest-point clustering of their means. Allocating wrapper of
/// [`farthest_first_into`]; see it for the rules.
pub fn farthest_first(candidates: &[Gaussian], j: usize) -> Vec<Gaussian> {
    let mut out = vec![Gaussian::EMPTY; j];
    farthest_first_into(candidates, &mut out);
    out
}

/// Furthest-point selection (Hochbaum–Shmoys 1985, as the vMF baker uses it,
/// [`crate::em::farthest_first_into`]) of `out.len()` components from `candidates` by the
/// planar distance between their means, writing into `out`:
///
/// 1. Candidates with `α ≤ 0`, non-finite α or a non-finite mean are skipped; means outside the
///    unit disk are moved onto it.
/// 2. The first pick is the candidate with the largest α (ties: lowest index).
/// 3. Each next pick is the candidate whose smallest distance to the picks so far is largest
///    (ties: larger α, then lowest index).
/// 4. A candidate within [`DUPLICATE_DISTANCE`] of a pick is not distinct. When fewer distinct
///    candidates than `out.len()` exist, the remaining slots are filled with the remaining
///    candidates (in the same furthest-first order), then with copies of the picks, all with
///    `α = 0` (empty components, which [`fit`] leaves empty).
/// 5. The picks' α are renormalized to sum to 1; the mean is kept and σ² is clamped to
///    `[INIT_VARIANCE_MIN, VARIANCE_MAX]` (so EM can move).
///
/// If no candidate is valid, every slot is [`Gaussian::EMPTY`] (then [`fit`] starts from equal
/// α). Deterministic; allocates nothing for up to 64 candidates.
pub fn farthest_first_into(candidates: &[Gaussian], out: &mut [Gaussian]) {
    let m = candidates.len();
    let j = out.len();
    if j == 0 {
        return;
    }
    // dist[c]: smallest squared distance from candidate c to the picks so far (+∞ before the
    // first pick); TAKEN marks candidates already used or invalid.
    const TAKEN: f64 = -1.0;
    let mut small = [(0.0_f64, DVec2::ZERO); 64];
    let mut heap = Vec::new();
    let state: &mut [(f64, DVec2)] = if m <= small.len() {
        &mut small[..m]
    } else {
        heap.resize(m, (0.0, DVec2::ZERO));
        &mut heap
    };
    let mut valid = 0;
    for (st, g) in state.iter_mut().zip(candidates) {
        *st = if is_positive(g.alpha) && g.alpha.is_finite() && g.mean.is_finite() {
            valid += 1;
            (f64::INFINITY, clamp_to_disk(g.mean))
        } else {
            (TAKEN, DVec2::ZERO)
        };
    }
    if valid == 0 {
        out.fill(Gaussian::EMPTY);
        return;
    }
    // Next candidate: largest distance, then larger α, then lowest index.
    let next = |state: &[(f64, DVec2)]| -> Option<usize> {
        let mut best: Option<usize> = None;
        for (c, &(d, _)) in state.iter().enumerate() {
            if d == TAKEN {
                continue;
            }
            best = match best {
                Some(b)
                    if d < state[b].0
                        || (d == state[b].0 && candidates[c].alpha <= candidates[b].alpha) =>
                {
                    Some(b)
                }
                _ => Some(c),
            };
        }
        best
    };
    let mut picked = 0;
    let mut alpha_sum = 0.0;
    while picked < j {
        let Some(c) = next(state) else { break };
        let (d, mean) = state[c];
        let distinct = picked == 0 || d > DUPLICATE_DISTANCE * DUPLICATE_DISTANCE;
        let g = &candidates[c];
        out[picked] = Gaussian {
            alpha: if distinct { g.alpha } else { 0.0 },
            mean,
            variance: clamp_variance(g.variance, INIT_VARIANCE_MIN),
        };
        alpha_sum += out[picked].alpha;
        state[c].0 = TAKEN;
        for st in state.iter_mut() {
            if st.0 != TAKEN {
                st.0 = st.0.min((st.1 - mean).length_squared());
            }
        }
        picked += 1;
    }
    // Out of candidates: copies of the picks, empty.
    for s in picked..j {
        out[s] = Gaussian {
            alpha: 0.0,
            ..out[s % picked]
        };
    }
    for g in out.iter_mut() {
        g.alpha /= alpha_sum;
    }
}

/// Tan's prior strength c (Sec 4.1: "which we set to 1 for all experiments"): what a caller
/// gets when it asks for aligned Gaussians without giving c.
pub const DEFAULT_ALIGN_STRENGTH: f64 = 1.0;

/// Tan's alignment prior (Sec 4.1): the components of K neighbouring, already fitted texels
/// and the constant c that "modulates smoothness among corresponding Gaussians" (Tan sets
/// c = 1).
///
/// Component `i` of this texel is pulled towards component `i` of every neighbour that has
/// one: `μ_i = (Σ_j Ez_ij p_j + c Σ_k α_ki μ_ki) / (Σ_j Ez_ij + c Σ_k α_ki)`, where
/// `Σ_j Ez_ij` counts samples (a sample of weight `w_j` counts `w_j / max w`; module docs).
/// Empty (`α = 0`) or non-finite neighbour components contribute nothing; neighbour means
/// outside the unit disk are moved onto it.
#[derive(Debug, Clone, Copy)]
pub struct GaussianAlignment<'a> {
    /// c ≥ 0. The data term counts samples, so c = 1 with the up to 13 neighbours of Tan's
    /// mipmap weighs like up to 13 samples: strong at the first levels, weak at coarse ones.
    pub strength: f64,
    /// Components of the K neighbouring texels, matched to this texel's components by index.
    pub neighbours: &'a [&'a [Gaussian]],
}

impl GaussianAlignment<'_> {
    /// `(c Σ_k α_ki μ_ki, c Σ_k α_ki)`, the terms the prior adds to the numerator and the
    /// denominator of component `i`'s mean. Zero when c is not a positive finite number.
    pub fn pull(&self, i: usize) -> (DVec2, f64) {
        if !is_positive(self.strength) || !self.strength.is_finite() {
            return (DVec2::ZERO, 0.0);
        }
        let (mut sum, mut weight) = (DVec2::ZERO, 0.0);
        for gaussians in self.neighbours {
            if let Some(g) = gaussians.get(i)
                && is_positive(g.alpha)
                && g.alpha.is_finite()
                && g.mean.is_finite()
            {
                sum += g.alpha * clamp_to_disk(g.mean);
                weight += g.alpha;
            }
        }
        (self.strength * sum, self.strength * weight)
    }
}

/// A usable sample: projected normal and weight (divided by the largest weight).
#[derive(Debug, Clone, Copy)]
struct Sample {
    p: DVec2,
    w: f64,
}

/// Reusable working memory for [`fit`]: the texel's samples, projected once per call (unusable
/// ones dropped), their original indices, and the log-likelihood history. Responsibilities are
/// never stored. Keep one per worker thread; after the first few calls [`fit`] allocates
/// nothing.
#[derive(Debug, Clone, Default)]
pub struct TanScratch {
    samples: Vec<Sample>,
    index: Vec<u32>,
    log_likelihoods: Vec<f64>,
}

impl TanScratch {
    /// Empty scratch space.
    pub fn new() -> Self {
        Self::default()
    }

    /// Weighted mean log-likelihood `Σ_j w_j ln G(p_j) / Σ_j w_j` of the most recent [`fit`],
    /// one entry per E-step: entry `t` belongs to the components after `t` M-steps (entry 0 to
    /// the initial ones), so there are `iterations + 1` entries (none when the input had no
    /// weight). Without alignment it never decreases (EM; the variance floor is a constraint
    /// the M-step maximizes under).
    pub fn log_likelihoods(&self) -> &[f64] {
        &self.log_likelihoods
    }

    /// Projects the input, dropping samples with a zero, negative or non-finite weight or a
    /// zero/non-finite normal, and divides the weights by the largest one (which changes no α
    /// and no mean log-likelihood, and makes `Σ_j Ez_ij` a count of samples). Returns
    /// `(Σ scaled w, Σ w)`.
    fn prepare(&mut self, input: &EmInput) -> (f64, f64) {
        let n = input.normals.len();
        if let Some(w) = input.weights {
            assert_eq!(w.len(), n, "EmInput: weights and normals differ in length");
        }
        if let Some(f) = input.features {
            assert_eq!(f.len(), n, "EmInput: features and normals differ in length");
        }
        self.samples.clear();
        self.index.clear();
        let (mut original, mut max_w) = (0.0, 0.0_f64);
        for (i, v) in input.normals.iter().enumerate() {
            let w = input.weights.map_or(1.0, |w| w[i]);
            if !is_positive(w) || !w.is_finite() {
                continue;
            }
            let Some(n) = normalize_robust(v.as_dvec3()) else {
                continue;
            };
            self.samples.push(Sample { p: project(n), w });
            self.index.push(i as u32);
            original += w;
            max_w = max_w.max(w);
        }
        let mut total = 0.0;
        for s in &mut self.samples {
            if max_w != 1.0 {
                s.w /= max_w;
            }
            total += s.w;
        }
        (total, original)
    }
}

/// The result of [`fit`] for one texel (a fixed-size value; nothing is allocated).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TanFit {
    gaussians: [Gaussian; MAX_LOBES],
    features: [[f64; 4]; MAX_LOBES],
    len: usize,
    /// Number of M-steps performed.
    pub iterations: u32,
    /// Whether the tolerance test of [`EmOptions::tolerance`] stopped the iteration (false
    /// when `max_iterations` ran out first).
    pub converged: bool,
    /// Weighted mean log-likelihood `Σ_j w_j ln G(p_j) / Σ_j w_j` of the final components, a
    /// log-density over the plane (0 when the input had no weight).
    pub log_likelihood: f64,
    /// `Σ_j w_j` over the samples used, as given.
    pub total_weight: f64,
}

impl TanFit {
    /// The J fitted components, in the order of the initial ones. `α`s sum to 1; empty
    /// components have `α = 0` and finite mean and variance.
    pub fn gaussians(&self) -> &[Gaussian] {
        &self.gaussians[..self.len]
    }

    /// Per-component features `y_i = Σ_j w_j Ez_ij y_j / Σ_j w_j Ez_ij` (eq 22 of Han 2007,
    /// with the responsibilities of the final components); zeros for empty components and when
    /// the input had no features. A texture stores `α_i y_i`.
    pub fn features(&self) -> &[[f64; 4]] {
        &self.features[..self.len]
    }

    /// The texture form of component `i` ([`Gaussian::texel`]).
    ///
    /// # Panics
    /// If `i ≥ self.gaussians().len()`.
    pub fn texel(&self, i: usize) -> [f64; 4] {
        self.gaussians()[i].texel()
    }
}

/// Per-component constants of one E-step, for the components with `α > 0` only ("active
/// slots").
struct Active {
    count: usize,
    component: [usize; MAX_LOBES],
    mean: [DVec2; MAX_LOBES],
    /// `ln α − ln(2πσ²)`.
    offset: [f64; MAX_LOBES],
    /// `1/(2σ²)`.
    inv_two_var: [f64; MAX_LOBES],
}

impl Active {
    fn new(gaussians: &[Gaussian]) -> Self {
        let mut a = Active {
            count: 0,
            component: [0; MAX_LOBES],
            mean: [DVec2::ZERO; MAX_LOBES],
            offset: [0.0; MAX_LOBES],
            inv_two_var: [0.0; MAX_LOBES],
        };
        for (i, g) in gaussians.iter().enumerate().take(MAX_LOBES) {
            if g.is_empty() {
                continue;
            }
            let s = a.count;
            a.component[s] = i;
            a.mean[s] = g.mean;
            a.offset[s] = g.alpha.ln() - (2.0 * PI * g.variance).ln();
            a.inv_two_var[s] = 0.5 / g.variance;
            a.count += 1;
        }
        a
    }
}

/// Responsibilities of sample `p` (Tan's E-step in log space): fills `e[s]` (`s < a.count`)
/// with `e^{x_s − max}`, `x_s = ln(α_s g_s(p))`, and returns `(ln Σ_s α_s g_s(p), Σ_s e[s])`, so
/// that `Ez_s = e[s] / Σ`. The largest term is 1, so the sum is ≥ 1 and never 0/0.
#[inline]
fn responsibilities(p: DVec2, a: &Active, e: &mut [f64; MAX_LOBES]) -> (f64, f64) {
    let mut max = f64::NEG_INFINITY;
    for (s, x) in e.iter_mut().enumerate().take(a.count) {
        *x = a.offset[s] - (p - a.mean[s]).length_squared() * a.inv_two_var[s];
        max = max.max(*x);
    }
    let mut sum = 0.0;
    for x in e.iter_mut().take(a.count) {
        // Terms below e^{−708} (relative to the largest, 1) are flushed to 0 without calling
        // `exp`, and the largest term is 1 without calling it: most samples lie far outside
        // most tight components.
        let d = *x - max;
        *x = if d == 0.0 {
            1.0
        } else if d > EXP_FLUSH {
            d.exp()
        } else {
            0.0
        };
        sum += *x;
    }
    (if sum == 1.0 { max } else { max + sum.ln() }, sum)
}

/// Log-sum-exp terms `x − max` at or below this are taken as 0 (their `exp` is below the
/// smallest normal f64 times 4, ≈ 3e-308).
const EXP_FLUSH: f64 = -708.0;

/// The M-step sums of one E-step pass, per active slot, taken around the slot's current mean
/// `c`: `Σ w Ez`, `Σ w Ez (p − c)`, `Σ w Ez |p − c|²`.
struct Sums {
    weight: [f64; MAX_LOBES],
    first: [DVec2; MAX_LOBES],
    second: [f64; MAX_LOBES],
    log_likelihood: f64,
}

/// One E-step over all samples, accumulating the M-step sums and the weighted log-likelihood
/// in sample order (deterministic).
fn e_step(samples: &[Sample], a: &Active) -> Sums {
    let mut sums = Sums {
        weight: [0.0; MAX_LOBES],
        first: [DVec2::ZERO; MAX_LOBES],
        second: [0.0; MAX_LOBES],
        log_likelihood: 0.0,
    };
    let mut e = [0.0; MAX_LOBES];
    for smp in samples {
        let (ln_g, sum) = responsibilities(smp.p, a, &mut e);
        sums.log_likelihood += smp.w * ln_g;
        let scale = smp.w / sum;
        for (s, &es) in e.iter().enumerate().take(a.count) {
            let wz = es * scale;
            let d = smp.p - a.mean[s];
            sums.weight[s] += wz;
            sums.first[s] += wz * d;
            sums.second[s] += wz * d.length_squared();
        }
    }
    sums
}

/// The M-step (Tan Sec 4.1, with the variance divisor `d Σ Ez` and the floor; module docs).
/// `pull[i]` is the alignment prior's `(c Σ α μ, c Σ α)` for component `i`.
fn m_step(
    gaussians: &mut [Gaussian],
    active: &Active,
    sums: &Sums,
    total: f64,
    pull: &[(DVec2, f64); MAX_LOBES],
) {
    for g in gaussians.iter_mut() {
        g.alpha = 0.0;
    }
    for s in 0..active.count {
        let i = active.component[s];
        let w = sums.weight[s];
        if !is_positive(w) {
            continue; // empty: α = 0, mean and variance kept
        }
        let g = &mut gaussians[i];
        g.alpha = w / total;
        let c = active.mean[s];
        let (p_sum, p_weight) = pull[i];
        // μ − c = (Σ Ez (p − c) + c_align Σ α_k (μ_k − c)) / (Σ Ez + c_align Σ α_k).
        let delta = (sums.first[s] + (p_sum - p_weight * c)) / (w + p_weight);
        g.mean = c + delta;
        // Σ Ez |p − μ|² = Σ Ez |p − c|² − 2 (μ − c)·Σ Ez (p − c) + Σ Ez |μ − c|², over d = 2.
        let sq = sums.second[s] - 2.0 * delta.dot(sums.first[s]) + w * delta.length_squared();
        g.variance = clamp_variance(sq / (2.0 * w), VARIANCE_MIN);
    }
}

/// Fits Tan's planar Gaussian mixture to the normals of one texel by EM (Tan Sec 4.1; module
/// docs), starting from `init` (J = `init.len()` components, 1 ≤ J ≤ [`MAX_LOBES`]), with
/// Tan's alignment prior when `alignment` is given, and computes per-component features
/// (eq 22 of Han 2007) when `input.features` is given. `options.kappa_estimator` is ignored.
///
/// `init` is sanitized first: negative/NaN α become 0 and the α are renormalized to sum 1
/// (equal α if they are all 0), non-finite means become 0 and means outside the unit disk are
/// moved onto it, σ² is clamped to `[VARIANCE_MIN, VARIANCE_MAX]` (NaN: `VARIANCE_MIN`).
/// Components starting with `α = 0` stay empty. Iteration stops when the weighted mean
/// log-likelihood `L` changes by at most `options.tolerance · max(1, |L|)` or after
/// `options.max_iterations` M-steps; every E-step's `L` is left in
/// [`TanScratch::log_likelihoods`].
///
/// If no sample has positive weight, the sanitized `init` is returned with `iterations = 0`,
/// `converged = true`, `log_likelihood = 0` and zero features.
///
/// Deterministic (scalar sums in sample order). Measured (release build, one core of the
/// shared 2-core 2.3 GHz Xeon this was developed on, J = 6, default options, random 4-cluster
/// data; the ignored `timing_*` tests, run while the machine was also busy with other builds,
/// so upper bounds): about 0.7 µs per fit for N = 4 (2.1 iterations on average), 9 µs for
/// N = 16 (6.2 iterations) and 1.5 ms for N = 1024 (20 iterations, the cap), i.e. about
/// 12 ns per normal·component·iteration, mostly libm's `exp` (per normal and component) and
/// `ln` (per normal) — about 3× the vectorized vMF E-step of [`crate::em`].
///
/// # Panics
/// If `init` is empty or longer than [`MAX_LOBES`], or `input.weights` / `input.features`
/// differ in length from `input.normals`.
pub fn fit(
    input: &EmInput,
    init: &[Gaussian],
    options: &EmOptions,
    alignment: Option<&GaussianAlignment>,
    scratch: &mut TanScratch,
) -> TanFit {
    let j_count = init.len();
    assert!(
        (1..=MAX_LOBES).contains(&j_count),
        "tan2005::fit: {j_count} components requested, 1..={MAX_LOBES} supported"
    );
    let (total, original_total) = scratch.prepare(input);
    scratch.log_likelihoods.clear();

    let mut gaussians = [Gaussian::EMPTY; MAX_LOBES];
    let mut alpha_sum = 0.0;
    for (dst, src) in gaussians.iter_mut().zip(init) {
        *dst = Gaussian {
            alpha: if is_positive(src.alpha) && src.alpha.is_finite() {
                src.alpha
            } else {
                0.0
            },
            mean: clamp_to_disk(src.mean),
            variance: clamp_variance(src.variance, VARIANCE_MIN),
        };
        alpha_sum += dst.alpha;
    }
    if is_positive(alpha_sum) && alpha_sum.is_finite() {
        for g in &mut gaussians[..j_count] {
            g.alpha /= alpha_sum;
        }
    } else {
        for g in &mut gaussians[..j_count] {
            g.alpha = 1.0 / j_count as f64;
        }
    }
    let mut pull = [(DVec2::ZERO, 0.0); MAX_LOBES];
    if let Some(a) = alignment {
        for (i, p) in pull.iter_mut().enumerate().take(j_count) {
            *p = a.pull(i);
        }
    }

    let mut result = TanFit {
        gaussians,
        features: [[0.0; 4]; MAX_LOBES],
        len: j_count,
        iterations: 0,
        converged: true,
        log_likelihood: 0.0,
        total_weight: original_total,
    };
    if !is_positive(total) {
        return result;
    }

    let samples = &scratch.samples;
    let mut active = Active::new(&gaussians[..j_count]);
    let mut sums = e_step(samples, &active);
    let mut ll = sums.log_likelihood / total;
    scratch.log_likelihoods.push(ll);
    let mut iterations = 0;
    let mut converged = false;
    while iterations < options.max_iterations && !input.cancelled() {
        m_step(&mut gaussians[..j_count], &active, &sums, total, &pull);
        iterations += 1;
        active = Active::new(&gaussians[..j_count]);
        sums = e_step(samples, &active);
        let next = sums.log_likelihood / total;
        scratch.log_likelihoods.push(next);
        let done = (next - ll).abs() <= options.tolerance * next.abs().max(1.0);
        ll = next;
        if done {
            converged = true;
            break;
        }
    }

    result.gaussians = gaussians;
    result.iterations = iterations;
    result.converged = converged;
    result.log_likelihood = ll;
    if let Some(features) = input.features {
        result.features = component_features(samples, &scratch.index, features, &active);
    }
    result
}

/// Eq 22 of Han 2007 as a post-process: `y_i = Σ_j w_j Ez_ij y_j / Σ_j w_j Ez_ij` with the
/// responsibilities of the final components; 0 for components that win no weight.
fn component_features(
    samples: &[Sample],
    index: &[u32],
    features: &[[f32; 4]],
    active: &Active,
) -> [[f64; 4]; MAX_LOBES] {
    let mut acc = [[0.0; 4]; MAX_LOBES];
    let mut weight = [0.0; MAX_LOBES];
    let mut e = [0.0; MAX_LOBES];
    for (smp, &i) in samples.iter().zip(index) {
        let (_, sum) = responsibilities(smp.p, active, &mut e);
        let scale = smp.w / sum;
        let y = features[i as usize].map(f64::from);
        for ((a, w), &es) in acc.iter_mut().zip(&mut weight).zip(&e).take(active.count) {
            let wz = es * scale;
            *w += wz;
            for (ac, yc) in a.iter_mut().zip(y) {
                *ac += wz * yc;
            }
        }
    }
    let mut out = [[0.0; 4]; MAX_LOBES];
    for s in 0..active.count {
        if is_positive(weight[s]) {
            out[active.component[s]] = acc[s].map(|a| a / weight[s]);
        }
    }
    out
}

/// Shading of one component (module docs): `μ3 = lift(μ)`,
/// `s' = s / (1 + s σ²)`, diffuse `α max(μ3·l, 0)`, specular
/// `α (s'+1)/(2π) max(μ3·h, 0)^{s'} max(μ3·l, 0)`. The specular lobe equals
/// [`crate::brdf::widened_lobe`] with `Σ = [σ², σ², 0]` and the offset of `h` in μ3's
/// [`crate::brdf::tangent_frame`] (to rounding); with `α = 1` and `σ² = 0` it is
/// bit-identical to [`crate::brdf::reference`]`(μ3, l, h, s)`. An empty component (`α ≤ 0` or
/// non-finite) contributes nothing; a negative or NaN σ² counts as 0. `s` must be positive and
/// finite.
pub fn shade_gaussian(g: &Gaussian, l: DVec3, h: DVec3, s: f64) -> Shading {
    if !is_positive(g.alpha) || !g.alpha.is_finite() {
        return Shading::default();
    }
    let mu = lift(g.mean);
    let var = if g.variance > 0.0 { g.variance } else { 0.0 };
    let s_eff = s / (1.0 + s * var);
    let cos_i = mu.dot(l).max(0.0);
    Shading {
        diffuse: g.alpha * cos_i,
        specular: g.alpha * (blinn_phong(mu.dot(h), s_eff) * cos_i),
    }
}

/// Filtered shading from one texel's components (`texels[i]` = component i's
/// `[α, αμx, αμy, α(σ² + |μ|²)]`, possibly trilinearly filtered), for light `l`, half vector `h`
/// (unit, tangent space) and Blinn-Phong exponent `s` (positive, finite): the sum of
/// [`shade_gaussian`] over the decoded components ([`Gaussian::from_texel`]). The CPU twin of
/// the Tan shader.
pub fn shade(texels: &[[f32; 4]], l: DVec3, h: DVec3, s: f64) -> Shading {
    let mut sum = Shading::default();
    for &t in texels {
        let one = shade_gaussian(&Gaussian::from_texel(t), l, h, s);
        sum.diffuse += one.diffuse;
        sum.specular += one.specular;
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::{reference, tangent_frame, widened_lobe};

    use crate::rng::Rng;

    fn dir(theta_deg: f64, phi_deg: f64) -> DVec3 {
        let (t, p) = (theta_deg.to_radians(), phi_deg.to_radians());
        DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
    }

    /// A normal around `center` whose tangent-plane offset is Gaussian with standard deviation
    /// `delta` radians per axis (exponential map), i.e. an isotropic angular cluster.
    fn around(rng: &mut Rng, center: DVec3, delta: f64) -> DVec3 {
        let (e1, e2) = center.any_orthonormal_pair();
        let v = delta * (rng.normal() * e1 + rng.normal() * e2);
        let r = v.length();
        if r == 0.0 {
            return center;
        }
        (r.cos() * center + r.sin() * (v / r)).normalize()
    }

    fn cluster(rng: &mut Rng, center: DVec3, delta: f64, n: usize) -> Vec<Vec3> {
        (0..n)
            .map(|_| around(rng, center, delta).as_vec3())
            .collect()
    }

    fn assert_finite(fit: &TanFit) {
        let mut sum = 0.0;
        for g in fit.gaussians() {
            assert!(g.alpha.is_finite() && g.alpha >= 0.0, "{g:?}");
            assert!(
                g.mean.is_finite() && g.mean.length() <= 1.0 + 1e-12,
                "{g:?}"
            );
            assert!(
                g.variance.is_finite() && (VARIANCE_MIN..=VARIANCE_MAX).contains(&g.variance),
                "{g:?}"
            );
            sum += g.alpha;
        }
        assert!((sum - 1.0).abs() < 1e-12, "Σα = {sum}");
        assert!(fit.log_likelihood.is_finite());
        for y in fit.features() {
            assert!(y.iter().all(|c| c.is_finite()));
        }
    }

    fn f32s(t: [f64; 4]) -> [f32; 4] {
        t.map(|c| c as f32)
    }

    /// A random light and view in the upper hemisphere, and their half vector.
    fn light_and_half(rng: &mut Rng) -> (DVec3, DVec3) {
        let l = rng.upper();
        let v = rng.upper();
        (l, crate::brdf::half_vector(l, v))
    }

    #[test]
    fn single_normal_is_its_own_fit_and_level_0_shades_like_the_reference() {
        let mut scratch = TanScratch::new();
        let mut rng = Rng(1);
        let mut worst = [0.0_f64; 4];
        let exps: [f64; 4] = [1.0, 10.0, 100.0, 1000.0];
        for (theta, phi) in [
            (0.0, 0.0),
            (10.0, 45.0),
            (35.0, 200.0),
            (60.0, 300.0),
            (80.0, 100.0),
        ] {
            let n = dir(theta, phi).as_vec3();
            let g0 = init_single(n);
            let nd = normalize_robust(n.as_dvec3()).unwrap();
            assert_eq!((g0.alpha, g0.variance), (1.0, VARIANCE_MIN));
            assert_eq!(g0.mean, project(nd));
            // EM on the (repeated) normal returns it unchanged, also from a broad start.
            let normals = [n; 5];
            for init in [
                g0,
                Gaussian {
                    variance: 0.3,
                    ..g0
                },
            ] {
                let f = fit(
                    &EmInput::new(&normals),
                    &[init],
                    &EmOptions::default(),
                    None,
                    &mut scratch,
                );
                assert_finite(&f);
                assert_eq!(f.gaussians()[0], g0);
            }
            // Level 0 through an f32 texel against the unfiltered BRDF of n, with half
            // vectors within the highlight (about 1/sqrt(s) from n) and random lights.
            let t = f32s(g0.texel());
            for _ in 0..400 {
                let l = rng.upper();
                for (k, &s) in exps.iter().enumerate() {
                    let h = around(&mut rng, nd, 1.0 / s.sqrt());
                    let a = shade(&[t], l, h, s);
                    let b = reference(nd, l, h, s);
                    let peak = (s + 1.0) / (2.0 * PI);
                    worst[k] = worst[k]
                        .max((a.diffuse - b.diffuse).abs())
                        .max((a.specular - b.specular).abs() / peak);
                }
            }
        }
        // Errors as a fraction of the diffuse maximum (1) and of the specular peak
        // (s+1)/(2π), from the variance floor (s' = s/(1 + s·VARIANCE_MIN): at most about
        // 1.4 s·VARIANCE_MIN) and f32 rounding of μ. Measured: 1.1e-7 (s = 1), 2.1e-6 (10),
        // 2.3e-5 (100), 2.3e-4 (1000).
        let shown = worst.map(|w| format!("{w:.2e}")).join(", ");
        eprintln!("level-0 error vs reference per s = {exps:?}: {shown}");
        for (k, &s) in exps.iter().enumerate() {
            assert!(
                worst[k] <= 1e-6 + 1.5 * s * VARIANCE_MIN,
                "s = {s}: {}",
                worst[k]
            );
        }
    }

    #[test]
    fn zero_variance_shading_is_exactly_the_reference() {
        let mut rng = Rng(2);
        for _ in 0..2000 {
            let n = rng.upper();
            let g = Gaussian {
                alpha: 1.0,
                mean: project(n),
                variance: 0.0,
            };
            let mu3 = lift(g.mean);
            assert!((mu3 - n).length() < 1e-7, "{mu3} {n}");
            let (l, h) = light_and_half(&mut rng);
            for s in [1.0, 3.0, 77.0, 1000.0, 12345.0] {
                assert_eq!(shade_gaussian(&g, l, h, s), reference(mu3, l, h, s));
            }
        }
        // Through a texel whose numbers f32 holds exactly: σ² decodes to exactly 0.
        let t = [1.0, 0.375, -0.5, 0.390625];
        let g = Gaussian::from_texel(t);
        assert_eq!(g.variance, 0.0);
        let (l, h) = (dir(20.0, 10.0), dir(30.0, 200.0));
        assert_eq!(shade(&[t], l, h, 50.0), reference(lift(g.mean), l, h, 50.0));
    }

    #[test]
    fn shading_is_the_widened_lobe_and_guards_empty_texels() {
        let mut rng = Rng(3);
        let mut worst = 0.0_f64;
        for _ in 0..2000 {
            let n = rng.upper();
            let g = Gaussian {
                alpha: 0.2 + 0.8 * rng.uniform(),
                mean: project(n),
                variance: 0.05 * rng.uniform().powi(3),
            };
            let mu = lift(g.mean);
            let (t1, t2) = tangent_frame(mu);
            let (l, h) = light_and_half(&mut rng);
            for s in [1.0, 30.0, 1000.0] {
                let d = DVec2::new(h.dot(t1), h.dot(t2));
                let cos_i = mu.dot(l).max(0.0);
                let sigma = [g.variance, g.variance, 0.0];
                let expected = g.alpha * widened_lobe(mu.dot(h), d, sigma, s) * cos_i;
                let got = shade_gaussian(&g, l, h, s);
                worst = worst.max((got.specular - expected).abs() / expected.max(1e-300));
                assert_eq!(got.diffuse, g.alpha * cos_i);
            }
        }
        eprintln!("closed-form vs widened_lobe: worst relative difference {worst:e}");
        assert!(worst < 1e-12, "{worst}");
        // Components add; empty and broken texels contribute nothing and never NaN.
        let (l, h) = (dir(10.0, 0.0), dir(5.0, 90.0));
        let a = Gaussian {
            alpha: 0.25,
            mean: project(dir(10.0, 30.0)),
            variance: 0.01,
        };
        let b = Gaussian {
            alpha: 0.75,
            mean: project(dir(40.0, 250.0)),
            variance: 1e-4,
        };
        let (sa, sb) = (
            shade_gaussian(&a, l, h, 64.0),
            shade_gaussian(&b, l, h, 64.0),
        );
        let junk = [
            [0.0; 4],
            [-1.0, 0.3, 0.2, 0.5],
            [f32::NAN, 0.0, 0.0, 0.0],
            [0.0, 0.5, 0.5, 0.5],
            [0.5, f32::NAN, 0.0, 0.0],
        ];
        let mut texels = vec![f32s(a.texel()), f32s(b.texel())];
        texels.extend_from_slice(&junk);
        let sum = shade(&texels, l, h, 64.0);
        assert!((sum.diffuse - (sa.diffuse + sb.diffuse)).abs() < 1e-6);
        assert!((sum.specular - (sa.specular + sb.specular)).abs() < 1e-5 * sum.specular);
        for t in junk {
            assert_eq!(shade(&[t], l, h, 64.0), Shading::default(), "{t:?}");
        }
        // A mean outside the disk (from quantization) lifts onto the horizon.
        assert_eq!(lift(DVec2::new(3.0, 4.0)), DVec3::new(0.6, 0.8, 0.0));
        assert_eq!(lift(DVec2::NAN), DVec3::Z);
    }

    /// Labelled statistics of a cluster: weighted fraction, mean and per-axis variance of the
    /// projected normals.
    fn stats(normals: &[Vec3], weights: &[f64], keep: impl Fn(usize) -> bool) -> (f64, DVec2, f64) {
        let (mut w, mut m, mut all) = (0.0, DVec2::ZERO, 0.0);
        for (i, (n, &wi)) in normals.iter().zip(weights).enumerate() {
            all += wi;
            if keep(i) {
                w += wi;
                m += wi * project(n.as_dvec3().normalize());
            }
        }
        let mean = m / w;
        let mut var = 0.0;
        for (i, (n, &wi)) in normals.iter().zip(weights).enumerate() {
            if keep(i) {
                var += wi * (project(n.as_dvec3().normalize()) - mean).length_squared();
            }
        }
        (w / all, mean, var / (2.0 * w))
    }

    #[test]
    fn recovers_two_separated_clusters_near_the_pole() {
        let mut rng = Rng(4);
        let (ca, cb) = (dir(15.0, 0.0), dir(25.0, 180.0));
        let (da, db) = (2f64.to_radians(), 4f64.to_radians());
        let n = 4000;
        let mut normals = Vec::with_capacity(n);
        let mut label = Vec::with_capacity(n);
        for _ in 0..n {
            let a = rng.uniform() < 0.65;
            normals.push(
                if a {
                    around(&mut rng, ca, da)
                } else {
                    around(&mut rng, cb, db)
                }
                .as_vec3(),
            );
            label.push(a);
        }
        let weights: Vec<f64> = (0..n).map(|_| 0.5 + rng.uniform()).collect();
        let candidates: Vec<Gaussian> = normals[..16].iter().map(|&v| init_single(v)).collect();
        let init = farthest_first(&candidates, 2);
        let mut scratch = TanScratch::new();
        let input = EmInput::new(&normals).with_weights(&weights);
        let f = fit(&input, &init, &EmOptions::default(), None, &mut scratch);
        assert_finite(&f);
        // Match fitted components to clusters by their means.
        let (ga, gb) = if f.gaussians()[0].mean.x > 0.0 {
            (f.gaussians()[0], f.gaussians()[1])
        } else {
            (f.gaussians()[1], f.gaussians()[0])
        };
        let sa = stats(&normals, &weights, |i| label[i]);
        let sb = stats(&normals, &weights, |i| !label[i]);
        for (g, (alpha, mean, var), centre, delta) in [(ga, sa, ca, da), (gb, sb, cb, db)] {
            eprintln!(
                "α {:.4} (labels {alpha:.4}), μ {:.5} (labels {mean:.5}, centre {:.5}), \
                 σ² {:.3e} (labels {var:.3e}, δ² {:.3e}), {} iterations",
                g.alpha,
                g.mean,
                project(centre),
                g.variance,
                delta * delta,
                f.iterations
            );
            // Clusters 0.68 apart with σ ≤ 0.07: the fit is the labelled statistics (to
            // 1e-9), which are the truth up to sampling (|Δα| ≤ 0.02, |Δμ| ≤ 0.005, σ² within
            // 15 % of δ² cos-compressed: δ²(1 + cos²θ)/2).
            assert!((g.alpha - alpha).abs() < 1e-9);
            assert!((g.mean - mean).length() < 1e-9);
            assert!((g.variance / var - 1.0).abs() < 1e-7);
            assert!((g.alpha - if centre == ca { 0.65 } else { 0.35 }).abs() < 0.02);
            assert!((g.mean - project(centre)).length() < 0.005);
            let c2 = centre.z * centre.z;
            assert!((g.variance / (delta * delta * (1.0 + c2) / 2.0) - 1.0).abs() < 0.15);
        }
    }

    /// The worst relative decrease of the log-likelihood over J = 1..=8 on random data.
    #[test]
    fn log_likelihood_never_decreases() {
        let mut worst = 0.0_f64;
        let mut scratch = TanScratch::new();
        let mut runs = 0;
        for j in 1..=MAX_LOBES {
            for trial in 0..4u64 {
                let mut rng = Rng(1000 * j as u64 + trial);
                let clusters = 1 + (rng.next_u64() % 6) as usize;
                let centres: Vec<(DVec3, f64)> = (0..clusters)
                    .map(|_| {
                        let c = dir(85.0 * rng.uniform(), 360.0 * rng.uniform());
                        (c, (0.5 + 25.0 * rng.uniform().powi(2)).to_radians())
                    })
                    .collect();
                let normals: Vec<Vec3> = (0..1500)
                    .map(|i| {
                        if i % 10 == 9 {
                            rng.upper().as_vec3()
                        } else {
                            let (c, d) = centres[(rng.next_u64() % clusters as u64) as usize];
                            around(&mut rng, c, d).as_vec3()
                        }
                    })
                    .collect();
                let weights: Vec<f64> = (0..normals.len()).map(|_| rng.uniform()).collect();
                let candidates: Vec<Gaussian> =
                    normals[..4 * j].iter().map(|&v| init_single(v)).collect();
                let init = farthest_first(&candidates, j);
                let options = EmOptions {
                    max_iterations: 100,
                    tolerance: 0.0,
                    ..EmOptions::default()
                };
                let input = EmInput::new(&normals).with_weights(&weights);
                let f = fit(&input, &init, &options, None, &mut scratch);
                assert_finite(&f);
                assert_eq!(scratch.log_likelihoods().len(), f.iterations as usize + 1);
                for g in f.gaussians() {
                    let t = g.texel();
                    assert!(t[3] >= 0.0 && t[3] <= g.alpha * (1.0 + VARIANCE_MIN) * (1.0 + 1e-15));
                }
                for w in scratch.log_likelihoods().windows(2) {
                    worst = worst.max((w[0] - w[1]) / w[0].abs().max(1.0));
                }
                runs += 1;
            }
        }
        eprintln!("{runs} runs: worst relative log-likelihood decrease {worst:e}");
        assert!(worst <= 1e-9, "{worst}");
    }

    #[test]
    fn degenerate_inputs_stay_finite() {
        let mut scratch = TanScratch::new();
        let opts = EmOptions::default();
        let n = Vec3::new(0.3, -0.2, 0.9).normalize();
        let p = project(n.as_dvec3().normalize());

        // One repeated normal: the floor variance at the normal; extra components empty.
        let normals = vec![n; 100];
        let f = fit(
            &EmInput::new(&normals),
            &[init_single(Vec3::Z)],
            &opts,
            None,
            &mut scratch,
        );
        assert_finite(&f);
        assert!((f.gaussians()[0].mean - p).length() < 1e-15);
        assert_eq!(f.gaussians()[0].variance, VARIANCE_MIN);
        let init = [init_single(n), init_single(Vec3::X), init_single(-Vec3::Y)];
        let f = fit(&EmInput::new(&normals), &init, &opts, None, &mut scratch);
        assert_finite(&f);
        assert_eq!(f.gaussians()[0].alpha, 1.0);
        assert_eq!((f.gaussians()[1].alpha, f.gaussians()[2].alpha), (0.0, 0.0));
        assert_eq!(
            f.gaussians()[1].mean,
            DVec2::X,
            "an empty component keeps its mean"
        );

        // Antipodal pairs: ±Z share the projection 0; ±X are the two ends of a diameter.
        let f = fit(
            &EmInput::new(&[Vec3::Z, -Vec3::Z]),
            &[init_single(Vec3::X)],
            &opts,
            None,
            &mut scratch,
        );
        assert_finite(&f);
        assert_eq!(
            (f.gaussians()[0].mean, f.gaussians()[0].variance),
            (DVec2::ZERO, VARIANCE_MIN)
        );
        let pair = [Vec3::X, -Vec3::X];
        let f = fit(
            &EmInput::new(&pair),
            &[init_single(Vec3::Z)],
            &opts,
            None,
            &mut scratch,
        );
        assert_finite(&f);
        assert_eq!(
            (f.gaussians()[0].mean, f.gaussians()[0].variance),
            (DVec2::ZERO, 0.5)
        );
        let init = [init_single(Vec3::X), init_single(-Vec3::X)];
        let f = fit(&EmInput::new(&pair), &init, &opts, None, &mut scratch);
        assert_finite(&f);
        assert_eq!(f.gaussians()[0].alpha, 0.5);
        let init = [init_single(Vec3::Y), init_single(Vec3::Y)];
        let f = fit(&EmInput::new(&pair), &init, &opts, None, &mut scratch);
        assert_finite(&f);

        // All normals on the horizon (the unit circle of the plane).
        let normals: Vec<Vec3> = (0..64)
            .map(|k| {
                let a = 2.0 * std::f32::consts::PI * k as f32 / 64.0;
                Vec3::new(a.cos(), a.sin(), 0.0)
            })
            .collect();
        for j in [1, 4, 8] {
            let candidates: Vec<Gaussian> = normals.iter().map(|&v| init_single(v)).collect();
            let init = farthest_first(&candidates, j);
            let f = fit(&EmInput::new(&normals), &init, &opts, None, &mut scratch);
            assert_finite(&f);
        }
        let f = fit(
            &EmInput::new(&normals),
            &[init_single(Vec3::Z)],
            &opts,
            None,
            &mut scratch,
        );
        assert_finite(&f);
        assert!(f.gaussians()[0].mean.length() < 1e-6);
        assert!((f.gaussians()[0].variance - 0.5).abs() < 1e-6);

        // J larger than the number of distinct normals (3 distinct, J = 8), both through
        // farthest_first (5 empty fillers) and from 8 live components.
        let distinct = [Vec3::Z, Vec3::X, Vec3::new(0.0, 0.6, 0.8)];
        let normals: Vec<Vec3> = (0..30).map(|i| distinct[i % 3]).collect();
        let candidates: Vec<Gaussian> = normals.iter().map(|&v| init_single(v)).collect();
        let init = farthest_first(&candidates, 8);
        assert_eq!(init.iter().filter(|g| g.alpha > 0.0).count(), 3);
        let f = fit(&EmInput::new(&normals), &init, &opts, None, &mut scratch);
        assert_finite(&f);
        let init: Vec<Gaussian> = (0..8)
            .map(|i| Gaussian {
                alpha: 1.0,
                mean: project(distinct[i % 3].as_dvec3()) + 1e-3 * i as f64,
                variance: 0.01,
            })
            .collect();
        let f = fit(&EmInput::new(&normals), &init, &opts, None, &mut scratch);
        assert_finite(&f);

        // Degenerate initial components are sanitized.
        let bad = [
            Gaussian {
                alpha: f64::NAN,
                mean: DVec2::splat(f64::INFINITY),
                variance: f64::INFINITY,
            },
            Gaussian {
                alpha: -1.0,
                mean: DVec2::NAN,
                variance: f64::NAN,
            },
            Gaussian {
                alpha: f64::INFINITY,
                mean: DVec2::splat(1e300),
                variance: -1.0,
            },
        ];
        let f = fit(&EmInput::new(&normals), &bad, &opts, None, &mut scratch);
        assert_finite(&f);

        // No usable sample (zero weights, bad normals, nothing): init returned, sanitized.
        for input in [
            EmInput::new(&normals).with_weights(&[0.0; 30]),
            EmInput::new(&[Vec3::ZERO, Vec3::NAN]),
            EmInput::new(&[]),
        ] {
            let f = fit(&input, &bad, &opts, None, &mut scratch);
            assert_finite(&f);
            assert_eq!(
                (f.iterations, f.log_likelihood, f.total_weight),
                (0, 0.0, 0.0)
            );
            assert!(scratch.log_likelihoods().is_empty());
        }
    }

    #[test]
    fn texel_round_trip_and_appendix_interpolation() {
        let mut rng = Rng(6);
        let (mut worst_mu, mut worst_var) = (0.0_f64, 0.0_f64);
        for _ in 0..10_000 {
            let g = Gaussian {
                alpha: rng.uniform(),
                mean: project(rng.upper()),
                variance: VARIANCE_MIN + 0.3 * rng.uniform().powi(4),
            };
            // f64: exact up to rounding.
            let t = g.texel();
            let d = Gaussian::from_moments(t[0], DVec2::new(t[1], t[2]), t[3]);
            assert_eq!(d.alpha, g.alpha);
            assert!((d.mean - g.mean).length() < 1e-15);
            assert!((d.variance - g.variance).abs() < 1e-15);
            // f32.
            let d = Gaussian::from_texel(f32s(t));
            assert!((d.alpha / g.alpha - 1.0).abs() < 1e-7);
            worst_mu = worst_mu.max((d.mean - g.mean).length());
            worst_var = worst_var.max((d.variance - g.variance).abs());
        }
        // Measured: |Δμ| ≤ 1.0e-7, |Δσ²| ≤ 2.0e-7 (cancellation against |μ|² ≤ 1).
        eprintln!("f32 texel: |Δμ| ≤ {worst_mu:.2e}, |Δσ²| ≤ {worst_var:.2e}");
        assert!(worst_mu < 2e-7 && worst_var < 3e-7);

        // Guards.
        assert_eq!(Gaussian::EMPTY.texel(), [0.0; 4]);
        for t in [
            [0.0; 4],
            [-1.0, 0.5, 0.5, 1.0],
            [f32::NAN, 0.0, 0.0, 0.0],
            [f32::INFINITY, 0.0, 0.0, 0.0],
            [0.5, 0.0, f32::INFINITY, 0.0],
        ] {
            let g = Gaussian::from_texel(t);
            assert!(
                g.is_empty() && g.mean.is_finite() && g.variance.is_finite(),
                "{t:?}"
            );
        }
        assert!(Gaussian::from_moments(1e-300, DVec2::new(1e300, 0.0), 0.0).is_empty());
        // A tiny α with a huge αμ (quantization junk) is a finite, negligible component whose
        // mean lifts onto the horizon.
        let g = Gaussian::from_texel([1e-30, 1e30, 0.0, 0.0]);
        assert!(g.mean.is_finite() && g.variance == 0.0);
        let sh = shade(&[[1e-30, 1e30, 0.0, 0.0]], DVec3::X, DVec3::Z, 64.0);
        assert!(sh.diffuse <= 2e-30 && sh.specular.is_finite());
        let g = Gaussian::from_texel([1.0, 0.5, 0.0, 0.1]); // σ² = 0.1 − 0.25 < 0
        assert_eq!((g.mean, g.variance), (DVec2::new(0.5, 0.0), 0.0));
        assert_eq!(
            Gaussian::from_texel([1.0, 0.5, 0.0, f32::NAN]).variance,
            0.0
        );

        // Linear filtering of texels is the Appendix's interpolated component:
        // α̂ = Σ w α, μ̂ = Σ w α μ / α̂, σ̂² = Σ w α (σ² + |μ − μ̂|²) / α̂ (Tan counts the spread
        // of the means in full, module docs).
        let comps = [
            Gaussian {
                alpha: 0.7,
                mean: DVec2::new(0.1, 0.2),
                variance: 0.01,
            },
            Gaussian {
                alpha: 0.2,
                mean: DVec2::new(0.3, -0.1),
                variance: 0.002,
            },
            Gaussian {
                alpha: 0.5,
                mean: DVec2::new(-0.2, 0.4),
                variance: 0.03,
            },
        ];
        let w = [0.5, 0.3, 0.2];
        let mut t = [0.0; 4];
        for (g, wk) in comps.iter().zip(w) {
            for (tc, gc) in t.iter_mut().zip(g.texel()) {
                *tc += wk * gc;
            }
        }
        let d = Gaussian::from_moments(t[0], DVec2::new(t[1], t[2]), t[3]);
        let a: f64 = comps.iter().zip(w).map(|(g, wk)| wk * g.alpha).sum();
        let mu = comps
            .iter()
            .zip(w)
            .map(|(g, wk)| wk * g.alpha * g.mean)
            .sum::<DVec2>()
            / a;
        let var = comps
            .iter()
            .zip(w)
            .map(|(g, wk)| wk * g.alpha * (g.variance + (g.mean - mu).length_squared()))
            .sum::<f64>()
            / a;
        assert!((d.alpha - a).abs() < 1e-15);
        assert!((d.mean - mu).length() < 1e-15);
        assert!((d.variance - var).abs() < 1e-15, "{} {var}", d.variance);
    }

    #[test]
    fn alignment_pulls_means_towards_neighbours() {
        let mut rng = Rng(9);
        let mut normals = cluster(&mut rng, dir(10.0, 0.0), 3f64.to_radians(), 200);
        normals.extend(cluster(&mut rng, dir(45.0, 180.0), 3f64.to_radians(), 200));
        let init = [
            init_single(dir(12.0, 5.0).as_vec3()),
            init_single(dir(40.0, 175.0).as_vec3()),
        ]
        .map(|g| Gaussian {
            alpha: 0.5,
            variance: INIT_VARIANCE_MIN,
            ..g
        });
        // The neighbours' component 0 sits 0.3 away from the data's component 0 (towards
        // -y); their component 1 is empty (or missing).
        let nb = [
            Gaussian {
                alpha: 0.8,
                mean: project(dir(10.0, 0.0)) - DVec2::new(0.0, 0.3),
                variance: 1e-3,
            },
            Gaussian::EMPTY,
        ];
        let neighbours: [&[Gaussian]; 3] = [&nb, &nb, &nb[..1]];
        let mut scratch = TanScratch::new();
        let opts = EmOptions::default();
        let input = EmInput::new(&normals);
        let free = fit(&input, &init, &opts, None, &mut scratch);
        assert_finite(&free);
        let mut previous = (free.gaussians()[0].mean - nb[0].mean).length();
        for c in [0.5, 5.0, 50.0, 500.0] {
            let align = GaussianAlignment {
                strength: c,
                neighbours: &neighbours,
            };
            let (ps, pw) = align.pull(0);
            assert!((ps - c * 2.4 * nb[0].mean).length() < 1e-12 && (pw - c * 2.4).abs() < 1e-12);
            assert_eq!(align.pull(1), (DVec2::ZERO, 0.0));
            let f = fit(&input, &init, &opts, Some(&align), &mut scratch);
            assert_finite(&f);
            let g = f.gaussians()[0];
            let d = (g.mean - nb[0].mean).length();
            // Tan's update at the fixed point: μ = (Σ Ez p + c Σ α_k μ_k)/(Σ Ez + c Σ α_k),
            // with Σ Ez = 200 samples (unit weights) and the data mean of cluster 0.
            let data = stats(&normals, &[1.0; 400], |i| i < 200).1;
            let expected = (200.0 * data + ps) / (200.0 + pw);
            eprintln!(
                "c = {c}: component 0 is {d:.4} from the neighbours (before {previous:.4}), σ² {:.2e}",
                g.variance
            );
            assert!((g.mean - expected).length() < 1e-6, "{} {expected}", g.mean);
            assert!(d < previous - 1e-3, "c = {c}: {d} vs {previous}");
            previous = d;
            // Component 1 has no neighbour to follow; it only moves as far as component 0,
            // widened by the pull, takes a share of its samples (measured: < 1e-9 for c ≤ 5,
            // 3e-3 at c = 500).
            let moved = (f.gaussians()[1].mean - free.gaussians()[1].mean).length();
            assert!(
                moved < if c <= 5.0 { 1e-9 } else { 1e-2 },
                "c = {c}: {moved}"
            );
        }
        // c = 0 is the free fit, bit for bit; so is an alignment with no neighbours.
        for (c, nbs) in [(0.0, &neighbours[..]), (1.0, &[][..])] {
            let align = GaussianAlignment {
                strength: c,
                neighbours: nbs,
            };
            assert_eq!(fit(&input, &init, &opts, Some(&align), &mut scratch), free);
        }
        // The prior weighs like samples: with weights 1/400 (footprint fractions), the data
        // still count as 400 samples, so the result is the same as with unit weights.
        let align = GaussianAlignment {
            strength: 5.0,
            neighbours: &neighbours,
        };
        let a = fit(&input, &init, &opts, Some(&align), &mut scratch);
        let fractions = [1.0 / 400.0; 400];
        let b = fit(
            &input.with_weights(&fractions),
            &init,
            &opts,
            Some(&align),
            &mut scratch,
        );
        for (ga, gb) in a.gaussians().iter().zip(b.gaussians()) {
            assert!((ga.mean - gb.mean).length() < 1e-12 && (ga.alpha - gb.alpha).abs() < 1e-12);
        }
    }

    /// Han 2007 (Sec 7.1, Fig 7): Tan's planar projection distorts lobes near the horizon. The
    /// same isotropic angular cluster (δ = 1° per axis) is fitted at the pole and at 80°.
    #[test]
    fn planar_projection_distorts_near_the_horizon() {
        let delta = 1f64.to_radians();
        let s = 1000.0;
        let mut rng = Rng(10);
        let mut fitted = Vec::new();
        for theta in [0.0, 80.0] {
            let centre = dir(theta, 30.0);
            let normals = cluster(&mut rng, centre, delta, 20_000);
            let mut scratch = TanScratch::new();
            let init = farthest_first(&[init_single(centre.as_vec3())], 1);
            let f = fit(
                &EmInput::new(&normals),
                &init,
                &EmOptions::default(),
                None,
                &mut scratch,
            );
            assert_finite(&f);
            let g = f.gaussians()[0];
            let mu3 = lift(g.mean);
            // Spherical reading of the planar Gaussian: along the polar direction a planar
            // offset dr is an angle dr / cos θ, so the polar-angle variance is σ² / μ3.z².
            let polar = g.variance / (mu3.z * mu3.z);
            // Shading at the highlight (l = v = centre): the filtered lobe against the exact
            // average of the unfiltered BRDF over the cluster.
            let (l, h) = (centre, centre);
            let exact: f64 = normals
                .iter()
                .map(|n| reference(n.as_dvec3().normalize(), l, h, s).specular)
                .sum::<f64>()
                / normals.len() as f64;
            let got = shade(&[f32s(g.texel())], l, h, s).specular;
            let err = got / exact - 1.0;
            eprintln!(
                "θ = {theta}°: planar σ² = {:.4e} ({:.3} δ²), polar-angle variance {:.3} δ², \
                 specular at the highlight {got:.2} vs exact {exact:.2} ({:+.1} %)",
                g.variance,
                g.variance / (delta * delta),
                polar / (delta * delta),
                100.0 * err
            );
            fitted.push((g.variance, polar, err));
        }
        let (planar_ratio, polar_ratio) = (fitted[1].0 / fitted[0].0, fitted[1].1 / fitted[0].1);
        eprintln!(
            "80° vs pole: planar σ² ×{planar_ratio:.3}, polar-angle variance ×{polar_ratio:.2}"
        );
        // Measured: planar σ² ×0.523 (0.514 δ² against 0.983 δ²) — the projection compresses
        // the radial spread by cos 80° = 0.17 (expected (1 + cos²80°)/2 = 0.515) — while the
        // fitted isotropic planar Gaussian, read back on the sphere, spreads ×17.0 wider in
        // polar angle than the same fit at the pole (expected 0.515 / cos²80° = 17.1) and
        // ×0.52 as wide in azimuth: it cannot represent the 33:1 anisotropy the projection
        // gives the cluster. Shading (σ² added isotropically in μ's tangent frame) therefore
        // under-widens the highlight at 80°: +12.6 % at its peak (s = 1000) against +0.1 %
        // at the pole. So the planar variance is *smaller* near the horizon, not larger; the
        // distortion is its anisotropy on the sphere.
        assert!((planar_ratio - 0.515).abs() < 0.03, "{planar_ratio}");
        assert!(polar_ratio > 15.0, "{polar_ratio}");
        assert!(fitted[0].2.abs() < 0.02, "pole: {}", fitted[0].2);
        assert!(fitted[1].2 > 0.05, "80°: {}", fitted[1].2);
    }

    #[test]
    fn features_per_component_eq22() {
        let mut rng = Rng(21);
        let red = [1.0f32, 0.0, 0.0, 1.0];
        let blue = [0.0f32, 0.0, 1.0, 0.0];
        let (ca, cb) = (dir(10.0, 0.0), dir(50.0, 120.0));
        let mut normals = Vec::new();
        let mut colours = Vec::new();
        for i in 0..2000 {
            let (c, y) = if i % 3 == 0 { (cb, blue) } else { (ca, red) };
            normals.push(around(&mut rng, c, 2f64.to_radians()).as_vec3());
            colours.push(y);
        }
        let init = [
            Gaussian {
                alpha: 1.0,
                mean: project(ca) + 0.05,
                variance: 0.01,
            },
            Gaussian {
                alpha: 1.0,
                mean: project(cb) - 0.05,
                variance: 0.01,
            },
            Gaussian {
                alpha: 0.0,
                ..init_single(Vec3::X)
            },
        ];
        let mut scratch = TanScratch::new();
        let input = EmInput::new(&normals).with_features(&colours);
        let f = fit(&input, &init, &EmOptions::default(), None, &mut scratch);
        assert_finite(&f);
        let y = f.features();
        for c in 0..4 {
            assert!((y[0][c] - f64::from(red[c])).abs() < 1e-9, "{:?}", y[0]);
            assert!((y[1][c] - f64::from(blue[c])).abs() < 1e-9, "{:?}", y[1]);
        }
        assert_eq!(y[2], [0.0; 4]);
        assert!((f.gaussians()[0].alpha - 2.0 / 3.0).abs() < 1e-3);
        // Without features: zero features, the same components.
        let g = fit(
            &EmInput::new(&normals),
            &init,
            &EmOptions::default(),
            None,
            &mut scratch,
        );
        assert_eq!(g.gaussians(), f.gaussians());
        assert_eq!(g.features()[0], [0.0; 4]);
        // One component: y is the weighted mean of the features.
        let grey: Vec<[f32; 4]> = (0..normals.len()).map(|i| [i as f32 / 2000.0; 4]).collect();
        let f = fit(
            &EmInput::new(&normals).with_features(&grey),
            &init[..1],
            &EmOptions::default(),
            None,
            &mut scratch,
        );
        let mean: f64 = grey.iter().map(|y| f64::from(y[0])).sum::<f64>() / 2000.0;
        assert!((f.features()[0][0] - mean).abs() < 1e-12);
    }

    #[test]
    fn weights_act_like_repetition_and_junk_changes_nothing() {
        let normals = [
            Vec3::Z,
            Vec3::X,
            Vec3::new(0.0, 0.6, 0.8),
            Vec3::new(0.1, 0.1, 1.0),
        ];
        let weights = [3.0, 1.0, 2.0, 1.0];
        let repeated: Vec<Vec3> = [0, 0, 0, 1, 2, 2, 3].iter().map(|&i| normals[i]).collect();
        let init = [
            Gaussian {
                alpha: 0.5,
                mean: DVec2::new(0.1, 0.2),
                variance: 0.05,
            },
            Gaussian {
                alpha: 0.5,
                mean: DVec2::new(0.9, 0.0),
                variance: 0.05,
            },
        ];
        let mut scratch = TanScratch::new();
        let opts = EmOptions::default();
        let a = fit(
            &EmInput::new(&normals).with_weights(&weights),
            &init,
            &opts,
            None,
            &mut scratch,
        );
        let b = fit(&EmInput::new(&repeated), &init, &opts, None, &mut scratch);
        for (ga, gb) in a.gaussians().iter().zip(b.gaussians()) {
            assert!((ga.alpha - gb.alpha).abs() < 1e-12);
            assert!((ga.mean - gb.mean).length() < 1e-12);
            assert!((ga.variance - gb.variance).abs() < 1e-12);
        }

        let mut rng = Rng(77);
        let mut normals = cluster(&mut rng, dir(20.0, 0.0), 0.1, 300);
        normals.extend(cluster(&mut rng, dir(50.0, 200.0), 0.05, 200));
        let weights: Vec<f64> = (0..normals.len()).map(|_| rng.uniform()).collect();
        let candidates: Vec<Gaussian> = normals
            .iter()
            .step_by(40)
            .map(|&v| init_single(v))
            .collect();
        let init = farthest_first(&candidates, 3);
        let base = fit(
            &EmInput::new(&normals).with_weights(&weights),
            &init,
            &opts,
            None,
            &mut scratch,
        );
        let base_ll = scratch.log_likelihoods().to_vec();
        // Interleave junk with zero or invalid weights, and junk normals.
        let (mut n2, mut w2) = (Vec::new(), Vec::new());
        for (i, (&v, &w)) in normals.iter().zip(&weights).enumerate() {
            n2.push(v);
            w2.push(w);
            n2.push(rng.upper().as_vec3());
            w2.push([0.0, -1.0, f64::NAN, 0.0][i % 4]);
            if i % 50 == 0 {
                n2.extend([Vec3::ZERO, Vec3::NAN]);
                w2.extend([1.0, 0.5]);
            }
        }
        let other = fit(
            &EmInput::new(&n2).with_weights(&w2),
            &init,
            &opts,
            None,
            &mut scratch,
        );
        assert_eq!(base, other);
        assert_eq!(base_ll, scratch.log_likelihoods());
        // Determinism: the same call twice is bit-identical.
        let again = fit(
            &EmInput::new(&n2).with_weights(&w2),
            &init,
            &opts,
            None,
            &mut scratch,
        );
        assert_eq!(other, again);
        // Absurd weight scales change nothing but the reported total.
        for scale in [1e300, 1e-300] {
            let w: Vec<f64> = weights.iter().map(|w| w * scale).collect();
            let f = fit(
                &EmInput::new(&normals).with_weights(&w),
                &init,
                &opts,
                None,
                &mut scratch,
            );
            assert_finite(&f);
            for (ga, gb) in f.gaussians().iter().zip(base.gaussians()) {
                assert!((ga.alpha - gb.alpha).abs() < 1e-9 && (ga.mean - gb.mean).length() < 1e-9);
            }
        }
    }

    #[test]
    fn init_helpers() {
        let g = init_single(Vec3::new(0.0, 0.0, 2.0));
        assert_eq!(
            g,
            Gaussian {
                alpha: 1.0,
                mean: DVec2::ZERO,
                variance: VARIANCE_MIN
            }
        );
        assert_eq!(init_single(Vec3::ZERO).mean, DVec2::ZERO);
        assert_eq!(
            init_single(Vec3::new(3.0, 0.0, 4.0)).mean,
            DVec2::new(0.6, 0.0)
        );

        let at = |x: f64, y: f64| DVec2::new(x, y);
        let c = [
            Gaussian {
                alpha: 0.2,
                mean: at(0.0, 0.0),
                variance: 0.01,
            },
            Gaussian {
                alpha: 0.5,
                mean: at(0.05, 0.0),
                variance: 0.02,
            },
            Gaussian {
                alpha: 0.3,
                mean: at(0.9, 0.0),
                variance: 0.03,
            },
            Gaussian {
                alpha: 0.0,
                mean: at(-0.9, 0.0),
                variance: 0.04,
            }, // empty: skipped
            Gaussian {
                alpha: 0.4,
                mean: at(-0.5, 0.5),
                variance: 0.05,
            },
            Gaussian {
                alpha: f64::NAN,
                mean: at(0.0, -0.9),
                variance: 0.06,
            }, // invalid
        ];
        let out = farthest_first(&c, 2);
        assert_eq!(out.len(), 2);
        assert_eq!((out[0].variance, out[1].variance), (0.02, 0.03));
        assert!(
            (out[0].alpha - 0.5 / 0.8).abs() < 1e-15 && (out[1].alpha - 0.3 / 0.8).abs() < 1e-15
        );
        assert_eq!(farthest_first(&c, 3)[2].variance, 0.05);
        // Fewer distinct candidates than J: empty fillers, still exactly J components.
        let out = farthest_first(&c, 6);
        assert_eq!(
            out.iter().map(|g| g.variance).collect::<Vec<_>>()[..4],
            [0.02, 0.03, 0.05, 0.01]
        );
        assert!(out[..4].iter().all(|g| g.alpha > 0.0));
        assert!(
            out[4..]
                .iter()
                .all(|g| g.alpha == 0.0 && g.mean.is_finite())
        );
        assert!((out.iter().map(|g| g.alpha).sum::<f64>() - 1.0).abs() < 1e-15);
        // Initial variances are capped from below (so EM can move) and above.
        let needles: Vec<Gaussian> = [Vec3::Z, Vec3::X].map(init_single).to_vec();
        assert!(
            farthest_first(&needles, 2)
                .iter()
                .all(|g| g.variance == INIT_VARIANCE_MIN)
        );
        let wide = [Gaussian {
            variance: 9.0,
            ..needles[0]
        }];
        assert_eq!(farthest_first(&wide, 1)[0].variance, VARIANCE_MAX);
        // Duplicates count once; ties go to the lower index.
        let d = [Vec3::Z, Vec3::Z, Vec3::X, Vec3::X].map(init_single);
        let out = farthest_first(&d, 3);
        assert_eq!((out[0].mean, out[1].mean), (DVec2::ZERO, DVec2::X));
        assert_eq!((out[0].alpha, out[1].alpha, out[2].alpha), (0.5, 0.5, 0.0));
        // No valid candidate at all; J = 0.
        assert_eq!(
            farthest_first(&[Gaussian::EMPTY; 3], 2),
            vec![Gaussian::EMPTY; 2]
        );
        assert_eq!(farthest_first(&[], 2), vec![Gaussian::EMPTY; 2]);
        assert!(farthest_first(&c, 0).is_empty());
        // More than 64 candidates (heap path) follows the same rule.
        let mut rng = Rng(5);
        let many: Vec<Gaussian> = (0..100)
            .map(|_| Gaussian {
                alpha: rng.uniform(),
                mean: project(rng.upper()),
                variance: 0.01,
            })
            .collect();
        let out = farthest_first(&many, 8);
        assert!(out.iter().all(|g| g.alpha > 0.0));
        let first = many.iter().map(|g| g.alpha).fold(0.0, f64::max);
        assert_eq!(
            out[0].mean,
            many.iter().find(|g| g.alpha == first).unwrap().mean
        );
        let mut small = [Gaussian::EMPTY; 8];
        farthest_first_into(&many, &mut small);
        assert_eq!(small.to_vec(), out);
    }

    #[test]
    fn options_and_history() {
        let mut rng = Rng(3);
        let normals = cluster(&mut rng, dir(30.0, 60.0), 0.2, 300);
        let candidates: Vec<Gaussian> = normals[..12].iter().map(|&v| init_single(v)).collect();
        let init = farthest_first(&candidates, 3);
        let mut scratch = TanScratch::new();
        let zero = EmOptions {
            max_iterations: 0,
            ..EmOptions::default()
        };
        let f = fit(&EmInput::new(&normals), &init, &zero, None, &mut scratch);
        assert_eq!((f.iterations, f.converged), (0, false));
        assert_eq!(f.gaussians(), &init[..]);
        assert_eq!(scratch.log_likelihoods().len(), 1);
        let long = EmOptions {
            max_iterations: 1000,
            ..EmOptions::default()
        };
        let f = fit(&EmInput::new(&normals), &init, &long, None, &mut scratch);
        assert!(f.converged && f.iterations > 1);
        assert_eq!(scratch.log_likelihoods().len(), f.iterations as usize + 1);
        assert_eq!(*scratch.log_likelihoods().last().unwrap(), f.log_likelihood);
        assert_eq!(f.texel(1), f.gaussians()[1].texel());
        // The reported likelihood is the mixture's, evaluated directly.
        let direct = normals
            .iter()
            .map(|v| {
                let p = project(v.as_dvec3().normalize());
                f.gaussians().iter().map(|g| g.eval(p)).sum::<f64>().ln()
            })
            .sum::<f64>()
            / normals.len() as f64;
        assert!((direct - f.log_likelihood).abs() < 1e-12 * direct.abs().max(1.0));
    }

    /// Time per [`fit`] call (J = 6, default options) for N normals drawn from random
    /// 4-cluster data, initialized by [`farthest_first`] over the normals' own finest-level
    /// components. Run with
    /// `cargo test --release --lib tan2005::tests::timing -- --ignored --nocapture --test-threads 1`.
    #[test]
    #[ignore = "timing; run in release mode"]
    fn timing_n4() {
        time_fits(4, 100_000);
    }

    /// See [`timing_n4`].
    #[test]
    #[ignore = "timing; run in release mode"]
    fn timing_n16() {
        time_fits(16, 20_000);
    }

    /// See [`timing_n4`].
    #[test]
    #[ignore = "timing; run in release mode"]
    fn timing_n1024() {
        time_fits(1024, 400);
    }

    fn time_fits(n: usize, texels: usize) {
        let mut rng = Rng(42);
        let data: Vec<Vec<Vec3>> = (0..texels)
            .map(|_| {
                let centres: Vec<(DVec3, f64)> = (0..4)
                    .map(|_| {
                        (
                            dir(70.0 * rng.uniform(), 360.0 * rng.uniform()),
                            0.02 + 0.2 * rng.uniform(),
                        )
                    })
                    .collect();
                (0..n)
                    .map(|i| around(&mut rng, centres[i % 4].0, centres[i % 4].1).as_vec3())
                    .collect()
            })
            .collect();
        let inits: Vec<Vec<Gaussian>> = data
            .iter()
            .map(|normals| {
                let c: Vec<Gaussian> = normals.iter().take(24).map(|&v| init_single(v)).collect();
                farthest_first(&c, 6)
            })
            .collect();
        let mut scratch = TanScratch::new();
        let opts = EmOptions::default();
        let mut iterations = 0u64;
        let start = std::time::Instant::now();
        for (normals, init) in data.iter().zip(&inits) {
            let f = fit(&EmInput::new(normals), init, &opts, None, &mut scratch);
            iterations += u64::from(f.iterations);
        }
        let dt = start.elapsed().as_secs_f64() / texels as f64;
        eprintln!(
            "N = {n}, J = 6: {:.2} µs per fit, {:.1} iterations on average, {:.1} ns per normal·component·iteration",
            dt * 1e6,
            iterations as f64 / texels as f64,
            dt * 1e9 / (n as f64 * 6.0 * (1.0 + iterations as f64 / texels as f64))
        );
    }
}
