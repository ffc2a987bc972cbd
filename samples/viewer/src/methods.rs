//! What the viewer draws with: [`MethodSpec`] names a method with its lobe count and alignment
//! (`plain`, `toksvig`, `lean`, `olano`, `vmf6a`, `vmf4`, `tan2005-4`, `sh6`, …, the labels of
//! `ndfmap::bake::Bake::label`; and the PBR bakes `pbr`, `pbr-aniso` and the engines' plain
//! MIP chain `pbr-mip`, drawn by a plain glTF GGX shader), and [`Bakes`] bakes them once each,
//! on a background thread.

use ndfmap::NormalMap;
use ndfmap::bake::{Bake, BakeOptions, Method, PbrOptions};
use ndfmap::methods::bake_with;
use ndfmap::pbr::{Widening, bake_formula};
use std::collections::{HashMap, HashSet};
use std::fmt;
use std::str::FromStr;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, Sender, channel};

/// A method and, for the mixtures, its lobe count and whether the lobes are aligned.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct MethodSpec {
    /// The method.
    pub method: Method,
    /// Lobes (mixtures), the band limit l* (SH), 0 for the baselines.
    pub lobes: usize,
    /// Aligned lobes (Sec 7.3, hardware filtering); mixtures only.
    pub aligned: bool,
    /// Which PBR bake ([`Method::Pbr`] only).
    pub pbr: PbrKind,
}

/// The PBR bakes the viewer shows, all drawn by the same plain glTF GGX shader
/// (`ndfmap_gl::gltf`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum PbrKind {
    /// ndfmap's fitted isotropic lobe per texel (`pbr`).
    #[default]
    Fitted,
    /// ndfmap's fitted anisotropic lobe (`pbr-aniso`, `KHR_materials_anisotropy`).
    Anisotropic,
    /// What engines do without prefiltering (`pbr-mip`): the normalized mean normal and the
    /// roughness left as it is.
    Mip,
}

impl MethodSpec {
    /// A baseline method.
    pub const fn baseline(method: Method) -> Self {
        MethodSpec {
            method,
            lobes: 0,
            aligned: false,
            pbr: PbrKind::Fitted,
        }
    }

    /// A PBR bake.
    pub const fn pbr(kind: PbrKind) -> Self {
        MethodSpec {
            method: Method::Pbr,
            lobes: 0,
            aligned: false,
            pbr: kind,
        }
    }

    /// A mixture method with `lobes` lobes.
    pub const fn mixture(method: Method, lobes: usize, aligned: bool) -> Self {
        MethodSpec {
            method,
            lobes,
            aligned,
            pbr: PbrKind::Fitted,
        }
    }

    /// The bake options of this spec: its lobes (or band limit), aligned with strength `align`
    /// when the spec is aligned (`None`: the method's usual C,
    /// [`BakeOptions::default_align_strength`]).
    pub fn bake_options(&self, align: Option<f64>) -> BakeOptions {
        let d = BakeOptions::default();
        BakeOptions {
            lobes: self.lobes.max(1),
            align: self
                .aligned
                .then(|| align.unwrap_or_else(|| d.default_align_strength(self.method))),
            lmax: self.lobes,
            ..d
        }
    }

    /// Whether the method is a mixture (vMF or Tan 2005), whose lobe count can change.
    pub fn is_mixture(&self) -> bool {
        matches!(self.method, Method::Vmf | Method::Tan2005)
    }

    /// The spherical-harmonic NDF with band limit `lmax`.
    pub const fn sh(lmax: usize) -> Self {
        MethodSpec {
            method: Method::Sh,
            lobes: lmax,
            aligned: false,
            pbr: PbrKind::Fitted,
        }
    }

    /// The same method with `lobes` lobes, or SH with band limit `lobes` (baselines are
    /// unchanged).
    pub fn with_lobes(self, lobes: usize) -> Self {
        if self.is_mixture() || self.method == Method::Sh {
            MethodSpec { lobes, ..self }
        } else {
            self
        }
    }

    /// The viewer's default list: plain, Toksvig, LEAN and vMF J = 6 aligned.
    pub fn defaults() -> Vec<MethodSpec> {
        vec![
            MethodSpec::baseline(Method::Plain),
            MethodSpec::baseline(Method::Toksvig),
            MethodSpec::baseline(Method::Lean),
            MethodSpec::mixture(Method::Vmf, 6, true),
        ]
    }
}

impl fmt::Display for MethodSpec {
    /// The label `Bake::label` gives the bake (without the format).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.method.name())?;
        if self.is_mixture() {
            if self.method.name().ends_with(|c: char| c.is_ascii_digit()) {
                f.write_str("-")?;
            }
            write!(f, "{}{}", self.lobes, if self.aligned { "a" } else { "" })?;
        }
        if self.method == Method::Sh {
            write!(f, "{}", self.lobes)?;
        }
        if self.method == Method::Pbr {
            match self.pbr {
                PbrKind::Fitted => {}
                PbrKind::Anisotropic => f.write_str("-aniso")?,
                PbrKind::Mip => f.write_str("-mip")?,
            }
        }
        Ok(())
    }
}

