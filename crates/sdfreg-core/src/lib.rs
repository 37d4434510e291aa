//! # sdfreg-core
//!
//! Correspondence-free rigid point-cloud registration by a neural signed distance function
//! (SDFReg, section 3 of the paper in `shared/paper`). The target cloud is represented by a small
//! MLP SDF Φ fitted to it; the source is moved by damped Levenberg–Marquardt on SE(3) so that
//! `Σ Φ(R pᵢ + t)²` is minimal — no point correspondences, no nearest-neighbour search in the
//! optimisation loop.
//!
//! ```no_run
//! use sdfreg_core::{io::read_point_cloud, register, RegisterSettings};
//! let source = read_point_cloud("source.ply")?;
//! let target = read_point_cloud("target.ply")?;
//! let result = register(&source, &target, None, &RegisterSettings::default())?;
//! println!("{}", result.matrix()); // maps source coordinates into the target frame
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! Modules: [`mod@register`] (the coarse-to-fine loop, settings and result), [`sdf_fit`] (fitting Φ),
//! [`mlp`] (the network with hand-written derivatives), [`lm`] (the SE(3) solver), [`polish`] (the final point-to-plane steps), [`shift_search`] (translations the SDF's valley
//! hides), [`se3`]
//! (exp/log maps), [`cloud`] (normalisation), [`mesh`] (surface sampling), [`degeneracy`] (free motions), [`io`] (PLY/XYZ), [`protocol`] (the paper's
//! evaluation pairs and error measures), [`shapes`] (procedural test shapes).
#![warn(missing_docs)]

pub mod cloud;
pub mod degeneracy;
pub mod error;
pub mod io;
pub mod lm;
pub mod mesh;
pub mod mlp;
pub mod polish;
pub mod protocol;
pub mod register;
pub mod sdf_fit;
pub mod se3;
pub mod shapes;
pub mod shift_search;

pub use degeneracy::{Degeneracy, FreeMotion, MotionKind};
pub use error::{Error, IoError, Role};
pub use lm::{Kernel, LmSettings};
pub use mlp::MlpSettings;
pub use polish::PolishSettings;
pub use register::{
    register, register_with_progress, RegisterSettings, Registration, Stage, StopReason,
};
pub use sdf_fit::FitSettings;
pub use shift_search::ShiftSearchSettings;
