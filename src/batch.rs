//! Batch bakes (issue 19): many inputs, each with its own method and options, baked in
//! parallel within one memory budget, each output folder keyed by a **content hash** so that
//! an input whose output is complete and current is skipped.
//!
//! Main types and functions: [`Job`] (one input: what to read, how to bake, where to write),
//! [`Settings`] (the keys of a batch file's `[defaults]` and `[[input]]` tables, TOML or JSON,
//! unknown keys refused), [`parse_batch`], [`content_hash`], [`is_up_to_date`], [`run`].
//!
//! **The cache key.** [`Job::hash`] is SHA-256 over the ndfmap version, every setting that
//! changes the output (method, bake options except the memory budget, storage format,
//! container, compression, ingest options) and the bytes of the input and of its feature
//! image. The bake's `manifest.json` records it (`content_hash`). The output folder is written
//! as a whole (`output::write_folder`: a staging folder, the manifest written last, then one
//! rename), so a folder whose manifest carries a hash is complete: an interrupted bake (killed,
//! disk full) leaves the previous folder or none, never a manifest over partial files.
//! [`is_up_to_date`] also checks that every file the manifest lists is there.
//!
//! **Admission.** Each job's peak memory is estimated before it starts
//! (`methods::estimate_peak_bytes`, from the input's header); a job starts only when the
//! estimates of the jobs running plus its own fit the budget, and a job whose estimate alone
//! exceeds the budget fails with [`Error::MemoryBudget`]. Jobs start in the order given.
//!
//! **Failures stay per input.** A job that fails (unreadable, corrupt or vanished input, a
//! refused option, an output path another job also writes, a write error such as a full disk)
//! is reported as [`Outcome::Failed`] and the others go on.

use crate::bake::{BakeOptions, FitMode, Method, PbrOptions};
use crate::compress::Codec;
use crate::container::Container;
use crate::em::AlignmentForm;
use crate::error::{Error, Result};
use crate::format::Format;
use crate::ingest::{IngestOptions, NormalMap};
use crate::output::{InputInfo, MANIFEST, Manifest};
use serde::Deserialize;
use sha2::{Digest, Sha256};
use std::path::{Component, Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Condvar, Mutex};
use std::time::Instant;

/// One input of a batch: the map (and feature image) to read, how to bake it, and the folder
/// to write.
#[derive(Debug, Clone, PartialEq)]
pub struct Job {
    /// The normal map.
    pub input: PathBuf,
    /// The feature (colour) image, for the mixtures' eq 22 colours.
    pub feature: Option<PathBuf>,
    /// The output folder (written all-or-nothing).
    pub output: PathBuf,
    /// The method.
    pub method: Method,
    /// The bake's options (`memory_limit` is set by [`run`] to the batch's budget).
    pub options: BakeOptions,
    /// The storage format of the files.
    pub format: Format,
    /// The container of the files.
    pub container: Container,
    /// Block compression (KTX2/DDS).
    pub codec: Option<Codec>,
    /// How the input is read.
    pub ingest: IngestOptions,
}

impl Job {
    /// Every setting that changes the output, in one canonical line per setting (the memory
    /// budgets, which only decide whether a bake runs, are left out).
    pub fn settings_text(&self) -> String {
        let options = BakeOptions {
            memory_limit: None,
            ..self.options
        };
        let ingest = IngestOptions {
            memory_limit: None,
            ..self.ingest
        };
        format!(
            "ndfmap {}\nmethod {}\noptions {options:?}\nformat {}\ncontainer {}\ncodec {}\n\
             ingest {ingest:?}\nfeature {}\n",
            env!("CARGO_PKG_VERSION"),
            self.method,
            self.format,
            self.container,
            self.codec.map_or("none", Codec::name),
            self.feature.is_some(),
        )
    }

    /// The job's content hash ([`content_hash`] of its settings and of its input's and
    /// feature image's bytes), reading the files (bounded by the ingest memory budget).
    ///
    /// # Errors
    ///
    /// [`Error::Read`] when a file cannot be read, [`Error::MemoryBudget`] when it exceeds the
    /// budget.
    pub fn hash(&self) -> Result<String> {
        let (input, feature) = self.read_inputs()?;
        Ok(content_hash(
            &self.settings_text(),
            &input,
            feature.as_deref(),
        ))
    }

    fn read_inputs(&self) -> Result<(Vec<u8>, Option<Vec<u8>>)> {
        let input = crate::ingest::read_file(&self.input, self.ingest.memory_limit)?;
        let feature = self
            .feature
            .as_deref()
            .map(|f| crate::ingest::read_file(f, self.ingest.memory_limit))
            .transpose()?;
        Ok((input, feature))
    }

    /// Whether this job's output folder is complete and current ([`is_up_to_date`] with
    /// [`Job::hash`]); false when the inputs cannot be read.
    pub fn is_up_to_date(&self) -> bool {
        self.hash().is_ok_and(|h| is_up_to_date(&self.output, &h))
    }
}

