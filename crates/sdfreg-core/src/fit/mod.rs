//! Layer 3, fitting Φ to the target cloud, self-supervised (paper eq. 18–20).
//!
//! - [`fitter`]: [`fitter::SdfFitter`] — the losses, the queries and the Adam steps;
//! - [`settings`]: [`FitSettings`](settings::FitSettings), the fit's settings;
//! - `adam` (crate-private): the optimiser.

pub(crate) mod adam;
pub mod fitter;
pub mod settings;