impl FromStr for MethodSpec {
    type Err = String;

    /// `plain`, `toksvig`, `lean`, `olano`; `vmf` or `tan2005` followed by a lobe count (1–8,
    /// `-` optional) and `a` for aligned lobes: `vmf6a`, `vmf4`, `tan2005-4a`; `sh` followed by
    /// the band limit (0–10): `sh6`. A bare `vmf` is `vmf6a`, a bare `tan2005` is `tan2005-4`, a
    /// bare `sh` is `sh6`. `pbr`, `pbr-aniso`, `pbr-mip`: the PBR bakes ([`PbrKind`]).
    fn from_str(s: &str) -> Result<Self, String> {
        let s = s.trim().to_ascii_lowercase();
        match s.as_str() {
            "pbr" => return Ok(MethodSpec::pbr(PbrKind::Fitted)),
            "pbr-aniso" => return Ok(MethodSpec::pbr(PbrKind::Anisotropic)),
            "pbr-mip" => return Ok(MethodSpec::pbr(PbrKind::Mip)),
            _ => {}
        }
        let name_end = if let Some(rest) = s.strip_prefix("tan2005") {
            s.len() - rest.len()
        } else {
            s.find(|c: char| c.is_ascii_digit() || c == '-')
                .unwrap_or(s.len())
        };
        let method: Method = s[..name_end].parse().map_err(|e| format!("{e}"))?;
        let rest = s[name_end..].trim_start_matches('-');
        match method {
            Method::Vmf | Method::Tan2005 => {
                if rest.is_empty() {
                    return Ok(match method {
                        Method::Vmf => MethodSpec::mixture(method, 6, true),
                        _ => MethodSpec::mixture(method, 4, false),
                    });
                }
                let (digits, aligned) = match rest.strip_suffix('a') {
                    Some(d) => (d, true),
                    None => (rest, false),
                };
                let lobes: usize = digits
                    .parse()
                    .ok()
                    .filter(|j| (1..=8).contains(j))
                    .ok_or_else(|| format!("'{s}': the lobe count must be 1 to 8"))?;
                Ok(MethodSpec::mixture(method, lobes, aligned))
            }
            Method::Sh => {
                if rest.is_empty() {
                    return Ok(MethodSpec::sh(6));
                }
                let lmax: usize = rest
                    .parse()
                    .ok()
                    .filter(|l| *l <= 10)
                    .ok_or_else(|| format!("'{s}': the band limit must be 0 to 10"))?;
                Ok(MethodSpec::sh(lmax))
            }
            _ if rest.is_empty() => Ok(MethodSpec::baseline(method)),
            _ => Err(format!("'{s}': {method} takes no lobe count")),
        }
    }
}

/// What a bake is made of: the method, and whether the map's albedo is baked in as colour
/// textures (mixtures only).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct BakeKey {
    /// The method.
    pub spec: MethodSpec,
    /// Colour textures from the map's albedo.
    pub color: bool,
}

/// Bakes of one map, each made once: on a background thread ([`Bakes::request`], then
/// [`Bakes::poll`]) or on the caller's ([`Bakes::get_blocking`]).
pub struct Bakes {
    map: Arc<NormalMap>,
    align: Option<f64>,
    roughness: f64,
    done: HashMap<BakeKey, Arc<Bake>>,
    pending: HashSet<BakeKey>,
    sender: Sender<(BakeKey, Result<Bake, String>)>,
    receiver: Receiver<(BakeKey, Result<Bake, String>)>,
}

impl Bakes {
    /// Bakes of `map`; aligned mixtures use alignment strength `align` (C of eq 29, or Tan's c;
    /// `None`: each method's usual one), PBR bakes the base perceptual roughness `roughness`
    /// (`√α`, glTF's).
    pub fn new(map: NormalMap, align: Option<f64>, roughness: f64) -> Bakes {
        let (sender, receiver) = channel();
        Bakes {
            map: Arc::new(map),
            align,
            roughness,
            done: HashMap::new(),
            pending: HashSet::new(),
            sender,
            receiver,
        }
    }

    /// Whether the map has an albedo to bake as colour.
    pub fn has_albedo(&self) -> bool {
        self.map.feature().is_some()
    }

    /// The bake of `key` if it is done.
    pub fn get(&self, key: &BakeKey) -> Option<Arc<Bake>> {
        self.done.get(key).cloned()
    }

    /// Whether any bake is running.
    pub fn busy(&self) -> bool {
        !self.pending.is_empty()
    }

    /// Starts baking `key` on a background thread unless it is done or running.
    pub fn request(&mut self, key: BakeKey) {
        if self.done.contains_key(&key) || !self.pending.insert(key) {
            return;
        }
        let (map, align, roughness) = (self.map.clone(), self.align, self.roughness);
        let sender = self.sender.clone();
        std::thread::spawn(move || {
            // The receiver may be gone when the viewer quits mid-bake; nothing to do then.
            let _ = sender.send((key, bake_key(&map, key, align, roughness)));
        });
    }

