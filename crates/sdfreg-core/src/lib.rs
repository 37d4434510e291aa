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
//!   [`ShiftSearchSettings`], [`ScaleSettings`] (similarity registration, off by default);
//!   presets [`RegisterSettings::default`] and
//!   [`RegisterSettings::partial_scans`].
//! - [`SdfModel`]: the fitted target as an object — [`SdfModel::fit`] once, then
//!   [`SdfModel::register`] many sources against it (Φ frozen; [`SdfModel::register_refined`]
//!   refines a private copy), [`SdfModel::track`] a sequence of frames, query it
//!   ([`SdfModel::distance`], [`SdfModel::gradient`], [`SdfModel::closest_points`]), mesh it
//!   ([`SdfModel::mesh`]), save and load it as `.sdfm` ([`model::file`]).
//! - [`register_many`]: many [`Pair`]s (against clouds or models) on every core, one pair per
//!   worker, results in input order and equal to registering each alone.
//! - [`register_each`]: the same over any iterator of keyed pairs, pulled lazily, each result
//!   handed back as it finishes ([`register_each_loading`]: each worker reads its own pair's
//!   files); [`batch::log`]: the results file of `sdfreg batch`, and its reader.
//! - [`io`]: reading and writing clouds and meshes (PLY, PCD, LAS/LAZ, XYZ/TXT/CSV/PTS), errors
//!   naming file and place ([`IoError`]).
//!
//! ## The layers, bottom-up
//! Each folder of the source is a layer; a module imports only from its own layer or from lower
//! ones, and no two modules import each other, directly or around a loop (checked by the
//! `layers` test of the workspace).
//! 0. `base` (crate-private): the error types ([`Error`], [`IoError`]), the range checks of
//!    settings, the worker pool.
//! 1. [`geometry`]: [`geometry::se3`] (exp/log maps, pose errors), [`geometry::cloud`]
//!    (bounding box, centroid, the unit-frame normalisation), [`geometry::mesh`] (sampling
//!    triangles), [`geometry::tree`] (the k-d tree, the point spacing), local planes.
//! 2. [`field`]: the [`field::Field`] trait, the MLP with hand-written derivatives
//!    ([`field::mlp`], its softplus kernels in `field::activation`), the local grid
//!    ([`field::local_grid`]), Φ = MLP + grid ([`field::sdf`]), Φ baked into a grid
//!    ([`field::baked`]), a mesh's exact distance ([`field::mesh`]).
//! 3. [`fit`]: fitting Φ — [`fit::fitter::SdfFitter`] (losses, queries, Adam),
//!    [`fit::settings::FitSettings`].
//! 4. [`solve`]: the SE(3) Levenberg–Marquardt solver ([`solve::lm`]), the robust kernel
//!    ([`solve::kernel`]), the free motions ([`solve::degeneracy`]), the quality figures.
//! 5. `pipeline` (crate-private, its entry points re-exported here): the stages of
//!    [`register()`] below, each with its settings, [`RegisterSettings`] and the report.
//! 6. [`model`]: [`SdfModel`], [`MeshModel`], tracking, the `.sdfm` format ([`model::file`]).
//! 7. [`batch`]: [`register_many`], [`register_each`], and the results file of `sdfreg batch`
//!    ([`batch::log`]).
//! 8. [`views`]: many scans into one frame — [`align()`] (pairwise registrations through stored
//!    models, a pose graph, a joint refinement), [`Alignment`].
//!
//! Beside the layers: [`io`] (above `geometry`: a mesh file is sampled into a cloud) and [`sim`]
//! (procedural [`sim::shapes`] and the LiDAR simulator [`sim::lidar`], for tests and benches).
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

mod base;
pub mod batch;
pub mod field;
pub mod fit;
pub mod geometry;
pub mod io;
pub mod model;
mod pipeline;
pub mod sim;
pub mod solve;
pub mod views;

pub use base::error::{Error, IoError, Role};
pub use batch::pairs::{register_each, register_each_loading, register_many, Pair, PairTarget};
pub use field::local_grid::{LocalSettings, ModelKind};
pub use field::mlp::MlpSettings;
pub use fit::settings::FitSettings;
pub use geometry::cloud::LeftOut;
pub use model::mesh_model::MeshModel;
pub use model::sdf_model::SdfModel;
pub use pipeline::coarse_to_fine::CoarseToFineSettings;
pub use pipeline::direction::SWAP_MIN_EXTENT;
pub use pipeline::evaluate::{evaluate_registration, Evaluation};
pub use pipeline::multistart::MultistartSettings;
pub use pipeline::polish::{PolishSettings, SNAP_RATIO};
pub use pipeline::register::{register, register_with_progress};
pub use pipeline::registration::Registration;
pub use pipeline::report::{
    CoarseToFineReport, FinalLmReport, GlobalRerunReport, InitialReport, PolishReport,
    PolishResult, PoseChange, RescueReport, RobustReport, ShiftSearchReport, Stage, StageTimes,
    Stages,
};
pub use pipeline::robust::{RobustMode, RobustSettings, OUTSIDE_SPACINGS};
pub use pipeline::scale::{ScaleSettings, DEFAULT_RANGE, UNIT_FACTORS};
pub use pipeline::settings::{RegisterSettings, DEFAULT_SWAP_RATIO, MIN_POINTS};
pub use pipeline::shift_search::ShiftSearchSettings;
pub use solve::degeneracy::{Degeneracy, FreeMotion, MotionKind, FREE_MOTION_RATIO};
pub use solve::kernel::{Kernel, MAD_TO_SIGMA, SCALE_SIGMAS};
pub use solve::lm::{LmSettings, StopReason};
pub use views::align::{align, AlignSettings, AlignTimes, Alignment, Edge};
pub use views::consensus::{ConsensusOutcome, ConsensusSettings};
pub use views::free_space::SeenFrom;