/// SHA-256 of `settings` (a job's [`Job::settings_text`]), the input's bytes and the feature
/// image's bytes, each part length-prefixed so no two different inputs hash alike by moving
/// bytes between parts: `sha256:` and 64 hex digits.
pub fn content_hash(settings: &str, input: &[u8], feature: Option<&[u8]>) -> String {
    let mut h = Sha256::new();
    for part in [Some(settings.as_bytes()), Some(input), feature] {
        match part {
            Some(bytes) => {
                h.update([1u8]);
                h.update((bytes.len() as u64).to_le_bytes());
                h.update(bytes);
            }
            None => h.update([0u8]),
        }
    }
    let digest = h.finalize();
    let mut out = String::with_capacity(71);
    out.push_str("sha256:");
    for b in digest {
        out.push_str(&format!("{b:02x}"));
    }
    out
}

/// Whether folder `dir` holds a complete bake whose manifest records `hash`: the manifest
/// parses, its `content_hash` is `hash`, and every file it lists is a non-empty regular file.
/// (The folder is swapped in whole, the manifest last, so a manifest only exists over complete
/// files; the listing check also catches files deleted by hand.)
pub fn is_up_to_date(dir: &Path, hash: &str) -> bool {
    let Ok(text) = std::fs::read_to_string(dir.join(MANIFEST)) else {
        return false;
    };
    let Ok(manifest) = serde_json::from_str::<Manifest>(&text) else {
        return false;
    };
    manifest.content_hash.as_deref() == Some(hash)
        && manifest
            .textures
            .iter()
            .flat_map(|t| &t.files)
            .all(|f| std::fs::metadata(dir.join(f)).is_ok_and(|m| m.is_file() && m.len() > 0))
}

/// The alignment of a batch entry: a strength C, `"default"` (the method's usual strength,
/// [`BakeOptions::default_align_strength`]) or `"none"` (unaligned, overriding a default).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(untagged)]
pub enum AlignSetting {
    /// Aligned with strength C.
    Strength(f64),
    /// `"default"`: aligned with the method's usual strength; `"none"`: unaligned.
    Name(String),
}

/// The keys of a batch file's `[defaults]` table and of each `[[input]]` entry (TOML), or of
/// `"defaults"` and each object of `"input"` (JSON). Every key is optional; an entry's keys
/// override the defaults, which override the command line's options. Unknown keys are
/// refused (a misspelt key would otherwise be silently ignored). Names and values are those
/// of `ndfmap bake`'s options; paths are relative to the batch file's folder.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Settings {
    /// The normal map (entries only; required there).
    pub path: Option<String>,
    /// The output folder (entries only; default: the command line's `-o` folder / the input's
    /// file stem).
    pub output: Option<String>,
    /// The feature (colour) image.
    pub feature: Option<String>,
    /// Method: plain, toksvig, lean, olano, tan2005, vmf, sh, pbr.
    pub method: Option<String>,
    /// Lobes per texel (vmf, tan2005).
    pub lobes: Option<usize>,
    /// Alignment strength C, "default" or "none".
    pub align: Option<AlignSetting>,
    /// vmf: appendix or main-text.
    pub align_form: Option<String>,
    /// vmf: fast, balanced or exact.
    pub mode: Option<String>,
    /// vmf, tan2005: the EM iteration cap (1 to [`crate::bake::MAX_EM_ITERATIONS`]; exact
    /// mode and Tan 2005 use it as given, fast and balanced lower their own caps to it).
    pub em_iterations: Option<u32>,
    /// vmf, tan2005: the EM convergence tolerance (0 to [`crate::bake::MAX_EM_TOLERANCE`];
    /// exact mode and Tan 2005 use it as given, fast and balanced raise it to their own).
    pub em_tolerance: Option<f64>,
    /// sh: band limit l*.
    pub lmax: Option<usize>,
    /// pbr: base perceptual roughness.
    pub roughness: Option<f64>,
    /// pbr: anisotropic lobes.
    pub anisotropic: Option<bool>,
    /// pbr: the widest view and light angle the fit covers, degrees (20 to 90).
    pub fit_max_angle: Option<f64>,
    /// pbr: keep the footprint's mean normal, fit only the roughness.
    pub mean_normal: Option<bool>,
    /// f32, f16, unorm16, unorm8.
    pub format: Option<String>,
    /// exr, ktx2, dds.
    pub container: Option<String>,
    /// bc6h, bc7, bc5.
    pub compress: Option<String>,
    /// opengl or directx.
    pub green: Option<String>,
    /// auto, unorm, snorm.
    pub encoding: Option<String>,
    /// auto, xyz, xy.
    pub channels: Option<String>,
    /// wrap or clamp.
    pub addressing: Option<String>,
    /// repair or reject.
    pub bad_normals: Option<String>,
    /// srgb or linear.
    pub feature_encoding: Option<String>,
}

macro_rules! overlay {
    ($base:expr, $over:expr, $($f:ident),*) => {
        Settings { $($f: $over.$f.clone().or_else(|| $base.$f.clone()),)* }
    };
}

