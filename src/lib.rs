//! ndfmap: filtered normal-distribution textures from normal maps.
//!
//! Implements "Frequency Domain Normal Map Filtering" (Han, Sun, Ramamoorthi, Grinspun 2007)
//! and the baselines it compares with. Data flows forward through one module per stage:
//! [`ingest`] → [`pyramid`] → methods ([`baseline`]) → [`bake`] → [`shade`] / [`eval`] /
//! [`output`].

pub mod em;
pub mod error;
pub mod ingest;
pub mod vmf;

pub use error::{Error, Result};
pub use ingest::{IngestOptions, NormalMap};
