//! Mixture bakes: one EM fit per texel of every MIP level, over *all* finest normals the texel
//! covers (exact footprints, [`crate::pyramid`]), for any [`Model`]: the paper's vMF lobes
//! (Algorithm 1, [`crate::em`]) and Tan et al. 2005's planar Gaussians ([`crate::tan2005`]).
//!
//! **Unaligned** (Sec 7.1): levels are fitted from the finest up. The finest texel holds one
//! component, `α = 1` and as sharp as storable (vMF: `μ = n, κ = KAPPA_MAX`); a coarser texel
//! starts EM from the J furthest-apart of its children's components (Hochbaum–Shmoys,
//! [`crate::em::farthest_first`]). A texel with no more normals than components gets the
//! closed-form answer (one component per normal) without EM.
//!
//! **Aligned** (Sec 7.3, the appendix's eq 29 or the main text's eq 23): after the unaligned
//! pass, levels are
//! refitted from the coarsest down. Each texel starts from its own unaligned fit with its
//! components moved to the slots of the parent's components they are closest to (so slot j keeps
//! its meaning down the chain), and EM runs pulled, with strength C, towards slot j of the
//! previously visited neighbours — left, upper-left, up, upper-right in scan-line order — and of
//! the parent. Scan-line order is kept exactly, yet texels run in parallel along wavefronts
//! `x + 2y = const`, whose texels depend only on earlier wavefronts; the result is the same for
//! any thread count. At the finest level the single normal goes, unpulled, to the parent's slot
//! that explains it best (so level 0 stays exact). Under eq 29 a texel with no more normals than
//! lobes (level 1) takes the closed form in the parent's slots: its lobes are as sharp as
//! storable, so eq 29's pull, `C/(κα)`, would tilt them by under 10 µrad (texels
//! where it could tilt more run EM).
//!
//! Colour (eq 22): with a feature image, each component also gets `y_j = Σ z_ij y_i / Σ z_ij`,
//! stored as `α_j y_j`.

use crate::bake::{
    Bake, BakeOptions, CancelFlag, MAX_ALIGN_STRENGTH, MAX_EM_ITERATIONS, MAX_EM_TOLERANCE, Method,
    Progress, Texture,
};
use crate::em::{self, Alignment, AlignmentForm, EmInput, EmScratch, MAX_LOBES};
use crate::error::{Error, Result};
use crate::format::{Format, ValueRange};
use crate::ingest::NormalMap;
use crate::pyramid::{AxisFootprints, LevelFootprints, level_sizes};
use crate::tan2005::{self, Gaussian, GaussianAlignment, TanScratch};
use crate::vmf::{KAPPA_MAX, Lobe};
use glam::Vec3;
use rayon::prelude::*;