    /// Collects finished background bakes; returns the errors of failed ones.
    pub fn poll(&mut self) -> Vec<String> {
        let mut errors = Vec::new();
        while let Ok((key, result)) = self.receiver.try_recv() {
            self.pending.remove(&key);
            match result {
                Ok(b) => {
                    self.done.insert(key, Arc::new(b));
                }
                Err(e) => errors.push(format!("{}: {e}", key.spec)),
            }
        }
        errors
    }

    /// The bake of `key`, baked on this thread if it is not done yet.
    pub fn get_blocking(&mut self, key: BakeKey) -> Result<Arc<Bake>, String> {
        if let Some(b) = self.get(&key) {
            return Ok(b);
        }
        let b = Arc::new(bake_key(&self.map, key, self.align, self.roughness)?);
        self.done.insert(key, b.clone());
        Ok(b)
    }
}

/// Bakes `key` of `map` at f32 (PBR bakes at base perceptual roughness `roughness`).
fn bake_key(
    map: &NormalMap,
    key: BakeKey,
    align: Option<f64>,
    roughness: f64,
) -> Result<Bake, String> {
    let spec = key.spec;
    let pbr = PbrOptions {
        roughness,
        anisotropic: spec.pbr == PbrKind::Anisotropic,
        ..PbrOptions::default()
    };
    let options = BakeOptions {
        pbr,
        ..spec.bake_options(align)
    };
    if spec.method == Method::Pbr && spec.pbr == PbrKind::Mip {
        bake_formula(map, &pbr, None, Widening::Constant(0.0)).map_err(|e| e.to_string())
    } else if key.color && spec.is_mixture() {
        bake_with(map, spec.method, &options).map_err(|e| e.to_string())
    } else if spec.is_mixture() {
        // Without colour the lobes alone: bake a copy of the map without its albedo.
        let plain = NormalMap::from_vectors(
            map.width(),
            map.height(),
            map.normals().to_vec(),
            map.addressing(),
            ndfmap::ingest::BadNormals::Repair,
        )
        .map_err(|e| e.to_string())?;
        bake_with(&plain, spec.method, &options).map_err(|e| e.to_string())
    } else {
        bake_with(map, spec.method, &options).map_err(|e| e.to_string())
    }
}

/// `bake` with only its finest level: sampled with `GL_TEXTURE_MAX_LEVEL` 0 (the upload sets it
/// to the level count − 1), it is the unfiltered map, which the supersampled reference shades.
pub fn finest_level_only(bake: &Bake) -> Bake {
    let mut out = bake.clone();
    out.sizes.truncate(1);
    for t in &mut out.textures {
        t.levels.truncate(1);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_parse_and_print_as_bake_labels() {
        for (text, want) in [
            ("plain", "plain"),
            ("Toksvig", "toksvig"),
            ("vmf6a", "vmf6a"),
            ("vmf-3", "vmf3"),
            ("vmf", "vmf6a"),
            ("tan2005-4a", "tan2005-4a"),
            ("tan20054", "tan2005-4"),
            ("tan2005", "tan2005-4"),
            ("olano", "olano"),
            ("sh", "sh6"),
            ("SH2", "sh2"),
            ("pbr", "pbr"),
            ("PBR-aniso", "pbr-aniso"),
            ("pbr-mip", "pbr-mip"),
        ] {
            let spec: MethodSpec = text.parse().unwrap();
            assert_eq!(spec.to_string(), want, "{text}");
        }
        for bad in [
            "vmf9", "vmf0a", "plain2", "phong", "vmfx", "sh11", "sh2a", "pbr2", "pbr-x",
        ] {
            assert!(bad.parse::<MethodSpec>().is_err(), "{bad}");
        }
    }

    #[test]
    fn labels_match_the_bakes() {
        let map = ndfmap::procedural::generate(16, 1).map;
        for spec in [
            "plain",
            "lean",
            "vmf2a",
            "vmf2",
            "tan2005-2",
            "sh3",
            "pbr",
            "pbr-aniso",
        ] {
            let spec: MethodSpec = spec.parse().unwrap();
            let key = BakeKey { spec, color: false };
            // At the method's default strength (no `--align` value) the labels agree.
            let b = bake_key(&map, key, None, 0.3).unwrap();
            assert_eq!(b.label(), spec.to_string());
            let finest = finest_level_only(&b);
            assert_eq!(finest.level_count(), 1);
            assert!(finest.textures.iter().all(|t| t.levels.len() == 1));
        }
        // Another strength shows in the bake's label (the window's), not in the spec (the
        // benchmark's, whose frame times do not depend on it).
        let spec: MethodSpec = "vmf2a".parse().unwrap();
        let key = BakeKey { spec, color: false };
        let b = bake_key(&map, key, Some(1.0), 0.3).unwrap();
        assert_eq!(
            (b.label(), spec.to_string()),
            ("vmf2a(C=1)".into(), "vmf2a".into())
        );
    }
}