impl Settings {
    /// The method-specific keys set here that `method` would ignore (`lobes` for plain,
    /// `lmax` for vmf, …; `anisotropic` and `mean_normal` only when true), each with the methods it is for. A
    /// bake refuses them rather than ignore them silently.
    pub fn keys_for_other_methods(&self, method: Method) -> Vec<(&'static str, &'static str)> {
        const MIXTURES: (&str, &[Method]) = ("vmf and tan2005", &[Method::Vmf, Method::Tan2005]);
        const VMF: (&str, &[Method]) = ("vmf", &[Method::Vmf]);
        const SH: (&str, &[Method]) = ("sh", &[Method::Sh]);
        const PBR: (&str, &[Method]) = ("pbr", &[Method::Pbr]);
        [
            ("lobes", self.lobes.is_some(), MIXTURES),
            ("align", self.align.is_some(), MIXTURES),
            ("align_form", self.align_form.is_some(), VMF),
            ("mode", self.mode.is_some(), VMF),
            ("em_iterations", self.em_iterations.is_some(), MIXTURES),
            ("em_tolerance", self.em_tolerance.is_some(), MIXTURES),
            ("lmax", self.lmax.is_some(), SH),
            ("roughness", self.roughness.is_some(), PBR),
            ("anisotropic", self.anisotropic == Some(true), PBR),
            ("fit_max_angle", self.fit_max_angle.is_some(), PBR),
            ("mean_normal", self.mean_normal == Some(true), PBR),
        ]
        .into_iter()
        .filter(|&(_, set, (_, methods))| set && !methods.contains(&method))
        .map(|(key, _, (for_methods, _))| (key, for_methods))
        .collect()
    }

    /// `over`'s keys where it has them, else `self`'s.
    pub fn overlay(&self, over: &Settings) -> Settings {
        overlay!(
            self,
            over,
            path,
            output,
            feature,
            method,
            lobes,
            align,
            align_form,
            mode,
            em_iterations,
            em_tolerance,
            lmax,
            roughness,
            anisotropic,
            fit_max_angle,
            mean_normal,
            format,
            container,
            compress,
            green,
            encoding,
            channels,
            addressing,
            bad_normals,
            feature_encoding
        )
    }

    /// The job these settings describe: paths relative to `base_dir`, the output defaulting
    /// to `out_root` / the input's file stem; `ingest` supplies the memory budget.
    ///
    /// # Errors
    ///
    /// [`Error::InvalidOption`] naming the key for a missing path or method, a missing output
    /// without `out_root`, or a value that does not parse.
    pub fn job(
        &self,
        base_dir: &Path,
        out_root: Option<&Path>,
        memory: Option<u64>,
    ) -> Result<Job> {
        let bad = |key: &str, e: Error| match e {
            Error::InvalidOption(m) => Error::InvalidOption(format!("batch key '{key}': {m}")),
            e => e,
        };
        let path = self
            .path
            .as_deref()
            .ok_or_else(|| Error::InvalidOption("batch entry without 'path'".into()))?;
        let input = base_dir.join(path);
        let output = match (&self.output, out_root) {
            (Some(o), _) => base_dir.join(o),
            (None, Some(root)) => {
                root.join(input.file_stem().ok_or_else(|| {
                    Error::InvalidOption(format!("input '{path}' has no file name"))
                })?)
            }
            (None, None) => {
                return Err(Error::InvalidOption(format!(
                    "input '{path}': no output folder (give -o DIR, or 'output' in a batch file)"
                )));
            }
        };
        let method: Method = self
            .method
            .as_deref()
            .ok_or_else(|| {
                Error::InvalidOption(format!(
                    "input '{path}': no method (give --method, or 'method' in a batch file)"
                ))
            })?
            .parse()
            .map_err(|e| bad("method", e))?;
        fn enum_of<T: serde::de::DeserializeOwned>(
            key: &str,
            value: &Option<String>,
            allowed: &str,
        ) -> Result<Option<T>> {
            value
                .as_deref()
                .map(|v| {
                    let v = v.trim().to_ascii_lowercase();
                    serde_json::from_value(serde_json::Value::String(v.clone())).map_err(|_| {
                        Error::InvalidOption(format!(
                            "batch key '{key}': '{v}' (expected one of: {allowed})"
                        ))
                    })
                })
                .transpose()
        }
        let defaults = IngestOptions::default();
        let ingest = IngestOptions {
            green: enum_of("green", &self.green, "opengl, directx")?.unwrap_or(defaults.green),
            encoding: enum_of("encoding", &self.encoding, "auto, unorm, snorm")?
                .unwrap_or(defaults.encoding),
            channels: enum_of("channels", &self.channels, "auto, xyz, xy")?
                .unwrap_or(defaults.channels),
            addressing: enum_of("addressing", &self.addressing, "wrap, clamp")?
                .unwrap_or(defaults.addressing),
            bad_normals: enum_of("bad_normals", &self.bad_normals, "repair, reject")?
                .unwrap_or(defaults.bad_normals),
            feature_encoding: enum_of("feature_encoding", &self.feature_encoding, "srgb, linear")?
                .unwrap_or(defaults.feature_encoding),
            memory_limit: memory,
        };
        let d = BakeOptions::default();
        let align_form = match &self.align_form {
            Some(f) => f
                .parse::<AlignmentForm>()
                .map_err(|e| bad("align_form", e))?,
            None => d.align_form,
        };
        let align = match &self.align {
            None => None,
            Some(AlignSetting::Strength(c)) => Some(*c),
            Some(AlignSetting::Name(n)) if n.trim().eq_ignore_ascii_case("none") => None,
            Some(AlignSetting::Name(n)) if n.trim().eq_ignore_ascii_case("default") => {
                Some(BakeOptions { align_form, ..d }.default_align_strength(method))
            }
            Some(AlignSetting::Name(n)) => {
                return Err(Error::InvalidOption(format!(
                    "batch key 'align': '{n}' (expected a strength C, \"default\" or \"none\")"
                )));
            }
        };
        let options = BakeOptions {
            lobes: self.lobes.unwrap_or(d.lobes),
            align,
            align_form,
            mode: match &self.mode {
                Some(m) => m.parse::<FitMode>().map_err(|e| bad("mode", e))?,
                None => d.mode,
            },
            em: crate::em::EmOptions {
                max_iterations: self.em_iterations.unwrap_or(d.em.max_iterations),
                tolerance: self.em_tolerance.unwrap_or(d.em.tolerance),
                ..d.em
            },
            lmax: self.lmax.unwrap_or(d.lmax),
            pbr: PbrOptions {
                roughness: self.roughness.unwrap_or(d.pbr.roughness),
                anisotropic: self.anisotropic.unwrap_or(d.pbr.anisotropic),
                fit_max_angle: self.fit_max_angle.or(d.pbr.fit_max_angle),
                mean_normal: self.mean_normal.unwrap_or(d.pbr.mean_normal),
            },
            memory_limit: memory,
        };
        Ok(Job {
            feature: self.feature.as_ref().map(|f| base_dir.join(f)),
            output,
            method,
            options,
            format: match &self.format {
                Some(f) => f.parse().map_err(|e| bad("format", e))?,
                None => Format::F32,
            },
            container: match &self.container {
                Some(c) => c.parse().map_err(|e| bad("container", e))?,
                None => Container::Exr,
            },
            codec: self
                .compress
                .as_deref()
                .map(|c| c.parse::<Codec>())
                .transpose()
                .map_err(|e| bad("compress", e))?,
            ingest,
            input,
        })
    }
}

