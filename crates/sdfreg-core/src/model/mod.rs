//! Layer 6, models: a target kept to register many sources against — [`crate::SdfModel`] (Φ
//! fitted once), [`crate::MeshModel`] (a mesh's exact distance), tracking, and the `.sdfm`
//! file format ([`file`](mod@file)).

pub mod file;
pub(crate) mod mesh_model;
pub(crate) mod sdf_model;
pub(crate) mod track;
