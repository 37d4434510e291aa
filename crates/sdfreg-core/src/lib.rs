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
//! ## Entry points
//! - [`register()`] / [`register_with_progress`]: one pair, the pipeline below; returns a
//!   [`Registration`] (pose, convergence, fitness, information matrix, [`Degeneracy`], and
//!   [`Stages`]: what each stage did) or an [`Error`].
//! - [`RegisterSettings`]: every setting, one struct per stage — [`MlpSettings`],
//!   [`FitSettings`], [`MultistartSettings`], [`CoarseToFineSettings`], [`LmSettings`],
//!   [`RobustSettings`] (with the [`RobustMode`] choice), [`PolishSettings`],
//!   [`ShiftSearchSettings`]; presets [`RegisterSettings::default`] and
//!   [`RegisterSettings::partial_scans`].
//! - [`SdfModel`]: the fitted target as an object — [`SdfModel::fit`] once, then
//!   [`SdfModel::register`] many sources against it (Φ frozen; [`SdfModel::register_refined`]
//!   refines a private copy), [`SdfModel::track`] a sequence of frames, query it
//!   ([`SdfModel::distance`], [`SdfModel::gradient`], [`SdfModel::closest_points`]), mesh it
//!   ([`SdfModel::mesh`]), save and load it as `.sdfm` ([`model_file`]).
//! - [`register_many`]: many [`Pair`]s (against clouds or models) on every core, one pair per
//!   worker, results in input order and equal to registering each alone.
//! - [`register_each`]: the same over any iterator of keyed pairs, pulled lazily, each result
//!   handed back as it finishes; [`batch_log`]: the results file of `sdfreg batch`, and its reader.
//! - [`io`]: reading and writing clouds and meshes (PLY, PCD, XYZ/TXT/CSV), errors naming file
//!   and place ([`IoError`]).
//! - [`se3`]: exp/log maps, rigid checks and pose errors; [`cloud`]: bounding box, centroid,
//!   the unit-frame normalisation; [`mesh`]: sampling points on triangles; [`shapes`]:
//!   procedural test shapes; [`lidar`]: a procedural LiDAR simulator (a spinning multi-beam
//!   sensor ray-cast into a street or a room); [`mesh_field`]: a mesh as its exact distance field.
//! - Building blocks (benchmarks, experiments): [`mlp`] (the network with hand-written
//!   derivatives), [`sdf_fit`] (fitting Φ), [`lm`] (the SE(3) solver).
//!
//! ## The pipeline, in the order [`register()`] runs it
//! 1. normalise both clouds into the target's unit frame (largest bounding-box side 1);
//! 2. pre-fit Φ to the target, self-supervised (paper eq. 18–20): queries projected along
//!    `Φ∇Φ/‖∇Φ‖` onto their nearest target point, `Φ = 0` on the target, an Eikonal term;
//! 3. initial hypotheses: the caller's guess, or a multi-start over the cube group's 24
//!    rotations (and shifted centroids), each refined by a few LM steps and scored on the target
//!    points, near-ties to the least rotation;
//! 4. coarse-to-fine (eq. 18-1): Φ refined with the moved source among its queries, alternating
//!    with LM steps (eq. 9–13) per hypothesis; the best-fitting one is kept;
//! 5. final LM on the frozen Φ;
//! 6. robust re-run when needed ([`RobustMode::Auto`]): a poor least-squares fit is redone with
//!    the Geman–McClure kernel;
//! 7. polish: robust point-to-plane Gauss–Newton against local planes of the target points
//!    (removes Φ's fitting floor), snapped onto the target's own points when the source lies on
//!    them, undone if it moves too far;
//! 8. shift search: a sparse occupancy cross-correlation proposes translations (a scene's
//!    fragments slide along walls in a smooth Φ); each is polished, kept on a fitness gain;
//! 9. measure: fitness, inlier RMSE, `JᵀJ` and the motions the data leave free.
#![warn(missing_docs)]

pub mod cloud;
pub mod field;
pub mod grid_field;
pub mod io;
pub mod lidar;
pub mod lm;
pub mod local_grid;
pub mod mesh;
pub mod mesh_field;
pub mod mlp;
pub mod sdf_fit;
pub mod se3;
pub mod shapes;

mod batch;
pub mod batch_log;
mod coarse_to_fine;
mod degeneracy;
mod error;
mod measure;
mod model;
pub mod model_file;
mod multistart;
mod polish;
mod register;
mod report;
mod robust;
mod settings;
mod shift_search;

pub use batch::{register_each, register_many, Pair, PairTarget};
pub use degeneracy::{Degeneracy, FreeMotion, MotionKind, FREE_MOTION_RATIO};
pub use error::{Error, IoError, Role};
pub use lm::{LmSettings, StopReason};
pub use local_grid::{LocalSettings, ModelKind};
pub use mesh_field::MeshModel;
pub use mlp::MlpSettings;
pub use model::SdfModel;
pub use polish::{PolishSettings, SNAP_RATIO};
pub use register::{register, register_with_progress, Registration, Stage};
pub use report::{
    CoarseToFineReport, FinalLmReport, InitialReport, PolishReport, PolishResult, PoseChange,
    RobustReport, ShiftSearchReport, Stages,
};
pub use robust::{
    Kernel, RobustMode, RobustSettings, MAD_TO_SIGMA, OUTSIDE_SPACINGS, SCALE_SIGMAS,
};
pub use sdf_fit::FitSettings;
pub use settings::{CoarseToFineSettings, MultistartSettings, RegisterSettings, MIN_POINTS};
pub use shift_search::ShiftSearchSettings;
