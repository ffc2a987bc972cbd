//! ndfmap: filtered normal-distribution textures from normal maps.
//!
//! Implements "Frequency Domain Normal Map Filtering" (Han, Sun, Ramamoorthi, Grinspun 2007)
//! and the baselines it compares with. Data flows forward through one module per stage, and no
//! module imports one above it:
//!
//! - data: [`budget`] (the memory budget), [`mod@format`] (storage formats, value ranges) →
//!   [`bake`] (the textures every method produces, options, progress); [`harmonics`] (the
//!   real SH basis, quadratures) → [`brdf`] (the one BRDF library: lobes, g factors, `ρ̂_l`,
//!   widening rules, the exact unfiltered shading);
//! - input: [`ingest`] → [`pyramid`] (exact footprints);
//! - methods: [`baseline`]; [`sh`] (the spherical-harmonic NDF); [`vmf`], [`em`] and
//!   [`tan2005`] driven per level by [`mixture`]; [`pbr`] (normal + GGX roughness MIP chains
//!   for unmodified engines); [`methods`] is the one dispatch over them;
//! - consumers: [`shade`] (the shaders' CPU twin) → [`sample`] / [`eval`] / [`render`];
//!   [`pack`] / [`output`] (storage, files), [`glsl`] (the shaders), [`plan`] (the scene
//!   planner: what a scene needs, issue 18), `report` (feature
//!   `report`, error against run time), [`ffi`] (the C ABI, `include/ndfmap.h`); [`usage`]
//!   (this process's CPU time and memory, for the timings they print).

pub mod bake;
pub mod banded;
pub mod baseline;
pub mod batch;
pub mod brdf;
pub mod budget;
pub mod compress;
pub mod container;
pub mod em;
pub mod envgpu;
pub mod environment;
pub mod envlight;
pub mod error;
pub mod eval;
pub mod ffi;
pub mod format;
pub mod glsl;
pub mod harmonics;
pub mod ingest;
pub mod methods;
pub mod mixture;
pub mod output;
pub mod pack;
pub mod pbr;
pub mod plan;
pub mod procedural;
pub mod pyramid;
pub mod quality;
pub mod render;
#[cfg(feature = "report")]
pub mod report;
mod rng;
pub mod sample;
pub mod sh;
pub mod shade;
pub mod tan2005;
pub mod usage;
pub mod vmf;

pub use error::{Error, Result};
pub use ingest::{IngestOptions, NormalMap};