/// A batch file: optional `defaults` and the list of `input` entries.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BatchFile {
    /// Settings every entry starts from (no `path` or `output` here).
    #[serde(default)]
    pub defaults: Settings,
    /// One entry per input.
    #[serde(default)]
    pub input: Vec<Settings>,
}

/// Parses a batch file's text, TOML or (when `json`) JSON, into jobs: each entry's settings
/// over the file's `defaults` over `base` (the command line's), paths relative to `base_dir`
/// (the batch file's folder), outputs defaulting to `out_root` / the input's stem.
///
/// # Errors
///
/// [`Error::InvalidOption`] naming the file and the problem for a syntax error, an unknown
/// key (with its place), `path` or `output` in `defaults`, an empty input list, or an entry
/// whose settings are invalid ([`Settings::job`], naming the entry).
pub fn parse_batch(
    name: &str,
    text: &str,
    json: bool,
    base: &Settings,
    base_dir: &Path,
    out_root: Option<&Path>,
    memory: Option<u64>,
) -> Result<Vec<Job>> {
    // The parsers' messages quote the input (TOML its line, serde a key or value): cut to a
    // few hundred characters, so a megabyte-long line still makes one readable line.
    let parse_error = |m: String| {
        let m = m.split_whitespace().collect::<Vec<_>>().join(" ");
        Error::InvalidOption(format!(
            "batch file {name}: {}",
            crate::error::clip_message(&m, crate::error::MAX_PARSE_ERROR_CHARS)
        ))
    };
    let file: BatchFile = if json {
        serde_json::from_str(text).map_err(|e| parse_error(e.to_string()))?
    } else {
        toml::from_str(text).map_err(|e| parse_error(e.to_string()))?
    };
    if file.defaults.path.is_some() || file.defaults.output.is_some() {
        return Err(Error::InvalidOption(format!(
            "batch file {name}: 'path' and 'output' belong to [[input]] entries, not [defaults]"
        )));
    }
    if file.input.is_empty() {
        return Err(Error::InvalidOption(format!(
            "batch file {name}: no [[input]] entries"
        )));
    }
    let defaults = base.overlay(&file.defaults);
    file.input
        .iter()
        .enumerate()
        .map(|(i, entry)| {
            let settings = defaults.overlay(entry);
            // The entry's own method-specific keys must apply to its method (a key in
            // [defaults] or on the command line may be meant for other entries).
            if let Some(Ok(method)) = settings.method.as_deref().map(str::parse::<Method>) {
                let stray = entry.keys_for_other_methods(method);
                if let Some(&(key, for_methods)) = stray.first() {
                    return Err(Error::InvalidOption(format!(
                        "batch file {name}, input {}: key '{key}' does not apply to method {} \
                         (it is for {for_methods})",
                        i + 1,
                        method.name()
                    )));
                }
            }
            settings
                .job(base_dir, out_root, memory)
                .map_err(|e| match e {
                    Error::InvalidOption(m) => {
                        Error::InvalidOption(format!("batch file {name}, input {}: {m}", i + 1))
                    }
                    e => e,
                })
        })
        .collect()
}

