//! Layer 9, many views: a set of scans aligned into one frame ([`align::align`]) through
//! pairwise registrations against stored models, a pose graph ([`graph`]), an optional multi-view
//! point-to-plane refinement ([`consensus`]) and an optional joint refinement against one model of
//! the others; a pair that lays one scan into the other's free space ([`free_space`]) can be
//! dropped. The poses file that records an alignment: [`poses_file`].

pub mod align;
pub mod consensus;
pub mod free_space;
pub mod graph;
pub mod poses_file;
