//! Layer 7, many pairs: [`crate::register_many`] and [`crate::register_each`] on every core
//! (`pairs`, crate-private), and the results file of `sdfreg batch` with its reader ([`log`]).

pub mod log;
pub(crate) mod pairs;
