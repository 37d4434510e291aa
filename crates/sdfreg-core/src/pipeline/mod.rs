//! Layer 5, the registration pipeline: the stages of [`crate::register()`] in order, each
//! with its settings beside it, [`settings::RegisterSettings`] gathering them, and the report
//! of what each did.
//!
//! - [`direction`]: stage 0 of a full call, which cloud Φ represents;
//! - [`target`]: stages 1–2 for the target (unit frame, pre-fit of Φ);
//! - [`surface`]: the target as the stages see it, fitted or frozen;
//! - [`multistart`] (stage 3), [`coarse_to_fine`] (stages 4–5), [`rerun`] (stage 6, the robust re-run; [`robust`]: the kernel's
//!   settings and policy),
//!   [`polish`] (stage 7), [`shift_search`] (stage 8);
//! - [`scale`]: the similarity's settings and scale starts (off by default);
//! - [`registration`]: stage 9 and the result, [`report`]: what each stage did;
//! - [`register`]: the entry points, one line per stage;
//! - [`evaluate`]: a given transformation's fitness at a chosen distance, no registration run.

pub(crate) mod coarse_to_fine;
pub(crate) mod direction;
pub(crate) mod evaluate;
pub(crate) mod multistart;
pub(crate) mod polish;
pub(crate) mod register;
pub(crate) mod registration;
pub(crate) mod report;
pub(crate) mod rerun;
pub(crate) mod robust;
pub(crate) mod scale;
pub(crate) mod settings;
pub(crate) mod shift_search;
pub(crate) mod surface;
pub(crate) mod target;