/// What the per-level driver needs of a mixture model: its components (vMF lobes, Tan's planar
/// Gaussians), their one-texel EM, and their texture form.
pub(crate) trait Model: Sync {
    /// One mixture component.
    type C: Copy + Send + Sync;
    /// Reusable working memory of one EM run.
    type Scratch: Default + Send;
    /// The method this model bakes.
    const METHOD: Method;
    /// The empty component (α = 0); encodes as a zero texel.
    const EMPTY: Self::C;
    /// Texture names of the component chains.
    const NAMES: [&'static str; MAX_LOBES];
    /// Meaning of R, G, B, A of a component texel.
    const CHANNELS: [&'static str; 4];
    /// Value ranges of a component texel.
    const RANGES: [ValueRange; 4];
    /// The finest level's component for one normal (α = 1, as sharp as storable).
    fn single(n: Vec3) -> Self::C;
    /// The component's α.
    fn alpha(c: &Self::C) -> f64;
    /// The component with α replaced.
    fn with_alpha(c: &Self::C, alpha: f64) -> Self::C;
    /// How alike two components' directions are (larger is closer); used to match slots.
    fn closeness(a: &Self::C, b: &Self::C) -> f64;
    /// `ln(α p(n))`, the E-step's score of normal `n` under `c` (−∞ for an empty one).
    fn log_score(c: &Self::C, n: Vec3) -> f64;
    /// Furthest-first initialization from candidate components (Sec 7.1).
    fn farthest_first(candidates: &[Self::C], j: usize) -> Vec<Self::C>;
    /// One texel's EM from `init` (`options.em`), optionally pulled towards `neighbours` with
    /// the strength (and, for vMF, the form) of `options`' alignment. `cancel` is the bake's
    /// cancellation flag: a fit may stop early once it is set (its result is then discarded).
    fn fit(
        input: &EmInput,
        init: &[Self::C],
        options: &BakeOptions,
        neighbours: Option<&[&[Self::C]]>,
        scratch: &mut Self::Scratch,
        cancel: &CancelFlag,
    ) -> TexelFit<Self::C>;
    /// Whether, in the aligned pass, a texel with no more samples than components, the
    /// lightest of weight fraction `min_alpha`, may take the closed-form fit (one component
    /// per sample) in its parent's slots instead of running the pulled EM: true when the pull
    /// on such (maximally sharp) components is negligible.
    fn closed_form_when_aligned(options: &BakeOptions, min_alpha: f64) -> bool;
    /// The component's texel.
    fn texel(c: &Self::C) -> [f64; 4];
    /// The component as a sample of the approximate mode: its mean vector, or `None` when the
    /// model has no approximate mode.
    fn mean_vector(c: &Self::C) -> Option<Vec3>;
}

/// The paper's vMF lobes (Sec 7).
pub(crate) struct VmfModel;

impl Model for VmfModel {
    type C = Lobe;
    type Scratch = EmScratch;
    const METHOD: Method = Method::Vmf;
    const EMPTY: Lobe = Lobe::EMPTY;
    const NAMES: [&'static str; MAX_LOBES] = [
        "lobe0", "lobe1", "lobe2", "lobe3", "lobe4", "lobe5", "lobe6", "lobe7",
    ];
    const CHANNELS: [&'static str; 4] = ["alpha", "alpha*r_x", "alpha*r_y", "alpha*r_z"];
    const RANGES: [ValueRange; 4] = [
        ValueRange::Unit,
        ValueRange::Signed,
        ValueRange::Signed,
        ValueRange::Signed,
    ];
    fn single(n: Vec3) -> Lobe {
        em::init_single(n)
    }
    fn alpha(c: &Lobe) -> f64 {
        c.alpha
    }
    fn with_alpha(c: &Lobe, alpha: f64) -> Lobe {
        Lobe { alpha, ..*c }
    }
    fn closeness(a: &Lobe, b: &Lobe) -> f64 {
        a.mu.dot(b.mu)
    }
    fn log_score(c: &Lobe, n: Vec3) -> f64 {
        if c.is_empty() {
            f64::NEG_INFINITY
        } else {
            c.alpha.ln() + crate::vmf::log_density(n.as_dvec3().dot(c.mu), c.kappa)
        }
    }
    fn farthest_first(candidates: &[Lobe], j: usize) -> Vec<Lobe> {
        em::farthest_first(candidates, j)
    }
    fn fit(
        input: &EmInput,
        init: &[Lobe],
        options: &BakeOptions,
        neighbours: Option<&[&[Lobe]]>,
        scratch: &mut EmScratch,
        cancel: &CancelFlag,
    ) -> TexelFit<Lobe> {
        // em::fit does not take the flag yet: a texel's fit runs to its end (at most
        // MAX_EM_ITERATIONS), the driver polls the flag between texels.
        let _ = cancel;
        let alignment = neighbours.map(|neighbours| Alignment {
            strength: options.align.unwrap_or(0.0),
            neighbours,
            form: options.align_form,
        });
        let f = em::fit(input, init, &options.em, alignment.as_ref(), scratch);
        let lobes = f.lobes().to_vec();
        let texels = (0..lobes.len()).map(|j| f.texel(j)).collect();
        (lobes, f.features().to_vec(), texels)
    }
    fn texel(c: &Lobe) -> [f64; 4] {
        c.texel()
    }
    fn closed_form_when_aligned(options: &BakeOptions, min_alpha: f64) -> bool {
        // Eq 29 tilts a lobe by at most atan(C |Σ_k α_jk μ_jk| / (κ α_j)) ≤ C K / (κ α_j), with
        // K ≤ ALIGN_NEIGHBOURS lobes of α ≤ 1 pulling. The closed form's lobes have κ =
        // KAPPA_MAX ≈ 4.2e6: with C = 1 and four normals per texel (α = 1/4) that is under
        // 5 µrad. Eq 23 pulls every lobe alike, so it runs EM.
        let c = options.align.unwrap_or(0.0);
        options.align_form == AlignmentForm::Appendix
            && c * ALIGN_NEIGHBOURS as f64 <= CLOSED_FORM_TILT * KAPPA_MAX * min_alpha
    }
    fn mean_vector(c: &Lobe) -> Option<Vec3> {
        let t = c.texel();
        (t[0] > 0.0)
            .then(|| glam::DVec3::new(t[1], t[2], t[3]) / t[0])
            .map(|r| r.as_vec3())
    }
}

/// Tan et al. 2005's planar Gaussians ([`crate::tan2005`]): the paper's comparison row.
pub(crate) struct TanModel;

impl Model for TanModel {
    type C = Gaussian;
    type Scratch = TanScratch;
    const METHOD: Method = Method::Tan2005;
    const EMPTY: Gaussian = Gaussian::EMPTY;
    const NAMES: [&'static str; MAX_LOBES] = [
        "gauss0", "gauss1", "gauss2", "gauss3", "gauss4", "gauss5", "gauss6", "gauss7",
    ];
    const CHANNELS: [&'static str; 4] = [
        "alpha",
        "alpha*mu_x",
        "alpha*mu_y",
        "alpha*(sigma^2+|mu|^2)",
    ];
    // α(σ² + |μ|²) reaches 3α (σ² ≤ VARIANCE_MAX = 2): float formats, as Tan stores it.
    const RANGES: [ValueRange; 4] = [
        ValueRange::Unit,
        ValueRange::Signed,
        ValueRange::Signed,
        ValueRange::Any,
    ];
    fn single(n: Vec3) -> Gaussian {
        tan2005::init_single(n)
    }
    fn alpha(c: &Gaussian) -> f64 {
        c.alpha
    }
    fn with_alpha(c: &Gaussian, alpha: f64) -> Gaussian {
        Gaussian { alpha, ..*c }
    }
    fn closeness(a: &Gaussian, b: &Gaussian) -> f64 {
        -(a.mean - b.mean).length_squared()
    }
    fn log_score(c: &Gaussian, n: Vec3) -> f64 {
        if c.is_empty() {
            f64::NEG_INFINITY
        } else {
            c.alpha.ln() + c.log_density(tan2005::project(n.as_dvec3()))
        }
    }
    fn farthest_first(candidates: &[Gaussian], j: usize) -> Vec<Gaussian> {
        tan2005::farthest_first(candidates, j)
    }
    fn fit(
        input: &EmInput,
        init: &[Gaussian],
        options: &BakeOptions,
        neighbours: Option<&[&[Gaussian]]>,
        scratch: &mut TanScratch,
        cancel: &CancelFlag,
    ) -> TexelFit<Gaussian> {
        let _ = cancel; // as for vMF: polled between texels
        let alignment = neighbours.map(|neighbours| GaussianAlignment {
            strength: options.align.unwrap_or(0.0),
            neighbours,
        });
        let f = tan2005::fit(input, init, &options.em, alignment.as_ref(), scratch);
        let comps = f.gaussians().to_vec();
        let texels = (0..comps.len()).map(|i| f.texel(i)).collect();
        (comps, f.features().to_vec(), texels)
    }
    fn texel(c: &Gaussian) -> [f64; 4] {
        c.texel()
    }
    fn closed_form_when_aligned(_: &BakeOptions, _: f64) -> bool {
        false // Tan's prior weighs the neighbours like samples: it moves even sharp Gaussians.
    }
    fn mean_vector(_: &Gaussian) -> Option<Vec3> {
        None
    }
}

/// Bakes Tan et al. 2005's Gaussian mixture of `map` with the same driver as vMF.
pub(crate) fn bake_tan2005(
    map: &NormalMap,
    options: &BakeOptions,
    progress: &mut Progress,
) -> Result<Bake> {
    bake_mixture::<TanModel>(map, options, progress)
}

/// Components and colours of every texel of one level: `components[t * J + j]`, and per
/// slot j the texture planes `texels[j][t]` and `colors[j][t]` laid out as the bake stores
/// them (so [`assemble`] moves them without copying).
struct LevelFit<C> {
    /// Empty for the finest level, whose components are the normals themselves (level 1 reads
    /// the normals directly).
    components: Vec<C>,
    /// Per slot: `α_j y_j` of each texel (eq 22), when a feature image is present, as stored
    /// (f32).
    colors: Option<Vec<Vec<[f32; 4]>>>,
    /// Per slot: the texel of each texel's component, as its EM encodes it, as stored (f32).
    /// Empty when the pass's textures are not wanted (the unaligned pass of an aligned bake).
    texels: Vec<Vec<[f32; 4]>>,
}

/// One texel's fit: its components, their eq 22 colours `y_j`, and their texels.
pub(crate) type TexelFit<C> = (Vec<C>, Vec<[f64; 4]>, Vec<[f64; 4]>);

/// Per-thread working memory for gathering a texel's samples.
struct Gather<M: Model> {
    /// True when `normals` holds the mean vectors of finer components (approximate mode).
    mean_vectors: bool,
    normals: Vec<Vec3>,
    weights: Vec<f64>,
    features: Vec<[f32; 4]>,
    candidates: Vec<M::C>,
    scratch: M::Scratch,
}

impl<M: Model> Default for Gather<M> {
    fn default() -> Self {
        Gather {
            mean_vectors: false,
            normals: Vec::new(),
            weights: Vec::new(),
            features: Vec::new(),
            candidates: Vec::new(),
            scratch: M::Scratch::default(),
        }
    }
}

impl<M: Model> Gather<M> {
    /// Collects the finest normals (and features) texel `(x, y)` of `level` covers.
    fn collect(&mut self, map: &NormalMap, level: &LevelFootprints, x: u32, y: u32) {
        self.mean_vectors = false;
        self.normals.clear();
        self.weights.clear();
        self.features.clear();
        let w = map.width() as usize;
        for (fy, wy) in level.y.taps(y as usize) {
            for (fx, wx) in level.x.taps(x as usize) {
                let i = fy as usize * w + fx as usize;
                self.normals.push(map.normals()[i]);
                self.weights.push(wx * wy);
                if let Some(f) = map.feature() {
                    self.features.push(f[i]);
                }
            }
        }
    }

    /// Approximate mode: collects the components of the finer-level texels that texel `(x, y)`
    /// covers (`children`: the finer level's fit, `cx`/`cy` its footprints on this level) as
    /// samples — mean vector, `α × footprint weight`, colour `y`. Returns false (and collects
    /// nothing) when the model has no approximate mode.
    #[allow(clippy::too_many_arguments)]
    fn collect_children(
        &mut self,
        children: &LevelFit<M::C>,
        child_width: u32,
        cx: &AxisFootprints,
        cy: &AxisFootprints,
        x: u32,
        y: u32,
        j: usize,
    ) -> bool {
        self.mean_vectors = true;
        self.normals.clear();
        self.weights.clear();
        self.features.clear();
        for (py, wy) in cy.taps(y as usize) {
            for (px, wx) in cx.taps(x as usize) {
                let p = (py * child_width + px) as usize;
                for (s, c) in children.components[p * j..(p + 1) * j].iter().enumerate() {
                    let a = M::alpha(c);
                    if a <= 0.0 {
                        continue;
                    }
                    let Some(r) = M::mean_vector(c) else {
                        self.mean_vectors = false;
                        return false;
                    };
                    self.normals.push(r);
                    self.weights.push(a * wx * wy);
                    if let Some(colors) = &children.colors {
                        self.features
                            .push(colors[s][p].map(|v| (v as f64 / a) as f32));
                    }
                }
            }
        }
        true
    }

    /// The maximum-likelihood mixture when there are no more samples than components: one
    /// component per normal, `α = w_i / Σw`, as sharp as storable (what EM converges to,
    /// without running it; level 1 of a power-of-two map, 4 normals per texel, is all this).
    fn one_per_normal(&self, j: usize) -> TexelFit<M::C> {
        let total: f64 = self.weights.iter().sum();
        let mut comps = vec![M::EMPTY; j];
        let mut colors = vec![[0.0; 4]; j];
        for (i, (&n, &w)) in self.normals.iter().zip(&self.weights).enumerate() {
            comps[i] = M::with_alpha(&M::single(n), w / total);
            if let Some(f) = self.features.get(i) {
                colors[i] = f.map(|v| v as f64);
            }
        }
        let texels = comps.iter().map(M::texel).collect();
        (comps, colors, texels)
    }

    /// The smallest weight fraction `w_i / Σ w` among the collected samples (1 when none).
    fn min_alpha(&self) -> f64 {
        let total: f64 = self.weights.iter().sum();
        self.weights.iter().fold(1.0_f64, |m, &w| m.min(w / total))
    }

    /// Runs the model's EM on the collected samples.
    fn fit(
        &mut self,
        init: &[M::C],
        options: &BakeOptions,
        neighbours: Option<&[&[M::C]]>,
        cancel: &CancelFlag,
    ) -> TexelFit<M::C> {
        let mut input = EmInput::new(&self.normals).with_weights(&self.weights);
        if !self.features.is_empty() {
            input = input.with_features(&self.features);
        }
        if self.mean_vectors {
            input = input.as_mean_vectors();
        }
        M::fit(&input, init, options, neighbours, &mut self.scratch, cancel)
    }
}

/// Validates the mixture options against their documented ranges (`bake`'s `MAX_*`).
pub(crate) fn check(options: &BakeOptions) -> Result<()> {
    if !(1..=MAX_LOBES).contains(&options.lobes) {
        return Err(Error::InvalidOption(format!(
            "lobe count {} (expected 1 to {MAX_LOBES})",
            options.lobes
        )));
    }
    if let Some(c) = options.align
        && !(0.0..=MAX_ALIGN_STRENGTH).contains(&c)
    {
        return Err(Error::InvalidOption(format!(
            "alignment strength {c} (expected C from 0 to {MAX_ALIGN_STRENGTH})"
        )));
    }
    if !(1..=MAX_EM_ITERATIONS).contains(&options.em.max_iterations) {
        return Err(Error::InvalidOption(format!(
            "EM iterations {} (expected 1 to {MAX_EM_ITERATIONS})",
            options.em.max_iterations
        )));
    }
    if !(0.0..=MAX_EM_TOLERANCE).contains(&options.em.tolerance) {
        return Err(Error::InvalidOption(format!(
            "EM tolerance {} (expected 0 to {MAX_EM_TOLERANCE})",
            options.em.tolerance
        )));
    }
    Ok(())
}

/// `count` planes of `len` texels each, empty (reserved) or zeroed.
fn planes(count: usize, len: usize, zeroed: bool) -> Vec<Vec<[f32; 4]>> {
    (0..count)
        .map(|_| {
            if zeroed {
                vec![[0.0; 4]; len]
            } else {
                Vec::with_capacity(len)
            }
        })
        .collect()
}

impl<C: Copy> LevelFit<C> {
    /// An empty level of `texels` texels of `j` components, to be filled by [`LevelFit::push`]:
    /// with texture planes when `textures`, with colour planes when `colors`.
    fn with_capacity(texels: usize, j: usize, textures: bool, colors: bool) -> Self {
        LevelFit {
            components: Vec::with_capacity(texels * j),
            colors: colors.then(|| planes(j, texels, false)),
            texels: if textures {
                planes(j, texels, false)
            } else {
                Vec::new()
            },
        }
    }

    /// Appends one texel's result (colours become `α_j y_j`).
    fn push<M: Model<C = C>>(&mut self, fit: TexelFit<C>) {
        let (comps, colors, texels) = fit;
        if let Some(dst) = self.colors.as_mut() {
            for ((plane, c), y) in dst.iter_mut().zip(&comps).zip(&colors) {
                plane.push(y.map(|v| (M::alpha(c) * v) as f32));
            }
        }
        self.components.extend_from_slice(&comps);
        for (plane, t) in self.texels.iter_mut().zip(&texels) {
            plane.push(t.map(|v| v as f32));
        }
    }

    /// Stores texel `t`'s result (colours become `α_j y_j`) into a level made with zeroed
    /// planes.
    fn set<M: Model<C = C>>(&mut self, t: usize, fit: TexelFit<C>) {
        let (comps, colors, texels) = fit;
        let j = comps.len();
        self.components[t * j..(t + 1) * j].copy_from_slice(&comps);
        for (plane, v) in self.texels.iter_mut().zip(&texels) {
            plane[t] = v.map(|v| v as f32);
        }
        if let Some(dst) = self.colors.as_mut() {
            for ((plane, c), y) in dst.iter_mut().zip(&comps).zip(&colors) {
                plane[t] = y.map(|v| (M::alpha(c) * v) as f32);
            }
        }
    }
}

/// The finest level's fit: every texel's normal as one component in `slot_of(texel)`.
fn finest_level<M: Model>(
    map: &NormalMap,
    j: usize,
    slot_of: impl Fn(usize) -> usize + Sync,
) -> LevelFit<M::C> {
    let slots: Vec<u8> = (0..map.normals().len())
        .into_par_iter()
        .map(|t| slot_of(t) as u8)
        .collect();
    // Plane s holds the texels whose slot is s; the others are empty (zero).
    let fill = |value: &(dyn Fn(usize) -> [f32; 4] + Sync)| -> Vec<Vec<[f32; 4]>> {
        (0..j)
            .map(|s| {
                slots
                    .par_iter()
                    .enumerate()
                    .map(|(t, &slot)| {
                        if slot as usize == s {
                            value(t)
                        } else {
                            [0.0; 4]
                        }
                    })
                    .collect()
            })
            .collect()
    };
    let texels = fill(&|t| M::texel(&M::single(map.normals()[t])).map(|v| v as f32));
    // α = 1 in the slot: the colour texel is the feature itself.
    let colors = map.feature().map(|f| fill(&|t| f[t]));
    LevelFit {
        components: Vec::new(),
        colors,
        texels,
    }
}

/// The finest level of the unaligned pass of an aligned bake: nothing, since level 1 reads the
/// normals directly and the aligned pass makes its own finest level.
fn placeholder_level<C>() -> LevelFit<C> {
    LevelFit {
        components: Vec::new(),
        colors: None,
        texels: Vec::new(),
    }
}

/// Bakes the vMF mixture of `map` (module docs).
pub(crate) fn bake_vmf(
    map: &NormalMap,
    options: &BakeOptions,
    progress: &mut Progress,
) -> Result<Bake> {
    bake_mixture::<VmfModel>(map, options, progress)
}

/// Most lobes that pull a texel's lobe in the aligned pass: its left, upper-left, upper and
/// upper-right neighbours and its parent.
const ALIGN_NEIGHBOURS: usize = 5;

/// Largest tilt, in radians, that eq 29's pull may give a lobe of a texel that the aligned
/// pass fits in closed form instead of by EM (well below what an f32 texel resolves at the
/// storable κ: the lobe's angular radius `sqrt(2/KAPPA_MAX)` is 690 µrad).
const CLOSED_FORM_TILT: f64 = 1e-5;

/// Texels fitted in parallel between two progress reports of the unaligned pass.
const PROGRESS_CHUNK: u32 = 1 << 14;

/// The part of the whole bake that one pass over the levels covers: `(start, span)`.
type Pass = (f64, f64);

/// Bakes a mixture model for `map`: unaligned, or aligned from the unaligned fits. Each level
/// of a pass counts as an equal share of its progress (every level covers all normals).
pub(crate) fn bake_mixture<M: Model>(
    map: &NormalMap,
    options: &BakeOptions,
    progress: &mut Progress,
) -> Result<Bake> {
    check(options)?;
    let sizes = level_sizes(map.width(), map.height());
    let first_pass = if options.align.is_some() { 0.5 } else { 1.0 };
    let unaligned = bottom_up::<M>(map, options, &sizes, progress, (0.0, first_pass))?;
    let fits = match options.align {
        None => unaligned,
        Some(_) => top_down::<M>(map, options, &sizes, &unaligned, progress, (0.5, 0.5))?,
    };
    Ok(assemble::<M>(map, options, sizes, fits))
}

/// Unaligned: finest level up, each texel initialized from its children's components.
fn bottom_up<M: Model>(
    map: &NormalMap,
    options: &BakeOptions,
    sizes: &[(u32, u32)],
    progress: &mut Progress,
    (start, span): Pass,
) -> Result<Vec<LevelFit<M::C>>> {
    let j = options.lobes;
    let finest = (map.width(), map.height());
    // An aligned bake keeps only this pass's components (and, in approximate mode, its
    // colours, which are the next level's features), not its textures.
    let textures = options.align.is_none();
    let colors = map.feature().is_some() && (textures || options.approximate);
    let mut fits = vec![if textures {
        finest_level::<M>(map, j, |_| 0)
    } else {
        placeholder_level()
    }];
    let steps = sizes.len().saturating_sub(1).max(1) as f64;
    let cancel = progress.cancel_flag();
    for k in 1..sizes.len() {
        let (w, h) = sizes[k];
        let (pw, ph) = sizes[k - 1];
        let level = LevelFootprints::new(finest, (w, h));
        let (cx, cy) = (AxisFootprints::new(pw, w), AxisFootprints::new(ph, h));
        let prev = &fits[k - 1];
        let fit_texel = |g: &mut Gather<M>, t: u32| -> TexelFit<M::C> {
            let (x, y) = (t % w, t / w);
            let fast =
                options.approximate && k >= 2 && g.collect_children(prev, pw, &cx, &cy, x, y, j);
            if !fast {
                g.collect(map, &level, x, y);
                if g.normals.len() <= j {
                    return g.one_per_normal(j);
                }
            }
            g.candidates.clear();
            for (py, wy) in cy.taps(y as usize) {
                for (px, wx) in cx.taps(x as usize) {
                    let p = (py * pw + px) as usize;
                    if k == 1 {
                        let c = M::single(map.normals()[p]);
                        g.candidates.push(M::with_alpha(&c, wx * wy));
                    } else {
                        for c in &prev.components[p * j..(p + 1) * j] {
                            g.candidates.push(M::with_alpha(c, M::alpha(c) * wx * wy));
                        }
                    }
                }
            }
            let init = M::farthest_first(&g.candidates, j);
            g.fit(&init, options, None, cancel)
        };
        let mut out = LevelFit::with_capacity((w * h) as usize, j, textures, colors);
        for lo in (0..w * h).step_by(PROGRESS_CHUNK as usize) {
            let hi = (lo + PROGRESS_CHUNK).min(w * h);
            // Workers poll the cancellation flag between texels.
            let results: Vec<TexelFit<M::C>> = (lo..hi)
                .into_par_iter()
                .map_init(Gather::<M>::default, |g, t| {
                    (!cancel.is_cancelled()).then(|| fit_texel(g, t))
                })
                .collect::<Option<_>>()
                .ok_or(Error::Cancelled)?;
            for r in results {
                out.push::<M>(r);
            }
            let done = (k - 1) as f64 + hi as f64 / (w * h) as f64;
            progress.report(start + span * done / steps)?;
        }
        fits.push(out);
    }
    Ok(fits)
}

/// Index of the parent (next coarser level) texel containing the centre of `x` on an axis of
/// `n` texels whose parent axis has `pn` texels.
fn parent_of(x: u32, n: u32, pn: u32) -> u32 {
    (((2 * x + 1) as u64 * pn as u64) / (2 * n as u64)) as u32
}

/// Puts `own` components into the slots of `reference` ones ([`slot_order`]).
fn match_slots<M: Model>(own: &[M::C], reference: &[M::C]) -> Vec<M::C> {
    slot_order::<M>(own, reference)
        .into_iter()
        .map(|i| i.map_or(M::EMPTY, |i| own[i]))
        .collect()
}

/// Which of `own`'s components goes into each slot of `reference` (`None`: an empty slot):
/// greedily pairs the closest (non-empty) components first, then fills the remaining slots
/// in order. Deterministic.
fn slot_order<M: Model>(own: &[M::C], reference: &[M::C]) -> Vec<Option<usize>> {
    let j = own.len();
    let live = |c: &M::C| M::alpha(c) > 0.0;
    let mut pairs: Vec<(f64, usize, usize)> = Vec::with_capacity(j * j);
    for (i, a) in own.iter().enumerate().filter(|(_, c)| live(c)) {
        for (s, b) in reference.iter().enumerate().filter(|(_, c)| live(c)) {
            pairs.push((M::closeness(a, b), i, s));
        }
    }
    pairs.sort_by(|p, q| q.0.total_cmp(&p.0).then(p.1.cmp(&q.1)).then(p.2.cmp(&q.2)));
    let mut out: Vec<Option<usize>> = vec![None; j];
    let mut used = vec![false; j];
    for (_, i, s) in pairs {
        if !used[i] && out[s].is_none() {
            out[s] = Some(i);
            used[i] = true;
        }
    }
    let mut rest = (0..j).filter(|&i| !used[i]);
    out.into_iter().map(|i| i.or_else(|| rest.next())).collect()
}

/// `fit` with its components (and their colours and texels) moved into the slots of
/// `reference` ([`slot_order`]).
fn into_slots<M: Model>(fit: TexelFit<M::C>, reference: &[M::C]) -> TexelFit<M::C> {
    let (comps, colors, texels) = fit;
    let order = slot_order::<M>(&comps, reference);
    let pick = |i: &Option<usize>| {
        i.map_or((M::EMPTY, [0.0; 4], [0.0; 4]), |i| {
            (comps[i], colors[i], texels[i])
        })
    };
    let mut out: TexelFit<M::C> = (Vec::new(), Vec::new(), Vec::new());
    for (c, y, t) in order.iter().map(pick) {
        out.0.push(c);
        out.1.push(y);
        out.2.push(t);
    }
    out
}

/// Aligned: coarsest level down. Each texel starts from its own unaligned fit with its
/// components matched to the parent's slots, then EM runs pulled towards the visited
/// neighbours and the parent (eq 29 or eq 23 for vMF; Tan's prior for Gaussians). A texel
/// with no more normals than components takes the closed form in the parent's slots when the
/// model says the pull vanishes there ([`Model::closed_form_when_aligned`]).
fn top_down<M: Model>(
    map: &NormalMap,
    options: &BakeOptions,
    sizes: &[(u32, u32)],
    unaligned: &[LevelFit<M::C>],
    progress: &mut Progress,
    (start, span): Pass,
) -> Result<Vec<LevelFit<M::C>>> {
    let j = options.lobes;
    let finest = (map.width(), map.height());
    let levels = sizes.len();
    let mut fits: Vec<Option<LevelFit<M::C>>> = (0..levels).map(|_| None).collect();
    let cancel = progress.cancel_flag();
    for k in (0..levels).rev() {
        let (w, h) = sizes[k];
        let parent = fits.get(k + 1).and_then(|p| p.as_ref());
        let parent_size = sizes.get(k + 1).copied();
        let parent_of_texel = |x: u32, y: u32| -> Option<&[M::C]> {
            let (p, (pw, ph)) = (parent?, parent_size?);
            let i = (parent_of(y, h, ph) * pw + parent_of(x, w, pw)) as usize;
            Some(&p.components[i * j..(i + 1) * j])
        };
        if k == 0 {
            // One normal per texel: it goes, unpulled, to the parent's component that explains
            // it best (the E-step with the parent's components), so level 0 stays exact. A 1×1
            // map has no parent and nothing to align: slot 0.
            let fit0 = finest_level::<M>(map, j, |t| {
                let (x, y) = (t as u32 % w, t as u32 / w);
                let n = map.normals()[t];
                let Some(comps) = parent_of_texel(x, y) else {
                    return 0;
                };
                let mut best = (0, f64::NEG_INFINITY);
                for (s, c) in comps.iter().enumerate() {
                    let score = M::log_score(c, n);
                    if score > best.1 {
                        best = (s, score);
                    }
                }
                best.0
            });
            fits[0] = Some(fit0);
            continue;
        }
        let level = LevelFootprints::new(finest, (w, h));
        // Footprints of this level on the finer one (the approximate mode's samples).
        let finer = sizes[k.saturating_sub(1)];
        let (cx, cy) = (
            AxisFootprints::new(finer.0, w),
            AxisFootprints::new(finer.1, h),
        );
        let texels = (w * h) as usize;
        let mut out = LevelFit {
            components: vec![M::EMPTY; texels * j],
            colors: map.feature().map(|_| planes(j, texels, true)),
            texels: planes(j, texels, true),
        };
        // Wavefronts d = x + 2y: (x−1, y), (x−1, y−1), (x, y−1), (x+1, y−1) lie on earlier ones.
        let wavefronts = w + 2 * (h - 1);
        for d in 0..wavefronts {
            let done = (levels - 1 - k) as f64 + d as f64 / wavefronts as f64;
            progress.report(start + span * done / levels as f64)?;
            // x = d − 2y must lie in [0, w): y > (d − w)/2 and y ≤ d/2.
            let y_lo = if d >= w { (d - w) / 2 + 1 } else { 0 };
            let y_hi = (d / 2).min(h - 1);
            if y_lo > y_hi {
                continue;
            }
            let done = &out;
            // Workers poll the cancellation flag between texels.
            let results: Vec<(u32, u32, TexelFit<M::C>)> = (y_lo..=y_hi)
                .into_par_iter()
                .map_init(Gather::<M>::default, |g, y| {
                    if cancel.is_cancelled() {
                        return None;
                    }
                    let x = d - 2 * y;
                    let at = |xx: i64, yy: i64| -> Option<&[M::C]> {
                        if xx < 0 || yy < 0 || xx >= w as i64 || yy >= h as i64 {
                            return None;
                        }
                        let i = (yy as usize) * w as usize + xx as usize;
                        Some(&done.components[i * j..(i + 1) * j])
                    };
                    let (xi, yi) = (x as i64, y as i64);
                    let mut neighbours: Vec<&[M::C]> = [
                        (xi - 1, yi),
                        (xi - 1, yi - 1),
                        (xi, yi - 1),
                        (xi + 1, yi - 1),
                    ]
                    .into_iter()
                    .filter_map(|(a, b)| at(a, b))
                    .collect();
                    let t = (y * w + x) as usize;
                    let own = &unaligned[k].components[t * j..(t + 1) * j];
                    let parent = parent_of_texel(x, y);
                    let fast = options.approximate
                        && k >= 2
                        && g.collect_children(&unaligned[k - 1], sizes[k - 1].0, &cx, &cy, x, y, j);
                    if !fast {
                        g.collect(map, &level, x, y);
                        if g.normals.len() <= j
                            && M::closed_form_when_aligned(options, g.min_alpha())
                        {
                            let fit = g.one_per_normal(j);
                            let fit = match parent {
                                Some(p) => into_slots::<M>(fit, p),
                                None => fit,
                            };
                            return Some((x, y, fit));
                        }
                    }
                    let init = match parent {
                        Some(p) => {
                            neighbours.push(p);
                            match_slots::<M>(own, p)
                        }
                        None => own.to_vec(),
                    };
                    Some((x, y, g.fit(&init, options, Some(&neighbours), cancel)))
                })
                .collect::<Option<_>>()
                .ok_or(Error::Cancelled)?;
            for (x, y, fit) in results {
                out.set::<M>((y * w + x) as usize, fit);
            }
        }
        fits[k] = Some(out);
    }
    Ok(fits
        .into_iter()
        .map(|f| f.expect("every level fitted"))
        .collect())
}

/// Lays the fits out as textures: J component chains, then J colour chains `α·y`.
fn assemble<M: Model>(
    map: &NormalMap,
    options: &BakeOptions,
    sizes: Vec<(u32, u32)>,
    fits: Vec<LevelFit<M::C>>,
) -> Bake {
    const COLOR_NAMES: [&str; MAX_LOBES] = [
        "color0", "color1", "color2", "color3", "color4", "color5", "color6", "color7",
    ];
    let j = options.lobes;
    let color = map.feature().is_some();
    let mut textures: Vec<Texture> = M::NAMES
        .iter()
        .take(j)
        .map(|&name| Texture {
            name,
            channels: M::CHANNELS,
            ranges: M::RANGES,
            levels: Vec::new(),
        })
        .collect();
    if color {
        textures.extend(COLOR_NAMES.iter().take(j).map(|&name| Texture {
            name,
            channels: ["alpha*y_r", "alpha*y_g", "alpha*y_b", "alpha*y_a"],
            ranges: [ValueRange::Unit; 4],
            levels: Vec::new(),
        }));
    }
    // Move plane s of every level into chain s (and colour chain J + s).
    for fit in fits {
        let mut planes = fit.texels;
        if color {
            planes.extend(fit.colors.expect("features give colours"));
        }
        for (texture, plane) in textures.iter_mut().zip(planes) {
            texture.levels.push(plane);
        }
    }
    let mut parameters = serde_json::json!({
        "lobes": j,
        "aligned": options.align.is_some(),
        "align_strength": options.align,
        "align_form": (M::METHOD == Method::Vmf && options.align.is_some())
            .then(|| options.align_form.name()),
        "color": map.feature().is_some(),
        "approximate": options.approximate && M::METHOD == Method::Vmf,
        "em_max_iterations": options.em.max_iterations,
        "em_tolerance": options.em.tolerance,
    });
    if M::METHOD == Method::Vmf {
        parameters["kappa_max"] = KAPPA_MAX.into();
    }
    Bake {
        method: M::METHOD,
        sizes,
        textures,
        addressing: map.addressing(),
        lobes: j,
        parameters,
        format: Format::F32,
    }
}

/// How well lobe j lines up with lobe j of the neighbouring texels, per level: the mean angle
/// in degrees between the μ of lobe j at `(x, y)` and at its right and lower neighbours
/// (within the level, no wrap), weighted by the smaller of the two α. Small angles are what
/// hardware trilinear interpolation of aligned lobes needs (Sec 7.3); an entry is `None` when
/// the level has no neighbouring non-empty lobes.
pub fn lobe_coherence(bake: &Bake) -> Vec<Option<f64>> {
    let j = bake.lobes;
    (0..bake.level_count())
        .map(|k| {
            let (w, h) = bake.sizes[k];
            let lobe = |x: u32, y: u32, s: usize| {
                let t = bake.textures[s].levels[k][(y * w + x) as usize];
                Lobe::from_moments(
                    t[0] as f64,
                    glam::DVec3::new(t[1] as f64, t[2] as f64, t[3] as f64),
                )
            };
            let (mut sum, mut weight) = (0.0f64, 0.0f64);
            for y in 0..h {
                for x in 0..w {
                    for (nx, ny) in [(x + 1, y), (x, y + 1)] {
                        if nx >= w || ny >= h {
                            continue;
                        }
                        for s in 0..j {
                            let (a, b) = (lobe(x, y, s), lobe(nx, ny, s));
                            let wt = a.alpha.min(b.alpha);
                            if wt > 0.0 {
                                sum += wt * a.mu.dot(b.mu).clamp(-1.0, 1.0).acos().to_degrees();
                                weight += wt;
                            }
                        }
                    }
                }
            }
            (weight > 0.0).then(|| sum / weight)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::Brdf;
    use crate::eval::{default_directions, evaluate};
    use crate::ingest::{Addressing, BadNormals};
    use crate::methods::bake_with;

    fn bumpy(w: u32, h: u32) -> NormalMap {
        let v = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                Vec3::new(
                    (x * 0.7).sin() * 0.5 + (y * 1.9).cos() * 0.2,
                    (y * 0.45).sin() * 0.5,
                    1.0,
                )
            })
            .collect();
        NormalMap::from_vectors(w, h, v, Addressing::Wrap, BadNormals::Repair).unwrap()
    }

    fn opts(lobes: usize, align: Option<f64>) -> BakeOptions {
        BakeOptions {
            lobes,
            align,
            ..BakeOptions::default()
        }
    }

    fn all_finite(b: &Bake) {
        for t in &b.textures {
            for l in &t.levels {
                for v in l.iter().flatten() {
                    assert!(v.is_finite(), "{} holds {v}", t.name);
                }
            }
        }
    }

    #[test]
    fn level_zero_is_exact_and_alphas_sum_to_one() {
        let m = bumpy(12, 10);
        for align in [None, Some(0.1)] {
            let b = bake_with(&m, Method::Vmf, &opts(4, align)).unwrap();
            all_finite(&b);
            for k in 0..b.level_count() {
                let (w, h) = b.sizes[k];
                for t in 0..(w * h) as usize {
                    let sum: f32 = (0..4).map(|s| b.textures[s].levels[k][t][0]).sum();
                    assert!((sum - 1.0).abs() < 1e-5, "level {k} texel {t}: Σα = {sum}");
                }
            }
            let e = evaluate(
                &m,
                &[&b],
                &Brdf::blinn_phong(&[16.0, 512.0]),
                &default_directions(),
            );
            for row in &e {
                // κ is capped at KAPPA_MAX, so s' = s·κ/(κ+s) ≈ s(1 − s/KAPPA_MAX): the relative
                // error of the lobe is about s/KAPPA_MAX (1.2e-4 at s = 512).
                let bound = 2.0 * row.brdf.equivalent_exponent() / KAPPA_MAX;
                assert!(
                    row.levels[0].specular < bound,
                    "{align:?}: {:?}",
                    row.levels[0]
                );
                assert!(row.levels[0].diffuse < 1e-6);
            }
        }
    }

    #[test]
    fn enough_lobes_represent_a_two_by_two_footprint_exactly() {
        // Level 1 of a power-of-two map covers 4 normals: with J ≥ 4 each gets its own lobe.
        let m = bumpy(8, 8);
        let b = bake_with(&m, Method::Vmf, &opts(4, None)).unwrap();
        let e = evaluate(
            &m,
            &[&b],
            &Brdf::blinn_phong(&[64.0]),
            &default_directions(),
        );
        assert!(e[0].levels[1].specular < 1e-3, "{:?}", e[0].levels[1]);
        assert!(e[0].levels[1].diffuse < 1e-6, "{:?}", e[0].levels[1]);
    }

    #[test]
    fn tan2005_bake_is_exact_at_level_zero_and_beats_plain() {
        let m = bumpy(16, 16);
        let t = bake_with(&m, Method::Tan2005, &opts(4, None)).unwrap();
        assert_eq!(t.textures.len(), 4);
        assert_eq!(t.textures[0].name, "gauss0");
        all_finite(&t);
        let p = crate::methods::bake(&m, Method::Plain);
        let e = evaluate(
            &m,
            &[&t, &p],
            &Brdf::blinn_phong(&[64.0]),
            &default_directions(),
        );
        assert!(
            e[0].levels[0].specular < 2.0 * 64.0 / KAPPA_MAX + 1e-6,
            "{:?}",
            e[0].levels[0]
        );
        assert!(e[0].overall_specular < e[1].overall_specular);
    }

    #[test]
    fn vmf_beats_toksvig_on_a_bumpy_map() {
        let m = bumpy(32, 32);
        let v = bake_with(&m, Method::Vmf, &opts(6, None)).unwrap();
        let t = crate::methods::bake(&m, Method::Toksvig);
        let e = evaluate(
            &m,
            &[&v, &t],
            &Brdf::blinn_phong(&[64.0]),
            &default_directions(),
        );
        assert!(
            e[0].overall_specular < 0.7 * e[1].overall_specular,
            "{} vs {}",
            e[0].overall_specular,
            e[1].overall_specular
        );
    }

    #[test]
    fn degenerate_maps_give_finite_lobes() {
        let cases: Vec<(u32, u32, Vec<Vec3>)> = vec![
            (1, 1, vec![Vec3::Z]),
            (1, 5, vec![Vec3::new(0.3, 0.0, 0.9); 5]),
            (
                3,
                5,
                (0..15)
                    .map(|i| if i % 2 == 0 { Vec3::X } else { -Vec3::X })
                    .collect(),
            ),
            (
                4,
                4,
                (0..16)
                    .map(|i| Vec3::new((i as f32).cos(), (i as f32).sin(), 0.0))
                    .collect(),
            ),
            (4, 4, vec![Vec3::Z; 16]),
        ];
        for (w, h, v) in cases {
            let m =
                NormalMap::from_vectors(w, h, v, Addressing::Clamp, BadNormals::Repair).unwrap();
            for method in [Method::Vmf, Method::Tan2005] {
                for align in [None, Some(0.5)] {
                    for lobes in [1, 3, 8] {
                        let b = bake_with(&m, method, &opts(lobes, align)).unwrap();
                        all_finite(&b);
                        assert_eq!(b.sizes.last(), Some(&(1, 1)));
                    }
                }
            }
        }
    }

    #[test]
    fn colour_follows_the_lobes() {
        // Left half tilted +x and red, right half tilted −x and blue: at the 1×1 level two
        // lobes separate the halves and each carries its half's colour (eq 22).
        let (w, h) = (8u32, 8u32);
        let v = (0..w * h)
            .map(|i| {
                if i % w < w / 2 {
                    Vec3::new(0.5, 0.0, 0.8)
                } else {
                    Vec3::new(-0.5, 0.0, 0.8)
                }
            })
            .collect();
        let c = (0..w * h)
            .map(|i| {
                if i % w < w / 2 {
                    [1.0, 0.0, 0.0, 1.0]
                } else {
                    [0.0, 0.0, 1.0, 1.0]
                }
            })
            .collect();
        let m = NormalMap::from_vectors(w, h, v, Addressing::Wrap, BadNormals::Repair)
            .unwrap()
            .with_feature(c)
            .unwrap();
        let b = bake_with(&m, Method::Vmf, &opts(2, None)).unwrap();
        assert_eq!(b.textures.len(), 4);
        let top = b.level_count() - 1;
        for s in 0..2 {
            let lobe = b.textures[s].levels[top][0];
            let color = b.textures[2 + s].levels[top][0];
            assert!((lobe[0] - 0.5).abs() < 1e-4, "α {lobe:?}");
            let want = if lobe[1] > 0.0 {
                [0.5, 0.0, 0.0, 0.5]
            } else {
                [0.0, 0.0, 0.5, 0.5]
            };
            for (a, b) in color.iter().zip(want) {
                assert!((a - b).abs() < 1e-4, "{color:?} vs {want:?}");
            }
        }
    }

    #[test]
    fn output_does_not_depend_on_thread_count() {
        let m = bumpy(16, 12);
        for method in [Method::Vmf, Method::Tan2005] {
            for align in [None, Some(0.2)] {
                let run = |threads| {
                    rayon::ThreadPoolBuilder::new()
                        .num_threads(threads)
                        .build()
                        .unwrap()
                        .install(|| bake_with(&m, method, &opts(5, align)).unwrap())
                };
                assert_eq!(run(1).textures, run(4).textures, "{method}");
            }
        }
    }

    #[test]
    fn alignment_makes_neighbouring_lobes_coherent() {
        let m = bumpy(32, 32);
        let u = lobe_coherence(&bake_with(&m, Method::Vmf, &opts(4, None)).unwrap());
        let a = lobe_coherence(&bake_with(&m, Method::Vmf, &opts(4, Some(0.5))).unwrap());
        let mean = |v: &[Option<f64>]| v[1..4].iter().map(|x| x.unwrap()).sum::<f64>() / 3.0;
        assert!(
            mean(&a) < 0.8 * mean(&u),
            "aligned {a:?} vs unaligned {u:?}"
        );
    }

    #[test]
    fn approximate_mode_matches_exact_below_level_two_and_stays_accurate() {
        let m = bumpy(32, 32);
        let exact = bake_with(&m, Method::Vmf, &opts(4, None)).unwrap();
        let fast_opts = BakeOptions {
            approximate: true,
            ..opts(4, None)
        };
        let fast = bake_with(&m, Method::Vmf, &fast_opts).unwrap();
        all_finite(&fast);
        for t in 0..4 {
            for k in 0..=1 {
                assert_eq!(
                    exact.textures[t].levels[k], fast.textures[t].levels[k],
                    "level {k}"
                );
            }
        }
        assert_eq!(fast.label(), "vmf4f");
        let toksvig = crate::methods::bake(&m, Method::Toksvig);
        let e = evaluate(
            &m,
            &[&exact, &fast, &toksvig],
            &Brdf::blinn_phong(&[64.0]),
            &default_directions(),
        );
        assert!(
            e[1].overall_specular < e[2].overall_specular,
            "fast {} vs Toksvig {}",
            e[1].overall_specular,
            e[2].overall_specular
        );
        assert!(
            e[1].overall_specular < 2.5 * e[0].overall_specular,
            "fast {} vs exact {}",
            e[1].overall_specular,
            e[0].overall_specular
        );
        // Aligned and with colour it stays finite and deterministic too.
        let c = (0..32 * 32)
            .map(|i| [(i % 7) as f32 / 7.0, 0.5, 0.2, 1.0])
            .collect();
        let mc = m.clone().with_feature(c).unwrap();
        let a = bake_with(
            &mc,
            Method::Vmf,
            &BakeOptions {
                align: Some(0.1),
                ..fast_opts
            },
        )
        .unwrap();
        all_finite(&a);
    }

    #[test]
    fn invalid_options_are_errors() {
        let m = bumpy(4, 4);
        assert!(bake_with(&m, Method::Vmf, &opts(0, None)).is_err());
        assert!(bake_with(&m, Method::Vmf, &opts(9, None)).is_err());
        assert!(bake_with(&m, Method::Vmf, &opts(2, Some(f64::NAN))).is_err());
        assert!(bake_with(&m, Method::Vmf, &opts(2, Some(-1.0))).is_err());
    }

    #[test]
    fn parent_of_maps_centres() {
        assert_eq!(
            (0..4).map(|x| parent_of(x, 4, 2)).collect::<Vec<_>>(),
            vec![0, 0, 1, 1]
        );
        assert_eq!(
            (0..5).map(|x| parent_of(x, 5, 2)).collect::<Vec<_>>(),
            vec![0, 0, 1, 1, 1]
        );
        assert_eq!(parent_of(2, 3, 1), 0);
    }
}
