//! sdfreg-core: correspondence-free rigid registration by a neural signed distance function.
#![warn(missing_docs)]
pub mod cloud;
pub mod error;
pub mod mlp;
pub mod sdf_fit;
pub mod se3;