/// Expands command-line inputs: a name that is an existing file stays as it is; one with glob
/// characters (`*`, `?`, `[`) is expanded (sorted); a pattern that matches nothing is an
/// error, as is a malformed one.
pub fn expand_inputs(args: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for a in args {
        let text = a.to_string_lossy();
        if a.exists() || !text.contains(['*', '?', '[']) {
            out.push(a.clone());
            continue;
        }
        let paths = glob::glob(&text)
            .map_err(|e| Error::InvalidOption(format!("input pattern '{text}': {e}")))?;
        let mut found: Vec<PathBuf> = paths.filter_map(|p| p.ok()).collect();
        if found.is_empty() {
            return Err(Error::InvalidOption(format!(
                "input pattern '{text}' matches no file"
            )));
        }
        found.sort();
        out.extend(found);
    }
    Ok(out)
}

/// `path` made absolute (against the current folder) with `.` and `..` resolved lexically:
/// what two output paths are compared as.
fn normalized(path: &Path) -> PathBuf {
    let absolute = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir().unwrap_or_default().join(path)
    };
    let mut out = PathBuf::new();
    for c in absolute.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            c => out.push(c),
        }
    }
    out
}

/// For each job, the error for an output folder that another job of the batch also writes,
/// or that lies inside another job's output folder or holds one (compared after making paths
/// absolute and resolving `.` and `..`), naming the other inputs: such jobs are not run (which
/// one's bake would stay is a race, and a folder inside another's would be a file its
/// manifest does not list).
pub fn output_collisions(jobs: &[Job]) -> Vec<Option<Error>> {
    let outs: Vec<PathBuf> = jobs.iter().map(|j| normalized(&j.output)).collect();
    (0..jobs.len())
        .map(|i| {
            let others = |related: &dyn Fn(&Path, &Path) -> bool| -> Vec<String> {
                (0..jobs.len())
                    .filter(|&k| k != i && related(&outs[i], &outs[k]))
                    .map(|k| jobs[k].input.display().to_string())
                    .collect()
            };
            let message = |relation: &str, others: Vec<String>| {
                (!others.is_empty()).then(|| {
                    Error::InvalidOption(format!(
                        "output folder {} {relation} {}: give each input its own output, \
                         none inside another's",
                        jobs[i].output.display(),
                        others.join(", ")
                    ))
                })
            };
            message("is also the output of", others(&|a, b| a == b))
                .or_else(|| {
                    message(
                        "lies inside the output of",
                        others(&|a, b| a != b && a.starts_with(b)),
                    )
                })
                .or_else(|| {
                    message(
                        "holds the output of",
                        others(&|a, b| a != b && b.starts_with(a)),
                    )
                })
        })
        .collect()
}

/// What became of one job.
#[derive(Debug)]
pub enum Outcome {
    /// Baked and written; its manifest, and the bake's seconds (decoding, baking, writing).
    Baked {
        /// The manifest written.
        manifest: PathBuf,
        /// Wall seconds of the job.
        seconds: f64,
    },
    /// The output was complete and current ([`is_up_to_date`]): nothing done.
    UpToDate {
        /// The manifest found.
        manifest: PathBuf,
    },
    /// The job failed; the others went on.
    Failed(Error),
}

impl Outcome {
    /// Whether the job failed.
    pub fn failed(&self) -> bool {
        matches!(self, Outcome::Failed(_))
    }
}

/// Options of [`run`].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RunOptions {
    /// Memory budget of the whole batch in bytes (`None`: the machine's default,
    /// [`crate::budget::default_memory_limit`]).
    pub memory: Option<u64>,
    /// Most jobs running at once (0: as many as the machine has cores).
    pub workers: usize,
    /// Bake even inputs whose output is up to date.
    pub force: bool,
}

/// The memory still free in the budget, shared by the workers.
struct Budget {
    free: Mutex<u64>,
    freed: Condvar,
}

impl Budget {
    /// Waits until `bytes` are free and takes them.
    fn acquire(&self, bytes: u64) {
        let mut free = self.free.lock().unwrap_or_else(|e| e.into_inner());
        while *free < bytes {
            free = self.freed.wait(free).unwrap_or_else(|e| e.into_inner());
        }
        *free -= bytes;
    }

    fn release(&self, bytes: u64) {
        *self.free.lock().unwrap_or_else(|e| e.into_inner()) += bytes;
        self.freed.notify_all();
    }
}

/// Runs `jobs`: up to `options.workers` at once, each admitted when its estimated peak fits
/// in what the running jobs leave of the budget, skipping those whose output is up to date
/// (unless `force`). `on_done(i, outcome)` is called (from a worker thread) as job `i` ends;
/// `on_start(i)` as it starts. Returns every job's outcome, in job order. Outputs that
/// collide ([`output_collisions`]) fail without running.
pub fn run(
    jobs: &[Job],
    options: &RunOptions,
    on_start: &(dyn Fn(usize) + Sync),
    on_done: &(dyn Fn(usize, &Outcome) + Sync),
) -> Vec<Outcome> {
    let limit = crate::budget::resolve(options.memory);
    let budget = Budget {
        free: Mutex::new(limit),
        freed: Condvar::new(),
    };
    let collisions = output_collisions(jobs);
    let workers = match options.workers {
        0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
        n => n,
    }
    .clamp(1, jobs.len().max(1));
    let next = AtomicUsize::new(0);
    let results: Vec<Mutex<Option<Outcome>>> = jobs.iter().map(|_| Mutex::new(None)).collect();
    std::thread::scope(|scope| {
        for _ in 0..workers {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    if i >= jobs.len() {
                        break;
                    }
                    on_start(i);
                    let outcome = match &collisions[i] {
                        Some(Error::InvalidOption(m)) => {
                            Outcome::Failed(Error::InvalidOption(m.clone()))
                        }
                        Some(e) => Outcome::Failed(Error::InvalidOption(e.to_string())),
                        None => run_job(&jobs[i], limit, options.force, &budget),
                    };
                    on_done(i, &outcome);
                    *results[i].lock().unwrap_or_else(|e| e.into_inner()) = Some(outcome);
                }
            });
        }
    });
    results
        .into_iter()
        .map(|r| {
            r.into_inner()
                .unwrap_or_else(|e| e.into_inner())
                .unwrap_or(Outcome::Failed(Error::Cancelled))
        })
        .collect()
}

