//! Integration tests of sdfreg-core on procedural shapes (no data files needed).

mod common;
mod io;
mod model;
mod register;
mod scenes;
