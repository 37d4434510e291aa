//! Layer 0, the foundation: the error types, the range checks of settings, the worker pool.
//! Imports nothing of the crate.

pub mod check;
pub mod error;
pub mod pool;
