//! Layer 9, many views: a set of scans aligned into one frame ([`align::align`]) through
//! pairwise registrations against stored models, a pose graph ([`graph`]) and a joint
//! refinement against one model of the others.

pub mod align;
pub mod graph;
