//! Rendering: radiance estimation from a photon map, to OpenEXR and PNG.
//!
//! **Units.** Photon flux is in watts per RGB channel. The irradiance estimate
//! E(x) = Σ_p Φ_p w(d_p) is in W/m² per channel ([`estimate`]); the radiance of a Lambertian
//! surface of albedo ρ is L = (ρ/π)·E in W/(m²·sr) per channel (method.md:
//! L = Σ f_r Φ_p w(d_p), f_r = ρ/π). An image in `full`, `caustic` or `direct` mode holds
//! that radiance as seen by the camera; in `irradiance` mode it holds E on the receiver (no
//! albedo, no 1/π), so a pixel of an orthographic top-down view is the mean irradiance over
//! its floor cell.

pub mod estimate;
pub mod image;

pub use estimate::{Estimator, Kernel, PhotonData, PhotonLookup, Scratch};
pub use image::{Image, Outputs};

use crate::format::FormatError;
use crate::scene::SceneError;
use crate::trace::TraceError;

/// Everything that can go wrong while rendering.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RenderError {
    #[error(transparent)]
    Format(#[from] FormatError),
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error(transparent)]
    Trace(#[from] TraceError),
    #[error("{file}: the photon map holds no photons: nothing to render")]
    EmptyMap { file: String },
    #[error("{file}: photon {index} has a non-finite {column}")]
    NonFinite { file: String, column: String, index: u64 },
    #[error("{file}: {message}")]
    Image { file: String, message: String },
    #[error("{file}: {source}")]
    Io { file: String, source: std::io::Error },
    #[error("{0}")]
    Invalid(String),
}