/// One job: read, hash, skip if current, estimate and wait for the budget, decode, bake,
/// write. A panic in the job is caught and reported as its failure.
fn run_job(job: &Job, limit: u64, force: bool, budget: &Budget) -> Outcome {
    let start = Instant::now();
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        bake_job(job, limit, force, budget)
    }))
    .unwrap_or_else(|_| {
        Err(Error::InvalidOption(format!(
            "{}: the bake failed unexpectedly (internal error)",
            job.input.display()
        )))
    });
    match result {
        Ok(Some(manifest)) => Outcome::Baked {
            manifest,
            seconds: start.elapsed().as_secs_f64(),
        },
        Ok(None) => Outcome::UpToDate {
            manifest: job.output.join(MANIFEST),
        },
        Err(e) => Outcome::Failed(e),
    }
}

/// [`run_job`]'s work: `Ok(None)` when the output is up to date.
fn bake_job(job: &Job, limit: u64, force: bool, budget: &Budget) -> Result<Option<PathBuf>> {
    let color = job.feature.is_some();
    let options = BakeOptions {
        memory_limit: Some(limit),
        ..job.options
    };
    crate::methods::check_options(job.method, &options, color, Some(job.format))?;
    let lobes_or_lmax = if job.method == Method::Sh {
        options.lmax
    } else {
        options.lobes
    };
    crate::container::check(
        job.container,
        job.method,
        lobes_or_lmax,
        color,
        job.format,
        job.codec,
    )?;
    // The bytes are read once: hashed, probed and decoded from the same bytes, so a file
    // replaced meanwhile cannot give a manifest whose hash names other contents.
    let (input, feature) = job.read_inputs()?;
    let hash = content_hash(&job.settings_text(), &input, feature.as_deref());
    if !force && is_up_to_date(&job.output, &hash) {
        // Nothing to write, but what killed writers left beside the folder goes, as a
        // write would remove it.
        crate::output::tidy(&job.output)?;
        return Ok(None);
    }
    let probe = crate::ingest::probe_bytes(&job.input, &input)?;
    let (w, h) = (probe.width, probe.height);
    // Mixture bakes (block-compressed or not) are baked in bands and streamed to their files
    // (module `banded`: bounded memory, the same bytes), from the decoded 8/16-bit samples
    // kept as they are (`ingest::CompactNormals`, `CompactFeature`); the others whole.
    let banded = matches!(job.method, Method::Vmf | Method::Tan2005);
    let needed = if banded {
        let bands = crate::banded::Bands::for_size(w, h);
        let kept = |p: &crate::ingest::Probe, decoded: u64| {
            if p.float {
                decoded
            } else {
                p.bytes_per_texel as u64
            }
        };
        let mut source = kept(&probe, crate::banded::DECODED_NORMAL_BYTES);
        if let (Some(path), Some(bytes)) = (&job.feature, &feature) {
            let f = crate::ingest::probe_bytes(path, bytes)?;
            source += kept(&f, crate::banded::DECODED_FEATURE_BYTES);
        }
        crate::banded::estimate_peak_bytes(w, h, &options, color, source, bands)
    } else {
        crate::methods::estimate_peak_bytes(w, h, job.method, &options, color)
    };
    crate::budget::check(
        &format!("{}: a {} bake of {w}x{h}", job.input.display(), job.method),
        needed,
        Some(limit),
    )?;
    budget.acquire(needed);
    let result = (|| {
        let name = job.input.display().to_string();
        if banded {
            return bake_banded_job(job, &options, &name, input, feature, hash);
        }
        let mut map = NormalMap::load_memory(&name, &input, &job.ingest)?;
        drop(input);
        if let (Some(path), Some(bytes)) = (&job.feature, &feature) {
            map = map.with_feature_memory(&path.display().to_string(), bytes, &job.ingest)?;
        }
        drop(feature);
        let info = InputInfo {
            path: Some(name),
            options: job.ingest,
            stats: map.stats().clone(),
        };
        let bake = crate::methods::bake_with(&map, job.method, &options)?;
        drop(map);
        let bake = crate::pack::quantize_into(bake, job.format)?;
        crate::container::write_bake_hashed(
            &bake,
            info,
            &job.output,
            job.container,
            job.codec,
            Some(hash),
        )
    })();
    budget.release(needed);
    result.map(Some)
}

