//! Layer 4, solving for the pose against a fixed field: the Levenberg–Marquardt solver on SE(3),
//! the robust kernel, and the figures of a pose's quality.
//!
//! - [`lm`]: damped LM on SE(3) (paper eq. 9–13);
//! - [`kernel`]: the Geman–McClure kernel and its scale;
//! - [`degeneracy`]: the motions the data leave free;
//! - `measure` (crate-private): cost, fitness, inlier RMSE and `JᵀJ` of a result.

pub mod degeneracy;
pub mod kernel;
pub mod lm;
pub(crate) mod measure;
