//! ndfmap: filtered normal-distribution textures from normal maps.
//!
//! Implements "Frequency Domain Normal Map Filtering" (Han, Sun, Ramamoorthi, Grinspun 2007)
//! and the baselines it compares with. Data flows forward through one module per stage:
//! [`ingest`] → [`pyramid`] → methods ([`baseline`]; [`vmf`] and [`em`] for the paper's
//! Sec 7) → [`bake`] → [`shade`] / [`eval`] / [`pack`] / [`output`]; [`render`] draws views
//! (supersampled ground truth and the shaders' CPU twin) and `report` (feature `report`)
//! measures error against run time; [`ffi`] is the C ABI (`include/ndfmap.h`).

pub mod bake;
pub mod baseline;
pub mod em;
pub mod error;
pub mod eval;
pub mod ffi;
pub mod glsl;
pub mod ingest;
pub mod mixture;
pub mod output;
pub mod pack;
pub mod procedural;
pub mod pyramid;
pub mod render;
#[cfg(feature = "report")]
pub mod report;
mod rng;
pub mod sample;
pub mod shade;
pub mod tan2005;
pub mod vmf;

pub use error::{Error, Result};
pub use ingest::{IngestOptions, NormalMap};