/// The banded bake of a job (vMF or Tan 2005, block-compressed or not): 8/16-bit inputs are kept
/// as their decoded samples (`ingest::load_normals_compact`, `CompactFeature`), float ones
/// decoded; the same files as from a decoded [`NormalMap`], byte for byte.
fn bake_banded_job(
    job: &Job,
    options: &BakeOptions,
    name: &str,
    input: Vec<u8>,
    feature: Option<Vec<u8>>,
    hash: String,
) -> Result<PathBuf> {
    use crate::banded::{CompactSource, Map};
    use crate::ingest::{CompactFeature, LoadedNormals, load_normals_compact};
    let loaded = load_normals_compact(name, &input, &job.ingest)?;
    drop(input);
    let feature_name = job.feature.as_ref().map(|p| p.display().to_string());
    let write = |map: &Map, stats| {
        let info = InputInfo {
            path: Some(name.to_string()),
            options: job.ingest,
            stats,
        };
        crate::banded::write_folder(
            map,
            job.method,
            options,
            job.format,
            job.container,
            job.codec,
            &job.output,
            info,
            Some(hash.clone()),
            None,
            &mut |_| true,
        )
    };
    match loaded {
        LoadedNormals::Compact(normals) => {
            let size = (normals.width(), normals.height());
            let feature = match (&feature_name, feature) {
                (Some(f), Some(bytes)) => {
                    Some(CompactFeature::load_memory(f, &bytes, size, &job.ingest)?)
                }
                _ => None,
            };
            let stats = normals.stats_with(feature.as_ref());
            let map = Map::Compact(CompactSource {
                normals: &normals,
                feature: feature.as_ref(),
            });
            write(&map, stats)
        }
        LoadedNormals::Decoded(mut map) => {
            if let (Some(f), Some(bytes)) = (&feature_name, feature) {
                map = map.with_feature_memory(f, &bytes, &job.ingest)?;
            }
            let stats = map.stats().clone();
            write(&Map::Full(&map), stats)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_hash_changes_with_every_part_and_only_with_them() {
        let a = content_hash("s", b"abc", None);
        assert_eq!(a, content_hash("s", b"abc", None));
        assert_eq!(a.len(), 7 + 64);
        assert_ne!(a, content_hash("t", b"abc", None));
        assert_ne!(a, content_hash("s", b"abd", None));
        assert_ne!(a, content_hash("s", b"abc", Some(b"")));
        // Moving bytes between parts changes it (length prefixes).
        assert_ne!(
            content_hash("sa", b"bc", None),
            content_hash("s", b"abc", None)
        );
        // The empty input against SHA-256's definition: the digest of the framing bytes.
        let mut h = Sha256::new();
        h.update([1u8]);
        h.update(1u64.to_le_bytes());
        h.update(b"s");
        h.update([1u8]);
        h.update(0u64.to_le_bytes());
        h.update([0u8]);
        let want: String = h.finalize().iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(content_hash("s", b"", None), format!("sha256:{want}"));
    }

    #[test]
    fn settings_text_ignores_the_memory_budget_but_not_the_options() {
        let s = Settings {
            path: Some("a.png".into()),
            method: Some("vmf".into()),
            ..Settings::default()
        };
        let a = s.job(Path::new("."), Some(Path::new("out")), None).unwrap();
        let b = s
            .job(Path::new("."), Some(Path::new("out")), Some(1 << 30))
            .unwrap();
        assert_eq!(a.settings_text(), b.settings_text());
        assert_eq!(a.output, Path::new("out/a"));
        let c = Settings {
            lobes: Some(4),
            ..s.clone()
        }
        .job(Path::new("."), Some(Path::new("out")), None)
        .unwrap();
        assert_ne!(a.settings_text(), c.settings_text());
    }

    #[test]
    fn batch_files_refuse_unknown_keys_and_merge_defaults() {
        let base = Settings {
            method: Some("plain".into()),
            ..Settings::default()
        };
        let toml = r#"
            [defaults]
            method = "vmf"
            lobes = 2
            align = 1.0
            em_iterations = 60
            [[input]]
            path = "maps/a.png"
            em_tolerance = 1e-8
            [[input]]
            path = "maps/b.png"
            output = "custom/b"
            align = "none"
            format = "f16"
            [[input]]
            path = "maps/c.png"
            align = "default"
            [[input]]
            path = "maps/d.png"
            method = "tan2005"
            align = "default"
        "#;
        let jobs = parse_batch(
            "b.toml",
            toml,
            false,
            &base,
            Path::new("/w"),
            Some(Path::new("/o")),
            None,
        )
        .unwrap();
        assert_eq!(jobs.len(), 4);
        assert_eq!(jobs[0].method, Method::Vmf);
        assert_eq!(jobs[0].options.lobes, 2);
        assert_eq!(jobs[0].options.align, Some(1.0));
        assert_eq!(jobs[0].input, Path::new("/w/maps/a.png"));
        assert_eq!(jobs[0].output, Path::new("/o/a"));
        assert_eq!(jobs[0].options.em.max_iterations, 60);
        assert_eq!(jobs[0].options.em.tolerance, 1e-8);
        let d = crate::em::EmOptions::default();
        assert_eq!(jobs[1].options.em.max_iterations, 60);
        assert_eq!(jobs[1].options.em.tolerance, d.tolerance);
        assert_eq!(jobs[1].options.align, None);
        assert_eq!(jobs[1].format, Format::F16);
        assert_eq!(jobs[1].output, Path::new("/w/custom/b"));
        // "default": the method's usual strength (vMF eq 29 0.03, Tan's c = 1).
        assert_eq!(jobs[2].options.align, Some(0.03));
        assert_eq!(jobs[3].options.align, Some(1.0));
        for (text, json, needle) in [
            ("[[input]]\npath = \"a.png\"\nlobez = 3\n", false, "lobez"),
            (
                "[defaultz]\n[[input]]\npath = \"a.png\"\n",
                false,
                "defaultz",
            ),
            (
                r#"{"input": [{"path": "a.png", "colour": "x.png"}]}"#,
                true,
                "colour",
            ),
            (
                "[defaults]\npath = \"a.png\"\n[[input]]\npath = \"b.png\"\n",
                false,
                "defaults",
            ),
            (
                "[[input]]\npath = \"a.png\"\nmethod = \"vfm\"\n",
                false,
                "vfm",
            ),
            (
                "[[input]]\npath = \"a.png\"\nalign = \"yes\"\n",
                false,
                "align",
            ),
            ("", false, "no [[input]]"),
        ] {
            let e = parse_batch(
                "b",
                text,
                json,
                &base,
                Path::new("."),
                Some(Path::new("o")),
                None,
            )
            .unwrap_err()
            .to_string();
            assert!(
                e.contains(needle) && e.contains("batch file b"),
                "{text}: {e}"
            );
        }
    }

    #[test]
    fn colliding_outputs_are_named() {
        let job = |input: &str, output: &str| {
            Settings {
                path: Some(input.into()),
                output: Some(output.into()),
                method: Some("plain".into()),
                ..Settings::default()
            }
            .job(Path::new("/w"), None, None)
            .unwrap()
        };
        let jobs = [
            job("a.png", "out/x"),
            job("b.png", "out/./y/../x"),
            job("c.png", "out/c"),
        ];
        let c = output_collisions(&jobs);
        assert!(c[0].as_ref().unwrap().to_string().contains("/w/b.png"));
        assert!(c[1].as_ref().unwrap().to_string().contains("/w/a.png"));
        assert!(c[2].is_none());
    }

    #[test]
    fn nested_outputs_are_refused_like_identical_ones() {
        // `x` and `x/y` were both baked, leaving x holding a folder its manifest does not
        // list; compared as absolute paths with `.` and `..` resolved.
        let job = |base: &str, input: &str, output: &str| {
            Settings {
                path: Some(input.into()),
                output: Some(output.into()),
                method: Some("plain".into()),
                ..Settings::default()
            }
            .job(Path::new(base), None, None)
            .unwrap()
        };
        let cwd = std::env::current_dir().unwrap();
        let absolute = cwd.join("rel").join("p").join("q");
        let jobs = [
            job("/w", "a.png", "out/x"),
            job("/w", "b.png", "out/x/../x/y"),
            job("/w", "c.png", "/w/out/x/y/z/"),
            job("/w", "d.png", "out/xy"),
            job("", "e.png", "rel/./p"),
            job("/w", "f.png", absolute.to_str().unwrap()),
            job("/w", "g.png", "other/../out2"),
        ];
        let c: Vec<Option<String>> = output_collisions(&jobs)
            .into_iter()
            .map(|e| e.map(|e| e.to_string()))
            .collect();
        let says = |i: usize, relation: &str, others: &str| {
            let e = c[i].as_deref().unwrap_or_default();
            assert!(
                e.contains(&format!(
                    "{relation} {others}: give each input its own output"
                )),
                "{i}: {e}"
            );
        };
        says(0, "holds the output of", "/w/b.png, /w/c.png");
        says(1, "lies inside the output of", "/w/a.png");
        says(2, "lies inside the output of", "/w/a.png, /w/b.png");
        assert!(c[3].is_none(), "{:?}", c[3]);
        says(4, "holds the output of", "/w/f.png");
        says(5, "lies inside the output of", "e.png");
        assert!(c[6].is_none(), "{:?}", c[6]);
        // Run, the colliding jobs fail without reading anything, their message said once.
        let outcomes = run(&jobs[..2], &RunOptions::default(), &|_| {}, &|_, _| {});
        for o in outcomes {
            let Outcome::Failed(e) = o else {
                panic!("{o:?}")
            };
            let e = e.to_string();
            assert!(
                e.starts_with("invalid option: output folder /w/out/x"),
                "{e}"
            );
            assert_eq!(e.matches("invalid option").count(), 1, "{e}");
        }
    }

    #[test]
    fn parse_errors_quoting_a_huge_line_stay_short() {
        // The TOML error quoted the offending line (a 1 MB key made megabytes of message).
        let key = "k".repeat(1 << 20);
        for (text, json) in [
            (format!("[[input]]\n{key} = 1\n"), false),
            (format!("{{\"input\": [{{\"{key}\": 1}}]}}"), true),
        ] {
            let e = parse_batch(
                "b",
                &text,
                json,
                &Settings::default(),
                Path::new("."),
                None,
                None,
            )
            .unwrap_err()
            .to_string();
            assert!(
                e.len() < 1000 && e.contains("batch file b: ") && e.ends_with("characters)"),
                "{}",
                &e[..e.len().min(600)]
            );
        }
    }
}
